"""The Gradescope image, rehearsed: the zip, setup.sh, the venv's size, a grading's wall time,
CPU time and peak memory, as Gradescope would run them.

    python benchmarks/pset_image.py [--gradings N] [--jobs J ...] [--out FILE.json]

Writes the autograder zip (default assignment) into a temporary folder, runs its ``setup.sh``
in a stand-in for ``/autograder`` (``DOORLAB_AUTOGRADER_ROOT``; dependencies from the package
index; as root inside bubblewrap with a private ``/etc``, so the user it creates exists only
there), then grades a correct submission (the key's three files, flat) with
``run_autograder`` N times per ``--jobs`` value (default: the zip's 1, Gradescope's default,
and 2). Per grading: wall time, the CPU time of the process tree (counted in a cgroup as
root: the student's processes in bubblewrap's PID namespace included; else getrusage's, which
misses them), and its peak memory:
the largest sum of the proportional set sizes (PSS, ``/proc/PID/smaps_rollup``: shared pages
split between the processes sharing them) of every process of the tree, sampled every
50 ms (a shorter peak can be missed). The line ``other cpu`` is the average number of cores
other processes used meanwhile: wall times depend on it.
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
import threading
import time
import zipfile
from pathlib import Path

from common import cpu_times
from pset_grading import _cgroup_cpu, _new_cgroup

from doorlab.pset.classroom import gradescope
from doorlab.pset.handout.folder import STUDENT_FILES, render_folder

SAMPLE_S = 0.05


def _tree(pid: int) -> list[int]:
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        children.setdefault(ppid, []).append(int(entry))
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        todo += children.get(p, [])
    return out


def _pss_kb(pid: int) -> int:
    try:
        for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
            if line.startswith("Pss:"):
                return int(line.split()[1])
    except (OSError, ValueError):
        pass
    return 0


def _du(path: Path) -> int:
    """Bytes of the files under ``path`` (each inode once)."""
    seen, total = set(), 0
    for dirpath, _, names in os.walk(path):
        for name in names:
            st = os.lstat(os.path.join(dirpath, name))
            if (st.st_dev, st.st_ino) not in seen:
                seen.add((st.st_dev, st.st_ino))
                total += st.st_blocks * 512
    return total


def _setup(root: Path) -> float:
    env = dict(os.environ, **{gradescope.ROOT_ENV: str(root)})
    command = ["bash", str(root / "source" / "setup.sh")]
    if os.geteuid() == 0 and shutil.which("bwrap"):
        etc = root.parent / "etc"
        shutil.copytree("/etc", etc, symlinks=True, ignore_dangling_symlinks=True)
        command = ["bwrap", "--bind", "/", "/", "--bind", str(etc), "/etc", "--dev", "/dev"]
        command += ["--proc", "/proc", "bash", str(root / "source" / "setup.sh")]
    else:
        env.setdefault("DOORLAB_SANDBOX_USER", "nobody")
    start = time.perf_counter()
    proc = subprocess.run(command, env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"setup.sh failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}")
    print(proc.stdout.strip().splitlines()[-1])
    return time.perf_counter() - start


def _grade(root: Path, jobs: int) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON")}
    env[gradescope.ROOT_ENV] = str(root)
    before = os.times()
    cgroup = _new_cgroup(f"doorlab_image_{os.getpid()}_{time.time_ns()}")

    def enter() -> None:
        if cgroup is not None:
            (cgroup[0] / "cgroup.procs").write_text(str(os.getpid()))

    start = time.perf_counter()
    process = subprocess.Popen(
        ["bash", str(root / "run_autograder"), "--jobs", str(jobs)],
        cwd=root,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        preexec_fn=enter,
    )
    peak = [0]

    def sample() -> None:
        while process.poll() is None:
            peak[0] = max(peak[0], sum(_pss_kb(p) for p in _tree(process.pid)))
            time.sleep(SAMPLE_S)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    _, err = process.communicate()
    wall = time.perf_counter() - start
    sampler.join()
    after = os.times()
    if process.returncode != 0:
        sys.exit(f"run_autograder failed: {err.decode()[-2000:]}")
    results = json.loads((root / "results" / "results.json").read_text())
    cpu = (after.children_user + after.children_system) - (
        before.children_user + before.children_system
    )
    if cgroup is not None:  # every process, the student's in bubblewrap's PID namespace too
        cpu = _cgroup_cpu(*cgroup)
        cgroup[0].rmdir()
    return {"wall_s": wall, "cpu_s": cpu, "peak_pss_mib": peak[0] / 1024, "score": results["score"]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gradings", type=int, default=2, help="per --jobs value (default 2)")
    parser.add_argument("--jobs", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--out", type=Path, default=None, help="write the figures as JSON")
    args = parser.parse_args(argv)
    figures: dict = {"cores": os.cpu_count()}
    with tempfile.TemporaryDirectory(prefix="doorlab_image_bench_") as tmp:
        tmp = Path(tmp)
        os.chmod(tmp, 0o755)
        zip_path = gradescope.write_autograder(tmp / "autograder.zip")
        figures["zip_bytes"] = zip_path.stat().st_size
        root = tmp / "autograder"
        with zipfile.ZipFile(zip_path) as archive:
            archive.extractall(root / "source")
            for info in archive.infolist():
                (root / "source" / info.filename).chmod(info.external_attr >> 16 & 0o777)
        shutil.copy2(root / "source" / "run_autograder", root / "run_autograder")
        figures["setup_s"] = _setup(root)
        figures["venv_bytes"] = _du(root / "doorlab-venv")
        submission = root / "submission"
        submission.mkdir()
        key = render_folder(solutions=True)
        for rel in STUDENT_FILES:
            (submission / Path(rel).name).write_text(key[rel])
        busy0, total0 = cpu_times()
        runs: dict[str, list[dict]] = {}
        for _ in range(args.gradings):
            for jobs in args.jobs:
                runs.setdefault(str(jobs), []).append(_grade(root, jobs))
        busy1, total1 = cpu_times()
    ticks, cores = os.sysconf("SC_CLK_TCK"), os.cpu_count() or 1
    elapsed = (total1 - total0) / ticks / cores
    ours = sum(r["cpu_s"] for rs in runs.values() for r in rs)
    figures["other_cpu"] = max(0.0, ((busy1 - busy0) / ticks - ours) / max(elapsed, 1e-9))
    figures["gradings"] = runs
    print(f"zip            {figures['zip_bytes'] / 1e3:.0f} kB")
    print(f"setup.sh       {figures['setup_s']:.0f} s")
    print(f"venv           {figures['venv_bytes'] / 2**20:.0f} MiB")
    for jobs, rs in runs.items():
        med = {k: statistics.median(r[k] for r in rs) for k in ("wall_s", "cpu_s", "peak_pss_mib")}
        print(
            f"--jobs {jobs}        wall {med['wall_s']:.1f} s, cpu {med['cpu_s']:.1f} s, "
            f"peak {med['peak_pss_mib']:.0f} MiB (PSS), scores {[r['score'] for r in rs]} "
            f"(medians of {len(rs)})"
        )
    print(f"other cpu      {figures['other_cpu']:.2f} cores")
    if args.out:
        args.out.write_text(json.dumps(figures, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
