"""Issue 43: what a class shares that no view owns, the machine's memory and disk.

Each attack is rebuilt from the untouched stubs, graded by ``grade-all --jobs 2`` (a
subprocess, as an instructor runs it, with its own ``TMPDIR``) beside honest submissions whose
files differ (the answer key, each with a comment of its own: identical files would be
graded once), against the session's reference episodes:

- **hidden memory**: a submission that writes 2.6 GiB into memfds it never maps (in no
  process's resident set), the class in a memory cgroup smaller than the views' limits of
  main's grader together (2 x 3 GiB): on main the kernel's OOM killer ended grading
  supervisors, the honest classmate an ``error`` in every run;
- **a disk filler**: a submission that writes until ENOSPC everywhere it can, the class
  folder and ``TMPDIR`` on one small tmpfs the test mounts;
- **a disk that something else fills** during the run: ENOSPC for the class folder's writes;
- **a supervisor killed outright** (SIGKILL): its folders are gone at the next start.

Every honest classmate is 14 and ``graded`` in the first run and after ``--resume``, nothing
of theirs is left in ``TMPDIR``, the exit code and the summary say what happened. Tests that
make cgroups or mount run as root (they skip, saying why, elsewhere).
"""

from __future__ import annotations

import contextlib
import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pset_fixtures
import pytest
from pset_attacks import _insert, evidence

from doorlab.pset.classroom.grade_all import GRADES_CSV, RESULTS_JSON
from doorlab.pset.grading.grader import TESTS
from doorlab.pset.handout.folder import init_folder
from doorlab.pset.isolation import cgroups, memory

pytestmark = pytest.mark.slow

FULL = sum(t.max_score for t in TESTS)
SETUP = cgroups.probe()
AS_ROOT = os.geteuid() == 0
needs_cgroups = pytest.mark.skipif(
    SETUP.version is None or not AS_ROOT,
    reason=f"needs root and writable cgroups ({SETUP.reason or 'not root'})",
)
needs_root = pytest.mark.skipif(not AS_ROOT, reason="mounts a tmpfs: needs root")
HONEST = 2
"""Honest classmates in each class (their files differ)."""

MEMFD = r"""
import json, os, time
held, fds = 0, []
chunk = b"\x01" * (1 << 20)
def note():
    print("EVIDENCE memfd " + json.dumps({"held_mib": held >> 20, "files": len(fds)}), flush=True)
while held < TOTAL:  # never mapped: in no process's resident set
    fd = os.memfd_create("hold")
    for _ in range(31):  # below the 32 MiB file-size limit
        os.write(fd, chunk)
        held += len(chunk)
    fds.append(fd)
    if len(fds) % 2 == 0:
        note()
note()
time.sleep(SECONDS)
raise NotImplementedError("calc_p_Q: held memory in memfds")
"""
"""calc_p_Q: writes TOTAL bytes into memfds it never maps, then holds them SECONDS."""
MEMFD_TOTAL = 2600 << 20
"""What the attacker holds [bytes]: 2.6 GiB, as in the issue (under main's 3-GiB view limit)."""
CLASS_MEMORY = 2560 << 20
"""The class's memory cgroup [bytes]: less than two views of main's grader (2 x 3 GiB), room
for the grader (about 0.4 GiB, measured) and two views of this one."""

FILLER = r"""
import errno, json, os
ev = {}
for place in ("/pset", "/tmp", "/dev/shm", "/var/tmp", "/", os.getcwd()):
    written = 0
    try:
        i = 0
        while True:
            with open(os.path.join(place, f"fill_{i}"), "wb") as f:
                for _ in range(30):  # below the 32 MiB file-size limit
                    f.write(b"\x02" * (1 << 20))
                    written += 1 << 20
            i += 1
    except OSError as e:
        ev[place] = [written >> 20, errno.errorcode.get(e.errno, str(e.errno))]
print("EVIDENCE fill " + json.dumps(ev), flush=True)
raise NotImplementedError("calc_p_Q: filled what it could")
"""
"""calc_p_Q: writes until the kernel refuses everywhere it might (MiB written, the error)."""
DISK_BYTES = 96 << 20
"""The tmpfs holding the class folder and TMPDIR [bytes]: room for the grader (a grading's
private folders hold a few MiB; a submission's results and page 0.5 MiB), not for a filler."""


@pytest.fixture(scope="module")
def reference_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("reference") / "reference.json"
    path.write_text(json.dumps({"extra_data": {"reference": pset_fixtures.reference()}}))
    os.chmod(path.parent, 0o755)
    return path


def _class(
    root: Path, attackers: dict[str, tuple[str, dict]], honest: str = "key", count: int = HONEST
) -> Path:
    """``count`` honest submissions whose files differ (the answer key, or the stubs, each
    with a comment of its own) and the ``attackers`` (the stubs, calc_p_Q replaced), by name."""
    export = root / "export"
    export.mkdir(parents=True)
    base = init_folder(root / honest, solutions=honest == "key")
    for i in range(count):
        folder = export / f"honest_{i}"
        shutil.copytree(base, folder)
        path = folder / "open_left_door.py"
        path.write_text(path.read_text() + f"\n# honest classmate {i}\n")
    for name, (code, values) in attackers.items():
        _insert(init_folder(export / name), "calc_p_Q", code, values)
    subprocess.run(["chmod", "-R", "a+rX", str(root)], check=True)
    return export


def _rows(out: Path) -> dict[str, dict]:
    with open(out / GRADES_CSV, newline="") as f:
        return {row["submission"]: row for row in csv.DictReader(f)}


def _grade_all(export: Path, out: Path, tmp: Path, reference: Path, *more: str, group=None):
    """``doorlab pset grade-all`` as an instructor runs it (in ``group``'s cgroup)."""
    argv = [sys.executable, "-m", "doorlab.cli", "pset", "grade-all", str(export)]
    argv += ["--out", str(out), "--reference", str(reference), *more]
    env = dict(os.environ, TMPDIR=str(tmp))
    fds = group.join_descriptors() if group is not None else []
    try:
        return subprocess.run(
            argv,
            capture_output=True,
            text=True,
            timeout=900,
            env=env,
            pass_fds=fds,
            preexec_fn=(lambda: cgroups.join_by_descriptors(fds)) if fds else None,
        )
    finally:
        for fd in fds:
            os.close(fd)


def _memory_group(name: str, limit: int) -> cgroups.Group:
    """A cgroup of ``limit`` bytes of memory and no swap, below this process's."""
    base = cgroups.Group(SETUP, {k: Path(v) for k, v in SETUP.bases.items()})
    group = base.child(name, holds_groups=True)
    group.set_memory(limit)
    return group


@contextlib.contextmanager
def _tmpfs(folder: Path, size: int):
    """A tmpfs of ``size`` bytes mounted at ``folder`` for the block."""
    folder.mkdir(mode=0o755)
    options = f"size={size},mode=0755"
    subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(folder)], check=True)
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=False)


class Attacked:
    """The class graded beside hidden memory and a disk filler (see :func:`attacked`)."""

    runs: list[subprocess.CompletedProcess]
    rows: list[dict[str, dict]]
    left: list[list[str]]
    results: dict[str, dict]
    free: int
    group: str


@pytest.fixture(scope="module")
def attacked(tmp_path_factory, reference_file) -> Attacked:
    """HONEST answer keys beside a submission that hides 2.6 GiB in memfds and one that
    writes until ENOSPC everywhere, graded by ``grade-all --jobs 2`` in a memory group of
    CLASS_MEMORY, the class folder and TMPDIR on a tmpfs of DISK_BYTES; then ``--resume``."""
    if SETUP.version is None or not AS_ROOT:
        pytest.skip(f"needs root and writable cgroups ({SETUP.reason or 'not root'})")
    root = tmp_path_factory.mktemp("attacked")
    os.chmod(root, 0o755)
    attackers = {
        "hider": (MEMFD, {"TOTAL": MEMFD_TOTAL, "SECONDS": 20}),
        "filler": (FILLER, {}),
    }
    export = _class(root, attackers)
    state = Attacked()
    group = _memory_group(f"doorlab-test-memory-{os.getpid()}", CLASS_MEMORY)
    state.group, state.runs, state.rows, state.left = group.name, [], [], []
    try:
        with _tmpfs(root / "disk", DISK_BYTES) as disk:
            out, tmp = disk / "out", disk / "tmp"
            tmp.mkdir(mode=0o755)
            for more in ((), ("--resume",)):
                state.runs.append(
                    _grade_all(export, out, tmp, reference_file, "--jobs", "2", *more, group=group)
                )
                state.rows.append(_rows(out))
                state.left.append(sorted(p.name for p in tmp.iterdir()))
            state.results = {
                name: json.loads((out / name / RESULTS_JSON).read_text()) for name in attackers
            }
            state.free = shutil.disk_usage(disk).free
    finally:
        group.remove()
    return state


def test_every_honest_classmate_keeps_full_marks_beside_hidden_memory_and_a_disk_filler(
    attacked,
):
    """In the first run and after --resume: every honest classmate 14 and graded, both
    attackers graded (their own tests' verdicts), exit code 0, nothing left in TMPDIR. (On
    main, 57717eb, in this group: the hider's and an honest classmate's rows "error" ("the
    grading process failed (exit code -9)": the kernel ended their supervisors) and six
    supervisors' folders left in TMPDIR, one holding the classmate's files.)"""
    for run, rows, left in zip(attacked.runs, attacked.rows, attacked.left, strict=True):
        assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
        assert "Traceback" not in run.stderr, run.stderr[-3000:]
        for i in range(HONEST):
            row = rows[f"honest_{i}"]
            assert (row["status"], float(row["total"])) == ("graded", FULL), row
        assert rows["hider"]["status"] == rows["filler"]["status"] == "graded", rows
        assert left == [], left
    assert "changes: none" in attacked.runs[1].stdout, attacked.runs[1].stdout


def test_hidden_memory_is_its_own_view_s_and_the_summary_says_so(attacked):
    """The views' limits come from the class's group (two of them and what is kept for the
    grader fit in it; main's: 2 x 3 GiB), the summary says so; the hider's view is the only
    group out of memory, the kernel ends its code, which held memory up to its limit: its
    own test's verdict, named in the summary."""
    summary = attacked.runs[0].stdout
    results = attacked.results["hider"]
    view = results["extra_data"]["sandbox"]["cgroup"]["view_memory_bytes"]
    assert 2 * view + memory.GRADER_BYTES + 2 * memory.GRADING_BYTES <= CLASS_MEMORY
    assert view >= memory.VIEW_MEMORY_MIN_BYTES
    line = f"memory: each student's view at most {memory.mib(view)} (2 at once;"
    assert line in summary and attacked.group in summary, summary  # the class's group's room
    assert "the kernel ended the code of 1 submission at its view's limit (hider)" in summary
    test = next(t for t in results["tests"] if t["name"] == "Task 2 unit test: calc_p_Q")
    assert test["score"] == 0
    assert f"used more than {view >> 20} MiB of memory together" in test["output"], test
    held = evidence(results)["memfd"]["held_mib"]
    assert view >> 21 <= held <= view >> 20, held  # it held memory, up to its view's limit
    print(f"the hider held {held} MiB before the kernel ended it; {summary}")


def test_a_disk_filler_fills_only_its_own_view_s_memory(attacked):
    """The filler's writable places are its view's three tmpfs (64 MiB each, its memory):
    ENOSPC there, a read-only root elsewhere; the disk of the class folder and TMPDIR keeps
    its room (the class's own files only). (On main /pset was that disk.)"""
    filled = evidence(attacked.results["filler"])["fill"]
    assert filled["/pset"][1] == filled["/tmp"][1] == filled["/dev/shm"][1] == "ENOSPC"
    for place in ("/pset", "/tmp", "/dev/shm"):
        assert 32 <= filled[place][0] <= 64, filled  # whole MiB of 30-MiB files
    assert filled["/"][1] in ("EROFS", "EACCES") and filled["/var/tmp"][0] == 0, filled
    assert attacked.free > DISK_BYTES - (16 << 20), attacked.free  # a few MiB of the class's
    print(f"the filler wrote (MiB, then): {filled}")


SPACE_CHUNK = 1 << 20


def _fill(disk: Path) -> int:
    """Writes ``disk/filler.bin`` until the file system refuses (ENOSPC); returns its size."""
    written = 0
    with open(disk / "filler.bin", "wb") as f:
        try:
            while True:
                f.write(b"\0" * SPACE_CHUNK)
                f.flush()
                written += SPACE_CHUNK
        except OSError:
            pass
    return written


@needs_root
def test_a_disk_filled_from_outside_is_error_rows_and_resume_grades_them(tmp_path, reference_file):
    """The class folder's disk fills (from outside: another program) once the first results
    are written: grade-all goes on, each submission it cannot write or start is an ``error``
    row, the summary says what could not be written, exit 1, no traceback, the sheet is whole;
    once there is room, --resume grades those rows and goes on (no file it refuses). (On
    main: a raw traceback, or --resume refused until summary.txt was moved away by hand.)"""
    os.chmod(tmp_path, 0o755)
    export = _class(tmp_path, {}, honest="stubs", count=4)  # four cheap gradings
    tmp = tmp_path / "tmp"
    tmp.mkdir(mode=0o755)
    with _tmpfs(tmp_path / "disk", 24 << 20) as disk:
        out = disk / "out"
        filled = {}

        def fill_after_the_first() -> None:
            deadline = time.monotonic() + 600
            while time.monotonic() < deadline and not list(out.glob("*/results.json")):
                time.sleep(0.02)
            filled["bytes"] = _fill(disk)

        thread = threading.Thread(target=fill_after_the_first)
        thread.start()
        first = _grade_all(export, out, tmp, reference_file, "--jobs", "1")
        thread.join()
        assert first.returncode == 1, first.stdout[-3000:] + first.stderr[-3000:]
        assert "Traceback" not in first.stderr, first.stderr[-3000:]
        said = first.stdout
        assert "No space left on device" in said or "MiB free" in said, said
        sheet = (out / GRADES_CSV).read_text()
        rows = list(csv.DictReader(sheet.splitlines()))
        header = sheet.splitlines()[0].split(",")
        assert rows and all(len(r) == len(header) and None not in r.values() for r in rows)
        graded = [r for r in rows if r["status"] == "graded"]
        assert 1 <= len(graded) < 4, rows  # the disk filled after the first
        assert sorted(tmp.iterdir()) == []
        (disk / "filler.bin").unlink()
        again = _grade_all(export, out, tmp, reference_file, "--jobs", "1", "--resume")
        assert again.returncode == 0, again.stdout[-3000:] + again.stderr[-3000:]
        assert "Traceback" not in again.stderr, again.stderr[-3000:]
        rows = _rows(out)
        assert {r["status"] for r in rows.values()} == {"graded"}, rows
        assert len(rows) == 4
    print(f"filled {filled.get('bytes', 0) >> 20} MiB; the first run said: {said[-1500:]}")


SLEEPER = r"""
import time
time.sleep(60)
raise NotImplementedError("calc_p_Q: slept")
"""


def test_the_folders_of_a_supervisor_killed_outright_are_removed_at_the_next_start(
    tmp_path, monkeypatch
):
    """A supervisor killed by SIGKILL (the OOM killer's way) cannot remove its folders: the
    submission's copy (the student's files), the grading's, its own. The next supervisor
    removes them as it starts; a live one's stay."""
    from doorlab.pset.grading.grader import Supervisor, take_files

    folder = init_folder(tmp_path / "sleeper")
    _insert(folder, "calc_p_Q", SLEEPER, {})
    files, intake = take_files(folder)
    tmp = tmp_path / "tmp"
    tmp.mkdir(mode=0o755)
    monkeypatch.setenv("TMPDIR", str(tmp))
    alive = tmp / f"doorlab_grade_{os.getpid()}_live"  # a running grader's (this process)
    alive.mkdir()
    supervisor = Supervisor()
    thread, outcome = pset_fixtures.grade_in_thread(files, intake, supervisor)
    deadline = time.monotonic() + 120
    # (not a pattern on the name: a random suffix may end like the live folder's name)
    while time.monotonic() < deadline and not set(tmp.glob("doorlab_grade_*")) - {alive}:
        time.sleep(0.05)
    time.sleep(2)  # the grading under way: its student process sleeping
    assert thread.is_alive(), outcome  # still grading (the student sleeps 60 s)
    os.kill(supervisor._proc.pid, signal.SIGKILL)
    thread.join(60)
    supervisor.close()
    left = sorted(p.name.split("_")[1] for p in tmp.iterdir() if p != alive)
    assert {"supervisor", "submission", "grade"} <= set(left), left
    assert "error" in outcome, outcome
    subprocess.run(
        [sys.executable, "-I", "-m", "doorlab.pset.grading.supervisor", "serve"],
        input=b"",
        env=dict(os.environ, TMPDIR=str(tmp)),
        check=True,
        timeout=120,
    )
    assert sorted(tmp.iterdir()) == [alive]
