"""tests/realtime_host.py: a real-time test skips with the host's measured load when a timing
fails on a loaded host, and fails when the host was not loaded."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import realtime_host
from realtime_host import (
    LOADED_CORES,
    STALL_S,
    HostWatch,
    StallProbe,
    page_in_real_time,
    watchdog_excused,
)


def _cpu_s(pid: int) -> float:
    """A process's CPU time so far [s] (/proc/PID/stat's utime and stime)."""
    text = Path(f"/proc/{pid}/stat").read_text()
    fields = text[text.rindex(")") + 2 :].split()
    return (float(fields[11]) + float(fields[12])) / os.sysconf("SC_CLK_TCK")


def test_a_missed_timing_is_excused_on_a_loaded_host_only():
    loaded, idle = HostWatch(), HostWatch()
    loaded.other_cores, idle.other_cores = LOADED_CORES + 0.5, 0.0
    with pytest.raises(pytest.skip.Exception) as skipped:
        with loaded.excuse("the driver's measured rate"):
            assert 191.0 == 200.0, "IIWA_STATUS at 191.0 Hz (200 +- 2 %)"
    text = str(skipped.value)
    assert "could not keep real time" in text and f"{LOADED_CORES + 0.5:.2f}" in text
    assert "the driver's measured rate: IIWA_STATUS at 191.0 Hz" in text
    with pytest.raises(AssertionError, match="191.0 Hz"):
        with idle.excuse("the driver's measured rate"):
            raise AssertionError("IIWA_STATUS at 191.0 Hz")


class _Stalled:
    """A probe that saw the host stop it for ``worst_s``."""

    def __init__(self, worst_s: float) -> None:
        self.worst_s = worst_s

    def stop(self) -> float:
        return self.worst_s


def test_a_stopped_probe_measures_the_stop():
    """The host stops the probe (SIGSTOP, as a paused machine stops every process) for 150
    ms: its latest wake-up is at least that late, less its 2 ms period; it cannot exceed the
    stop by much unless the host held it off longer still, so the upper bound (1 s) only says
    the figure is the stop's and not an accident of the probe."""
    probe = StallProbe()
    time.sleep(0.3)  # started: Python's start-up is not a late wake-up (its loop starts after)
    os.kill(probe._proc.pid, signal.SIGSTOP)
    time.sleep(0.15)
    os.kill(probe._proc.pid, signal.SIGCONT)
    time.sleep(0.05)
    assert 0.15 - 0.002 <= probe.stop() < 1.0, probe.stop()
    assert probe.stop() == probe.worst_s  # stopped once: the figure is kept


def test_a_stall_excuses_a_missed_timing_on_an_idle_host_and_only_the_watchdog_s():
    """A host that stopped the section's processes for STALL_S or more explains a missed
    timing whatever the load (the skip says how late); a shorter stall does not. A page's
    command that failed otherwise than on the client's watchdog is never the host's."""
    stalled, brief = HostWatch(probe=_Stalled(STALL_S + 0.02)), HostWatch(probe=_Stalled(0.01))
    stalled.other_cores = brief.other_cores = 0.0
    with pytest.raises(pytest.skip.Exception) as skipped:
        with watchdog_excused(stalled, "the rehearsal's client lost the driver"):
            raise AssertionError("driver_lost: no fresh status for 50 ms after t = 6.310 s")
    assert f"woke {1e3 * (STALL_S + 0.02):.0f} ms late" in str(skipped.value)
    with pytest.raises(AssertionError, match="no fresh status"):
        with watchdog_excused(brief, "the rehearsal's client lost the driver"):
            raise AssertionError("driver_lost: no fresh status for 50 ms after t = 6.310 s")
    with pytest.raises(AssertionError, match="exited 1"):
        with watchdog_excused(stalled, "the rehearsal's client lost the driver"):
            raise AssertionError("`doorlab identify --yes` exited 1 (the page expects 0)")


def test_a_page_the_host_stopped_runs_once_more_and_only_then(monkeypatch, tmp_path, capsys):
    """page_in_real_time: a command that ended on the client's watchdog in a section the host
    explains runs the page again in the next folder (and says so); a second such end skips; a
    failure of another kind, or one the host does not explain, is raised at once. (STALL_S is
    set to 0 here so that any wake-up counts as the host's stop: the probe's figure is checked
    by test_a_stopped_probe_measures_the_stop.)"""
    folders = [tmp_path / "first", tmp_path / "again"]
    lost = AssertionError("`doorlab run --hardware` exited 7: no fresh status for 50 ms")
    tried = []

    def run(folder, fail=(lost,)):
        tried.append(folder)
        if len(tried) <= len(fail):
            raise fail[len(tried) - 1]
        return folder

    def realtime():
        return contextlib.nullcontext()

    monkeypatch.setattr(realtime_host, "STALL_S", 0.0)
    assert page_in_real_time(realtime, run, folders, "the rehearsal") == tmp_path / "again"
    assert tried == folders and "the page once more, in" in capsys.readouterr().out
    tried.clear()
    with pytest.raises(pytest.skip.Exception, match="the rehearsal: `doorlab run --hardware`"):
        page_in_real_time(realtime, lambda f: run(f, (lost, lost)), folders, "the rehearsal")
    tried.clear()
    other = AssertionError("`doorlab identify --yes` exited 1")
    with pytest.raises(AssertionError, match="exited 1"):
        page_in_real_time(realtime, lambda f: run(f, (other,)), folders, "the rehearsal")
    assert tried == folders[:1]
    tried.clear()
    monkeypatch.setattr(realtime_host, "STALL_S", 10.0)  # no stop, and an idle host: a defect
    monkeypatch.setattr(realtime_host, "LOADED_CORES", 10.0)
    with pytest.raises(AssertionError, match="no fresh status"):
        page_in_real_time(realtime, run, folders, "the rehearsal")
    assert tried == folders[:1]


def _skip_if_starved(burned: float, tolerance: float) -> None:
    """The burning process's share of a core [cores] must exceed the check's ``tolerance``
    [cores] by 0.05 (the watch's sampling, 10 ms ticks over 1 s, with room), or the check could
    pass without seeing it: on a host so loaded that it did not (other processes on every
    core), the test skips and says what it measured."""
    if burned < tolerance + 0.05:
        pytest.skip(
            f"the burning process got {burned:.2f} of a core (other processes on this "
            f"host's cores): too little for the check of +-{tolerance} to see it"
        )


def test_another_process_s_cpu_counts_as_load():
    """A process this test does not wait for burns a core for a second: the watch sees at
    least what it used (a core, or its share of a loaded host's), measured from its /proc."""
    burner = subprocess.Popen(
        [sys.executable, "-c", "import time\nt = time.time()\nwhile time.time() < t + 3: pass"]
    )
    try:
        time.sleep(0.5)  # started and burning
        before, start = _cpu_s(burner.pid), time.monotonic()
        watch = HostWatch()
        time.sleep(1.0)
        other = watch.stop()
        burned = (_cpu_s(burner.pid) - before) / (time.monotonic() - start)
        _skip_if_starved(burned, 0.1)
        assert other >= burned - 0.1, (watch.describe(), burned)
    finally:
        burner.kill()
        burner.wait()


def test_the_suite_s_other_workers_do_not_count_as_load():
    """What the suite runs beside a real-time section (the other workers, under the xdist
    controller, and their processes) is not the host's load: two watches over the same
    second, one told that a process whose child burns a core is the suite's and one not,
    differ by what that child used meanwhile (whatever else the host runs)."""
    controller = subprocess.Popen(  # its child burns a core for 5 s
        [
            sys.executable,
            "-c",
            "import subprocess, sys\n"
            "subprocess.run([sys.executable, '-c', "
            "'import time\\nt = time.time()\\nwhile time.time() < t + 5: pass'])",
        ]
    )
    try:
        time.sleep(0.5)  # started and burning
        (child,) = (
            Path(f"/proc/{controller.pid}/task/{controller.pid}/children").read_text().split()
        )
        burned = _cpu_s(int(child))
        told, untold = HostWatch(suite=controller.pid), HostWatch(suite=os.getpid())
        start = time.monotonic()
        time.sleep(1.0)
        untold.stop()
        told.stop()
        burned = (_cpu_s(int(child)) - burned) / (time.monotonic() - start)
        difference = untold.other_cores - told.other_cores
        _skip_if_starved(burned, 0.15)
        assert abs(difference - burned) < 0.15, (difference, burned, told.describe())
    finally:
        controller.kill()  # its child ends by itself
        controller.wait()


def test_heavy_work_runs_at_idle_priority_and_hands_back_its_result():
    """conftest's ``heavy``: the call runs in a thread of the idle scheduling class (a
    real-time section's processes take the core from it at once), returns its value, raises
    its exception; the calling thread keeps its own class."""
    import os

    from conftest import run_at_idle_priority

    assert run_at_idle_priority(lambda: os.sched_getscheduler(0)) == os.SCHED_IDLE
    assert os.sched_getscheduler(0) == os.SCHED_OTHER
    with pytest.raises(ZeroDivisionError):
        run_at_idle_priority(lambda: 1 // 0)


def test_a_real_time_block_puts_every_thread_of_the_process_in_the_class_and_back():
    """tests/realtime_priority.py (as root): inside ``realtime_process`` every thread of this
    process (a waiting helper thread too) is SCHED_FIFO, after it each has its class back."""
    import threading

    import realtime_priority

    if realtime_priority.problem():
        pytest.skip(f"no real-time priority here: {realtime_priority.problem()}")
    ready, done = threading.Event(), threading.Event()
    tids: list[int] = []

    def helper() -> None:
        tids.append(threading.get_native_id())
        ready.set()
        done.wait(30)

    thread = threading.Thread(target=helper)
    thread.start()
    ready.wait(30)
    try:
        with realtime_priority.realtime_process():
            assert os.sched_getscheduler(0) == os.SCHED_FIFO
            assert os.sched_getscheduler(tids[0]) == os.SCHED_FIFO
        assert os.sched_getscheduler(0) == os.SCHED_OTHER
        assert os.sched_getscheduler(tids[0]) == os.SCHED_OTHER
    finally:
        done.set()
        thread.join()
