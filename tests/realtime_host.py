"""Telling a loaded host from a defect in the real-time tests.

A real-time section (LCM processes paced to the wall clock, ``with alone():``) needs the CPU
when it asks for it; the ``alone`` fixture keeps the suite's other workers out, but not the
machine's other users. :class:`HostWatch` measures what they took during the section: the
machine's busy CPU time (``/proc/stat``) minus that of this test process and the children it
waited for (the driver, the client), as an average number of cores. A timing assertion
inside ``with host.excuse(what):`` that fails on a host whose other processes used
:data:`LOADED_CORES` or more skips the test with that measurement and the failed figure (the
driver's rate, the statuses missed, the client's watchdog): the host could not keep real
time. On a host that was not loaded it fails: a defect of the product.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

import pytest

LOADED_CORES = 0.25
"""Other processes' average use [cores] from which a missed timing is put down to the host:
the driver takes ~0.33 of a core and the client about as much; benchmarks/README.md calls
timings above 0.25 cores of other use noisy."""


def _machine_busy_s() -> float:
    fields = [float(x) for x in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    return (sum(fields) - fields[3] - fields[4]) / os.sysconf("SC_CLK_TCK")


def _own_s() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


class HostWatch:
    """Measures the other processes' CPU use from its creation to :meth:`stop` (or to the
    first :meth:`excuse`)."""

    def __init__(self) -> None:
        self._busy0, self._own0, self._wall0 = _machine_busy_s(), _own_s(), os.times().elapsed
        self.other_cores: float | None = None

    def stop(self) -> float:
        """Ends the measurement (once); returns the other processes' average cores."""
        if self.other_cores is None:
            wall = max(os.times().elapsed - self._wall0, 1e-6)
            other = (_machine_busy_s() - self._busy0) - (_own_s() - self._own0)
            self.other_cores = max(0.0, other / wall)
        return self.other_cores

    def describe(self) -> str:
        cores = os.cpu_count() or 1
        return (
            f"other processes used {self.stop():.2f} of the host's {cores} cores during the "
            "real-time section"
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
            if self.stop() < LOADED_CORES and not explained:
                raise
            shown = str(e).strip().splitlines()[0][:300] if str(e).strip() else repr(e)
            why = f"; {explained}" if explained else ""
            pytest.skip(
                f"the host could not keep real time ({self.describe()}, {LOADED_CORES} or "
                f"more counts as loaded{why}): {what}: {shown}"
            )


@contextlib.contextmanager
def host_watch() -> Iterator[HostWatch]:
    """``with alone(), host_watch() as host, <processes>:``: a :class:`HostWatch` over the
    section (started before its processes, stopped after they were waited for)."""
    host = HostWatch()
    try:
        yield host
    finally:
        host.stop()
