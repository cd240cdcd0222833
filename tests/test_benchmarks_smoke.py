"""Smoke test of the benchmark CLI: it runs and writes well-formed JSON.

No timing assertions: speed targets live in benchmarks/ (printed as pass/fail there), never in
unit tests, whose timings depend on the machine and its load.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import doorlab

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "benchmarks" / "run_benchmarks.py"
SMOKE_TIMEOUT_S = 120
"""Generous bound on a run that takes ~2-5 s (a hung run should fail, a slow machine not)."""


def _env() -> dict[str, str]:
    env = dict(os.environ)
    src = str(Path(doorlab.__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (src, env.get("PYTHONPATH", "")) if p)
    env["MPLBACKEND"] = "Agg"
    return env


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(SCRIPT), *args],
        env=_env(),
        capture_output=True,
        text=True,
        timeout=SMOKE_TIMEOUT_S,
    )


@pytest.mark.slow
def test_quick_run_writes_positive_metrics(tmp_path):
    """--quick --only tick/velocity ik/10_knots exits 0 and saves positive medians, min, max."""
    out = tmp_path / "quick.json"
    proc = _run("--quick", "--only", "tick/velocity", "ik/10_knots", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    data = json.loads(out.read_text())
    for key in ("machine", "settings", "metrics", "created"):
        assert key in data
    assert data["machine"]["cpu_model"] and data["machine"]["drake"]
    for key, unit in (("tick/velocity", "us"), ("ik/10_knots", "s")):
        metric = data["metrics"][key]
        assert metric["unit"] == unit
        assert metric["n"] == 1
        for stat in ("median", "min", "max"):
            assert isinstance(metric[stat], float) and metric[stat] > 0, (key, stat)
        assert metric["passed"] in (True, False)  # a target exists; its outcome is not tested
    assert data["errors"] == {}
    assert "tick/velocity" in proc.stdout  # the table


@pytest.mark.slow
def test_compare_against_itself_has_no_regression(tmp_path):
    """--compare with a previous file prints new/old ratios (same metrics, so no 'new' rows)."""
    old = tmp_path / "old.json"
    assert _run("--quick", "--only", "ik/2_knots", "--out", str(old)).returncode == 0
    new = tmp_path / "new.json"
    proc = _run("--quick", "--only", "ik/2_knots", "--out", str(new), "--compare", str(old))
    assert proc.returncode == 0, proc.stderr
    assert "new/old" in proc.stdout


def test_bad_arguments_exit_2_with_one_line(tmp_path):
    """Unknown benchmark names and bad repeats are usage errors: exit 2, one line on stderr."""
    for args in (["--only", "no_such_benchmark"], ["--repeats", "0"]):
        proc = _run(*args, "--out", str(tmp_path / "x.json"))
        assert proc.returncode == 2
        assert len(proc.stderr.strip().splitlines()) == 1
        assert not (tmp_path / "x.json").exists()


@pytest.mark.slow
def test_the_python_variant_replays_the_episode_it_is_compared_with():
    """design/*'s python variant (the Python runner replaying the recorded commands) must
    simulate the very episode it times against: the same joint trajectory and door, bit for
    bit at the shared log times, or its ratio to the floor would compare different physics."""
    import numpy as np

    sys.path.insert(0, str(REPO / "benchmarks"))
    try:
        from designs import recorded_commands, replay_episode
    finally:
        sys.path.remove(str(REPO / "benchmarks"))
    scenario, recorded = recorded_commands("impedance", "closed")
    replayed = replay_episode(scenario, recorded)
    common, i_rec, i_rep = np.intersect1d(
        np.round(recorded.t, 9), np.round(replayed.t, 9), return_indices=True
    )
    assert len(common) == len(replayed.t)
    np.testing.assert_array_equal(replayed.q_measured, recorded.q_measured[i_rec])
    np.testing.assert_array_equal(replayed.door_angles, recorded.door_angles[i_rec])


def test_the_bench_guide_s_card_is_the_recorded_one_of_every_built_in():
    """docs/guides/bench.md's table of the card at 200 episodes (``docs/figures/bench_200``,
    checked against the page by test_docs.py) is what ``bench_scale.py --table`` prints of the
    recorded card; that card holds every built-in of the registry, 200 episodes each, and the
    recorded comparison found it identical on a LocalCluster (all but the costs)."""
    from doorlab.config import CONTROLLERS

    sys.path.insert(0, str(REPO / "benchmarks"))
    try:
        from bench_scale import table
    finally:
        sys.path.remove(str(REPO / "benchmarks"))
    results = REPO / "benchmarks" / "results"
    card = json.loads((results / "bench_card_200.json").read_text())
    assert list(card["controllers"]) == list(CONTROLLERS)
    assert {c["episodes"] for c in card["controllers"].values()} == {200}
    shown = (REPO / "docs" / "figures" / "bench_200" / "table.md").read_text()
    assert shown == table(card)
    compared = json.loads((results / "bench_compare_200.json").read_text())
    assert compared["same_card"] is True
    assert compared["episodes"] == [200, 200]
    assert {n: r["successes"] for n, r in compared["rates"].items()} == {
        n: c["successes"] for n, c in card["controllers"].items()
    }
    # What the guide says of the table, read off the card.
    rates = card["controllers"]
    top = sorted(rates, key=lambda n: rates[n]["success_rate"], reverse=True)[:3]
    assert set(top) == {"diffik", "velocity", "osc"}, top  # "open the most cupboards"
    for a in top:  # "their intervals overlap"
        for b in top:
            assert rates[a]["ci95"][0] <= rates[b]["ci95"][1], (a, b)
    impedance = rates["impedance"]
    assert impedance["robosuite"]["success_rate"] == 1.0  # "never fails" under robosuite's
    failures = impedance["failures"]
    assert max(failures, key=failures.get) == "short"  # "its commonest failure"
    stopped = {n for n, c in rates.items() if c["failures"]["stop"] > 0}
    assert stopped == {"adaptive"}  # "the only one the ... safety limits stop"
