"""Issue 19, "Wrong or misleading answers": inputs that passed validation and broke later, a
``--set`` that smuggled in extra config, hints that suggested spellings that fail too,
messages that named the wrong problem, and a grading that failed only at its end.

Run as a user would (tests/cli_harness.py): each is one line, exit 2, within 5 s, before any
episode runs, nothing written.
"""

from __future__ import annotations

import os
import re

import pytest
from cli_harness import User, assert_refused, leftovers


@pytest.fixture
def user(tmp_path) -> User:
    return User(tmp_path)


def _nothing_written(user: User) -> bool:
    home, work = user.home, user.work
    return not any(work.iterdir()) and not leftovers(home) and not any((home / "tmp").iterdir())


def test_a_log_period_longer_than_the_arc_is_refused_before_the_episode(user):
    """``--set timeline.log_period=1000.0`` used to pass validation, run the whole episode and
    end in a broadcasting ValueError in the metrics."""
    outcome = user.run("run", "--set", "timeline.log_period=1000.0")
    assert_refused(outcome, "timeline.log_period", "arc_duration")
    assert _nothing_written(user)


@pytest.mark.parametrize(
    "value",
    ["station.time_step=0.002\ncontroller: ik", "station.time_step=0.002\r\ncontroller: ik"],
    ids=["newline", "crlf"],
)
def test_a_set_value_with_a_newline_is_refused(user, value):
    """A newline in a ``--set`` value used to become extra config (here: the IK controller)."""
    outcome = user.run("run", "--set", value)
    assert_refused(outcome, "--set", "line break")
    assert _nothing_written(user)


def test_a_set_value_is_one_value_for_its_key(user):
    """A block mapping on one line (``a: b``) is no scalar or flow value: refused; a flow
    mapping changes only the key's fields (an unknown one is named)."""
    outcome = user.run("run", "--set", "station=controller: ik")
    assert_refused(outcome, "--set", "one YAML scalar")
    outcome = user.run("run", "--set", "station={time_step: 0.001, controller: ik}")
    assert_refused(outcome, "station.controller")
    assert _nothing_written(user)


@pytest.mark.parametrize(
    ("written", "works"),
    [("1e+300", True), ("nan", False), ("inf", False)],
)
def test_hints_suggest_only_spellings_that_work(user, written, works):
    """A number YAML reads as text: the hint, if any, is a spelling YAML reads as that number
    (following it moves past the type error); nan and inf get no spelling (every number
    must be finite) and the message says so."""
    field = "timeline.extra_time"
    outcome = user.run("run", "--set", f"{field}={written}")
    assert_refused(outcome, field, "must be a number")
    hint = re.search(r"write (\S+)\)", outcome.stderr)
    if not works:
        assert hint is None and "finite" in outcome.stderr
        return
    assert hint is not None, outcome.stderr
    followed = user.run("run", "--set", f"{field}={hint.group(1)}")
    assert "must be a number" not in followed.stderr  # the spelling is read as a number
    if written == "1e+300":
        assert_refused(followed, field, "600 s")  # and then held to the timeline's bound


@pytest.mark.parametrize("what", ["/dev/zero", "folder"])
@pytest.mark.parametrize("command", ["run --config", "sweep"])
def test_a_config_that_is_no_regular_file_gets_the_right_message(user, what, command):
    """``--config /dev/zero`` or a folder used to say "does not exist" (and /dev/zero would
    be read forever)."""
    home = user.home
    path = os.path.realpath("/dev/zero") if what == "/dev/zero" else str(home)
    if what == "/dev/zero" and not os.path.exists(path):
        pytest.skip("no /dev/zero here")
    expected = "not a regular file" if what == "/dev/zero" else "is a folder"
    outcome = user.run(*command.split(), path)
    assert_refused(outcome, expected, memory=True)
    assert "does not exist" not in outcome.stderr
    assert _nothing_written(user)


def _unwritable_folders(home) -> list[str]:
    folders = ["/proc/1"]  # no one may create a file there, root included
    if os.geteuid() != 0:
        locked = home / "locked"
        locked.mkdir()
        locked.chmod(0o555)
        folders.append(str(locked))
    return folders


def test_grading_into_an_unwritable_folder_fails_before_grading(user):
    """``pset grade --out`` into a folder that takes no file: refused before grading (which
    takes minutes), the problem set untouched."""
    home, work = user.home, user.work
    init = user.run("pset", "init", "pset5")
    assert init.code == 0, init.stderr
    before = sorted(p.name for p in (work / "pset5").iterdir())
    for folder in _unwritable_folders(home):
        outcome = user.run("pset", "grade", "pset5", "--out", f"{folder}/results.json")
        assert_refused(outcome, "cannot write", folder)
    assert sorted(p.name for p in (work / "pset5").iterdir()) == before
    assert not leftovers(work, home)
