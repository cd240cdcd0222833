"""The fits of ``doorlab identify`` (pure functions of the logged statuses, numpy only).

Each fit returns its values with a standard error derived from its own residuals (least
squares: sigma^2 = RSS / (n - p), covariance sigma^2 (J^T J)^-1), and the tolerance a
recovered value is stated with is :data:`TOLERANCE_SIGMAS` standard errors.

- :func:`fit_rest`: at rest at the calibration pose KUKA's external torque is its load-data
  error (the gripper's gravity it leaves out, linear in the mass it lacks) plus noise: the
  mass, per joint the noise's standard deviation and the torque KUKA's model lacks.
- :func:`fit_step`: one joint's response to a ramped step of q_ref, as the single joint
  M a + D v = K (r(t - L) - q) + b with K known (KUKA's stiffness, set in the Java
  application): the effective inertia M, the damping D, the latency L beyond the cycle and
  the bias b, by Gauss-Newton on the exact response (the input is piecewise constant, each
  cycle's command from the cycle plus L on: :func:`step_response`). Samples where
  |r - q| < 2 x the friction-compensation band are left out (there KUKA's friction observer
  lets the joints' friction act).
- :func:`fit_timed_steps`: single-cycle steps with M, D known: the latency of each, so the
  mean latency and its jitter (a uniform jitter of half-width J has standard deviation
  J / sqrt(3)).
- :func:`fit_breakaway`: the feed-forward torque at which a joint held at q_ref = q starts
  to move under a slow ramp, in both directions: stiction (half the difference), and the
  bias between them.
- :func:`fit_coulomb`: while the joint slides with KUKA's observer off (|q_ref - q| below
  its band), the friction left once the inertia, the damping and the spring are taken
  away: Coulomb friction.

A fit the recording cannot make raises :class:`NotIdentifiable` with the reason, found where
it arises (a joint that never moved, too few samples, a Jacobian that is singular or not
finite, no breakaway): :mod:`.analysis` keeps the preset's value for that parameter and says
why. The standard errors come from the Jacobian's singular values (J^T J is never formed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from doorlab.hardware.identify.response import (
    coupled_response,
    step_response,
)
from doorlab.kuka import CYCLE_PERIOD

TOLERANCE_SIGMAS = 3.0
"""A recovered value's tolerance: this many standard errors of its fit."""


class NotIdentifiable(ValueError):
    """The recording cannot give this estimate; the message says why in a few words (the
    caller keeps the preset's value and says so: :mod:`.analysis`)."""


def _finite(name: str, *arrays: np.ndarray) -> None:
    """Raises :class:`NotIdentifiable` if an entry of ``arrays`` is NaN or infinite."""
    for a in arrays:
        if not np.all(np.isfinite(a)):
            raise NotIdentifiable(f"{name} not finite")


SINGULAR = 1e-10
"""A least-squares problem whose Jacobian's smallest singular value is below this share of its
largest is singular: some combination of its parameters does not change the residual."""


def standard_errors(J: np.ndarray, residual: np.ndarray, names: tuple[str, ...]) -> np.ndarray:
    """Least squares' standard errors sqrt(diag(sigma^2 (J^T J)^-1)), sigma^2 = RSS / (n - p),
    from J's singular values (J^T J is never formed: it squares the condition number).

    Raises:
        NotIdentifiable: J or the residual is not finite, fewer samples than parameters, or J
            is singular (:data:`SINGULAR`; the message names the parameter it leaves free).
    """
    J, residual = np.atleast_2d(np.asarray(J, float)), np.asarray(residual, float)
    _finite("the fit's Jacobian", J)
    _finite("the fit's residual", residual)
    n, p = J.shape
    if n <= p:
        raise NotIdentifiable(f"{n} samples for {p} parameters")
    _, s, vt = np.linalg.svd(J, full_matrices=False)
    if s[0] == 0.0 or s[-1] < SINGULAR * s[0]:
        free = names[int(np.argmax(np.abs(vt[-1])))]
        raise NotIdentifiable(f"singular fit: the recording does not determine the {free}")
    sigma2 = float(residual @ residual) / (n - p)
    return np.sqrt(sigma2 * np.sum((vt / s[:, None]) ** 2, axis=0))


@dataclass(frozen=True)
class Estimate:
    """A fitted value with its quality.

    Attributes:
        value: The estimate. stderr: Its standard error (same unit). n: Samples used.
        rms_residual: The fit's root-mean-square residual (in the data's unit).
    """

    value: float
    stderr: float
    n: int
    rms_residual: float

    @property
    def tolerance(self) -> float:
        """:data:`TOLERANCE_SIGMAS` standard errors."""
        return TOLERANCE_SIGMAS * self.stderr

    def to_dict(self, unit: str) -> dict:
        def clean(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None

        return {
            "value": clean(self.value),
            "stderr": clean(self.stderr),
            "tolerance": clean(self.tolerance),
            "unit": unit,
            "samples": self.n,
            "rms_residual": clean(self.rms_residual),
        }


def linear_fit(
    A: np.ndarray, y: np.ndarray, names: tuple[str, ...] = ("value",)
) -> tuple[np.ndarray, np.ndarray, float]:
    """Least squares y ~ A x: (x, standard errors of x, rms residual).

    Raises:
        NotIdentifiable: A or y not finite, too few samples, A singular
            (:func:`standard_errors`).
    """
    A, y = np.atleast_2d(np.asarray(A, float)), np.asarray(y, float)
    _finite("the fit's data", A, y)
    standard_errors(A, y, names)  # the checks, before lstsq meets a NaN
    x, *_ = np.linalg.lstsq(A, y, rcond=None)
    r = y - A @ x
    return x, standard_errors(A, r, names), math.sqrt(float(r @ r) / max(len(y), 1))


# Rest ----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RestFit:
    """What the arm at rest tells.

    Attributes:
        load_mass: The mass KUKA's load data carry [kg] (None: not identifiable, see
            ``load_reason``). noise: Per joint, the external torque's standard deviation
            [N m] (7 estimates). bias: Per joint, the mean external torque [N m] (7,).
        load_reason: Why the load data were not identified ("" when they were).
    """

    load_mass: Estimate | None
    noise: tuple[Estimate, ...]
    bias: np.ndarray
    load_reason: str = ""


def fit_rest(tau_external: np.ndarray, gravity_per_kg: np.ndarray, true_mass: float) -> RestFit:
    """Load data and noise from the external torques at rest.

    Args:
        tau_external: The statuses' external torques at rest (n, 7) [N m].
        gravity_per_kg: The holding torque of 1 kg at the gripper's centre of mass at the
            pose (7,) [N m/kg] (KUKA's estimate lacks (m_true - m_entered) times it).
        true_mass: The mass the arm carries [kg] (the gripper's).

    Raises:
        NotIdentifiable: Fewer than two statuses, or an external torque not finite (a
            driver that does not report it).
    """
    tau = np.asarray(tau_external, float)
    n = len(tau)
    if n < 2:
        raise NotIdentifiable(f"{n} status at rest")
    _finite("KUKA's external torque at rest", tau)
    mean = tau.mean(axis=0)
    std = tau.std(axis=0, ddof=1)
    noise = tuple(Estimate(float(s), float(s) / math.sqrt(2 * (n - 1)), n, float(s)) for s in std)
    # mean = (m_entered - m_true) G; each mean's standard error std / sqrt(n)
    weights = 1.0 / np.maximum(std / math.sqrt(n), 1e-6)
    G = np.asarray(gravity_per_kg, float)
    try:
        x, se, rms = linear_fit((G * weights)[:, None], mean * weights, ("load mass",))
    except NotIdentifiable as e:
        return RestFit(None, noise, mean, str(e))
    # the weighted residual's rms is ~1 when the model holds; the standard error carries it
    return RestFit(Estimate(true_mass + float(x[0]), float(se[0]), n, float(rms)), noise, mean)


# The step fits ------------------------------------------------------------------------------


@dataclass(frozen=True)
class StepFit:
    """One joint's step fit. Attributes: inertia [kg m^2], damping [N m s/rad], latency [s],
    bias [N m] (:class:`Estimate` each)."""

    inertia: Estimate
    damping: Estimate
    latency: Estimate
    bias: Estimate


def _jacobian(residual, x: np.ndarray, r: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """The residual's forward-difference Jacobian at x (n, p)."""
    J = np.empty((len(r), len(x)))
    for j in range(len(x)):
        dx = np.zeros_like(x)
        dx[j] = 1e-6 * scale[j]
        J[:, j] = (residual(x + dx) - r) / dx[j]
    return J


def _gauss_newton(residual, x0: np.ndarray, scale: np.ndarray, iterations: int = 30):
    """Minimizes |residual(x)|^2 (Levenberg-Marquardt, numeric Jacobian): (x, J, r).

    Raises:
        NotIdentifiable: the residual or its Jacobian is not finite where the fit starts or
            ends (a NaN in the log, or a model that overflows): a trial step that is not
            finite is refused like one that does not improve.
    """
    x = np.asarray(x0, float).copy()
    lam = 1e-3
    r = residual(x)
    _finite("the fit's residual", r)
    cost = float(r @ r)
    for _ in range(iterations):
        J = _jacobian(residual, x, r, scale)
        if not np.all(np.isfinite(J)):
            break  # the standard errors' check below names it
        H = J.T @ J
        g = J.T @ r
        improved = False
        for _ in range(10):
            step = -np.linalg.lstsq(H + lam * np.diag(np.diag(H) + 1e-30), g, rcond=None)[0]
            trial = x + step
            r_trial = residual(trial)
            c_trial = float(r_trial @ r_trial)
            if np.isfinite(c_trial) and c_trial < cost:
                x, r, cost, lam = trial, r_trial, c_trial, max(lam / 3, 1e-9)
                improved = True
                break
            lam *= 10
        if not improved or np.all(np.abs(step) < 1e-9 * scale):
            break
    return x, _jacobian(residual, x, r, scale), r


def correlation_inflation(inertia: float, damping: float) -> float:
    """What a step fit's standard errors are multiplied by: its residuals are the model's
    error, a shape over the whole response, correlated over the loop's 2 % settling time
    t_s = 4 / (zeta w_n) = 8 M / D; of n residuals about n T / t_s are independent, so the
    white-noise standard errors grow by sqrt(t_s / T) (at least 1)."""
    return math.sqrt(max(8.0 * inertia / damping / CYCLE_PERIOD, 1.0))


def _combine(values: list[float], stderrs: list[float], n: int, rms: float) -> Estimate:
    """The mean of per-segment estimates; its standard error the larger of their scatter's
    (std / sqrt(m): what repeats show, model error included) and their own fits'."""
    v = np.asarray(values, float)
    m = len(v)
    scatter = float(v.std(ddof=1)) / math.sqrt(m) if m > 1 else math.nan
    own = float(np.sqrt(np.mean(np.square(stderrs)) / m))
    se = own if not math.isfinite(scatter) else max(scatter, own)
    return Estimate(float(v.mean()), se, n, rms)


def fit_step(
    segments: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
    *,
    stiffness: float,
    guess_inertia: float,
    guess_damping: float,
    band: float,
    latency: float = 0.0,
) -> StepFit:
    """M, D and the bias of one joint from its step segments, each fitted on its own (the
    latency given: :func:`fit_timed_steps` measures it); the estimates their mean, their
    standard errors from the repeats' scatter (:func:`_combine`).

    Args:
        segments: (r, q, u) per segment: r[k] the command applied at cycle k (the answer
            to status k - 1), q[k] the status's measured position at cycle k (both (m,)
            [rad]), u[k] the coupling torque over cycle k (:func:`coupling_torque`).
        stiffness: K [N m/rad]. guess_inertia, guess_damping: Where the fit starts.
        band: KUKA's friction-compensation band [rad]: samples with |r - q| < 2 band are
            left out of the residual.
        latency: The latency beyond the cycle [s].

    Raises:
        NotIdentifiable: The joint never moved (:func:`check_moved`), or a segment's fit is
            singular or not finite (:func:`standard_errors`).
    """
    check_moved([(r, q) for r, q, _ in segments])
    fits = []
    for r, q, u in segments:

        def residual(x: np.ndarray, r=r, q=q, u=u) -> np.ndarray:
            M, D, b = math.exp(x[0]), math.exp(x[1]), x[2]
            model = step_response(
                r, M=M, D=D, K=stiffness, latency=latency, bias=b, q0=q[0], coupling=u
            )
            keep = np.abs(r - q) >= 2 * band
            keep[0] = False
            return (model - q)[keep]

        x0 = np.array([math.log(guess_inertia), math.log(guess_damping), 0.0])
        x, J, res = _gauss_newton(residual, x0, np.array([1.0, 1.0, 1.0]))
        fits.append(_segment_fit(x, J, res, STEP_PARAMETERS[:3]))
    return _step_fit(fits, latency)


STEP_PARAMETERS = ("inertia", "damping", "bias", "partner's bias")
"""The step fits' parameters (log M, log D, b, and the coupled fit's partner's b)."""
MOVED_SHARE = 0.1
"""A joint whose steps moved it less than this share of the commanded travel never moved (a
brake, a joint the driver does not command): its steps identify nothing."""


def check_moved(segments: list[tuple[np.ndarray, np.ndarray]]) -> None:
    """Raises :class:`NotIdentifiable` if no segment moved the joint :data:`MOVED_SHARE` of
    the travel it was commanded ((r, q) per segment, (m,) each [rad])."""
    commanded = max((float(np.ptp(r)) for r, _ in segments), default=0.0)
    moved = max((float(np.ptp(q)) for _, q in segments), default=0.0)
    if not segments or moved < MOVED_SHARE * commanded or not commanded > 0:
        raise NotIdentifiable(
            f"the joint never moved (steps of {math.degrees(commanded):.3g} deg moved it "
            f"{math.degrees(moved):.2g} deg)"
        )


def _segment_fit(x: np.ndarray, J: np.ndarray, res: np.ndarray, names: tuple[str, ...]):
    """One segment's (x, standard errors inflated for the residuals' correlation, samples,
    rms residual)."""
    se = standard_errors(J, res, names)
    se *= correlation_inflation(math.exp(x[0]), math.exp(x[1]))
    return x, se, len(res), math.sqrt(float(res @ res) / max(len(res), 1))


def _step_fit(fits: list, latency: float) -> StepFit:
    """The segments' fits combined (:func:`_combine`)."""
    n = sum(f[2] for f in fits)
    rms = math.sqrt(sum(f[3] ** 2 * f[2] for f in fits) / max(n, 1))
    M = [math.exp(f[0][0]) for f in fits]
    D = [math.exp(f[0][1]) for f in fits]
    return StepFit(
        _combine(M, [m * f[1][0] for m, f in zip(M, fits, strict=True)], n, rms),
        _combine(D, [d * f[1][1] for d, f in zip(D, fits, strict=True)], n, rms),
        Estimate(latency, 0.0, 0, math.nan),
        _combine([f[0][2] for f in fits], [f[1][2] for f in fits], n, rms),
    )


def fit_coupled_step(
    segments: list[tuple[np.ndarray, np.ndarray]],
    *,
    joint: int,
    partner: int,
    inertia: np.ndarray,
    partner_damping: float,
    stiffness: np.ndarray,
    guess: StepFit,
    band: float,
    latency: float = 0.0,
) -> StepFit:
    """:func:`fit_step` for a joint strongly coupled to another through the inertia matrix
    (the iiwa's joints 1 and 3): both simulated together, the partner's inertia and damping
    and the pair's cross inertia given (from the model and the partner's own fit); M, D and
    the joint's bias fitted per segment.

    Args:
        segments: (r, q) per segment, each (m, 7): the commands applied and measured q.
        inertia: The 2 x 2 block [[M_ii, M_ij], [M_ji, M_jj]] (M_ii the starting guess).
        stiffness: K of the two joints (2,).
    """
    check_moved([(r[:, joint], q[:, joint]) for r, q in segments])
    fits = []
    pair = [joint, partner]
    for r, q in segments:
        r2, q2 = r[:, pair], q[:, pair]

        def residual(x: np.ndarray, r2=r2, q2=q2) -> np.ndarray:
            M = inertia.copy()
            M[0, 0] = math.exp(x[0])
            D = np.array([math.exp(x[1]), partner_damping])
            b = np.array([x[2], x[3]])
            model = coupled_response(r2, M=M, D=D, K=stiffness, latency=latency, bias=b, q0=q2[0])
            keep = np.abs(r2[:, 0] - q2[:, 0]) >= 2 * band
            keep[0] = False
            return np.concatenate([(model[:, 0] - q2[:, 0])[keep], (model[:, 1] - q2[:, 1])[1:]])

        x0 = np.array(
            [math.log(guess.inertia.value), math.log(guess.damping.value), guess.bias.value, 0.0]
        )
        x, J, res = _gauss_newton(residual, x0, np.ones(4))
        fits.append(_segment_fit(x, J, res, STEP_PARAMETERS))
    return _step_fit(fits, latency)


COUPLING_THRESHOLD = 0.2
"""Two joints whose inertia coupling M_ij / sqrt(M_ii M_jj) exceeds this are fitted together
(:func:`fit_coupled_step`)."""
MIN_LATENCY = -0.5 * CYCLE_PERIOD
"""The lowest latency a fit considers [s]: an arm's is >= 0, but the simulator realizes its
arm's latency L as L - h/2 (:func:`.response.step_response`), -1.25 ms for the arm preset's
(none beyond the cycle, h = 2.5 ms); a fit held at 0 there takes the difference out of the
damping (1 % low, measured on the preset) and leaves it in every friction estimate."""
ONSET_CYCLES = 6
"""A timed step's latency is fitted on this many cycles after each change of the command
(where the latency shows and the single-joint model is closest to the arm)."""


def fit_timed_steps(
    segments: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
    *,
    stiffness: float,
    inertia: float,
    damping: float,
) -> np.ndarray:
    """The latency of each single-cycle change of the command (M, D known), fitted on the
    :data:`ONSET_CYCLES` after it, within [:data:`MIN_LATENCY`, the period] (m,) [s]; a change
    whose fit is not finite is left out (:func:`latency_estimate` summarizes them)."""
    latencies = []
    for r, q, u in segments:
        changes = np.flatnonzero(np.abs(np.diff(r)) > 1e-9) + 1
        for c in changes:
            lo, hi = c - 1, min(c + ONSET_CYCLES + 1, len(r))

            v0 = (q[lo] - q[lo - 1]) / CYCLE_PERIOD if lo > 0 else 0.0

            def residual(x: np.ndarray, r=r[lo:hi], q=q[lo:hi], u=u[lo:hi], v0=v0):
                model = step_response(
                    r,
                    M=inertia,
                    D=damping,
                    K=stiffness,
                    latency=x[0],
                    bias=0.0,
                    q0=q[0],
                    v0=v0,
                    coupling=u,
                )
                return (model - q)[1:]

            best = None
            for latency0 in (-1.5e-3, 0.5e-3, 2.5e-3, 4.5e-3):
                try:
                    x, _, res = _gauss_newton(residual, np.array([latency0]), np.array([1e-3]))
                except NotIdentifiable:
                    continue
                if best is None or float(res @ res) < best[1]:
                    best = (x, float(res @ res))
            if best is not None:
                latencies.append(float(best[0][0]))
    return np.clip(np.array(latencies, float), MIN_LATENCY, CYCLE_PERIOD)


def latency_estimate(latencies: np.ndarray) -> Estimate:
    """The mean of the timed steps' latencies [s], its standard error their scatter's.

    Raises:
        NotIdentifiable: No timed step, or every one's fit at a bound of its range
            ([:data:`MIN_LATENCY`, the period]): the latency lies beyond what the fit resolves.
    """
    values = np.asarray(latencies, float)
    m = len(values)
    if m == 0:
        raise NotIdentifiable("no timed step in the recording")
    if np.all((values <= MIN_LATENCY + 1e-7) | (values >= CYCLE_PERIOD - 1e-7)):
        raise NotIdentifiable(
            f"every timed step's fit at a bound of [{1e3 * MIN_LATENCY:g}, "
            f"{1e3 * CYCLE_PERIOD:g}] ms"
        )
    std = float(values.std(ddof=1)) if m > 1 else math.nan
    return Estimate(float(values.mean()), std / math.sqrt(m) if m > 1 else math.nan, m, std)


def jitter_estimate(latencies: np.ndarray) -> Estimate:
    """The jitter's half-width sqrt(3) x the latencies' standard deviation [s] (a uniform
    jitter of half-width J has a standard deviation J / sqrt(3)).

    Raises:
        NotIdentifiable: Fewer than two timed steps.
    """
    values = np.asarray(latencies, float)
    m = len(values)
    if m == 0:
        raise NotIdentifiable("no timed step in the recording")
    if m < 2:
        raise NotIdentifiable("one timed step in the recording: no scatter to measure")
    std = float(values.std(ddof=1))
    value = math.sqrt(3.0) * std
    return Estimate(value, value / math.sqrt(2 * (m - 1)), m, std)


# Friction ------------------------------------------------------------------------------------


def fit_breakaway(
    positive: list[float], negative: list[float], *, noise: float = 0.0
) -> tuple[Estimate, Estimate]:
    """(stiction, bias) [N m] from the torques at which the joint broke away, ramping up
    (positive) and down (negative): tau+ = b + Fs, tau- = b - Fs. The standard error is the
    larger of the repeats' scatter and each estimate's own ``noise`` [N m] (its scatter from
    one cycle to the next), over sqrt(2 m).

    Raises:
        NotIdentifiable: No breakaway in one of the directions, or one not finite.
    """
    up, down = np.asarray(positive, float), np.asarray(negative, float)
    if not len(up) or not len(down):
        raise NotIdentifiable(f"no breakaway {'up' if not len(up) else 'down'}")
    _finite("a breakaway's torque", up, down)
    m = min(len(up), len(down))
    fs = 0.5 * (up.mean() - down.mean())
    b = 0.5 * (up.mean() + down.mean())
    spread = np.concatenate([up - up.mean(), down - down.mean()])
    sd = float(spread.std(ddof=2)) if len(spread) > 2 else 0.0
    sd = max(sd, noise)
    se = 0.5 * sd * math.sqrt(1 / max(len(up), 1) + 1 / max(len(down), 1))
    return Estimate(float(fs), se, m, sd), Estimate(float(b), se, m, sd)


def fit_coulomb(
    tau: np.ndarray,
    v: np.ndarray,
    compensation: np.ndarray,
    *,
    min_speed: float,
    slides: int = 1,
    damping_error: float = 0.0,
) -> Estimate:
    """Coulomb friction [N m] from sliding samples: tau (the torque left once inertia,
    damping, spring and bias are taken away) = -(1 - w) Fc sign(v), over |v| >= min_speed
    and w < 0.9.

    The residuals are the friction model's error more than noise, smooth over a slide: the
    standard error is at least their rms over sqrt(``slides``) (one independent sample per
    slide), not over sqrt(n); and at least what the damping's error makes of it: at one
    speed a damping off by dD shows as a friction dD |v| (the slides of a joint that breaks
    away at the script's threshold all run at about that speed).

    Args:
        tau: (n,) [N m]. v: (n,) [rad/s]. compensation: w (n,) in [0, 1].
        slides: How many slides the samples come from.
        damping_error: The damping's standard error [N m s/rad] (the step fit's).

    Raises:
        NotIdentifiable: Fewer than 3 samples slid at ``min_speed`` or faster with KUKA's
            observer mostly off, or the fit is singular or not finite.
    """
    tau, v, w = (np.asarray(a, float) for a in (tau, v, compensation))
    keep = (np.abs(v) >= min_speed) & (w < 0.9)
    if keep.sum() < 3:
        raise NotIdentifiable(
            f"the joint never slid at {min_speed:g} rad/s or faster with KUKA's friction "
            f"observer off ({int(keep.sum())} samples)"
        )
    regressor = -(1.0 - w[keep]) * np.sign(v[keep])
    x, se, rms = linear_fit(regressor[:, None], tau[keep], ("Coulomb friction",))
    # w is known to a cycle's travel only (the arm compares q_ref with q within the cycle):
    # (1 - w) uncertain by up to w, so Fc by up to Fc w / (1 - w)
    share = float(np.mean(w[keep]))
    model = abs(float(x[0])) * share / max(1.0 - share, 0.1) / TOLERANCE_SIGMAS
    correlated = rms / math.sqrt(max(slides, 1))
    damping = damping_error * float(np.mean(np.abs(v[keep]) / (1.0 - w[keep])))
    se = max(float(se[0]), model, correlated, damping)
    return Estimate(float(x[0]), se, int(keep.sum()), rms)
