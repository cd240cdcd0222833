"""Validation of scenarios: ``doorlab.config.validate`` and ``load_scenario`` on bad inputs.

Every bad input must raise ``ConfigError`` naming the offending field by its dotted name
(YAML problems: naming the file); choice fields must also list the valid choices.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydrake.common.yaml import yaml_dump_typed

from doorlab.config import (
    CONTACT_APPROXIMATIONS,
    CONTROLLERS,
    DOOR_STATES,
    IK_OBJECTIVES,
    INNER_LOOPS,
    KUKA_DAMPING_MODELS,
    MIN_TIME_STEP,
    Scenario,
    load_scenario,
    validate,
)
from doorlab.errors import ConfigError
from doorlab.runtime.drake_compat import contact_approximations

EXAMPLES_DIR = Path(__file__).resolve().parents[1] / "examples"
NAN, INF = math.nan, math.inf
CONTROL_PERIOD = Scenario().timeline.control_period  # [s]


def _with(path: str, value: Any) -> Scenario:
    """A default Scenario with the dotted field ``path`` set to ``value``."""
    scenario = Scenario()
    *parents, leaf = path.split(".")
    target = scenario
    for part in parents:
        target = getattr(target, part)
    setattr(target, leaf, value)
    return scenario


def _with_entry(path: str, index: int, value: float) -> Scenario:
    """A default Scenario whose list field ``path`` has entry ``index`` replaced."""
    values = list(copy.deepcopy(_get(Scenario(), path)))
    values[index] = value
    return _with(path, values)


def _get(scenario: Scenario, path: str) -> Any:
    for part in path.split("."):
        scenario = getattr(scenario, part)
    return scenario


# --- validate(): choices ---------------------------------------------------------------------

CHOICES = [
    ("controller", "bogus", CONTROLLERS),
    ("doors", "ajar", DOOR_STATES),
    ("station.inner_loop.kind", "pid", INNER_LOOPS),
    ("station.contact_approximation", "hydroelastic", CONTACT_APPROXIMATIONS),
    ("ik.objective", "best", IK_OBJECTIVES),
    ("station.inner_loop.kuka_damping_model", "guess", KUKA_DAMPING_MODELS),
]


@pytest.mark.parametrize(("field", "value", "choices"), CHOICES, ids=[c[0] for c in CHOICES])
def test_unknown_choice_is_rejected_with_the_valid_ones(field, value, choices):
    """An unknown choice raises ConfigError naming the field and listing every valid choice."""
    with pytest.raises(ConfigError) as info:
        validate(_with(field, value))
    message = str(info.value)
    assert field in message
    assert repr(value) in message or value in message
    for choice in choices:
        assert choice in message


# --- validate(): numbers, lists and ranges ---------------------------------------------------

# (id, scenario, dotted field the message must name)
BAD_VALUES = [
    # ik.knots: an integer in [2, 100]
    *[(f"ik.knots={v!r}", _with("ik.knots", v), "ik.knots") for v in (0, 1, 101, 2.5, True)],
    # time step: finite and > 0
    *[
        (f"station.time_step={v!r}", _with("station.time_step", v), "station.time_step")
        for v in (0.0, -0.001, NAN, INF, -INF)
    ],
    # gains and limits: finite and > 0
    *[
        (f"{f}={v!r}", _with(f, v), f)
        for f in (
            "velocity.kv",
            "velocity.kw",
            "velocity.joint_speed_limit",
            "impedance.kv",
            "impedance.kw",
            "impedance.torque_limit",
        )
        for v in (0.0, -1.0)
    ],
    ("impedance.torque_limit=nan", _with("impedance.torque_limit", NAN), "impedance.torque_limit"),
    # the adaptive plan: gains, speeds and thresholds finite and > 0, target below 90 deg
    *[
        (f"{f}={v!r}", _with(f, v), f)
        for f in (
            "adaptive.target_angle",
            "adaptive.speed",
            "adaptive.force_gain",
            "adaptive.yaw_rate_limit",
            "adaptive.min_sagitta",
        )
        for v in (0.0, -1.0, NAN)
    ],
    ("adaptive.target_angle=95", _with("adaptive.target_angle", 95.0), "adaptive.target_angle"),
    ("adaptive.force_target=inf", _with("adaptive.force_target", INF), "adaptive.force_target"),
    # inner-loop gains: kq > 0, dq >= 0, per entry
    ("kq[0]=0", _with_entry("station.inner_loop.kq", 0, 0.0), "station.inner_loop.kq[0]"),
    ("kq[3]=-1", _with_entry("station.inner_loop.kq", 3, -1.0), "station.inner_loop.kq[3]"),
    ("kq[6]=inf", _with_entry("station.inner_loop.kq", 6, INF), "station.inner_loop.kq[6]"),
    ("dq[2]=-1", _with_entry("station.inner_loop.dq", 2, -1.0), "station.inner_loop.dq[2]"),
    ("dq[6]=nan", _with_entry("station.inner_loop.dq", 6, NAN), "station.inner_loop.dq[6]"),
    ("dq_scale=-1", _with("station.inner_loop.dq_scale", -1.0), "station.inner_loop.dq_scale"),
    ("dq_scale=nan", _with("station.inner_loop.dq_scale", NAN), "station.inner_loop.dq_scale"),
    ("id_kp=0", _with("station.inner_loop.id_kp", 0.0), "station.inner_loop.id_kp"),
    ("id_ki=-1", _with("station.inner_loop.id_ki", -1.0), "station.inner_loop.id_ki"),
    # inner-loop gains: 7 entries
    ("kq len 6", _with("station.inner_loop.kq", [1.0] * 6), "station.inner_loop.kq"),
    ("kq len 8", _with("station.inner_loop.kq", [1.0] * 8), "station.inner_loop.kq"),
    ("dq len 0", _with("station.inner_loop.dq", []), "station.inner_loop.dq"),
    # door angles: left in [-pi/2, 0], right in [0, pi/2], exactly two
    ("door_angles left > 0", _with("door_angles", [0.1, 0.1]), "door_angles[0]"),
    ("door_angles left < -pi/2", _with("door_angles", [-1.6, 0.1]), "door_angles[0]"),
    ("door_angles right < 0", _with("door_angles", [-0.1, -0.1]), "door_angles[1]"),
    ("door_angles right > pi/2", _with("door_angles", [-0.1, 1.6]), "door_angles[1]"),
    ("door_angles nan", _with("door_angles", [NAN, 0.1]), "door_angles"),
    ("door_angles len 1", _with("door_angles", [-0.1]), "door_angles"),
    ("door_angles len 3", _with("door_angles", [-0.1, 0.1, 0.0]), "door_angles"),
    ("door_angles len 0", _with("door_angles", []), "door_angles"),
    # timing consistency
    ("time_step > control_period", _with("station.time_step", 0.01), "station.time_step"),
    ("log_period < time_step", _with("timeline.log_period", 0.001), "timeline.log_period"),
    ("control_period 0", _with("timeline.control_period", 0.0), "timeline.control_period"),
    ("arc_duration -1", _with("timeline.arc_duration", -1.0), "timeline.arc_duration"),
    ("extra_time -1", _with("timeline.extra_time", -1.0), "timeline.extra_time"),
    # gripper widths: [0, 0.11] m
    *[
        (f"{f}={v!r}", _with(f"station.gripper.{f}", v), f"station.gripper.{f}")
        for f in ("initial_width", "approach_width", "grasp_width")
        for v in (-0.001, 0.111, NAN)
    ],
    (
        "gripper.force_limit=0",
        _with("station.gripper.force_limit", 0.0),
        "station.gripper.force_limit",
    ),
    # other physics
    ("hinge_damping=-1", _with("station.hinge_damping", -1.0), "station.hinge_damping"),
    ("friction=nan", _with("station.friction", NAN), "station.friction"),
    *[
        (
            f"cupboard_yaw_error={v!r}",
            _with("station.cupboard_yaw_error", v),
            "station.cupboard_yaw_error",
        )
        for v in (0.786, -0.786, NAN, INF)
    ],
    *[
        (
            f"cupboard_position_error={v!r}",
            _with("station.cupboard_position_error", v),
            "station.cupboard_position_error",
        )
        for v in ([0.051, 0.0, 0.0], [0.0, NAN, 0.0], [0.0, 0.0], [0.0, 0.0, True])
    ],
    # arc end angle: [15, 90] deg
    *[
        (f"arc.angle_end_deg={v!r}", _with("arc.angle_end_deg", v), "arc.angle_end_deg")
        for v in (14.9, 90.1, -50.0, NAN)
    ],
    # IK tolerances
    ("ik.position_tolerance=0", _with("ik.position_tolerance", 0.0), "ik.position_tolerance"),
    ("ik.theta_bound=-1", _with("ik.theta_bound", -1.0), "ik.theta_bound"),
    *[
        (f"ik.grasp_offset={v!r}", _with("ik.grasp_offset", v), "ik.grasp_offset")
        for v in ([0.011, 0.0, 0.0], [0.0, NAN, 0.0], [0.0, 0.0], [0.0, 0.0, 0.0, 0.0], 0.001)
    ],
    # the arm's uncertain parameters (station.arm)
    *[
        (f"arm.load_mass={v!r}", _with("station.arm.load_mass", v), "station.arm.load_mass")
        for v in (-0.1, 7.5, NAN)
    ],
    (
        "arm.stiction below coulomb",
        _with("station.arm.coulomb_friction", [1.0] * 7),
        "station.arm.stiction[0]",
    ),
    ("arm.stiction short", _with("station.arm.stiction", [1.0] * 6), "station.arm.stiction"),
    ("arm.latency=-1", _with("station.arm.latency", -0.001), "station.arm.latency"),
    ("arm.latency=5ms", _with("station.arm.latency", 0.005), "station.arm.latency"),
    (
        "arm.latency on a 2 ms step",
        _with("station.arm.latency", 0.002),
        "station.arm.latency needs a station.time_step",
    ),
    (
        "arm.jitter above latency",
        _with("station.arm.latency_jitter", 0.001),
        "station.arm.latency",
    ),
    (
        "arm.noise=-1",
        _with("station.arm.external_torque_noise", [-1.0] + [0.0] * 6),
        "station.arm.external_torque_noise[0]",
    ),
    ("arm.seed=-1", _with("station.arm.seed", -1), "station.arm.seed"),
    (
        "kuka_damping_values without values",
        _with("station.inner_loop.kuka_damping_values", [50.0] * 7),
        "station.inner_loop.kuka_damping_values",
    ),
    (
        "kuka_damping_model values without values",
        _with("station.inner_loop.kuka_damping_model", "values"),
        "station.inner_loop.kuka_damping_values",
    ),
]


@pytest.mark.parametrize(
    ("scenario", "field"), [b[1:] for b in BAD_VALUES], ids=[b[0] for b in BAD_VALUES]
)
def test_bad_value_is_rejected_naming_the_field(scenario, field):
    """A bad number, list or range raises ConfigError whose message names the dotted field."""
    with pytest.raises(ConfigError) as info:
        validate(scenario)
    assert field in str(info.value)


def test_time_step_above_control_period_names_both_fields():
    """time_step > control_period names station.time_step and timeline.control_period."""
    with pytest.raises(ConfigError) as info:
        validate(_with("station.time_step", 0.01))
    assert "timeline.control_period" in str(info.value)


@pytest.mark.skipif(
    "tamsi" not in contact_approximations(), reason="this Drake has no TAMSI (1.57 removed it)"
)
def test_tamsi_with_pd_actuators_is_rejected():
    """contact_approximation tamsi cannot run the implicit_pd loop (names the field); the
    stiffness and inverse_dynamics loops need no PD actuators and run with it."""
    scenario = _with("station.contact_approximation", "tamsi")
    scenario.station.inner_loop.kind = "implicit_pd"
    with pytest.raises(ConfigError, match="station.contact_approximation"):
        validate(scenario)
    for kind in ("stiffness", "inverse_dynamics"):
        scenario.station.inner_loop.kind = kind
        assert validate(scenario) is scenario


def test_door_angles_of_the_wrong_type_is_a_config_error():
    """door_angles that is not a list (a bare float) raises ConfigError naming door_angles."""
    with pytest.raises(ConfigError, match="door_angles"):
        validate(_with("door_angles", 0.5))


# --- validate(): good inputs -----------------------------------------------------------------


def test_default_scenario_validates():
    """The default Scenario validates and validate() returns it."""
    scenario = Scenario()
    assert validate(scenario) is scenario


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("ik.knots", 2),
        ("ik.knots", 100),
        ("door_angles", [-math.pi / 2, math.pi / 2]),
        ("door_angles", [0.0, 0.0]),
        ("station.gripper.grasp_width", 0.0),
        ("station.gripper.initial_width", 0.11),
        ("arc.angle_end_deg", 15.0),
        ("arc.angle_end_deg", 90.0),
        ("station.inner_loop.dq", [0.0] * 7),
        ("timeline.extra_time", 0.0),
        ("station.cupboard_yaw_error", math.pi / 4),
        ("station.cupboard_yaw_error", -math.pi / 4),
    ],
)
def test_range_boundaries_validate(field, value):
    """Values on the closed boundaries of each range validate (the checks are not too strict)."""
    validate(_with(field, value))


@given(time_step=st.floats(min_value=MIN_TIME_STEP, max_value=CONTROL_PERIOD))
@settings(max_examples=200, deadline=None, database=None)
def test_any_time_step_up_to_the_control_period_validates(time_step):
    """Any float time_step in [MIN_TIME_STEP, control_period] validates."""
    validate(_with("station.time_step", time_step))


@given(time_step=st.floats(min_value=0.0, max_value=MIN_TIME_STEP, exclude_max=True))
@settings(max_examples=100, deadline=None, database=None)
def test_a_time_step_below_the_finest_fails(time_step):
    """A time_step in [0, MIN_TIME_STEP) raises ConfigError naming the bound."""
    with pytest.raises(ConfigError, match=r"station\.time_step"):
        validate(_with("station.time_step", time_step))


@given(
    time_step=st.floats(max_value=0.0, allow_nan=False)
    | st.sampled_from([math.nan, math.inf, -math.inf])
)
@settings(max_examples=200, deadline=None, database=None)
def test_any_non_positive_or_non_finite_time_step_fails(time_step):
    """Any time_step <= 0 or non-finite raises ConfigError naming station.time_step."""
    with pytest.raises(ConfigError, match=r"station\.time_step"):
        validate(_with("station.time_step", time_step))


# --- load_scenario(): YAML files -------------------------------------------------------------

BAD_YAML = [
    ("unknown top-level key", "nosuch_key: 1\n", "nosuch_key"),
    ("unknown nested key", "station:\n  nosuch_key: 1\n", "nosuch_key"),
    ("unknown deep key", "station:\n  inner_loop:\n    nosuch_key: 1\n", "nosuch_key"),
    ("float for an int", "ik:\n  knots: 2.5\n", "knots"),
    ("string for a float", "station:\n  time_step: fast\n", None),
    ("scalar for a list", "station:\n  inner_loop:\n    kq: 5\n", None),
]
WRONG_TYPES = [  # (id, text, the field the message should name)
    ("string for a float", "station:\n  time_step: fast\n", "time_step"),
    ("scalar for a list", "station:\n  inner_loop:\n    kq: 5\n", "kq"),
]


@pytest.mark.parametrize(("text", "key"), [b[1:] for b in BAD_YAML], ids=[b[0] for b in BAD_YAML])
def test_bad_yaml_names_the_file(tmp_path, text, key):
    """A YAML file with an unknown key or a wrong type raises ConfigError naming the file."""
    path = tmp_path / "bad_scenario.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_scenario(path)
    message = str(info.value)
    assert "bad_scenario.yaml" in message
    if key is not None:  # unknown keys (and int fields) are named by the schema loader
        assert key in message


@pytest.mark.parametrize(
    ("text", "field"), [b[1:] for b in WRONG_TYPES], ids=[b[0] for b in WRONG_TYPES]
)
def test_wrong_type_in_yaml_names_the_field(tmp_path, text, field):
    """A value of the wrong type in a YAML file names its field (time_step, kq) in the message."""
    path = tmp_path / "bad_scenario.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=field):
        load_scenario(path)


@pytest.mark.parametrize("text", ["station: [\n", "station:\n  time_step: 0.002\n bad: 1\n"])
def test_invalid_yaml_syntax_names_the_file(tmp_path, text):
    """A file that is not valid YAML raises ConfigError naming the file."""
    path = tmp_path / "broken.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match="broken.yaml"):
        load_scenario(path)


def test_missing_yaml_file_names_the_file(tmp_path):
    """A config file that does not exist raises ConfigError naming the file."""
    with pytest.raises(ConfigError, match="no_such_scenario.yaml"):
        load_scenario(tmp_path / "no_such_scenario.yaml")


def test_yaml_with_an_out_of_range_value_names_the_field(tmp_path):
    """A well-formed YAML file with a bad value is validated on load (names the field)."""
    path = tmp_path / "scenario.yaml"
    path.write_text("station:\n  time_step: -1.0\n")
    with pytest.raises(ConfigError, match=r"station\.time_step"):
        load_scenario(path)


@pytest.mark.parametrize(
    "path",
    sorted(p for p in EXAMPLES_DIR.glob("*.yaml") if not p.name.startswith("sweep_")),
    ids=lambda p: p.name,
)
def test_shipped_example_loads_and_validates(path):
    """Every shipped scenario examples/*.yaml loads and validates (sweep_*.yaml are SPECs,
    tested in test_sweep.py)."""
    scenario = load_scenario(path)
    assert validate(scenario) is scenario


def test_yaml_dump_then_load_round_trips(tmp_path):
    """yaml_dump_typed then load_scenario gives back an equal (modified) Scenario."""
    scenario = Scenario(controller="ik", doors="open", door_angles=[-0.3, 0.25])
    scenario.station.time_step = 0.001
    scenario.station.contact_approximation = "lagged"
    scenario.station.inner_loop.kind = "inverse_dynamics"
    scenario.station.inner_loop.kq = [1000.0, 2000.0, 3000.0, 400.0, 500.0, 60.0, 7.0]
    scenario.station.gripper.grasp_width = 0.004
    scenario.timeline.arc_duration = 7.5
    scenario.arc.angle_end_deg = 60.0
    scenario.ik.knots = 17
    scenario.ik.objective = "centered"
    scenario.ik.theta_bound = 0.1 / 3  # not exactly representable in a short decimal
    scenario.velocity.kv = 80.0
    scenario.impedance.torque_limit = 12.5
    validate(scenario)
    assert scenario != Scenario()
    path = tmp_path / "round_trip.yaml"
    path.write_text(yaml_dump_typed(scenario))
    assert load_scenario(path) == scenario
