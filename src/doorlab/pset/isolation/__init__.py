"""The student's code contained, for the grader that runs it: what of a submission is taken,
the student's process with its limits, its view of the machine and its channel to the
trusted side, and what runs inside that process.

On the trusted side: :mod:`~doorlab.pset.isolation.intake` (the one intake: what of a
submission is graded), :mod:`~doorlab.pset.isolation.choice` (how a grading isolates, decided
once), :mod:`~doorlab.pset.isolation.bwrap_root` (the minimal root bubblewrap builds),
:mod:`~doorlab.pset.isolation.student_view` (a grading's view, whose first process forks a
student process per test), :mod:`~doorlab.pset.isolation.handle` (the handle on one student
process), :mod:`~doorlab.pset.isolation.sandbox`, :mod:`~doorlab.pset.isolation.cgroups` and
:mod:`~doorlab.pset.isolation.seccomp` (its limits, its cgroup, its system-call filter),
:mod:`~doorlab.pset.isolation.channel` (the framed messages and the checks of every answer)
and :mod:`~doorlab.pset.isolation.safe_text` (its text made safe). In the student's process:
:mod:`~doorlab.pset.isolation.zygote` (the view's first process),
:mod:`~doorlab.pset.isolation.worker` (runs the student's functions) and
:mod:`~doorlab.pset.isolation.guard` (the honesty guard).

Above :mod:`doorlab.pset.rules` (the time limits, what must stay hidden) and
:mod:`doorlab.pset.handout` (the worker runs the folder's files on the station API; the intake
writes a fresh folder); below grading, which it knows nothing of. Of doorlab: the
foundations, and in the worker what the folder's files import (the cell's frames and door
model, the one-shot IK), loaded before the student's code.
"""
