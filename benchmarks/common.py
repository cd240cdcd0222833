"""Shared pieces of the benchmarks: settings, the metric record, the CPU-noise watch, the
lazily built context, constants and targets."""

from __future__ import annotations

import os
import statistics
import time
from collections.abc import Callable
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
    instr_runs: int = 1  # full sets of instruction counts (instr/*): deterministic, one suffices


# ---------------------------------------------------------------------------------------------
# Noise: how much CPU other processes used while we measured.


def cpu_times() -> tuple[float, float] | None:
    """(busy, total) jiffies of all CPUs from /proc/stat (idle and iowait not busy), or None
    off Linux: the machine's busy share over a span is the ratio of two readings' differences."""
    try:
        fields = [float(x) for x in Path("/proc/stat").read_text().split("\n")[0].split()[1:]]
    except OSError:
        return None
    idle = fields[3] + fields[4]
    return sum(fields) - idle, sum(fields)


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
        from doorlab.cell.station import make_controller_plant

        return self.get("plant", make_controller_plant)

    def geometry(self):
        from doorlab import Scenario
        from doorlab.cell.geometry import default_door_geometry

        return self.get("geometry", lambda: default_door_geometry(Scenario().arc.angle_end_deg))

    def warm(self) -> None:
        """Loads the models and the door geometry once (module and model caches)."""
        self.plant()
        self.geometry()


def subprocess_env() -> dict[str, str]:
    """The environment of child processes: this doorlab importable, no GUI backend."""
    import doorlab

    env = dict(os.environ)
    src = str(Path(doorlab.__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (src, env.get("PYTHONPATH", "")) if p)
    env["MPLBACKEND"] = "Agg"
    return env


def source_label(src: Path | str) -> str:
    """Which code a folder holds, for a result file: its git commit (``-dirty`` with local
    changes), or "not a git checkout"; never the folder's path, which names one machine."""
    import subprocess

    def git(*args: str) -> str:
        out = subprocess.run(["git", "-C", str(src), *args], capture_output=True, text=True)
        return out.stdout.strip() if out.returncode == 0 else ""

    commit = git("rev-parse", "--short=12", "HEAD")
    if not commit:
        return "not a git checkout"
    return commit + ("-dirty" if git("status", "--porcelain", "--untracked-files=no") else "")


def machine() -> dict:
    """What a results file says of the machine it was measured on: cores, Python, Drake and
    the load average (1, 5, 15 min) at the time of writing."""
    import platform

    from doorlab.outputs.pages import drake_version

    return {
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "drake": drake_version(),
        "loadavg": os.getloadavg(),
    }


def children_cpu_s() -> float:
    import resource

    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime
