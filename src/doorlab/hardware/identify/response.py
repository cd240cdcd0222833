"""The single joint's response to its commands, as :mod:`.fit`'s step fits model it (pure,
numpy): M a + D v = K (r - q) + b + u, each cycle's command from the cycle plus the latency on
(a piecewise-constant input: exact discretization, :func:`step_response`), and joints coupled
through the inertia matrix (:func:`coupled_response`)."""

from __future__ import annotations

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
    """Exact discretization over dt of x' = [[0, 1], [-K/M, -D/M]] x + [0, 1/M] (K r + b):
    (Phi (2, 2), Gamma (2,)) with x+ = Phi x + Gamma (K r + b)."""
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


def _commands(r: np.ndarray, k: int, own: int):
    """The two commands acting over cycle k (:func:`_split`'s ``own``)."""
    if own == 0:
        return r[k - 1] if k > 0 else r[0], r[k]
    return r[k], r[min(k + 1, len(r) - 1)]


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
    x = np.array([q0, v0])
    out = np.empty(len(r))
    for k in range(len(r)):
        out[k] = x[0]
        before, after = _commands(r, k, own)
        x = P1 @ x + G1 * (K * before + bias + u[k])
        x = P2 @ x + G2 * (K * after + bias + u[k])
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
    x = np.concatenate([np.asarray(q0, float), np.zeros(n)])
    out = np.empty((len(r), n))
    for k in range(len(r)):
        out[k] = x[:n]
        before, after = _commands(r, k, own)
        x = P1 @ x + G1 @ (K * before + bias)
        x = P2 @ x + G2 @ (K * after + bias)
    return out
