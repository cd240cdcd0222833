"""What the grader's channel costs: the student's plan asked across a process boundary, per
control tick and per episode, side by side with the same plan called in the grader's process.

    python benchmarks/pset_channel.py [--repeats N] [--ticks N] [--out FILE.json]

Per tick (``--ticks`` ticks at states near the arc, the solutions' velocity plan):

- ``local``: the plan called in this process through ``ProblemSetPlanAdapter`` (what the student's
  process did when it also ran the simulation, before issue 17);
- ``remote``: the same plan in a sandboxed student process, through
  ``doorlab.pset.grading.episodes.RemotePlan`` (one round trip of ``doorlab.pset.isolation.channel``
  per tick: 30 floats out, 14 back, validated);
- ``remote_trivial``: a plan that answers at once (q_ref = q, tau_ff = 0): the channel alone.

Per episode (task 2's episode, doors open, as graded): ``local`` runs it in this process
through ``station_api.StationRun`` (the pre-issue-17 student episode), ``remote`` through
``doorlab.pset.grading.episodes.student_episode`` (the simulation here, the plan in the student's
process). Wall times and CPU times (``cpu``: this process plus the student's process);
medians of the repeats, run alternately. ``other cpu``: the average number of cores other
processes used meanwhile (the machine is shared).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # no thread when the student's process forks

import argparse  # noqa: E402
import importlib  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from common import cpu_times


def _process_cpu(pid: int) -> float:
    """User + system CPU of a process [s] (from /proc/PID/stat)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (float(fields[11]) + float(fields[12])) / os.sysconf("SC_CLK_TCK")


def _states(n: int, seed: int = 0) -> list[tuple[float, np.ndarray, np.ndarray, np.ndarray]]:
    from doorlab.constants import Q_HOME

    rng = np.random.default_rng(seed)
    return [
        (0.005 * k, Q_HOME + rng.uniform(-0.05, 0.05, 7), rng.uniform(-0.1, 0.1, 7), np.zeros(7))
        for k in range(n)
    ]


def _trivial_folder(solutions: Path, root: Path) -> Path:
    """The solutions with a velocity plan that answers at once (the channel alone)."""
    import shutil

    folder = root / "trivial"
    shutil.copytree(solutions, folder)
    path = folder / "manip_station_sim" / "robot_plans.py"
    text = path.read_text()
    body = "        if t_plan >= self.duration:\n            return self.q_iiwa_previous"
    start = text.index(body)
    end = text.index("class Iiwa", start)
    path.write_text(text[:start] + "        return q_iiwa\n\n\n" + text[end:])
    return folder


def _student(folder: Path, root: Path, name: str):
    from doorlab.pset.isolation import sandbox
    from doorlab.pset.isolation.handle import StudentProcess

    work = root / name
    work.mkdir()
    os.chmod(work, 0o711)
    return StudentProcess(folder, work, name, 600.0, sandbox.sandbox_identity())


def _remote_ticks(folder: Path, root: Path, name: str, states) -> tuple[float, float]:
    """(wall, cpu) [s] of the ticks through the channel (cpu: both processes)."""
    from doorlab.cell.frames import p_L7Q
    from doorlab.constants import Q_HOME
    from doorlab.control.plans import ArmState
    from doorlab.pset.grading.episodes import RemotePlan

    with _student(folder, root, name) as student:
        q = Q_HOME.tolist()
        student.call("plan", kind="velocity", duration=10.0, p_L7Q=p_L7Q.tolist(), q_start=q)
        plan = RemotePlan(student, 10.0, 0.005, name="remote")
        cpu0, theirs0, t0 = time.process_time(), _process_cpu(student.proc.pid), time.perf_counter()
        for t, q, v, tau in states:
            plan.command(t, ArmState(q, v, tau))
        wall = time.perf_counter() - t0
        cpu = time.process_time() - cpu0 + _process_cpu(student.proc.pid) - theirs0
    return wall, cpu


def _local_ticks(plans_module, states) -> tuple[float, float]:
    from doorlab.cell.frames import p_L7Q
    from doorlab.control.plans import ArmState
    from doorlab.pset.handout.station_api import ProblemSetPlanAdapter

    old = importlib.import_module("open_left_door")
    plan = plans_module.IiwaTaskSpaceVelocityPlan(
        calc_p_Q=old.calc_p_Q, calc_R_WL7_ref=old.calc_R_WL7_ref, duration=10.0, p_L7Q=p_L7Q
    )
    plan = ProblemSetPlanAdapter(plan, 0.005)
    cpu0, t0 = time.process_time(), time.perf_counter()
    for t, q, v, tau in states:
        plan.command(t, ArmState(q, v, tau))
    return time.perf_counter() - t0, time.process_time() - cpu0


def _local_episode(plans_module) -> tuple[float, float]:
    """The pre-issue-17 student episode: the problem set's task cell, plan and simulation here."""
    from pydrake.trajectories import PiecewisePolynomial

    from doorlab.constants import Q_HOME
    from doorlab.pset.grading.episodes import DOOR_OPEN, grasp_configuration
    from doorlab.pset.handout.station_api import StationRun

    old = importlib.import_module("open_left_door")
    cpu0, t0 = time.process_time(), time.perf_counter()
    q_start = grasp_configuration()
    plan = plans_module.IiwaTaskSpaceVelocityPlan(
        calc_p_Q=old.calc_p_Q, calc_R_WL7_ref=old.calc_R_WL7_ref, duration=10.0, p_L7Q=old.p_L7Q
    )
    hold = plans_module.JointSpacePlan(
        PiecewisePolynomial.ZeroOrderHold([0, 1], np.column_stack([q_start, q_start]))
    )
    StationRun().run(
        Q_HOME,
        [-DOOR_OPEN, DOOR_OPEN],
        [hold, plan],
        [0.005, 0.005],
        extra_time=2.0,
        real_time_rate=0.0,
        meshcat=None,
        gripper_setpoint_initial=0.025,
    )
    return time.perf_counter() - t0, time.process_time() - cpu0


def _remote_episode(folder: Path, root: Path, name: str) -> tuple[float, float, int]:
    from doorlab.pset.grading import episodes

    ticks = []
    original = episodes.RemotePlan.command

    def counted(self, t, state):
        ticks.append(1)
        return original(self, t, state)

    episodes.RemotePlan.command = counted
    try:
        with _student(folder, root, name) as student:
            pid = student.proc.pid
            cpu0, theirs0, t0 = time.process_time(), _process_cpu(pid), time.perf_counter()
            episodes.student_episode(student, "velocity")
            wall = time.perf_counter() - t0
            cpu = time.process_time() - cpu0 + _process_cpu(pid) - theirs0
    finally:
        episodes.RemotePlan.command = original
    return wall, cpu, len(ticks)


def _median(xs: list[float]) -> float:
    return statistics.median(xs)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="repeats (default 3)")
    parser.add_argument("--ticks", type=int, default=2000, help="ticks per repeat (default 2000)")
    parser.add_argument("--out", type=Path, default=None, help="write the figures as JSON")
    args = parser.parse_args(argv)
    from doorlab.pset.handout.folder import init_folder

    root = Path(tempfile.mkdtemp(prefix="doorlab_channel_bench_"))
    os.chmod(root, 0o711)
    solutions = init_folder(root / "solutions", solutions=True)
    trivial = _trivial_folder(solutions, root)
    sys.path.insert(0, str(solutions))
    plans_module = importlib.import_module("manip_station_sim.robot_plans")
    states = _states(args.ticks)
    runs: dict[str, list] = {k: [] for k in ("local", "remote", "remote_trivial")}
    episodes: dict[str, list] = {"local": [], "remote": []}
    ticks_per_episode = 0
    busy0, total0 = cpu_times()
    self0 = os.times()
    for r in range(args.repeats):
        runs["local"].append(_local_ticks(plans_module, states))
        runs["remote"].append(_remote_ticks(solutions, root, f"t{r}", states))
        runs["remote_trivial"].append(_remote_ticks(trivial, root, f"z{r}", states))
        episodes["local"].append(_local_episode(plans_module))
        wall, cpu, ticks_per_episode = _remote_episode(solutions, root, f"e{r}")
        episodes["remote"].append((wall, cpu))
    busy1, total1 = cpu_times()
    self1 = os.times()
    ticks = os.sysconf("SC_CLK_TCK")
    cores = os.cpu_count() or 1
    elapsed = (total1 - total0) / ticks / cores
    ours = sum(self1[:4]) - sum(self0[:4])
    other_cpu = max(0.0, ((busy1 - busy0) / ticks - ours) / max(elapsed, 1e-9))
    n = args.ticks
    per_tick = {
        k: {
            "wall_us": _median([w for w, _ in v]) / n * 1e6,
            "cpu_us": _median([c for _, c in v]) / n * 1e6,
        }
        for k, v in runs.items()
    }
    per_episode = {
        k: {"wall_s": _median([w for w, _ in v]), "cpu_s": _median([c for _, c in v])}
        for k, v in episodes.items()
    }
    added_wall = per_tick["remote"]["wall_us"] - per_tick["local"]["wall_us"]
    print(f"the grader's channel, {args.repeats} repeats, {n} ticks each, {cores} cores")
    for k, v in per_tick.items():
        print(f"  tick {k:15s} wall {v['wall_us']:7.1f} us   cpu {v['cpu_us']:7.1f} us")
    print(f"  channel's added wall per tick: {added_wall:.1f} us")
    for k, v in per_episode.items():
        print(f"  episode {k:12s} wall {v['wall_s']:6.2f} s   cpu {v['cpu_s']:6.2f} s")
    ratio = per_episode["remote"]["wall_s"] / per_episode["local"]["wall_s"]
    print(
        f"  episode remote/local wall {ratio:.2f} ({ticks_per_episode} ticks through the "
        f"channel; at {added_wall:.0f} us each: {added_wall * ticks_per_episode / 1e6:.2f} s)"
    )
    print(f"  other cpu       {other_cpu:.2f} cores")
    if args.out:
        figures = {
            "per_tick": per_tick,
            "per_episode": per_episode,
            "ticks_per_episode": ticks_per_episode,
            "added_wall_us_per_tick": added_wall,
            "episode_wall_ratio": ratio,
            "repeats": args.repeats,
            "ticks": n,
            "other_cpu": other_cpu,
            "samples": {"ticks": runs, "episodes": episodes},
        }
        args.out.write_text(json.dumps(figures, indent=2) + "\n")
    return 0 if math.isfinite(ratio) else 1


if __name__ == "__main__":
    sys.exit(main())
