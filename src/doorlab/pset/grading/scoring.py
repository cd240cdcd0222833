"""A grading's scoring: each test judged on the jobs' figures (the judges of
:data:`doorlab.pset.rules.verdicts.TESTS`) at the assignment's points and visibility, and the
Gradescope results (every output cleaned and capped; in ``extra_data`` what the grading stored
to re-judge it). In the grader's supervisor, the trusted side (:mod:`doorlab.pset.grading.jobs`).
"""

from __future__ import annotations

import os
from collections.abc import Sequence

from doorlab.pset.isolation.safe_text import clean_text
from doorlab.pset.rules.verdicts import TestSpec, test_settings

MAX_OUTPUT_CHARS = 4000
"""Longest output of one test in the results (the student's printed output is capped
before that, see :mod:`doorlab.pset.isolation.sandbox`)."""


def _cap(text: str) -> str:
    if len(text) <= MAX_OUTPUT_CHARS:
        return text
    return text[:MAX_OUTPUT_CHARS] + f"\n[... {len(text) - MAX_OUTPUT_CHARS} characters left out]"


ISOLATION_HELD = {
    "bwrap": "a minimal read-only root (bubblewrap): the student's code sees only its own "
    "scratch copy, the interpreter and the libraries it needs; no network; its own processes",
    "uid": "WITHOUT the minimal root: another user, no namespaces; it can read what that user "
    "may read on this machine",
    "none": "WITHOUT the minimal root: the grader's own user, no namespaces; it can read and "
    "write what that user may",
}
"""What each isolation mode means, for ``extra_data.sandbox.held``."""


def _sandbox_facts(results: dict[str, dict], isolation) -> dict:
    """How the student's processes ran: the grading's isolation and what each process
    observed of itself before its code loaded (judged here)."""
    from doorlab.pset.isolation import sandbox

    facts = [r["sandbox"] for r in results.values() if isinstance(r.get("sandbox"), dict)]
    uids = sorted({f.get("uid") for f in facts if isinstance(f.get("uid"), int)})

    def every(key: str) -> bool:
        return bool(facts) and all(f.get(key) is True for f in facts)

    sizes = [f.get("tmpfs_bytes") for f in facts if isinstance(f.get("tmpfs_bytes"), dict)]
    mode = getattr(isolation, "mode", None)
    out = {
        "mode": mode,
        "isolated": mode == "bwrap",
        "held": ISOLATION_HELD.get(mode, "no student process ran"),
        "student_uids": uids,
        "grader_uid": os.geteuid(),
        "network_isolated": every("network_isolated"),
        "reference_hidden": every("reference_hidden"),
        "pid_namespace": every("pid_namespace"),
        "user_namespaces_refused": every("user_namespaces_refused"),
        "python_path_read_only": bool(facts)
        and not any(f.get("python_path_writable") for f in facts),
        "seen": {
            key: sorted({str(p) for f in facts for p in f.get(key) or []})[:5]
            for key in ("reference_readable", "python_path_writable")
        },
        "tmpfs_bytes": max(
            (v for s in sizes for v in s.values() if isinstance(v, int)), default=None
        ),
        "memory_limit_bytes": sandbox.MEMORY_LIMIT_BYTES,
        "file_size_limit_bytes": sandbox.FILE_SIZE_LIMIT_BYTES,
        "output_limit_bytes": sandbox.OUTPUT_LIMIT_BYTES,
        "process_limit": sandbox.PROCESS_LIMIT,
    }
    if isolation is not None and isolation.mode != "bwrap":
        out["why_no_minimal_root"] = clean_text(isolation.reason, 300)
        out["policy"] = isolation.policy
        out["made_unreadable"] = list(isolation.hardened)
    return out


def _unit_passed(results: dict[str, dict], job: str) -> bool:
    r = results.get(job)
    return isinstance(r, dict) and r.get("passed") is True and "error" not in r


def _helper_note(spec: TestSpec, settings: object, results: dict[str, dict]) -> str:
    """Which helpers the episode ran, and (the student's) which of them failed their unit
    test, so a helper's mistake is seen where it is."""
    if not spec.helpers:
        return ""
    names = " and ".join(name for name, _ in spec.helpers)
    if not spec.uses_student_helpers(settings):
        return (
            f"(this episode runs doorlab's {names}, as the assignment sets: it grades your "
            "plan; your helpers are graded by their unit tests)"
        )
    failed = [name for name, job in spec.helpers if not _unit_passed(results, job)]
    lines = [f"this episode uses your {name}, which failed its unit test" for name in failed]
    return "\n".join(lines) or f"(this episode runs your {names}, as the assignment sets)"


def _gradescope_test(spec: TestSpec, settings: object, passed: bool, output: str) -> dict:
    points = float(getattr(settings, "points", spec.max_score))
    return {
        "name": spec.name,
        "number": spec.number,
        "score": points if passed else 0.0,
        "max_score": points,
        "status": "passed" if passed else "failed",
        "visibility": getattr(settings, "visibility", "visible"),
        "output": _cap(clean_text(output)),
        "output_format": "text",
    }


def _gradescope_results(assignment: object, tests: list[dict], output: str) -> dict:
    """The top level of Gradescope's results: plain text everywhere (no HTML, Markdown or
    ANSI is rendered from a student's output), the assignment's visibility and its stdout's."""
    return {
        "score": sum(t["score"] for t in tests),
        "visibility": getattr(assignment, "visibility", "visible"),
        "stdout_visibility": getattr(assignment, "stdout_visibility", "hidden"),
        "output": output,
        "output_format": "text",
        "test_output_format": "text",
        "test_name_format": "text",
        "tests": tests,
    }


def results_from_jobs(
    specs: Sequence[TestSpec],
    results: dict[str, dict],
    execution_time: float,
    assignment: object = None,
    drawn: dict | None = None,
    isolation: object = None,
) -> dict:
    """The Gradescope results of ``specs`` judged on the jobs' ``results`` (in the
    supervisor; see :func:`doorlab.pset.grading.grader.grade` for the format). Every test's output
    is cleaned (:func:`~doorlab.pset.isolation.safe_text.clean_text`).

    Args:
        specs: The tests.
        results: The jobs' results.
        execution_time: The grading's wall time [s].
        assignment: The assignment (:class:`doorlab.pset.rules.assignment.Assignment`: points,
            margins, visibility); None: the defaults.
        drawn: How the unit tests' random inputs were drawn (``extra_data["seed"]``: the
            grading seed, its source, the graded files' SHA-256), if they were.
        isolation: The grading's :class:`~doorlab.pset.isolation.choice.Isolation` (None: no
            student process ran).
    """
    tests = [judge_test(spec, test_settings(assignment, spec), results) for spec in specs]
    line = ""
    if drawn is not None:
        line = (
            f"The unit tests' random inputs come from grading seed {drawn['grading']} "
            f"({drawn['source']}); doorlab pset grade --seed {drawn['grading']} replays them."
        )
    out = _gradescope_results(assignment, tests, line)
    out["execution_time"] = round(execution_time, 2)
    out["extra_data"] = {
        "max_score": sum(t["max_score"] for t in tests),
        "seed": drawn,
        "reference": {k: v for k, v in results.items() if k.startswith("reference:")},
        "sandbox": _sandbox_facts(results, isolation),
        "episodes": stored_episodes(results),
        "settings": _settings(assignment),
    }
    return out


def judge_test(spec: TestSpec, settings: object, results: dict[str, dict]) -> dict:
    """One test's Gradescope entry, judged on the jobs' ``results`` under ``settings`` (its
    assignment entry: points, visibility, margins; None: the defaults)."""
    passed, output = spec.judge(results, settings)
    if note := _helper_note(spec, settings, results):
        output = f"{output}\n{note}" if output else note
    return _gradescope_test(spec, settings, passed, output)


def stored_episodes(results: dict[str, dict]) -> dict[str, dict]:
    """What re-judging needs of the student's episodes (``extra_data.episodes``): each
    ``student:*`` job's figures (with the compact series the feedback figures draw) or its
    failure, without its times and sandbox facts (the same files give the same figures)."""
    out = {}
    for job, result in results.items():
        if not job.startswith("student:") or not isinstance(result, dict):
            continue
        kept = {k: v for k, v in result.items() if k not in ("sandbox", "seconds")}
        if isinstance(kept.get("figures"), dict):
            kept["figures"] = {k: v for k, v in kept["figures"].items() if k != "wall_time_s"}
        out[job] = kept
    return out


def _settings(assignment: object) -> dict | None:
    """The settings a grading used (``extra_data.settings``), as plain data."""
    to_dict = getattr(assignment, "to_dict", None)
    return to_dict() if callable(to_dict) else None


def results_not_graded(specs: Sequence[TestSpec], reason: str, assignment: object = None) -> dict:
    """Results for a submission that is not graded (over an intake bound; none of the
    student files): every test 0 with the reason, in the same format as
    :func:`results_from_jobs`."""
    text = f"Not graded: {reason}"
    tests = [_gradescope_test(s, test_settings(assignment, s), False, text) for s in specs]
    out = _gradescope_results(assignment, tests, text)
    out["execution_time"] = 0.0
    out["extra_data"] = {
        "max_score": sum(t["max_score"] for t in tests),
        "not_graded": reason,
        "settings": _settings(assignment),
    }
    return out
