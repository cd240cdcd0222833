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
    arc, the plan built by ``doorlab.episode.controllers.build_*_plan`` (target < 100 us).
``ik/<n>_knots``
    ``pointwise_ik`` along the arc with n = 2, 5, 10 knots, as task 1 builds it (target for
    10 knots < 0.1 s).
``run/<controller>``, ``run/report``, ``run/report_full``
    ``python -m doorlab.cli run --controller C --doors closed`` end to end in a subprocess
    (interpreter start, imports, episode, metrics, PNG plots, replay.html; target for
    velocity < 4 s), the default ``doorlab report --jobs 2`` (the problem set's 8 runs and
    diffik's and osc's 4; target < 15 s, set for the 8) and ``doorlab report --jobs 2
    --robustness`` (with the robustness section's runs);
    ``info.cpu_s`` is the CPU time of the whole process tree.
``design/<controller>_closed``
    The episode against Drake's floor (the same cell, the recorded commands replayed from
    C++), against the same machinery with no law (the Python runner replaying the commands)
    and against the 353b732 design, side by side (``benchmarks/designs.py``).
``instr/velocity_closed``, ``instr/impedance_closed``
    The same three simulations (floor, python, new) counted in instructions by callgrind on a
    short episode with the same phases (``benchmarks/instructions.py``): metrics
    ``design/<controller>_closed/python_over_floor_instr`` (target <= 1.2),
    ``.../new_over_python_instr`` (<= 1.1), the counts themselves; one count per run (they are
    deterministic). Needs valgrind; ~3 min on 2 cores.
``memory/episode``
    Peak resident set size of a fresh process that runs one velocity/closed episode, and of
    one that only imports doorlab: VmHWM read by the child from /proc/self/status (NOT
    ``ru_maxrss`` via RUSAGE_CHILDREN, which Linux seeds with the parent's peak at fork).
``profile/episode``
    Where the time of one velocity/closed episode goes: Python control ticks, the rest of the
    advance (the C++ plant steps), and setup/teardown. Measured with a timer around
    ``PlanRunner._tick`` (unbiased), then once more under cProfile for the top lines, then
    once more timing each velocity command and its repeat at once (cold and warm caches).

The command line, selection, output and comparison live here; the benchmark groups in
``micro.py`` (tick, ik), ``episodes.py``, ``designs.py``, ``instructions.py``, ``processes.py``
(run, memory) and ``profiling.py``; what they share in ``common.py``.

Every number is the MEDIAN over the repeats, with min and max. Targets are printed as pass/fail
but never change the exit code: 0 when the benchmarks ran (targets missed or not), 1 when a
benchmark itself crashed, 2 on bad arguments (one line on stderr).
"""

from __future__ import annotations

import argparse
import datetime
import fnmatch
import json
import math
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from common import (
    BENCHMARK_ERROR,
    CONTROLLERS,
    DEFAULT_REPEATS,
    DOORS,
    IK_KNOTS,
    QUICK_SUBSET,
    QUICK_TICK_CALLS,
    REGRESSION_THRESHOLD,
    REPO_DIR,
    RESULTS_DIR,
    SCHEMA,
    TICK_CALLS,
    Context,
    CpuWatch,
    Metric,
    Settings,
)
from episodes import bench_episodes
from micro import bench_ik, bench_tick
from processes import bench_memory, bench_runs
from profiling import bench_profile

# ---------------------------------------------------------------------------------------------
# Registry and selection.

EPISODES = tuple(f"episode/{c}_{d}" for c in CONTROLLERS for d in DOORS)
TICKS = ("tick/velocity", "tick/impedance", "tick/adaptive")
IKS = tuple(f"ik/{n}_knots" for n in IK_KNOTS)
RUNS = (*(f"run/{c}" for c in CONTROLLERS), "run/report", "run/report_full")
DESIGNS = tuple(f"design/{c}_closed" for c in CONTROLLERS)
INSTRUCTIONS = ("instr/velocity_closed", "instr/impedance_closed")
ALL = (*TICKS, *IKS, *EPISODES, *DESIGNS, *INSTRUCTIONS, *RUNS, "memory/episode", "profile/episode")
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
            lambda: bench_designs(designs, settings, ctx),
        )
    counted = [n for n in selected if n.startswith("instr/")]
    if counted:
        from instructions import bench_instructions

        attempt("instr/*", lambda: bench_instructions(counted, settings, ctx))
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
    # the CLI's one-line errors, exit 2
    from doorlab.runtime.argtypes import OneLineParser, bounded_int

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
            ("(b) rest of the advance (C++ plant steps)", "plant_step_s"),
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
            print(
                f"  the same command repeated at once in a tick: "
                f"{split['velocity_command_first_median_us']:.0f} us, then "
                f"{split['velocity_command_repeat_median_us']:.0f} us (warm caches)"
            )
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
