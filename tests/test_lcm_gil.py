"""No Python LCM handler runs inside ``Simulator.AdvanceTo`` (issue 45: ``run --hardware``'s
segmentation fault on Python >= 3.12).

The cause is pydrake's: ``Simulator.AdvanceTo`` releases the GIL, and ``DrakeLcm.Subscribe``'s
C++ callback builds the handler's ``bytes`` before it takes the GIL back. When an
``LcmInterfaceSystem`` reads a bus inside ``AdvanceTo``, a Python handler of that bus is called
there: Python 3.12 dereferences the missing thread state in its allocator (SIGSEGV); 3.11 does
the same work without the GIL, a silent race. Under ``python -X dev`` (the debug allocator,
which checks that the GIL is held) every Python from 3.10 on stops at once with "Python
memory allocator called without holding the GIL", so these tests fail without the fix on the
machine's Python 3.11 too. They run each case in a child process (a crash fails the test, not
the worker) under ``-X dev``:

- the client of ``run --hardware`` (``DriverLink`` and the hardware cell on one ``DrakeLcm``)
  against the in-process stand-in driver, with a status left on the bus while the client
  computes (tests/fake_driver.py's ``late_copy``: the race over UDP, made deterministic);
- ``SimDriver`` on memq:// with a client of Python handlers in the same process;
- pydrake itself (the minimal reproduction): it fails while Drake has the defect, and says
  so when a release fixes it (then the ways around it can be reconsidered).
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent
GIL_ERROR = "Python memory allocator called without holding the GIL"

CLIENT = """
    import numpy as np
    from fake_driver import FakeDriver
    from doorlab.config import Scenario, validate
    from doorlab.constants import Q_HOME
    from doorlab.episode.controllers import episode_plans
    from doorlab.hardware.episode import run_hardware_episode
    from doorlab.hardware.link import DriverLink

    scenario = Scenario(controller="velocity", doors="closed")
    t = scenario.timeline
    t.hold_duration, t.approach_duration, t.grasp_duration = 0.2, 1.0, 0.2
    t.arc_duration, t.extra_time = 3.0, 0.2  # test_hardware_client's short episode
    scenario = validate(scenario)
    driver = FakeDriver(Q_HOME + np.array([0.1, 0.1, 0, 0.2, 0, 0, 0]), late_copy=True)
    link = DriverLink(driver.lcm, clock=driver.clock, pump=driver.pump)
    link.wait_first_status(1.0)
    plans, widths, arc = episode_plans(scenario)
    outcome = run_hardware_episode(
        scenario, plans, widths, q_start=arc.q_start, link=link, wait=1.0
    )
    print("status", outcome.status, "commands", len(driver.commands), "copies", driver.sent)
"""

SIM_DRIVER = """
    from drake import lcmt_iiwa_command, lcmt_iiwa_status
    from doorlab.config import Scenario
    from doorlab.constants import Q_HOME
    from doorlab.hardware.sim_driver import SimDriver

    driver = SimDriver(Scenario(), lcm_url="memq://")
    answered = []

    def answer(data: bytes) -> None:  # a client in this process: answers every status
        status = lcmt_iiwa_status.decode(data)
        if status.utime >= 300_000:
            message = lcmt_iiwa_command()
            message.utime, message.num_joints = status.utime, 7
            message.joint_position = list(Q_HOME)
            driver.lcm.Publish("IIWA_COMMAND", message.encode())
            answered.append(status.utime)

    driver.lcm.Subscribe("IIWA_STATUS", answer)
    outcome = driver.run(duration=0.5, realtime_rate=0.0)
    print("status", outcome.status, "answered", len(answered))
"""

PYDRAKE = """
    from pydrake.lcm import DrakeLcm
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.lcm import LcmInterfaceSystem

    lcm = DrakeLcm("memq://")
    received = []
    lcm.Subscribe("CHANNEL", received.append)
    builder = DiagramBuilder()
    builder.AddSystem(LcmInterfaceSystem(lcm))
    simulator = Simulator(builder.Build())
    lcm.Publish("CHANNEL", b"hello")
    simulator.AdvanceTo(0.1)  # the interface system calls the handler in here
    print("received", received)
"""


def run_dev(script: str, tmp_path: Path) -> subprocess.CompletedProcess:
    """``script`` in a child ``python -X dev`` (the GIL-checking allocator), tests/ on its
    path, in ``tmp_path``."""
    return subprocess.run(
        [sys.executable, "-X", "dev", "-W", "ignore", "-c", textwrap.dedent(script)],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(TESTS)},
        capture_output=True,
        text=True,
        timeout=300,
    )


def _explain(proc: subprocess.CompletedProcess) -> str:
    return f"exit {proc.returncode}; stderr: {proc.stderr[-1500:]}"


@pytest.mark.slow
def test_the_hardware_client_runs_no_handler_inside_advance_to(tmp_path):
    """The episode reads the bus only through its link: the late copies of statuses wait for
    the link's next read (and are skipped as repeats) instead of reaching its handler from
    inside the simulator; the episode ends as it does without them."""
    proc = run_dev(CLIENT, tmp_path)
    assert proc.returncode == 0, _explain(proc)
    words = proc.stdout.split()
    assert words[:2] == ["status", "ok"], proc.stdout
    assert int(words[3]) > 1000  # a command per status: over 6 s of statuses every 5 ms


def test_an_in_process_client_of_the_simulated_driver_runs_with_the_gil(tmp_path):
    """SimDriver on memq:// reads its bus from Python: the client's handler answers every
    status from 0.3 s to 0.5 s (40) and the run ends as asked."""
    proc = run_dev(SIM_DRIVER, tmp_path)
    assert proc.returncode == 0, _explain(proc)
    assert proc.stdout.split() == ["status", "stopped", "answered", "40"], proc.stdout


def test_pydrake_still_calls_lcm_handlers_without_the_gil(tmp_path):
    """The cause, in pydrake alone (seen on 1.51.1 and 1.58; in the source since 1.26): a
    Python handler called by an ``LcmInterfaceSystem`` inside ``AdvanceTo`` runs without the
    GIL. When this fails, a Drake release has fixed it: the notes in doorlab.hardware.link
    and sim_cell can say so."""
    proc = run_dev(PYDRAKE, tmp_path)
    assert proc.returncode != 0 and GIL_ERROR in proc.stderr, (
        "pydrake now calls LCM handlers inside AdvanceTo with the GIL held "
        f"(exit {proc.returncode}, {proc.stdout.strip()!r}): doorlab's way around it "
        "(issue 45) is no longer needed on this Drake"
    )
