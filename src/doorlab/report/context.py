"""What the generated answers work with: the loaded runs, their metrics as facts
(:class:`~doorlab.report.prose.Num`: the value, the run and the metrics.json key, so tests can
check the printed value against the folder), and the page's figures.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from doorlab.episode.metrics import Tracking
from doorlab.outputs.pages import EmbeddedFigure, Figures, format_number, metric_unit
from doorlab.report.folders import LoadedRun, line_style
from doorlab.report.prose import Num, Paragraph, Part, code, joined, number, para, strong


class AnswerPage:
    """The loaded runs and the helpers the answers use."""

    def __init__(self, runs: list[LoadedRun], figures: Figures) -> None:
        self.runs = {run.name: run for run in runs}
        self.order = [run.name for run in runs]
        self.figures = figures
        self.styles = {run.label: line_style(run, i) for i, run in enumerate(runs)}

    # -- access ----------------------------------------------------------------------------
    def logged(self, *names: str) -> list[LoadedRun]:
        """The named runs that have logs, in the order given."""
        return [self.runs[n] for n in names if n in self.runs and self.runs[n].has_logs]

    def value(self, name: str, key: str) -> float | None:
        value = self.runs[name].metrics.get(key)
        return float(value) if isinstance(value, (int, float)) else None

    def num(self, name: str, key: str) -> Num:
        """A metric of run ``name`` in display units, as a fact tied to its run and key."""
        unit, scale = metric_unit(key)
        value = self.value(name, key)
        shown = None if value is None else value * scale
        return Num(shown, format_number(shown), unit, name, key)

    def missing(self, *names: str) -> Paragraph | None:
        """A paragraph naming the runs among ``names`` that have no logs (None if none)."""
        parts: list[list[Part]] = []
        for name in names:
            run = self.runs.get(name)
            if run is None:
                parts.append([code(name), " was not run"])
            elif not run.has_logs:
                reason = f": {run.error}" if run.error else ""
                parts.append(
                    [code(name), " produced no logs (status ", strong(run.status), f"{reason})"]
                )
        if not parts:
            return None
        return para("Not answered from data: ", joined(parts, "; "), ".")

    def status_note(self, *names: str) -> Paragraph | None:
        """A paragraph flagging runs that finished with a status other than ok (None if none)."""
        parts = [
            [
                code(n),
                " finished with status ",
                strong(self.runs[n].status),
                f" ({self.runs[n].error})" if self.runs[n].error else "",
            ]
            for n in names
            if n in self.runs and self.runs[n].has_logs and self.runs[n].status != "ok"
        ]
        return para("Note: ", joined(parts, "; "), ".") if parts else None

    # -- figures ---------------------------------------------------------------------------
    def tracking_figures(self, key: str, runs: list[LoadedRun], what: str) -> list[EmbeddedFigure]:
        from doorlab.outputs.plots import plot_orientation_error, plot_radial_error

        if not runs:
            return []
        curves = {run.label: run.tracking for run in runs}
        return [
            self.figures.add(
                f"{key}_radial_error",
                plot_radial_error(
                    curves, title=f"Radial tracking error of Q: {what}", styles=self.styles
                ),
                f"Radial error of Q (measured q, FK) over the arc window [mm]: {what}. "
                "Bottom panel: |error| on a log scale.",
            ),
            self.figures.add(
                f"{key}_orientation_error",
                plot_orientation_error(
                    curves, title=f"Orientation error of L7: {what}", styles=self.styles
                ),
                f"Orientation error angle of L7 (measured q) over the arc window [deg]: {what}.",
            ),
        ]

    def path_figure(self, key: str, runs: list[LoadedRun], what: str) -> list[EmbeddedFigure]:
        from doorlab.outputs.plots import plot_q_path

        if not runs:
            return []
        curves = {run.label: run.tracking for run in runs}
        return [
            self.figures.add(
                f"{key}_q_path",
                plot_q_path(
                    curves,
                    runs[0].geometry,
                    title=f"Q in the xy plane: {what}",
                    styles=self.styles,
                ),
                f"Q's path (measured q) against the handle arc and the hinge: {what}. Right: "
                "the zoom, Q's radial deviation from the arc [mm] along the arc.",
            )
        ]

    def door_figure(self, key: str, runs: list[LoadedRun], what: str) -> list[EmbeddedFigure]:
        from doorlab.outputs.plots import plot_door_angle

        if not runs:
            return []
        return [
            self.figures.add(
                f"{key}_door_angle",
                plot_door_angle(
                    {run.label: run.result for run in runs},
                    geometry=runs[0].geometry,
                    title=f"Left hinge angle: {what}",
                    styles=self.styles,
                ),
                f"Left door hinge angle [deg] (negative = open): {what}; dotted: the door angle "
                "the arc plan implies.",
            )
        ]

    def torque_figure(self, key: str, runs: list[LoadedRun], what: str) -> list[EmbeddedFigure]:
        from doorlab.outputs.plots import plot_external_torque_norm

        if not runs:
            return []
        return [
            self.figures.add(
                f"{key}_external_torque_norm",
                plot_external_torque_norm(
                    {run.label: run.result for run in runs},
                    title=f"|tau_ext|: {what}",
                    styles=self.styles,
                ),
                f"Norm of the external (contact) joint torques [N m]: {what}.",
            )
        ]


# Helpers of the answers: describing measured sequences and logs in words.


def order_phrase(values: Sequence[float], *, falling: str = "falls", rising: str = "grows") -> str:
    """Describes a sequence by its actual order: monotone falling/rising or not monotone."""
    diffs = np.diff(np.asarray(values, float))
    if len(diffs) and np.all(diffs < 0):
        return falling
    if len(diffs) and np.all(diffs > 0):
        return rising
    return "changes, not monotonically,"


def ratio_phrase(a: float | None, b: float | None) -> list[Part]:
    """'3.2 times smaller than' / 'larger than' / 'equal to' for a vs b (both > 0)."""
    if a is None or b is None or not (math.isfinite(a) and math.isfinite(b)):
        return ["not comparable with"]
    if a == b:
        return ["equal to"]
    if a < b:
        ratio = b / a if a > 0 else math.inf
        return [number(ratio), " times smaller than"] if math.isfinite(ratio) else ["smaller than"]
    ratio = a / b if b > 0 else math.inf
    return [number(ratio), " times larger than"] if math.isfinite(ratio) else ["larger than"]


def signed_range_mm(tracking: Tracking, *, skip: float = 0.05) -> tuple[float, float]:
    """(min, max) of the signed radial error [mm] for tau >= skip (after the start transient)."""
    mask = tracking.tau >= skip
    e = 1000.0 * tracking.radial_error[mask if np.any(mask) else slice(None)]
    return float(np.min(e)), float(np.max(e))


def knot_profile(run: LoadedRun) -> tuple[float, list[float]] | None:
    """(max |e| at the knots [mm], peak |e| per knot segment [mm]) of an IK run."""
    knots = run.scenario.ik.knots if run.scenario else None
    if not knots or knots < 2:
        return None
    tau = run.tracking.tau
    e = np.abs(1000.0 * run.tracking.radial_error)
    knot_taus = np.linspace(0.0, 1.0, knots)
    at_knots = [float(e[int(np.argmin(np.abs(tau - k)))]) for k in knot_taus]
    peaks = []
    for a, b in zip(knot_taus[:-1], knot_taus[1:], strict=True):
        mask = (tau >= a) & (tau <= b)
        peaks.append(float(np.max(e[mask])) if np.any(mask) else float("nan"))
    return max(at_knots), peaks


def tau_of_max(tracking: Tracking) -> float:
    """Arc parameter tau in [0, 1] where |radial error| is largest."""
    return float(tracking.tau[int(np.argmax(np.abs(tracking.radial_error)))])


def side(tracking: Tracking) -> str:
    """ "outside" or "inside": where Q is at its largest radial error."""
    e = tracking.radial_error
    return "inside" if len(e) and e[int(np.argmax(np.abs(e)))] < 0 else "outside"


def door_lag_deg(run: LoadedRun) -> float | None:
    """Largest lag of the left door behind the arc plan over the arc [deg] (metrics.py)."""
    lag = run.metrics.get("door_lag_max_rad")
    return None if lag is None else math.degrees(lag)
