"""Wall time of a full grading of a correct problem-set folder (target: under 3 minutes).

    python benchmarks/pset_grading.py [--repeats N] [--jobs J] [--out FILE.json]
                                      [--baseline-src DIR]

Writes a ``--solutions`` folder to a temporary directory and grades it N times from scratch
(reference episodes included), printing the median wall time against the target, the score,
and the per-job process times of the last grading. Timings depend on the machine's load: the
line ``other cpu`` is the average number of cores other processes used meanwhile.

``--baseline-src DIR`` (another version's ``src`` folder, e.g. ``git archive main src | tar
-x -C /tmp/main``) also grades the same folder with that version, alternately with this one
(each grading in a fresh interpreter; the baseline's is a venv of this interpreter whose
path file puts DIR first and this environment's packages after it, since the grader's own
processes run in isolated mode and ignore ``PYTHONPATH``), and prints both medians of wall
time and of CPU time (every process of the grading) and their ratios: the two see the same
load.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import cpu_times, source_label

from doorlab.pset.grading.grader import grade
from doorlab.pset.handout.folder import init_folder

TARGET_S = 180.0
"""The issue's target for a full grading on 2 cores [s]."""


_GRADE = """
import json, resource, sys, time
import doorlab
from doorlab.pset.grading.grader import grade
start = time.perf_counter()
r = grade(sys.argv[1], jobs=int(sys.argv[2]))
usage = [resource.getrusage(w) for w in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)]
cpu = sum(u.ru_utime + u.ru_stime for u in usage)
print(json.dumps({"wall": time.perf_counter() - start, "score": r["score"], "cpu": cpu,
                  "doorlab": doorlab.__file__}))
"""


def _baseline_python(src: Path, where: Path) -> Path:
    """A venv of this interpreter in ``where`` that imports doorlab from ``src`` and the
    rest from this environment (a path file: its own ``.pth`` files do not run there)."""
    import site

    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(where)], check=True)
    python = where / "bin" / "python"
    purelib = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    paths = [str(src.resolve()), *site.getsitepackages()]
    Path(purelib, "doorlab_baseline.pth").write_text("\n".join(paths) + "\n")
    return python


CGROUPS = (
    ("/sys/fs/cgroup/cpuacct", "cpuacct.usage", 1e-9),  # cgroup v1 [ns]
    ("/sys/fs/cgroup/unified", "cpu.stat", 1e-6),  # cgroup v2 beside v1 [us]
    ("/sys/fs/cgroup", "cpu.stat", 1e-6),  # cgroup v2 [us]
)
"""Where a grading's CPU time can be counted whole. getrusage cannot: the student's
processes run in a PID namespace of their own (bubblewrap's), and when its init dies the
kernel reaps them inside it, so their CPU time reaches no parent outside."""


def _cgroup_cpu(folder: Path, usage_file: str, scale: float) -> float:
    text = (folder / usage_file).read_text()
    if usage_file == "cpu.stat":
        text = dict(line.split() for line in text.splitlines())["usage_usec"]
    return int(text) * scale


def _new_cgroup(name: str) -> tuple[Path, str, float] | None:
    """A fresh cgroup that counts CPU time (root only), or None."""
    for base, usage_file, scale in CGROUPS:
        folder = Path(base) / name
        try:
            folder.mkdir()
        except OSError:
            continue
        if (folder / usage_file).exists() and (folder / "cgroup.procs").exists():
            return folder, usage_file, scale
        folder.rmdir()
    return None


def _grade_in_subprocess(folder: Path, jobs: int, python: Path) -> dict:
    """One grading by ``python``'s doorlab: {"wall" [s] of the whole interpreter, "cpu" [s]
    of it and every process below it (a cgroup's count where this process may make one, else
    getrusage's, which misses the student's processes: "cpu_source" says which), "score",
    "doorlab" (where it came from)}."""
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)
    cgroup = _new_cgroup(f"doorlab_bench_{os.getpid()}_{time.time_ns()}")

    def enter() -> None:
        if cgroup is not None:
            (cgroup[0] / "cgroup.procs").write_text(str(os.getpid()))

    try:
        start = time.perf_counter()
        proc = subprocess.run(
            [str(python), "-c", _GRADE, str(folder), str(jobs)],
            env=env,
            cwd="/",
            capture_output=True,
            text=True,
            check=True,
            preexec_fn=enter,
        )
        wall = time.perf_counter() - start
        out = json.loads(proc.stdout.strip().splitlines()[-1])
        out["wall"] = wall
        out["cpu_source"] = "getrusage (lower bound)"
        if cgroup is not None:
            out["cpu"] = _cgroup_cpu(*cgroup)
            out["cpu_source"] = f"cgroup {cgroup[0].parent}"
    finally:
        if cgroup is not None:
            cgroup[0].rmdir()
    return out


def _side_by_side(args) -> int:
    walls: dict[str, list[float]] = {"this": [], "baseline": []}
    cpus: dict[str, list[float]] = {"this": [], "baseline": []}
    scores: dict[str, float] = {}
    origins: dict[str, str] = {}
    with tempfile.TemporaryDirectory(prefix="doorlab_pset_bench_") as tmp:
        os.chmod(tmp, 0o755)
        folder = init_folder(Path(tmp) / "solutions", solutions=True)
        pythons = {
            "this": Path(sys.executable),
            "baseline": _baseline_python(args.baseline_src, Path(tmp) / "baseline-venv"),
        }
        busy0, total0 = cpu_times()
        for _ in range(args.repeats):
            for name, python in pythons.items():
                out = _grade_in_subprocess(folder, args.jobs, python)
                walls[name].append(out["wall"])
                cpus[name].append(out["cpu"])
                scores[name] = out["score"]
                origins[name] = source_label(Path(out["doorlab"]).resolve().parents[1])
                cpu_source = out["cpu_source"]
        busy1, total1 = cpu_times()
    ticks = os.sysconf("SC_CLK_TCK")
    cores = os.cpu_count() or 1
    elapsed = (total1 - total0) / ticks / cores
    busy = (busy1 - busy0) / ticks / max(elapsed, 1e-9)
    medians = {k: statistics.median(v) for k, v in walls.items()}
    cpu_medians = {k: statistics.median(v) for k, v in cpus.items()}
    ratio = medians["this"] / medians["baseline"]
    cpu_ratio = cpu_medians["this"] / cpu_medians["baseline"]
    print(f"full grading of a --solutions folder, jobs={args.jobs}, {cores} cores, alternately")
    for name in ("this", "baseline"):
        w = walls[name]
        print(
            f"  {name:9s} wall median {medians[name]:.1f} s over {len(w)} (min {min(w):.1f}, "
            f"max {max(w):.1f}); cpu median {cpu_medians[name]:.1f} s; score "
            f"{scores[name]:g}; doorlab from {origins[name]}"
        )
    print(f"  this / baseline wall {ratio:.2f}, cpu {cpu_ratio:.2f} (cpu from {cpu_source})")
    print(f"  busy cores      {busy:.2f} of {cores} (these gradings and everything else)")
    if args.out:
        figures = {
            "wall_s": walls,
            "median_wall_s": medians,
            "ratio": ratio,
            "cpu_s": cpus,
            "cpu_source": cpu_source,
            "median_cpu_s": cpu_medians,
            "cpu_ratio": cpu_ratio,
            "doorlab": origins,
            "scores": scores,
            "jobs": args.jobs,
            "cores": cores,
            "busy_cores": busy,
        }
        args.out.write_text(json.dumps(figures, indent=2) + "\n")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=1, help="gradings (default 1)")
    parser.add_argument("--jobs", type=int, default=2, help="processes at a time (default 2)")
    parser.add_argument("--out", type=Path, default=None, help="write the figures as JSON")
    parser.add_argument(
        "--baseline-src", type=Path, default=None, help="also grade with the version at DIR"
    )
    args = parser.parse_args(argv)
    if args.baseline_src is not None:
        return _side_by_side(args)
    walls, last = [], None
    with tempfile.TemporaryDirectory(prefix="doorlab_pset_bench_") as tmp:
        folder = init_folder(Path(tmp) / "solutions", solutions=True)
        busy0, total0 = cpu_times()
        self0 = os.times()
        for _ in range(args.repeats):
            start = time.perf_counter()
            last = grade(folder, jobs=args.jobs)
            walls.append(time.perf_counter() - start)
        busy1, total1 = cpu_times()
        self1 = os.times()
    ticks = os.sysconf("SC_CLK_TCK")
    cores = os.cpu_count() or 1
    elapsed = (total1 - total0) / ticks / cores
    ours = (
        self1.user
        + self1.system
        + self1.children_user
        + self1.children_system
        - self0.user
        - self0.system
        - self0.children_user
        - self0.children_system
    )
    other_cpu = max(0.0, ((busy1 - busy0) / ticks - ours) / max(elapsed, 1e-9))
    median = statistics.median(walls)
    max_score = last["extra_data"]["max_score"]
    print(f"full grading of a --solutions folder, jobs={args.jobs}, {cores} cores")
    print(
        f"  wall time       median {median:.1f} s over {len(walls)} (min {min(walls):.1f}, "
        f"max {max(walls):.1f}); target < {TARGET_S:.0f} s: "
        f"{'met' if median < TARGET_S else 'NOT met'}"
    )
    print(f"  score           {last['score']:g} / {max_score:g}")
    print(f"  other cpu       {other_cpu:.2f} cores")
    figures = {
        "wall_s": walls,
        "median_wall_s": median,
        "target_s": TARGET_S,
        "score": last["score"],
        "max_score": max_score,
        "jobs": args.jobs,
        "cores": cores,
        "other_cpu": other_cpu,
    }
    if args.out:
        args.out.write_text(json.dumps(figures, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
