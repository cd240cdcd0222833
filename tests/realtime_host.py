"""Telling a loaded host from a defect in the real-time tests.

A real-time section (LCM processes paced to the wall clock, ``with realtime():``) needs the
CPU when it asks for it: its processes have real-time priority where they can
(tests/realtime_priority.py), else the ``realtime`` fixture keeps the suite's ordinary tests
out (tests/run_lock.py). What the suite runs beside a section is the suite's own choice, not
the host's load; the machine's other users are. :class:`HostWatch` measures what they took
during the section: the machine's busy CPU time (``/proc/stat``) minus that of this test
process and the children it waited for (the driver, the client) and minus the suite's other
workers and their processes (:func:`suite_workers_s`), as an average number of cores. A
timing assertion inside ``with host.excuse(what):`` that fails on a host whose other
processes used :data:`LOADED_CORES` or more skips the test with that measurement and the
failed figure (the driver's rate, the statuses missed, the client's watchdog): the host could
not keep real time. On a host that was not loaded it fails: a defect of the product.

A host can also stop every process at once for tens of milliseconds (a virtual machine's
pause, a kernel stall) while its average load stays low. :class:`StallProbe` measures that as
cyclictest does: a process at the paced processes' priority wakes every 2 ms and keeps its
latest wake-up. A wake-up :data:`STALL_S` or more late explains a missed timing whatever the
load.
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TypeVar

import pytest
import realtime_priority

T = TypeVar("T")

LOADED_CORES = 0.25
"""Other processes' average use [cores] from which a missed timing is put down to the host:
the driver takes ~0.33 of a core and the client about as much; benchmarks/README.md calls
timings above 0.25 cores of other use noisy."""


STALL_S = 0.040
"""A wake-up of :class:`StallProbe` this late [s] or later: the host stopped the section's
processes. The client's watchdog stops commanding after 50 ms without a status (10 periods of
5 ms), so a driver stopped for 45 ms trips it: 40 ms leaves the probe's own period (2 ms) and a
few milliseconds of phase. Such a process woke at most 4 ms late here beside three CPU
burners."""

_PROBE = r"""
import json, select, sys, time
period, worst = 0.002, 0.0
due = time.monotonic() + period
while not select.select([sys.stdin], [], [], max(0.0, due - time.monotonic()))[0]:
    now = time.monotonic()
    worst = max(worst, now - due)
    due = now + period
print(json.dumps({"worst_s": worst}))
"""


class StallProbe:
    """The latest wake-up of a process that sleeps 2 ms at a time, at the paced processes'
    real-time priority where it can be had (cyclictest's measure), from its creation to
    :meth:`stop`. It costs about two hundredths of a core (0.18 CPU-s in 10 s here)."""

    def __init__(self) -> None:
        self._proc = subprocess.Popen(
            [sys.executable, "-I", "-c", _PROBE],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            preexec_fn=realtime_priority.preexec(),
        )
        self.worst_s: float | None = None

    def stop(self) -> float:
        """Ends the probe (once); returns its latest wake-up [s] (0 if it could not say)."""
        if self.worst_s is None:
            try:
                out, _ = self._proc.communicate(input="", timeout=10)  # EOF ends its loop
                self.worst_s = float(json.loads(out)["worst_s"])
            except (OSError, ValueError, KeyError, subprocess.TimeoutExpired):
                self._proc.kill()
                self._proc.wait()
                self.worst_s = 0.0
        return self.worst_s


def _machine_busy_s() -> float:
    fields = [float(x) for x in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    return (sum(fields) - fields[3] - fields[4]) / os.sysconf("SC_CLK_TCK")


def _own_s() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def _process_table() -> dict[int, tuple[int, float]]:
    """{pid: (parent pid, CPU time of the process and of its children it waited for [s])}."""
    tick = os.sysconf("SC_CLK_TCK")
    table = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            text = (entry / "stat").read_text()
        except OSError:
            continue
        fields = text[text.rindex(")") + 2 :].split()  # after the command's name
        # fields[1] is the ppid; utime, stime, cutime, cstime are fields[11:15]
        table[int(entry.name)] = (int(fields[1]), sum(float(x) for x in fields[11:15]) / tick)
    return table


def suite_root() -> int | None:
    """The pytest-xdist controller (every worker's parent), under xdist; else None."""
    return os.getppid() if os.environ.get("PYTEST_XDIST_WORKER") else None


def suite_workers_s(root: int | None = None) -> float:
    """The CPU time [s] used so far by ``root`` (default :func:`suite_root`) and every process
    under it but this one and its own: the suite's other workers and what they run beside a
    real-time section (other sections, or ordinary tests where the paced processes have
    real-time priority). A process's time stays counted when it ends (its parent's
    children's time takes it over)."""
    root = suite_root() if root is None else root
    if root is None:
        return 0.0
    table = _process_table()
    children: dict[int, list[int]] = {}
    for pid, (ppid, _) in table.items():
        children.setdefault(ppid, []).append(pid)
    total, todo = 0.0, [root] if root in table else []
    while todo:
        pid = todo.pop()
        if pid == os.getpid():  # this test's own: counted by _own_s
            continue
        total += table[pid][1]
        todo += children.get(pid, [])
    return total


class HostWatch:
    """Measures the other processes' CPU use from its creation to :meth:`stop` (or to the
    first :meth:`excuse`)."""

    def __init__(self, suite: int | None = None, probe: StallProbe | None = None) -> None:
        """``suite``: the process whose tree is the suite's (default :func:`suite_root`);
        ``probe``: a :class:`StallProbe` over the same section, stopped with the watch."""
        self._busy0, self._own0, self._wall0 = _machine_busy_s(), _own_s(), os.times().elapsed
        self._suite = suite
        self._suite0 = suite_workers_s(suite)
        self._probe = probe
        self.other_cores: float | None = None

    def stall_s(self) -> float:
        """The probe's latest wake-up in the section [s] (0 without a probe)."""
        return 0.0 if self._probe is None else self._probe.stop()

    def stop(self) -> float:
        """Ends the measurement (once); returns the other processes' average cores."""
        self.stall_s()
        if self.other_cores is None:
            wall = max(os.times().elapsed - self._wall0, 1e-6)
            other = (_machine_busy_s() - self._busy0) - (_own_s() - self._own0)
            other -= suite_workers_s(self._suite) - self._suite0
            self.other_cores = max(0.0, other / wall)
        return self.other_cores

    def explains(self) -> bool:
        """Whether the host explains a missed timing: its other processes used
        :data:`LOADED_CORES` or more, or it stopped the section's processes (:data:`STALL_S`)."""
        return self.stop() >= LOADED_CORES or self.stall_s() >= STALL_S

    def describe(self) -> str:
        cores = os.cpu_count() or 1
        stall = f", a real-time process woke at most {1e3 * self.stall_s():.1f} ms late"
        return (
            f"other processes used {self.stop():.2f} of the host's {cores} cores during the "
            f"real-time section{stall if self._probe is not None else ''}"
        )

    @contextlib.contextmanager
    def excuse(self, what: str, explained: str = "") -> Iterator[None]:
        """A timing assertion: on a loaded host its failure skips the test, saying why.

        ``explained``: what the run itself measured that puts it down to the host whatever
        the other processes' use (as test_hardware_two_process.py's ``host_explains``: the
        host dropped a stale answer, the driver fell behind real time); empty: nothing."""
        try:
            yield
        except AssertionError as e:
            if self.stall_s() >= STALL_S:
                stalled = f"a real-time process woke {1e3 * self.stall_s():.0f} ms late"
                explained = f"{explained}, {stalled}" if explained else stalled
            if not explained and not self.explains():
                raise
            shown = str(e).strip().splitlines()[0][:300] if str(e).strip() else repr(e)
            why = f"; {explained}" if explained else ""
            pytest.skip(
                f"the host could not keep real time ({self.describe()}, {LOADED_CORES} or "
                f"more counts as loaded{why}): {what}: {shown}"
            )


@contextlib.contextmanager
def host_watch() -> Iterator[HostWatch]:
    """``with realtime(), host_watch() as host, <processes>:``: a :class:`HostWatch` over the
    section (started before its processes, stopped after they were waited for), with a
    :class:`StallProbe`."""
    host = HostWatch(probe=StallProbe())
    try:
        yield host
    finally:
        host.stop()


WATCHDOG = "no fresh status for"
"""The client's line when its watchdog stopped commanding (``doorlab run --hardware``,
``doorlab identify``: statuses stopped coming)."""


@contextlib.contextmanager
def watchdog_excused(host: HostWatch, what: str) -> Iterator[None]:
    """A page's real-time commands (tests/doc_commands.py): a command that ended on the
    client's watchdog (:data:`WATCHDOG` in its output) skips the test where ``host`` puts it
    down to the host (:meth:`HostWatch.excuse`); any other failure is the test's."""
    try:
        yield
    except AssertionError as e:
        if WATCHDOG not in str(e):
            raise
        with host.excuse(what):
            raise


def page_in_real_time(
    realtime: Callable, run: Callable[[Path], T], folders: Sequence[Path], what: str
) -> T:
    """``run(folder)``, a page's blocks that hold real-time commands, in a real-time section
    (the ``realtime`` fixture's) under :func:`host_watch`. A command that ended on the
    client's watchdog where the host explains it (:meth:`HostWatch.explains`: a loaded host,
    or one that stopped the section's processes) runs the page once more in the next folder,
    saying so on stdout; in the last folder that skips the test (:func:`watchdog_excused`).
    Any other failure is the test's. Returns what ``run`` returned."""
    for i, folder in enumerate(folders):
        with realtime(), host_watch() as host:
            try:
                return run(folder)
            except AssertionError as e:
                if WATCHDOG not in str(e) or not host.explains() or i == len(folders) - 1:
                    with watchdog_excused(host, what):
                        raise
                print(f"{what} ({host.describe()}): the page once more, in {folders[i + 1]}")
    raise ValueError("page_in_real_time needs at least one folder")
