"""From an identification's log to the arm's parameters and an arm preset (pure: arrays in,
estimates and YAML out; the fits are :mod:`.fit`'s).

The log has one row per status (:meth:`doorlab.hardware.identify.session.IdentifyLog.arrays`):
the command that answered status k is applied from cycle k + 1 (kuka_driver's cycle), so the
command the arm tracks at cycle k is the one that answered status k - 1.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np

from doorlab.constants import NUM_JOINTS
from doorlab.hardware.identify.fit import (
    COUPLING_THRESHOLD,
    Estimate,
    RestFit,
    StepFit,
    coupling_torque,
    fit_breakaway,
    fit_coulomb,
    fit_coupled_step,
    fit_rest,
    fit_step,
    fit_timed_steps,
)
from doorlab.hardware.identify.script import Segment
from doorlab.kuka import CYCLE_PERIOD, MAX_LATENCY, STRIBECK_VELOCITY


def gravity_per_kg(q: np.ndarray) -> np.ndarray:
    """The holding torque of 1 kg at the gripper's centre of mass at pose q (7,) [N m/kg]."""
    from doorlab.cell.station import make_controller_plant

    torques = []
    for mass in (1.0, 0.0):
        plant = make_controller_plant(mass)
        context = plant.CreateDefaultContext()
        plant.SetPositions(context, q)
        torques.append(-plant.CalcGravityGeneralizedForces(context))
    return torques[0] - torques[1]


def gripper_mass() -> float:
    """The mass the arm carries at its flange [kg] (the model's WSG-50, fingers included)."""
    from doorlab.cell.station import gripper_spatial_inertia

    return float(gripper_spatial_inertia().get_mass())


@dataclass(frozen=True)
class Identified:
    """What the identification found.

    Attributes:
        rest: Load data and noise. steps: Per joint, the step fit (None: not identified).
        stiction, coulomb: Per joint [N m] (None: not identified).
        breakaway_bias: Per joint, the feed-forward torque midway between the breakaways.
        latency, jitter: The latency beyond the cycle and its jitter's half-width [s].
        latencies: Each timed step's latency [s].
        model_inertia: The model's M_ii at the calibration pose (rotors included) (7,).
    """

    rest: RestFit
    steps: tuple[StepFit | None, ...]
    stiction: tuple[Estimate | None, ...]
    coulomb: tuple[Estimate | None, ...]
    breakaway_bias: tuple[Estimate | None, ...]
    latency: Estimate
    jitter: Estimate
    latencies: np.ndarray
    model_inertia: np.ndarray


def _applied(log: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Per status row k, the command the arm tracks at that cycle (the one that answered the
    status before, held while none went out)."""
    q_ref = log["q_ref"].copy()
    tau_ff = log["tau_ff"].copy()
    sent = log["sent"]
    q_applied = np.empty_like(q_ref)
    tau_applied = np.zeros_like(tau_ff)
    q_applied[0] = log["q_commanded"][0]
    for k in range(1, len(q_ref)):
        if sent[k - 1]:
            q_applied[k], tau_applied[k] = q_ref[k - 1], tau_ff[k - 1]
        else:
            q_applied[k], tau_applied[k] = q_applied[k - 1], tau_applied[k - 1]
    return {"q": q_applied, "tau": tau_applied}


def _windows(segments: list[Segment], kind: str, joint: int) -> list[Segment]:
    return [s for s in segments if s.kind == kind and s.joint == joint and s.stop > s.start]


def analyse(
    log: dict[str, np.ndarray],
    segments: list[Segment],
    *,
    stiffness: np.ndarray,
    band: float,
    q_calibration: np.ndarray,
) -> Identified:
    """The fits over the log's segments (see the module docstring).

    Args:
        log: The log's arrays. segments: The script's segments (command indices = rows).
        stiffness: KUKA's joint stiffness (7,) [N m/rad] (the Java application's).
        band: KUKA's friction-compensation band [rad] (``station.arm``).
        q_calibration: The calibration pose (7,) [rad].
    """
    from doorlab.cell.station import make_controller_plant

    applied = _applied(log)
    q = log["q"]
    plant = make_controller_plant()
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, q_calibration)
    mass_matrix = plant.CalcMassMatrix(context)
    model_inertia = np.diag(mass_matrix).copy()

    rest_rows = [s for s in segments if s.kind == "rest" and s.stop > s.start]
    rows = np.arange(rest_rows[0].start, rest_rows[0].stop)
    rows = rows[len(rows) // 2 :]  # settled
    # the load's gravity where the arm stood (sagged by what KUKA's gravity model lacks)
    rest = fit_rest(log["tau_external"][rows], gravity_per_kg(q[rows].mean(axis=0)), gripper_mass())

    stiction: list[Estimate | None] = []
    coulomb: list[Estimate | None] = []
    bias: list[Estimate | None] = []

    def windows_of(kind: str, joint: int, friction=None):
        # from the status before the segment's first (the joint's speed at its start); the
        # other joints' inertial torque, and (once measured) the friction, from the data
        out = []
        for s in _windows(segments, kind, joint):
            rows = slice(s.start - 1, s.stop + 1)
            r, qj = applied["q"][rows, joint], q[rows, joint]
            u = coupling_torque(q[rows], mass_matrix, joint)
            if friction is not None:
                u = u + friction_torque(r, qj, *friction, band=band)
            out.append((r, qj, u))
        return out

    def fit_steps(latency: float, frictions=None) -> list[StepFit | None]:
        out = []
        for joint in range(NUM_JOINTS):
            friction = None if frictions is None else frictions[joint]
            parts = windows_of("step", joint, friction)
            out.append(
                fit_step(
                    parts,
                    stiffness=float(stiffness[joint]),
                    guess_inertia=float(model_inertia[joint]),
                    guess_damping=2.0 * math.sqrt(stiffness[joint] * model_inertia[joint]),
                    band=band,
                    latency=latency,
                )
                if parts
                else None
            )
        return out

    def refit_coupled(steps: list[StepFit | None], latency: float) -> list[StepFit | None]:
        """Joints strongly coupled to another (the iiwa's 1 and 3) fitted with it."""
        d = np.sqrt(np.diag(mass_matrix))
        rho = np.abs(mass_matrix / np.outer(d, d))
        np.fill_diagonal(rho, 0.0)
        out = list(steps)
        for joint in range(NUM_JOINTS):
            partner = int(np.argmax(rho[joint]))
            if rho[joint, partner] < COUPLING_THRESHOLD:
                continue
            if steps[joint] is None or steps[partner] is None:
                continue
            parts = [
                (applied["q"][s.start : s.stop + 1], q[s.start : s.stop + 1])
                for s in _windows(segments, "step", joint)
            ]
            block = mass_matrix[np.ix_([joint, partner], [joint, partner])].copy()
            block[1, 1] = steps[partner].inertia.value
            out[joint] = fit_coupled_step(
                parts,
                joint=joint,
                partner=partner,
                inertia=block,
                partner_damping=steps[partner].damping.value,
                stiffness=np.asarray(stiffness, float)[[joint, partner]],
                guess=steps[joint],
                band=band,
                latency=latency,
            )
        return out

    def fit_latency(steps: list[StepFit | None]) -> np.ndarray:
        values = []
        for joint, fit in enumerate(steps):
            parts = windows_of("timed_step", joint)
            if fit is None or not parts:
                continue
            values.append(
                fit_timed_steps(
                    parts,
                    stiffness=float(stiffness[joint]),
                    inertia=fit.inertia.value,
                    damping=fit.damping.value,
                    band=band,
                )[2]
            )
        return np.concatenate(values) if values else np.array([])

    # the steps' M, D need the latency, the timed steps' latency needs M, D: twice round
    steps = fit_steps(0.0)
    latencies = fit_latency(steps)
    for _ in range(2):
        latency = float(np.mean(latencies)) if len(latencies) else 0.0
        steps = refit_coupled(fit_steps(latency), latency)
        latencies = fit_latency(steps)

    def fit_frictions(steps):
        out = []
        for joint in range(NUM_JOINTS):
            ramps = _windows(segments, "breakaway", joint)
            fit = steps[joint]
            if fit is None or not ramps:
                out.append((None, None, None))
                continue
            out.append(_friction(log, applied, ramps, joint, fit, stiffness, band))
        return out

    # the friction acts where |q_ref - q| is below the observer's band (as each step's ramp
    # starts): once measured, its torque (from the data) enters the steps' fit, once round
    frictions = fit_frictions(steps)
    known = [
        None if fs is None else (fs.value, fc.value if fc is not None else 0.7 * fs.value)
        for fs, fc, _ in frictions
    ]
    steps = refit_coupled(fit_steps(latency, known), latency)
    latencies = fit_latency(steps)
    for fs, fc, b in fit_frictions(steps):
        stiction.append(fs)
        coulomb.append(fc)
        bias.append(b)
    m = len(latencies)
    std = float(latencies.std(ddof=1)) if m > 1 else math.nan
    latency = Estimate(
        float(latencies.mean()) if m else math.nan,
        std / math.sqrt(m) if m > 1 else math.nan,
        m,
        std,
    )
    jitter_value = math.sqrt(3.0) * std if m > 1 else math.nan
    jitter = Estimate(jitter_value, jitter_value / math.sqrt(2 * max(m - 1, 1)), m, std)
    return Identified(
        rest,
        tuple(steps),
        tuple(stiction),
        tuple(coulomb),
        tuple(bias),
        latency,
        jitter,
        latencies,
        model_inertia,
    )


def friction_torque(
    r: np.ndarray, q: np.ndarray, stiction: float, coulomb: float, *, band: float
) -> np.ndarray:
    """Over each cycle k, the friction torque a joint feels from the data [N m] (m,): -(1 - w)
    (Fc + (Fs - Fc) exp(-(v/vs)^2)) sign(v), v its speed over the cycle, w = min(1, |r - q| /
    band) KUKA's observer's share."""
    v = np.zeros(len(q))
    v[:-1] = np.diff(q) / CYCLE_PERIOD
    w = np.minimum(np.abs(r - q) / band, 1.0)
    level = coulomb + (stiction - coulomb) * np.exp(-((v / STRIBECK_VELOCITY) ** 2))
    return -(1.0 - w) * level * np.tanh(v / (0.1 * STRIBECK_VELOCITY))


def _friction(log, applied, ramps, joint, step: StepFit, stiffness, band):
    """(stiction, Coulomb friction, bias) from the breakaways (:func:`.fit.fit_breakaway`,
    :func:`.fit.fit_coulomb`): per sample the friction torque the joint showed, its inertia,
    damping and spring taken away from the applied feed-forward torque; stiction the
    largest of it before the joint slid, per ramp and direction."""
    K = float(stiffness[joint])
    qj = log["q"][:, joint]
    peaks = {+1: [], -1: []}
    noise: list[float] = []
    taus, speeds, weights = [], [], []
    for s in ramps:
        rows = np.arange(s.start + 1, min(s.stop, len(qj) - 1))
        if len(rows) < 3:
            continue
        vel = (qj[rows + 1] - qj[rows - 1]) / (2 * CYCLE_PERIOD)
        acc = (qj[rows + 1] - 2 * qj[rows] + qj[rows - 1]) / CYCLE_PERIOD**2
        r = applied["q"][rows, joint]
        tau_ff = applied["tau"][rows, joint]
        base = applied["tau"][s.start, joint]  # the ramp starts at the bias the rest showed
        # M a + D v = tau_ff - base + K (r - q) + tau_friction
        friction = step.inertia.value * acc + step.damping.value * vel - K * (r - qj[rows])
        friction -= tau_ff - base
        w = np.minimum(np.abs(r - qj[rows]) / band, 1.0)
        if s.info.get("broke_away"):  # the friction opposing the push, at its largest
            # (1 - w) of it acts: KUKA's observer cancels w (|q_ref - q| = v x the delay)
            full = -s.sign * friction / np.maximum(1.0 - w, 0.1)
            full = np.where(w < 0.9, full, -np.inf)
            peak = int(np.argmax(full))
            peaks[s.sign].append(float(full[peak]))
            if 3 < peak < len(full) - 1:
                # The estimate's uncertainty: its change from one cycle to the next at the
                # peak, or the observer's share w, known to a cycle's travel only (the arm
                # compares q_ref with q at its own rate, within the cycle): dw = |v| T / band.
                change = max(abs(full[peak] - full[peak - 1]), abs(full[peak] - full[peak + 1]))
                dw = abs(vel[peak]) * CYCLE_PERIOD / band
                noise.append(float(max(change, abs(full[peak]) * dw)))
        taus.append(friction)
        speeds.append(vel)
        weights.append(w)
    stiction = bias = None
    if peaks[+1] and peaks[-1]:  # tau+ = b + Fs going up, tau- = b - Fs going down
        stiction, bias = fit_breakaway(
            peaks[+1], [-p for p in peaks[-1]], noise=float(np.mean(noise)) if noise else 0.0
        )
    coulomb = None
    if taus:
        coulomb = fit_coulomb(
            np.concatenate(taus),
            np.concatenate(speeds),
            np.concatenate(weights),
            min_speed=2 * STRIBECK_VELOCITY,
        )
    return stiction, coulomb, bias


def _value(estimate: Estimate | None, fallback: float) -> float:
    if estimate is None or not math.isfinite(estimate.value):
        return fallback
    return estimate.value


def identified_scenario(base, found: Identified):
    """``base`` (the arm preset the identification ran with) with the identified parameters:
    KUKA's damping as measured values, the load data, friction, latency and noise (a
    validated copy)."""
    from doorlab.config import validate

    scenario = copy.deepcopy(base)
    loop, arm = scenario.station.inner_loop, scenario.station.arm
    from doorlab.cell.station import kuka_joint_damping

    nominal = kuka_joint_damping(loop)
    loop.kuka_damping_model = "values"
    loop.kuka_damping_values = [
        round(_value(fit.damping if fit else None, float(d)), 3)
        for fit, d in zip(found.steps, nominal, strict=True)
    ]
    arm.load_mass = round(max(found.rest.load_mass.value, 0.0), 4)
    stiction = [max(_value(e, 0.0), 0.0) for e in found.stiction]
    coulomb = [
        min(max(_value(c, 0.7 * fs), 0.0), fs)
        for c, fs in zip(found.coulomb, stiction, strict=True)
    ]
    arm.stiction = [round(v, 4) for v in stiction]
    arm.coulomb_friction = [round(v, 4) for v in coulomb]
    # The simulator realizes a latency L as L - h/2: its semi-implicit step answers half a
    # step early (a double integrator's q_n = a h^2 n (n + 1) / 2 = a (n h + h / 2)^2 / 2 -
    # a h^2 / 8). The measured latency is the arm's; the preset's is the simulator's.
    lead = 0.5 * scenario.station.time_step
    latency = min(max(_value(found.latency, 0.0) + lead, 0.0), MAX_LATENCY)
    jitter = min(max(_value(found.jitter, 0.0), 0.0), latency, MAX_LATENCY - latency)
    arm.latency, arm.latency_jitter = round(latency, 6), round(jitter, 6)
    arm.external_torque_noise = [round(e.value, 4) for e in found.rest.noise]
    return validate(scenario)


def fits_dict(found: Identified) -> dict:
    """``fit.json``'s content: every estimate with its standard error and tolerance."""
    from doorlab.cell.frames import ARM_JOINTS

    def joint_map(values, unit):
        return {
            name: (None if e is None else e.to_dict(unit))
            for name, e in zip(ARM_JOINTS, values, strict=True)
        }

    return {
        "load_mass": found.rest.load_mass.to_dict("kg"),
        "external_torque_noise": joint_map(found.rest.noise, "N m"),
        "rest_external_torque_mean_Nm": found.rest.bias.tolist(),
        "damping": joint_map([s.damping if s else None for s in found.steps], "N m s/rad"),
        "effective_inertia": joint_map([s.inertia if s else None for s in found.steps], "kg m^2"),
        "model_inertia_kg_m2": found.model_inertia.tolist(),
        "step_latency": joint_map([s.latency if s else None for s in found.steps], "s"),
        "stiction": joint_map(found.stiction, "N m"),
        "coulomb_friction": joint_map(found.coulomb, "N m"),
        "breakaway_bias": joint_map(found.breakaway_bias, "N m"),
        "latency": found.latency.to_dict("s"),
        "latency_jitter": found.jitter.to_dict("s"),
        "timed_step_latencies_s": found.latencies.tolist(),
    }


def preset_yaml(scenario, found: Identified, *, source: str) -> str:
    """``identified.yaml``: the arm preset's station fields with the identified values, each
    with its fit's tolerance in a comment; loadable with ``--config``."""

    def floats(values, digits=6) -> str:
        return "[" + ", ".join(f"{v:.{digits}g}" for v in values) + "]"

    def tol(estimates, scale=1.0) -> str:
        return ", ".join(
            "n/a" if e is None or not math.isfinite(e.tolerance) else f"{scale * e.tolerance:.2g}"
            for e in estimates
        )

    st = scenario.station
    loop, arm = st.inner_loop, st.arm
    steps = found.steps
    lines = [
        "# The lab's arm as doorlab identify measured it: the arm preset with KUKA's damping,",
        "# the load data, friction, latency and external-torque noise identified.",
        f"# From: {source}. Each value's tolerance (3 standard errors of its fit) follows it;",
        "# fit.json has every estimate, identify_log.npz the raw statuses and commands.",
        "#",
        "#   doorlab run --config identified.yaml --controller C     # predict the lab's arm",
        "#   doorlab report --config identified.yaml                 # the verdicts on it",
        "station:",
        f"  time_step: {st.time_step:g}",
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
        f"    velocity_filter_cutoff: {st.driver.velocity_filter_cutoff:g}",
        f"    external_torque_limit: {st.driver.external_torque_limit:g}",
        "  safety:",
        f"    enabled: {'true' if st.safety.enabled else 'false'}",
        "  arm:",
        f"    load_mass: {arm.load_mass:.6g}   # [kg] KUKA's load data, +- "
        f"{found.rest.load_mass.tolerance:.2g} (the arm carries {gripper_mass():.3g} kg)",
        f"    stiction: {floats(arm.stiction)}   # [N m] +- {tol(found.stiction)}",
        f"    coulomb_friction: {floats(arm.coulomb_friction)}   # [N m] +- {tol(found.coulomb)}",
        f"    friction_compensation_band: {arm.friction_compensation_band:g}   # [rad] assumed",
        f"    latency: {arm.latency:.6g}   # [s] +- {found.latency.tolerance:.2g}",
        f"    latency_jitter: {arm.latency_jitter:.6g}   # [s] +- {found.jitter.tolerance:.2g}",
        f"    external_torque_noise: {floats(arm.external_torque_noise)}   # [N m] std",
        f"    seed: {arm.seed}",
    ]
    return "\n".join(lines) + "\n"
