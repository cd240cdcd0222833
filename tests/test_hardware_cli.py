"""``doorlab run --hardware``'s options: bad input is one line and exit 2, before any wait."""

from __future__ import annotations

import time

import pytest

from doorlab.cli import main
from doorlab.runs import write_manifest


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
