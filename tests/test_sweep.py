"""Tests of ``doorlab sweep``: SPEC validation, the results table, failing runs, resume, Ctrl-C
and a real Dask LocalCluster giving the same rows as local processes.

Sweeps here are tiny: the short timeline of the report tests (about 10 s simulated) and a
failing run that costs no simulation (a cupboard out of the arm's reach: the one-shot IK to the
handle fails, status ik_failed). The local sweep is run once per module and shared.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from dask_local import plain_cluster

from doorlab.cli.parser import main
from doorlab.config import Scenario
from doorlab.errors import ConfigError
from doorlab.runtime.folders import staged_output
from doorlab.sweep import load_spec, parse_spec, plan_runs, read_table, run_one, run_sweep
from doorlab.sweep.results import RESULTS_CSV, RESULTS_PARQUET, TIMING_COLUMNS, write_table
from doorlab.sweep.spec import scenario_key

SHORT_TIMELINE = {
    "arc_duration": 2.0,
    "approach_duration": 2.0,
    "hold_duration": 0.5,
    "extra_time": 0.5,
}
"""The report tests' short timeline (see report_fixtures.short_scenario)."""

HOME = [0.9057, 0.0, 0.4148]
FAR = [2.5, 0.0, 0.4148]
"""Cupboard positions [m]: the default, and 2.5 m away (beyond the arm's ~0.8 m reach)."""

SPEC = {
    "scenario": {"timeline": SHORT_TIMELINE},
    "controllers": ["velocity"],
    "doors": ["closed"],
    "axes": {"station.cupboard_position": [FAR, HOME], "velocity.kv": [100.0, 200.0]},
}
"""Four runs: two ik_failed (cupboard out of reach, no simulation) and two short episodes."""


LONG_EXTRA_S = 120.0
"""The Ctrl-C test's long run's extra time [s]: 130 s simulated, 10 s of wall time on an idle
core here: the window in which the test must see the table's third row and its Ctrl-C reach
the sweep. At 40 s (3 s of wall time) a fresh clone's whole run missed it once: its Ctrl-C came
after the fourth run had ended ("interrupted; 4 finished runs")."""


def write_spec(folder: Path, data: dict, name: str = "spec.yaml") -> Path:
    path = folder / name
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.fixture(scope="module")
def local_sweep(tmp_path_factory) -> tuple[Path, Path, pd.DataFrame]:
    """(spec file, output folder, table) of SPEC run by the CLI on 2 local processes."""
    folder = tmp_path_factory.mktemp("sweep_local")
    spec = write_spec(folder, SPEC)
    out = folder / "out"
    code = main(["sweep", str(spec), "--out", str(out), "--jobs", "2"])
    assert code == 0
    return spec, out, read_table(out)


def metrics_only(frame: pd.DataFrame) -> pd.DataFrame:
    """The table without the columns a clock measured."""
    return frame.drop(columns=list(TIMING_COLUMNS)).reset_index(drop=True)


# ---------------------------------------------------------------------------------------------
# SPEC validation (no simulation).


def test_grid_runs_every_combination_with_its_scenario():
    spec = parse_spec(
        {
            "controllers": ["ik", "impedance"],
            "doors": ["open", "closed"],
            "axes": {
                "impedance.kv": [50, 100.0, 200.0],
                "station.hinge_damping": {"low": 0.2, "high": 5.0, "num": 3, "log": True},
            },
        }
    )
    runs = plan_runs(spec)
    assert len(runs) == 2 * 2 * 3 * 3
    assert len({run.key for run in runs}) == len(runs)
    damping = sorted({run.values["station.hinge_damping"] for run in runs})
    np.testing.assert_allclose(damping, [0.2, 1.0, 5.0], rtol=1e-12)  # geometric midpoint
    for run in runs:
        assert run.scenario.impedance.kv == run.values["impedance.kv"]
        assert run.scenario.station.hinge_damping == run.values["station.hinge_damping"]
        assert run.key == scenario_key(run.scenario)
    assert {(r.scenario.controller, r.scenario.doors) for r in runs} == {
        ("ik", "open"),
        ("ik", "closed"),
        ("impedance", "open"),
        ("impedance", "closed"),
    }


def test_random_samples_are_reproducible_and_within_their_ranges():
    data = {
        "controllers": ["impedance"],
        "axes": {
            "station.hinge_damping": {"low": 0.2, "high": 5.0, "log": True},
            "station.friction": {"low": 0.3, "high": 1.2},
            "impedance.kv": [50.0, 100.0],
        },
        "samples": 40,
        "seed": 7,
    }
    first = [run.values for run in plan_runs(parse_spec(data))]
    again = [run.values for run in plan_runs(parse_spec(data))]
    other = [run.values for run in plan_runs(parse_spec({**data, "seed": 8}))]
    assert first == again != other
    damping = np.array([v["station.hinge_damping"] for v in first])
    assert 0.2 <= damping.min() and damping.max() <= 5.0
    # log-uniform: about as many draws below the geometric mean (1.0) as above it
    assert 10 <= np.sum(damping < 1.0) <= 30
    assert {v["impedance.kv"] for v in first} == {50.0, 100.0}


def test_degree_axes_are_stored_in_radians():
    spec = parse_spec(
        {
            "axes": {
                "arc.angle_end_deg": [40.0],
                "station.friction": {"low": 0.5, "high": 1.0, "num": 2},
            }
        }
    )
    assert spec.axes[1].values == (0.5, 1.0)
    deg = parse_spec({"axes": {"ik.theta_bound": {"low": 1, "high": 2, "num": 2, "unit": "deg"}}})
    np.testing.assert_allclose(deg.axes[0].values, np.radians([1.0, 2.0]), rtol=1e-15)


EXAMPLES_DIR = Path(__file__).resolve().parents[1] / "examples"


@pytest.mark.parametrize("path", sorted(EXAMPLES_DIR.glob("sweep_*.yaml")), ids=lambda p: p.name)
def test_shipped_sweep_specs_load(path):
    """Every shipped SPEC loads, and each run's scenario validates (checked by load_spec)."""
    spec = load_spec(path)
    runs = plan_runs(spec)
    assert len(runs) == len(spec.controllers) * len(spec.doors) * np.prod(
        [len(a.values) for a in spec.axes]
    )


def test_grid_shorthand_adds_list_axes(tmp_path: Path):
    spec = load_spec(None, grid=["impedance.kv=50,100", "station.inner_loop.kind=stiffness"])
    assert [(a.field, a.values) for a in spec.axes] == [
        ("impedance.kv", (50, 100)),
        ("station.inner_loop.kind", ("stiffness",)),
    ]
    path = write_spec(tmp_path, {"controllers": ["ik"], "axes": {"impedance.kv": [1.0]}})
    merged = load_spec(path, grid=["impedance.kw=5,10"])
    assert [a.field for a in merged.axes] == ["impedance.kv", "impedance.kw"]
    assert merged.controllers == ["ik"]


BAD_SPECS = [
    ("unknown key", {"axes": {"impedance.kv": [1.0]}, "axis": {}}, ["unknown key 'axis'"]),
    ("unknown field", {"axes": {"impedance.kvv": [1.0]}}, ["impedance.kvv", "kv, kw"]),
    ("unknown group", {"axes": {"stationn.friction": [1.0]}}, ["stationn.friction"]),
    ("group, not a field", {"axes": {"station.gripper": [1.0]}}, ["station.gripper.kp"]),
    ("wrong type", {"axes": {"impedance.kv": [1.0, "stiff"]}}, ["axes.impedance.kv[1]", "number"]),
    ("empty axis", {"axes": {"impedance.kv": []}}, ["axes.impedance.kv is empty"]),
    ("key type", {"axes": {"impedance.kv": [1.0]}, "samples": "many"}, ["samples", "integer"]),
    ("list key type", {"axes": {"impedance.kv": [1.0]}, "doors": "closed"}, ["doors", "list"]),
    ("no axes", {"controllers": ["ik"]}, ["axes is empty"]),
    ("out of range", {"axes": {"impedance.kv": [100.0, -5.0]}}, ["impedance.kv", "> 0"]),
    ("bad controller", {"controllers": ["pid"], "axes": {"impedance.kv": [1.0]}}, ["pid"]),
    ("range without num", {"axes": {"impedance.kv": {"low": 1, "high": 2}}}, ["num"]),
    ("range key", {"axes": {"impedance.kv": {"low": 1, "hi": 2}}}, ["axes.impedance.kv.hi"]),
    (
        "scenario field",
        {"scenario": {"timeline": {"arc": 1}}, "axes": {"ik.knots": [2]}},
        ["scenario", "timeline.arc"],
    ),
    ("reserved field", {"axes": {"controller": ["ik"]}}, ["controllers"]),
]


@pytest.mark.parametrize(
    "data, expected", [c[1:] for c in BAD_SPECS], ids=[c[0] for c in BAD_SPECS]
)
def test_bad_spec_is_one_line_exit_2_and_writes_nothing(tmp_path: Path, capsys, data, expected):
    spec = write_spec(tmp_path, data)
    out = tmp_path / "out"
    assert main(["sweep", str(spec), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("doorlab sweep: error: "), err
    for text in expected:
        assert text in err, (text, err)
    assert not out.exists()
    with pytest.raises(ConfigError):
        load_spec(spec)


@pytest.mark.parametrize(
    "argv, expected",
    [
        (["sweep"], "SPEC"),
        (["sweep", "missing.yaml"], "does not exist"),
        (["sweep", "--grid", "impedance.kv"], "KEY=V1,V2"),
        (["sweep", "--grid", "impedance.kv=1", "--scheduler", "localhost"], "tcp://HOST:PORT"),
        (["sweep", "--grid", "impedance.kv=1", "--resume", "--force"], "exclude"),
        (["report", "--scheduler", "127.0.0.1:8786"], "tcp://HOST:PORT"),
    ],
)
def test_bad_command_line_is_exit_2(tmp_path: Path, capsys, argv, expected):
    out = tmp_path / "out"
    assert main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert expected in err and err.count("\n") == 1, err
    assert not out.exists()


@pytest.mark.slow
def test_an_unreachable_scheduler_is_exit_2_and_writes_nothing(tmp_path, capsys, monkeypatch):
    import doorlab.runtime.executor

    monkeypatch.setattr(doorlab.runtime.executor, "CONNECT_TIMEOUT_S", 2.0)
    out = tmp_path / "out"
    argv = ["sweep", "--grid", "impedance.kv=100", "--out", str(out)]
    assert main([*argv, "--scheduler", "tcp://127.0.0.1:9"]) == 2  # port 9: nobody listens
    err = capsys.readouterr().err
    assert "cannot reach the Dask scheduler at tcp://127.0.0.1:9" in err and err.count("\n") == 1
    assert not out.exists()


def test_an_exception_in_a_run_is_a_row(monkeypatch):
    """A bug inside a run (here: the controller raises) gives status error, not a crash."""
    import doorlab.episode.controllers

    def broken(scenario):
        raise RuntimeError("the physics engine caught fire")

    monkeypatch.setattr(doorlab.episode.controllers, "run_controller", broken)
    row = run_one(Scenario())
    assert row["status"] == "error"
    assert row["error"] == "RuntimeError: the physics engine caught fire"
    assert row["run_wall_time_s"] >= 0


# ---------------------------------------------------------------------------------------------
# Real sweeps.


@pytest.mark.slow
def test_table_has_a_row_per_run_with_metrics_and_failures(local_sweep):
    spec_path, out, table = local_sweep
    runs = plan_runs(load_spec(spec_path))
    assert list(table["run"]) == [r.index for r in runs]
    assert list(table["key"]) == [r.key for r in runs]
    far = table["station.cupboard_position"].map(lambda v: list(v) == FAR)
    # The cupboard out of reach: ik_failed rows with the IK's message and no metrics.
    assert (table.loc[far, "status"] == "ik_failed").all()
    assert table.loc[far, "error"].str.contains("IK").all()
    assert table.loc[far, "door_opening_arc_end_rad"].isna().all()
    # In reach: finished episodes, every metric of metrics.json present.
    done = table[~far]
    assert done["status"].isin(["ok", "slipped", "speed_limit"]).all()
    assert done["sim_time_s"].gt(5.0).all() and done["door_opening_arc_end_rad"].notna().all()
    assert list(done["velocity.kv"]) == [100.0, 200.0]
    # CSV and Parquet hold the same table.
    csv = pd.read_csv(out / RESULTS_CSV)
    assert list(csv.columns) == list(table.columns)
    np.testing.assert_allclose(
        csv["door_opening_arc_end_rad"], table["door_opening_arc_end_rad"].astype(float)
    )
    assert (out / "index.html").is_file() and not list(out.glob(".*.tmp"))


@pytest.mark.slow
def test_same_rows_on_a_dask_local_cluster(local_sweep, tmp_path: Path):
    """A real LocalCluster (scheduler + 2 worker processes on loopback) through --scheduler
    gives the local run's rows: the same scenarios, bit-identical metrics (a scenario fully
    determines an episode), wall times aside."""
    pytest.importorskip("distributed")
    spec_path, _, local = local_sweep
    with plain_cluster(2) as cluster:
        address = cluster.scheduler_address
        assert address.startswith("tcp://127.0.0.1:")
        out = tmp_path / "dask"
        assert main(["sweep", str(spec_path), "--out", str(out), "--scheduler", address]) == 0
    remote = read_table(out)
    pd.testing.assert_frame_equal(metrics_only(remote), metrics_only(local))
    assert "Dask cluster" in (out / "index.html").read_text()


@pytest.mark.slow
def test_resume_runs_only_the_missing_runs(local_sweep, tmp_path: Path):
    spec_path, out, table = local_sweep
    folder = tmp_path / "resume"
    with staged_output(folder, force=False):  # a sweep folder as doorlab makes it
        pass
    kept = table.drop(index=0)  # the first run (ik_failed: costs no simulation) is "missing"
    write_table(kept, folder)  # written by doorlab: in the folder's manifest
    assert main(["sweep", str(spec_path), "--out", str(folder)]) == 2  # exists: needs --resume
    assert main(["sweep", str(spec_path), "--out", str(folder), "--resume"]) == 0
    resumed = read_table(folder)
    pd.testing.assert_frame_equal(metrics_only(resumed), metrics_only(table))
    # The kept rows were not re-run: their measured wall times are the old ones, bit for bit.
    pd.testing.assert_frame_equal(
        resumed.drop(index=0).reset_index(drop=True), kept.reset_index(drop=True)
    )


@pytest.mark.slow
def test_ctrl_c_leaves_the_finished_runs_and_resume_completes(local_sweep, tmp_path: Path):
    """SIGINT while the last run simulates: exit 130, a table of exactly the finished runs;
    --resume then runs only that run, and the others keep their rows (the short episode's
    equal to the local sweep's run of the same scenario)."""
    _, _, local = local_sweep
    # Runs in order (one worker): two ik_failed, the short episode, a long one (LONG_EXTRA_S
    # more: the window in which this test sees the third row and its Ctrl-C reaches the sweep;
    # the table is written as each run ends, even after a slow first write:
    # test_each_finished_run_reaches_the_table_after_a_slow_first_write).
    axes = {"station.cupboard_position": [FAR, HOME], "timeline.extra_time": [0.5, LONG_EXTRA_S]}
    spec_path = write_spec(tmp_path, {**SPEC, "axes": axes})
    out = tmp_path / "out"
    command = [sys.executable, "-m", "doorlab.cli", "sweep", str(spec_path), "--out", str(out)]
    process = subprocess.Popen(
        [*command, "--jobs", "1"],
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "MPLBACKEND": "Agg"},
    )
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        table = read_table(out) if (out / RESULTS_PARQUET).is_file() else None
        if table is not None and len(table) >= 3:
            break
        assert process.poll() is None, process.stderr.read()
        time.sleep(0.05)
    else:
        process.kill()
        pytest.fail("the first three runs did not finish in time")
    process.send_signal(signal.SIGINT)  # the long episode has just started
    _, err = process.communicate(timeout=60)
    assert process.returncode == 130, err
    assert "interrupted; 3 finished runs" in err, err[-600:]
    table = read_table(out)
    assert list(table["run"]) == [0, 1, 2]
    assert list(table["status"].iloc[:2]) == ["ik_failed", "ik_failed"]
    assert len(pd.read_csv(out / RESULTS_CSV)) == 3
    assert not list(out.glob(".*.tmp"))

    assert main([*command[3:], "--resume", "--jobs", "1"]) == 0
    done = read_table(out)
    assert list(done["run"]) == [0, 1, 2, 3]
    pd.testing.assert_frame_equal(done.iloc[:3], table)  # kept as they were, not re-run
    assert done["sim_time_s"].iloc[3] == pytest.approx(
        done["sim_time_s"].iloc[2] + LONG_EXTRA_S - 0.5
    )
    # The short episode is the local sweep's run with the same scenario (same key, metrics).
    row = done.iloc[[2]].drop(columns=["run", "timeline.extra_time"])
    match = local[local["key"] == row["key"].iloc[0]].drop(columns=["run", "velocity.kv"])
    assert len(match) == 1
    pd.testing.assert_frame_equal(
        metrics_only(row).reset_index(drop=True), metrics_only(match).reset_index(drop=True)
    )


def test_run_sweep_api_returns_the_table_without_writing(tmp_path: Path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    spec = parse_spec(
        {
            "axes": {"station.cupboard_position": [FAR]},
            "controllers": ["velocity"],
            "doors": ["closed"],
        }
    )
    frame = run_sweep(spec, jobs=1)
    assert list(frame["status"]) == ["ik_failed"] and list(frame["run"]) == [0]
    assert not list(tmp_path.iterdir())


@pytest.mark.slow
def test_each_finished_run_reaches_the_table_after_a_slow_first_write(tmp_path, monkeypatch):
    """The table on disk follows the finished runs even when the sweep's first write (the
    empty table, which imports the Parquet writer) was slow: its time does not set how often
    the table is rewritten (a half-second first write on a loaded machine once kept the next
    runs off the disk for 5 s)."""
    import doorlab.sweep.execution as execution

    written = []

    def write(frame, out):
        # Only the first write takes time: a real write's duration follows the machine's load
        # (the next write is due 10 x the last one's time later: a write of a tenth of an
        # episode's time skips a row; on CI's loaded cores the test failed with [0, 1, 3, 3]),
        # which is not what this test is about.
        if not written:
            time.sleep(1.0)  # a slow first write
        written.append(len(frame))

    monkeypatch.setattr(execution, "write_table", write)
    # The timed write builds its table too: pandas, a few ms, tens on loaded cores (a fresh
    # clone's run failed with [0, 1, 3, 3] again with only that in the timing). The rows as
    # they are instead: the later writes then take microseconds whatever the load.
    monkeypatch.setattr(execution, "make_table", lambda rows, *args: list(rows))
    spec = parse_spec({**SPEC, "axes": {"velocity.kv": [100.0, 200.0, 300.0]}})  # 3 episodes
    run_sweep(spec, tmp_path / "out", jobs=1, page=False)
    # Each episode takes 0.3 s or more, the later writes microseconds: each row is written as
    # its run ends (under the old rule, 10 x the first write's 1 s would have skipped rows 1-2).
    assert written[:4] == [0, 1, 2, 3] and set(written[4:]) <= {3}, written


@pytest.mark.slow
def test_sweep_page_renders_in_chromium(local_sweep, tmp_path: Path):
    """The sweep page is self-contained and renders in headless Chromium: every embedded plot
    decodes, every table has rows; one plot per axis, a heatmap for the pair of grid axes."""
    from test_report_browser import render_check

    _, out, table = local_sweep
    page = (out / "index.html").read_text(encoding="utf-8")
    assert "http://" not in page and "https://" not in page and "<script" not in page.lower()
    assert "@media print" in page  # the shared stylesheet: figures do not break across pages
    images = re.findall(r'<img src="data:image/png;base64,', page)
    assert len(images) == 2 + 1  # two axes, one pair of axes
    rows = re.findall(r'<tr data-run="(\d+)"', page)
    assert [int(r) for r in rows] == list(table["run"])
    result = render_check(page, tmp_path)
    assert result["images"] == len(images)
    assert result["broken_images"] == []
    assert result["tables"] == len(re.findall(r"<table\b", page)) >= 3
    assert result["empty_tables"] == []


@pytest.mark.slow
def test_page_of_random_samples_marks_failures_without_simulating(tmp_path: Path):
    """A page from a hand-made table (random draws of two axes, no heatmaps): every run is a
    table row, runs without metrics and runs not ok are marked, nothing is simulated."""
    from doorlab.sweep.page import build_sweep_page
    from doorlab.sweep.results import make_table

    spec = parse_spec(
        {
            "controllers": ["ik", "impedance"],
            "doors": ["closed"],
            "axes": {
                "station.hinge_damping": {"low": 0.2, "high": 5.0, "log": True},
                "station.cupboard_yaw_error": {"low": -10, "high": 10, "unit": "deg"},
            },
            "samples": 6,
        }
    )
    rows = []
    for run in plan_runs(spec):
        status = ("ok", "slipped", "ik_failed")[run.index % 3]
        row = {
            "run": run.index,
            "key": run.key,
            "controller": run.scenario.controller,
            "doors": "closed",
            **run.values,
            "status": status,
            "run_wall_time_s": 1.0,
        }
        if status != "ik_failed":
            row.update(
                door_opening_arc_end_rad=0.1 * run.index,
                peak_external_torque_arc_Nm=2.0,
                max_radial_error_m=0.001,
                max_orientation_error_rad=0.01,
            )
        else:
            row["error"] = "IK found no solution"
        rows.append(row)
    frame = make_table(rows, [a.field for a in spec.axes])
    page = build_sweep_page(frame, spec, tmp_path).read_text()
    assert len(re.findall(r"<img ", page)) == 2  # one figure per axis, no heatmaps
    assert len(re.findall(r'<tr data-run="\d+" class="failed">', page)) == 4
    assert len(re.findall(r'<tr data-run="\d+" class="warn">', page)) == 4
    assert "IK found no solution" in page and "log-uniform in [0.200, 5.00]" in page
    assert "uniform in [-10.0, 10.0] deg" in page
