"""What ``doorlab identify`` writes from its estimates (:class:`.analysis.Identified`): the arm
preset with the identified values (``identified.yaml``), ``fit.json``'s estimates, and one
line for each parameter the recording could not give, whose preset value is kept
(:func:`kept_lines`)."""

from __future__ import annotations

import copy
import math

from doorlab.hardware.identify.analysis import Identified, gripper_mass
from doorlab.hardware.identify.fit import Estimate
from doorlab.kuka import MAX_LATENCY
from doorlab.runtime.inputs import yaml_float_spelling

FIELDS = {
    "load_mass": ("station.arm.load_mass", "kg"),
    "external_torque_noise": ("station.arm.external_torque_noise", "N m"),
    "damping": ("station.inner_loop.kuka_damping_values", "N m s/rad"),
    "stiction": ("station.arm.stiction", "N m"),
    "coulomb_friction": ("station.arm.coulomb_friction", "N m"),
    "latency": ("station.arm.latency", "s"),
    "latency_jitter": ("station.arm.latency_jitter", "s"),
}
"""The parameters an identification measures: the preset's field each is written to, its unit."""


def _value(estimate: Estimate | None, fallback: float) -> float:
    if estimate is None or not math.isfinite(estimate.value):
        return fallback
    return estimate.value


def noise_estimates(found: Identified) -> list[Estimate | None]:
    """Each joint's noise estimate (None where not identified)."""
    if found.rest is None:
        return [None] * len(found.steps)
    return [
        None if ("external_torque_noise", j) in found.missing else e
        for j, e in enumerate(found.rest.noise)
    ]


def identified_scenario(base, found: Identified):
    """``base`` (the arm preset the identification ran with) with the identified parameters:
    KUKA's damping as measured values, the load data, friction, latency and noise; where an
    estimate is missing (:attr:`Identified.missing`) ``base``'s value is kept (a validated
    copy)."""
    from doorlab.cell.station import kuka_joint_damping
    from doorlab.config import validate

    scenario = copy.deepcopy(base)
    loop, arm = scenario.station.inner_loop, scenario.station.arm
    nominal = kuka_joint_damping(loop)
    loop.kuka_damping_model = "values"
    loop.kuka_damping_values = [
        round(_value(fit.damping if fit else None, float(d)), 3)
        for fit, d in zip(found.steps, nominal, strict=True)
    ]
    load = found.rest.load_mass if found.rest is not None else None
    if load is not None and math.isfinite(load.value):
        arm.load_mass = round(max(load.value, 0.0), 4)
    stiction = [
        max(_value(e, float(v)), 0.0) for e, v in zip(found.stiction, arm.stiction, strict=True)
    ]
    coulomb = [
        min(max(_value(c, float(v)), 0.0), fs)
        for c, v, fs in zip(found.coulomb, arm.coulomb_friction, stiction, strict=True)
    ]
    arm.stiction = [round(v, 4) for v in stiction]
    arm.coulomb_friction = [round(v, 4) for v in coulomb]
    # The simulator realizes a latency L as L - h/2: its semi-implicit step answers half a
    # step early (a double integrator's q_n = a h^2 n (n + 1) / 2 = a (n h + h / 2)^2 / 2 -
    # a h^2 / 8). The measured latency is the arm's; the preset's is the simulator's.
    if found.latency is not None:
        lead = 0.5 * scenario.station.time_step
        arm.latency = round(min(max(found.latency.value + lead, 0.0), MAX_LATENCY), 6)
    jitter = _value(found.jitter, float(arm.latency_jitter))
    arm.latency_jitter = round(min(max(jitter, 0.0), arm.latency, MAX_LATENCY - arm.latency), 6)
    noise = list(arm.external_torque_noise)
    if found.rest is not None:
        for j, e in enumerate(found.rest.noise):
            if ("external_torque_noise", j) not in found.missing:
                noise[j] = e.value
    arm.external_torque_noise = [round(float(v), 4) for v in noise]
    return validate(scenario)


def _written(scenario, name: str, joint: int):
    """The value ``scenario`` holds for a parameter (a joint's, or the arm's)."""
    arm = scenario.station.arm
    if name == "damping":
        from doorlab.cell.station import kuka_joint_damping

        return float(kuka_joint_damping(scenario.station.inner_loop)[joint])
    if name == "load_mass":
        return arm.load_mass
    value = getattr(arm, name)
    return float(value[joint]) if joint >= 0 else float(value)


def kept(base, found: Identified) -> list[dict]:
    """The parameters not identified, grouped by parameter and reason: per group the
    parameter, the joints (numbers 1-7; empty for the arm's), why, and the preset's values
    kept (as written: a Coulomb friction is at most the stiction identified)."""
    written = identified_scenario(base, found)
    groups: dict[tuple[str, str], list[int]] = {}
    for (name, joint), reason in sorted(found.missing.items()):
        groups.setdefault((name, reason), []).append(joint)
    out = []
    for (name, reason), joints in groups.items():
        values = [_written(written, name, j) for j in joints]
        out.append(
            {
                "parameter": name,
                "field": FIELDS[name][0],
                "joints": [j + 1 for j in joints if j >= 0],
                "reason": reason,
                "kept": values if joints != [-1] else values[0],
                "unit": FIELDS[name][1],
            }
        )
    order = list(FIELDS)
    return sorted(out, key=lambda g: (order.index(g["parameter"]), g["joints"]))


def _number(value) -> str:
    if value is None:
        return "null (exact)"
    return f"{value:.4g}"


def kept_line(group: dict) -> str:
    """One line: the parameter (and joints), why it was not identified, the value kept."""
    joints = group["joints"]
    where = f" of joint{'s' if len(joints) > 1 else ''} {', '.join(map(str, joints))}"
    values = group["kept"]
    shown = ", ".join(_number(v) for v in values) if isinstance(values, list) else _number(values)
    return (
        f"{group['parameter']}{where if joints else ''}: not identified, {group['reason']}; "
        f"kept the preset's {shown} {group['unit']}"
    )


def kept_lines(base, found: Identified) -> list[str]:
    """:func:`kept_line` for each group of :func:`kept`."""
    return [kept_line(g) for g in kept(base, found)]


def fits_dict(found: Identified) -> dict:
    """``fit.json``'s estimates: every estimate with its standard error and tolerance (null
    where not identified)."""
    from doorlab.cell.frames import ARM_JOINTS

    def entry(e: Estimate | None, unit: str):
        return None if e is None else e.to_dict(unit)

    def joint_map(values, unit):
        return {name: entry(e, unit) for name, e in zip(ARM_JOINTS, values, strict=True)}

    rest = found.rest
    noise = noise_estimates(found)
    return {
        "load_mass": entry(rest.load_mass if rest else None, "kg"),
        "external_torque_noise": joint_map(noise, "N m"),
        "rest_external_torque_mean_Nm": None if rest is None else rest.bias.tolist(),
        "damping": joint_map([s.damping if s else None for s in found.steps], "N m s/rad"),
        "effective_inertia": joint_map([s.inertia if s else None for s in found.steps], "kg m^2"),
        "model_inertia_kg_m2": found.model_inertia.tolist(),
        "step_latency": joint_map([s.latency if s else None for s in found.steps], "s"),
        "stiction": joint_map(found.stiction, "N m"),
        "coulomb_friction": joint_map(found.coulomb, "N m"),
        "breakaway_bias": joint_map(found.breakaway_bias, "N m"),
        "latency": entry(found.latency, "s"),
        "latency_jitter": entry(found.jitter, "s"),
        "timed_step_latencies_s": found.latencies.tolist(),
    }


def yaml_number(value: float, digits: int = 6) -> str:
    """``value`` to ``digits`` significant digits, spelled so that YAML 1.1 reads a number:
    ``4.0e-05``, where Python's ``4e-05`` is text to it (and ``doorlab run --config`` refuses
    the file)."""
    text = f"{value:.{digits}g}"
    return (yaml_float_spelling(text) or text) if "e" in text else text


def preset_yaml(scenario, found: Identified, *, source: str, kept_from: list[str]) -> str:
    """``identified.yaml``: the arm preset's station fields with the identified values, each
    with its fit's tolerance in a comment, and the lines of the values kept from the preset
    (``kept_from``); loadable with ``--config``."""

    def floats(values, digits=6) -> str:
        return "[" + ", ".join(yaml_number(v, digits) for v in values) + "]"

    def tol(estimates, scale=1.0) -> str:
        return ", ".join(
            "kept" if e is None or not math.isfinite(e.tolerance) else f"{scale * e.tolerance:.2g}"
            for e in estimates
        )

    def one(e: Estimate | None) -> str:
        return "kept" if e is None or not math.isfinite(e.tolerance) else f"{e.tolerance:.2g}"

    st = scenario.station
    loop, arm = st.inner_loop, st.arm
    steps = found.steps
    rest = found.rest
    noise = noise_estimates(found)
    lines = [
        "# The lab's arm as doorlab identify measured it: the arm preset with KUKA's damping,",
        "# the load data, friction, latency and external-torque noise identified.",
        f"# From: {source}. Each value's tolerance (3 standard errors of its fit) follows it",
        "# ('kept': the preset's value, not identified from the recording);",
        "# fit.json has every estimate, identify_log.npz the raw statuses and commands.",
    ]
    if kept_from:
        lines += ["# Kept from the preset:"] + [f"#   {line}" for line in kept_from]
    lines += [
        "#",
        "#   doorlab run --config identified.yaml --controller C     # predict the lab's arm",
        "#   doorlab report --config identified.yaml                 # the verdicts on it",
        "station:",
        f"  time_step: {yaml_number(st.time_step)}",
        "  inner_loop:",
        "    kind: kuka_joint_impedance",
        f"    kuka_stiffness: {floats(loop.kuka_stiffness, 6)}   # [N m/rad] the Java app's",
        f"    kuka_damping: {floats(loop.kuka_damping, 4)}",
        "    kuka_damping_model: values",
        f"    kuka_damping_values: {floats(loop.kuka_damping_values)}   # [N m s/rad]",
        f"    # +- {tol([s.damping if s else None for s in steps])} N m s/rad; effective inertia "
        f"{floats([s.inertia.value if s else math.nan for s in steps], 3)} kg m^2 against the "
        f"model's {floats(found.model_inertia, 3)}",
        "  driver:",
        f"    timing: {st.driver.timing}",
        f"    velocity_filter_cutoff: {yaml_number(st.driver.velocity_filter_cutoff)}",
        f"    external_torque_limit: {yaml_number(st.driver.external_torque_limit)}",
        "  safety:",
        f"    enabled: {'true' if st.safety.enabled else 'false'}",
        "  arm:",
        f"    load_mass: {'null' if arm.load_mass is None else yaml_number(arm.load_mass)}   "
        f"# [kg] KUKA's load data, +- {one(rest.load_mass if rest else None)} (the arm "
        f"carries {gripper_mass():.3g} kg)",
        f"    stiction: {floats(arm.stiction)}   # [N m] +- {tol(found.stiction)}",
        f"    coulomb_friction: {floats(arm.coulomb_friction)}   # [N m] +- {tol(found.coulomb)}",
        f"    friction_compensation_band: {yaml_number(arm.friction_compensation_band)}"
        "   # [rad] assumed",
        f"    latency: {yaml_number(arm.latency)}   # [s] +- {one(found.latency)}",
        f"    latency_jitter: {yaml_number(arm.latency_jitter)}   # [s] +- {one(found.jitter)}",
        f"    external_torque_noise: {floats(arm.external_torque_noise)}   # [N m] std, +- "
        f"{tol(noise)}",
        f"    seed: {arm.seed}",
    ]
    return "\n".join(lines) + "\n"


def summary_rows(fits: dict) -> list[tuple[str, str]]:
    """The rows ``doorlab identify`` prints of ``fit.json``'s estimates ('kept': not
    identified, the preset's value kept)."""

    def per_joint(key: str) -> str:
        values = []
        for entry in fits[key].values():
            values.append(
                "kept" if entry is None or entry["value"] is None else f"{entry['value']:.3g}"
            )
        return ", ".join(values)

    def scalar(key: str, scale: float, unit: str) -> str:
        entry = fits[key]
        if entry is None or entry["value"] is None:
            return "kept"
        tolerance = entry["tolerance"]
        plus = "" if tolerance is None else f" (+- {scale * tolerance:.2g})"
        return f"{scale * entry['value']:.3g} {unit}{plus}"

    return [
        ("damping [N m s/rad]", per_joint("damping")),
        ("effective inertia", per_joint("effective_inertia") + " kg m^2"),
        ("stiction [N m]", per_joint("stiction")),
        ("Coulomb friction [N m]", per_joint("coulomb_friction")),
        ("load data", scalar("load_mass", 1.0, "kg")),
        (
            "latency",
            f"{scalar('latency', 1e3, 'ms')}, jitter {scalar('latency_jitter', 1e3, 'ms')}",
        ),
        ("torque noise [N m]", per_joint("external_torque_noise")),
    ]
