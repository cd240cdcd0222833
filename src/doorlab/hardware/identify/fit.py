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
    noise = tuple(Estimate(float(s), float(s) / math.sqrt(2 * (n - 1)), n, float(s)) for s in std)
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
    coupling: np.ndarray | None = None,
) -> np.ndarray:
    """q at each cycle of the single joint M a + D v = K (r - q) + b + u, where r[k] (the
    command applied at cycle k) acts from cycle k + ``latency`` on (0 <= latency < period)
    and u[k] (``coupling``: the torque the other joints' accelerations exert through the
    inertia matrix, -sum_j M_ij a_j) over cycle k.

    Returns:
        (len(r),) q at cycles 0 .. len(r) - 1 (q0 at cycle 0) [rad].
    """
    r = np.asarray(r, float)
    u = np.zeros(len(r)) if coupling is None else np.asarray(coupling, float)
    L = min(max(latency, 0.0), period * (1 - 1e-9))
    P1, G1 = _transition(M, D, K, L)
    P2, G2 = _transition(M, D, K, period - L)
    x = np.array([q0, v0])
    out = np.empty(len(r))
    previous = r[0]
    for k in range(len(r)):
        out[k] = x[0]
        x = P1 @ x + G1 * (K * previous + bias + u[k])
        x = P2 @ x + G2 * (K * r[k] + bias + u[k])
        previous = r[k]
    return out


def coupling_torque(q: np.ndarray, inertia: np.ndarray, joint: int) -> np.ndarray:
    """Over each cycle k, the torque the other joints' accelerations exert on ``joint``
    through the inertia matrix: -sum_{j != joint} M_ij a_j, a_j the mean of the second
    differences at k and k + 1 (m,) [N m].

    Args:
        q: Measured positions at each cycle (m, 7) [rad]. inertia: M (7, 7) [kg m^2].
    """
    q = np.asarray(q, float)
    a = np.zeros_like(q)
    a[1:-1] = (q[2:] - 2 * q[1:-1] + q[:-2]) / CYCLE_PERIOD**2
    over = 0.5 * (a + np.vstack([a[1:], a[-1:]]))
    row = np.asarray(inertia, float)[joint].copy()
    row[joint] = 0.0
    return -over @ row


def coupled_response(
    r: np.ndarray,
    *,
    M: np.ndarray,
    D: np.ndarray,
    K: np.ndarray,
    latency: float,
    bias: np.ndarray,
    q0: np.ndarray,
    period: float = CYCLE_PERIOD,
) -> np.ndarray:
    """:func:`step_response` for n joints coupled through M (n, n): M a + D v = K (r - q) + b
    (D, K diagonal (n,)); r (m, n) the commands applied at each cycle, q0 (n,) at rest.

    Returns:
        (m, n) q at each cycle [rad].
    """
    r = np.asarray(r, float)
    n = len(K)
    M_inv = np.linalg.inv(M)
    L = min(max(latency, 0.0), period * (1 - 1e-9))

    def transition(dt: float):
        A = np.zeros((3 * n, 3 * n))
        A[:n, n : 2 * n] = np.eye(n)
        A[n : 2 * n, :n] = -M_inv @ np.diag(K)
        A[n : 2 * n, n : 2 * n] = -M_inv @ np.diag(D)
        A[n : 2 * n, 2 * n :] = M_inv
        E = _expm(A * dt)
        return E[: 2 * n, : 2 * n], E[: 2 * n, 2 * n :]

    P1, G1 = transition(L)
    P2, G2 = transition(period - L)
    x = np.concatenate([np.asarray(q0, float), np.zeros(n)])
    out = np.empty((len(r), n))
    previous = r[0]
    for k in range(len(r)):
        out[k] = x[:n]
        x = P1 @ x + G1 @ (K * previous + bias)
        x = P2 @ x + G2 @ (K * r[k] + bias)
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
    """
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
        n = len(res)
        sigma2 = float(res @ res) / max(n - 3, 1)
        se = np.sqrt(np.maximum(np.diag(sigma2 * np.linalg.pinv(J.T @ J)), 0.0))
        se *= correlation_inflation(math.exp(x[0]), math.exp(x[1]))
        fits.append((x, se, n, math.sqrt(float(res @ res) / max(n, 1))))
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
        n = len(res)
        sigma2 = float(res @ res) / max(n - 4, 1)
        se = np.sqrt(np.maximum(np.diag(sigma2 * np.linalg.pinv(J.T @ J)), 0.0))
        se *= correlation_inflation(math.exp(x[0]), math.exp(x[1]))
        fits.append((x, se, n, math.sqrt(float(res @ res) / max(n, 1))))
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


COUPLING_THRESHOLD = 0.2
"""Two joints whose inertia coupling M_ij / sqrt(M_ii M_jj) exceeds this are fitted together
(:func:`fit_coupled_step`)."""
ONSET_CYCLES = 6
"""A timed step's latency is fitted on this many cycles after each change of the command
(where the latency shows and the single-joint model is closest to the arm)."""


def fit_timed_steps(
    segments: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
    *,
    stiffness: float,
    inertia: float,
    damping: float,
    band: float,
) -> tuple[Estimate, Estimate, np.ndarray]:
    """The latency of each single-cycle change of the command (M, D known), fitted on the
    :data:`ONSET_CYCLES` after it; then (the mean latency, the jitter's half-width sqrt(3) x
    their standard deviation, the latencies (m,) [s])."""
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
            for latency0 in (0.5e-3, 2.5e-3, 4.5e-3):
                x, _, res = _gauss_newton(residual, np.array([latency0]), np.array([1e-3]))
                if best is None or float(res @ res) < best[1]:
                    best = (x, float(res @ res))
            latencies.append(float(best[0][0]))
    values = np.clip(np.array(latencies), 0.0, CYCLE_PERIOD)
    m = len(values)
    mean = float(values.mean()) if m else math.nan
    std = float(values.std(ddof=1)) if m > 1 else math.nan
    latency = Estimate(mean, std / math.sqrt(m) if m > 1 else math.nan, m, std)
    jitter_value = math.sqrt(3.0) * std if m > 1 else math.nan
    jitter = Estimate(jitter_value, jitter_value / math.sqrt(2 * max(m - 1, 1)), m, std)
    return latency, jitter, values


# Friction ------------------------------------------------------------------------------------


def fit_breakaway(
    positive: list[float], negative: list[float], *, noise: float = 0.0
) -> tuple[Estimate, Estimate]:
    """(stiction, bias) [N m] from the torques at which the joint broke away, ramping up
    (positive) and down (negative): tau+ = b + Fs, tau- = b - Fs. The standard error is the
    larger of the repeats' scatter and each estimate's own ``noise`` [N m] (its scatter from
    one cycle to the next), over sqrt(2 m)."""
    up, down = np.asarray(positive, float), np.asarray(negative, float)
    m = min(len(up), len(down))
    fs = 0.5 * (up.mean() - down.mean())
    b = 0.5 * (up.mean() + down.mean())
    spread = np.concatenate([up - up.mean(), down - down.mean()])
    sd = float(spread.std(ddof=2)) if len(spread) > 2 else 0.0
    sd = max(sd, noise)
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
    # w is known to a cycle's travel only (the arm compares q_ref with q within the cycle):
    # (1 - w) uncertain by up to w, so Fc by up to Fc w / (1 - w)
    share = float(np.mean(w[keep]))
    model = abs(float(x[0])) * share / max(1.0 - share, 0.1) / TOLERANCE_SIGMAS
    return Estimate(float(x[0]), max(float(se[0]), model), int(keep.sum()), rms)
