"""Bad input to the ``doorlab`` command: exit code 2, one line on stderr, nothing written.

Every case fails before any simulation starts (the successful runs are tested elsewhere).
The CLI runs in-process through ``doorlab.cli.parser.main`` and, for a few cases, as a subprocess
(``python -m doorlab.cli``) to prove that no traceback reaches the user.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from doorlab.cli.parser import USAGE_ERROR, main
from doorlab.config import CONTROLLERS, DOOR_STATES, INNER_LOOPS

SRC_DIR = Path(__file__).resolve().parents[1] / "src"
SUBPROCESS_TIMEOUT = 120  # [s] importing pydrake takes a few seconds; nothing is simulated


def _cli(argv: list[str], capsys) -> tuple[int, str, str]:
    """Runs ``main(argv)``; returns (exit code, stdout, stderr). argparse errors exit."""
    try:
        code = main(argv)
    except SystemExit as e:  # argparse reports its errors through sys.exit
        code = e.code
    out, err = capsys.readouterr()
    return code, out, err


def _files(folder: Path) -> set[Path]:
    """Everything under ``folder``, hidden entries included."""
    return set(folder.rglob("*"))


@pytest.fixture
def workdir(tmp_path, monkeypatch) -> Path:
    """An empty working directory with the files the cases refer to."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("not a folder\n")
    (tmp_path / "existing").mkdir()
    (tmp_path / "existing" / "keep.txt").write_text("old run\n")
    (tmp_path / "unknown_key.yaml").write_text("station:\n  nosuch_key: 1\n")
    (tmp_path / "broken.yaml").write_text("station: [\n")
    return tmp_path


# (id, argv, strings stderr must contain: the option or field, and the valid choices)
BAD_INPUTS = [
    ("controller bogus", ["run", "--controller", "bogus"], ["--controller", "bogus", *CONTROLLERS]),
    ("doors ajar", ["run", "--doors", "ajar"], ["--doors", "ajar", *DOOR_STATES]),
    ("knots 1", ["run", "--knots", "1"], ["--knots", "[2, 100]"]),
    ("knots x", ["run", "--knots", "x"], ["--knots", "'x'"]),
    ("knots 101", ["run", "--controller", "ik", "--knots", "101"], ["--knots", "[2, 100]"]),
    (
        "knots without ik",
        ["run", "--controller", "velocity", "--knots", "5"],
        ["--knots", "--controller ik"],
    ),
    ("config missing", ["run", "--config", "missing.yaml"], ["missing.yaml"]),
    (
        "config unknown key",
        ["run", "--config", "unknown_key.yaml"],
        ["unknown_key.yaml", "nosuch_key"],
    ),
    ("set time_step=-1", ["run", "--set", "station.time_step=-1"], ["station.time_step"]),
    ("set unknown field", ["run", "--set", "nosuchfield=3"], ["nosuchfield"]),
    ("set without =", ["run", "--set", "station.time_step"], ["--set", "station.time_step"]),
    (
        "set bad choice",
        ["run", "--set", "station.inner_loop.kind=pid"],
        ["station.inner_loop.kind", *INNER_LOOPS],
    ),
    ("set bad list", ["run", "--set", "station.inner_loop.kq=[1,2]"], ["station.inner_loop.kq"]),
    ("realtime -1", ["run", "--realtime", "-1"], ["--realtime"]),
    ("report jobs 0", ["report", "--jobs", "0"], ["--jobs"]),
    ("out under a file", ["run", "--out", "afile/sub"], ["--out", "afile"]),
    ("out is a file", ["run", "--out", "afile"], ["--out", "afile"]),
    ("out exists", ["run", "--out", "existing"], ["--out", "existing", "keep.txt", "--force"]),
]


def _check_one_line_error(code: int, out: str, err: str, needles: list[str]) -> None:
    assert code == USAGE_ERROR, (code, err)
    assert "Traceback" not in out + err
    assert out == ""
    assert err.endswith("\n") and len(err.splitlines()) == 1, err
    for needle in needles:
        assert needle in err, (needle, err)


@pytest.mark.parametrize(
    ("argv", "needles"), [c[1:] for c in BAD_INPUTS], ids=[c[0] for c in BAD_INPUTS]
)
def test_bad_input_is_one_line_exit_2_and_writes_nothing(workdir, capsys, argv, needles):
    """Bad input exits 2 with one stderr line naming the option/field (and choices), no files."""
    before = _files(workdir)
    code, out, err = _cli(argv, capsys)
    _check_one_line_error(code, out, err, needles)
    assert _files(workdir) == before  # no doorlab_out/, no .*.partial, existing/ untouched


def test_report_with_a_bad_field_is_one_line_exit_2(workdir, capsys):
    """report --set station.time_step=-1 exits 2 naming the field, nothing written."""
    before = _files(workdir)
    code, out, err = _cli(["report", "--set", "station.time_step=-1"], capsys)
    _check_one_line_error(code, out, err, ["station.time_step"])
    assert _files(workdir) == before


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["run", "--config", "broken.yaml"], "broken.yaml"),
        (["run", "--set", "station.time_step=[1"], "station.time_step"),
    ],
    ids=["config not YAML", "set value not YAML"],
)
def test_invalid_yaml_is_one_line_exit_2(workdir, capsys, argv, needle):
    """A config file or --set value that is not valid YAML exits 2 with one line naming it."""
    code, out, err = _cli(argv, capsys)
    _check_one_line_error(code, out, err, [needle])


def test_main_returns_the_exit_code_on_an_option_error(workdir, capsys):
    """main() returns 2 (does not raise SystemExit) for an invalid --controller."""
    assert main(["run", "--controller", "bogus"]) == USAGE_ERROR


def test_out_exists_leaves_the_old_folder_and_no_staging(workdir, capsys):
    """run --out on an existing folder without --force keeps it intact and stages nothing."""
    code, _, err = _cli(["run", "--out", "existing"], capsys)
    assert code == USAGE_ERROR, err
    assert (workdir / "existing" / "keep.txt").read_text() == "old run\n"
    assert not list(workdir.glob(".existing*"))
    assert not list(workdir.glob("*.partial")) and not list(workdir.glob(".*.partial"))


SUBPROCESS_CASES = [
    ("argparse choice", ["run", "--controller", "bogus"], ["--controller", *CONTROLLERS]),
    ("scenario field", ["run", "--set", "station.time_step=-1"], ["station.time_step"]),
    ("output folder", ["run", "--out", "afile/sub"], ["--out"]),
]


@pytest.mark.parametrize(
    ("argv", "needles"), [c[1:] for c in SUBPROCESS_CASES], ids=[c[0] for c in SUBPROCESS_CASES]
)
def test_subprocess_bad_input_exits_2_without_traceback(workdir, argv, needles):
    """python -m doorlab.cli with bad input exits 2 with one stderr line and no traceback."""
    env = {**os.environ, "PYTHONPATH": str(SRC_DIR)}
    before = _files(workdir)
    completed = subprocess.run(
        [sys.executable, "-m", "doorlab.cli", *argv],
        cwd=workdir,
        env=env,
        capture_output=True,
        text=True,
        timeout=SUBPROCESS_TIMEOUT,
        check=False,
    )
    _check_one_line_error(completed.returncode, completed.stdout, completed.stderr, needles)
    assert _files(workdir) == before
