"""Benchmark group ``instr/<controller>_closed``: the design group's three simulations counted in
instructions (callgrind), so that a ratio does not depend on what else the machine runs.

``benchmarks/designs.py`` times three simulations of one episode side by side in CPU time:
**floor** (Drake alone: the recorded commands replayed from C++), **python** (the episode's
machinery, the Python plan runner and the logger, with a plan that replays the recorded
commands) and **new** (``run_controller``). On a shared 2-core machine their CPU-time ratios
moved by 2x between runs of the same commit (issue 35). Here each of the three runs in its own
process under ``valgrind --tool=callgrind``, which counts the instructions of the episode's
advance only, the region ``designs.py`` times: ``Simulator.AdvanceTo`` for the floor, the
episode's ``advance_interruptibly`` for the others (the simulator's steps and the plan
runner's ticks between them; nothing of the imports, IK or diagram building). Callgrind
starts uninstrumented and the region is marked with its client requests
(``callgrind_region.c``, built with the system's C compiler: valgrind's headers and ``cc``).

Under callgrind Python and Drake run ~50x slower, so the counted episode is a short one with
the same phases (:func:`short_scenario`: the approach, the grasp, the arc against the closed
door at the full episode's door speed, the settle and extra time): 9.85 s of simulated time
instead of 24 s. ``python benchmarks/instructions.py --check-cpu`` checks that its ratios
predict the full episode's (CPU-time medians of both, side by side).

What the count leaves out: an instruction is an instruction, whether its data came from L1 or
from memory. Cache and TLB misses, branch mispredictions and the interpreter's poor
instruction-level parallelism are invisible to it, and Python code, which chases pointers,
spends more time per instruction than Drake's dense numerics: the CPU-time ratios (medians of
side-by-side repeats) remain the check on any conclusion drawn from the counts.

Metrics (per controller, one count per run: the counts are deterministic to ~0.01 %):
``design/<controller>_closed/{floor,python,new}_instr`` [instructions] and the ratios
``python_over_floor_instr`` (target <= 1.2), ``new_over_python_instr`` (<= 1.1) and
``new_over_floor_instr``.

Run alone::

    python benchmarks/instructions.py [--runs N] [--jobs J] [--keep DIR]
    python benchmarks/instructions.py --check-cpu [--repeats N]
"""

from __future__ import annotations

import argparse
import concurrent.futures
import os
import pickle
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

from common import BENCH_DIR, CpuWatch, Metric, Settings, subprocess_env

CONTROLLERS = ("velocity", "impedance")
"""The controllers whose ticks run Python (IK has no python variant: no tick to replay)."""
VARIANTS = ("floor", "python", "new")
PYTHON_OVER_FLOOR_TARGET = 1.2
NEW_OVER_PYTHON_TARGET = 1.1

REGION_SOURCE = BENCH_DIR / "callgrind_region.c"
"""The counted region's markers (callgrind's client requests): built into each run's folder."""
REGION_ENV = "DOORLAB_CALLGRIND_REGION"

SHORT_TIMELINE = {
    "hold_duration": 0.05,
    "approach_duration": 1.5,
    "grasp_duration": 0.3,
    "arc_duration": 3.0,
    "extra_time": 1.0,
}
"""The counted episode's timeline [s] (each plan is also held PLAN_SETTLE_TIME, 1 s, after it):
0-1.05 hold, 1.05-3.55 approach, 3.55-4.85 grasp, 4.85-8.85 arc, then 1 s: 9.85 s in all, the
plan runner ticking over the last 5 s (the full episode: 13 of 24 s)."""
SHORT_ARC_END_DEG = 15.0
"""The short arc's end [deg]: 15 deg in 3 s, the full arc's 50 deg in 10 s (the same handle
speed, so the same contact forces on the door)."""


def short_scenario(controller: str):
    """The counted episode: ``controller`` against the closed doors on :data:`SHORT_TIMELINE`."""
    from doorlab import Scenario

    scenario = Scenario(controller=controller, doors="closed")
    for name, value in SHORT_TIMELINE.items():
        setattr(scenario.timeline, name, value)
    scenario.arc.angle_end_deg = SHORT_ARC_END_DEG
    return scenario


def recorded_short(controller: str):
    """(scenario, result): the short episode run once, its commands logged at every tick."""
    from designs import recorded_commands

    return recorded_commands(controller, "closed", scenario=short_scenario(controller))


def valgrind() -> str:
    """The valgrind executable.

    Raises:
        RuntimeError: It is not installed (one line, how to get it).
    """
    found = shutil.which("valgrind")
    if found is None:
        raise RuntimeError(
            "valgrind not found: instr/* counts instructions with callgrind "
            "(apt-get install valgrind), or leave instr/* out"
        )
    return found


def build_region(folder: Path) -> Path:
    """The region markers as a shared library in ``folder``.

    Raises:
        RuntimeError: No C compiler, or no valgrind headers (one line, what to install).
    """
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        raise RuntimeError("no C compiler (cc): instr/* builds callgrind's region markers")
    library = folder / "callgrind_region.so"
    proc = subprocess.run(
        [compiler, "-O2", "-shared", "-fPIC", "-o", str(library), str(REGION_SOURCE)],
        capture_output=True,
        text=True,
    )
    if proc.returncode != 0:
        first = (proc.stderr.strip().splitlines() or ["?"])[0]
        raise RuntimeError(f"cannot build {REGION_SOURCE.name} (valgrind's headers?): {first}")
    return library


CACHE_SIM = (
    "--cache-sim=yes",
    "--branch-sim=yes",
    "--I1=65536,16,64",  # this machine's L1 instruction cache (per core, /sys/.../cache)
    "--D1=49152,12,64",  # its L1 data cache
    "--LL=2097152,16,64",  # its L2, the last level private to a core, as callgrind's LL
)
"""``--cache-sim``: callgrind also simulates this machine's caches and a branch predictor."""


def _events(out_file: Path) -> dict[str, int]:
    """The events a callgrind output file collected: ``Ir`` (instructions), and with
    :data:`CACHE_SIM` the cache misses (``I1mr``, ``D1mr``, ``D1mw``, ``ILmr``, ``DLmr``,
    ``DLmw``) and mispredicted branches (``Bcm``, ``Bim``)."""
    lines = out_file.read_text().splitlines()
    names = next((line.split()[1:] for line in lines if line.startswith("events:")), ["Ir"])
    for prefix in ("totals:", "summary:"):  # with the collection toggled, summary is 0
        for line in lines:
            if line.startswith(prefix):
                values = [int(v) for v in line.split()[1:]]
                return dict(zip(names, values + [0] * (len(names) - len(values)), strict=True))
    raise RuntimeError(f"{out_file}: no totals line (did callgrind finish?)")


def count(
    variant: str, recorded_file: Path, out_file: Path, region: Path, *, cache_sim: bool = False
) -> dict[str, int]:
    """The events (:func:`_events`) of the advance of one ``variant`` simulation of the
    recorded episode, in a child process under callgrind (``region``: :func:`build_region`'s
    library)."""
    env = subprocess_env()
    env["PYTHONHASHSEED"] = "0"  # the same dict and set orders in every run
    env[REGION_ENV] = str(region)
    cmd = [
        valgrind(),
        "--tool=callgrind",
        "--instr-atstart=no",
        "--collect-atstart=no",
        *(CACHE_SIM if cache_sim else ()),
        f"--callgrind-out-file={out_file}",
        sys.executable,
        str(Path(__file__).resolve()),
        "--child",
        variant,
        str(recorded_file),
    ]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=BENCH_DIR)
    if proc.returncode != 0:
        tail = "\n".join(proc.stderr.strip().splitlines()[-5:])
        raise RuntimeError(f"callgrind run of {variant} failed (exit {proc.returncode}):\n{tail}")
    return _events(out_file)


def _child(variant: str, recorded_file: Path) -> None:
    """One simulation of ``variant`` (the counted process): its advance between the markers."""
    import ctypes

    from designs import build_floor, replay_episode

    from doorlab.episode import simulation

    markers = ctypes.CDLL(os.environ[REGION_ENV])
    scenario, result = pickle.loads(recorded_file.read_bytes())
    if variant == "floor":
        simulator, t_final = build_floor(scenario, result)
        simulator.Initialize()
        markers.doorlab_region_start()
        simulator.AdvanceTo(t_final)
        markers.doorlab_region_stop()
        return
    original = simulation.advance_interruptibly

    def counted(*args, **kwargs):
        markers.doorlab_region_start()
        try:
            return original(*args, **kwargs)
        finally:
            markers.doorlab_region_stop()

    simulation.advance_interruptibly = counted
    if variant == "python":
        replay_episode(scenario, result)
    else:
        from doorlab import run_controller

        run_controller(scenario)


def count_all(
    controllers: Sequence[str], *, jobs: int, keep: Path | None = None, cache_sim: bool = False
) -> dict[str, dict[str, dict[str, int]]]:
    """{controller: {variant: events}} (:func:`count`): every (controller, variant) counted
    once, ``jobs`` child processes at a time."""
    with tempfile.TemporaryDirectory(prefix="doorlab-instr-") as tmp:
        folder = Path(tmp) if keep is None else keep
        folder.mkdir(parents=True, exist_ok=True)
        region = build_region(folder)
        recorded = {}
        for controller in controllers:
            path = folder / f"{controller}.pkl"
            path.write_bytes(pickle.dumps(recorded_short(controller)))
            recorded[controller] = path
        with concurrent.futures.ThreadPoolExecutor(max_workers=jobs) as pool:
            futures = {
                (c, v): pool.submit(
                    count,
                    v,
                    recorded[c],
                    folder / f"callgrind.{c}_{v}.out",
                    region,
                    cache_sim=cache_sim,
                )
                for c in controllers
                for v in VARIANTS
            }
            counts: dict[str, dict[str, dict[str, int]]] = {c: {} for c in controllers}
            for (c, v), future in futures.items():
                counts[c][v] = future.result()
    return counts


def ratios(counts: dict[str, dict[str, int]]) -> dict[str, float]:
    """The three ratios of one controller's instruction counts."""
    floor, python, new = (counts[v]["Ir"] for v in VARIANTS)
    return {
        "python_over_floor_instr": python / floor,
        "new_over_python_instr": new / python,
        "new_over_floor_instr": new / floor,
    }


def misses(counts: dict[str, dict[str, int]]) -> list[str]:
    """Lines for ``--cache-sim``: each variant's misses, then per 1000 instructions of the
    floor and of what python adds to it and new to python (MPKI)."""

    def kinds(e: dict[str, int]) -> tuple[int, int, int, int, int]:
        return (
            e["Ir"],
            e["I1mr"],
            e["D1mr"] + e["D1mw"],
            e["ILmr"] + e["DLmr"] + e["DLmw"],
            e["Bcm"] + e["Bim"],
        )

    rows = {v: kinds(counts[v]) for v in VARIANTS}
    lines = [
        f"    {v:<7} instr {r[0]:>14,d}  L1i miss {r[1]:>12,d}  L1d miss {r[2]:>12,d}  "
        f"L2 miss {r[3]:>10,d}  branch miss {r[4]:>12,d}"
        for v, r in rows.items()
    ]
    parts = {
        "floor": rows["floor"],
        "python - floor": tuple(a - b for a, b in zip(rows["python"], rows["floor"], strict=True)),
        "new - python": tuple(a - b for a, b in zip(rows["new"], rows["python"], strict=True)),
    }
    for label, r in parts.items():
        per = [1000 * x / r[0] for x in r[1:]]
        lines.append(
            f"    {label:<15} per 1000 instructions: L1i {per[0]:.2f}, L1d {per[1]:.2f}, "
            f"L2 {per[2]:.3f}, branch {per[3]:.2f}"
        )
    return lines


def bench_instructions(names: Sequence[str], settings: Settings, ctx) -> list[Metric]:
    """``instr/<controller>_closed``: the counts and their ratios, ``settings.instr_runs``
    runs (each a full set of counts)."""
    valgrind()
    controllers = [n.split("/", 1)[1].split("_")[0] for n in names]
    samples: dict[str, dict[str, list[float]]] = {c: {} for c in controllers}
    watch = CpuWatch()
    for _ in range(settings.instr_runs):
        start = time.perf_counter()
        counts = count_all(controllers, jobs=min(2, os.cpu_count() or 1))
        for c in controllers:
            row = {f"{v}_instr": float(counts[c][v]["Ir"]) for v in VARIANTS} | ratios(counts[c])
            for key, value in row.items():
                samples[c].setdefault(key, []).append(value)
            print(
                f"  instr/{c}_closed: floor {row['floor_instr'] / 1e9:.3f} G, python "
                f"{row['python_instr'] / 1e9:.3f} G, new {row['new_instr'] / 1e9:.3f} G "
                f"(python/floor {row['python_over_floor_instr']:.4f}, new/python "
                f"{row['new_over_python_instr']:.4f})",
                flush=True,
            )
        print(f"  ({time.perf_counter() - start:.0f} s)", flush=True)
    targets = {
        "python_over_floor_instr": ("<", PYTHON_OVER_FLOOR_TARGET),
        "new_over_python_instr": ("<", NEW_OVER_PYTHON_TARGET),
    }
    other = watch.other_cores()
    metrics = []
    for c in controllers:
        name = f"design/{c}_closed"
        for key, values in samples[c].items():
            metric = Metric(
                f"{name}/{key}",
                f"instr/{c}_closed",
                "instr" if key.endswith("_instr") and "_over_" not in key else "x",
                values,
                target=targets.get(key),
                info={"timeline": SHORT_TIMELINE, "arc_end_deg": SHORT_ARC_END_DEG},
            )
            metric.other_cpu_cores = other
            metrics.append(metric)
    return metrics


# ---------------------------------------------------------------------------------------------
# The check: do the short episode's ratios predict the full episode's? (CPU time, side by side)


def check_cpu(controllers: Sequence[str], repeats: int) -> dict[str, dict[str, list[float]]]:
    """CPU times [s] of the full and the short episode's three simulations, round-robin over
    ``repeats``: {"<controller>/<full|short>": {"floor": [...], "python": [...], "new": [...],
    "python_over_floor": [...], "new_over_python": [...]}} (ratios per repeat)."""
    import gc

    from designs import recorded_commands, time_episode, time_floor, time_python_floor

    from doorlab import run_controller

    episodes = {}
    for c in controllers:
        episodes[f"{c}/full"] = recorded_commands(c, "closed")
        episodes[f"{c}/short"] = recorded_short(c)
    keys = ("floor", "python", "new", "python_over_floor", "new_over_python")
    samples = {k: {key: [] for key in keys} for k in episodes}
    for i in range(repeats):
        watch = CpuWatch()
        for key, (scenario, result) in episodes.items():
            floor = time_floor(scenario, result)[1]
            gc.collect()
            python = time_python_floor(scenario, result)[1]
            gc.collect()
            new = time_episode(run_controller, scenario)[1]
            gc.collect()
            row = (floor, python, new, python / floor, new / python)
            for name, value in zip(keys, row, strict=True):
                samples[key][name].append(value)
        other = watch.other_cores()
        print(
            f"  repeat {i + 1}/{repeats} (other processes: {other:.2f} cores): "
            + ", ".join(
                f"{k} {s['python_over_floor'][-1]:.3f} / {s['new_over_python'][-1]:.3f}"
                for k, s in samples.items()
            ),
            flush=True,
        )
    return samples


def _main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--child", nargs=2, metavar=("VARIANT", "RECORDED"), help=argparse.SUPPRESS)
    parser.add_argument("--runs", type=int, default=3, help="full sets of counts (default 3)")
    parser.add_argument("--jobs", type=int, default=2, help="callgrind processes at a time")
    parser.add_argument("--keep", type=Path, help="keep the callgrind files in this folder")
    parser.add_argument("--controllers", nargs="+", default=list(CONTROLLERS))
    parser.add_argument(
        "--check-cpu", action="store_true", help="CPU-time ratios of the full and short episodes"
    )
    parser.add_argument("--repeats", type=int, default=15, help="repeats of --check-cpu")
    parser.add_argument(
        "--cache-sim",
        action="store_true",
        help="also simulate this machine's caches and branch predictor (slower): the misses",
    )
    args = parser.parse_args(argv)
    if args.child:
        _child(args.child[0], Path(args.child[1]))
        return 0
    print(f"load average {os.getloadavg()} on {os.cpu_count()} cores", flush=True)
    if args.check_cpu:
        samples = check_cpu(args.controllers, args.repeats)
        print("\nmedians: CPU s of floor, python, new; python/floor, new/python")
        for key, s in samples.items():
            m = {name: statistics.median(values) for name, values in s.items()}
            print(
                f"  {key:<16} {m['floor']:.3f} {m['python']:.3f} {m['new']:.3f}  "
                f"{m['python_over_floor']:.3f}  {m['new_over_python']:.3f}"
            )
        return 0
    runs = []
    for r in range(args.runs):
        keep = None if args.keep is None else args.keep / f"run{r + 1}"
        start = time.perf_counter()
        counts = count_all(args.controllers, jobs=args.jobs, keep=keep, cache_sim=args.cache_sim)
        runs.append(counts)
        print(f"run {r + 1} ({time.perf_counter() - start:.0f} s, load {os.getloadavg()}):")
        for c, row in counts.items():
            q = ratios(row)
            floor, python, new = (row[v]["Ir"] for v in VARIANTS)
            print(
                f"  {c:<10} floor {floor:>14,d}  python {python:>14,d}  new {new:>14,d}  "
                f"python/floor {q['python_over_floor_instr']:.4f}  "
                f"new/python {q['new_over_python_instr']:.4f}",
                flush=True,
            )
            if args.cache_sim:
                print("\n".join(misses(row)), flush=True)
    if len(runs) > 1:
        print("spread over the runs (max / min - 1):")
        for c in args.controllers:
            for v in VARIANTS:
                values = [run[c][v]["Ir"] for run in runs]
                print(f"  {c:<10} {v:<7} {100 * (max(values) / min(values) - 1):.4f} %")
    return 0


if __name__ == "__main__":
    sys.exit(_main())
