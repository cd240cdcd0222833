"""The problem set's autograder: Gradescope-format JSON, every verdict on the trusted side.

:func:`grade` starts the *supervisor* (:mod:`doorlab.pset.jobs`, in Python's isolated mode,
its working directory outside the folder), which runs every job in a trusted process of its
own: a unit test of one student function, a student episode, or a reference episode. The
student's code runs in a separate, sandboxed process (:mod:`doorlab.pset.sandbox`) that
only answers numbers over a channel (:mod:`doorlab.pset.channel`); the trusted side draws
the inputs, runs the simulations, and computes every figure and verdict
(:mod:`doorlab.pset.checks`, :mod:`doorlab.pset.episodes`), so nothing the submission does
can write its own score. Episode thresholds that depend on the physics are relative to
doorlab's reference solution, simulated in the same grading (or passed in, ``reference=``).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from doorlab.errors import DoorlabError, OutputError
from doorlab.pset.jobs import EPISODE_TIME_LIMIT_S, UNIT_TIME_LIMIT_S

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
MAX_OUTPUT_CHARS = 4000
"""Longest output of one test in the results (the student's printed output is capped
before that, see :mod:`doorlab.pset.sandbox`)."""
__all__ = [
    "EPISODE_TIME_LIMIT_S",
    "TESTS",
    "UNIT_TIME_LIMIT_S",
    "GradingError",
    "grade",
    "load_reference",
    "pretty_format_json_results",
    "write_results",
]


class GradingError(DoorlabError):
    """The grader itself could not grade (its sandbox cannot start, its process failed):
    no verdict, rather than zeros the submission did not earn."""


@dataclass(frozen=True)
class TestSpec:
    """One graded test: its Gradescope name, points, the jobs it needs and how it is judged."""

    name: str
    max_score: float
    jobs: tuple[str, ...]
    judge: Callable[[dict[str, dict]], tuple[bool, str]]


FIGURES = (
    "max_radial_error_m",
    "max_orientation_error_rad",
    "q_end_angle_rad",
    "door_opening_at_arc_end_rad",
)
"""The episode figures the judges read (finite numbers), besides ``handle_held``."""


def _figures(results: dict[str, dict], job: str) -> dict | None:
    """The job's figures if they are all there and numbers (None otherwise)."""
    r = results.get(job)
    figures = r.get("figures") if isinstance(r, dict) else None
    if not isinstance(figures, dict) or figures.get("handle_held") not in (True, False, None):
        return None
    for key in FIGURES:
        x = figures.get(key)
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
            return None
    return figures


def _failed_job(results: dict[str, dict], jobs: Sequence[str]) -> str | None:
    for job in jobs:
        if _figures(results, job) is not None:
            continue
        r = results.get(job)
        r = r if isinstance(r, dict) else {}
        who = "doorlab's reference" if job.startswith("reference") else "your code"
        text = str(r.get("error") or "no result")
        detail = str(r.get("output") or "")
        return f"{who} ({job}) did not finish: {text}" + (f"\n{detail}" if detail else "")
    return None


def _angle_zero(*figures: dict) -> str:
    """What Q's angle about the hinge is measured from (it is not the door's opening)."""
    theta0 = next((f["theta0_rad"] for f in figures if "theta0_rad" in f), None)
    at = f" ({_deg(theta0)} at the closed door's handle)" if theta0 is not None else ""
    return (
        f"Q's angle about the hinge is the seed's theta, measured from W's y axis{at}; the "
        "door's opening is measured from the closed door"
    )


def _mm(x: float) -> str:
    return f"{x * 1e3:.2f} mm"


def _deg(x: float) -> str:
    return f"{math.degrees(x):.2f} deg"


def _judge_unit(job: str) -> Callable[[dict[str, dict]], tuple[bool, str]]:
    def judge(results: dict[str, dict]) -> tuple[bool, str]:
        r = results.get(job)
        r = r if isinstance(r, dict) else {}
        text = str(r.get("output") or "")
        if "error" in r:
            text = f"{r['error']}\n{text}".rstrip()
        return r.get("passed") is True and "error" not in r, text

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
    passed, text = _combine(checks)
    return passed, f"{text}\n({_angle_zero(s, r)})"


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
    passed, text = _combine(checks)
    return passed, f"{text}\n({_angle_zero(s, r)})"


_DOOR = "door_opening_at_arc_end_rad"


def _judge_impedance(results: dict[str, dict]) -> tuple[bool, str]:
    jobs = ("student:impedance", "reference:impedance")
    if failed := _failed_job(results, jobs):
        return False, failed
    s, r = _figures(results, "student:impedance"), _figures(results, "reference:impedance")
    checks = [
        (s["handle_held"] is True, f"handle held at the end: {s['handle_held']}"),
        (
            abs(s[_DOOR] - r[_DOOR]) <= DOOR_OPENING_MARGIN,
            f"door opened {_deg(s[_DOOR])} by the arc's end (from the closed door; "
            f"reference {_deg(r[_DOOR])}, margin {_deg(DOOR_OPENING_MARGIN)})",
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


def _cap(text: str) -> str:
    if len(text) <= MAX_OUTPUT_CHARS:
        return text
    return text[:MAX_OUTPUT_CHARS] + f"\n[... {len(text) - MAX_OUTPUT_CHARS} characters left out]"


def _sandbox_facts(results: dict[str, dict]) -> dict:
    """How the student's processes ran (from what each reported before its code loaded)."""
    from doorlab.pset import sandbox

    facts = [r["sandbox"] for r in results.values() if isinstance(r.get("sandbox"), dict)]
    uids = sorted({f.get("uid") for f in facts if isinstance(f.get("uid"), int)})
    return {
        "student_uids": uids,
        "grader_uid": os.geteuid(),
        "network_isolated": bool(facts) and all(f.get("network_isolated") for f in facts),
        "reference_hidden": bool(facts) and all(f.get("reference_hidden") for f in facts),
        "memory_limit_bytes": sandbox.MEMORY_LIMIT_BYTES,
        "file_size_limit_bytes": sandbox.FILE_SIZE_LIMIT_BYTES,
        "output_limit_bytes": sandbox.OUTPUT_LIMIT_BYTES,
        "process_limit": sandbox.PROCESS_LIMIT,
    }


def results_from_jobs(
    specs: Sequence[TestSpec], results: dict[str, dict], execution_time: float
) -> dict:
    """The Gradescope results of ``specs`` judged on the jobs' ``results`` (in the
    supervisor; see :func:`grade` for the format)."""
    tests = []
    for spec in specs:
        passed, output = spec.judge(results)
        tests.append(
            {
                "name": spec.name,
                "score": spec.max_score if passed else 0.0,
                "max_score": spec.max_score,
                "output": _cap(output),
            }
        )
    return {
        "score": sum(t["score"] for t in tests),
        "tests": tests,
        "execution_time": round(execution_time, 2),
        "extra_data": {
            "max_score": sum(t["max_score"] for t in tests),
            "reference": {k: v for k, v in results.items() if k.startswith("reference:")},
            "sandbox": _sandbox_facts(results),
        },
    }


def grade(
    folder: str | Path,
    *,
    jobs: int = 2,
    reference: dict[str, dict] | None = None,
    only: Sequence[str] | None = None,
    time_limit_scale: float = 1.0,
) -> dict:
    """Grades a problem-set folder; returns the Gradescope results (write them with
    :func:`write_results`).

    Returns only after every process the grading started (the student's included, however
    detached) is dead. The folder is not written to.

    Args:
        folder: The folder written by ``doorlab pset init`` (the submission).
        jobs: Tests run at a time.
        reference: Results of the ``reference:*`` jobs to reuse (e.g. an earlier grading's
            ``extra_data["reference"]``); None simulates them in this grading.
        only: Names of the tests to run (default: all, :data:`TESTS`).
        time_limit_scale: Multiplies every test's time limit.

    Returns:
        ``{"score", "tests": [{"name", "score", "max_score", "output"}], "execution_time",
        "extra_data": {"max_score", "reference", "sandbox"}}`` (``reference``: the reference
        episodes' figures, reusable as the ``reference`` argument; ``sandbox``: how the
        student's code ran: uids, network isolated, reference files hidden, limits).

    Raises:
        GradingError: The grader could not run (e.g. the sandbox's user cannot run this
            Python); no results, rather than zeros the submission did not earn.
    """
    request = {
        "folder": str(Path(folder).resolve()),
        "jobs": int(jobs),
        "reference": reference,
        "only": None if only is None else list(only),
        "time_limit_scale": float(time_limit_scale),
    }
    proc = subprocess.Popen(
        [sys.executable, "-I", "-m", "doorlab.pset.jobs", "supervise"],
        cwd="/",
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
    )
    try:
        out, _ = proc.communicate(json.dumps(request).encode())
    except BaseException:
        proc.terminate()  # the supervisor kills everything below it, then exits
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
        raise
    try:
        results = json.loads(out.decode())
    except (UnicodeDecodeError, ValueError):
        results = None
    if not isinstance(results, dict) or proc.returncode != 0:
        raise GradingError(f"the grading process failed (exit code {proc.returncode})")
    if "grader_error" in results:
        raise GradingError(f"cannot grade: {results['grader_error']}")
    return results


def write_results(results: dict, path: str | Path) -> Path:
    """Writes Gradescope JSON atomically: a new file in the same folder, flushed to disk,
    renamed over ``path`` (a reader sees the old file or the whole new one)."""
    path = Path(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
        try:
            with os.fdopen(fd, "w") as f:
                f.write(json.dumps(results, indent=2, default=str) + "\n")
                f.flush()
                os.fsync(f.fileno())
            os.chmod(tmp, 0o644)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
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


def load_reference(path: str | Path) -> dict[str, dict]:
    """The reference episodes' figures of an earlier results file (its
    ``extra_data["reference"]``), to pass as :func:`grade`'s ``reference``.

    Raises:
        OutputError: The file cannot be read or holds no reference figures.
    """
    try:
        data = json.loads(Path(path).read_text())
        reference = data["extra_data"]["reference"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise OutputError(f"{path}: not a results file with reference figures ({e})") from None
    if not isinstance(reference, dict) or not reference:
        raise OutputError(f"{path}: its results hold no reference figures")
    return reference


def main(argv: Sequence[str]) -> int:
    """``python -I -m doorlab.pset.grader FOLDER [RESULTS_JSON] [--reference FILE]`` (what the
    folder's ``test_pset_5a.py`` runs): grades FOLDER, writes the JSON (default
    ``test_results.json`` in the working directory) and prints the summary."""
    import argparse

    from doorlab.errors import interrupt_exit_code

    parser = argparse.ArgumentParser(
        prog="test_pset_5a.py", description="Grades the problem-set folder."
    )
    parser.add_argument("folder", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("out", nargs="?", type=Path, default=Path("test_results.json"))
    parser.add_argument(
        "--reference", type=Path, help="reuse the reference episodes of an earlier results file"
    )
    args = parser.parse_args(argv)
    folder, out = args.folder.resolve(), args.out.resolve()
    os.chdir("/")  # nothing of the folder in this process either
    try:
        reference = None if args.reference is None else load_reference(args.reference)
        results = grade(folder, reference=reference)
        write_results(results, out)
    except DoorlabError as e:
        print(f"test_pset_5a.py: {e}", file=sys.stderr)
        return 1 if isinstance(e, GradingError) else 2  # as doorlab's CLI
    except KeyboardInterrupt as e:
        return interrupt_exit_code(e)
    print(pretty_format_json_results(out))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
