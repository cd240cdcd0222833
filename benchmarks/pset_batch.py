"""A class's grading: CPU seconds per submission in a batch against one by one, throughput.

    python benchmarks/pset_batch.py [--submissions K] [--repeats N] [--baseline-src DIR]
                                    [--out FILE.json]

A class of K correct submissions (the answer key: every test runs to the end, the costliest
submission there is; each with a comment of its own appended to ik_utils.py, so that no two
have identical files, which grade-all grades once) is graded, per repeat, side by side:

- ``batch_1`` and ``batch_2``: ``doorlab pset grade-all``
  (:func:`doorlab.pset.classroom.grade_all.grade_class`) on 1 and on 2 local workers, the reference
  episodes given (as ``--reference``; the class simulates them once otherwise: ``reference`` below);
- ``batch_1_stubs``: a class of K untouched stubs on 1 worker (every test fails at its
  first call: what a grading costs beyond the work);
- ``alone``: each submission by ``grade_submission`` (as ``doorlab pset grade SUBMISSION
  --reference EARLIER.json``: its own supervisor, 2 tests at a time);
- ``reference``: the reference episodes once (:func:`doorlab.pset.grading.grader.grade_reference`);
- with ``--baseline-src DIR`` (another version's ``src``, e.g. ``git archive main src | tar -x
  -C /tmp/main``): ``baseline_alone``, each submission graded by that version's
  ``grade_submission`` with the reference given, and ``baseline_batch_1`` /
  ``baseline_batch_2`` (``_stubs``: the stubs' class), the class graded by that version's
  ``grade_class`` on 1 / 2 workers, each in a fresh interpreter (a venv whose path file puts
  DIR first; see pset_grading.py). ``batch_1`` against ``baseline_batch_1`` is a
  submission's cost in a batch against that version's, everything a run writes included
  (this version's feedback pages, class page and statistics too).

``--variants a,b`` runs only those (e.g. ``batch_2,baseline_batch_2``: a class on 2 workers
against another version's, side by side, one after the other in each repeat).

CPU time is counted in a cgroup holding this process and everything it starts (root; the
student's processes included, which getrusage misses). Printed: the medians of the CPU
seconds per submission and of the wall time per submission, the throughput on 1 and 2
workers (submissions per minute) and the 2 workers' scaling; from them, the wall time of a
class of 200 on a cluster of N cores (one worker per core): the reference once, then
200 / N submissions per worker at the measured 1-worker time, divided by the measured
scaling efficiency of 2 workers (at most 1; an estimate: a cluster's network and file
system add little, each submission ships a few kB).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import source_label
from pset_grading import _baseline_python
from pset_profile import CpuMeter

CLASS_SIZE = 200
"""The class the derived wall times are for."""
CLUSTER_CORES = (2, 8, 32, 64)
"""Cluster sizes [cores] of the derived wall times."""

_BASELINE = """
import json, sys
from doorlab.pset.grading.grader import grade_submission
reference = json.loads(open(sys.argv[1]).read())
for folder in sys.argv[2:]:
    r = grade_submission(folder, reference=reference)
    print(r["score"])
"""
_BASELINE_BATCH = """
import json, shutil, sys
from doorlab.pset.classroom.grade_all import grade_class
reference = json.loads(open(sys.argv[1]).read())
shutil.rmtree(sys.argv[3], ignore_errors=True)
outcome = grade_class(sys.argv[2], sys.argv[3], jobs=int(sys.argv[4]), reference=reference)
print(json.dumps([[r.get("status"), r.get("total")] for r in outcome.rows]))
"""


def _measure(meter: CpuMeter, call) -> tuple[float, float]:
    cpu0, wall0 = meter.read(), time.perf_counter()
    call()
    return meter.read() - cpu0, time.perf_counter() - wall0


def _class(root: Path, count: int, *, solutions: bool) -> Path:
    from doorlab.pset.handout.folder import init_folder

    name = "key" if solutions else "stubs"
    key = init_folder(root / name, solutions=solutions)
    export = root / f"export_{name}"
    export.mkdir()
    for i in range(count):
        shutil.copytree(key, export / f"submission_{i}")
        ik = export / f"submission_{i}" / "ik_utils.py"  # files of its own (not graded once)
        ik.write_text(ik.read_text() + f"\n# submission {i}\n")
    subprocess.run(["chmod", "-R", "a+rX", str(root)], check=True)
    return export


def _batch(export: Path, out: Path, reference: dict, jobs: int, score: float = 14.0) -> None:
    from doorlab.pset.classroom.grade_all import grade_class

    shutil.rmtree(out, ignore_errors=True)
    outcome = grade_class(export, out, jobs=jobs, reference=reference)
    bad = [r for r in outcome.rows if r.get("status") != "graded" or r.get("total") != score]
    if bad:
        raise RuntimeError(f"a submission did not score {score:g} in the batch: {bad[0]}")


def _alone(export: Path, reference: dict) -> None:
    from doorlab.pset.grading.grader import grade_submission

    for folder in sorted(export.iterdir()):
        results = grade_submission(folder, reference=reference)
        if results["score"] != 14.0:
            raise RuntimeError(f"the key scored {results['score']} alone")


def _baseline(python: Path, export: Path, reference_file: Path) -> None:
    folders = [str(p) for p in sorted(export.iterdir())]
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = subprocess.run(
        [str(python), "-c", _BASELINE, str(reference_file), *folders],
        env=env,
        cwd="/",
        capture_output=True,
        text=True,
        check=True,
    )
    scores = [float(x) for x in proc.stdout.split()]
    if scores != [14.0] * len(folders):
        raise RuntimeError(f"the baseline scored {scores}")


def _baseline_batch(
    python: Path, export: Path, out: Path, reference_file: Path, jobs: int, score: float = 14.0
) -> None:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    argv = [str(python), "-c", _BASELINE_BATCH, str(reference_file), str(export), str(out)]
    proc = subprocess.run(
        [*argv, str(jobs)],
        env=env,
        cwd="/",
        capture_output=True,
        text=True,
        check=True,
    )
    rows = json.loads(proc.stdout.strip().splitlines()[-1])
    if any(row != ["graded", score] for row in rows):
        raise RuntimeError(f"the baseline's batch: {rows}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--submissions", type=int, default=4, help="class size K (default 4)")
    parser.add_argument("--repeats", type=int, default=3, help="repeats (default 3)")
    parser.add_argument("--baseline-src", type=Path, default=None, help="also grade with DIR")
    parser.add_argument("--out", type=Path, default=None, help="write the figures as JSON")
    parser.add_argument(
        "--variants",
        default=None,
        help="comma-separated variants to run (default: all), e.g. batch_1,baseline_batch_1",
    )
    args = parser.parse_args(argv)

    from doorlab.pset.grading.grader import grade_reference

    k = args.submissions
    meter = CpuMeter()
    samples: dict[str, list[tuple[float, float]]] = {}
    load0 = os.getloadavg()[0]
    try:
        with tempfile.TemporaryDirectory(prefix="doorlab_batch_bench_") as tmp:
            root = Path(tmp)
            os.chmod(root, 0o755)
            export = _class(root, k, solutions=True)
            stubs = _class(root, k, solutions=False)
            box = {}
            samples["reference"] = [_measure(meter, lambda: box.update(r=grade_reference()))]
            reference = box["r"]
            reference_file = root / "reference.json"
            reference_file.write_text(json.dumps(reference))
            variants = {
                "batch_1": lambda: _batch(export, root / "out", reference, 1),
                "batch_2": lambda: _batch(export, root / "out", reference, 2),
                "alone": lambda: _alone(export, reference),
                "batch_1_stubs": lambda: _batch(stubs, root / "out", reference, 1, 0.0),
                "batch_2_stubs": lambda: _batch(stubs, root / "out", reference, 2, 0.0),
            }
            if args.baseline_src is not None:
                python = _baseline_python(args.baseline_src, root / "baseline-venv")
                variants["baseline_alone"] = lambda: _baseline(python, export, reference_file)
                for jobs in (1, 2):
                    variants[f"baseline_batch_{jobs}"] = lambda jobs=jobs: _baseline_batch(
                        python, export, root / "out_baseline", reference_file, jobs
                    )
                variants["baseline_batch_2_stubs"] = lambda: _baseline_batch(
                    python, stubs, root / "out_baseline", reference_file, 2, 0.0
                )
            if args.variants:
                wanted = args.variants.split(",")
                unknown = sorted(set(wanted) - set(variants))
                if unknown:
                    parser.error(f"unknown variants {unknown}; choose from {sorted(variants)}")
                variants = {k: v for k, v in variants.items() if k in wanted}
            for _ in range(args.repeats):
                for name, call in variants.items():
                    samples.setdefault(name, []).append(_measure(meter, call))
                samples["reference"].append(_measure(meter, grade_reference))
    finally:
        meter.close()
    load1 = os.getloadavg()[0]
    figures = {}
    for name, values in samples.items():
        per = 1 if name == "reference" else k
        figures[name] = {
            "cpu_s_per_submission": statistics.median(c / per for c, _ in values),
            "wall_s_per_submission": statistics.median(w / per for _, w in values),
            "samples": values,
        }
    one = figures["batch_1"]["wall_s_per_submission"] if "batch_1" in figures else float("nan")
    two = figures["batch_2"]["wall_s_per_submission"] if "batch_2" in figures else float("nan")
    efficiency = min(1.0, one / (2 * two)) if two == two else float("nan")
    ref_wall = figures["reference"]["wall_s_per_submission"]
    derived = {n: ref_wall + CLASS_SIZE * one / (n * efficiency) for n in CLUSTER_CORES}
    print(
        f"a class of {k} correct submissions, medians of {args.repeats}; CPU from "
        f"{meter.source}; load average {load0:.2f} -> {load1:.2f} on {os.cpu_count()} cores"
    )
    print(f"  {'variant':16s} {'cpu/submission':>15s} {'wall/submission':>16s}")
    for name, f in figures.items():
        unit = "(once)" if name == "reference" else ""
        print(
            f"  {name:16s} {f['cpu_s_per_submission']:13.2f} s {f['wall_s_per_submission']:14.2f} s"
            f" {unit}"
        )
    base = figures["alone"]["cpu_s_per_submission"] if "alone" in figures else float("nan")
    if "batch_1" in figures and "alone" in figures:
        print(f"  batch / alone CPU {figures['batch_1']['cpu_s_per_submission'] / base:.2f}")
    if "baseline_alone" in figures and "batch_1" in figures:
        old = figures["baseline_alone"]["cpu_s_per_submission"]
        print(
            f"  batch / baseline alone CPU {figures['batch_1']['cpu_s_per_submission'] / old:.2f}"
            f", alone / baseline alone CPU {base / old:.2f}"
        )
    for mine in ("batch_1", "batch_2", "batch_2_stubs"):
        theirs = "baseline_" + mine
        if theirs in figures and mine in figures:
            ratio = figures[mine]["cpu_s_per_submission"] / figures[theirs]["cpu_s_per_submission"]
            pairs = zip(samples[mine], samples[theirs], strict=True)
            ratios = [a / b for (a, _), (b, _) in pairs]
            print(
                f"  {mine} / {theirs} CPU per submission {ratio:.3f} (per repeat: "
                + ", ".join(f"{r:.3f}" for r in ratios)
                + ")"
            )
    print(
        f"  throughput: {60 / one:.1f} submissions/min on 1 worker, {60 / two:.1f} on 2 "
        f"(scaling efficiency {efficiency:.2f})"
    )
    print(
        f"  a class of {CLASS_SIZE} (correct submissions), reference once, N cores: "
        + ", ".join(f"N={n}: {t / 60:.1f} min" for n, t in derived.items())
    )
    if args.out:
        data = {
            "submissions": k,
            "repeats": args.repeats,
            "cpu_source": meter.source,
            "load": [load0, load1],
            "cores": os.cpu_count(),
            "figures": figures,
            "scaling_efficiency_2": efficiency,
            "class_of_200_wall_s": derived,
            "this": source_label(Path(__file__).resolve().parent),
            "baseline": None if args.baseline_src is None else source_label(args.baseline_src),
        }
        args.out.write_text(json.dumps(data, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
