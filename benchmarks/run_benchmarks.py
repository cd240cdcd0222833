#!/usr/bin/env python3
"""doorlab benchmarks: one command, medians over repeats, saved as JSON, compared to a baseline.

Usage::

    python benchmarks/run_benchmarks.py [--repeats N] [--quick] [--out FILE.json]
                                        [--compare OLD.json] [--only NAME ...]

Benchmarks (``--only`` takes names, groups such as ``episode``, or globs such as
``episode/*_closed``):

``episode/<controller>_<doors>``
    One full 24 s episode, ``run_controller(Scenario(controller=..., doors=...))``, in this
    process: ``sim_s`` (``EpisodeResult.wall_time_s``, the simulation only), ``rtf`` (simulated
    time / ``sim_s``; target >= 20) and ``e2e_s`` (the whole call: plans, IK, diagram, logs).
``tick/velocity``, ``tick/impedance``
    Wall time of one ``plan.command(t, ArmState(q, v, tau))`` [us] at configurations along the
    arc, the plan built by ``doorlab.controllers.build_*_plan`` (target < 100 us).
``ik/<n>_knots``
    ``pointwise_ik`` along the arc with n = 2, 5, 10 knots, as task 1 builds it (target for
    10 knots < 0.1 s).
``run/<controller>``, ``run/report``
    ``python -m doorlab.cli run --controller C --doors closed`` end to end in a subprocess
    (interpreter start, imports, episode, metrics, PNG plots, replay.html; target for
    velocity < 4 s), and ``doorlab report --jobs 2`` (target < 15 s); ``info.cpu_s`` is the
    CPU time of the whole process tree.
``design/<controller>_closed``
    The episode against Drake's floor (the same cell, the recorded commands replayed from
    C++) and against the 353b732 design, side by side (``benchmarks/designs.py``).
``memory/episode``
    Peak resident set size of a fresh process that runs one velocity/closed episode, and of
    one that only imports doorlab: VmHWM read by the child from /proc/self/status (NOT
    ``ru_maxrss`` via RUSAGE_CHILDREN, which Linux seeds with the parent's peak at fork).
``profile/episode``
    Where the time of one velocity/closed episode goes: Python control ticks, the rest of
    ``Simulator.AdvanceTo`` (the C++ plant step), and setup/teardown. Measured with a timer
    around ``PlanRunner._tick`` (unbiased), then once more under cProfile for the top lines.

Every number is the MEDIAN over the repeats, with min and max. Targets are printed as pass/fail
but never change the exit code: 0 when the benchmarks ran (targets missed or not), 1 when a
benchmark itself crashed, 2 on bad arguments (one line on stderr).
"""

from __future__ import annotations

import argparse
import datetime
import fnmatch
import gc
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

BENCH_DIR = Path(__file__).resolve().parent
REPO_DIR = BENCH_DIR.parent
RESULTS_DIR = BENCH_DIR / "results"
SCHEMA = "doorlab-benchmarks/1"

CONTROLLERS = ("ik", "velocity", "impedance")
DOORS = ("open", "closed")
IK_KNOTS = (2, 5, 10)

DEFAULT_REPEATS = 3
"""Repeats of the in-process benchmarks (episodes, ticks, IK): a full run takes ~3-5 min on 2
cores, most of it the 6 x 3 episodes."""
TICK_CALLS = 5000
"""Plan commands timed per repeat (--quick: QUICK_TICK_CALLS)."""
QUICK_TICK_CALLS = 1000
TICK_STATES = 200
"""Distinct arm states along the arc the tick benchmark cycles through."""
TICK_PERTURBATION = 2e-3
"""Random joint offset added to the states on the arc [rad], so the pose errors are not zero."""
REGRESSION_THRESHOLD = 0.20
"""--compare flags a metric that got worse by more than this fraction."""
QUICK_SUBSET = ("tick/velocity", "tick/impedance", "ik/10_knots", "episode/velocity_closed")
"""What --quick runs when --only is not given."""

# Targets (design notes: speed targets live here, never in timed unit tests).
RTF_TARGET_OPEN = 18.0
"""An open-door episode (free space, no contact but the grasp) simulates at least 18x faster
than real time (issue 9). Closed-door episodes are judged against Drake's floor instead
(``design/*``: within 1.15x of it), which SAP's contact steps keep near 10x."""
TICK_TARGET_US = 100.0
"""A control tick must fit well inside the 5 ms control period (and not dominate the step)."""
RUN_TARGETS_S = {"run/velocity": ("<", 4.0), "run/report": ("<", 15.0)}
"""Issue 9: ``doorlab run`` (velocity, closed, every output) in 4 s end to end, ``doorlab
report`` (8 runs, 2 workers) in 15 s, wall-clock on the 2-core development machine."""
REPORT_JOBS = 2
IK10_TARGET_S = 0.1
"""Pointwise IK with 10 knots (task 1's plan) in under 0.1 s."""

USAGE_ERROR = 2
BENCHMARK_ERROR = 1


# ---------------------------------------------------------------------------------------------
# Results.


@dataclass
class Metric:
    """One measured quantity: samples (one per repeat) and how to judge them."""

    key: str
    benchmark: str
    unit: str
    samples: list[float]
    better: str = "lower"  # "lower" or "higher": which direction is an improvement
    target: tuple[str, float] | None = None  # (">=" or "<", value), judged on the median
    info: dict = field(default_factory=dict)
    other_cpu_cores: float | None = None  # CPU used by OTHER processes while measuring

    @property
    def median(self) -> float:
        return float(statistics.median(self.samples))

    @property
    def passed(self) -> bool | None:
        if self.target is None:
            return None
        op, value = self.target
        return self.median >= value if op == ">=" else self.median < value

    def _target_dict(self) -> dict | None:
        return None if self.target is None else {"op": self.target[0], "value": self.target[1]}

    def to_dict(self) -> dict:
        return {
            "benchmark": self.benchmark,
            "median": self.median,
            "min": float(min(self.samples)),
            "max": float(max(self.samples)),
            "unit": self.unit,
            "n": len(self.samples),
            "samples": [float(s) for s in self.samples],
            "better": self.better,
            "target": self._target_dict(),
            "passed": self.passed,
            "other_cpu_cores": self.other_cpu_cores,
            "info": self.info,
        }


@dataclass
class Settings:
    repeats: int
    run_repeats: int
    tick_calls: int
    quick: bool
    selected: list[str]


# ---------------------------------------------------------------------------------------------
# Noise: how much CPU other processes used while we measured.


def _busy_cpu_seconds() -> float | None:
    """CPU seconds spent busy by the whole machine since boot (/proc/stat), None if unknown."""
    try:
        with open("/proc/stat") as f:
            fields = f.readline().split()[1:]
    except OSError:
        return None
    ticks = [int(x) for x in fields]
    # user nice system idle iowait irq softirq steal [guest guest_nice: already in user/nice]
    busy = sum(ticks[i] for i in (0, 1, 2, 5, 6, 7) if i < len(ticks))
    return busy / os.sysconf("SC_CLK_TCK")


def _own_cpu_seconds() -> float:
    import resource

    total = 0.0
    for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN):
        usage = resource.getrusage(who)
        total += usage.ru_utime + usage.ru_stime
    return total


class CpuWatch:
    """Average number of cores used by other processes between start and stop."""

    def __init__(self) -> None:
        self._t = time.perf_counter()
        self._busy = _busy_cpu_seconds()
        self._own = _own_cpu_seconds()

    def other_cores(self) -> float | None:
        busy = _busy_cpu_seconds()
        wall = time.perf_counter() - self._t
        if busy is None or self._busy is None or wall <= 0:
            return None
        other = (busy - self._busy) - (_own_cpu_seconds() - self._own)
        return max(other, 0.0) / wall


# ---------------------------------------------------------------------------------------------
# The benchmarks. Each takes the settings and a context (shared, lazily built objects) and
# returns its metrics.


class Context:
    """Objects several benchmarks share, built on first use (kept out of the timings)."""

    def __init__(self) -> None:
        self._cache: dict[str, object] = {}

    def get(self, key: str, build: Callable[[], object]):
        if key not in self._cache:
            self._cache[key] = build()
        return self._cache[key]

    def plant(self):
        from doorlab.station import make_controller_plant

        return self.get("plant", make_controller_plant)

    def geometry(self):
        from doorlab import Scenario
        from doorlab.geometry import default_door_geometry

        return self.get("geometry", lambda: default_door_geometry(Scenario().arc.angle_end_deg))

    def warm(self) -> None:
        """Loads the models and the door geometry once (module and model caches)."""
        self.plant()
        self.geometry()


def _pointwise_ik(ctx: Context, knots: int):
    """Pointwise IK along the arc exactly as ``doorlab.controllers.build_ik_plan`` calls it."""
    from doorlab import Scenario
    from doorlab.constants import Q_HOME
    from doorlab.ik import pointwise_ik

    scenario = Scenario(controller="ik")
    geometry = ctx.geometry()
    return pointwise_ik(
        ctx.plant(),
        geometry.p_WQ_ref,
        geometry.R_WL7_ref,
        duration=scenario.timeline.arc_duration,
        num_knots=knots,
        q_guess=Q_HOME,
        position_tolerance=scenario.ik.position_tolerance,
        theta_bound=scenario.ik.theta_bound,
        centered=scenario.ik.objective == "centered",
    )


def _arc_states(ctx: Context):
    """(times, states): TICK_STATES arm states along the arc, slightly off it."""
    import numpy as np
    from pydrake.trajectories import PiecewisePolynomial

    from doorlab import Scenario
    from doorlab.plans import ArmState

    def build():
        ik = _pointwise_ik(ctx, 10)
        zero = np.zeros((7, 1))
        spline = PiecewisePolynomial.CubicWithContinuousSecondDerivatives(
            ik.times, ik.q_knots.T, zero, zero
        )
        velocity = spline.derivative(1)
        duration = Scenario().timeline.arc_duration
        times = np.linspace(0.0, duration, TICK_STATES)
        rng = np.random.default_rng(0)
        states = [
            ArmState(
                spline.value(t).ravel() + rng.normal(0.0, TICK_PERTURBATION, 7),
                velocity.value(t).ravel(),
                np.zeros(7),
            )
            for t in times
        ]
        return [float(t) for t in times], states

    return ctx.get("arc_states", build)


def bench_tick(controller: str) -> Callable[[Settings, Context], list[Metric]]:
    def run(settings: Settings, ctx: Context) -> list[Metric]:
        import numpy as np

        from doorlab import Scenario
        from doorlab.controllers import build_impedance_plan, build_velocity_plan

        build = build_velocity_plan if controller == "velocity" else build_impedance_plan
        scenario = Scenario(controller=controller)
        plan = build(scenario, ctx.geometry(), ctx.plant()).plan
        times, states = _arc_states(ctx)
        n = len(states)
        for i in range(100):  # warm-up
            plan.command(times[i % n], states[i % n])
        clock = time.perf_counter_ns
        medians, p90s, means = [], [], []
        for _ in range(settings.repeats):
            durations = np.empty(settings.tick_calls)
            for i in range(settings.tick_calls):
                t, state = times[i % n], states[i % n]
                start = clock()
                plan.command(t, state)
                durations[i] = clock() - start
            durations /= 1e3  # [us]
            medians.append(float(np.median(durations)))
            p90s.append(float(np.percentile(durations, 90)))
            means.append(float(np.mean(durations)))
        return [
            Metric(
                f"tick/{controller}",
                f"tick/{controller}",
                "us",
                medians,
                target=("<", TICK_TARGET_US),
                info={
                    "calls_per_repeat": settings.tick_calls,
                    "p90_us": statistics.median(p90s),
                    "mean_us": statistics.median(means),
                    "plan": type(plan).__name__,
                },
            )
        ]

    return run


def bench_ik(knots: int) -> Callable[[Settings, Context], list[Metric]]:
    def run(settings: Settings, ctx: Context) -> list[Metric]:
        _pointwise_ik(ctx, 2)  # warm-up: solver libraries, first-call costs
        samples, result = [], None
        for _ in range(settings.repeats):
            start = time.perf_counter()
            result = _pointwise_ik(ctx, knots)
            samples.append(time.perf_counter() - start)
        name = f"ik/{knots}_knots"
        return [
            Metric(
                name,
                name,
                "s",
                samples,
                target=("<", IK10_TARGET_S) if knots == 10 else None,
                info={
                    "solver": result.solver,
                    "max_position_residual_m": float(max(result.position_residuals)),
                },
            )
        ]

    return run


def bench_episodes(names: Sequence[str], settings: Settings, ctx: Context) -> list[Metric]:
    """All selected episodes, round-robin over the repeats (spreads slow phases evenly)."""
    from designs import advance_clock

    from doorlab import Scenario, run_controller

    ctx.warm()
    samples: dict[str, dict[str, list[float]]] = {
        n: {"sim_s": [], "rtf": [], "rtf_cpu": [], "e2e_s": []} for n in names
    }
    info: dict[str, dict] = {n: {} for n in names}
    watches = {n: [] for n in names}
    for _ in range(settings.repeats):
        for name in names:
            controller, doors = name.split("/", 1)[1].split("_")
            watch = CpuWatch()
            start = time.perf_counter()
            with advance_clock() as spent:
                result, _ = run_controller(Scenario(controller=controller, doors=doors))
            e2e = time.perf_counter() - start
            watches[name].append(watch.other_cores())
            s = samples[name]
            s["sim_s"].append(result.wall_time_s)
            s["rtf"].append(result.sim_time_s / result.wall_time_s)
            s["rtf_cpu"].append(result.sim_time_s / spent[1])
            s["e2e_s"].append(e2e)
            info[name] = {
                "sim_time_s": result.sim_time_s,
                "final_left_door_angle_rad": float(result.door_angles[-1, 0]),
            }
            print(
                f"  {name}: sim {result.wall_time_s:.2f} s "
                f"(RTF {result.sim_time_s / result.wall_time_s:.1f}), end to end {e2e:.2f} s",
                flush=True,
            )
            del result
            gc.collect()
    metrics = []
    for name in names:
        other = [w for w in watches[name] if w is not None]
        other_cores = statistics.mean(other) if other else None
        s = samples[name]
        metrics += [
            Metric(f"{name}/sim_s", name, "s", s["sim_s"], info=info[name]),
            Metric(
                f"{name}/rtf",
                name,
                "x",
                s["rtf"],
                better="higher",
                target=(">=", RTF_TARGET_OPEN) if name.endswith("_open") else None,
            ),
            Metric(f"{name}/rtf_cpu", name, "x", s["rtf_cpu"], better="higher"),
            Metric(f"{name}/e2e_s", name, "s", s["e2e_s"]),
        ]
        for m in metrics[-4:]:
            m.other_cpu_cores = other_cores
    return metrics


def _subprocess_env() -> dict[str, str]:
    """The environment of child processes: this doorlab importable, no GUI backend."""
    import doorlab

    env = dict(os.environ)
    src = str(Path(doorlab.__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (src, env.get("PYTHONPATH", "")) if p)
    env["MPLBACKEND"] = "Agg"
    return env


def _children_cpu_s() -> float:
    import resource

    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def bench_runs(names: Sequence[str], settings: Settings, ctx: Context) -> list[Metric]:
    """``doorlab run --doors closed`` end to end, one subprocess per repeat and controller;
    ``run/report``: ``doorlab report --jobs 2`` (8 runs and the page)."""
    env = _subprocess_env()
    samples = {n: [] for n in names}
    info: dict[str, dict] = {
        n: {"exit_codes": [], "episode_sim_s": [], "cpu_s": []} for n in names
    }
    watches = {n: [] for n in names}
    for _ in range(settings.run_repeats):
        for name in names:
            controller = name.split("/", 1)[1]
            with tempfile.TemporaryDirectory(prefix="doorlab-bench-") as tmp:
                out = Path(tmp) / "run"
                if controller == "report":
                    cmd = [
                        sys.executable, "-m", "doorlab.cli", "report", "--jobs",
                        str(REPORT_JOBS), "--out", str(out), "--force",
                    ]  # fmt: skip
                else:
                    cmd = [
                        sys.executable, "-m", "doorlab.cli", "run", "--controller", controller,
                        "--doors", "closed", "--out", str(out), "--force",
                    ]  # fmt: skip
                watch = CpuWatch()
                cpu = _children_cpu_s()
                start = time.perf_counter()
                proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
                elapsed = time.perf_counter() - start
                info[name]["cpu_s"].append(_children_cpu_s() - cpu)
                watches[name].append(watch.other_cores())
                if controller == "report" and proc.returncode == 1:
                    pass  # a run not ok: still a report
                elif proc.returncode not in (0, 3, 4, 5, 6):  # 3-6: a run status, not a crash
                    last = (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
                    raise RuntimeError(f"doorlab run exited {proc.returncode}: {last}")
                samples[name].append(elapsed)
                info[name]["exit_codes"].append(proc.returncode)
                try:
                    metrics = json.loads((out / "metrics.json").read_text())
                    info[name]["episode_sim_s"].append(metrics.get("wall_time_s"))
                except (OSError, ValueError):
                    pass
            print(f"  {name}: {elapsed:.2f} s (exit {proc.returncode})", flush=True)
    out_metrics = []
    for name in names:
        other = [w for w in watches[name] if w is not None]
        out_metrics.append(
            Metric(
                name,
                name,
                "s",
                samples[name],
                target=RUN_TARGETS_S.get(name),
                info=info[name],
                other_cpu_cores=statistics.mean(other) if other else None,
            )
        )
    return out_metrics


_PEAK_RSS = """
def _peak_rss_kib():
    # VmHWM: the peak RSS of this process's own address space since its exec.
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    import resource
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
"""
_EPISODE_CHILD = (
    _PEAK_RSS
    + """
from doorlab import Scenario, run_controller
result, _ = run_controller(Scenario(controller="velocity", doors="closed"))
print("PEAK_RSS_KIB", _peak_rss_kib())
"""
)
_IMPORT_CHILD = (
    _PEAK_RSS
    + """
import doorlab, doorlab.controllers, doorlab.metrics
print("PEAK_RSS_KIB", _peak_rss_kib())
"""
)
MEMORY_METHOD = (
    "peak RSS of a fresh child process: VmHWM from the child's /proc/self/status at its end "
    "(ru_maxrss of the child, via os.wait4 or RUSAGE_CHILDREN, is kept as info only: Linux "
    "carries the PARENT's peak RSS over fork/vfork + exec into it)"
)


def _peak_rss_mib(code: str, env: dict[str, str]) -> tuple[float, float]:
    """(VmHWM, ru_maxrss) [MiB] of a fresh interpreter running ``code``."""
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        proc = subprocess.Popen([sys.executable, "-c", code], env=env, stdout=out, stderr=err)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        if proc.returncode != 0:
            err.seek(0)
            lines = err.read().decode(errors="replace").strip().splitlines() or ["(no output)"]
            raise RuntimeError(f"child exited {proc.returncode}: {lines[-1]}")
        out.seek(0)
        reported = [
            line.split()[1]
            for line in out.read().decode(errors="replace").splitlines()
            if line.startswith("PEAK_RSS_KIB")
        ]
    if not reported:
        raise RuntimeError("the child did not report its peak RSS")
    return int(reported[-1]) / 1024.0, usage.ru_maxrss / 1024.0  # Linux: KiB


def bench_memory(settings: Settings, ctx: Context) -> list[Metric]:
    env = _subprocess_env()
    episode, episode_maxrss = _peak_rss_mib(_EPISODE_CHILD, env)
    baseline, baseline_maxrss = _peak_rss_mib(_IMPORT_CHILD, env)
    print(f"  memory/episode: {episode:.0f} MiB (imports alone: {baseline:.0f} MiB)", flush=True)
    return [
        Metric(
            "memory/episode",
            "memory/episode",
            "MiB",
            [episode],
            info={"method": MEMORY_METHOD, "ru_maxrss_mib": episode_maxrss},
        ),
        Metric(
            "memory/import",
            "memory/episode",
            "MiB",
            [baseline],
            info={
                "method": MEMORY_METHOD,
                "ru_maxrss_mib": baseline_maxrss,
                "what": "import doorlab, doorlab.controllers, doorlab.metrics",
            },
        ),
    ]


def bench_profile(settings: Settings, ctx: Context) -> tuple[list[Metric], dict]:
    """Split of one velocity/closed episode: ticks, plant step, setup; then cProfile."""
    import cProfile
    import io
    import pstats

    from doorlab import Scenario, run_controller
    from doorlab.plans import TaskSpaceVelocityPlan
    from doorlab.simulation import PlanRunner

    ctx.warm()
    scenario = Scenario(controller="velocity", doors="closed")

    # 1. Unbiased split: a perf_counter around every tick (~1 us of overhead per tick).
    original = PlanRunner._tick
    spent = [0.0, 0]

    def timed_tick(self, context, discrete_state):
        start = time.perf_counter()
        try:
            return original(self, context, discrete_state)
        finally:
            spent[0] += time.perf_counter() - start
            spent[1] += 1

    # ... and one around the velocity plan's command, to compare a tick inside an episode
    # (caches shared with the plant step) with the isolated tick/velocity benchmark.
    original_command = TaskSpaceVelocityPlan.command
    commands: list[float] = []

    def timed_command(self, t, state):
        start = time.perf_counter_ns()
        try:
            return original_command(self, t, state)
        finally:
            commands.append((time.perf_counter_ns() - start) / 1e3)

    PlanRunner._tick = timed_tick  # the runner binds self._tick when it is built
    TaskSpaceVelocityPlan.command = timed_command
    try:
        start = time.perf_counter()
        result, _ = run_controller(scenario)
        e2e = time.perf_counter() - start
    finally:
        PlanRunner._tick = original
        TaskSpaceVelocityPlan.command = original_command
    ticks_s, n_ticks = spent
    sim_s = result.wall_time_s
    plant_s = sim_s - ticks_s
    setup_s = e2e - sim_s

    # 2. cProfile (deterministic profiling inflates Python-heavy parts: shares are indicative).
    profiler = cProfile.Profile()
    start = time.perf_counter()
    profiler.enable()
    run_controller(scenario)
    profiler.disable()
    profiled_e2e = time.perf_counter() - start
    stats = pstats.Stats(profiler)

    def cumulative(match: Callable[[tuple], bool]) -> float:
        return sum(v[3] for k, v in stats.stats.items() if match(k))

    cp_ticks = cumulative(lambda k: k[2] == "_tick" and k[0].endswith("simulation.py"))
    cp_sim = cumulative(lambda k: k[0] == "~" and k[2].endswith(("AdvanceTo>", "Initialize>")))
    cp_named = {
        label: cumulative(lambda k, f=func: k[2] == f)
        for label, func in (
            ("grasp IK + plan (build_velocity_plan)", "build_velocity_plan"),
            ("controller plant (make_controller_plant)", "make_controller_plant"),
            ("station: parsing + diagram (build_station)", "build_station"),
            ("plan commands (every Plan.command)", "command"),
        )
    }
    text = io.StringIO()
    stats.stream = text
    stats.sort_stats("cumulative").print_stats(18)
    stats.sort_stats("tottime").print_stats(12)
    top = _trim_pstats(text.getvalue())

    split = {
        "episode_e2e_s": e2e,
        "ticks_s": ticks_s,
        "ticks": n_ticks,
        "tick_mean_us": 1e6 * ticks_s / max(n_ticks, 1),
        "plant_step_s": plant_s,
        "setup_and_teardown_s": setup_s,
        "velocity_commands": len(commands),
        "velocity_command_median_us": statistics.median(commands) if commands else None,
        "cprofile": {
            "e2e_s": profiled_e2e,
            "ticks_s": cp_ticks,
            "plant_step_s": cp_sim - cp_ticks,
            "setup_and_teardown_s": profiled_e2e - cp_sim,
            "named_cumulative_s": cp_named,
        },
    }
    print(
        f"  profile/episode: e2e {e2e:.2f} s = ticks {ticks_s:.2f} s ({n_ticks} ticks, "
        f"{split['tick_mean_us']:.0f} us each) + plant step {plant_s:.2f} s "
        f"+ setup/teardown {setup_s:.2f} s",
        flush=True,
    )
    if commands:
        print(
            f"  velocity plan command inside the episode: median "
            f"{statistics.median(commands):.0f} us over {len(commands)} calls",
            flush=True,
        )
    metrics = [
        Metric("profile/episode/ticks_s", "profile/episode", "s", [ticks_s]),
        Metric("profile/episode/plant_step_s", "profile/episode", "s", [plant_s]),
        Metric("profile/episode/setup_s", "profile/episode", "s", [setup_s]),
    ]
    if commands:
        metrics.append(
            Metric(
                "profile/episode/velocity_command_us",
                "profile/episode",
                "us",
                [statistics.median(commands)],
                info={"what": "median TaskSpaceVelocityPlan.command inside the episode"},
            )
        )
    return metrics, {"split": split, "top": top}


def _trim_pstats(text: str) -> str:
    """pstats output without its blank lines and with shortened paths."""
    lines = []
    for line in text.splitlines():
        if not line.strip():
            continue
        for prefix in sorted({str(REPO_DIR) + os.sep, sys.prefix + os.sep}, key=len, reverse=True):
            line = line.replace(prefix, "")
        lines.append(line.rstrip())
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------
# Registry and selection.

EPISODES = tuple(f"episode/{c}_{d}" for c in CONTROLLERS for d in DOORS)
TICKS = ("tick/velocity", "tick/impedance")
IKS = tuple(f"ik/{n}_knots" for n in IK_KNOTS)
RUNS = (*(f"run/{c}" for c in CONTROLLERS), "run/report")
DESIGNS = tuple(f"design/{c}_closed" for c in CONTROLLERS)
ALL = (*TICKS, *IKS, *EPISODES, *DESIGNS, *RUNS, "memory/episode", "profile/episode")
"""Every benchmark, in the order they run (cheap ones first)."""


def select(patterns: Sequence[str] | None, quick: bool) -> list[str]:
    """Benchmark names matching the patterns (names, groups like ``episode``, or globs)."""
    if not patterns:
        return list(QUICK_SUBSET if quick else ALL)
    chosen = set()
    for pattern in patterns:
        matched = [
            n for n in ALL if n == pattern or n.startswith(pattern.rstrip("/") + "/")
            or fnmatch.fnmatchcase(n, pattern)
        ]  # fmt: skip
        if not matched:
            choices = ", ".join(ALL)
            raise ValueError(f"--only {pattern!r} matches no benchmark; choose from {choices}")
        chosen.update(matched)
    return [n for n in ALL if n in chosen]


def run_all(settings: Settings) -> tuple[list[Metric], dict[str, str], dict | None]:
    """Runs the selected benchmarks; a crashing benchmark is recorded, the others still run."""
    import traceback

    ctx = Context()
    metrics: list[Metric] = []
    errors: dict[str, str] = {}
    profile = None
    selected = settings.selected

    def attempt(name: str, func: Callable[[], list[Metric]]) -> None:
        print(f"[{name}]", flush=True)
        watch = CpuWatch()
        try:
            produced = func()
        except Exception as e:  # keep going: one broken benchmark must not hide the others
            errors[name] = f"{type(e).__name__}: {e}"
            print(f"  ERROR {errors[name]}", file=sys.stderr, flush=True)
            traceback.print_exc(limit=3)
            return
        other = watch.other_cores()
        for m in produced:
            if m.other_cpu_cores is None:
                m.other_cpu_cores = other
        metrics.extend(produced)

    for name in selected:
        if name.startswith("tick/"):
            attempt(name, lambda n=name: bench_tick(n.split("/")[1])(settings, ctx))
        elif name.startswith("ik/"):
            knots = int(name.split("/")[1].split("_")[0])
            attempt(name, lambda k=knots: bench_ik(k)(settings, ctx))
    episodes = [n for n in selected if n.startswith("episode/")]
    if episodes:
        attempt("episode/*", lambda: bench_episodes(episodes, settings, ctx))
    designs = [n for n in selected if n.startswith("design/")]
    if designs:
        from designs import bench_designs

        attempt(
            "design/*",
            lambda: bench_designs(designs, settings, ctx, Metric=Metric, CpuWatch=CpuWatch),
        )
    runs = [n for n in selected if n.startswith("run/")]
    if runs:
        attempt("run/*", lambda: bench_runs(runs, settings, ctx))
    if "memory/episode" in selected:
        attempt("memory/episode", lambda: bench_memory(settings, ctx))
    if "profile/episode" in selected:
        holder: dict = {}

        def profile_bench() -> list[Metric]:
            produced, holder["profile"] = bench_profile(settings, ctx)
            return produced

        attempt("profile/episode", profile_bench)
        profile = holder.get("profile")
    return metrics, errors, profile


# ---------------------------------------------------------------------------------------------
# Machine information, output and comparison.


def machine_info() -> dict:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        from importlib.metadata import version

        drake = version("drake")
    except Exception:  # not installed as a distribution (e.g. a source build)
        drake = "unknown"
    try:
        import numpy

        numpy_version = numpy.__version__
    except ImportError:
        numpy_version = "unknown"
    try:
        commit = subprocess.run(
            ["git", "-C", str(REPO_DIR), "rev-parse", "--short", "HEAD"],
            capture_output=True, text=True, timeout=5,
        ).stdout.strip() or None  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        commit = None
    affinity = hasattr(os, "sched_getaffinity")
    return {
        "cpu_model": cpu,
        "cores": os.cpu_count(),
        "cores_available": len(os.sched_getaffinity(0)) if affinity else None,
        "python": platform.python_version(),
        "drake": drake,
        "numpy": numpy_version,
        "platform": platform.platform(),
        "hostname": platform.node(),
        "git_commit": commit,
    }


def _loadavg() -> list[float] | None:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None


def _fmt(value: float | None) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    if value == 0:
        return "0"
    magnitude = abs(value)
    if magnitude >= 1000:
        return f"{value:.0f}"
    if magnitude >= 1:
        return f"{value:.3g}" if magnitude < 100 else f"{value:.1f}"
    return f"{value:.3g}"


def format_table(metrics: Sequence[Metric]) -> str:
    header = ("name", "median", "min", "max", "unit", "target", "result", "other cpu")
    rows = [header]
    for m in metrics:
        target = "" if m.target is None else f"{m.target[0]} {_fmt(m.target[1])}"
        result = "" if m.passed is None else ("pass" if m.passed else "FAIL")
        other = "" if m.other_cpu_cores is None else f"{m.other_cpu_cores:.1f}"
        rows.append(
            (
                m.key,
                _fmt(m.median),
                _fmt(min(m.samples)),
                _fmt(max(m.samples)),
                m.unit,
                target,
                result,
                other,
            )
        )
    widths = [max(len(r[i]) for r in rows) for i in range(len(header))]
    lines = []
    for i, row in enumerate(rows):
        cells = [
            cell.ljust(w) if j in (0, 4, 5, 6) else cell.rjust(w)
            for j, (cell, w) in enumerate(zip(row, widths, strict=True))
        ]
        lines.append("  ".join(cells).rstrip())
        if i == 0:
            lines.append("  ".join("-" * w for w in widths))
    return "\n".join(lines)


def _clean(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    return value


def write_json(path: Path, data: dict) -> None:
    """Writes ``data`` atomically (temporary file, then rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(_clean(data), indent=2) + "\n")
    os.replace(tmp, path)


def load_baseline(path: Path) -> dict:
    """A previous JSON output (raises ValueError with a one-line reason)."""
    try:
        data = json.loads(path.read_text())
    except OSError as e:
        raise ValueError(f"--compare {str(path)!r}: cannot read ({e.strerror})") from None
    except json.JSONDecodeError as e:
        raise ValueError(f"--compare {str(path)!r}: not valid JSON ({e.msg})") from None
    if not isinstance(data, dict) or not isinstance(data.get("metrics"), dict):
        raise ValueError(f"--compare {str(path)!r}: not a benchmark result (no 'metrics')")
    return data


def compare(new: dict, old: dict) -> tuple[str, list[str]]:
    """A table of new/old per metric present in both; returns (text, regressed keys)."""
    rows = [("name", "old", "new", "unit", "new/old", "")]
    regressed = []
    for key, metric in new["metrics"].items():
        before = old["metrics"].get(key)
        if not isinstance(before, dict) or not before.get("median"):
            rows.append((key, "-", _fmt(metric["median"]), metric["unit"], "-", "new"))
            continue
        ratio = metric["median"] / before["median"]
        if metric.get("better") == "higher":
            worse, better = ratio < 1 / (1 + REGRESSION_THRESHOLD), ratio > 1 + REGRESSION_THRESHOLD
        else:
            worse, better = ratio > 1 + REGRESSION_THRESHOLD, ratio < 1 / (1 + REGRESSION_THRESHOLD)
        flag = "REGRESSION" if worse else ("improved" if better else "")
        if worse:
            regressed.append(key)
        old_value, new_value = _fmt(before["median"]), _fmt(metric["median"])
        rows.append((key, old_value, new_value, metric["unit"], f"{ratio:.2f}", flag))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = []
    for i, row in enumerate(rows):
        cells = [
            c.ljust(w) if j in (0, 3, 5) else c.rjust(w)
            for j, (c, w) in enumerate(zip(row, widths, strict=True))
        ]
        lines.append("  ".join(cells).rstrip())
        if i == 0:
            lines.append("  ".join("-" * w for w in widths))
    missing = sorted(set(old["metrics"]) - set(new["metrics"]))
    if missing:
        lines.append(f"(not measured this time: {', '.join(missing)})")
    old_cpu = old.get("machine", {}).get("cpu_model")
    if old_cpu and old_cpu != new["machine"].get("cpu_model"):
        lines.append(f"note: the baseline ran on a different CPU ({old_cpu})")
    return "\n".join(lines), regressed


# ---------------------------------------------------------------------------------------------
# Command line.


def build_parser() -> argparse.ArgumentParser:
    from doorlab.cli import OneLineParser, bounded_int  # the CLI's one-line errors, exit 2

    parser = OneLineParser(
        prog="run_benchmarks.py",
        description="doorlab benchmarks: medians (min, max) over repeats, JSON out, compare.",
        epilog=f"benchmarks: {', '.join(ALL)}",
    )
    parser.add_argument(
        "--repeats",
        type=bounded_int(1),
        default=None,
        help=f"repeats of episodes, ticks and IK (default {DEFAULT_REPEATS}, 1 with --quick); "
        "doorlab run subprocesses repeat max(1, N // 2) times",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="smoke run: 1 repeat, fewer tick calls, and (without --only) "
        f"only {', '.join(QUICK_SUBSET)}",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="JSON file to write (default: benchmarks/results/bench-<date>-<time>.json)",
    )
    parser.add_argument(
        "--compare", type=Path, default=None, metavar="OLD.json", help="print new/old per metric"
    )
    parser.add_argument(
        "--only",
        nargs="+",
        default=None,
        metavar="NAME",
        help="benchmark names, groups (episode, tick, ik, run) or globs (episode/*_closed)",
    )
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        selected = select(args.only, args.quick)
        baseline = load_baseline(args.compare) if args.compare is not None else None
    except ValueError as e:
        parser.error(str(e))
    now = datetime.datetime.now().astimezone()
    out = args.out or RESULTS_DIR / f"bench-{now:%Y%m%d-%H%M%S}.json"
    if out.is_dir():
        parser.error(f"--out {str(out)!r} is a folder; give a .json file")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        parser.error(f"--out {str(out)!r}: cannot create its folder ({e.strerror})")
    if not os.access(out.parent, os.W_OK):
        parser.error(f"--out {str(out)!r}: folder not writable")

    try:
        import doorlab  # noqa: F401
    except ImportError:  # run from a checkout without `pip install -e .`
        sys.path.insert(0, str(REPO_DIR / "src"))

    repeats = args.repeats or (1 if args.quick else DEFAULT_REPEATS)
    settings = Settings(
        repeats=repeats,
        run_repeats=max(1, repeats // 2),
        tick_calls=QUICK_TICK_CALLS if args.quick else TICK_CALLS,
        quick=args.quick,
        selected=selected,
    )
    load_start = _loadavg()
    cores = os.cpu_count() or 1
    print(
        f"doorlab benchmarks: {len(selected)} benchmark(s), {repeats} repeat(s); "
        f"load average {load_start} on {cores} cores",
        flush=True,
    )
    watch = CpuWatch()
    wall_start = time.perf_counter()
    metrics, errors, profile = run_all(settings)
    duration = time.perf_counter() - wall_start
    other_cores = watch.other_cores()

    data = {
        "schema": SCHEMA,
        "created": now.isoformat(timespec="seconds"),
        "machine": machine_info(),
        "settings": {
            "repeats": settings.repeats,
            "run_repeats": settings.run_repeats,
            "tick_calls": settings.tick_calls,
            "quick": settings.quick,
            "selected": selected,
            "argv": list(sys.argv[1:] if argv is None else argv),
        },
        "load": {
            "loadavg_start": load_start,
            "loadavg_end": _loadavg(),
            "other_cpu_cores_mean": other_cores,
        },
        "duration_s": duration,
        "metrics": {m.key: m.to_dict() for m in metrics},
        "errors": errors,
        "profile": profile,
    }

    print()
    print(format_table(metrics))
    if profile is not None:
        split = profile["split"]
        e2e = split["episode_e2e_s"]
        print()
        print("profile/episode (velocity, doors closed): where the wall time goes")
        for label, key in (
            ("(a) Python control ticks (PlanRunner._tick)", "ticks_s"),
            ("(b) rest of Simulator.AdvanceTo (C++ plant step)", "plant_step_s"),
            ("(c) setup/teardown (parsing, IK, build, logs)", "setup_and_teardown_s"),
        ):
            cp = split["cprofile"][key]
            print(
                f"  {label:<50} {split[key]:6.2f} s  {100 * split[key] / e2e:5.1f} %   "
                f"(cProfile: {cp:.2f} s, {100 * cp / split['cprofile']['e2e_s']:.1f} %)"
            )
        print(f"  {'total (end to end)':<50} {e2e:6.2f} s")
        inside = split.get("velocity_command_median_us")
        if inside is not None:
            isolated = next((m.median for m in metrics if m.key == "tick/velocity"), None)
            versus = "" if isolated is None else f" vs {isolated:.0f} us isolated (tick/velocity)"
            print(f"  velocity plan command: median {inside:.0f} us inside the episode{versus}")
        for label, value in split["cprofile"]["named_cumulative_s"].items():
            print(f"    cProfile cumulative, {label}: {value:.3f} s")
        print("\n  cProfile top lines:")
        print("\n".join("    " + line for line in profile["top"].splitlines()))
    if other_cores is not None:
        noisy = other_cores > 0.25
        print(
            f"\nother processes used {other_cores:.2f} of {cores} cores on average during the "
            f"run{' -- timings are NOISY' if noisy else ''}"
        )
    if errors:
        print(f"\n{len(errors)} benchmark(s) failed: {', '.join(errors)}", file=sys.stderr)
    write_json(out, data)
    print(f"wrote {out} ({duration:.0f} s)")

    if baseline is not None:
        text, regressed = compare(data, baseline)
        print(f"\ncompared with {args.compare}:")
        print(text)
        threshold = int(100 * REGRESSION_THRESHOLD)
        if regressed:
            print(f"{len(regressed)} regression(s) > {threshold} %: {', '.join(regressed)}")
        else:
            print(f"no regression > {threshold} %")
    return BENCHMARK_ERROR if errors else 0


if __name__ == "__main__":
    sys.exit(main())
