#!/usr/bin/env python3
"""What ``doorlab report`` costs, in ``doorlab run``s: both timed in one run, side by side.

Per repeat, back to back: ``doorlab run`` (the README's run: velocity, doors closed, every
output) and the default ``doorlab report --jobs J``; then, once each, the report with each
section a user can ask for (``--robustness``, ``--arm --no-arm-band``, ``--arm``). Every command
is the installed CLI in a subprocess (interpreter start and imports included), with its own
output folder in a temporary directory. Reported: wall time (median of the repeats), the CPU
time of the process tree, the episodes each report ran (its run folders), the other processes'
load meanwhile, and each report's time as a number of ``doorlab run``s (its wall time over the
runs' median) against the budget, :data:`BUDGET_RUNS` (issue 42).

The results go to ``benchmarks/results/report_time.json``; :func:`block` writes what the pages
quote of them (``python docs/tools/make_figures.py report_time`` runs this benchmark and puts
the blocks into the pages' measured regions).

Usage::

    python benchmarks/report_time.py [--repeats 2] [--jobs 2] [--no-sections]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BENCH_DIR = Path(__file__).resolve().parent
REPO_DIR = BENCH_DIR.parent
RESULTS = BENCH_DIR / "results" / "report_time.json"
BUDGET_RUNS = 14.0
"""The default report's budget: at most this many ``doorlab run``s of wall time (issue 42)."""
SECTIONS = {
    "robustness": (["--robustness"], "the robustness section: every controller, 5 yaw errors"),
    "arm_preset": (
        ["--arm", "--no-arm-band"],
        '"On the arm" on the arm preset only (no band)',
    ),
    "arm": (["--arm"], '"On the arm" with the band of arm models: the verdicts'),
}
"""The sections a user asks for: the report's flags and what they add."""


def cli(*args: str) -> list[str]:
    """The command line of ``doorlab ARGS`` in this Python."""
    return [sys.executable, "-m", "doorlab.cli", *args]


def _children_cpu_s() -> float:
    import resource

    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def timed(command: list[str], cwd: Path) -> dict:
    """Runs ``command`` in ``cwd``: wall and CPU time, exit code, the other processes' load."""
    sys.path.insert(0, str(BENCH_DIR))
    from common import CpuWatch, subprocess_env

    watch = CpuWatch()
    cpu = _children_cpu_s()
    start = time.perf_counter()
    proc = subprocess.run(command, cwd=cwd, env=subprocess_env(), capture_output=True, text=True)
    wall = time.perf_counter() - start
    if proc.returncode not in (0, 1):  # 1: a report with a run not ok is still a report
        last = (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise RuntimeError(f"{' '.join(command[2:])} exited {proc.returncode}: {last}")
    return {
        "wall_s": wall,
        "cpu_s": _children_cpu_s() - cpu,
        "exit_code": proc.returncode,
        "other_cores": watch.other_cores(),
    }


def _episodes(report_dir: Path) -> int:
    return sum(1 for p in (report_dir / "runs").iterdir() if p.is_dir())


def measure(repeats: int, jobs: int, sections: bool) -> dict:
    """Runs the commands and returns the results (see the module docstring)."""
    runs, reports = [], []
    with tempfile.TemporaryDirectory(prefix="doorlab_report_time_") as tmp:
        work = Path(tmp)
        for k in range(repeats):
            run = timed(cli("run", "--out", f"run{k}"), work)
            runs.append(run)
            print(f"  doorlab run: {run['wall_s']:.1f} s", flush=True)
            report = timed(cli("report", "--jobs", str(jobs), "--out", f"report{k}"), work)
            report["episodes"] = _episodes(work / f"report{k}")
            reports.append(report)
            print(f"  doorlab report: {report['wall_s']:.1f} s", flush=True)
        run_median = statistics.median(r["wall_s"] for r in runs)
        report_median = statistics.median(r["wall_s"] for r in reports)
        results: dict = {
            "schema": "doorlab-report-time/1",
            "created": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
            "machine": _machine(),
            "jobs": jobs,
            "budget_runs": BUDGET_RUNS,
            "run": {
                "command": "doorlab run",
                "samples": runs,
                "median_s": run_median,
            },
            "report": {
                "command": f"doorlab report --jobs {jobs}",
                "samples": reports,
                "median_s": report_median,
                "episodes": reports[0]["episodes"],
                "runs_of_time": report_median / run_median,
                "within_budget": report_median / run_median <= BUDGET_RUNS,
            },
            "sections": {},
        }
        if sections:
            for name, (flags, what) in SECTIONS.items():
                out = f"report_{name}"
                sample = timed(cli("report", "--jobs", str(jobs), "--out", out, *flags), work)
                episodes = _episodes(work / out)
                results["sections"][name] = {
                    "command": f"doorlab report --jobs {jobs} {' '.join(flags)}",
                    "what": what,
                    **sample,
                    "episodes": episodes,
                    "extra_episodes": episodes - results["report"]["episodes"],
                    "extra_s": sample["wall_s"] - report_median,
                    "runs_of_time": sample["wall_s"] / run_median,
                }
                if name == "arm":
                    summary = json.loads((work / out / "summary.json").read_text())
                    results["sections"][name]["verdicts"] = summary.get("on_the_arm_verdicts")
                print(f"  {results['sections'][name]['command']}: {sample['wall_s']:.1f} s")
    return results


def _machine() -> dict:
    sys.path.insert(0, str(BENCH_DIR))
    from run_benchmarks import machine_info

    info = machine_info()
    info.pop("hostname", None)
    try:
        info["loadavg"] = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        pass
    return info


# What the pages quote ------------------------------------------------------------------------


def _s(value: float) -> str:
    return f"{value:.0f}" if value >= 10 else f"{value:.1f}"


def _load(results: dict) -> str:
    samples = [s for s in results["run"]["samples"] + results["report"]["samples"]]
    samples += list(results["sections"].values())
    loads = [s["other_cores"] for s in samples if s.get("other_cores") is not None]
    return f"{statistics.mean(loads):.1f}" if loads else "unknown"


def _measured(results: dict) -> str:
    m = results["machine"]
    return (
        f"measured by `python benchmarks/report_time.py` "
        f"(`benchmarks/results/report_time.json`: {m['cores']} cores, drake {m['drake']}, "
        f"commit {m.get('git_commit') or 'unknown'}, {results['created'][:10]}; other processes "
        f"used {_load(results)} cores meanwhile on average)"
    )


def block(name: str, results: dict) -> str:
    """The Markdown of what the pages quote (``summary``, ``table``, ``arm``)."""
    run, report = results["run"], results["report"]
    budget = results["budget_runs"]
    if name == "summary":
        return (
            f"The default report ran {report['episodes']} episodes in {_s(report['median_s'])} s, "
            f"{report['runs_of_time']:.1f} times a `doorlab run` ({_s(run['median_s'])} s; its "
            f'budget is {budget:g}); the robustness and "On the arm" sections run when asked '
            f"for ([what each costs](guides/experiments.md#what-each-section-costs)), "
            f"{_measured(results)}."
        )
    if name == "arm":
        arm = results["sections"].get("arm")
        if arm is None:
            return "Not measured yet: `python docs/tools/make_figures.py report_time`."
        text = (
            f"`doorlab report --arm` ran {arm['episodes']} episodes "
            f"({arm['extra_episodes']} more than the default report's {report['episodes']}) in "
            f"{_s(arm['wall_s'])} s on {results['jobs']} workers, {arm['runs_of_time']:.0f} "
            f"times a `doorlab run`; `--arm --no-arm-band` "
            f"{results['sections']['arm_preset']['extra_episodes']} more in "
            f"{_s(results['sections']['arm_preset']['wall_s'])} s; {_measured(results)}."
        )
        return text + "\n\n" + _verdicts_table(arm.get("verdicts") or [])
    rows = [
        "| `doorlab report` | what it runs | episodes | wall time [s] | CPU time [s] "
        "| in `doorlab run`s |",
        "|---|---|---|---|---|---|",
        f"| (default) | the problem set's experiments, diffik's and osc's, the page | "
        f"{report['episodes']} | {_s(report['median_s'])} | "
        f"{_s(statistics.median(s['cpu_s'] for s in report['samples']))} | "
        f"{report['runs_of_time']:.1f} |",
    ]
    for section in results["sections"].values():
        flags = section["command"].split(f"--jobs {results['jobs']} ", 1)[1]
        rows.append(
            f"| `{flags}` | also {section['what']} | {section['episodes']} "
            f"(+{section['extra_episodes']}) | {_s(section['wall_s'])} | {_s(section['cpu_s'])} "
            f"| {section['runs_of_time']:.1f} |"
        )
    return "\n".join(rows) + (
        f"\n\nOne `doorlab run` (velocity, doors closed, every output): {_s(run['median_s'])} s "
        f"(median of {len(run['samples'])}; CPU "
        f"{statistics.median(s['cpu_s'] for s in run['samples']):.1f} s); the default report is "
        f"{'within' if report['within_budget'] else 'OVER'} its budget of {budget:g} runs. "
        f"Reports on `--jobs {results['jobs']}`, {_measured(results)}."
    )


VERDICTS = {
    "opens": "opens under every plausible model",
    "does_not_open": "does not open under any plausible model",
    "uncertain": "uncertain",
}
OUTCOMES = {
    "opens": "opens",
    "falls_short": "keeps the handle short of open",
    "loses_the_handle": "loses the handle",
    "stopped": "stopped",
}


def _verdicts_table(verdicts: list[dict]) -> str:
    """The band's verdict per plan, as that run gave it (summary.json's on_the_arm_verdicts)."""
    if not verdicts:
        return ""
    from doorlab.report.experiments import ARM_PARAMETERS

    rows = [
        "| plan | verdict | depends on | on the nominal arm | door at the arc's end [deg] |",
        "|---|---|---|---|---|",
    ]
    for v in verdicts:
        plan = v["controller"] + (f", `{v['tuning']}`" if v.get("tuned") else "")
        verdict = VERDICTS.get(v["verdict"], v["verdict"])
        if v["verdict"] == "uncertain" and "opens" not in v["outcomes"]:
            verdict = "does not open under any plausible model; what it does instead, uncertain"
        doors = [d for d in v["door_arc_end_deg"] if d is not None]
        span = f"{min(doors):.1f}-{max(doors):.1f}" if doors else "n/a"
        depends = ", ".join(ARM_PARAMETERS[p] for p in v["depends_on"]) or "-"
        nominal = OUTCOMES.get(v["outcomes"][0], v["outcomes"][0])
        rows.append(f"| {plan} | {verdict} | {depends} | {nominal} | {span} |")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=2, help="run/report pairs (default 2)")
    parser.add_argument("--jobs", type=int, default=2, help="the reports' --jobs (default 2)")
    parser.add_argument(
        "--no-sections", action="store_true", help="only the default report (not each section)"
    )
    parser.add_argument("--out", type=Path, default=RESULTS, help=f"default: {RESULTS}")
    args = parser.parse_args(argv)
    if args.repeats < 1 or args.jobs < 1:
        parser.error("--repeats and --jobs must be >= 1")
    results = measure(args.repeats, args.jobs, not args.no_sections)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1) + "\n")
    print(f"wrote {args.out}")
    report = results["report"]
    print(
        f"doorlab run {results['run']['median_s']:.1f} s; doorlab report {report['median_s']:.1f} "
        f"s = {report['runs_of_time']:.1f} runs (budget {results['budget_runs']:g}): "
        f"{'within' if report['within_budget'] else 'OVER'}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
