"""The grading costs the pages quote are the recorded benchmarks' figures: each number, as the
page prints it, computed here from the results file it cites (benchmarks/results/): the
README's "What grading costs", the teaching guide's (a correct folder, where its seconds go,
a class, the autograder's image) and the grader's explanation (what its rules cost a class).
A benchmark run again whose figures move fails this test until the page says what it
measured."""

from __future__ import annotations

import json
import re
import statistics
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
MIB = 2**20


def _page(path: str) -> str:
    """A page with its lines joined (a phrase may wrap)."""
    return re.sub(r"\s+", " ", (ROOT / path).read_text())


def _results(name: str) -> dict:
    return json.loads((RESULTS / name).read_text())


def _quoted() -> list[str]:
    """The README's phrases, each with the numbers computed from the results files."""
    batch = _results("pset-batch-issue26.json")
    figures = batch["figures"]
    minutes = {cores: seconds / 60 for cores, seconds in batch["class_of_200_wall_s"].items()}
    image = _results("pset-image-issue26.json")
    one_job = image["gradings"]["1"]

    def median(key: str) -> float:
        return statistics.median(g[key] for g in one_job)

    return [
        f"{figures['batch_1']['cpu_s_per_submission']:.1f} CPU-seconds per correct submission"
        " in a batch",
        f"once per class: {figures['reference']['cpu_s_per_submission']:.1f})",
        f"against {figures['alone']['cpu_s_per_submission']:.1f} graded alone and"
        f" {figures['baseline_alone']['cpu_s_per_submission']:.1f} with the grader before",
        f"grade at {batch['scaling_efficiency_2']:.2f} of twice 1 worker's rate",
        f"about {minutes['2']:.0f} minutes on 2 cores, {minutes['8']:.1f} on 8,"
        f" {minutes['32']:.1f} on 32",
        f"a venv of {image['venv_bytes'] / MIB:.0f} MiB",
        f"costs {median('cpu_s'):.1f} CPU-seconds ({median('wall_s'):.1f} s of wall time) and"
        f" peaks at {median('peak_pss_mib'):.0f} MiB",
    ]


def _teaching() -> list[str]:
    """The teaching guide's phrases (docs/guides/teaching.md), computed likewise."""
    grading = _results("pset-grading-issue26.json")
    profile = _results("pset-profile-issue26.json")
    cpu = {name: figure["cpu_s"] for name, figure in profile["figures"].items()}
    start = {k.removeprefix("start/"): v for k, v in cpu.items() if k.startswith("start/")}
    jobs = {k.removeprefix("job/"): v for k, v in cpu.items() if k.startswith("job/")}
    batch = _results("pset-batch-issue26.json")
    f = batch["figures"]
    image = _results("pset-image-issue26.json")
    units = sorted(v for k, v in jobs.items() if k.startswith("unit:"))

    def episodes(side: str) -> float:
        return sum(v for k, v in jobs.items() if k.startswith(f"{side}:"))

    def median(job_count: str, key: str) -> float:
        return statistics.median(g[key] for g in image["gradings"][job_count])

    per_minute = {n: 60 / f[f"batch_{n}"]["wall_s_per_submission"] for n in (1, 2)}
    low, high = batch["load"]
    return [
        f"grades in {grading['median_wall_s']['this']:.1f} s on this machine's 2 cores,"
        f" {grading['median_cpu_s']['this']:.1f} CPU-seconds, against"
        f" {grading['median_wall_s']['baseline']:.1f} s and"
        f" {grading['median_cpu_s']['baseline']:.1f} CPU-s for the grader of main 649b4e0"
        f" ({grading['ratio']:.2f} and {grading['cpu_ratio']:.2f} times; medians of"
        f" {len(grading['wall_s']['this'])} gradings each",
        f"{grading['busy_cores']:.2f} of 2 busy in all",
        f"With `--reference` a correct folder costs {f['alone']['cpu_s_per_submission']:.1f}"
        f" CPU-seconds against {f['baseline_alone']['cpu_s_per_submission']:.1f}"
        f" ({f['alone']['cpu_s_per_submission'] / f['baseline_alone']['cpu_s_per_submission']:.2f}"
        f" times; {f['alone']['wall_s_per_submission']:.1f} s against"
        f" {f['baseline_alone']['wall_s_per_submission']:.1f}",
        f"imported pydrake and the checks ({start['trusted_job_imports']:.2f} CPU-s each)",
        f"a student process in a view of its own ({start['student_process_in_own_view']:.2f}"
        f" CPU-s): {profile['process_starts_cpu_s']['before_issue_26']:.1f} CPU-s of process"
        " starts per grading",
        f"forks each job's trusted process ({start['trusted_fork']:.2f} CPU-s), and a view"
        f" ({start['view']:.2f} CPU-s to start) forks each test's student process"
        f" ({start['forked_student']:.2f} CPU-s):"
        f" {profile['process_starts_cpu_s']['now']:.1f} CPU-s per grading",
        f"simulation and ticks, {episodes('student'):.1f} CPU-s for a correct folder, the three"
        f" reference episodes', {episodes('reference'):.1f}, and"
        f" {units[0]:.2f}-{units[-1]:.2f} CPU-s per unit test",
        f"a class of {batch['submissions']} answer keys",
        f"medians of {batch['repeats']} repeats side by side, load average"
        f" {low:.1f}-{high:.1f} on the 2 cores",
        f"{f['batch_1']['cpu_s_per_submission']:.1f} CPU-seconds per submission on 1 worker"
        f" ({f['batch_1']['wall_s_per_submission']:.1f} s of wall time each:"
        f" {per_minute[1]:.1f} submissions a minute) and on 2 workers"
        f" ({f['batch_2']['wall_s_per_submission']:.1f} s each: {per_minute[2]:.1f} a minute,"
        f" {batch['scaling_efficiency_2']:.2f} of twice the 1-worker rate)",
        f"each graded alone with `--reference`, {f['alone']['cpu_s_per_submission']:.1f}"
        " CPU-s; by the grader of main 649b4e0 alone with `--reference`,"
        f" {f['baseline_alone']['cpu_s_per_submission']:.1f} CPU-s: a submission in a batch"
        f" costs {f['batch_1']['cpu_s_per_submission'] / f['baseline_alone']['cpu_s_per_submission']:.2f}"  # noqa: E501
        " times what it cost there",
        f"once per class: {f['reference']['cpu_s_per_submission']:.1f} CPU-s"
        f" ({f['reference']['wall_s_per_submission']:.1f} s)",
        f"A class of {batch['submissions']} untouched stubs (each test fails at its first"
        f" call): {f['batch_1_stubs']['cpu_s_per_submission']:.1f} CPU-s per submission",
        f"about {batch['class_of_200_wall_s']['2'] / 60:.0f} minutes on this 2-core machine",
        f"{batch['class_of_200_wall_s']['8'] / 60:.1f} on 8 cores,"
        f" {batch['class_of_200_wall_s']['32'] / 60:.1f} on 32 and"
        f" {batch['class_of_200_wall_s']['64'] / 60:.1f} on 64",
        f"against 200 x {f['baseline_alone']['wall_s_per_submission']:.1f} s ="
        f" {200 * f['baseline_alone']['wall_s_per_submission'] / 60:.0f} minutes one by one",
        f"other processes using {image['other_cpu']:.2f} of the 2 cores",
        f"a grading costs {median('1', 'cpu_s'):.1f} CPU-seconds (so at least"
        f" {2 * median('1', 'cpu_s'):.0f} s at half a CPU; {median('1', 'wall_s'):.1f} s of"
        f" wall time here) and peaks at {median('1', 'peak_pss_mib'):.0f} MiB",
        f"`--jobs 2` (for 2 CPUs) costs {median('2', 'cpu_s'):.1f} CPU-seconds, takes"
        f" {median('2', 'wall_s'):.1f} s and peaks at {median('2', 'peak_pss_mib'):.0f} MiB",
        f"no pandas, pyarrow or Dask: {image['venv_bytes'] / MIB:.0f} MiB;"
        f" {image['setup_s']:.0f} s here in the same benchmark's rehearsal",
    ]


def _grader() -> list[str]:
    """The grader's explanation's phrases (docs/explanation/grader.md): what issues 31's and
    43's rules cost a class, each beside main's grader of its day."""
    phrases = []
    for name in ("pset-batch-issue31.json", "pset-batch-issue43.json"):
        batch = _results(name)
        f = batch["figures"]
        this, base = f["batch_2"], f["baseline_batch_2"]
        stubs, base_stubs = f["batch_2_stubs"], f["baseline_batch_2_stubs"]
        low, high = batch["load"]
        phrases += [
            f"{this['cpu_s_per_submission']:.2f} CPU-s per correct submission against"
            f" {base['cpu_s_per_submission']:.2f} with main's grader",
            f"{stubs['cpu_s_per_submission']:.2f} against"
            f" {base_stubs['cpu_s_per_submission']:.2f} per untouched stubs"
            f" ({stubs['cpu_s_per_submission'] / base_stubs['cpu_s_per_submission']:.2f} times)",
            f"load average {low:.1f}-{high:.1f} on the 2 cores",
        ]
    return phrases


@pytest.mark.parametrize(
    ("page", "phrases"),
    [
        ("README.md", _quoted),
        ("docs/guides/teaching.md", _teaching),
        ("docs/explanation/grader.md", _grader),
    ],
)
def test_a_page_s_grading_costs_are_the_recorded_benchmarks(page, phrases):
    text = _page(page)
    missing = [phrase for phrase in phrases() if phrase not in text]
    assert missing == [], missing
