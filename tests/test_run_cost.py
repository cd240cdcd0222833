"""The CPU line at the end of a run (tests/run_cost.py): a waited-for child's CPU is counted."""

from __future__ import annotations

import os
import re
import sys

import run_cost

BURN_S = 0.5
"""CPU the child spends in a loop [s]."""

CHILD = f"""
import time
start = time.process_time()
while time.process_time() - start < {BURN_S}:
    pass
"""


def test_a_waited_for_child_s_cpu_is_counted():
    start = run_cost.mark()
    pid = os.posix_spawn(sys.executable, [sys.executable, "-c", CHILD], dict(os.environ))
    _, status, child = os.wait4(pid, 0)
    end = run_cost.mark()
    assert os.waitstatus_to_exitcode(status) == 0
    child_cpu = child.ru_utime + child.ru_stime
    # The kernel accounts CPU in clock ticks (1-10 ms), hence the 0.02 s.
    assert child_cpu >= BURN_S - 0.02, child_cpu  # the loop ran (the interpreter's start on top)
    used = run_cost.used(start, end)
    assert used >= child_cpu - 0.02, (used, child_cpu)  # the child's CPU is in the marks
    line = run_cost.summary(start, end, 2)
    figures = re.fullmatch(
        r"CPU: (\d+) CPU-s \(user (\d+), system (\d+)\) in (\d+) s on 2 cores: (\d+) % of (\d+) "
        r"core-s",
        line,
    )
    assert figures is not None, line
    assert int(figures[1]) == round(used)


def test_the_share_is_the_cpu_over_the_cores_time():
    start = run_cost.Mark(wall=100.0, user=10.0, system=1.0)
    end = run_cost.Mark(wall=700.0, user=1150.0, system=111.0)  # 600 s; 1250 CPU-s
    line = run_cost.summary(start, end, 2)
    assert line.startswith("CPU: 1250 CPU-s (user 1140, system 110) in 600 s on 2 cores")
    assert line.endswith("104 % of 1200 core-s")  # more than the cores could give
    assert len(line) < 90  # whole in a page's code block
