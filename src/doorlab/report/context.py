"""What the generated answers work with: the loaded runs, their metrics printed as tagged
numbers, and the page's figures.

Every number tied to a metric is a ``<span class="num">`` carrying the run and the metrics.json
key, so tests can check the printed value against the folder.
"""

from __future__ import annotations

import html

from doorlab.pages import Figures, format_number, metric_unit
from doorlab.report.folders import LoadedRun, line_style


def span(text: str, *, run: str = "", key: str = "", unit: str = "") -> str:
    attrs = ' class="num"'
    if run:
        attrs += f' data-run="{html.escape(run)}"'
    if key:
        attrs += f' data-key="{html.escape(key)}"'
    if unit:
        attrs += f' data-unit="{html.escape(unit)}"'
    shown = f"{text} {unit}" if unit else text
    return f"<span{attrs}>{html.escape(shown)}</span>"


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

    def num(self, name: str, key: str) -> str:
        """A metric of run ``name`` in display units, tagged for tests."""
        unit, scale = metric_unit(key)
        value = self.value(name, key)
        text = format_number(None if value is None else value * scale)
        return span(text, run=name, key=key, unit=unit)

    def missing(self, *names: str) -> str:
        """A sentence naming the runs among ``names`` that have no logs ("" if none)."""
        parts = []
        for name in names:
            run = self.runs.get(name)
            if run is None:
                parts.append(f"<code>{name}</code> was not run")
            elif not run.has_logs:
                reason = f": {html.escape(run.error)}" if run.error else ""
                parts.append(
                    f"<code>{name}</code> produced no logs (status "
                    f"<b>{html.escape(run.status)}</b>{reason})"
                )
        if not parts:
            return ""
        return "<p>Not answered from data: " + "; ".join(parts) + ".</p>"

    def status_note(self, *names: str) -> str:
        """A sentence flagging runs that finished with a status other than ok."""
        parts = [
            f"<code>{n}</code> finished with status <b>{html.escape(self.runs[n].status)}</b>"
            + (f" ({html.escape(self.runs[n].error)})" if self.runs[n].error else "")
            for n in names
            if n in self.runs and self.runs[n].has_logs and self.runs[n].status != "ok"
        ]
        return "<p>Note: " + "; ".join(parts) + ".</p>" if parts else ""

    # -- figures ---------------------------------------------------------------------------
    def tracking_figures(self, key: str, runs: list[LoadedRun], what: str) -> str:
        from doorlab.plots import plot_orientation_error, plot_radial_error

        if not runs:
            return ""
        curves = {run.label: run.tracking for run in runs}
        return self.figures.embed(
            f"{key}_radial_error",
            plot_radial_error(
                curves, title=f"Radial tracking error of Q: {what}", styles=self.styles
            ),
            f"Radial error of Q (measured q, FK) over the arc window [mm]: {what}. "
            "Bottom panel: |error| on a log scale.",
        ) + self.figures.embed(
            f"{key}_orientation_error",
            plot_orientation_error(
                curves, title=f"Orientation error of L7: {what}", styles=self.styles
            ),
            f"Orientation error angle of L7 (measured q) over the arc window [deg]: {what}.",
        )

    def path_figure(self, key: str, runs: list[LoadedRun], what: str) -> str:
        from doorlab.plots import plot_q_path

        if not runs:
            return ""
        curves = {run.label: run.tracking for run in runs}
        return self.figures.embed(
            f"{key}_q_path",
            plot_q_path(
                curves, runs[0].geometry, title=f"Q in the xy plane: {what}", styles=self.styles
            ),
            f"Q's path (measured q) against the handle arc and the hinge: {what}. Right: the "
            "zoom, Q's radial deviation from the arc [mm] along the arc.",
        )

    def door_figure(self, key: str, runs: list[LoadedRun], what: str) -> str:
        from doorlab.plots import plot_door_angle

        if not runs:
            return ""
        return self.figures.embed(
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

    def torque_figure(self, key: str, runs: list[LoadedRun], what: str) -> str:
        from doorlab.plots import plot_external_torque_norm

        if not runs:
            return ""
        return self.figures.embed(
            f"{key}_external_torque_norm",
            plot_external_torque_norm(
                {run.label: run.result for run in runs},
                title=f"|tau_ext|: {what}",
                styles=self.styles,
            ),
            f"Norm of the external (contact) joint torques [N m]: {what}.",
        )
