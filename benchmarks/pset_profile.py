"""Where a grading's CPU seconds go: the grader's processes and jobs, one by one.

    python benchmarks/pset_profile.py [--repeats N] [--out FILE.json]

As root (a cgroup counts every process, the student's included: getrusage cannot, since the
student's processes are reaped inside bubblewrap's PID namespace), this script moves itself
into a fresh cgroup and measures, one after the other, with nothing else of its own
running, the CPU time [s] (user + system, every process of the cgroup) and the wall time of:

- ``grading/*``: a whole grading of a correct folder (``grade_submission``), from scratch and
  with the reference episodes given (``reference=``, as a batch shares them); and
  ``grading/batch_worker``, as a worker of ``doorlab pset grade-all`` grades: the reference
  given, one test at a time, through a supervisor that already graded a submission
  (:class:`doorlab.pset.grading.grader.Supervisor`: its imports and the view's preparation done);
- ``start/*``: what a grading pays before any work: an interpreter with the supervisor's
  imports, one with a trusted job's imports (pydrake, the checks, the episodes: what the
  supervisor imports once, and what the design before issue 26 paid in each job's
  interpreter), the student's view prepared (``isolation.prepare``: the student side copied
  and compiled, the probe), a student process started in its own view and stopped (bwrap,
  the interpreter, its imports: the design before issue 26, once per test), a view started
  with its first process (``views.StudentView``: once per grading now), a
  student process forked in that view and ended (``views.ForkedStudent``: once per test now),
  a trusted process forked from this one and waited for;
- ``job/*``: each job's own work, run in this (already warm) process with its student
  process forked in a view: the unit tests, the student episodes (with a correct folder) and
  the reference episodes (the fork of the student's process included).

Prints the medians of the repeats, and what starting processes costs per grading in the
design before issue 26 (a trusted interpreter per job, a student process in a view of its
own per student job) and now (one view per grading, forks).
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

CGROUP_ROOTS = (
    ("/sys/fs/cgroup/cpuacct", "cpuacct.usage", 1e-9),  # cgroup v1 [ns]
    ("/sys/fs/cgroup/unified", "cpu.stat", 1e-6),  # cgroup v2 beside v1 [us]
    ("/sys/fs/cgroup", "cpu.stat", 1e-6),  # cgroup v2 [us]
)
"""Where a process tree's CPU time can be counted whole (see pset_grading.py's CGROUPS)."""


class CpuMeter:
    """CPU time of this process and everything it starts, from a cgroup it moved into (root),
    else from getrusage (which misses the student's processes: ``source`` says which)."""

    def __init__(self) -> None:
        self.folder: Path | None = None
        self.source = "getrusage (lower bound: misses the student's processes)"
        name = f"doorlab_profile_{os.getpid()}"
        for base, usage, scale in CGROUP_ROOTS:
            folder = Path(base) / name
            try:
                folder.mkdir()
            except OSError:
                continue
            if (folder / usage).exists() and (folder / "cgroup.procs").exists():
                (folder / "cgroup.procs").write_text(str(os.getpid()))
                self.folder, self.usage, self.scale = folder, usage, scale
                self.source = f"cgroup {base}"
                break
            folder.rmdir()

    def read(self) -> float:
        """CPU seconds so far."""
        if self.folder is None:
            import resource

            usages = [
                resource.getrusage(w) for w in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)
            ]
            return sum(u.ru_utime + u.ru_stime for u in usages)
        text = (self.folder / self.usage).read_text()
        if self.usage == "cpu.stat":
            text = dict(line.split() for line in text.splitlines())["usage_usec"]
        return int(text) * self.scale

    def close(self) -> None:
        if self.folder is None:
            return
        parent = self.folder.parent
        (parent / "cgroup.procs").write_text(str(os.getpid()))
        try:
            self.folder.rmdir()
        except OSError:
            pass


def measure(meter: CpuMeter, call) -> tuple[float, float]:
    """(CPU [s], wall [s]) of ``call()``."""
    cpu0, wall0 = meter.read(), time.perf_counter()
    call()
    return meter.read() - cpu0, time.perf_counter() - wall0


def _python(code: str) -> None:
    subprocess.run([sys.executable, "-I", "-c", code], check=True, cwd="/")


def _student_process(folder: Path, work: Path, isolation, name: str) -> None:
    from doorlab.pset.isolation.handle import StudentProcess

    with StudentProcess(folder, work, name, 60.0, isolation):
        pass


def _forked_student(folder: Path, student_view, name: str) -> None:
    from doorlab.pset.isolation.student_view import ForkedStudent

    with ForkedStudent(student_view, folder, name, 60.0):
        pass


def _fork_and_wait() -> None:
    pid = os.fork()
    if pid == 0:
        os._exit(0)
    os.waitpid(pid, 0)


def _job(name: str, folder: Path, work: Path, isolation, views: dict) -> dict:
    """One job as the supervisor runs it: a forked trusted process, its student's process
    forked in its view."""
    from doorlab.pset.grading.jobs import _Jobs

    runner = _Jobs(folder, work, 1.0, isolation, {name: {"seed": 1}})
    runner.views = views
    result = runner.run([name], 1)[name]
    runner.selector.close()
    if "grader_error" in result:
        raise RuntimeError(result["grader_error"])
    return result


class Samples(dict):
    """key -> [(CPU [s], wall [s]), ...], measured by a CpuMeter."""

    def __init__(self, meter: CpuMeter):
        super().__init__()
        self.meter = meter

    def timed(self, key: str, call):
        """``call()``'s result; its CPU and wall time appended to ``self[key]``."""
        box = {}
        self.setdefault(key, []).append(measure(self.meter, lambda: box.update(r=call())))
        return box["r"]


def one_round(samples: Samples, folder: Path, work: Path, jobs: list[str]) -> None:
    """Every figure once (see the module docstring)."""
    from doorlab.pset.grading.grader import Supervisor, grade_submission
    from doorlab.pset.grading.supervisor import _warm
    from doorlab.pset.isolation.choice import prepare
    from doorlab.pset.isolation.student_view import StudentView

    samples.timed(
        "start/supervisor_imports",
        lambda: _python("import doorlab.pset.grading.jobs, doorlab.pset.grading.supervisor"),
    )
    samples.timed(
        "start/trusted_job_imports",
        lambda: _python(
            "import doorlab.pset.grading.jobs, doorlab.pset.grading.checks, "
            "doorlab.pset.grading.episodes"
        ),
    )
    isolation = samples.timed("start/isolation_prepare", lambda: prepare(work, "require"))
    samples.timed(
        "start/student_process_in_own_view",
        lambda: _student_process(folder, work, isolation, "probe"),
    )
    samples.timed("start/trusted_fork", _fork_and_wait)
    student_view = samples.timed("start/view", lambda: StudentView(isolation, work, "view0", 150.0))
    views = {"view0": student_view}
    try:
        samples.timed("start/forked_student", lambda: _forked_student(folder, student_view, "p"))
        _warm(jobs, {})
        for job in jobs:
            samples.timed(f"job/{job}", lambda job=job: _job(job, folder, work, isolation, views))
    finally:
        student_view.close()
    results = samples.timed("grading/from_scratch", lambda: grade_submission(folder))
    reference = results["extra_data"]["reference"]
    samples.timed("grading/reference_given", lambda: grade_submission(folder, reference=reference))
    with Supervisor() as supervisor:  # a batch's worker: its second submission
        grade_submission(folder, reference=reference, jobs=1, supervisor=supervisor)
        samples.timed(
            "grading/batch_worker",
            lambda: grade_submission(folder, reference=reference, jobs=1, supervisor=supervisor),
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="repeats of each (default 3)")
    parser.add_argument("--out", type=Path, default=None, help="write the figures as JSON")
    args = parser.parse_args(argv)

    from doorlab.pset.handout.folder import init_folder
    from doorlab.pset.rules.verdicts import TESTS

    jobs = sorted({j for t in TESTS for j in t.jobs})
    meter = CpuMeter()
    samples = Samples(meter)
    load0 = os.getloadavg()[0]
    try:
        with tempfile.TemporaryDirectory(prefix="doorlab_profile_") as tmp:
            root = Path(tmp)
            os.chmod(root, 0o755)
            folder = init_folder(root / "solutions", solutions=True)
            os.chmod(root / "solutions", 0o755)
            for i in range(args.repeats):
                work = root / f"work{i}"
                work.mkdir(mode=0o711)
                os.chmod(work, 0o711)
                one_round(samples, folder, work, jobs)
    finally:
        meter.close()
    load1 = os.getloadavg()[0]
    medians = {
        key: {
            "cpu_s": statistics.median(c for c, _ in values),
            "wall_s": statistics.median(w for _, w in values),
            "samples": values,
        }
        for key, values in samples.items()
    }
    student_jobs = [j for j in jobs if not j.startswith("reference:")]
    m = {key: value["cpu_s"] for key, value in medians.items()}
    common = m["start/supervisor_imports"] + m["start/isolation_prepare"]
    before = (
        common
        + m["start/trusted_job_imports"] * len(jobs)
        + m["start/student_process_in_own_view"] * len(student_jobs)
    )
    now = (
        common
        + m["start/trusted_job_imports"]
        + m["start/trusted_fork"] * len(jobs)
        + m["start/view"]
        + m["start/forked_student"] * len(student_jobs)
    )
    print(
        f"CPU from {meter.source}; load average {load0:.2f} -> {load1:.2f} on "
        f"{os.cpu_count()} cores; medians of {args.repeats}"
    )
    print(f"  {'what':34s} {'cpu [s]':>8s} {'wall [s]':>9s}")
    for key, m in medians.items():
        print(f"  {key:34s} {m['cpu_s']:8.2f} {m['wall_s']:9.2f}")
    print(
        f"  starting processes, per grading from scratch: {before:.1f} CPU-s before issue 26 (a "
        f"trusted interpreter per job x {len(jobs)}, a student process in its own view per "
        f"student job x {len(student_jobs)}); {now:.1f} CPU-s now (one trusted interpreter, "
        f"{len(jobs)} forks; 1 view, {len(student_jobs)} forked student processes)"
    )
    if args.out:
        args.out.write_text(
            json.dumps(
                {
                    "cpu_source": meter.source,
                    "load": [load0, load1],
                    "figures": medians,
                    "process_starts_cpu_s": {"before_issue_26": before, "now": now},
                },
                indent=2,
            )
            + "\n"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
