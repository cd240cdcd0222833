"""The joints' friction from an identification's breakaways (pure: the log's arrays and the
joint's step fit in, estimates out; :mod:`.analysis` calls it per joint).

Per sample of a breakaway ramp the friction the joint showed is what is left of the applied
feed-forward torque once its inertia, damping and spring are taken away, each command taken
as it acts around the sample (:func:`acting`: the
latency shifts when a command acts, by up to a cycle's ramp of torque and a cycle's travel).
Stiction is the largest of it before the joint slid, per ramp and direction
(:func:`.fit.fit_breakaway`); Coulomb friction what is left while it slid
(:func:`.fit.fit_coulomb`).
"""

from __future__ import annotations

import math

import numpy as np

from doorlab.hardware.identify.fit import Estimate, StepFit, fit_breakaway, fit_coulomb
from doorlab.kuka import CYCLE_PERIOD, STRIBECK_VELOCITY


def acting(values: np.ndarray, rows: np.ndarray, latency: float) -> np.ndarray:
    """What a command acts as around each row k: its mean over the cycle centred on the
    status (the command applied at cycle j acts from j T + L on, L the latency; a sample's
    central differences look half a cycle either side) (len(rows), ...).

    Args:
        values: One entry per row, the command applied at that cycle (``analysis._applied``).
        rows: The rows. latency: L in [-T/2, T) [s].
    """
    s = latency / CYCLE_PERIOD + 0.5
    j = math.floor(s)
    f = s - j
    last = len(values) - 1
    newer = values[np.clip(rows - j, 0, last)]
    older = values[np.clip(rows - j - 1, 0, last)]
    return (1.0 - f) * newer + f * older


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


def fit_friction(
    log: dict[str, np.ndarray],
    applied: dict[str, np.ndarray],
    ramps: list,
    joint: int,
    step: StepFit,
    stiffness: float,
    band: float,
    latency: float,
    attempt,
) -> tuple[Estimate | None, Estimate | None, Estimate | None]:
    """(stiction, Coulomb friction, bias) [N m] of one joint from its breakaway ramps (module
    docstring); an estimate the ramps cannot give is None, its reason in ``attempt``.

    Args:
        log: The log's arrays. applied: The commands applied per row (``q``, ``tau``).
        ramps: The joint's breakaway segments. step: The joint's step fit (M, D).
        stiffness: K [N m/rad]. band: KUKA's friction observer's band [rad].
        latency: The latency beyond the cycle [s] (the timed steps'). attempt: Keeps the
            reasons (:class:`doorlab.hardware.identify.analysis._Attempts`).

    A stiction's uncertainty is at least one cycle's increment of the ramp over sqrt(12):
    the joint held at one status and slid at the next, so the torque it broke away at lies
    anywhere within that increment (what bounds the estimate of a joint with no friction).
    """
    qj = log["q"][:, joint]
    peaks: dict[int, list[float]] = {+1: [], -1: []}
    noise: list[float] = []
    taus, speeds, weights = [], [], []
    largest = 0.0
    for s in ramps:
        rows = np.arange(s.start + 1, min(s.stop, len(qj) - 1))
        if len(rows) < 3:
            continue
        vel = (qj[rows + 1] - qj[rows - 1]) / (2 * CYCLE_PERIOD)
        acc = (qj[rows + 1] - 2 * qj[rows] + qj[rows - 1]) / CYCLE_PERIOD**2
        r = applied["q"][rows, joint]
        r_acting = acting(applied["q"][:, joint], rows, latency)
        tau_ff = applied["tau"][rows, joint]
        tau_acting = acting(applied["tau"][:, joint], rows, latency)
        base = applied["tau"][s.start, joint]  # the ramp starts at the bias the rest showed
        largest = max(largest, float(np.max(np.abs(tau_ff - base))))
        # M a + D v = tau_ff - base + K (r - q) + tau_friction
        friction = step.inertia.value * acc + step.damping.value * vel
        friction -= stiffness * (r_acting - qj[rows]) + tau_acting - base
        w = np.minimum(np.abs(r - qj[rows]) / band, 1.0)
        if s.info.get("broke_away"):  # the friction opposing the push, at its largest
            # (1 - w) of it acts: KUKA's observer cancels w (|q_ref - q| = v x the delay)
            full = -s.sign * friction / np.maximum(1.0 - w, 0.1)
            full = np.where(w < 0.9, full, -np.inf)
            peak = int(np.argmax(full))
            peaks[s.sign].append(float(full[peak]))
            increment = float(np.max(np.abs(np.diff(tau_ff))))
            uncertainty = increment / math.sqrt(12.0)
            if 3 < peak < len(full) - 1:
                # Or its change from one cycle to the next at the peak, or the observer's
                # share w, known to a cycle's travel only (the arm compares q_ref with q at
                # its own rate, within the cycle): dw = |v| T / band.
                change = max(abs(full[peak] - full[peak - 1]), abs(full[peak] - full[peak + 1]))
                dw = abs(vel[peak]) * CYCLE_PERIOD / band
                uncertainty = max(uncertainty, change, abs(full[peak]) * dw)
            # and what the damping's error makes of it at the peak's speed
            uncertainty = max(uncertainty, step.damping.stderr * abs(vel[peak]))
            noise.append(float(uncertainty))
        taus.append(friction)
        speeds.append(vel)
        weights.append(w)
    if not peaks[+1] or not peaks[-1]:
        never = "up" if not peaks[+1] else "down"
        attempt.absent(
            ("stiction", joint),
            f"the joint never broke away ramping {never} (to {largest:.3g} N m): its stiction "
            "is above what the script pushed",
        )
        stiction = bias = None
    else:  # tau+ = b + Fs going up, tau- = b - Fs going down
        pair = attempt(
            ("stiction", joint),
            fit_breakaway,
            peaks[+1],
            [-p for p in peaks[-1]],
            noise=float(np.mean(noise)) if noise else 0.0,
        )
        stiction, bias = pair if pair is not None else (None, None)
    coulomb = None
    if taus:
        coulomb = attempt(
            ("coulomb_friction", joint),
            fit_coulomb,
            np.concatenate(taus),
            np.concatenate(speeds),
            np.concatenate(weights),
            min_speed=2 * STRIBECK_VELOCITY,
            slides=len(taus),
            damping_error=step.damping.stderr,
        )
    else:
        attempt.absent(("coulomb_friction", joint), "no breakaway long enough to slide")
    return stiction, coulomb, bias
