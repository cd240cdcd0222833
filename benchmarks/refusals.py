#!/usr/bin/env python3
"""How fast and how small doorlab's refusals of hostile input are (issue 19).

Runs each case of the issue's lists that ends in a refusal as a user would (the ``doorlab``
command in a subprocess, through tests/cli_harness.py: peak RSS from ``os.wait4`` in a small
launcher, so it is the child's own), ``--repeats`` times, and prints per case the exit code,
the median wall time (interpreter start and imports included), the largest peak RSS and the
stderr size. The acceptance bounds are 5 s (a scheduler: its timeout + 5 s), 300 MB, 10 kB.

Usage::

    python benchmarks/refusals.py [--repeats N]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from cli_harness import run_doorlab  # noqa: E402
from test_hangs import billion_laughs, long_value_bomb, tcp_server  # noqa: E402


def cases(work: Path, home: Path) -> list[tuple[str, list[str]]]:
    bomb, value_bomb = billion_laughs(9, 9), long_value_bomb()
    (work / "bomb.yaml").write_text(bomb)
    (work / "value_bomb.yaml").write_text(value_bomb)
    (work / "deep.yaml").write_text("station: " + "[" * 100_000 + "]" * 100_000 + "\n")
    for exponent in (7, 8, 12):
        per_axis = 10 ** (exponent // 2)
        (work / f"grid{exponent}.yaml").write_text(
            "controllers: [impedance]\ndoors: [closed]\naxes:\n"
            f"  impedance.kv: {{low: 1, high: 100, num: {per_axis}}}\n"
            f"  impedance.kw: {{low: 1, high: 100, num: {10**exponent // per_axis}}}\n"
        )
    (work / "v").mkdir(exist_ok=True)
    (work / "v" / "p.txt").write_text("precious\n")
    return [
        (f"config: alias bomb ({len(bomb)} B, 9^9 values)", ["run", "--config", "bomb.yaml"]),
        (f"config: value bomb ({len(value_bomb)} B)", ["run", "--config", "value_bomb.yaml"]),
        ("config: 100,000 levels deep", ["run", "--config", "deep.yaml"]),
        ("config: /dev/zero", ["run", "--config", os.path.realpath("/dev/zero")]),
        ("config: a folder", ["run", "--config", str(home)]),
        ("sweep: 10^7 runs", ["sweep", "grid7.yaml"]),
        ("sweep: 10^8 runs", ["sweep", "grid8.yaml"]),
        ("sweep: 10^12 runs", ["sweep", "grid12.yaml"]),
        ("--set extra_time=1.0e+300", ["run", "--set", "timeline.extra_time=1.0e+300"]),
        ("--set log_period=1000.0", ["run", "--set", "timeline.log_period=1000.0"]),
        ("--set with a newline", ["run", "--set", "station.time_step=0.002\ncontroller: ik"]),
        ("--realtime 1e-9", ["run", "--realtime", "1e-9"]),
        ("run --out v --force (a user's file)", ["run", "--out", "v", "--force"]),
        ("run --out / --force", ["run", "--out", "/", "--force"]),
        ("run --out ~ --force", ["run", "--out", str(home), "--force"]),
        (
            "--scheduler tcp://127.0.0.1:99999999",
            ["sweep", "--grid", "impedance.kv=1", "--scheduler", "tcp://127.0.0.1:99999999"],
        ),
    ]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--scheduler-timeout", type=float, default=10.0)
    args = parser.parse_args(argv)
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        home, work = Path(tmp) / "home", Path(tmp) / "work"
        home.mkdir()
        work.mkdir()
        (home / ".bashrc").write_text("\n")
        todo = cases(work, home)
        for kind in ("silent", "garbage"):
            todo.append((f"--scheduler: a {kind} server", kind))
        print(
            f"{'case':44s} {'exit':>4s} {'wall [s]':>9s} {'peak RSS [MB]':>14s} {'stderr [B]':>10s}"
        )
        for name, command in todo:
            walls, peaks, codes, sizes = [], [], set(), set()
            for _ in range(args.repeats):
                if isinstance(command, str):
                    with tcp_server(command) as address:
                        outcome = run_doorlab(
                            [
                                "sweep",
                                "--grid",
                                "impedance.kv=1",
                                "--scheduler",
                                address,
                                "--scheduler-timeout",
                                str(args.scheduler_timeout),
                            ],
                            cwd=work,
                            home=home,
                        )
                else:
                    outcome = run_doorlab(command, cwd=work, home=home)
                walls.append(outcome.wall_s)
                peaks.append(outcome.peak_rss_mb)
                codes.add(outcome.code)
                sizes.add(len(outcome.stderr.encode()))
            print(
                f"{name:44s} {','.join(map(str, sorted(codes))):>4s} "
                f"{statistics.median(walls):9.2f} {max(peaks):14.0f} {max(sizes):10d}"
            )
    print(
        f"load average (1 min) {load:.2f} before, {os.getloadavg()[0]:.2f} after, "
        f"{os.cpu_count()} cores; scheduler timeout {args.scheduler_timeout:g} s"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
