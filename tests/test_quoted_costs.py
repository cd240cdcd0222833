"""The costs the README quotes ("What grading costs") are the recorded benchmarks' figures:
each number, as the README prints it, computed here from the results file it cites
(benchmarks/results/pset-batch-issue26.json, pset-image-issue26.json). A benchmark run again
whose figures move fails this test until the README says what it measured."""

from __future__ import annotations

import json
import re
import statistics
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
MIB = 2**20


def _readme() -> str:
    """README.md with its lines joined (a phrase may wrap)."""
    return re.sub(r"\s+", " ", (ROOT / "README.md").read_text())


def _quoted() -> list[str]:
    """The README's phrases, each with the numbers computed from the results files."""
    batch = json.loads((RESULTS / "pset-batch-issue26.json").read_text())
    figures = batch["figures"]
    minutes = {cores: seconds / 60 for cores, seconds in batch["class_of_200_wall_s"].items()}
    image = json.loads((RESULTS / "pset-image-issue26.json").read_text())
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


def test_the_readme_s_grading_costs_are_the_recorded_benchmarks():
    readme = _readme()
    missing = [phrase for phrase in _quoted() if phrase not in readme]
    assert missing == [], missing
