"""From an identification's log to the arm's parameters (pure: arrays in, estimates out; the
fits are :mod:`.fit`'s, the preset they write :mod:`.preset`'s).

The log has one row per status (:meth:`doorlab.hardware.identify.session.IdentifyLog.arrays`):
the command that answered status k is applied from cycle k + 1 (kuka_driver's cycle), so the
command the arm tracks at cycle k is the one that answered status k - 1.

Every estimate the recording cannot give is left out with the reason
(:attr:`Identified.missing`: a joint that never moved, a singular or non-finite fit, no noise,
the run cut short before a part of the script, a joint the script did not move): the preset
keeps its value there and says so (:func:`doorlab.hardware.identify.preset.kept_lines`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from doorlab.constants import NUM_JOINTS
from doorlab.hardware.identify.fit import (
    COUPLING_THRESHOLD,
    Estimate,
    NotIdentifiable,
    RestFit,
    StepFit,
    fit_coupled_step,
    fit_rest,
    fit_step,
    fit_timed_steps,
    jitter_estimate,
    latency_estimate,
)
from doorlab.hardware.identify.friction import fit_friction, friction_torque
from doorlab.hardware.identify.response import coupling_torque
from doorlab.hardware.identify.script import Segment

NOISE_FLOOR = 1e-9
"""[N m] An external torque at rest whose standard deviation is at most this did not vary:
no noise to estimate (a simulated arm without noise, a driver that reports a constant)."""
LATENCY_CONVERGED = 2e-6
"""[s] The steps' fits need the latency and the timed steps' latency needs their M, D: they
are iterated (with Aitken's extrapolation) until the latency moves less than this (0.04 % of
the cycle; the timed steps' own scatter is 10 times more)."""
LATENCY_ROUNDS = 8
"""At most this many rounds of that iteration."""


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
        rest: Load data and noise (None: no rest in the recording).
        steps: Per joint, the step fit (None: not identified).
        stiction, coulomb: Per joint [N m] (None: not identified).
        breakaway_bias: Per joint, the feed-forward torque midway between the breakaways.
        latency, jitter: The latency beyond the cycle and its jitter's half-width [s] (None:
            not identified).
        latencies: Each timed step's latency [s].
        model_inertia: The model's M_ii at the calibration pose (rotors included) (7,).
        missing: Why an estimate was not made: (the preset's field, the joint or -1 for the
            arm's) -> the reason, a few words (fields ``load_mass``,
            ``external_torque_noise``, ``damping``, ``stiction``, ``coulomb_friction``,
            ``latency``, ``latency_jitter``).
    """

    rest: RestFit | None
    steps: tuple[StepFit | None, ...]
    stiction: tuple[Estimate | None, ...]
    coulomb: tuple[Estimate | None, ...]
    breakaway_bias: tuple[Estimate | None, ...]
    latency: Estimate | None
    jitter: Estimate | None
    latencies: np.ndarray
    model_inertia: np.ndarray
    missing: dict[tuple[str, int], str] = field(default_factory=dict)


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


def complete_segments(segments: list[Segment], rows: int) -> list[Segment]:
    """The segments the log holds whole (a run cut short leaves its last one open)."""
    return [s for s in segments if 0 < s.start < s.stop <= rows - 1]


def _windows(segments: list[Segment], kind: str, joint: int) -> list[Segment]:
    return [s for s in segments if s.kind == kind and s.joint == joint]


class _Attempts:
    """Runs fits, keeping the reason of each that the recording cannot make."""

    def __init__(self) -> None:
        self.missing: dict[tuple[str, int], str] = {}

    def __call__(self, key: tuple[str, int], fit: Callable, *args, **kwargs):
        try:
            value = fit(*args, **kwargs)
        except NotIdentifiable as e:
            self.missing[key] = str(e)
            return None
        self.missing.pop(key, None)
        return value

    def absent(self, key: tuple[str, int], reason: str) -> None:
        self.missing[key] = reason


def analyse(
    log: dict[str, np.ndarray],
    segments: list[Segment],
    *,
    stiffness: np.ndarray,
    band: float,
    q_calibration: np.ndarray,
    joints: tuple[int, ...] | None = None,
) -> Identified:
    """The fits over the log's segments (see the module docstring); never raises for what
    the recording lacks (:attr:`Identified.missing` says what and why).

    Args:
        log: The log's arrays. segments: The script's segments (command indices = rows).
        stiffness: KUKA's joint stiffness (7,) [N m/rad] (the Java application's).
        band: KUKA's friction-compensation band [rad] (``station.arm``).
        q_calibration: The calibration pose (7,) [rad].
        joints: The joints the script moved (the reason given for the others).
    """
    from doorlab.cell.station import make_controller_plant

    q = log["q"]
    segments = complete_segments(segments, len(q))
    attempt = _Attempts()
    plant = make_controller_plant()
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, q_calibration)
    mass_matrix = plant.CalcMassMatrix(context)
    fitter = _Fitter(log, segments, stiffness, band, mass_matrix, attempt)

    def not_recorded(kind: str, joint: int) -> str:
        if joints is not None and joint not in joints:
            return "not among the joints the script moved (--joints)"
        return f"no {kind} in the recording (the run stopped before)"

    rest = _rest(log, segments, attempt)
    for joint in range(NUM_JOINTS):
        if not _windows(segments, "step", joint):
            attempt.absent(("damping", joint), not_recorded("step", joint))
        if not _windows(segments, "breakaway", joint):
            for name in ("stiction", "coulomb_friction"):
                attempt.absent((name, joint), not_recorded("breakaway", joint))

    latency, steps, values = fitter.converge()
    frictions = fitter.frictions(steps, latency)
    # the friction acts where |q_ref - q| is below the observer's band (as each step's ramp
    # starts): once measured, its torque (from the data) enters the steps' fit, once round
    known = [
        None if fs is None else (fs.value, fc.value if fc is not None else 0.7 * fs.value)
        for fs, fc, _ in frictions
    ]
    steps = fitter.steps(latency, known)
    values = fitter.latencies(steps)
    latency = float(np.mean(values)) if len(values) else latency
    frictions = fitter.frictions(steps, latency)
    return Identified(
        rest,
        tuple(steps),
        tuple(f[0] for f in frictions),
        tuple(f[1] for f in frictions),
        tuple(f[2] for f in frictions),
        attempt(("latency", -1), latency_estimate, values),
        attempt(("latency_jitter", -1), jitter_estimate, values),
        values,
        np.diag(mass_matrix).copy(),
        attempt.missing,
    )


def _rest(log, segments: list[Segment], attempt: _Attempts) -> RestFit | None:
    """The rest's fit (load data, noise); what it cannot give in ``attempt``."""
    rests = [s for s in segments if s.kind == "rest"]
    if not rests:
        for key in [("load_mass", -1)] + [("external_torque_noise", j) for j in range(7)]:
            attempt.absent(key, "no rest in the recording (the run stopped before)")
        return None
    rows = np.arange(rests[0].start, rests[0].stop)
    rows = rows[len(rows) // 2 :]  # settled
    q = log["q"]
    tau = log["tau_external"][rows]
    # the load's gravity where the arm stood (sagged by what KUKA's gravity model lacks)
    rest = attempt(
        ("load_mass", -1), fit_rest, tau, gravity_per_kg(q[rows].mean(axis=0)), gripper_mass()
    )
    if rest is None:
        reason = attempt.missing[("load_mass", -1)]
        for j in range(NUM_JOINTS):
            attempt.absent(("external_torque_noise", j), reason)
        return None
    if rest.load_mass is None:
        attempt.absent(("load_mass", -1), rest.load_reason)
    for j, estimate in enumerate(rest.noise):
        if estimate.value <= NOISE_FLOOR:
            attempt.absent(
                ("external_torque_noise", j),
                f"no noise to estimate (KUKA's external torque constant over {estimate.n} "
                "statuses at rest)",
            )
    return rest


class _Fitter:
    """The step, timed-step and breakaway fits of one log (:func:`analyse`'s parts)."""

    def __init__(self, log, segments, stiffness, band, mass_matrix, attempt: _Attempts):
        self.log, self.segments, self.band = log, segments, band
        self.stiffness = np.asarray(stiffness, float)
        self.mass_matrix = mass_matrix
        self.model_inertia = np.diag(mass_matrix)
        self.applied = _applied(log)
        self.attempt = attempt

    def windows(self, kind: str, joint: int, friction=None):
        """(r, q, u) per segment, from the status before its first (the joint's speed at its
        start); u the other joints' inertial torque and (once measured) the friction."""
        q, out = self.log["q"], []
        for s in _windows(self.segments, kind, joint):
            rows = slice(s.start - 1, s.stop + 1)
            r, qj = self.applied["q"][rows, joint], q[rows, joint]
            u = coupling_torque(q[rows], self.mass_matrix, joint)
            if friction is not None:
                u = u + friction_torque(r, qj, *friction, band=self.band)
            out.append((r, qj, u))
        return out

    def steps(self, latency: float, frictions=None) -> list[StepFit | None]:
        """Each joint's step fit, then the coupled joints' (the iiwa's 1 and 3)."""
        out = []
        for joint in range(NUM_JOINTS):
            friction = None if frictions is None else frictions[joint]
            parts = self.windows("step", joint, friction)
            K, M = float(self.stiffness[joint]), float(self.model_inertia[joint])
            out.append(
                self.attempt(
                    ("damping", joint),
                    fit_step,
                    parts,
                    stiffness=K,
                    guess_inertia=M,
                    guess_damping=2.0 * math.sqrt(K * M),
                    band=self.band,
                    latency=latency,
                )
                if parts
                else None
            )
        return self.coupled(out, latency)

    def coupled(self, steps: list[StepFit | None], latency: float) -> list[StepFit | None]:
        """Joints strongly coupled to another through the inertia matrix fitted with it."""
        mass = self.mass_matrix
        d = np.sqrt(np.diag(mass))
        rho = np.abs(mass / np.outer(d, d))
        np.fill_diagonal(rho, 0.0)
        out = list(steps)
        q = self.log["q"]
        for joint in range(NUM_JOINTS):
            partner = int(np.argmax(rho[joint]))
            if rho[joint, partner] < COUPLING_THRESHOLD:
                continue
            if steps[joint] is None or steps[partner] is None:
                continue
            parts = [
                (self.applied["q"][s.start : s.stop + 1], q[s.start : s.stop + 1])
                for s in _windows(self.segments, "step", joint)
            ]
            block = mass[np.ix_([joint, partner], [joint, partner])].copy()
            block[1, 1] = steps[partner].inertia.value
            try:
                out[joint] = fit_coupled_step(
                    parts,
                    joint=joint,
                    partner=partner,
                    inertia=block,
                    partner_damping=steps[partner].damping.value,
                    stiffness=self.stiffness[[joint, partner]],
                    guess=steps[joint],
                    band=self.band,
                    latency=latency,
                )
            except NotIdentifiable:
                pass  # a refinement: the joint's own fit stands
        return out

    def latencies(self, steps: list[StepFit | None]) -> np.ndarray:
        """Every timed step's latency, each joint's with its own M, D (m,) [s]."""
        values = []
        for joint, fit in enumerate(steps):
            parts = self.windows("timed_step", joint)
            if fit is None or not parts:
                continue
            values.append(
                fit_timed_steps(
                    parts,
                    stiffness=float(self.stiffness[joint]),
                    inertia=fit.inertia.value,
                    damping=fit.damping.value,
                )
            )
        return np.concatenate(values) if values else np.array([])

    def converge(self) -> tuple[float, list[StepFit | None], np.ndarray]:
        """The steps' M, D and the timed steps' latency, each fitted given the other, to
        their fixed point (:data:`LATENCY_CONVERGED`; Aitken's extrapolation every third
        round): (the latency [s], the step fits, the timed steps' latencies)."""
        latency = 0.0
        history: list[float] = []
        for _ in range(LATENCY_ROUNDS):
            steps = self.steps(latency)
            values = self.latencies(steps)
            if not len(values):
                return latency, steps, values
            following = float(np.mean(values))
            if abs(following - latency) < LATENCY_CONVERGED:
                return following, steps, values
            history += [latency, following] if not history else [following]
            latency = following
            if len(history) == 3:
                x0, x1, x2 = history
                curvature = x2 - 2.0 * x1 + x0
                if abs(curvature) > 1e-12:
                    latency = x0 - (x1 - x0) ** 2 / curvature
                history = []
        return latency, steps, values

    def frictions(self, steps: list[StepFit | None], latency: float):
        """Per joint (stiction, Coulomb friction, breakaway bias), each None where not
        identified (:func:`.friction.fit_friction`)."""
        out = []
        for joint in range(NUM_JOINTS):
            ramps = _windows(self.segments, "breakaway", joint)
            fit = steps[joint]
            if not ramps:
                out.append((None, None, None))
                continue
            if fit is None:
                reason = "no damping and inertia to take away (its steps were not identified)"
                for name in ("stiction", "coulomb_friction"):
                    self.attempt.absent((name, joint), reason)
                out.append((None, None, None))
                continue
            out.append(
                fit_friction(
                    self.log,
                    self.applied,
                    ramps,
                    joint,
                    fit,
                    float(self.stiffness[joint]),
                    self.band,
                    latency,
                    self.attempt,
                )
            )
        return out
