"""tests/warm_up.py: the background process that computes the notebook's shared run."""

from __future__ import annotations

import os
import sys
import time
import types

import pset_fixtures
import pytest
import warm_up


class _Item:
    def __init__(self, module) -> None:
        self.module = module


def test_wanted_only_with_the_notebook_and_a_problem_set_test(monkeypatch, tmp_path):
    grading = types.ModuleType("test_grading")
    grading.pset_fixtures = pset_fixtures
    other = types.ModuleType("test_other")
    monkeypatch.setenv(pset_fixtures.NOTEBOOK_ENV, str(tmp_path / "notebook.txt"))
    assert warm_up.wanted([_Item(other), _Item(grading)])
    assert not warm_up.wanted([_Item(other), _Item(None)])
    monkeypatch.delenv(pset_fixtures.NOTEBOOK_ENV)
    assert not warm_up.wanted([_Item(grading)])


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_it_runs_niced_in_its_own_group_and_an_interrupted_session_ends_it_all(
    monkeypatch, tmp_path
):
    """The process and the one it starts (as the notebook's run starts its cells' process)
    run at the workers' niceness + NICE, in a process group of their own; finish(...,
    interrupted=True) leaves neither."""
    child = tmp_path / "child.pid"
    script = (
        "import os, subprocess, sys, time\n"
        "p = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)'])\n"
        f"open({str(child)!r}, 'w').write(str(p.pid))\n"
        "time.sleep(60)\n"
    )
    monkeypatch.setattr(warm_up, "SCRIPT", script)
    process = warm_up.start(tmp_path)
    deadline = time.monotonic() + 30
    while not child.is_file() or not child.read_text():
        assert time.monotonic() < deadline and process.poll() is None
        time.sleep(0.05)
    grandchild = int(child.read_text())
    assert os.getpgid(process.pid) == process.pid == os.getpgid(grandchild)
    assert os.getpriority(os.PRIO_PROCESS, process.pid) == min(
        19, os.getpriority(os.PRIO_PROCESS, 0) + warm_up.NICE
    )
    began = time.monotonic()
    warm_up.finish(process, interrupted=True)
    assert time.monotonic() - began < 10  # SIGTERM ends both: no wait for the kill
    assert process.returncode is not None
    deadline = time.monotonic() + 5
    while _alive(grandchild) and time.monotonic() < deadline:  # reaped by init meanwhile
        time.sleep(0.05)
    assert not _alive(grandchild)


def test_an_uninterrupted_session_waits_for_its_result(monkeypatch, tmp_path):
    monkeypatch.setattr(warm_up, "SCRIPT", "import time; time.sleep(0.5); print('done')")
    process = warm_up.start(tmp_path)
    warm_up.finish(process, interrupted=False)
    assert process.returncode == 0
    assert (tmp_path / warm_up.LOG).read_text().strip() == "done"
