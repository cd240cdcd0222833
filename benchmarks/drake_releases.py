#!/usr/bin/env python3
"""The same results on every supported Drake (issue 45): 1.51.1 and the newest side by side.

Two steps, each Drake in its own venv (1.51.1 on Python 3.11, 1.58 on 3.12)::

    python benchmarks/drake_releases.py measure \
        --out benchmarks/results/drake_releases_1.51.1.json
    .venv312/bin/python benchmarks/drake_releases.py measure \
        --out benchmarks/results/drake_releases_1.58.0.json
    python benchmarks/drake_releases.py table benchmarks/results/drake_releases_1.51.1.json \
        benchmarks/results/drake_releases_1.58.0.json \
        [--instr benchmarks/results/instr_drake_1.51.1.json \
                 benchmarks/results/instr_drake_1.58.0.json] \
        [--out benchmarks/results/drake_releases.md]

(the ``--instr`` files: ``run_benchmarks.py --only instr --out FILE`` in each venv).

``measure`` runs, in this interpreter's Drake: the problem set's eight runs
(``doorlab.report.experiments.EXPERIMENTS``) and the arm preset's four plans
(``examples/kuka_arm.yaml``, doors closed, as ``benchmarks/kuka_arm.py``), keeping per run the
door at the arc's end, Q's radial error (max, RMS), L7's orientation error (max), the peak
contact torque in the arc and whether the handle is held; then it grades the answer key and
each catalogued mistake (``tests/test_pset_batch.py``'s ``MISTAKES``, planted alone over the
stubs) and keeps every test's score. ``table`` writes the side-by-side table with each
difference against its tolerance (:data:`TOLERANCES`, the reasons in the fidelity page) and
the grader's verdicts; ``--instr`` adds ``run_benchmarks.py --only instr``'s counts and
ratios from each Drake. Exit 1 from ``table`` when a difference exceeds its tolerance or a
verdict differs.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import tempfile
import time
from pathlib import Path

BENCH_DIR = Path(__file__).resolve().parent
ROOT = BENCH_DIR.parent
PRESET = ROOT / "examples" / "kuka_arm.yaml"
ARM_CONTROLLERS = ("ik", "velocity", "impedance", "adaptive")

TOLERANCES = {
    "door_arc_end_deg": 0.1,
    "max_radial_mm": 0.05,
    "rms_radial_mm": 0.05,
    "max_orientation_deg": 0.05,
    "peak_arc_contact_Nm": 0.05,
}
"""How far a figure may move between Drake releases and still be the same result (the
reasons: docs/explanation/fidelity.md, "Drake releases"): the door 0.1 deg, the precision the
report prints it with; Q's errors 0.05 mm, a twentieth of the grasp's 1 mm box, within
which the problem set's IK knots already land anywhere; L7's orientation 0.05 deg; the
contact torque 0.05 N m, a quarter of the smallest closed-door peak (the velocity plan's
0.19 N m)."""
LABELS = {
    "door_arc_end_deg": "door at the arc's end [deg]",
    "max_radial_mm": "Q radial max [mm]",
    "rms_radial_mm": "Q radial RMS [mm]",
    "max_orientation_deg": "L7 orientation max [deg]",
    "peak_arc_contact_Nm": "peak arc contact torque [N m]",
}


def _figures(metrics) -> dict:
    door = metrics.door_opening_arc_end_rad
    return {
        "status": metrics.status,
        "door_arc_end_deg": None if metrics.doors == "open" else math.degrees(door),
        "max_radial_mm": 1e3 * metrics.max_radial_error_m,
        "rms_radial_mm": 1e3 * metrics.rms_radial_error_m,
        "max_orientation_deg": math.degrees(metrics.max_orientation_error_rad),
        "peak_arc_contact_Nm": metrics.peak_external_torque_arc_Nm,
        "handle_held": metrics.handle_held,
    }


def measure_runs() -> dict[str, dict]:
    """The problem set's eight runs and the arm preset's four plans: {name: figures}."""
    from doorlab.cell.geometry import true_door_geometry
    from doorlab.config import load_scenario, validate
    from doorlab.episode.controllers import run_controller
    from doorlab.episode.metrics import compute_metrics
    from doorlab.report.experiments import EXPERIMENTS

    cases = [(name, validate(scenario)) for name, scenario in EXPERIMENTS]
    for controller in ARM_CONTROLLERS:
        scenario = load_scenario(PRESET)
        scenario.controller, scenario.doors = controller, "closed"
        cases.append((f"arm_{controller}_closed", validate(scenario)))
    out = {}
    for name, scenario in cases:
        start = time.perf_counter()
        result, _ = run_controller(scenario)
        metrics = compute_metrics(result, scenario, true_door_geometry(scenario))
        out[name] = _figures(metrics)
        print(f"  {name}: {out[name]} ({time.perf_counter() - start:.0f} s)", flush=True)
    return out


def measure_grades(jobs: int) -> dict[str, dict[str, float]]:
    """Every test's score for the answer key and each catalogued mistake: {submission: {test:
    score}}. The reference episodes are simulated once, with the key, and reused."""
    sys.path.insert(0, str(ROOT / "tests"))
    from test_pset_batch import FILES, MISTAKES, _edited

    from doorlab.pset.grading.grader import grade
    from doorlab.pset.handout.folder import init_folder

    def scores(results: dict) -> dict[str, float]:
        return {t["name"]: float(t["score"]) for t in results["tests"]}

    out = {}
    with tempfile.TemporaryDirectory(prefix="drake_releases.") as tmp:
        key = init_folder(Path(tmp) / "key", solutions=True)
        stubs = init_folder(Path(tmp) / "stubs")
        results = grade(key, jobs=jobs)
        reference = results["extra_data"]["reference"]
        out["key"] = scores(results)
        print(f"  key: {results['score']} of {results['extra_data']['max_score']}", flush=True)
        for name, (rel, edits) in MISTAKES.items():
            files = {r: (stubs / r).read_bytes() for r in FILES}
            files[rel] = _edited(key, rel, edits).encode()
            graded = grade(None, files=files, jobs=jobs, reference=reference)
            out[name] = scores(graded)
            print(f"  {name}: {graded['score']}", flush=True)
    return out


def measure(args: argparse.Namespace) -> int:
    from common import source_label

    from doorlab.runtime.drake_compat import drake_version

    record = {
        "drake": drake_version(),
        "python": platform.python_version(),
        "source": source_label(ROOT),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    if args.keep_runs and args.out.is_file():  # the runs of an earlier measure, same Drake
        earlier = json.loads(args.out.read_text())
        if (earlier["drake"], earlier["python"]) != (record["drake"], record["python"]):
            raise SystemExit(f"{args.out} was measured on another Drake or Python")
        record["runs"] = earlier["runs"]
    else:
        print(f"Drake {record['drake']}, Python {record['python']}: the runs", flush=True)
        record["runs"] = measure_runs()
        args.out.write_text(json.dumps(record, indent=1) + "\n")  # kept if grading fails
    if not args.no_grading:
        print("the grader", flush=True)
        record["grades"] = measure_grades(args.jobs)
    args.out.write_text(json.dumps(record, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


def _fmt(value, digits: int = 2) -> str:
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    return f"{value:.{digits}f}"


def runs_table(old: dict, new: dict) -> tuple[list[str], list[str]]:
    """Markdown rows of the runs (old / new per figure) and the figures over tolerance."""
    a, b = old["runs"], new["runs"]
    head = "| run | " + " | ".join(LABELS.values()) + " | handle held |"
    lines = [head, "|---" * (len(LABELS) + 2) + "|"]
    over = []
    for name in a:
        cells = []
        for key, label in LABELS.items():
            x, y = a[name][key], b.get(name, {}).get(key)
            if x is None and y is None:
                cells.append("-")
                continue
            diff = None if x is None or y is None else abs(y - x)
            flag = ""
            if diff is None or diff > TOLERANCES[key]:
                flag = " **!**"
                over.append(f"{name}: {label} {_fmt(x, 3)} -> {_fmt(y, 3)}")
            cells.append(f"{_fmt(x)} / {_fmt(y)}{flag}")
        held = a[name]["handle_held"], b.get(name, {}).get("handle_held")
        if held[0] != held[1]:
            over.append(f"{name}: handle held {held[0]} -> {held[1]}")
        cells.append(f"{_fmt(held[0])} / {_fmt(held[1])}")
        status = a[name]["status"], b.get(name, {}).get("status")
        if status[0] != status[1]:
            over.append(f"{name}: status {status[0]} -> {status[1]}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    diffs = ["| figure | largest difference | tolerance |", "|---|---|---|"]
    for key, label in LABELS.items():
        values = [
            abs(b[n][key] - a[n][key])
            for n in a
            if n in b and a[n][key] is not None and b[n][key] is not None
        ]
        diffs.append(f"| {label} | {max(values):.1e} | {TOLERANCES[key]:g} |")
    return lines + [""] + diffs, over


def grades_table(old: dict, new: dict) -> tuple[list[str], list[str]]:
    """Markdown rows of the grader's totals per submission, and the verdicts that differ."""
    a, b = old.get("grades"), new.get("grades")
    if not a or not b:
        return ["(the grader was not run on both)"], []
    lines = ["| submission | total, old / new | tests that score differently |", "|---|---|---|"]
    differ = []
    for name in a:
        tests = sorted(set(a[name]) | set(b.get(name, {})))
        changed = [t for t in tests if a[name].get(t) != b.get(name, {}).get(t)]
        differ += [f"{name}: {t} {a[name].get(t)} -> {b.get(name, {}).get(t)}" for t in changed]
        total = sum(a[name].values()), sum(b.get(name, {}).values())
        lines.append(f"| {name} | {total[0]:g} / {total[1]:g} | {', '.join(changed) or 'none'} |")
    return lines, differ


def instr_table(old_path: Path, new_path: Path, old: dict, new: dict) -> list[str]:
    """The instruction counts of ``run_benchmarks.py --only instr`` from each Drake (one
    count each: callgrind's counts are deterministic to ~0.01 %), and each count's ratio
    new Drake / old."""
    lines = [
        "| episode (short, closed) | Drake | floor [G instr] | Python runner | doorlab | "
        "Python / floor | doorlab / Python |",
        "|---|---|---|---|---|---|---|",
    ]
    counts = {}
    for path, record in ((old_path, old), (new_path, new)):
        metrics = json.loads(path.read_text())["metrics"]
        for controller in ("velocity", "impedance"):

            def get(name: str, controller=controller, metrics=metrics):
                entry = metrics.get(f"design/{controller}_closed/{name}")
                return None if entry is None else entry["median"]

            row = {n: get(f"{n}_instr") for n in ("floor", "python", "new")}
            counts[record["drake"], controller] = row
            lines.append(
                f"| {controller} | {record['drake']} | {_g(row['floor'])} | "
                f"{_g(row['python'])} | {_g(row['new'])} | "
                f"{_r(get('python_over_floor_instr'))} | {_r(get('new_over_python_instr'))} |"
            )
    lines += ["", "| episode | floor | Python runner | doorlab |", "|---|---|---|---|"]
    for controller in ("velocity", "impedance"):
        a, b = counts[old["drake"], controller], counts[new["drake"], controller]
        ratios = [_r(b[n] / a[n]) if a[n] and b[n] else "-" for n in ("floor", "python", "new")]
        label = f"{controller}: Drake {new['drake']} / {old['drake']}"
        lines.append(f"| {label} | " + " | ".join(ratios) + " |")
    return lines


def _g(x) -> str:
    return "-" if x is None else f"{x / 1e9:.3f}"


def _r(x) -> str:
    return "-" if x is None else f"{x:.3f}"


def table(args: argparse.Namespace) -> int:
    old, new = (json.loads(p.read_text()) for p in (args.old, args.new))
    runs, over = runs_table(old, new)
    grades, differ = grades_table(old, new)
    text = [
        f"Drake {old['drake']} (Python {old['python']}, {old['source']}) / Drake "
        f"{new['drake']} (Python {new['python']}, {new['source']}); written by "
        "`benchmarks/drake_releases.py table`.",
        "",
        *runs,
        "",
        "The grader (every test's score of the answer key and of each catalogued mistake):",
        "",
        *grades,
    ]
    if args.instr:
        text += ["", *instr_table(args.instr[0], args.instr[1], old, new)]
    text += ["", "Over tolerance or different: " + ("; ".join(over + differ) or "none") + "."]
    args.out.write_text("\n".join(text) + "\n")
    print("\n".join(text))
    return 1 if over or differ else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    m = sub.add_parser("measure", help="the runs and the grader on this interpreter's Drake")
    m.add_argument("--out", type=Path, required=True)
    m.add_argument("--jobs", type=int, default=2, help="the grader's tests at a time")
    m.add_argument("--no-grading", action="store_true", help="the runs only")
    m.add_argument(
        "--keep-runs", action="store_true", help="reuse the runs already in --out (grade only)"
    )
    t = sub.add_parser("table", help="two measure files side by side")
    t.add_argument("old", type=Path)
    t.add_argument("new", type=Path)
    t.add_argument("--instr", type=Path, nargs=2, metavar=("OLD", "NEW"))
    t.add_argument("--out", type=Path, default=BENCH_DIR / "results" / "drake_releases.md")
    args = parser.parse_args(argv)
    return measure(args) if args.command == "measure" else table(args)


if __name__ == "__main__":
    sys.exit(main())
