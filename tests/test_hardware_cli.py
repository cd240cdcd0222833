"""``doorlab run --hardware``'s options: bad input is one line and exit 2, before any wait."""

from __future__ import annotations

import time

import numpy as np
import pytest

from doorlab.cli.parser import main
from doorlab.runtime.folders import write_manifest


@pytest.mark.parametrize(
    "args, message",
    [
        (["--lcm-url", "foo://bar"], "is not an LCM URL: use udpm://GROUP:PORT"),
        (["--lcm-url", "udpm://10.0.0.1:7667"], "is not a multicast group"),
        (["--lcm-url", "memq://"], "memq:// works inside one process only"),
        (["--wait", "0"], "--wait: must be a number of seconds in [0.01, 3600]"),
        (["--meshcat"], "--meshcat and --realtime do not apply to --hardware"),
    ],
)
def test_bad_hardware_options_are_one_line_errors(tmp_path, capsys, args, message):
    code = main(["run", "--hardware", "--yes", "--out", str(tmp_path / "run"), *args])
    err = capsys.readouterr().err
    assert code == 2
    assert message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "run").exists()


def test_hardware_options_need_hardware(capsys):
    assert main(["run", "--yes"]) == 2
    assert "--yes applies to --hardware only" in capsys.readouterr().err


def test_an_existing_folder_is_refused_before_waiting_for_the_driver(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    (out / "metrics.json").write_text("{}")
    write_manifest(out)  # a folder doorlab wrote (an empty one is written without --force)
    start = time.monotonic()
    code = main(["run", "--hardware", "--yes", "--wait", "30", "--out", str(out)])
    assert code == 2 and time.monotonic() - start < 5
    assert "already exists; pass --force" in capsys.readouterr().err


@pytest.mark.parametrize("value", ["fast", "-1", "25", "nan"])
def test_a_bad_answer_delay_knob_is_one_line(tmp_path, capsys, monkeypatch, value):
    """The test knob DOORLAB_TEST_ANSWER_DELAY_MS takes 0-20 ms; anything else is exit 2,
    one line naming it, before any wait."""
    monkeypatch.setenv("DOORLAB_TEST_ANSWER_DELAY_MS", value)
    code = main(["run", "--hardware", "--yes", "--wait", "30", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code == 2 and "DOORLAB_TEST_ANSWER_DELAY_MS" in err and "[0, 20]" in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "run").exists()


def test_the_answer_hold_waits_on_the_links_clock():
    """hold_until returns once the clock reaches the time, not before, sleeping most of it."""
    from doorlab.hardware.episode import hold_until

    for hold in (0.0004, 0.003):  # the yield alone; a sleep, then the yield
        start = time.monotonic()
        hold_until(time.monotonic, start + hold)
        assert time.monotonic() >= start + hold
    ticks = iter(np.arange(1, 100) * 1e-4)  # a fake clock: one tick per look
    hold_until(lambda: next(ticks), 0.00055)
    assert next(ticks) == pytest.approx(0.0007)  # it looked at 0.5 and 0.6 ms, then returned
