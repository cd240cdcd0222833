"""doorlab bench: the benchmark card.

- the Wilson interval against published values (Newcombe 1998, Table I: the score interval
  without continuity correction) and its properties;
- the distribution: each episode's cupboard from (seed, episode) alone, in its ranges, the same
  for every controller; a bad distribution file is one line;
- success and failure defined once (classify), the summary's counts, rates and quantiles;
- a real benchmark (every controller of the registry and the example plug-in, a short
  timeline, 2 episodes each: one module fixture): bench.json's keys and numbers against its own
  table, the card's table and figures, --resume running only the new episodes, the same card
  (all but the cost) on a Dask LocalCluster.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from dask_local import plain_cluster

from doorlab.bench.distribution import (
    AXES,
    BenchDistribution,
    draw_episode,
    load_distribution,
    plan_bench,
)
from doorlab.bench.measures import ROBOSUITE_OPEN_RAD, classify
from doorlab.bench.stats import QUANTILES, summarize, wilson_interval
from doorlab.cli.parser import main
from doorlab.config import Scenario
from doorlab.episode.controllers import REGISTRY
from doorlab.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = f"{ROOT / 'examples' / 'dls_controller.py'}:dls"
SHORT = [
    "timeline.arc_duration=4.0",
    "timeline.approach_duration=2.0",
    "timeline.hold_duration=0.5",
    "timeline.extra_time=0.5",
]
"""A short timeline (9 s simulated) on which the closed door opens for some plans and not for
others (a 4 s arc asks twice the problem set's speed)."""
EPISODES = 2


# --- Wilson -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("k", "n", "low", "high"),
    [(81, 263, 0.2553, 0.3662), (15, 148, 0.0624, 0.1605), (0, 20, 0.0, 0.1611),
     (1, 29, 0.0061, 0.1718)],
)  # fmt: skip
def test_wilson_matches_newcombes_table(k, n, low, high):
    """Newcombe, Statistics in Medicine 17 (1998) 857-872, Table I, method 3 (score)."""
    got = wilson_interval(k, n)
    assert got == pytest.approx((low, high), abs=5e-5)


def test_wilson_holds_what_an_interval_must():
    """In [0, 1], about p^ (0 and n included: not empty there, unlike Wald's), symmetric in
    successes and failures, narrower with more trials; 0/n's upper bound is z^2 / (n + z^2)."""
    z2 = 1.959963984540054**2
    for n in (1, 2, 5, 40, 1000):
        for k in range(0, n + 1, max(1, n // 7)):
            low, high = wilson_interval(k, n)
            assert 0.0 <= low <= k / n <= high <= 1.0
            mirror = wilson_interval(n - k, n)
            assert (low, high) == pytest.approx((1 - mirror[1], 1 - mirror[0]), abs=1e-12)
        assert wilson_interval(0, n) == pytest.approx((0.0, z2 / (n + z2)))
        assert wilson_interval(n, n)[1] == 1.0
    assert (
        np.diff([np.subtract(*wilson_interval(n // 2, n)[::-1]) for n in (10, 40, 160)]).max() < 0
    )
    for bad in ((-1, 5), (6, 5), (0, 0)):
        with pytest.raises(ValueError):
            wilson_interval(*bad)


# --- the distribution ---------------------------------------------------------------------


def test_an_episodes_cupboard_depends_on_the_seed_and_its_index_only():
    d = BenchDistribution()
    first = [draw_episode(d, 7, i) for i in range(5)]
    assert [draw_episode(d, 7, i) for i in range(5)] == first  # reproducible
    assert first[0] != first[1] and draw_episode(d, 8, 0) != first[0]
    runs = plan_bench(["velocity", "impedance"], episodes=5, seed=7)
    assert [r.values for r in runs[:5]] == [r.values for r in runs[5:]]  # the same cupboards
    assert [r.values["episode"] for r in runs] == [0, 1, 2, 3, 4] * 2
    longer = plan_bench(["velocity"], episodes=12, seed=7)
    assert [r.values for r in longer[:5]] == [r.values for r in runs[:5]]  # N does not matter
    assert list(runs[0].values) == list(AXES)
    s = runs[3].scenario
    v = runs[3].values
    assert s.station.cupboard_yaw_error == v["station.cupboard_yaw_error"]
    assert s.ik.grasp_offset == [v[f"ik.grasp_offset[{k}]"] for k in range(3)]
    assert (s.doors, s.controller) == ("closed", "velocity")


def test_the_draws_fill_their_ranges():
    d = BenchDistribution()
    draws = [draw_episode(d, 0, i) for i in range(400)]

    def column(key):
        return np.array([x[key] for x in draws])

    yaw = np.degrees(column("station.cupboard_yaw_error"))
    assert yaw.min() >= -d.yaw_error_deg and yaw.max() <= d.yaw_error_deg
    assert yaw.min() < -0.9 * d.yaw_error_deg and yaw.max() > 0.9 * d.yaw_error_deg
    for k, w in enumerate(d.position_error_mm):
        x = 1e3 * column(f"station.cupboard_position_error[{k}]")
        assert np.abs(x).max() <= w and np.abs(x).max() > 0.9 * w
    damping = np.log(column("station.hinge_damping"))
    low, high = np.log(d.hinge_damping)
    assert low <= damping.min() and damping.max() <= high
    assert abs(np.median(damping) - (low + high) / 2) < 0.15 * (high - low)  # log-uniform
    friction = column("station.friction")
    assert d.friction[0] <= friction.min() and friction.max() <= d.friction[1]


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("yaw_error_deg: 50\n", "distribution.yaw_error_deg"),
        ("position_error_mm: [1, 2]\n", "distribution.position_error_mm"),
        ("hinge_damping: [2.0, 1.0]\n", "distribution.hinge_damping"),
        ("grasp_offset_mm: [0, 0, 11]\n", "distribution.grasp_offset_mm"),
        ("windspeed: 3\n", "unknown field 'windspeed'"),
        ("friction: high\n", "friction must be a list"),
    ],
)
def test_a_bad_distribution_is_one_line_naming_the_field(tmp_path, text, needle, capsys):
    path = tmp_path / "d.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=re.escape(needle)):
        load_distribution(path)
    code = main(["bench", "--distribution", str(path), "--out", str(tmp_path / "b")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and needle in err, err
    assert not (tmp_path / "b").exists()


def test_a_distribution_file_keeps_the_defaults_it_leaves_out(tmp_path):
    path = tmp_path / "d.yaml"
    path.write_text("yaw_error_deg: 10.0\nhinge_damping: [1.0, 1.0]\n")
    d = load_distribution(path)
    assert d.yaw_error_deg == 10.0 and d.hinge_damping == [1.0, 1.0]
    assert d.position_error_mm == BenchDistribution().position_error_mm
    assert {draw_episode(d, 0, i)["station.hinge_damping"] for i in range(5)} == {1.0}


# --- success, defined once ----------------------------------------------------------------


def _row(status="ok", held=True, opening=0.70, hinge=0.72, threshold=0.6837):
    return {
        "controller": "c",
        "status": status,
        "handle_held": held,
        "door_opening_rad": opening,
        "hinge_max_rad": hinge,
        "open_threshold_rad": threshold,
    }


@pytest.mark.parametrize(
    ("row", "verdict"),
    [
        (_row(), (True, True, None)),
        (_row(opening=0.5, hinge=0.5), (False, True, "short")),
        (_row(opening=0.2, hinge=0.25), (False, False, "short")),
        (_row(status="slipped", held=False, hinge=0.4), (False, True, "slip")),
        (_row(held=False), (False, True, "slip")),
        (_row(status="safety_stop", opening=None, hinge=0.31), (False, True, "stop")),
        (_row(status="speed_limit"), (False, True, "stop")),
        (_row(status="ik_failed", opening=None, hinge=None), (False, False, "error")),
        (_row(status="controller_error", opening=None, hinge=0.1), (False, False, "error")),
        (_row(status="error", opening=None, hinge=None), (False, False, "error")),
    ],
)
def test_each_episode_is_a_success_or_one_kind_of_failure(row, verdict):
    assert classify(row) == verdict


def test_the_summary_counts_rates_intervals_and_quantiles():
    rows = [_row() for _ in range(6)] + [_row(status="slipped", held=False)] * 2
    for r, x in zip(rows, range(8), strict=True):
        r["max_radial_error_m"] = 1e-3 * (x + 1)
    rows += [{**_row(), "controller": "other"}]
    summary = summarize(rows, ["c", "other", "absent"])
    assert list(summary) == ["c", "other"]
    c = summary["c"]
    assert (c["episodes"], c["successes"], c["success_rate"]) == (8, 6, 0.75)
    assert c["ci95"] == list(wilson_interval(6, 8))
    assert c["robosuite"]["successes"] == 8  # the hinge past 0.3 rad in every one
    assert c["failures"] == {"slip": 2, "stop": 0, "short": 0, "error": 0}
    radial = c["metrics"]["max_radial_error_m"]
    assert radial["n"] == 8 and radial["q50"] == pytest.approx(4.5e-3)
    assert radial["q05"] == pytest.approx(np.quantile(1e-3 * np.arange(1, 9), 0.05))
    assert c["metrics"]["time_to_open_s"] == {
        "what": "time to open, from the arc's start", "unit": "s", "n": 0, "mean": None,
        **{f"q{round(100 * q):02d}": None for q in QUANTILES},
    }  # fmt: skip


# --- a real benchmark -----------------------------------------------------------------------


def _controllers() -> list[str]:
    """Every controller of the registry, and the example plug-in."""
    return [*REGISTRY, EXAMPLE]


def _argv(out: Path, *extra: str) -> list[str]:
    argv = ["bench", "--out", str(out), "--episodes", str(EPISODES), "--seed", "3"]
    for controller in _controllers():
        argv += ["--controller", controller]
    for item in SHORT:
        argv += ["--set", item]
    return [*argv, *extra]


@pytest.fixture(scope="module")
def bench_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("bench") / "card"
    code = main(_argv(out, "--jobs", "2"))
    assert code == 0
    return out


def _results(out: Path) -> dict:
    """bench.json but what a run's machine and clock set (``cost``, ``machine``)."""
    document = json.loads((out / "bench.json").read_text())
    return {k: v for k, v in document.items() if k not in ("cost", "machine")}


@pytest.mark.slow
def test_the_card_holds_each_controllers_rates_and_distributions(bench_run):
    """bench.json: per controller the episodes, successes, rate, its Wilson interval, the
    failures by kind, the metrics' quantiles, each recomputed here from the table."""
    from doorlab.sweep import read_table

    document = json.loads((bench_run / "bench.json").read_text())
    table = read_table(bench_run)
    names = [*REGISTRY, "dls"]
    assert list(document["controllers"]) == names
    assert len(table) == len(names) * EPISODES
    assert document["bench"]["episodes"] == EPISODES and document["bench"]["seed"] == 3
    assert document["bench"]["specs"] == {"dls": EXAMPLE}
    for name, card in document["controllers"].items():
        mine = table[table["controller"] == name]
        verdicts = [classify(r) for r in mine.to_dict("records")]
        successes = sum(v[0] for v in verdicts)
        assert (card["episodes"], card["successes"]) == (EPISODES, successes)
        assert card["success_rate"] == successes / EPISODES
        assert card["ci95"] == pytest.approx(list(wilson_interval(successes, EPISODES)))
        assert sum(card["failures"].values()) == EPISODES - successes
        robosuite = (mine["hinge_max_rad"] > ROBOSUITE_OPEN_RAD).sum()
        assert card["robosuite"]["successes"] == robosuite
        radial = mine["max_radial_error_m"].dropna().to_numpy()
        quantiles = card["metrics"]["max_radial_error_m"]
        assert quantiles["n"] == len(radial)
        if len(radial):
            assert quantiles["q50"] == pytest.approx(np.median(radial))
        else:  # no episode had metrics (e.g. all stopped): no number, not NaN
            assert quantiles["q50"] is None
        assert card["metrics"]["max_radial_error_m"]["unit"] == "m"
    # the short arc separates them: some episodes open the door, some do not
    rates = [c["success_rate"] for c in document["controllers"].values()]
    assert min(rates) < max(rates)
    assert document["definition"]["open_threshold_deg"] == pytest.approx(
        math.degrees(math.radians(50) - math.atan2(0.041, 0.264)) - 2.0, abs=0.05
    )


@pytest.mark.slow
def test_the_page_is_self_contained_with_its_table_and_figures(bench_run):
    page = (bench_run / "index.html").read_text()
    for name in [*REGISTRY, "dls"]:
        assert f'data-controller="{name}"' in page
    assert page.count("data:image/png;base64,") == 4
    assert not re.search(r"""(src|href)=["']?(https?:)?//""", page)  # nothing fetched
    document = json.loads((bench_run / "bench.json").read_text())
    assert document["bench"]["command"] in page.replace("&#39;", "'")
    for row in document["distribution"]["draws"]:
        assert row["field"] in page
    manifest = json.loads((bench_run / ".doorlab-manifest.json").read_text())["files"]
    assert {"bench.json", "index.html", "results.parquet", "figures/success_rates.png"} <= set(
        manifest
    )


@pytest.mark.slow
def test_resume_runs_only_the_new_episodes_and_keeps_the_card(bench_run, tmp_path, capsys):
    """--resume with one more episode per controller runs only those (episode i's cupboard
    does not depend on N), the first episodes' rows unchanged."""
    import shutil

    from doorlab.sweep import read_table

    out = tmp_path / "card"
    shutil.copytree(bench_run, out)
    before = read_table(out)
    argv = _argv(out, "--resume")
    argv[argv.index("--episodes") + 1] = str(EPISODES + 1)
    assert main(argv) == 0
    document = json.loads((out / "bench.json").read_text())
    assert document["cost"]["episodes_run"] == len(_controllers())
    after = read_table(out)
    kept = after[after["episode"] < EPISODES].reset_index(drop=True)
    columns = ["controller", "episode", "key", "status", "max_radial_error_m", "success"]
    assert kept[columns].equals(before[columns])
    assert all(c["episodes"] == EPISODES + 1 for c in document["controllers"].values())
    capsys.readouterr()


@pytest.mark.slow
def test_the_same_card_on_a_dask_local_cluster(bench_run, tmp_path):
    """A LocalCluster (2 worker processes on loopback) through --scheduler, the same seed:
    the same numbers as the local run's, to the last digit (the same episodes: a scenario
    fully determines one), for the registry's first controller (one, to keep it cheap; the
    cupboards do not depend on which controllers run)."""
    pytest.importorskip("distributed")
    first = next(iter(REGISTRY))
    with plain_cluster(2) as cluster:
        out = tmp_path / "dask"
        argv = ["bench", "--out", str(out), "--episodes", str(EPISODES), "--seed", "3"]
        argv += ["--controller", first, "--scheduler", cluster.scheduler_address]
        assert main([*argv, *(w for item in SHORT for w in ("--set", item))]) == 0
    remote, local = _results(out), _results(bench_run)
    assert remote["controllers"] == {first: local["controllers"][first]}
    for key in ("definition", "distribution", "base_scenario"):
        assert remote[key] == local[key]
    assert "Dask cluster" in json.loads((out / "bench.json").read_text())["cost"]["executor"]


def test_a_broken_plug_in_is_one_line_and_exit_2(tmp_path, capsys):
    (tmp_path / "broken.py").write_text("raise RuntimeError('no gains')\n")
    code = main(["bench", "--controller", str(tmp_path / "broken.py:x"), "--out", str(tmp_path)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert "broken.py" in err and "RuntimeError: no gains" in err
    for argv in (["--resume", "--force"], ["--episodes", "0"]):
        assert main(["bench", *argv, "--out", str(tmp_path / "b")]) == 2
    capsys.readouterr()


def test_the_base_checks_the_safety_limits():
    from doorlab.bench.runner import bench_base

    assert bench_base().station.safety.enabled
    assert not Scenario().station.safety.enabled
