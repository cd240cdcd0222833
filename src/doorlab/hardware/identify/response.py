"""The single joint's response to its commands, as :mod:`.fit`'s step fits model it (pure,
numpy): M a + D v = K (r - q) + b + u, each cycle's command from the cycle plus the latency on
(a piecewise-constant input: exact discretization, :func:`step_response`), and joints coupled
through the inertia matrix (:func:`coupled_response`)."""

from __future__ import annotations

import cmath
import math

import numpy as np

from doorlab.kuka import CYCLE_PERIOD


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
    """Exact discretization over dt of x' = A x + [0, 1/M] (K r + b), A = [[0, 1], [-K/M,
    -D/M]]: (Phi (2, 2), Gamma (2,)) with x+ = Phi x + Gamma (K r + b).

    In closed form (the fits call it some 50 000 times): with s = tr(A) / 2 and q^2 = s^2 -
    det(A), exp(A t) = e^(s t) ((cosh(q t) - s sinh(q t) / q) I + sinh(q t) / q A) (q
    imaginary when underdamped: cos and sin), and Gamma = A^-1 (Phi - I) [0, 1/M].
    """
    a, b = -K / M, -D / M  # A = [[0, 1], [a, b]]
    s = 0.5 * b
    q = cmath.sqrt(s * s + a)  # s^2 - det(A), det(A) = -a
    qt = q * dt
    if abs(qt) < 1e-4:  # cosh, sinh / q by their series (q -> 0: critically damped)
        c = 1.0 + qt * qt / 2.0
        sh = dt * (1.0 + qt * qt / 6.0)
    else:
        c, sh = cmath.cosh(qt), cmath.sinh(qt) / q
    e = math.exp(s * dt)
    c, sh = (e * (c - s * sh)).real, (e * sh).real
    phi = np.array([[c, sh], [sh * a, c + sh * b]])
    # A^-1 = [[b, -1], [-a, 0]] / (-a); (Phi - I) [0, 1/M] = [phi01, phi11 - 1] / M
    g0, g1 = phi[0, 1] / M, (phi[1, 1] - 1.0) / M
    gamma = np.array([(b * g0 - g1) / -a, g0])
    return phi, gamma


def _transition_expm(M: float, D: float, K: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_transition` by the matrix exponential of the augmented system (its check)."""
    A = np.zeros((3, 3))
    A[0, 1] = 1.0
    A[1, 0], A[1, 1], A[1, 2] = -K / M, -D / M, 1.0 / M
    E = _expm(A * dt)
    return E[:2, :2], E[:2, 2]


def _split(latency: float, period: float) -> tuple[float, float, int]:
    """A cycle's two parts for a latency L in (-period, period): (the first part's length, the
    second's, which command acts over the first: 0 the previous cycle's, 1 the cycle's own).

    L >= 0: the cycle's command acts from L on (the previous one before). L < 0: it acted
    |L| before the cycle began, and the next cycle's command acts from period + L on: the
    simulator's semi-implicit step realizes its arm's latency L as L - h/2, so an arm
    simulated with no latency beyond the cycle answers as one whose commands act h/2 early.
    """
    L = min(max(latency, -period * (1 - 1e-9)), period * (1 - 1e-9))
    return (L, period - L, 0) if L >= 0 else (period + L, -L, 1)


def _acting(r: np.ndarray, own: int) -> tuple[np.ndarray, np.ndarray]:
    """The commands acting over each cycle's first and second part (:func:`_split`'s
    ``own``): (before, after), each shaped like r."""
    if own == 0:
        return np.concatenate([r[:1], r[:-1]]), r
    return r, np.concatenate([r[1:], r[-1:]])


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
    command applied at cycle k) acts from cycle k + ``latency`` on (-period < latency <
    period: :func:`_split`) and u[k] (``coupling``: the torque the other joints'
    accelerations exert through the inertia matrix, -sum_j M_ij a_j) over cycle k.

    Returns:
        (len(r),) q at cycles 0 .. len(r) - 1 (q0 at cycle 0) [rad].
    """
    r = np.asarray(r, float)
    u = np.zeros(len(r)) if coupling is None else np.asarray(coupling, float)
    first, second, own = _split(latency, period)
    P1, G1 = _transition(M, D, K, first)
    P2, G2 = _transition(M, D, K, second)
    before, after = _acting(r, own)
    # over a cycle x+ = P2 (P1 x + G1 f1) + G2 f2 = A x + w, w from the inputs at once; the
    # recursion on plain floats (numpy's per-call cost would be most of it)
    A = P2 @ P1
    w = np.outer(K * before + bias + u, P2 @ G1) + np.outer(K * after + bias + u, G2)
    (a, b), (c, d) = A.tolist()
    x, v = float(q0), float(v0)
    out = []
    for w0, w1 in w.tolist():
        out.append(x)
        x, v = a * x + b * v + w0, c * x + d * v + w1
    return np.array(out)


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
    first, second, own = _split(latency, period)

    def transition(dt: float):
        A = np.zeros((3 * n, 3 * n))
        A[:n, n : 2 * n] = np.eye(n)
        A[n : 2 * n, :n] = -M_inv @ np.diag(K)
        A[n : 2 * n, n : 2 * n] = -M_inv @ np.diag(D)
        A[n : 2 * n, 2 * n :] = M_inv
        E = _expm(A * dt)
        return E[: 2 * n, : 2 * n], E[: 2 * n, 2 * n :]

    P1, G1 = transition(first)
    P2, G2 = transition(second)
    before, after = _acting(r, own)
    A = P2 @ P1
    w = (K * before + bias) @ (P2 @ G1).T + (K * after + bias) @ G2.T  # (m, 2 n)
    x = np.concatenate([np.asarray(q0, float), np.zeros(n)])
    out = np.empty((len(r), n))
    for k in range(len(r)):
        out[k] = x[:n]
        x = A @ x + w[k]
    return out
