"""The grader's answer key: the unit tests' draws and expected answers, the reference episodes.

Everything here computes an answer with doorlab's reference solutions (the problem set's
equations, :mod:`doorlab.control.ik_pointwise`, :mod:`doorlab.control.laws`, the arc of
:mod:`doorlab.cell.geometry`, doorlab's controllers); :mod:`doorlab.pset.grading.checks` only
compares the student's answers with what this module expected. So the students' build of
doorlab (:func:`doorlab.pset.classroom.wheel.student_wheel_bytes`) leaves this module out and still
grades: its self-check judges the student's answers against a *practice* table that this
module computed where the handout was written (:func:`practice_table`: the practice draws'
expected answers, the reference episodes' figures, the reference helpers' table), while the
course's grading draws its own from each submission's grading seed.

Every ``expect_*`` function returns a JSON-ready dict: ``seed`` (the grading seed the draws
came from), what the student's process is asked, and what is accepted.
"""

from __future__ import annotations

import functools
import json

import numpy as np
from pydrake.math import RollPitchYaw, RotationMatrix

from doorlab.cell.frames import p_L7Q
from doorlab.cell.geometry import default_door_geometry
from doorlab.cell.station import make_controller_plant
from doorlab.config import Scenario
from doorlab.constants import JOINT_POSITION_LIMITS, Q_HOME
from doorlab.control.ik_pointwise import pointwise_ik
from doorlab.control.laws import orientation_error
from doorlab.pset.grading.checks import (
    SEED_CONTROL_PERIOD,
    TORQUE_CLIP,
    UNIT_DRAWS,
    VELOCITY_CLIP,
)
from doorlab.pset.grading.episodes import HELPER_KNOTS, episode_figures
from doorlab.pset.handout.station_api import ArmKinematics

PRACTICE_JOB = "practice"
"""What the handout's practice draws are derived from (with the assignment's random seed)."""


def _rng(seed: int | None, job: str) -> tuple[np.random.Generator, int]:
    """The random draws of ``job`` from the grading seed (None: a fresh one), and that seed."""
    from doorlab.pset.rules.assignment import SEED_BITS, job_seed

    grading = seed if seed is not None else int(np.random.SeedSequence().entropy % 2**SEED_BITS)
    return np.random.default_rng(job_seed(grading, job)), grading


def _draw_taus(rng: np.random.Generator) -> np.ndarray:
    """0, 1 and five values of tau off any grid (an IK's knots, tenths)."""
    return np.concatenate([[0.0, 1.0], rng.uniform(0.02, 0.98, 5)])


def _random_q(rng: np.random.Generator) -> np.ndarray:
    """An arm configuration near the task's (away from the straight-arm singularity)."""
    q = Q_HOME + rng.uniform(-0.4, 0.4, 7)
    q[3] = rng.uniform(-2.0, -1.0)  # elbow well bent
    return np.clip(q, -0.9 * JOINT_POSITION_LIMITS, 0.9 * JOINT_POSITION_LIMITS)


def _control_period(rng: np.random.Generator) -> float:
    """A control period in [1, 20] ms, at least 1 ms away from the runner's 5 ms."""
    while True:
        dt = float(rng.uniform(0.001, 0.02))
        if abs(dt - SEED_CONTROL_PERIOD) > 0.001:
            return dt


def _law_case(rng: np.random.Generator, kin: ArmKinematics) -> dict:
    """A random state, a reference a few mm and degrees away, and the plan's inputs, each
    argument distinct from the others (q_cmd != q, v != 0, tau_ext != 0, t_plan off 0)."""
    q = _random_q(rng)
    X_WL7 = kin.X_WL7(q)
    p_WQ = X_WL7 @ p_L7Q
    duration = float(rng.uniform(3.0, 15.0))
    t_plan = float(rng.uniform(0.05, 0.95) * duration)
    tau = t_plan / duration
    p_WQ_0 = p_WQ + rng.uniform(-0.02, 0.02, 3)
    delta = rng.uniform(-0.002, 0.002, 3)  # e_xyz = p_WQ_0 + p_Q(tau) - p_WQ, a few mm
    p_Q_end = (p_WQ + delta - p_WQ_0) / tau
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    R_ref_end = X_WL7.rotation() @ RotationMatrix(RollPitchYaw(*(axis * rng.uniform(0.002, 0.01))))
    e_xyz = p_WQ_0 + p_Q_end * tau - p_WQ
    theta_n_W = orientation_error(X_WL7.rotation(), R_ref_end)
    theta_n_L7 = X_WL7.rotation().inverse() @ theta_n_W
    case = {
        "q": q,
        "duration": duration,
        "t_plan": t_plan,
        "p_WQ_0": p_WQ_0,
        "p_Q_end": p_Q_end,
        "R_ref_end": R_ref_end.matrix(),
        "F": np.concatenate([50.0 * theta_n_W, 100.0 * e_xyz]),
        "F_L7": np.concatenate([50.0 * theta_n_L7, 100.0 * e_xyz]),
        "F_swapped": np.concatenate([100.0 * theta_n_W, 50.0 * e_xyz]),  # the gains swapped
        "J": kin.Jv_V_WL7q(q, p_L7Q),
    }
    for name in ("q_cmd", "v", "tau_ext", "dt"):
        case[name] = _redraw(rng, case, name)
    return case


def _redraw(rng: np.random.Generator, c: dict, name: str):
    """Another value of argument ``name`` for the draw ``c``."""
    if name == "q_cmd":
        return c["q"] + rng.choice([-1.0, 1.0], 7) * rng.uniform(0.02, 0.08, 7)
    if name == "v":
        return rng.uniform(-0.3, 0.3, 7)
    if name == "tau_ext":
        return rng.uniform(-2.0, 2.0, 7)
    return _control_period(rng)


def _request(c: dict, **changes) -> dict:
    args = {k: changes.get(k, c[k]) for k in ("q", "q_cmd", "v", "tau_ext", "t_plan", "dt")}
    return {
        "p_Q_end": c["p_Q_end"].tolist(),
        "R_ref_end": c["R_ref_end"].tolist(),
        "duration": c["duration"],
        "p_L7Q": p_L7Q.tolist(),
        "p_WQ_0": c["p_WQ_0"].tolist(),
        "args": [
            np.asarray(args["q"]).tolist(),
            np.asarray(args["q_cmd"]).tolist(),
            np.asarray(args["v"]).tolist(),
            np.asarray(args["tau_ext"]).tolist(),
            float(args["t_plan"]),
            float(args["dt"]),
        ],
    }


SWAPPED = (
    "100 on L7's orientation error (theta n) and 50 on Q's position error; the problem set's "
    "gains are 50 on theta n and 100 on the position error"
)
"""The swapped gains' diagnosis."""


def _expected(kind: str, c: dict) -> tuple[list[np.ndarray], list[tuple[str, np.ndarray]]]:
    """The accepted answers, and the answers of common mistakes (what each misuses)."""
    J_pinv = np.linalg.pinv(c["J"])
    if kind == "velocity":
        qdot = J_pinv @ c["F"]  # F holds V_des here: same gains, 1/s
        accepted = [c["q"] + qdot * c["dt"]]
        accepted.append(c["q"] + np.clip(qdot, -VELOCITY_CLIP, VELOCITY_CLIP) * c["dt"])
        mistakes = [
            (
                "q_cmd + J^+ V_des dt: q_ref must start from the measured q_iiwa, not from "
                "q_cmd (the last position command)",
                c["q_cmd"] + qdot * c["dt"],
            ),
            (
                f"a control period of {SEED_CONTROL_PERIOD} s: use the control_period argument "
                f"({c['dt']:.4f} s here)",
                c["q"] + qdot * SEED_CONTROL_PERIOD,
            ),
            ("q - J^+ V_des dt: the sign of V_des is flipped", c["q"] - qdot * c["dt"]),
            (
                "theta n expressed in L7: V_des's angular part must be expressed in W "
                "(self.R_WL7 @ axis)",
                c["q"] + J_pinv @ c["F_L7"] * c["dt"],
            ),
            (
                f"q + J^+ V_des dt with the gains swapped: {SWAPPED}",
                c["q"] + J_pinv @ c["F_swapped"] * c["dt"],
            ),
        ]
        return accepted, mistakes
    tau_ff = c["J"].T @ c["F"]
    accepted = [tau_ff, np.clip(tau_ff, -TORQUE_CLIP, TORQUE_CLIP)]
    mistakes = [
        ("-J^T F: the sign of F is flipped", -tau_ff),
        (
            "theta n expressed in L7: F's moment must be expressed in W (self.R_WL7 @ axis)",
            c["J"].T @ c["F_L7"],
        ),
        ("J^+ F: the impedance plan maps F through J's transpose", J_pinv @ c["F"]),
        (f"J^T F with the gains swapped: {SWAPPED}", c["J"].T @ c["F_swapped"]),
    ]
    return accepted, mistakes


def _ik_case(rng: np.random.Generator) -> dict:
    """A path (a shifted piece of the arc), a knot count, a duration, tolerances below the
    function's defaults, a grasp point and an initial guess off doorlab's."""
    a = float(rng.uniform(0.0, 0.7))
    return {
        "num_knot_points": int(rng.integers(3, 8)),
        "duration": float(rng.uniform(3.0, 8.0)),
        "a": a,
        "b": float(rng.uniform(a + 0.3, 1.0)),
        "offset": [rng.uniform(-0.04, 0.0), rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03)],
        "position_tolerance": float(rng.uniform(0.0005, 0.002)),
        "theta_bound": float(rng.uniform(0.004, 0.01)),
        # 5-10 mm off doorlab's grasp point on every axis: an IK that aims that point
        # instead misses the drawn one by >= 5 mm on some world axis, more than any
        # tolerance drawn (<= 2 mm) plus its own error in the box (<= 2 mm).
        "p_L7Q": (p_L7Q + rng.choice([-1.0, 1.0], 3) * rng.uniform(0.005, 0.01, 3)).tolist(),
        "q_initial_guess": (Q_HOME + rng.uniform(-0.05, 0.05, 7)).tolist(),
    }


def _json(value):
    """numpy arrays (and nested) as lists."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, dict):
        return {k: _json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json(v) for v in value]
    if isinstance(value, np.floating):
        return float(value)
    return value


# The unit tests --------------------------------------------------------------------------------


def expect_calc_p_Q(seed: int | None = None) -> dict:
    """calc_p_Q's draws (``taus``), the expected points (the arc minus the handle) and the
    arc's points (what an answer that forgot the handle gives) [m]."""
    g = default_door_geometry()
    rng, seed = _rng(seed, "unit:calc_p_Q")
    taus = _draw_taus(rng)
    return {
        "seed": seed,
        "taus": taus.tolist(),
        "expected": [(g.p_WQ_ref(tau) - g.p_W_handle).tolist() for tau in taus],
        "arc": [g.p_WQ_ref(tau).tolist() for tau in taus],
    }


def expect_calc_R_WL7_ref(seed: int | None = None) -> dict:
    """calc_R_WL7_ref's draws (``taus``) and the expected rotation matrices."""
    g = default_door_geometry()
    rng, seed = _rng(seed, "unit:calc_R_WL7_ref")
    taus = _draw_taus(rng)
    return {
        "seed": seed,
        "taus": taus.tolist(),
        "expected": [g.R_WL7_ref(tau).matrix().tolist() for tau in taus],
    }


def expect_law(kind: str, seed: int | None = None) -> dict:
    """A plan's law (``velocity`` or ``impedance``): the requests (each draw, then the same
    with one argument the law must not read drawn anew), which request is each draw's
    (``base``) and each probe (``probes``: draw, argument, request), and per draw its
    ``t_plan``, ``dt``, the accepted answers and the common mistakes' answers."""
    from doorlab.pset.grading.checks import ignored_arguments

    ignored = ignored_arguments(kind)
    kin = ArmKinematics()
    rng, seed = _rng(seed, f"unit:{kind}")
    cases = [_law_case(rng, kin) for _ in range(UNIT_DRAWS)]
    requests, base, probes = [], [], []
    for i, c in enumerate(cases):
        base.append(len(requests))
        requests.append(_request(c))
        for name in ignored:
            probes.append((i, name, len(requests)))
            requests.append(_request(c, **{name: _redraw(rng, c, name)}))
    draws = []
    for c in cases:
        accepted, mistakes = _expected(kind, c)
        draws.append(
            {
                "t_plan": c["t_plan"],
                "dt": c["dt"],
                "accepted": _json(accepted),
                "mistakes": [[text, _json(x)] for text, x in mistakes],
            }
        )
    return {"seed": seed, "requests": requests, "base": base, "probes": probes, "draws": draws}


def expect_velocity(seed: int | None = None) -> dict:
    return expect_law("velocity", seed=seed)


def expect_impedance(seed: int | None = None) -> dict:
    return expect_law("impedance", seed=seed)


def expect_ik(seed: int | None = None) -> dict:
    """InverseKinPointwise's drawn ``case`` and the reference IK's largest joint change
    between consecutive knots on it (``reference_steps`` [rad])."""
    g = default_door_geometry()
    rng, seed = _rng(seed, "unit:ik")
    case = _ik_case(rng)
    a, b, offset = case["a"], case["b"], np.array(case["offset"])
    reference = pointwise_ik(
        make_controller_plant(),
        lambda tau: g.p_WQ_ref(a + (b - a) * tau) + offset,
        lambda tau: g.R_WL7_ref(a + (b - a) * tau),
        duration=case["duration"],
        num_knots=case["num_knot_points"],
        q_guess=np.array(case["q_initial_guess"]),
        position_tolerance=case["position_tolerance"],
        theta_bound=case["theta_bound"],
    )
    steps = np.abs(np.diff(reference.q_knots, axis=0)).max(axis=1)
    return {"seed": seed, "case": _json(case), "reference_steps": steps.tolist()}


EXPECTATIONS = {
    "ik": expect_ik,
    "calc_p_Q": expect_calc_p_Q,
    "calc_R_WL7_ref": expect_calc_R_WL7_ref,
    "velocity": expect_velocity,
    "impedance": expect_impedance,
}
"""What each unit test (``unit:<name>``) expects, from a grading seed."""


# The episodes ------------------------------------------------------------------------------


def reference_helper_table(knots: int = HELPER_KNOTS) -> dict:
    """A fresh copy of :func:`_reference_helper_table` (computed once per process)."""
    return json.loads(_reference_helper_table(knots))


@functools.cache
def _reference_helper_table(knots: int) -> str:
    """doorlab's calc_p_Q and calc_R_WL7_ref at ``knots`` values of tau in [0, 1], for an
    episode that runs the reference helpers (:data:`doorlab.pset.rules.verdicts.TESTS`' helpers):
    the student's process interpolates them (positions linearly: the arc's chord error at
    1,001 knots is r (sweep / 1000)^2 / 8 < 0.1 um; orientations by slerp, exact for a yaw
    that is linear in tau), so no reference code runs there.

    Returns:
        ``{"taus": [...], "p_Q": [[x, y, z], ...] [m], "quaternions": [[w, x, y, z], ...]}``.
    """
    g = default_door_geometry()
    taus = np.linspace(0.0, 1.0, knots)
    p_Q = [(g.p_WQ_ref(tau) - g.p_W_handle).tolist() for tau in taus]
    quaternions = [g.R_WL7_ref(tau).ToQuaternion().wxyz().tolist() for tau in taus]
    return json.dumps({"taus": taus.tolist(), "p_Q": p_Q, "quaternions": quaternions})


def reference_episode(controller: str) -> dict:
    """doorlab's reference solution: IK 10 knots and velocity with the doors open, impedance
    with them closed."""
    from doorlab.episode.controllers import run_controller

    doors = "closed" if controller == "impedance" else "open"
    scenario = Scenario(controller=controller, doors=doors)
    result, _ = run_controller(scenario)
    return episode_figures(result, scenario)


# The handout's practice -------------------------------------------------------------------


def practice_seed(assignment_seed: int) -> int:
    """The grading seed of the handout's practice draws (from the assignment's seed)."""
    from doorlab.pset.rules.assignment import job_seed

    return int(job_seed(int(assignment_seed), PRACTICE_JOB))


def practiced(settings) -> bool:
    """Whether the handout practises a test (its settings, or None: the defaults): the
    self-check runs it (``self_check``), and it is not hidden."""
    if settings is None:
        return True
    return settings.visibility != "hidden" and bool(settings.self_check)


def practice_table(assignment, reference: dict) -> dict:
    """What the students' doorlab grades with, since it holds none of this module, for the
    tests the handout practises (:func:`practiced`: nothing of a hidden test, nor of one the
    self-check does not run): each such unit test's expectations on the practice draws (its
    mistakes' answers included), the reference episodes' figures (``reference``:
    :func:`doorlab.pset.grading.grader.grade_reference`'s; their wall times left out), the
    reference helpers' table (when a practised episode runs them), and the practised tests'
    names (``tests``). An episode that runs the student's helpers is practised with their
    unit tests (it reports them)."""
    from doorlab.pset.rules.assignment import Assignment
    from doorlab.pset.rules.verdicts import TESTS, test_settings

    assignment = assignment or Assignment()
    seed = practice_seed(assignment.seed)
    specs = [t for t in TESTS if practiced(test_settings(assignment, t))]
    jobs = {j for t in specs for j in t.needed_jobs(test_settings(assignment, t))}
    figures = {}
    for job, result in sorted(reference.items()):
        if job not in jobs:
            continue
        data = dict(result.get("figures") or {})
        data.pop("wall_time_s", None)  # the same doorlab writes the same handout
        figures[job] = {"figures": data}
    helped = [
        t for t in specs if t.helpers and not t.uses_student_helpers(test_settings(assignment, t))
    ]
    return {
        "seed": seed,
        "tests": [t.name for t in specs],
        "units": {
            name: expect(seed=seed)
            for name, expect in sorted(EXPECTATIONS.items())
            if f"unit:{name}" in jobs
        },
        "reference": figures,
        "helpers": reference_helper_table() if helped else None,
    }
