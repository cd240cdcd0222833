"""Benchmark groups ``run/*`` (the CLI end to end) and ``memory/*`` (peak RSS)."""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

from common import (
    REPORT_JOBS,
    RUN_TARGETS_S,
    Context,
    CpuWatch,
    Metric,
    Settings,
    children_cpu_s,
    subprocess_env,
)


def bench_runs(names: Sequence[str], settings: Settings, ctx: Context) -> list[Metric]:
    """``doorlab run --doors closed`` end to end, one subprocess per repeat and controller;
    ``run/report``: the default ``doorlab report --jobs 2`` (the problem set's 8 runs, diffik's
    and osc's 4, and the page); ``run/report_full``: ``doorlab report --jobs 2 --robustness``
    (and the robustness section's runs)."""
    env = subprocess_env()
    samples = {n: [] for n in names}
    info: dict[str, dict] = {n: {"exit_codes": [], "episode_sim_s": [], "cpu_s": []} for n in names}
    watches = {n: [] for n in names}
    for _ in range(settings.run_repeats):
        for name in names:
            controller = name.split("/", 1)[1]
            with tempfile.TemporaryDirectory(prefix="doorlab-bench-") as tmp:
                out = Path(tmp) / "run"
                if controller in ("report", "report_full"):
                    cmd = [
                        sys.executable, "-m", "doorlab.cli", "report", "--jobs",
                        str(REPORT_JOBS), "--out", str(out), "--force",
                    ]  # fmt: skip
                    if controller == "report_full":
                        cmd.append("--robustness")
                else:
                    cmd = [
                        sys.executable, "-m", "doorlab.cli", "run", "--controller", controller,
                        "--doors", "closed", "--out", str(out), "--force",
                    ]  # fmt: skip
                watch = CpuWatch()
                cpu = children_cpu_s()
                start = time.perf_counter()
                proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
                elapsed = time.perf_counter() - start
                info[name]["cpu_s"].append(children_cpu_s() - cpu)
                watches[name].append(watch.other_cores())
                if controller.startswith("report") and proc.returncode == 1:
                    pass  # a run not ok: still a report
                elif proc.returncode not in (0, 3, 4, 5, 6):  # 3-6: a run status, not a crash
                    last = (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
                    raise RuntimeError(f"doorlab run exited {proc.returncode}: {last}")
                samples[name].append(elapsed)
                info[name]["exit_codes"].append(proc.returncode)
                try:
                    metrics = json.loads((out / "metrics.json").read_text())
                    info[name]["episode_sim_s"].append(metrics.get("wall_time_s"))
                except (OSError, ValueError):
                    pass
            print(f"  {name}: {elapsed:.2f} s (exit {proc.returncode})", flush=True)
    out_metrics = []
    for name in names:
        other = [w for w in watches[name] if w is not None]
        out_metrics.append(
            Metric(
                name,
                name,
                "s",
                samples[name],
                target=RUN_TARGETS_S.get(name),
                info=info[name],
                other_cpu_cores=statistics.mean(other) if other else None,
            )
        )
    return out_metrics


_PEAK_RSS = """
def _peak_rss_kib():
    # VmHWM: the peak RSS of this process's own address space since its exec.
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    import resource
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
"""
_EPISODE_CHILD = (
    _PEAK_RSS
    + """
from doorlab import Scenario, run_controller
result, _ = run_controller(Scenario(controller="velocity", doors="closed"))
print("PEAK_RSS_KIB", _peak_rss_kib())
"""
)
_IMPORT_CHILD = (
    _PEAK_RSS
    + """
import doorlab, doorlab.episode.controllers, doorlab.episode.metrics

print("PEAK_RSS_KIB", _peak_rss_kib())
"""
)
MEMORY_METHOD = (
    "peak RSS of a fresh child process: VmHWM from the child's /proc/self/status at its end "
    "(ru_maxrss of the child, via os.wait4 or RUSAGE_CHILDREN, is kept as info only: Linux "
    "carries the PARENT's peak RSS over fork/vfork + exec into it)"
)


def _peak_rss_mib(code: str, env: dict[str, str]) -> tuple[float, float]:
    """(VmHWM, ru_maxrss) [MiB] of a fresh interpreter running ``code``."""
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        proc = subprocess.Popen([sys.executable, "-c", code], env=env, stdout=out, stderr=err)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        if proc.returncode != 0:
            err.seek(0)
            lines = err.read().decode(errors="replace").strip().splitlines() or ["(no output)"]
            raise RuntimeError(f"child exited {proc.returncode}: {lines[-1]}")
        out.seek(0)
        reported = [
            line.split()[1]
            for line in out.read().decode(errors="replace").splitlines()
            if line.startswith("PEAK_RSS_KIB")
        ]
    if not reported:
        raise RuntimeError("the child did not report its peak RSS")
    return int(reported[-1]) / 1024.0, usage.ru_maxrss / 1024.0  # Linux: KiB


def bench_memory(settings: Settings, ctx: Context) -> list[Metric]:
    env = subprocess_env()
    episode, episode_maxrss = _peak_rss_mib(_EPISODE_CHILD, env)
    baseline, baseline_maxrss = _peak_rss_mib(_IMPORT_CHILD, env)
    print(f"  memory/episode: {episode:.0f} MiB (imports alone: {baseline:.0f} MiB)", flush=True)
    return [
        Metric(
            "memory/episode",
            "memory/episode",
            "MiB",
            [episode],
            info={"method": MEMORY_METHOD, "ru_maxrss_mib": episode_maxrss},
        ),
        Metric(
            "memory/import",
            "memory/episode",
            "MiB",
            [baseline],
            info={
                "method": MEMORY_METHOD,
                "ru_maxrss_mib": baseline_maxrss,
                "what": "import doorlab, doorlab.episode.controllers, doorlab.episode.metrics",
            },
        ),
    ]
