"""Issue 31: no submission of a class reaches a classmate's grade.

Each attack of the issue is rebuilt from the untouched stubs, in a class graded by
``grade-all --jobs 2`` beside honest submissions (the answer key), against the session's
reference episodes (``pset_fixtures.reference``): a submission that forks until EAGAIN, on and
off for most of a minute, beside 6 honest ones; a submission whose 50 busy children share a
0.5-CPU group with an honest one. The honest ones keep full marks and the status ``graded``:
each grading is a cgroup of its own (:mod:`doorlab.pset.cgroups`), its views' processes
bounded by their own ``pids.max``, its CPU share its own. Tests that make cgroups run as root
on a machine whose cgroups this user may write (they skip, saying why, elsewhere).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pset_fixtures
import pytest
from pset_attacks import _insert, evidence

from doorlab.pset import cgroups
from doorlab.pset.batch import GRADES_CSV, RESULTS_JSON, grade_class
from doorlab.pset.folder import init_folder
from doorlab.pset.grader import TESTS

FULL = sum(t.max_score for t in TESTS)
SETUP = cgroups.probe()
needs_cgroups = pytest.mark.skipif(
    SETUP.version is None or os.geteuid() != 0,
    reason=f"needs root and writable cgroups ({SETUP.reason or 'not root'})",
)

FORK_CYCLER = r"""
import errno, json, os, signal, time
ev = {"eagain": 0, "most": 0, "rounds": 0}
end = time.monotonic() + SECONDS
while time.monotonic() < end:  # on: fork until the kernel refuses, hold; off: let them go
    children = []
    while True:
        try:
            pid = os.fork()
        except OSError as e:
            if e.errno == errno.EAGAIN:
                ev["eagain"] += 1
            break
        if pid == 0:
            time.sleep(1.5)
            os._exit(0)
        children.append(pid)
    ev["most"] = max(ev["most"], len(children))
    ev["rounds"] += 1
    for pid in children:
        os.waitpid(pid, 0)
    time.sleep(0.5)
print("EVIDENCE forks " + json.dumps(ev))
raise NotImplementedError("calc_p_Q: forked until EAGAIN")
"""
"""calc_p_Q: forks until the kernel refuses (EAGAIN), on and off for SECONDS."""

BUSY_CHILDREN = r"""
import json, os, time
children = []
for _ in range(CHILDREN):
    pid = os.fork()
    if pid == 0:
        while True:
            pass
    children.append(pid)
time.sleep(SECONDS)
print("EVIDENCE busy " + json.dumps({"children": len(children)}))
raise NotImplementedError("calc_p_Q: busy children")
"""
"""calc_p_Q: CHILDREN processes that spin until the test ends, for SECONDS."""


@pytest.fixture(scope="module")
def reference() -> dict:
    return pset_fixtures.reference()


def _class(root: Path, honest: int, attacker: tuple[str, dict]) -> Path:
    """``honest`` copies of the answer key and one attacker (stubs, calc_p_Q replaced)."""
    export = root / "export"
    export.mkdir(parents=True)
    key = init_folder(root / "key", solutions=True)
    for i in range(honest):
        shutil.copytree(key, export / f"honest_{i}")
    folder = init_folder(export / "attacker")
    code, values = attacker
    _insert(folder, "calc_p_Q", code, values)
    subprocess.run(["chmod", "-R", "a+rX", str(root)], check=True)
    return export


def _rows(out: Path) -> dict[str, dict]:
    import csv

    with open(out / GRADES_CSV, newline="") as f:
        return {row["submission"]: row for row in csv.DictReader(f)}


@needs_cgroups
@pytest.mark.slow
def test_six_honest_submissions_beside_a_fork_cycler_keep_full_marks(tmp_path, reference):
    """The fork cycler hits its own view's limit (EAGAIN) again and again while 6 honest
    submissions are graded on the other worker: every one of them 14 and graded."""
    export = _class(tmp_path, 6, (FORK_CYCLER, {"SECONDS": 45}))
    out = tmp_path / "out"
    outcome = grade_class(export, out, reference=reference, jobs=2)
    rows = _rows(out)
    for i in range(6):
        row = rows[f"honest_{i}"]
        assert (row["status"], float(row["total"])) == ("graded", FULL), row
    assert rows["attacker"]["status"] == "graded", rows["attacker"]
    results = json.loads((out / "attacker" / RESULTS_JSON).read_text())
    forks = evidence(results)["forks"]
    assert forks["eagain"] >= 10 and forks["rounds"] >= 10, forks
    # Its own view's limit, not the machine's: at most pids.max less the view's own tasks.
    assert 50 <= forks["most"] <= cgroups.VIEW_TASKS, forks
    assert results["extra_data"]["sandbox"]["cgroup"]["version"] == SETUP.version
    assert outcome.errors == 0
