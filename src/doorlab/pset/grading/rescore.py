"""New results from what a grading stored, without simulating: re-scoring and re-judging.

Every grading stores in its results (``extra_data``) the settings it graded with
(``settings``: :meth:`doorlab.pset.rules.assignment.Assignment.to_dict`), the student's episodes'
figures or failures (``episodes``, :func:`doorlab.pset.grading.scoring.stored_episodes`), the
reference episodes' figures (``reference``) and each unit test's verdict (its entry of
``tests``). From them, against another assignment (:func:`settings_change`):

- points or visibility (a test's, the results', their stdout's) changed: **re-scored**, the
  same verdicts at the new points;
- an episode's margins changed, or the reference episodes: **re-judged**, the same figures
  against the new bounds (the same judges as a grading:
  :func:`doorlab.pset.grading.scoring.judge_test`);
- the random seed (other unit-test inputs) or an episode's helpers (another simulation)
  changed, or the results hold no stored figures (an older doorlab): it must be **graded**
  again (:class:`NeedsGrading` says why).

Re-judging with the settings and reference a grading used gives back its results (tested).
"""

from __future__ import annotations

import copy
from collections.abc import Iterator
from dataclasses import dataclass, field

from doorlab.pset.grading.scoring import judge_test, results_not_graded
from doorlab.pset.rules import verdicts

ACTIONS = ("keep", "rescore", "rejudge", "grade")
"""What a regrade does to a submission, cheapest first."""

_RESCORE_FIELDS = ("points", "visibility")
_REJUDGE_SUFFIXES = ("_margin", "_margin_deg")
_GRADE_FIELDS = ("seed", "helpers")
_NO_EFFECT = ("title", "self_check", "late")
"""Settings that change no result (the late policy is re-applied on its own:
:mod:`doorlab.pset.classroom.late`)."""


class NeedsGrading(Exception):
    """The stored figures do not suffice: the submission must be graded (simulated) again."""


@dataclass
class Change:
    """What a change of settings does to a submission's results.

    Attributes:
        action: One of :data:`ACTIONS`.
        why: What changed, as ``field: old -> new`` (the strongest action's first).
    """

    action: str = "keep"
    why: list[str] = field(default_factory=list)

    def add(self, action: str, why: str) -> None:
        """Notes a change needing ``action`` (the strongest action wins)."""
        if ACTIONS.index(action) > ACTIONS.index(self.action):
            self.action = action
            self.why.insert(0, why)
        else:
            self.why.append(why)


def _flat(data: object, prefix: str = "") -> Iterator[tuple[str, object]]:
    if isinstance(data, dict):
        for key, value in data.items():
            yield from _flat(value, f"{prefix}.{key}" if prefix else str(key))
    else:
        yield prefix, data


def _shown(value: object) -> str:
    return f"{value:g}" if isinstance(value, float) else repr(value) if value == "" else str(value)


def settings_change(old: dict | None, new: dict) -> Change:
    """What changing a grading's settings ``old`` (``extra_data.settings``; None: not
    stored) to ``new`` (:meth:`~doorlab.pset.rules.assignment.Assignment.to_dict`) needs."""
    change = Change()
    if old is None:
        change.add("grade", "its results do not say what they were graded with (an older doorlab)")
        return change
    before, after = dict(_flat(old)), dict(_flat(new))
    for key in sorted(set(before) | set(after)):
        a, b = before.get(key), after.get(key)
        if a == b:
            continue
        name = key.rsplit(".", 1)[-1]
        why = f"{key}: {_shown(a)} -> {_shown(b)}"
        if key.split(".", 1)[0] in _NO_EFFECT or name in _NO_EFFECT:
            continue
        if name in _GRADE_FIELDS:
            change.add("grade", why)
        elif name.endswith(_REJUDGE_SUFFIXES):
            change.add("rejudge", why)
        elif name in _RESCORE_FIELDS or key == "stdout_visibility":
            change.add("rescore", why)
        else:  # a setting this doorlab does not know how to re-apply: be safe
            change.add("grade", why)
    return change


def _unit_test(spec: verdicts.TestSpec) -> bool:
    return all(job.startswith("unit:") for job in spec.jobs)


def rejudge(results: dict, assignment, reference: dict | None = None) -> dict:
    """``results`` re-scored and re-judged under ``assignment`` (its points, visibility,
    margins) from their stored figures, against ``reference`` (None: the stored one); a
    new results dict (the input is not changed). Unit tests keep their verdicts and outputs.

    Raises:
        NeedsGrading: An episode's figures are not stored (an older doorlab), or the
            settings need another simulation (:func:`settings_change`).
    """
    extra = results.get("extra_data") or {}
    change = settings_change(extra.get("settings"), assignment.to_dict())
    if change.action == "grade":
        raise NeedsGrading("; ".join(change.why))
    out = copy.deepcopy(results)
    if extra.get("not_graded"):  # not graded (the intake refused it): every test 0
        fresh = results_not_graded(
            [s for s in verdicts.TESTS if s.name in {t["name"] for t in results["tests"]}],
            extra["not_graded"],
            assignment,
        )
        out["tests"] = fresh["tests"]
    else:
        out["tests"] = _judged(results, assignment, reference)
    out["score"] = sum(t["score"] for t in out["tests"])
    out["visibility"] = assignment.visibility
    out["stdout_visibility"] = assignment.stdout_visibility
    out["extra_data"]["max_score"] = sum(t["max_score"] for t in out["tests"])
    out["extra_data"]["settings"] = assignment.to_dict()
    if reference is not None and not extra.get("not_graded"):
        out["extra_data"]["reference"] = copy.deepcopy(reference)
    return out


def _judged(results: dict, assignment, reference: dict | None) -> list[dict]:
    extra = results["extra_data"]
    jobs: dict[str, dict] = {}
    jobs.update(copy.deepcopy(reference if reference is not None else extra.get("reference") or {}))
    jobs.update(copy.deepcopy(extra.get("episodes") or {}))
    by_name = {t["name"]: t for t in results["tests"]}
    for spec in verdicts.TESTS:  # the unit tests' verdicts, for an episode's helper note
        if _unit_test(spec) and spec.name in by_name:
            jobs.setdefault(spec.jobs[0], {"passed": by_name[spec.name]["status"] == "passed"})
    tests = []
    for spec in verdicts.TESTS:
        old = by_name.get(spec.name)
        if old is None:
            continue
        settings = verdicts.test_settings(assignment, spec)
        if _unit_test(spec):
            points = float(settings.points)
            passed = old.get("status") == "passed"
            tests.append(
                {
                    **old,
                    "score": points if passed else 0.0,
                    "max_score": points,
                    "visibility": settings.visibility,
                }
            )
            continue
        missing = [j for j in spec.jobs if j not in jobs]
        if missing:
            raise NeedsGrading(
                f"the figures of {', '.join(missing)} are not in its results (graded by an "
                "older doorlab)"
            )
        tests.append(judge_test(spec, settings, jobs))
    return tests
