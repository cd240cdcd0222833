"""The report's verdict per plan on the arm, with its band: each plan (the four controllers and
the tuned plans of :data:`doorlab.report.experiments.ARM_TUNING`) run on the arm preset and
under each other plausible model of the arm (:func:`doorlab.report.experiments.arm_model_names`).

Each run has an outcome (:attr:`doorlab.report.arm_page.ArmRow.outcome`): it opens the door
(status ok, at least :data:`doorlab.studies.robustness.OPEN_THRESHOLD_DEG` at the arc's end,
the handle held), keeps the handle with the door short of that, loses the handle, or is
stopped (a safety stop, the driver's freeze). A plan "opens the door under every plausible
model" when every run of its band opened it; it "does not open the door under any plausible
model" when no run did and every run did the same instead (lost the handle, say); and it is
"uncertain: depends on X" otherwise, X the parameters of the models whose outcome differs
from the nominal's, whether that is opening the door or, when no model opens it, what it does
instead (a plan that keeps the handle under one damping model and loses it under another
behaves differently on the arm, and which it will do is not known until the arm is
identified). With each: the door at the arc's end, Q's max radial error, L7's max
orientation error and the freeze margin (1 - the largest |external torque| over
kuka_driver's limit, on the estimate the driver sees) over the band. Every number is read
from the runs.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from doorlab.outputs.pages import format_number
from doorlab.report.experiments import (
    ARM_MODELS,
    ARM_PARAMETERS,
    ARM_TUNING,
    arm_model_parameters,
)

VERDICTS = ("opens", "does_not_open", "uncertain")


@dataclass(frozen=True)
class PlanBand:
    """One plan's runs on the arm over the band, the nominal first.

    Attributes:
        controller: Registry name. tuned: With :data:`ARM_TUNING`'s settings.
        rows: (model, row) per model of the band ("" the nominal); each row a
            :class:`doorlab.report.arm_page.ArmRow`.
    """

    controller: str
    tuned: bool
    rows: tuple[tuple[str, Any], ...]

    @property
    def title(self) -> str:
        return f"{self.controller} (tuned)" if self.tuned else self.controller

    @property
    def nominal(self) -> Any:
        return self.rows[0][1]

    @property
    def verdict(self) -> str:
        """One of :data:`VERDICTS`."""
        outcomes = {row.outcome for _, row in self.rows}
        if outcomes == {"opens"}:
            return "opens"
        if len(outcomes) == 1:
            return "does_not_open"
        return "uncertain"

    @property
    def opens_anywhere(self) -> bool:
        """Whether any model of the band opens the door."""
        return any(row.opened for _, row in self.rows)

    def flips(self) -> list[tuple[str, Any]]:
        """The models whose outcome differs from the nominal's: each one-parameter model
        that does, and each corner whose outcome neither of its models gives alone (an
        interaction)."""
        nominal = self.nominal.outcome
        outcome = {model: row.outcome for model, row in self.rows}
        out = []
        for model, row in self.rows[1:]:
            if row.outcome == nominal:
                continue
            parts = model.split("+")
            if len(parts) > 1 and any(outcome.get(p) == row.outcome for p in parts):
                continue  # one of its models alone does it
            out.append((model, row))
        return out

    @property
    def depends_on(self) -> tuple[str, ...]:
        """The parameters of the models that change the verdict (:meth:`flips`)."""
        found: list[str] = []
        for model, _ in self.flips():
            found += [p for p in arm_model_parameters(model) if p not in found]
        return tuple(found)

    def values(self, attribute: str) -> np.ndarray:
        return np.array([getattr(row, attribute) for _, row in self.rows], float)


def plan_bands(rows: Sequence[Any]) -> list[PlanBand]:
    """The bands of the plans that have a nominal run on the arm, in the rows' order."""
    bands = {}
    for row in rows:
        case = row.case
        if case.condition != "arm" or case.yaw_error_rad:
            continue
        bands.setdefault((case.controller, case.tuned), []).append((case.model, row))
    out = []
    for (controller, tuned), found in bands.items():
        found.sort(key=lambda item: item[0] != "")
        if found[0][0] == "":
            out.append(PlanBand(controller, tuned, tuple(found)))
    return out


def _range(values: np.ndarray, scale: float = 1.0) -> str:
    finite = values[np.isfinite(values)] * scale
    if not finite.size:
        return "n/a"
    low, high = format_number(float(finite.min())), format_number(float(finite.max()))
    return low if low == high else f"{low}-{high}"


def model_label(model: str) -> str:
    """A band model's description ("" the nominal)."""
    if not model:
        return "the arm preset (nominal)"
    by_name = {m.name: m for m in ARM_MODELS}
    return " and ".join(by_name[name].label for name in model.split("+"))


OUTCOME_PHRASES = {
    "opens": "opens the door",
    "falls_short": "keeps the handle, the door short of open",
    "loses_the_handle": "loses the handle",
    "stopped": "is stopped",
}
"""How a verdict says what a run did (:data:`doorlab.report.arm_page.OUTCOMES`)."""


def _did(row: Any) -> str:
    phrase = OUTCOME_PHRASES[row.outcome]
    return f"{phrase} ({row.status})" if row.outcome == "stopped" else phrase


def verdict_sentence(band: PlanBand) -> str:
    """The plan's verdict with its band's figures."""
    runs = len(band.rows)
    if band.verdict == "opens":
        head = f"opens the door under every plausible model ({runs} runs)"
    elif band.verdict == "does_not_open":
        head = (
            f"does not open the door under any plausible model ({runs} runs; it "
            f"{OUTCOME_PHRASES[band.nominal.outcome]} under every one)"
        )
    else:
        names = " and ".join(ARM_PARAMETERS[p] for p in band.depends_on)
        flips = band.flips()
        alone = [(model_label(m), row) for m, row in flips if "+" not in m]
        together = [(model_label(m), row) for m, row in flips if "+" in m]
        parts = [f"on the nominal model it {_did(band.nominal)}"]
        parts += [f"with {label} it {_did(row)}" for label, row in alone]
        parts += [f"with {label} together it {_did(row)}" for label, row in together]
        why = f"it depends on {names} (" + "; ".join(parts) + ")"
        if band.opens_anywhere:
            head = f"is uncertain: {why}"
        else:
            head = (
                "does not open the door under any plausible model, and what it does instead "
                f"is uncertain: {why}"
            )
    stops = [
        f"{model_label(m)}: {row.status}"
        for m, row in band.rows
        if row.status not in ("ok", "slipped")
    ]
    held = [row.handle_held for _, row in band.rows]
    margin = band.values("freeze_margin")
    worst = int(np.nanargmin(margin)) if np.isfinite(margin).any() else None
    text = (
        f"The {band.title} plan {head}: the door at the arc's end "
        f"{_range(band.values('door_arc_end_deg'))} deg, Q's max radial error "
        f"{_range(band.values('max_radial_error_m'), 1e3)} mm, L7's max orientation error "
        f"{_range(np.degrees(band.values('max_orientation_error_rad')))} deg, the handle held in "
        f"{sum(bool(h) for h in held)} of {runs}"
    )
    if worst is not None:
        text += (
            f", the freeze margin {_range(margin, 100)} % (least: "
            f"{model_label(band.rows[worst][0])})"
        )
    if stops:
        text += "; stopped: " + "; ".join(stops)
    return text + "."


def band_table(bands: Sequence[PlanBand]) -> list[dict]:
    """The template's rows: one per plan and model."""
    from doorlab.cell.frames import ARM_JOINTS

    table = []
    for band in bands:
        for model, row in band.rows:
            held = {True: "held", False: "lost"}.get(row.handle_held, "n/a")
            joint = ARM_JOINTS[row.freeze_joint][-1] if row.freeze_joint is not None else ""
            parameters = ", ".join(arm_model_parameters(model)) or "nominal"
            table.append(
                {
                    "run": row.case.run,
                    "folder": row.folder,
                    "css": "" if row.opened else "warn",
                    "cells": [
                        band.title,
                        parameters,
                        model_label(model),
                        row.status,
                        format_number(row.door_arc_end_deg),
                        held,
                        format_number(1e3 * row.max_radial_error_m),
                        format_number(math.degrees(row.max_orientation_error_rad)),
                        f"{format_number(100 * row.freeze_margin)} ({joint})" if joint else "n/a",
                        _did(row),
                    ],
                }
            )
    return table


def band_figure(bands: Sequence[PlanBand], out_dir: Path):
    """Per plan: the door over the arc under each model (the nominal thick black, a model
    that does not open the door dashed, a stopped run's last sample marked x, the band
    shaded); one legend for all."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from doorlab.episode.metrics import door_opening
    from doorlab.episode.result import EpisodeResult
    from doorlab.studies.robustness import OPEN_THRESHOLD_DEG

    columns = 3
    rows_n = max(1, math.ceil(len(bands) / columns))
    fig, axes = plt.subplots(
        rows_n, columns, figsize=(4.2 * columns, 2.9 * rows_n + 0.9), sharey=True, squeeze=False
    )
    models = list(dict.fromkeys(m for band in bands for m, _ in band.rows if m))
    colors = {m: f"C{i % 10}" for i, m in enumerate(models)}
    handles = {}
    verdict = {"opens": "opens", "does_not_open": "does not open", "uncertain": "uncertain"}
    for ax, band in zip(axes.flat, bands, strict=False):
        curves = []
        for model, row in band.rows:
            try:
                result = EpisodeResult.load(Path(out_dir) / row.folder / "log.npz")
            except (OSError, ValueError, KeyError):
                continue
            if result.door_angles is None:
                continue
            t = result.t - result.arc_window[0]
            inside = (t >= 0) & (t <= result.arc_window[1] - result.arc_window[0])
            door = np.degrees(door_opening(result))
            color = "k" if not model else colors[model]
            style = {"lw": 2.0, "zorder": 3} if not model else {"lw": 0.9}
            (line,) = ax.plot(
                t[inside],
                door[inside],
                color=color,
                ls="-" if row.opened or not model else "--",
                **style,
            )
            handles.setdefault(model or "nominal", line)
            if row.status not in ("ok", "slipped"):  # stopped: where it stopped
                ax.plot(t[-1], door[-1], "x", color=color, ms=7, mew=2)
            if inside.any():
                curves.append((t[inside], door[inside]))
        if curves:
            grid = np.linspace(0.0, max(c[0][-1] for c in curves), 200)
            stacked = np.array([np.interp(grid, c[0], c[1], right=np.nan) for c in curves])
            with np.errstate(all="ignore"):
                ax.fill_between(
                    grid, np.nanmin(stacked, 0), np.nanmax(stacked, 0), color="0.88", zorder=0
                )
        ax.axhline(OPEN_THRESHOLD_DEG, color="0.4", lw=0.6, ls=":")
        ax.set(
            title=f"{band.title}: {verdict[band.verdict]}", xlabel="time since the arc's start [s]"
        )
        ax.grid(True, alpha=0.3)
    for ax in axes.flat[len(bands) :]:
        ax.set_visible(False)
    for ax in axes[:, 0]:
        ax.set_ylabel("left door opened [deg]")
    if handles:
        fig.legend(
            list(handles.values()),
            list(handles),
            loc="lower center",
            ncol=min(5, len(handles)),
            fontsize=7,
            frameon=False,
        )
    fig.tight_layout(rect=(0, 0.9 / (2.9 * rows_n + 0.9), 1, 1))
    return fig


def band_summary(bands: Sequence[PlanBand]) -> list[dict]:
    """summary.json's verdicts: per plan, the verdict, what it depends on, the band."""

    def finite(values: np.ndarray) -> list[float | None]:
        return [float(v) if math.isfinite(v) else None for v in values]

    return [
        {
            "controller": band.controller,
            "tuned": band.tuned,
            "tuning": ARM_TUNING.get(band.controller) if band.tuned else None,
            "verdict": band.verdict,
            "depends_on": list(band.depends_on),
            "models": [model for model, _ in band.rows],
            "runs": [row.case.run for _, row in band.rows],
            "opened": [row.opened for _, row in band.rows],
            "outcomes": [row.outcome for _, row in band.rows],
            "door_arc_end_deg": finite(band.values("door_arc_end_deg")),
            "max_radial_error_m": finite(band.values("max_radial_error_m")),
            "max_orientation_error_rad": finite(band.values("max_orientation_error_rad")),
            "freeze_margin": finite(band.values("freeze_margin")),
        }
        for band in bands
    ]
