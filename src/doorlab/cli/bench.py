"""``doorlab bench``: its options and what it does (:mod:`doorlab.bench`)."""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from pathlib import Path

from doorlab.errors import ConfigError, interrupt_exit_code
from doorlab.runtime.argtypes import bounded_int


def add_bench_parser(sub, scheduler, common) -> None:
    """``doorlab bench [--controller NAME ...] --episodes N --seed S --out DIR``."""
    from doorlab.config import CONTROLLERS

    bench = sub.add_parser(
        "bench",
        help="the benchmark card: each controller over the same N cupboards drawn from a "
        "stated distribution; success rates with their 95 %% intervals, the metrics' "
        "distributions (bench.json, index.html)",
    )
    bench.add_argument(
        "--controller",
        action="append",
        default=[],
        metavar="NAME",
        help=f"a controller to bench (repeatable; default: every built-in, "
        f"{', '.join(CONTROLLERS)}): a built-in, an installed plug-in's name, FILE.py:NAME "
        "or MODULE:NAME",
    )
    bench.add_argument(
        "--episodes",
        type=bounded_int(1, 100_000),
        default=100,
        metavar="N",
        help="cupboards per controller (default 100; each is an episode of seconds)",
    )
    bench.add_argument(
        "--seed",
        type=bounded_int(0, 2**63 - 1),
        default=0,
        metavar="S",
        help="the cupboards' random seed (default 0): episode i's cupboard depends on S and i only",
    )
    bench.add_argument(
        "--distribution",
        type=Path,
        default=None,
        metavar="FILE.yaml",
        help="what each episode draws (yaw and position error, hinge damping, friction, grasp "
        "offset; see docs/guides/bench.md; default: the built-in distribution)",
    )
    bench.add_argument(
        "--out",
        type=Path,
        default=Path("doorlab_bench"),
        help="output folder (default: doorlab_bench)",
    )
    bench.add_argument(
        "--jobs",
        type=bounded_int(1),
        default=None,
        help="local worker processes (default: the number of cores)",
    )
    scheduler(bench)
    bench.add_argument(
        "--resume", action="store_true", help="keep the episodes already in --out's table"
    )
    common(bench)


def bench(args: argparse.Namespace) -> int:
    """``doorlab bench``; returns the exit code: 0, 1 if an episode failed in doorlab's
    worker (status error), 2 if a plug-in raised or sent no valid command in an episode."""
    from doorlab.bench.distribution import load_distribution
    from doorlab.cli.commands import (
        _probe,
        apply_overrides,
        controller_option,
        require_sweep_extra,
    )
    from doorlab.config import load_scenario

    if args.resume and args.force:
        raise ConfigError("--resume and --force exclude each other")
    from doorlab.bench.runner import bench_base, controller_names

    defaults = bench_base()
    base = load_scenario(args.config, defaults=defaults) if args.config else defaults
    base = apply_overrides(base, args.overrides)
    distribution = load_distribution(args.distribution)
    controllers = [controller_option(c) for c in args.controller]
    controller_names(controllers or _builtins())  # plug-ins loaded now: one line, exit 2
    require_sweep_extra("doorlab bench", ("pandas", "pyarrow"))
    jobs = args.jobs or os.cpu_count() or 1
    command = _reproduce(args, controllers)
    try:
        _probe(args)
        from doorlab.bench.runner import run_bench

        result = run_bench(
            controllers or None,
            args.out,
            episodes=args.episodes,
            seed=args.seed,
            base=base,
            distribution=distribution,
            jobs=jobs,
            scheduler=args.scheduler,
            scheduler_timeout_s=args.scheduler_timeout,
            resume=args.resume,
            force=args.force,
            progress=True,
            command=command,
        )
    except KeyboardInterrupt as e:
        print(f"doorlab bench: interrupted; {_left(args.out)}", file=sys.stderr)
        return interrupt_exit_code(e)
    return _report(result, args.out)


def _builtins() -> list[str]:
    from doorlab.config import CONTROLLERS

    return list(CONTROLLERS)


def _reproduce(args: argparse.Namespace, controllers: list[str]) -> str:
    """The command line that draws the same card: what sets its numbers (not --out, --jobs,
    --scheduler or --resume, which do not)."""
    words = ["doorlab", "bench"]
    for spec in controllers:
        words += ["--controller", spec]
    words += ["--episodes", str(args.episodes), "--seed", str(args.seed)]
    if args.distribution is not None:
        words += ["--distribution", str(args.distribution)]
    if args.config is not None:
        words += ["--config", str(args.config)]
    for item in args.overrides:
        words += ["--set", item]
    return shlex.join(words)


def _report(result, out: Path) -> int:
    """Prints each controller's line; the exit code."""
    document = result.document
    for name, s in document["controllers"].items():
        low, high = s["ci95"]
        r = s["robosuite"]
        kinds = ", ".join(f"{n} {k}" for k, n in s["failures"].items() if n)
        print(
            f"  {name:<14} {s['successes']:>4}/{s['episodes']:<4} {100 * s['success_rate']:5.1f} % "
            f"[{100 * low:.1f}, {100 * high:.1f}]   robosuite {100 * r['success_rate']:5.1f} % "
            f"[{100 * r['ci95'][0]:.1f}, {100 * r['ci95'][1]:.1f}]"
            + (f"   failures: {kinds}" if kinds else "")
        )
    cost = document["cost"]
    print(
        f"doorlab bench: {len(result.frame)} episodes in {out} ({cost['episodes_run']} run now "
        f"on {cost['executor']}, {cost['wall_time_s']:.0f} s); card: {out / 'index.html'}, "
        f"numbers: {out / 'bench.json'}"
    )
    statuses = result.frame["status"]
    broken = result.frame[statuses == "controller_error"]
    if len(broken):  # a broken plug-in: its first error, one line
        first = broken.iloc[0]
        print(
            f"doorlab bench: error: {len(broken)} episodes of {first['controller']} ended "
            f"controller_error; the first: {first['error']}",
            file=sys.stderr,
        )
        return 2
    return 1 if (statuses == "error").any() else 0


def _left(out: Path) -> str:
    """What an interrupted benchmark left in ``out``."""
    from doorlab.cli.commands import _sweep_left

    return _sweep_left(out).replace("runs", "episodes")
