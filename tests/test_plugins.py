"""Controller plug-ins (doorlab.episode.plugins): a controller written outside doorlab, as a
file, a module or an installed package, runs through every command with every output a
built-in gets; a broken one is one line naming it and exit 2, never a traceback; a tick's
exception ends the run with status controller_error, its logs kept; on the arm's path the same
safety checks stop it.

The plug-ins are small files written into a temporary folder; the installed one is the example
package (examples/doorlab-feedforward) made visible by a ``.dist-info`` folder with its
entry points (what pip writes), so nothing is installed into the environment.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from fake_driver import FakeDriver
from report_fixtures import short_scenario

from doorlab.cli.parser import main
from doorlab.config import CONTROLLERS, load_scenario, validate
from doorlab.config_checks import controller_spec, installed_controller_names
from doorlab.constants import Q_HOME
from doorlab.control.plan_base import ArmState
from doorlab.episode import plugins
from doorlab.episode.contract import ArcPlan, Controller
from doorlab.episode.controllers import REGISTRY, get_controller
from doorlab.episode.result import EpisodeResult
from doorlab.errors import ConfigError, ControllerError, IkError, PluginError

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE_FILE = ROOT / "examples" / "dls_controller.py"
EXAMPLE_PACKAGE = ROOT / "examples" / "doorlab-feedforward"

PLUGINS = '''\
import numpy as np
import doorlab
from doorlab.episode.controllers import build_velocity_plan


def good(scenario, geometry, plant):
    """The velocity plan, as a plug-in."""
    return build_velocity_plan(scenario, geometry, plant)


NAMED = doorlab.Controller("tidy", title="Tidy", summary="a named one", build=good)
CLASH = doorlab.Controller("velocity", build=good)
NOT_CALLABLE = 3


class NotAController:
    pass


def two_arguments(scenario, geometry):
    return None


def raises_at_build(scenario, geometry, plant):
    return {}["missing key"]


def returns_nothing(scenario, geometry, plant):
    return None


class Failing:
    """A plan whose tick fails after t_fail [s] in one of several ways."""

    name = "failing"
    duration = 2.0

    def __init__(self, how, t_fail=0.1024):  # between two ticks: clear of float rounding
        self.how, self.t_fail = how, t_fail

    def command(self, t, state):
        if t < self.t_fail:
            return doorlab.Command(state.q, np.zeros(7))
        if self.how == "raise":
            return 1 / 0
        if self.how == "nan":
            return doorlab.Command(state.q * np.nan, np.zeros(7))
        if self.how == "shape":
            return doorlab.Command(state.q[:6], np.zeros(7))
        if self.how == "jump":  # half a radian at once: the safety checks refuse it
            return doorlab.Command(state.q + 0.5, np.zeros(7))
        return "not a command"


def failing(how):
    def build(scenario, geometry, plant):
        arc = build_velocity_plan(scenario, geometry, plant)
        return doorlab.ArcPlan(Failing(how), arc.q_start)
    return build


raise_in_tick = failing("raise")
nan_in_tick = failing("nan")
shape_in_tick = failing("shape")
text_in_tick = failing("text")
jump_in_tick = failing("jump")
'''


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    """A folder with plug-in files: ctl.py (good and broken ones), broken.py (NameError at
    line 2), syntax.py (a syntax error at line 3)."""
    root = tmp_path_factory.mktemp("plugins")
    (root / "ctl.py").write_text(PLUGINS)
    (root / "broken.py").write_text("import math\nvalue = undefined_name + 1\n")
    (root / "syntax.py").write_text("def build(scenario, geometry, plant):\n    return (\n\n")
    return root


def spec(folder: Path, name: str) -> str:
    return f"{folder / 'ctl.py'}:{name}"


# --- the spec's forms ------------------------------------------------------------------------


def test_a_spec_is_a_built_in_a_file_a_module_or_an_installed_name():
    assert controller_spec("velocity", CONTROLLERS).kind == "builtin"
    file = controller_spec("my/ctl.py:build", CONTROLLERS)
    assert (file.kind, file.target, file.name) == ("file", "my/ctl.py", "build")
    module = controller_spec("pkg.mod:CONTROLLER", CONTROLLERS)
    assert (module.kind, module.target, module.name) == ("module", "pkg.mod", "CONTROLLER")
    for bad in ("bogus", "", " velocity", "ctl.py:", ":build", "ctl.py:not-a-name", "a b:c"):
        with pytest.raises(ConfigError) as info:
            controller_spec(bad, CONTROLLERS)
        assert "FILE.py:NAME" in str(info.value)
    with pytest.raises(ConfigError, match="ik, velocity, impedance"):
        validate(short_scenario("bogus"))


def test_a_scenario_or_spec_file_names_a_plug_in_beside_it(folder, tmp_path, monkeypatch):
    """A relative FILE in a scenario YAML or a SPEC is relative to that file, from any working
    directory; on the command line, to the working directory."""
    (folder / "scenario.yaml").write_text("controller: ctl.py:good\n")
    monkeypatch.chdir(tmp_path)
    assert load_scenario(folder / "scenario.yaml").controller == spec(folder, "good")
    from doorlab.sweep import parse_spec

    data = {"controllers": ["ctl.py:good", "velocity"], "axes": {"velocity.kv": [50, 100]}}
    parsed = parse_spec(data, base_dir=folder)
    assert parsed.controllers == [spec(folder, "good"), "velocity"]
    from doorlab.cli.commands import controller_option

    monkeypatch.chdir(folder)
    assert controller_option("ctl.py:good") == spec(folder, "good")


# --- loading ---------------------------------------------------------------------------------


def test_a_function_or_a_controller_is_a_plug_in(folder):
    good = get_controller(spec(folder, "good"))
    assert isinstance(good, Controller) and good.name == "good" and good.task is None
    assert good.summary == "The velocity plan, as a plug-in."
    named = get_controller(spec(folder, "NAMED"))
    assert (named.name, named.title) == ("tidy", "Tidy")
    assert get_controller(spec(folder, "good")) is good  # loaded once per process
    assert get_controller("velocity") is REGISTRY["velocity"]
    # what a failed run's folder is named by, whatever its controller was
    assert plugins.display_name("teleport") == "teleport"
    assert plugins.display_name(str(folder / "broken.py:build")) == "build"


BROKEN = [
    ("import", "broken.py:build", ["failed to import", "NameError", "broken.py, line 2"]),
    ("syntax", "syntax.py:build", ["failed to import", "SyntaxError", "syntax.py, line"]),
    ("no file", "missing.py:build", ["no file"]),
    ("no name", "ctl.py:absent", ["has no 'absent'", "it defines", "good"]),
    ("signature", "ctl.py:two_arguments", ["(scenario, geometry)", "(scenario, geometry, plant)"]),
    ("a class", "ctl.py:NotAController", ["is a class"]),
    ("not callable", "ctl.py:NOT_CALLABLE", ["is a int"]),
    ("a built-in's name", "ctl.py:CLASH", ["'velocity', a built-in controller's name"]),
    ("no module", "no_such_module_here:build", ["no module named 'no_such_module_here'"]),
]


@pytest.mark.parametrize(("text", "needles"), [c[1:] for c in BROKEN], ids=[c[0] for c in BROKEN])
def test_a_broken_plug_in_is_one_line_naming_it(folder, text, needles):
    name = str(folder / text) if ".py" in text else text
    with pytest.raises(PluginError) as info:
        get_controller(name)
    message = str(info.value)
    assert "\n" not in message and "Traceback" not in message
    assert text.split(":")[0] in message
    for needle in needles:
        assert needle in message


@pytest.mark.parametrize("case", ["signature", "import"])
def test_the_command_line_says_one_line_and_exits_2_writing_nothing(folder, case, capsys):
    target = {"signature": "ctl.py:two_arguments", "import": "broken.py:build"}[case]
    out = folder / f"out_{case}"
    for command in (["run", "--out", str(out)], ["sweep", "--grid", "velocity.kv=50"]):
        code = main([*command, "--controller", str(folder / target)])
        err = capsys.readouterr().err.strip()
        assert code == 2, err
        assert len(err.splitlines()) == 1 and target.split(":")[0] in err, err
    assert not out.exists()


def test_an_installed_plug_in_is_found_by_its_entry_point(tmp_path, monkeypatch):
    """A distribution's entry point of the group doorlab.controllers names the controller; it
    is called by the entry point's name (the example package's, with its own pyproject's)."""
    site = _installed_example(tmp_path)
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.syspath_prepend(str(EXAMPLE_PACKAGE / "src"))
    installed_controller_names.cache_clear()
    try:
        assert "feedforward" in installed_controller_names()
        assert controller_spec("feedforward", CONTROLLERS).kind == "entry_point"
        controller = get_controller("feedforward")
        assert controller.name == "feedforward" and controller.title.startswith("Velocity")
        with pytest.raises(ConfigError, match="installed: feedforward"):
            controller_spec("feedfwd", CONTROLLERS)
    finally:
        installed_controller_names.cache_clear()
        plugins._loaded.pop("feedforward", None)


def _installed_example(root: Path) -> Path:
    """A site folder holding the example package's ``.dist-info`` (METADATA and the entry
    points of its pyproject.toml), as ``pip install`` writes it."""
    import tomllib

    project = tomllib.loads((EXAMPLE_PACKAGE / "pyproject.toml").read_text())["project"]
    site = root / "site"
    info = site / f"{project['name'].replace('-', '_')}-{project['version']}.dist-info"
    info.mkdir(parents=True)
    info.joinpath("METADATA").write_text(
        f"Metadata-Version: 2.1\nName: {project['name']}\nVersion: {project['version']}\n"
    )
    lines = []
    for group, entries in project["entry-points"].items():
        lines.append(f"[{group}]")
        lines += [f"{name} = {value}" for name, value in entries.items()]
    info.joinpath("entry_points.txt").write_text("\n".join(lines) + "\n")
    return site


# --- the build and the ticks, watched --------------------------------------------------------


def _arc(folder: Path, name: str) -> ArcPlan:
    from doorlab.episode.controllers import episode_plans

    return episode_plans(validate(short_scenario(spec(folder, name))))[2]


def test_a_build_that_raises_or_returns_no_arc_plan_is_one_line(folder):
    with pytest.raises(PluginError) as info:
        _arc(folder, "raises_at_build")
    line = PLUGINS.splitlines().index('    return {}["missing key"]') + 1
    assert f"its build raised KeyError: 'missing key' (ctl.py, line {line})" in str(info.value)
    with pytest.raises(PluginError, match="returned a NoneType, not an ArcPlan"):
        _arc(folder, "returns_nothing")


def test_a_builds_ik_failure_is_a_result_as_for_a_built_in(folder, monkeypatch):
    def no_solution(scenario, geometry, plant):
        raise IkError("no solution at knot 3", knot=3)

    controller = Controller("ikless", build=no_solution)
    with pytest.raises(IkError):
        plugins.build_arc(controller, "ikless.py:x", None, None, None)


@pytest.mark.parametrize(
    ("how", "needle"),
    [
        ("raise", "raised at t = 0.102 s of its plan: ZeroDivisionError: division by zero"),
        ("nan", "q_ref of shape 7 with 7 non-finite values"),
        ("shape", "q_ref of shape 6"),
        ("text", "returned a str"),
    ],
)
def test_a_tick_that_fails_is_a_controller_error(folder, how, needle):
    arc = _arc(folder, f"{how}_in_tick")
    state = ArmState(arc.q_start, np.zeros(7), np.zeros(7))
    np.testing.assert_array_equal(arc.plan.command(0.05, state).q_ref, arc.q_start)
    with pytest.raises(ControllerError) as info:
        arc.plan.command(0.1024, state)
    assert needle in str(info.value) and "'failing'" not in str(info.value)
    assert info.value.status == "controller_error"
    assert arc.plan.how == how  # the plan's own attributes stay reachable


@pytest.mark.slow
def test_a_tick_exception_ends_the_run_with_its_status_and_logs(folder, tmp_path, capsys):
    """doorlab run: status controller_error, exit 2, one line on stderr naming the plug-in;
    log.npz holds the episode up to the failing tick, metrics.json the error."""
    out = tmp_path / "run"
    code = main(
        ["run", "--controller", spec(folder, "raise_in_tick"), "--out", str(out)] + _short_args()
    )
    captured = capsys.readouterr()
    assert code == 2
    errors = captured.err.strip().splitlines()
    assert len(errors) == 1 and "raise_in_tick" in errors[0] and "ZeroDivisionError" in errors[0]
    assert "Traceback" not in captured.out + captured.err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["status"] == "controller_error"
    assert metrics["controller"] == "raise_in_tick"
    log = EpisodeResult.load(out / "log.npz")
    t_fail = log.arc_window[0] + 0.105  # the plan's first tick after 0.1024 s raised
    assert t_fail - 0.02 <= log.t[-1] <= t_fail + 0.01


def _short_args() -> list[str]:
    return [
        "--set", "timeline.arc_duration=2.0",
        "--set", "timeline.approach_duration=2.0",
        "--set", "timeline.hold_duration=0.5",
        "--set", "timeline.extra_time=0.5",
        "--no-replay",
    ]  # fmt: skip


# --- every command, every output -------------------------------------------------------------


@pytest.mark.slow
def test_the_example_file_gets_every_output_a_built_in_gets(tmp_path):
    """examples/dls_controller.py through doorlab run: the same files as the velocity plan's
    run, metrics named after it, the door open and the handle held (short arc: 2 s)."""
    from doorlab.outputs.runs import run_to_folder

    folders = {}
    for name in ("velocity", f"{EXAMPLE_FILE}:dls"):
        scenario = short_scenario(name, "open")
        folders[name] = tmp_path / name.rpartition(":")[2]
        assert run_to_folder(scenario, folders[name], replay=True).status == "ok"
    files = [sorted(p.name for p in f.iterdir()) for f in folders.values()]
    assert files[0] == files[1] and "replay.html" in files[1] and len(files[1]) >= 10
    metrics = json.loads((folders[f"{EXAMPLE_FILE}:dls"] / "metrics.json").read_text())
    assert metrics["controller"] == "dls"
    scenario_yaml = (folders[f"{EXAMPLE_FILE}:dls"] / "scenario.yaml").read_text()
    assert f"controller: {EXAMPLE_FILE}:dls" in scenario_yaml  # the run can be run again


@pytest.mark.slow
def test_the_example_package_runs_by_its_installed_name(tmp_path):
    """The example package's own tests pass, and once its entry point is visible (its
    .dist-info), ``doorlab run --controller feedforward`` runs it in a fresh process."""
    site = _installed_example(tmp_path)
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(site), str(EXAMPLE_PACKAGE / "src")]),
    }
    tests = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-n", "0", "-p", "no:cacheprovider",
         str(EXAMPLE_PACKAGE / "tests")],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert tests.returncode == 0, tests.stdout[-3000:]
    assert "3 passed" in tests.stdout  # installed: the entry point test runs too
    doorlab = Path(sys.executable).with_name("doorlab")
    run = subprocess.run(
        [str(doorlab), "run", "--controller", "feedforward", "--doors", "open",
         "--out", "ff", *_short_args()],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-3000:]
    metrics = json.loads((tmp_path / "ff" / "metrics.json").read_text())
    assert (metrics["controller"], metrics["status"]) == ("feedforward", "ok")


# --- the arm's path: run --hardware ----------------------------------------------------------

Q0 = Q_HOME + np.array([0.1, 0.1, 0.0, 0.2, 0.0, 0.0, 0.0])  # as test_hardware_client's


def _hardware(folder: Path, tmp_path: Path, name: str):
    from doorlab.hardware.link import DriverLink
    from doorlab.hardware.run import run_hardware_to_folder

    scenario = short_scenario(spec(folder, name))
    t = scenario.timeline
    t.hold_duration, t.approach_duration, t.grasp_duration = 0.2, 1.0, 0.2
    t.arc_duration, t.extra_time = 3.0, 0.2
    driver = FakeDriver(Q0)
    link = DriverLink(driver.lcm, clock=driver.clock, pump=driver.pump)
    outcome = run_hardware_to_folder(
        validate(scenario), tmp_path / name, link=link, wait=1.0, confirm=lambda plan: True
    )
    return outcome, driver


@pytest.mark.slow
def test_on_the_arm_a_tick_exception_stops_commanding_there(folder, tmp_path):
    """run --hardware (an ideal fake arm, memq): the plug-in's failing tick is answered by no
    command; the run stops with controller_error, exit 2, its folder written."""
    outcome, driver = _hardware(folder, tmp_path, "raise_in_tick")
    assert (outcome.status, outcome.exit_code) == ("controller_error", 2)
    assert "ZeroDivisionError" in outcome.message
    metrics = json.loads((tmp_path / "raise_in_tick" / "metrics.json").read_text())
    assert metrics["stop"]["reason"] == "controller_error"
    arc_start = 0.2 + 1 + 1.0 + 1 + 0.2 + 1  # hold, move, grasp (each + 1 s)
    utimes = [c.utime for c in driver.commands]  # the first answers the episode's t = 0
    last_t = (max(utimes) - min(utimes)) * 1e-6
    assert last_t == pytest.approx(arc_start + 0.1)  # the tick at 0.105 s raised: no answer


@pytest.mark.slow
def test_on_the_arm_a_plug_ins_command_meets_the_same_safety_checks(folder, tmp_path):
    """A plug-in's jump of 0.5 rad is a safety stop before it is sent, as a built-in's is."""
    outcome, driver = _hardware(folder, tmp_path, "jump_in_tick")
    assert (outcome.status, outcome.exit_code) == ("safety_stop", 8)
    sent = np.array([c.joint_position for c in driver.commands])
    assert np.max(np.abs(np.diff(sent, axis=0))) < 0.1  # the jump never went out
    assert "safety stop" in outcome.message


@pytest.mark.slow
def test_the_example_file_runs_on_the_simulated_driver(tmp_path):
    """run --hardware's client and doorlab sim-driver's library on one memq bus (the arm
    preset on both sides, stepped: tests/stepped_driver.py): the example plug-in opens the
    door the whole path through, and its folder holds what a built-in's hardware run holds."""
    from stepped_driver import SteppedDriver

    from doorlab.hardware.link import DriverLink
    from doorlab.hardware.run import run_hardware_to_folder

    scenario = load_scenario(ROOT / "examples" / "kuka_arm.yaml")
    scenario.controller, scenario.doors = f"{EXAMPLE_FILE}:dls", "closed"
    t = scenario.timeline
    t.hold_duration, t.approach_duration, t.arc_duration, t.extra_time = 0.5, 4.0, 10.0, 0.0
    stepped = SteppedDriver(validate(scenario))
    link = DriverLink(stepped.lcm, clock=stepped.clock, pump=stepped.pump)
    outcome = run_hardware_to_folder(
        scenario, tmp_path / "arm", link=link, wait=1.0, confirm=lambda plan: True
    )
    assert (outcome.status, outcome.exit_code) == ("ok", 0), outcome.message
    files = {p.name for p in (tmp_path / "arm").iterdir()}
    assert {"log.npz", "metrics.json", "scenario.yaml", "replay.html", "door_angle.png"} <= files
    metrics = json.loads((tmp_path / "arm" / "metrics.json").read_text())
    assert metrics["controller"] == "dls" and metrics["fingers_on_handle"]
    assert metrics["door_opening_arc_end_estimated_rad"] > np.radians(35)  # opened


def test_the_report_iterates_the_controllers_chosen(folder):
    """report --controller: a plug-in's runs with the doors open and closed beside the
    problem set's, and a row of its own in the robustness grid and On the arm (untuned: the
    arm's tuning is the built-ins'); every built-in of the registry keeps its rows."""
    from doorlab.report.experiments import (
        ARM_CONDITIONS,
        make_arm_cases,
        make_experiments,
        make_plugin_experiments,
        make_robustness_cases,
    )

    chosen = [*REGISTRY, spec(folder, "NAMED")]
    plugin_runs = make_plugin_experiments(chosen)
    assert [name for name, _ in plugin_runs] == ["tidy_open", "tidy_closed"]
    assert all(s.controller == spec(folder, "NAMED") for _, s in plugin_runs)
    experiments = (*make_experiments(), *plugin_runs)
    cases, _ = make_robustness_cases(None, experiments, controllers=chosen)
    assert list(dict.fromkeys(c.controller for c in cases)) == [*REGISTRY, "tidy"]
    assert {c.run for c in cases if c.controller == "tidy"} >= {"robust_tidy_yaw_m10"}
    arm, _ = make_arm_cases(None, experiments, band=False, controllers=chosen)
    tidy = [c for c in arm if c.controller == "tidy"]
    assert sorted(c.condition for c in tidy) == sorted(ARM_CONDITIONS)
    assert not any(c.tuned for c in tidy)
    assert {c.controller for c in arm} == {*REGISTRY, "tidy"}


@pytest.mark.slow
def test_a_sweep_runs_a_plug_in_in_its_workers(folder, tmp_path, capsys):
    """A SPEC's plug-ins (relative to the SPEC) run in a spawned worker process, which loads
    them from the same spec; the table names them by their own names; one that raised in a
    tick is a row with its status, and the sweep exits 2 with its line."""
    from doorlab.sweep import read_table

    short = "{arc_duration: 2.0, approach_duration: 2.0, hold_duration: 0.5, extra_time: 0.5}"
    (folder / "spec.yaml").write_text(
        f"controllers: [ctl.py:NAMED, ctl.py:raise_in_tick]\ndoors: [open]\n"
        f"scenario: {{timeline: {short}}}\naxes: {{velocity.kv: [100]}}\n"
    )
    code = main(
        ["sweep", str(folder / "spec.yaml"), "--out", str(tmp_path / "sweep"), "--jobs", "1"]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and "raise_in_tick" in err[-1] and "ZeroDivisionError" in err[-1]
    table = read_table(tmp_path / "sweep")
    assert table[["controller", "status"]].values.tolist() == [
        ["tidy", "ok"],
        ["raise_in_tick", "controller_error"],
    ]


def test_a_report_with_a_plug_in_that_raised_exits_2(tmp_path):
    """doorlab report's exit code: 2 when a run of its ended controller_error (the line names
    the run and the error), else the report's own."""
    from doorlab.cli.commands import _broken_plugin_run

    summary = {"runs": [{"name": "velocity_open", "status": "ok"}]}
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    assert _broken_plugin_run(tmp_path) is None
    summary["runs"].append(
        {"name": "mine_closed", "status": "controller_error", "error": "controller 'mine' raised"}
    )
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    assert _broken_plugin_run(tmp_path) == (
        "run mine_closed ended controller_error: controller 'mine' raised"
    )
    assert _broken_plugin_run(tmp_path / "absent") is None
