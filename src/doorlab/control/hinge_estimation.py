"""Estimating an unknown hinge from the grasp point's motion, and the contact wrench at Q.

Pure numerics, no simulator. Used by the ``adaptive`` plan (:mod:`doorlab.control.adaptive`), which
knows nothing of the cupboard model after the grasp.

**Hinge.** While the gripper holds the handle, Q moves on a horizontal circle about the
hinge axis. :class:`HingeEstimator` fits that circle to Q's measured path by linear least
squares (the algebraic "Hyper" fit, kept as running moments: O(1) per control tick) once the
path is curved enough to trust it, and takes the door's tangent from Q's measured velocity
(low-pass filtered unit direction; the idea of Karayiannidis et al., T-RO 2016: a radially
compliant gripper is turned onto the true tangent by the door, so its measured velocity
reveals the tangent before any hinge is known).

**Error bound of the fit** (:func:`center_error_std`). For N points spread evenly over an
arc of angle Phi and radius R, each with independent isotropic noise of standard deviation
sigma, the linearized least-squares fit of (center, R) has the Fisher information
(1/sigma^2) sum g g^T with g = (sin a, cos a, 1) (a the point's angle from the arc's middle).
The tangential center coordinate pairs with sin a ~ a (variance Phi^2/12 over the arc); the
radial one pairs with cos a ~ 1 - a^2/2, which is nearly the radius's column, so only the
a^2/2 part separates them (variance Phi^4/720). Hence, to first order in Phi and sigma::

    std(center, tangential) = sigma * sqrt(12 / N) / Phi
    std(center, radial)     = sigma * sqrt(720 / N) / Phi^2

The radial one dominates: a short arc fixes the direction to the hinge long before the
distance. The algebraic fit has the geometric fit's first-order variance on a circle (its
residual is 2 R times the geometric distance, a constant weight), so the bound applies; the
Hyper fit also removes the algebraic fit's second-order bias (see ``_CircleSums``).

**Contact wrench at Q** (:func:`estimate_contact_wrench`). The arm's measured external
torques are tau_ext = Jv_V_WL7q^T F_Q for a spatial force F_Q (torque; force) applied to the
gripper at Q, expressed in W. With 7 joints and rank-6 J, J^T is injective: every wrench
component is observable and the least-squares solution is unique. What it cannot see:
(1) forces that cancel inside the gripper (the fingers' squeeze on the handle); (2) torque
that no wrench at Q explains (contacts elsewhere on the arm, model error), which lands in
the one-dimensional residual orthogonal to range(J^T); (3) near a singular configuration the
direction of J's smallest singular value s_min is amplified by 1/s_min.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from doorlab.errors import ConfigError


class CircleFit(NamedTuple):
    """A circle fitted to points in a plane.

    Attributes:
        center: Center (2,) [m]. radius: Radius [m].
    """

    center: np.ndarray
    radius: float


class _CircleSums:
    """Running moments of the algebraic circle fit about a fixed origin (the first point).

    A circle is A |u|^2 + B u_x + C u_y + D = 0 (u = p - origin). With the moment matrix
    M = mean(w w^T), w = (|u|^2, u_x, u_y, 1), the "Hyper" fit (Al-Sharadqah and Chernov,
    2009) solves M a = eta N a for the smallest non-negative eta, with N the constraint
    matrix below. Unlike the simpler Kasa fit (least squares of |u|^2 + B u_x + C u_y + D,
    biased towards small circles on short arcs: +6 mm on a 20 deg arc at 0.2 mm noise), it
    has no bias to second order and the geometric fit's first-order variance.
    """

    def __init__(self) -> None:
        self.origin: np.ndarray | None = None
        self.moments = np.zeros((4, 4))
        self.count = 0

    def add(self, p: np.ndarray) -> None:
        if self.origin is None:
            self.origin = np.array(p[:2], dtype=float)
        ux, uy = p[0] - self.origin[0], p[1] - self.origin[1]
        w = np.array([ux * ux + uy * uy, ux, uy, 1.0])
        self.moments += np.outer(w, w)
        self.count += 1

    def solve(self) -> CircleFit | None:
        if self.count < 3:
            return None
        M = self.moments / self.count
        z, x, y = M[0, 3], M[1, 3], M[2, 3]
        N = np.array(
            [
                [8.0 * z, 4.0 * x, 4.0 * y, 2.0],
                [4.0 * x, 1.0, 0.0, 0.0],
                [4.0 * y, 0.0, 1.0, 0.0],
                [2.0, 0.0, 0.0, 0.0],
            ]
        )
        eta, vectors = np.linalg.eig(np.linalg.solve(N, M))
        eta = eta.real
        candidates = np.flatnonzero(eta >= -1e-12 * np.abs(eta).max())
        if not len(candidates):
            return None
        A, B, C, D = vectors[:, candidates[np.argmin(eta[candidates])]].real
        if abs(A) < 1e-12 * max(abs(B), abs(C), 1e-300):  # a line, not a circle
            return None
        r2 = (B * B + C * C - 4.0 * A * D) / (4.0 * A * A)
        if not (np.isfinite(r2) and r2 > 0.0):
            return None
        return CircleFit(self.origin + np.array([-B, -C]) / (2.0 * A), math.sqrt(r2))


def fit_circle(points: np.ndarray) -> CircleFit:
    """Least-squares (algebraic) circle through points (n, 2) or (n, 3) (z ignored) [m].

    Raises:
        ConfigError: Fewer than 3 points, or collinear points (no finite circle).
    """
    points = np.asarray(points, dtype=float)
    sums = _CircleSums()
    for p in points:
        sums.add(p)
    fit = sums.solve()
    if fit is None:
        raise ConfigError(f"no circle through {len(points)} points: need 3 or more, not collinear")
    return fit


def center_error_std(sigma: float, num_points: int, arc_angle: float) -> tuple[float, float]:
    """First-order standard deviation of a fitted circle's center (module docstring).

    Args:
        sigma: Noise per point and axis [m]. num_points: N, spread evenly over the arc.
        arc_angle: Angle Phi the points span about the center [rad].

    Returns:
        (tangential, radial) standard deviations [m], relative to the arc's middle.
    """
    return (
        sigma * math.sqrt(12.0 / num_points) / arc_angle,
        sigma * math.sqrt(720.0 / num_points) / arc_angle**2,
    )


def signed_angle(a: np.ndarray, b: np.ndarray) -> float:
    """Counter-clockwise angle from 2-D vector a to b, in (-pi, pi] [rad]."""
    return math.atan2(a[0] * b[1] - a[1] * b[0], a[0] * b[0] + a[1] * b[1])


class HingeEstimate(NamedTuple):
    """The estimator's belief after an update (horizontal plane of W).

    Attributes:
        tangent: Unit direction (2,) Q should move along to open the door.
        radial: Unit direction (2,) from the hinge to Q (perpendicular to tangent; before the
            fit is ready its sign is a guess, which a radial force law does not care about).
        fit_ready: Whether the circle fit is trusted (then center, radius, door_angle are).
        center: Hinge axis position (2,) [m] (nan before the fit is ready).
        radius: Distance hinge to Q [m] (nan before the fit is ready).
        door_angle: Counter-clockwise rotation of Q about the center since the first
            update [rad] (0 before the fit is ready).
    """

    tangent: np.ndarray
    radial: np.ndarray
    fit_ready: bool
    center: np.ndarray
    radius: float
    door_angle: float


_NAN2 = np.array([np.nan, np.nan])


class HingeEstimator:
    """Running estimate of the hinge from Q's horizontal positions and velocities.

    The tangent follows Q's measured velocity direction (low-pass filtered) while Q moves
    faster than ``min_speed``, else the fitted circle's tangent, else the last one. The
    circle fit is trusted once Q's path bulges at least ``min_sagitta`` from its chord
    (measured at the path's middle sample, no fit involved): a spurious circle through a
    nearly straight path cannot pass that test.

    Args:
        initial_tangent: Direction (2,) to pull before anything is measured (the grasp's
            approach direction reversed); need not be unit length.
        min_sagitta: Path bulge that makes the fit trusted [m]; several times Q's radial
            wobble about the true circle.
        velocity_time_constant: Low-pass time constant of the velocity direction [s].
        min_speed: Velocities slower than this do not update the direction [m/s].
    """

    def __init__(
        self,
        initial_tangent: np.ndarray,
        *,
        min_sagitta: float,
        velocity_time_constant: float,
        min_speed: float,
    ):
        t0 = np.asarray(initial_tangent, dtype=float)[:2]
        norm = float(np.hypot(*t0))
        if not norm > 0.0:
            raise ConfigError(f"initial_tangent must be a non-zero vector, got {t0!r}")
        for name, value in (
            ("min_sagitta", min_sagitta),
            ("velocity_time_constant", velocity_time_constant),
        ):
            if not value > 0.0:
                raise ConfigError(f"{name} must be > 0, got {value!r}")
        self.min_sagitta = float(min_sagitta)
        self.velocity_time_constant = float(velocity_time_constant)
        self.min_speed = float(min_speed)
        self._sums = _CircleSums()
        self._points: list[np.ndarray] = []
        self._tangent = t0 / norm
        self.estimate = HingeEstimate(
            self._tangent, np.array([-t0[1], t0[0]]) / norm, False, _NAN2, math.nan, 0.0
        )

    def sagitta(self) -> float:
        """Distance of the path's middle sample from the chord first-to-last point [m]."""
        if len(self._points) < 3:
            return 0.0
        p0, p1 = self._points[0], self._points[-1]
        chord = p1 - p0
        length = math.hypot(chord[0], chord[1])
        if length == 0.0:
            return 0.0
        m = self._points[len(self._points) // 2] - p0
        return abs(chord[0] * m[1] - chord[1] * m[0]) / length

    def update(self, p: np.ndarray, v: np.ndarray, dt: float) -> HingeEstimate:
        """Adds one measurement of Q.

        Args:
            p: Q's position (2,) or (3,) in W [m] (z ignored).
            v: Q's velocity (2,) or (3,) in W [m/s] (z ignored).
            dt: Time since the previous update [s].

        Returns:
            The new estimate (also kept as ``self.estimate``).
        """
        p = np.array(p[:2], dtype=float)
        self._points.append(p)
        self._sums.add(p)
        fit = self._sums.solve() if self.sagitta() >= self.min_sagitta else None

        speed = math.hypot(v[0], v[1])
        tangent = self._tangent
        if speed > self.min_speed:
            alpha = min(dt / self.velocity_time_constant, 1.0)
            d = tangent + alpha * (np.array(v[:2], dtype=float) / speed - tangent)
            tangent = d / math.hypot(d[0], d[1])
        elif fit is not None:
            r = p - fit.center
            tangent = np.array([-r[1], r[0]]) / math.hypot(r[0], r[1])
            if tangent @ self._tangent < 0.0:  # keep the sense of travel
                tangent = -tangent
        self._tangent = tangent

        if fit is None:
            self.estimate = HingeEstimate(
                tangent, np.array([-tangent[1], tangent[0]]), False, _NAN2, math.nan, 0.0
            )
        else:
            r = p - fit.center
            radial = r / math.hypot(r[0], r[1])
            angle = signed_angle(self._points[0] - fit.center, r)
            self.estimate = HingeEstimate(tangent, radial, True, fit.center, fit.radius, angle)
        return self.estimate


class WrenchEstimate(NamedTuple):
    """Least-squares contact wrench at Q from the arm's external torques.

    Attributes:
        F_Q_W: Spatial force on the gripper at Q, expressed in W, (torque; force) (6,)
            [N m, N].
        residual: Norm of the torque no wrench at Q explains [N m].
        min_singular_value: Smallest singular value of J: the estimate's noise gain along
            its direction is 1 / this [N/(N m) or 1/m].
    """

    F_Q_W: np.ndarray
    residual: float
    min_singular_value: float


def estimate_contact_wrench(Jv_V_WL7q: np.ndarray, tau_external: np.ndarray) -> WrenchEstimate:
    """F_Q = argmin |J^T F - tau_ext| (module docstring: what it cannot see).

    Args:
        Jv_V_WL7q: Geometric Jacobian of L7 at Q in W (6, 7).
        tau_external: Measured external (contact) joint torques (7,) [N m].
    """
    J = np.asarray(Jv_V_WL7q, dtype=float)
    tau = np.asarray(tau_external, dtype=float)
    F, _, _, s = np.linalg.lstsq(J.T, tau, rcond=None)
    return WrenchEstimate(F, float(np.linalg.norm(J.T @ F - tau)), float(s[-1]))
