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
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from doorlab.kuka import CYCLE_PERIOD

TOLERANCE_SIGMAS = 3.0
"""A recovered value's tolerance: this many standard errors of its fit."""


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


def linear_fit(A: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Least squares y ~ A x: (x, standard errors of x, rms residual)."""
    A, y = np.atleast_2d(np.asarray(A, float)), np.asarray(y, float)
    x, *_ = np.linalg.lstsq(A, y, rcond=None)
    r = y - A @ x
    dof = max(len(y) - A.shape[1], 1)
    sigma2 = float(r @ r) / dof
    cov = sigma2 * np.linalg.pinv(A.T @ A)
    return x, np.sqrt(np.maximum(np.diag(cov), 0.0)), math.sqrt(float(r @ r) / max(len(y), 1))


# Rest ----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RestFit:
    """What the arm at rest tells.

    Attributes:
        load_mass: The mass KUKA's load data carry [kg]. noise: Per joint, the external
            torque's standard deviation [N m] (7 estimates). bias: Per joint, the mean
            external torque [N m] (7,).
    """

    load_mass: Estimate
    noise: tuple[Estimate, ...]
    bias: np.ndarray


def fit_rest(tau_external: np.ndarray, gravity_per_kg: np.ndarray, true_mass: float) -> RestFit:
    """Load data and noise from the external torques at rest.

    Args:
        tau_external: The statuses' external torques at rest (n, 7) [N m].
        gravity_per_kg: The holding torque of 1 kg at the gripper's centre of mass at the
            pose (7,) [N m/kg] (KUKA's estimate lacks (m_true - m_entered) times it).
        true_mass: The mass the arm carries [kg] (the gripper's).
    """
    tau = np.asarray(tau_external, float)
    n = len(tau)
    mean = tau.mean(axis=0)
    std = tau.std(axis=0, ddof=1)
    # mean = (m_entered - m_true) G; each mean's standard error std / sqrt(n)
    weights = 1.0 / np.maximum(std / math.sqrt(n), 1e-6)
    G = np.asarray(gravity_per_kg, float)
    x, se, rms = linear_fit((G * weights)[:, None], mean * weights)
    # the weighted residual's rms is ~1 when the model holds; the standard error carries it
    load = Estimate(true_mass + float(x[0]), float(se[0]), n, float(rms))
    noise = tuple(
        Estimate(float(s), float(s) / math.sqrt(2 * (n - 1)), n, float(s)) for s in std
    )
    return RestFit(load, noise, mean)


# The step response ---------------------------------------------------------------------------


def _expm(A: np.ndarray) -> np.ndarray:
    """exp(A) of a small matrix (scaling and squaring of a Taylor series)."""
    norm = np.max(np.sum(np.abs(A), axis=1))
    k = max(0, int(math.ceil(math.log2(norm))) + 1) if norm > 0.5 else 0
    B = A / 2.0**k
    E, term = np.eye(len(A)), np.eye(len(A))
    for i in range(1, 14):
        term = term @ B / i
        E = E + term
    for _ in range(k):
        E = E @ E
    return E


def _transition(M: float, D: float, K: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact discretization over dt of x' = [[0, 1], [-K/M, -D/M]] x + [0, 1/M] (K r + b):
    (Phi (2, 2), Gamma (2,)) with x+ = Phi x + Gamma (K r + b)."""
    A = np.zeros((3, 3))
    A[0, 1] = 1.0
    A[1, 0], A[1, 1], A[1, 2] = -K / M, -D / M, 1.0 / M
    E = _expm(A * dt)
    return E[:2, :2], E[:2, 2]


def step_response(
    r: np.ndarray,
    *,
    M: float,
    D: float,
    K: float,
    latency: float,
    bias: float,
    q0: float,
    v0: float = 0.0,
    period: float = CYCLE_PERIOD,
) -> np.ndarray:
    """q at each cycle of the single joint M a + D v = K (r - q) + b, where r[k] (the command
    applied at cycle k) acts from cycle k + ``latency`` on (0 <= latency < period).

    Returns:
        (len(r),) q at cycles 0 .. len(r) - 1 (q0 at cycle 0) [rad].
    """
    r = np.asarray(r, float)
    L = min(max(latency, 0.0), period * (1 - 1e-9))
    P1, G1 = _transition(M, D, K, L)
    P2, G2 = _transition(M, D, K, period - L)
    x = np.array([q0, v0])
    out = np.empty(len(r))
    previous = r[0]
    for k in range(len(r)):
        out[k] = x[0]
        x = P1 @ x + G1 * (K * previous + bias)
        x = P2 @ x + G2 * (K * r[k] + bias)
        previous = r[k]
    return out


@dataclass(frozen=True)
class StepFit:
    """One joint's step fit. Attributes: inertia [kg m^2], damping [N m s/rad], latency [s],
    bias [N m] (:class:`Estimate` each)."""

    inertia: Estimate
    damping: Estimate
    latency: Estimate
    bias: Estimate


def _gauss_newton(residual, x0: np.ndarray, scale: np.ndarray, iterations: int = 30):
    """Minimizes |residual(x)|^2 (Levenberg-Marquardt, numeric Jacobian): (x, J, r)."""
    x = np.asarray(x0, float).copy()
    lam = 1e-3
    r = residual(x)
    cost = float(r @ r)
    for _ in range(iterations):
        J = np.empty((len(r), len(x)))
        for j in range(len(x)):
            dx = np.zeros_like(x)
            dx[j] = 1e-6 * scale[j]
            J[:, j] = (residual(x + dx) - r) / dx[j]
        H = J.T @ J
        g = J.T @ r
        improved = False
        for _ in range(10):
            step = -np.linalg.solve(H + lam * np.diag(np.diag(H) + 1e-30), g)
            trial = x + step
            r_trial = residual(trial)
            c_trial = float(r_trial @ r_trial)
            if c_trial < cost:
                x, r, cost, lam = trial, r_trial, c_trial, max(lam / 3, 1e-9)
                improved = True
                break
            lam *= 10
        if not improved or np.all(np.abs(step) < 1e-9 * scale):
            break
    J = np.empty((len(r), len(x)))
    for j in range(len(x)):
        dx = np.zeros_like(x)
        dx[j] = 1e-6 * scale[j]
        J[:, j] = (residual(x + dx) - r) / dx[j]
    return x, J, r


def fit_step(
    segments: list[tuple[np.ndarray, np.ndarray]],
    *,
    stiffness: float,
    guess_inertia: float,
    guess_damping: float,
    band: float,
) -> StepFit:
    """M, D, L and the bias of one joint from its step segments.

    Args:
        segments: (r, q) per segment: r[k] the command applied at cycle k (the answer to
            status k - 1), q[k] the status's measured position at cycle k (both (m,) [rad]).
        stiffness: K [N m/rad]. guess_inertia, guess_damping: Where the fit starts.
        band: KUKA's friction-compensation band [rad]: samples with |r - q| < 2 band are
            left out of the residual.
    """

    def residual(x: np.ndarray) -> np.ndarray:
        M, D, L, b = math.exp(x[0]), math.exp(x[1]), x[2], x[3]
        parts = []
        for r, q in segments:
            model = step_response(r, M=M, D=D, K=stiffness, latency=L, bias=b, q0=q[0])
            keep = np.abs(r - q) >= 2 * band
            keep[0] = False
            parts.append((model - q)[keep])
        return np.concatenate(parts)

    x0 = np.array([math.log(guess_inertia), math.log(guess_damping), 1e-3, 0.0])
    scale = np.array([1.0, 1.0, 1e-3, 1.0])
    best = None
    for latency0 in (0.5e-3, 2.5e-3, 4.0e-3):  # the latency's cost is not convex over a cycle
        x0[2] = latency0
        x, J, r = _gauss_newton(residual, x0, scale)
        if best is None or float(r @ r) < float(best[2] @ best[2]):
            best = (x, J, r)
    x, J, r = best
    n, p = len(r), len(x)
    sigma2 = float(r @ r) / max(n - p, 1)
    cov = sigma2 * np.linalg.pinv(J.T @ J)
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    rms = math.sqrt(float(r @ r) / max(n, 1))
    M, D = math.exp(x[0]), math.exp(x[1])
    return StepFit(
        Estimate(M, M * se[0], n, rms),  # d(exp x) = exp(x) dx
        Estimate(D, D * se[1], n, rms),
        Estimate(float(x[2]), float(se[2]), n, rms),
        Estimate(float(x[3]), float(se[3]), n, rms),
    )


def fit_timed_steps(
    segments: list[tuple[np.ndarray, np.ndarray]],
    *,
    stiffness: float,
    inertia: float,
    damping: float,
    band: float,
) -> tuple[Estimate, Estimate, np.ndarray]:
    """The latency of each single-cycle step (M, D known), then (the mean latency, the
    jitter's half-width sqrt(3) x their standard deviation, the latencies (m,) [s])."""
    latencies = []
    for r, q in segments:

        def residual(x: np.ndarray, r=r, q=q) -> np.ndarray:
            model = step_response(
                r, M=inertia, D=damping, K=stiffness, latency=x[0], bias=x[1], q0=q[0]
            )
            keep = np.abs(r - q) >= 2 * band
            keep[0] = False
            return (model - q)[keep]

        best = None
        for latency0 in (0.5e-3, 2.5e-3, 4.0e-3):
            x, _, res = _gauss_newton(residual, np.array([latency0, 0.0]), np.array([1e-3, 1.0]))
            if best is None or float(res @ res) < best[1]:
                best = (x, float(res @ res))
        latencies.append(float(best[0][0]))
    values = np.clip(np.array(latencies), 0.0, CYCLE_PERIOD)
    m = len(values)
    mean = float(values.mean())
    std = float(values.std(ddof=1)) if m > 1 else math.nan
    latency = Estimate(mean, std / math.sqrt(m) if m > 1 else math.nan, m, std)
    jitter_value = math.sqrt(3.0) * std if m > 1 else math.nan
    jitter = Estimate(jitter_value, jitter_value / math.sqrt(2 * max(m - 1, 1)), m, std)
    return latency, jitter, values


# Friction ------------------------------------------------------------------------------------


def fit_breakaway(positive: list[float], negative: list[float]) -> tuple[Estimate, Estimate]:
    """(stiction, bias) [N m] from the feed-forward torques at which the joint broke away,
    ramping up (positive) and down (negative): tau+ = b + Fs, tau- = b - Fs."""
    up, down = np.asarray(positive, float), np.asarray(negative, float)
    m = min(len(up), len(down))
    fs = 0.5 * (up.mean() - down.mean())
    b = 0.5 * (up.mean() + down.mean())
    spread = np.concatenate([up - up.mean(), down - down.mean()])
    sd = float(spread.std(ddof=2)) if len(spread) > 2 else math.nan
    se = 0.5 * sd * math.sqrt(1 / max(len(up), 1) + 1 / max(len(down), 1))
    return Estimate(float(fs), se, m, sd), Estimate(float(b), se, m, sd)


def fit_coulomb(
    tau: np.ndarray, v: np.ndarray, compensation: np.ndarray, *, min_speed: float
) -> Estimate:
    """Coulomb friction [N m] from sliding samples: tau (the torque left once inertia,
    damping, spring and bias are taken away) = -(1 - w) Fc sign(v), over |v| >= min_speed
    and w < 1.

    Args:
        tau: (n,) [N m]. v: (n,) [rad/s]. compensation: w (n,) in [0, 1].
    """
    tau, v, w = (np.asarray(a, float) for a in (tau, v, compensation))
    keep = (np.abs(v) >= min_speed) & (w < 0.9)
    if keep.sum() < 3:
        return Estimate(math.nan, math.nan, int(keep.sum()), math.nan)
    regressor = -(1.0 - w[keep]) * np.sign(v[keep])
    x, se, rms = linear_fit(regressor[:, None], tau[keep])
    return Estimate(float(x[0]), float(se[0]), int(keep.sum()), rms)
