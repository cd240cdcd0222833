"""Tests of ``doorlab.outputs.replay``: a self-contained HTML replay recorded from the logged
positions.

Meshcat's ``StaticHtml`` embeds every scene command as a base64 msgpack data URI
(``fetch("data:application/octet-binary;base64,...")``); the recorded animation is the command
holding ``set_animation``. Frames are integer keys ``time`` (k = 0..n-1) at ``fps``.
"""

from __future__ import annotations

import base64
import re
from pathlib import Path

import numpy as np
import pytest
from report_fixtures import short_result

from doorlab.errors import ConfigError
from doorlab.outputs.replay import replay_frame_times, replay_rows, save_replay

DATA_URI = re.compile(r"data:application/octet-binary;base64,([A-Za-z0-9+/=]+)")


def msgpack_uint(value: int) -> bytes:
    """msgpack encoding of a non-negative integer (positive fixint, uint8 or uint16)."""
    if value < 128:
        return bytes([value])
    if value < 256:
        return b"\xcc" + bytes([value])
    return b"\xcd" + value.to_bytes(2, "big")


def commands(html: str) -> list[bytes]:
    """The decoded msgpack commands embedded in a StaticHtml page."""
    return [base64.b64decode(m) for m in DATA_URI.findall(html)]


def animation(html: str) -> bytes:
    """The one embedded command that sets the recorded animation."""
    found = [c for c in commands(html) if b"set_animation" in c]
    assert len(found) == 1, f"expected one set_animation command, got {len(found)}"
    return found[0]


@pytest.fixture(scope="module")
def replays(tmp_path_factory):
    """Two replays of the same short run written in one process, with their sizes and times."""
    result, scenario = short_result()
    folder = tmp_path_factory.mktemp("replay")
    first = save_replay(result, folder / "first.html", scenario=scenario, fps=20)
    second = save_replay(result, folder / "second.html", scenario=scenario, fps=10)
    return result, first, second


def test_replay_is_written_and_self_contained(replays):
    """The HTML exists, loads no script, stylesheet or image from the network."""
    _, first, _ = replays
    html = first.read_text(encoding="utf-8")
    assert html.lstrip().lower().startswith("<!doctype html") or "<html" in html[:500].lower()
    for tag in re.findall(r"<(?:script|link|img|iframe)\b[^>]*>", html, flags=re.IGNORECASE):
        assert not re.search(r"(?:src|href)\s*=\s*[\"']?(?:https?:)?//", tag), tag
    # Drake inlines the viewer; the only remote URLs left are inside the three.js bundle (WebXR
    # controller profiles, the XR spec's documentation), never fetched by a desktop viewer.
    for url in re.findall(r"https?://[^\s\"'<>)]+", html):
        assert any(
            host in url
            for host in (
                "webxr-input-profiles",
                "w3.org",
                "developer.mozilla",
                "immersiveweb",
                "beej.us",
            )
        ), url
    assert first.stat().st_size < 10_000_000


def test_replay_contains_every_frame(replays):
    """The embedded animation has one keyframe index per frame: 0 .. n-1 and not n."""
    result, first, _ = replays
    times = replay_frame_times(result, 20)
    np.testing.assert_allclose(np.diff(times), 1 / 20)
    assert times[0] == 0.0 and times[-1] <= result.t[-1] + 1e-9 < times[-1] + 1 / 20
    anim = animation(first.read_text(encoding="utf-8"))
    n = len(times)
    assert b"\xa4time" + msgpack_uint(n - 1) in anim
    assert b"\xa4time" + msgpack_uint(n) not in anim
    assert anim.count(b"\xa4time") % n == 0  # every animated path has n keyframes


def test_second_replay_in_the_same_process_is_independent(replays):
    """A second replay (other fps) in the same process holds only its own animation."""
    result, first, second = replays
    n_first = len(replay_frame_times(result, 20))
    n_second = len(replay_frame_times(result, 10))
    anim_first = animation(first.read_text(encoding="utf-8"))
    anim_second = animation(second.read_text(encoding="utf-8"))
    tracks = anim_first.count(b"\xa4time") // n_first
    assert anim_second.count(b"\xa4time") == tracks * n_second
    assert b"\xa4time" + msgpack_uint(n_first - 1) not in anim_second


def test_frames_show_the_last_logged_row_at_or_before_them(replays):
    """Frame k shows the logged row with the largest t <= k / fps."""
    result, _, _ = replays
    times = replay_frame_times(result, 30)
    rows = replay_rows(result, times)
    assert np.all(result.t[rows] <= times + 1e-9)
    later = np.minimum(rows + 1, len(result.t) - 1)
    assert np.all((result.t[later] > times) | (later == rows))


def test_non_positive_fps_is_rejected(tmp_path: Path):
    """fps <= 0 raises ConfigError before anything is written."""
    result, scenario = short_result()
    with pytest.raises(ConfigError, match="fps"):
        save_replay(result, tmp_path / "x.html", scenario=scenario, fps=0)
    assert not (tmp_path / "x.html").exists()
