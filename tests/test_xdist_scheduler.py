"""The suite's xdist scheduler survives a worker that dies (tests/xdist_scheduler.py; issue 45:
a worker killed by a segmentation fault ended the run in a KeyError, or a hang, and lost the
other workers' results)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent

CONFTEST = """
    import pytest

    @pytest.hookimpl(tryfirst=True)
    def pytest_xdist_make_scheduler(config, log):
        from xdist_scheduler import RealtimeBins
        return RealtimeBins(config, log, lambda workers: {"test_rt.py": "realtime-1"})
"""
ORDINARY = """
    import time

    def test_one(): time.sleep(0.05)
    def test_two(): time.sleep(0.05)
    def test_three(): time.sleep(0.05)
"""
CRASH = """
    import os, signal

    def test_before(): pass
    def test_crash(): os.kill(os.getpid(), signal.SIGKILL)  # as a segfault does, at once
    def test_after(): pass
"""


@pytest.mark.slow
def test_a_dead_worker_is_reported_and_the_others_results_kept(tmp_path):
    """Two workers, five files, one test that kills its worker: that test fails once as the
    crash (it is not run again, which would kill the next worker), every other test passes,
    the crashed file's last test included, and the run ends (xdist's own loadfile scheduler
    hangs here)."""
    (tmp_path / "conftest.py").write_text(textwrap.dedent(CONFTEST))
    for name in ("test_a.py", "test_b.py", "test_c.py", "test_rt.py"):
        (tmp_path / name).write_text(textwrap.dedent(ORDINARY))
    (tmp_path / "test_crash.py").write_text(textwrap.dedent(CRASH))
    argv = [sys.executable, "-m", "pytest", "-p", "xdist.plugin", "-n", "2", "--dist", "loadfile"]
    argv += ["-rA", "-p", "no:cacheprovider", "-p", "no:faulthandler"]
    # xdist alone: four interpreters start (two workers, a replacement), each quicker so.
    env = {**os.environ, "PYTHONPATH": str(TESTS), "PYTEST_DISABLE_PLUGIN_AUTOLOAD": "1"}
    proc = subprocess.run(
        argv,
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=240,
    )
    out = proc.stdout
    assert proc.returncode == 1, out[-3000:]
    assert "1 failed, 14 passed" in out, out[-3000:]
    assert out.count("crashed while running 'test_crash.py::test_crash'") >= 1
    assert "PASSED test_crash.py::test_after" in out
    assert "KeyError" not in out + proc.stderr
