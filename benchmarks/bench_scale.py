#!/usr/bin/env python3
"""The benchmark card at scale: ``doorlab bench`` on a Dask LocalCluster, its throughput, and
whether its card is a local run's.

Usage::

    python benchmarks/bench_scale.py --episodes 200 [--workers 2] [--seed 0]
        [--local DIR] [--out-dir DIR] [--out FILE.json]

Starts a ``distributed.LocalCluster`` (``--workers`` processes, one thread each, on loopback),
runs ``doorlab bench --episodes N --seed S --scheduler ADDRESS`` over every built-in into
``--out-dir`` (default a folder under the system's temporary directory), and records: the
wall time, episodes per second per core (episodes / wall time / workers), the median
seconds of one worker per episode per controller, the card's rates with their intervals; with
``--local DIR`` (a local run's folder, ``doorlab bench --episodes N --seed S --out DIR``),
whether the two ``bench.json`` are the same but for ``cost`` and ``machine`` (they must be:
the same episodes). The cluster's start is not timed. ``busy_cores``: the cores the whole
machine kept busy meanwhile (from /proc/stat); above ``--workers`` other processes competed.

``--compare A B`` runs nothing: it compares two benchmark folders already written (say a local
run and a cluster's, each perhaps completed by ``--resume``) the same way, and records both
cards' rates and costs.

``--table CARD`` runs nothing: it prints a card's table in Markdown (a ``bench.json``, or a copy
of one such as ``results/bench_card_200.json``): per controller its successes with the Wilson
95 % interval, robosuite's rate, the failures by kind, the median time to open and the median
CPU seconds of an episode. docs/guides/bench.md shows it (``docs/tools/make_figures.py
bench_200``).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
import tempfile
import time
from pathlib import Path

from common import cpu_times, machine

BENCH_DIR = Path(__file__).resolve().parent
RESULTS_DIR = BENCH_DIR / "results"


def _results(folder: Path) -> dict:
    document = json.loads((folder / "bench.json").read_text())
    return {k: v for k, v in document.items() if k not in ("cost", "machine")}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=200, help="per controller (200)")
    parser.add_argument("--workers", type=int, default=2, help="the cluster's processes (2)")
    parser.add_argument("--seed", type=int, default=0, help="the cupboards' seed (0)")
    parser.add_argument("--local", type=Path, default=None, help="a local run's folder")
    parser.add_argument("--out-dir", type=Path, default=None, help="the card's folder")
    parser.add_argument("--out", type=Path, default=None, help="JSON file to write")
    parser.add_argument(
        "--compare", nargs=2, type=Path, metavar=("A", "B"), help="compare two folders, run nothing"
    )
    parser.add_argument(
        "--table", type=Path, default=None, help="print a card's table, run nothing"
    )
    args = parser.parse_args(argv)
    if args.table:
        print(table(json.loads(args.table.read_text())), end="")
        return 0
    if args.compare:
        return compare(*args.compare, args.out)

    from distributed import LocalCluster

    from doorlab.cli.parser import main as doorlab

    folder = args.out_dir or Path(tempfile.mkdtemp(prefix="doorlab_bench_scale_")) / "card"
    with LocalCluster(
        n_workers=args.workers,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=None,
        silence_logs=40,
    ) as cluster:
        before = cpu_times()
        start = time.perf_counter()
        code = doorlab(
            ["bench", "--episodes", str(args.episodes), "--seed", str(args.seed), "--out",
             str(folder), "--scheduler", cluster.scheduler_address]
        )  # fmt: skip
        wall = time.perf_counter() - start
        after = cpu_times()
    busy = None
    if before and after:
        busy = (after[0] - before[0]) / max(after[1] - before[1], 1.0) * (os.cpu_count() or 1)
    document = json.loads((folder / "bench.json").read_text())
    episodes = sum(c["episodes"] for c in document["controllers"].values())
    same = None
    if args.local is not None:
        same = _results(folder) == _results(args.local)
    summary = {
        "exit_code": code,
        "folder": str(folder),
        "episodes": episodes,
        "wall_s": wall,
        "episodes_per_s_per_core": episodes / wall / args.workers,
        "seconds_per_episode": document["cost"]["seconds_per_episode"],
        "busy_cores": busy,
        "rates": {
            name: {
                "success_rate": c["success_rate"],
                "ci95": c["ci95"],
                "robosuite": c["robosuite"]["success_rate"],
                "failures": c["failures"],
            }
            for name, c in document["controllers"].items()
        },
        "same_card_as_local": same,
        "local": str(args.local) if args.local else None,
    }
    print(json.dumps(summary, indent=2))
    out = args.out or RESULTS_DIR / (
        f"bench-scale-{datetime.datetime.now().strftime('%Y%m%d-%H%M%S')}.json"
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(
        json.dumps(
            {
                "machine": machine(),
                "settings": {
                    k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()
                },
                "summary": summary,
            },
            indent=2,
        )
        + "\n"
    )
    print(f"written to {out}")
    return 0 if code == 0 and same is not False else 1


def _percent(rate: float) -> str:
    return f"{100 * rate:.1f} %"


def table(document: dict) -> str:
    """A card's table in Markdown: a row per controller, in the card's order."""
    lines = [
        "| controller | success [95 % interval] | robosuite's | slip / stop / short "
        "| median time to open | median CPU per episode |",
        "|---|---|---|---|---|---|",
    ]
    cost = document["cost"]["seconds_per_episode"]
    for name, card in document["controllers"].items():
        low, high = card["ci95"]
        failures = card["failures"]
        to_open = card["metrics"]["time_to_open_s"]["q50"]
        cpu = cost.get(name, {}).get("cpu", {}).get("median")
        lines.append(
            f"| `{name}` | {card['successes']} / {card['episodes']}, "
            f"{_percent(card['success_rate'])} [{100 * low:.1f}, {100 * high:.1f}] "
            f"| {_percent(card['robosuite']['success_rate'])} "
            f"| {failures['slip']} / {failures['stop']} / {failures['short']} "
            f"| {'-' if to_open is None else f'{to_open:.1f} s'} "
            f"| {'-' if cpu is None else f'{cpu:.1f} s'} |"
        )
    return "\n".join(lines) + "\n"


def compare(a: Path, b: Path, out: Path | None) -> int:
    """Whether two benchmark folders hold the same card but for ``cost`` and ``machine``."""
    documents = [json.loads((folder / "bench.json").read_text()) for folder in (a, b)]
    same = _results(a) == _results(b)
    summary = {
        "same_card": same,
        "folders": [str(a), str(b)],
        "episodes": [d["bench"]["episodes"] for d in documents],
        "rates": {
            name: {
                "successes": c["successes"],
                "episodes": c["episodes"],
                "success_rate": c["success_rate"],
                "ci95": c["ci95"],
                "robosuite": c["robosuite"],
                "failures": c["failures"],
            }
            for name, c in documents[0]["controllers"].items()
        },
        "cost": [d["cost"] for d in documents],
    }
    print(json.dumps({k: v for k, v in summary.items() if k != "cost"}, indent=2))
    out = out or RESULTS_DIR / (
        f"bench-compare-{datetime.datetime.now().strftime('%Y%m%d-%H%M%S')}.json"
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(summary, indent=2) + "\n")
    print(f"written to {out}")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
