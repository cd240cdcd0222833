"""Issue 19, "Data loss": ``--force`` replaces only what doorlab wrote, every way out leaves
no staging folder, and what doorlab writes follows the user's umask.

Every case runs the ``doorlab`` command as a user would (tests/cli_harness.py: a subprocess
in its own session, signals to its process group) and checks: no user file lost, no staging
folder left, no traceback, stderr under 10 kB, refusals within 5 s.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import stat
from pathlib import Path

import pytest
from cli_harness import (
    User,
    assert_clean_exit,
    assert_refused,
    interrupt_doorlab,
)

from doorlab.runtime.folders import MANIFEST_NAME

SHORT = [
    *("--set", "timeline.hold_duration=0.1", "--set", "timeline.approach_duration=1.0"),
    *("--set", "timeline.grasp_duration=0.2", "--set", "timeline.arc_duration=1.0"),
    *("--set", "timeline.extra_time=0.0", "--no-replay"),
]
"""A 6.3 s episode (about a second of wall time): what a finished run needs, cheaply. Its
status may be slipped (exit 3): a 1 s arc yanks the handle."""
FINISHED = (0, 3, 4)
"""Exit codes of a run that finished (ok, slipped, speed_limit)."""
LONG = ["--set", "timeline.extra_time=300.0", "--no-replay"]
"""A 324 s episode, interrupted long before its end."""
FAR_SPEC = (
    "controllers: [ik]\ndoors: [closed]\naxes:\n  station.cupboard_position: [[3.0, 0.0, 0.4148]]\n"
)
"""A one-run sweep whose IK fails at once (the cupboard out of reach): a cheap sweep folder."""
UMASK = 0o002
"""A course group's umask: what doorlab writes must be group-writable under it."""


@pytest.fixture
def user(tmp_path) -> User:
    return User(tmp_path)


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {
        p.relative_to(folder).as_posix(): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


@pytest.fixture(scope="module")
def pristine(tmp_path_factory) -> dict[str, Path]:
    """Folders doorlab wrote, once per module: a run (short episode) and a sweep (one failed
    IK). Tests copy them (the manifest holds relative paths and content hashes)."""
    user = User(tmp_path_factory.mktemp("pristine"))
    run = user.run("run", "--out", "run", *SHORT, umask=UMASK)
    assert_clean_exit(run, run.code)
    assert run.code in FINISHED, run.stderr
    (user.work / "far.yaml").write_text(FAR_SPEC)
    sweep = user.run("sweep", "far.yaml", "--out", "sweep", "--jobs", "1", umask=UMASK)
    assert_clean_exit(sweep, 0)
    return {"run": user.work / "run", "sweep": user.work / "sweep"}


def _copy(source: Path, user: User, name: str) -> Path:
    target = user.work / name
    shutil.copytree(source, target, symlinks=True)
    return target


# --force replaces only what doorlab wrote --------------------------------------------------


@pytest.mark.parametrize("command", ["run", "report", "sweep"])
def test_force_refuses_a_folder_holding_a_users_file(user, command):
    """``mkdir v && echo precious > v/p.txt && doorlab run --out v --force`` (and report,
    sweep): exit 2 naming p.txt, before any episode; v is untouched."""
    folder = user.work / "v"
    folder.mkdir()
    (folder / "p.txt").write_text("precious\n")
    argv = {"run": SHORT, "report": ["--no-robustness"], "sweep": ["--grid", "impedance.kv=1"]}
    outcome = user.run(command, "--out", "v", "--force", *argv[command])
    assert_refused(outcome, "'v'", "p.txt", "--force")
    assert _snapshot(folder) == {"p.txt": b"precious\n"}
    assert user.clean()


def test_run_force_refuses_the_home_folder_and_the_root(user):
    """``--out ~ --force`` and ``--out / --force`` are refused at once (no episode runs)."""
    (user.home / ".bashrc").write_text("export KEEP=1\n")
    before = _snapshot(user.home)
    outcome = user.run("run", "--out", str(user.home), "--force", *SHORT)
    assert_refused(outcome, str(user.home), "--force")
    outcome = user.run("run", "--out", "/", "--force", *SHORT)
    assert_refused(outcome, "'/'", "root")
    after = _snapshot(user.home)
    assert {k: v for k, v in after.items() if not k.startswith("tmp/")} == before
    assert user.clean()


@pytest.mark.slow
def test_run_force_replaces_only_doorlabs_unchanged_files(user, pristine):
    """A run folder doorlab wrote: an edited or an added file stops --force (named, kept);
    unchanged, --force replaces it whole, with a fresh manifest."""
    folder = _copy(pristine["run"], user, "out")
    metrics = folder / "metrics.json"
    metrics.write_text(metrics.read_text().replace("{", '{"note": "mine",', 1))
    outcome = user.run("run", "--out", "out", "--force", *SHORT)
    assert_refused(outcome, "metrics.json", "changed since doorlab wrote it")
    assert '"note": "mine"' in metrics.read_text()
    shutil.copy(pristine["run"] / "metrics.json", metrics)
    (folder / "figures").mkdir()
    (folder / "figures" / "my.png").write_bytes(b"\x89PNG mine")
    outcome = user.run("run", "--out", "out", "--force", *SHORT)
    assert_refused(outcome, "figures/my.png", "did not write")
    assert (folder / "figures" / "my.png").read_bytes() == b"\x89PNG mine"
    shutil.rmtree(folder / "figures")
    outcome = user.run("run", "--out", "out", "--force", *SHORT)
    assert_clean_exit(outcome, outcome.code)
    assert outcome.code in FINISHED
    manifest = json.loads((folder / MANIFEST_NAME).read_text())["files"]
    assert set(manifest) == set(_snapshot(folder)) - {MANIFEST_NAME}
    assert user.clean()


@pytest.mark.slow
def test_run_force_through_a_link_leaves_the_link_and_no_old_folder(user, pristine):
    """``run --out LINK --force``: the folder the link names is replaced, the link stays a
    link to it, and no ``.partial.old`` is left (beside the link or the folder)."""
    target = _copy(pristine["run"], user, "real")
    (user.work / "link").symlink_to("real")
    outcome = user.run("run", "--out", "link", "--force", *SHORT)
    assert_clean_exit(outcome, outcome.code)
    assert outcome.code in FINISHED
    assert (user.work / "link").is_symlink() and os.readlink(user.work / "link") == "real"
    assert (target / MANIFEST_NAME).is_file() and (target / "metrics.json").is_file()
    assert sorted(p.name for p in user.work.iterdir()) == ["link", "real"]
    assert user.clean()


@pytest.mark.slow
def test_pset_init_force_never_replaces_a_students_edits(user):
    """``pset init DIR --force`` over a student's folder: refused naming the edited file, which
    is kept; over an untouched one (Python's bytecode caches aside) it replaces the folder."""
    assert_clean_exit(user.run("pset", "init", "pset5"), 0)
    solution = user.work / "pset5" / "ik_utils.py"
    solution.write_text(solution.read_text() + "\n# my solution\n")
    outcome = user.run("pset", "init", "pset5", "--force")
    assert_refused(outcome, "ik_utils.py", "changed since doorlab wrote it")
    assert solution.read_text().endswith("# my solution\n")
    fresh = user.work / "fresh"
    assert_clean_exit(user.run("pset", "init", "fresh"), 0)
    cache = fresh / "manip_station_sim" / "__pycache__"
    cache.mkdir()
    (cache / "robot_plans.cpython-311.pyc").write_bytes(b"\x00bytecode")
    outcome = user.run("pset", "init", "fresh", "--force", "--solutions")
    assert_clean_exit(outcome, 0)
    assert "NotImplementedError" not in (fresh / "ik_utils.py").read_text()  # the solutions
    assert user.clean()


@pytest.mark.slow
def test_sweep_force_and_resume_keep_a_users_page_and_figures(user, pristine):
    """A user's ``figures/my.png`` and edited ``index.html`` in a sweep folder stop both
    ``--force`` and ``--resume`` (named, kept); an untouched sweep folder is replaced."""
    (user.work / "far.yaml").write_text(FAR_SPEC)
    folder = _copy(pristine["sweep"], user, "sweep")
    (folder / "figures" / "my.png").write_bytes(b"\x89PNG mine")
    index = folder / "index.html"
    index.write_text(index.read_text() + "<!-- my notes -->")
    before = _snapshot(folder)
    outcome = user.run("sweep", "far.yaml", "--out", "sweep", "--force", "--jobs", "1")
    assert_refused(outcome, "figures/my.png")
    outcome = user.run("sweep", "far.yaml", "--out", "sweep", "--resume", "--jobs", "1")
    assert_refused(outcome, "--resume")
    assert _snapshot(folder) == before
    untouched = _copy(pristine["sweep"], user, "untouched")
    outcome = user.run("sweep", "far.yaml", "--out", "untouched", "--force", "--jobs", "1")
    assert_clean_exit(outcome, 0)
    assert (untouched / "results.parquet").is_file() and (untouched / MANIFEST_NAME).is_file()
    assert user.clean()


# Every way out leaves no staging folder ------------------------------------------------------


def _staging_exists(work: Path, name: str):
    return lambda: any(work.glob(f".{name}.*.partial"))


@pytest.mark.slow
@pytest.mark.parametrize(
    ("signum", "code"),
    [(signal.SIGTERM, 143), (signal.SIGINT, 130), (signal.SIGHUP, 129)],
    ids=["SIGTERM", "SIGINT", "SIGHUP"],
)
def test_a_signal_during_a_run_leaves_no_staging_folder(user, signum, code):
    """A signal to the process group (doorlab and its plot worker) mid-episode: the
    documented exit code, one line, no staging folder, no worker traceback."""
    outcome = interrupt_doorlab(
        ["run", "--out", "out", *LONG],
        signum,
        cwd=user.work,
        home=user.home,
        when=_staging_exists(user.work, "out"),
        settle_s=1.5,
    )
    assert_clean_exit(outcome, code, lines=1)
    assert "interrupted" in outcome.stderr
    assert outcome.wall_s < 5.0
    assert not (user.work / "out").exists() and user.clean()


@pytest.mark.slow
def test_sigterm_stops_an_ik_episode_of_cpp_systems_only(user):
    """IK has no Python in its episode: the chunked advance still lets SIGTERM in."""
    outcome = interrupt_doorlab(
        ["run", "--controller", "ik", "--out", "ik", *LONG],
        signal.SIGTERM,
        cwd=user.work,
        home=user.home,
        when=_staging_exists(user.work, "ik"),
        settle_s=2.0,
    )
    assert_clean_exit(outcome, 143, lines=1)
    assert outcome.wall_s < 5.0
    assert not (user.work / "ik").exists() and user.clean()


@pytest.mark.slow
def test_a_paced_run_stops_on_ctrl_c(user):
    """``--realtime 1e-9`` is refused (it would never end); at the slowest rate accepted,
    Ctrl-C still ends the run at once (Drake sleeps in C++ between the chunks)."""
    outcome = user.run("run", "--out", "slow", "--realtime", "1e-9", *SHORT)
    assert_refused(outcome, "--realtime", "0.01")
    outcome = interrupt_doorlab(
        ["run", "--out", "slow", "--realtime", "0.01", *SHORT],
        signal.SIGINT,
        cwd=user.work,
        home=user.home,
        when=_staging_exists(user.work, "slow"),
        settle_s=1.5,
    )
    assert_clean_exit(outcome, 130, lines=1)
    assert outcome.wall_s < 5.0
    assert not (user.work / "slow").exists() and user.clean()


# Permissions follow the umask ------------------------------------------------------------------


def _modes(folder: Path) -> dict[str, int]:
    return {
        p.relative_to(folder).as_posix(): stat.S_IMODE(p.stat().st_mode)
        for p in [folder, *folder.rglob("*")]
    }


def _assert_umask_modes(folder: Path, umask: int) -> None:
    for rel, mode in _modes(folder).items():
        expected = (0o777 if (folder / rel).is_dir() else 0o666) & ~umask
        assert mode == expected, (rel, oct(mode), oct(expected))


@pytest.mark.slow
def test_folders_and_files_follow_the_umask(user, pristine):
    """With umask 002 (a course group's), the pset folder, a run and a sweep (its table, page
    and figures) are group-writable: folders 0775, files 0664 (not tempfile's private
    0700/0600). The run and the sweep: the module's pristine folders, written under 002."""
    outcome = user.run("pset", "init", "pset5", umask=UMASK)
    assert_clean_exit(outcome, 0)
    for folder in (user.work / "pset5", pristine["run"], pristine["sweep"]):
        _assert_umask_modes(folder, UMASK)
    assert (pristine["sweep"] / "results.parquet").is_file()
    assert user.clean()
