"""The problem set's autograder: Gradescope-format JSON from isolated, time-limited jobs.

Every job (a unit test of one student function, a student episode, a reference episode) runs
in its own process (:mod:`doorlab.pset.worker`) with a time limit, ``jobs`` at a time, so a
student's exception, NaN or endless loop fails that test only. Episode thresholds that depend
on the physics are relative to doorlab's reference solution, simulated in the same grading.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from doorlab.errors import OutputError

IK_POSITION_TOLERANCE = 0.001
"""The task cell's position_tolerance [m]."""
IK_RADIAL_MARGIN = 2 * math.sqrt(2) * IK_POSITION_TOLERANCE
"""How much more Q's radial error may be with the student's IK than with the reference's [m]:
each knot may sit anywhere in a +-1 mm box, so two valid IKs can put a knot up to
2 sqrt(2) mm apart horizontally."""
ARC_END_MARGIN = math.radians(2.0)
"""Q's angle about the hinge at the arc's end vs the reference's [rad]: a correct plan ends
within a fraction of a degree of it; a plan that does not follow the whole arc misses by tens."""
VELOCITY_ORIENTATION_MARGIN = 0.01
"""How much larger L7's orientation error may be than the reference velocity plan's [rad]
(0.6 deg: a correct plan matches the reference to a small fraction of that; a wrong rotational
term is off by tenths of a radian)."""
DOOR_OPENING_MARGIN = math.radians(5.0)
"""Door opening by the arc's end vs the reference impedance plan's [rad]: a correct J^T F
lands within a degree; a wrong gain, sign or frame leaves the door far behind or loses the
handle."""
UNIT_TIME_LIMIT_S = 60.0
"""Time limit of a unit test's process [s] (a correct one takes 2-5 s)."""
EPISODE_TIME_LIMIT_S = 150.0
"""Time limit of an episode's process [s] (a correct one takes 5-15 s on a busy 2-core machine)."""


@dataclass(frozen=True)
class TestSpec:
    """One graded test: its Gradescope name, points, the jobs it needs and how it is judged."""

    name: str
    max_score: float
    jobs: tuple[str, ...]
    judge: Callable[[dict[str, dict]], tuple[bool, str]]


def _figures(results: dict[str, dict], job: str) -> dict | None:
    return results.get(job, {}).get("figures")


def _failed_job(results: dict[str, dict], jobs: Sequence[str]) -> str | None:
    for job in jobs:
        r = results.get(job, {})
        if "figures" not in r:
            who = "doorlab's reference" if job.startswith("reference") else "your code"
            text = r.get("error") or "no result"
            detail = r.get("output", "")
            return f"{who} ({job}) did not finish: {text}" + (f"\n{detail}" if detail else "")
    return None


def _mm(x: float) -> str:
    return f"{x * 1e3:.2f} mm"


def _deg(x: float) -> str:
    return f"{math.degrees(x):.2f} deg"


def _judge_unit(job: str) -> Callable[[dict[str, dict]], tuple[bool, str]]:
    def judge(results: dict[str, dict]) -> tuple[bool, str]:
        r = results.get(job, {})
        text = r.get("output", "")
        if "error" in r:
            text = f"{r['error']}\n{text}".rstrip()
        return bool(r.get("passed", False)), text

    return judge


def _judge_ik(results: dict[str, dict]) -> tuple[bool, str]:
    jobs = ("student:ik", "reference:ik")
    if failed := _failed_job(results, jobs):
        return False, failed
    s, r = _figures(results, "student:ik"), _figures(results, "reference:ik")
    bound = r["max_radial_error_m"] + IK_RADIAL_MARGIN
    checks = [
        (
            s["max_radial_error_m"] <= bound,
            f"max radial error of Q {_mm(s['max_radial_error_m'])} (bound {_mm(bound)} = the "
            f"reference's {_mm(r['max_radial_error_m'])} + {_mm(IK_RADIAL_MARGIN)})",
        ),
        (
            abs(s["q_end_angle_rad"] - r["q_end_angle_rad"]) <= ARC_END_MARGIN,
            f"Q's angle about the hinge at the arc's end {_deg(s['q_end_angle_rad'])} "
            f"(reference {_deg(r['q_end_angle_rad'])}, margin {_deg(ARC_END_MARGIN)})",
        ),
    ]
    return _combine(checks)


def _judge_velocity(results: dict[str, dict]) -> tuple[bool, str]:
    jobs = ("student:velocity", "reference:velocity", "reference:ik")
    if failed := _failed_job(results, jobs):
        return False, failed
    s = _figures(results, "student:velocity")
    r = _figures(results, "reference:velocity")
    ik = _figures(results, "reference:ik")
    o_bound = r["max_orientation_error_rad"] + VELOCITY_ORIENTATION_MARGIN
    checks = [
        (
            s["max_radial_error_m"] <= ik["max_radial_error_m"],
            f"max radial error of Q {_mm(s['max_radial_error_m'])} (must be below pointwise "
            f"IK's {_mm(ik['max_radial_error_m'])}; the reference velocity plan: "
            f"{_mm(r['max_radial_error_m'])})",
        ),
        (
            s["max_orientation_error_rad"] <= o_bound,
            f"max orientation error of L7 {s['max_orientation_error_rad']:.4f} rad (bound "
            f"{o_bound:.4f} = the reference's {r['max_orientation_error_rad']:.4f} + "
            f"{VELOCITY_ORIENTATION_MARGIN})",
        ),
        (
            abs(s["q_end_angle_rad"] - r["q_end_angle_rad"]) <= ARC_END_MARGIN,
            f"Q's angle about the hinge at the arc's end {_deg(s['q_end_angle_rad'])} "
            f"(reference {_deg(r['q_end_angle_rad'])}, margin {_deg(ARC_END_MARGIN)})",
        ),
    ]
    return _combine(checks)


_DOOR = "door_opening_at_arc_end_rad"


def _judge_impedance(results: dict[str, dict]) -> tuple[bool, str]:
    jobs = ("student:impedance", "reference:impedance")
    if failed := _failed_job(results, jobs):
        return False, failed
    s, r = _figures(results, "student:impedance"), _figures(results, "reference:impedance")
    checks = [
        (bool(s["handle_held"]), f"handle held at the end: {s['handle_held']}"),
        (
            abs(s[_DOOR] - r[_DOOR]) <= DOOR_OPENING_MARGIN,
            f"door opened {_deg(s[_DOOR])} by the arc's end (reference "
            f"{_deg(r[_DOOR])}, margin {_deg(DOOR_OPENING_MARGIN)})",
        ),
    ]
    return _combine(checks)


def _combine(checks: list[tuple[bool, str]]) -> tuple[bool, str]:
    lines = [("ok     " if ok else "FAILED ") + text for ok, text in checks]
    return all(ok for ok, _ in checks), "\n".join(lines)


TESTS: tuple[TestSpec, ...] = (
    TestSpec("Task 1 unit test: InverseKinPointwise", 2.0, ("unit:ik",), _judge_unit("unit:ik")),
    TestSpec("Task 2 unit test: calc_p_Q", 1.0, ("unit:calc_p_Q",), _judge_unit("unit:calc_p_Q")),
    TestSpec(
        "Task 2 unit test: calc_R_WL7_ref",
        1.0,
        ("unit:calc_R_WL7_ref",),
        _judge_unit("unit:calc_R_WL7_ref"),
    ),
    TestSpec(
        "Task 2 unit test: IiwaTaskSpaceVelocityPlan.CalcPositionCommand",
        2.0,
        ("unit:velocity",),
        _judge_unit("unit:velocity"),
    ),
    TestSpec(
        "Task 3 unit test: IiwaTaskSpaceImpedancePlan.CalcTorqueCommand",
        2.0,
        ("unit:impedance",),
        _judge_unit("unit:impedance"),
    ),
    TestSpec(
        "Task 1 episode: IK with 10 knots, doors open",
        2.0,
        ("student:ik", "reference:ik"),
        _judge_ik,
    ),
    TestSpec(
        "Task 2 episode: velocity plan, doors open",
        2.0,
        ("student:velocity", "reference:velocity", "reference:ik"),
        _judge_velocity,
    ),
    TestSpec(
        "Task 3 episode: impedance plan, doors closed",
        2.0,
        ("student:impedance", "reference:impedance"),
        _judge_impedance,
    ),
)
"""Every graded test, in report order."""


def _time_limit(job: str, scale: float) -> float:
    base = UNIT_TIME_LIMIT_S if job.startswith("unit:") else EPISODE_TIME_LIMIT_S
    return base * scale


def _run_job(job: str, folder: Path, workdir: Path, scale: float) -> dict:
    out = workdir / (job.replace(":", "_") + ".json")
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONDONTWRITEBYTECODE="1")
    limit = _time_limit(job, scale)
    start = time.perf_counter()
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "doorlab.pset.worker", job, str(folder), str(out)],
            cwd=folder,
            env=env,
            capture_output=True,
            text=True,
            timeout=limit,
        )
    except subprocess.TimeoutExpired:
        return {
            "passed": False,
            "error": f"time limit: still running after {limit:.0f} s (an endless loop?)",
        }
    elapsed = time.perf_counter() - start
    if out.exists():
        try:
            result = json.loads(out.read_text())
        except json.JSONDecodeError:
            result = {"passed": False, "error": "the job wrote an unreadable result"}
    else:
        tail = "\n".join((proc.stderr or "").strip().splitlines()[-8:])
        result = {
            "passed": False,
            "error": f"the process exited with code {proc.returncode} without a result",
            "output": tail,
        }
    result["seconds"] = elapsed
    return result


def _job_order(jobs: set[str]) -> list[str]:
    # Longest first (episodes), so the two workers finish together.
    return sorted(jobs, key=lambda j: (j.startswith("unit:"), j))


def grade(
    folder: str | Path,
    *,
    jobs: int = 2,
    reference: dict[str, dict] | None = None,
    only: Sequence[str] | None = None,
    time_limit_scale: float = 1.0,
) -> dict:
    """Grades a problem-set folder.

    Args:
        folder: The folder written by ``doorlab pset init``.
        jobs: Processes at a time.
        reference: Results of the ``reference:*`` jobs to reuse (e.g. from an earlier
            grading's ``reference`` entry); None simulates them in this grading.
        only: Names of the tests to run (default: all).
        time_limit_scale: Multiplies every job's time limit.

    Returns:
        Gradescope results: ``{"score", "tests": [{"name", "score", "max_score", "output"}],
        "execution_time", "extra_data": {"max_score", "reference"}}`` (``reference``: the
        figures of the reference episodes, reusable as the ``reference`` argument).
    """
    folder = Path(folder).resolve()
    specs = [t for t in TESTS if only is None or t.name in only]
    needed = {j for t in specs for j in t.jobs}
    results: dict[str, dict] = {}
    if reference is not None:
        results.update({k: v for k, v in reference.items() if k in needed})
    todo = _job_order(needed - set(results))
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="doorlab_grade_") as tmp:
        with ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
            futures = {
                job: pool.submit(_run_job, job, folder, Path(tmp), time_limit_scale) for job in todo
            }
            for job, future in futures.items():
                results[job] = future.result()
    tests = []
    for spec in specs:
        passed, output = spec.judge(results)
        tests.append(
            {
                "name": spec.name,
                "score": spec.max_score if passed else 0.0,
                "max_score": spec.max_score,
                "output": output,
            }
        )
    return {
        "score": sum(t["score"] for t in tests),
        "tests": tests,
        "execution_time": round(time.perf_counter() - start, 2),
        "extra_data": {
            "max_score": sum(t["max_score"] for t in tests),
            "reference": {k: v for k, v in results.items() if k.startswith("reference:")},
        },
    }


def write_results(results: dict, path: str | Path) -> Path:
    """Writes Gradescope JSON (atomically: a temporary file renamed into place)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    try:
        tmp.write_text(json.dumps(results, indent=2, default=str) + "\n")
        tmp.replace(path)
    except OSError as e:
        raise OutputError(f"cannot write {path}: {e.strerror or e}") from None
    return path


def pretty_format_json_results(path: str | Path) -> str:
    """A readable summary of a results file: one block per test and the total."""
    data = json.loads(Path(path).read_text())
    lines = []
    for t in data["tests"]:
        mark = "PASS" if t["score"] >= t["max_score"] else "FAIL"
        lines.append(f"[{mark}] {t['name']}: {t['score']:g} / {t['max_score']:g}")
        for line in str(t.get("output", "")).splitlines():
            lines.append(f"    {line}")
    total = sum(t["max_score"] for t in data["tests"])
    lines.append(f"Total score: {data['score']:g} / {total:g}")
    return "\n".join(lines)


def main(argv: Sequence[str], *, folder: str | Path) -> int:
    """``python3 test_pset_5a.py [RESULTS_JSON]``: grades ``folder`` and writes the JSON
    (default ``test_results.json``); prints the summary."""
    out = Path(argv[0]) if argv else Path("test_results.json")
    results = grade(folder)
    write_results(results, out)
    print(pretty_format_json_results(out))
    return 0
