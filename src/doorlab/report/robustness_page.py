"""The report's robustness section: every controller against the cupboard's yaw error.

Built from the robustness runs' folders only (``metrics.json``; ``log.npz`` and
``scenario.yaml`` of the adaptive runs for the hinge-estimate plot): the table, the figures
and the findings come from :func:`doorlab.studies.robustness.robustness_section`, so every number
on it is a measured one.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from pathlib import Path

from markupsafe import Markup

from doorlab.outputs.pages import Figures
from doorlab.report.experiments import RobustnessCase, RunRecord


def _metrics(case: RobustnessCase, record: RunRecord) -> dict:
    """The run's metrics.json, or a failed run's minimal metrics when it cannot be read."""
    try:
        return json.loads((Path(record.run_dir) / "metrics.json").read_text())
    except (OSError, ValueError):
        status = record.status if record.status not in ("ok", "unknown") else "missing"
        return {"controller": case.controller, "status": status}


def _adaptive_episode(case: RobustnessCase, record: RunRecord):
    """(episode, TRUE door geometry) of an adaptive run with logs, else None."""
    from pydrake.common.yaml import yaml_load_typed

    from doorlab.cell.geometry import true_door_geometry
    from doorlab.config import Scenario
    from doorlab.episode.result import EpisodeResult

    folder = Path(record.run_dir)
    if case.controller != "adaptive" or not (folder / "log.npz").is_file():
        return None
    try:
        result = EpisodeResult.load(folder / "log.npz")
        yaml_path = folder / "scenario.yaml"
        text = yaml_path.read_text() if yaml_path.is_file() else result.scenario_yaml
        scenario = yaml_load_typed(schema=Scenario, data=text)
        if "hinge_x" not in result.plan_log:
            return None
        return result, true_door_geometry(scenario)
    except (OSError, ValueError, KeyError, RuntimeError):
        return None


def _markdown_rows(table: str) -> tuple[list[str], list[list[str]]]:
    """(headers, rows of cells) of a Markdown table as :func:`robustness_table` writes it."""
    lines = [line.strip().strip("|").split("|") for line in table.splitlines()]
    headers = [cell.strip() for cell in lines[0]]
    return headers, [[cell.strip() for cell in line] for line in lines[2:]]


def robustness_context(
    grid: Sequence[tuple[RobustnessCase, RunRecord]], out_dir: Path, figures: Figures
) -> dict:
    """What ``report.html.j2`` shows in its robustness section.

    Args:
        grid: (case, its run) per cell, in (controller, yaw error) order.
        out_dir: The report folder (links to the runs are relative to it).
        figures: The page's figures (the two figures are saved and embedded).

    Returns:
        {"yaws", "controllers", "threshold", "headers", "rows", "figures", "findings"}.
    """
    from doorlab.studies.robustness import OPEN_THRESHOLD_DEG, robustness_section, row_from_metrics

    rows = [row_from_metrics(_metrics(case, record), case.yaw_error_rad) for case, record in grid]
    adaptive = {}
    for case, record in grid:
        episode = _adaptive_episode(case, record)
        if episode is not None:
            adaptive[f"yaw error {math.degrees(case.yaw_error_rad):+g} deg"] = episode
    section = robustness_section(rows, adaptive)
    headers, cells = _markdown_rows(section.table_markdown)
    table_rows = []
    for (case, record), row, line in zip(grid, rows, cells, strict=True):
        table_rows.append(
            {
                "run": case.run,
                "folder": os.path.relpath(record.run_dir, out_dir),
                "css": "" if row.opened else "warn",
                "cells": line,
            }
        )
    yaws = sorted({math.degrees(case.yaw_error_rad) for case, _ in grid})
    embedded = figures.embed(
        "robustness",
        section.figures["robustness"],
        "Left: the door's rotation at the arc's end against the cupboard's yaw error (x: not "
        f"opened, i.e. below {OPEN_THRESHOLD_DEG:g} deg, handle lost or a failed run). Right: "
        "the peak |external joint torque| during the arc [N m], log scale.",
    )
    if adaptive:
        embedded += figures.embed(
            "hinge_convergence",
            section.figures["hinge_convergence"],
            "The adaptive plan's hinge estimate against the TRUE hinge over the arc, one line "
            "per yaw error [mm], log scale (no line until its fit is trusted).",
        )
    return {
        "yaws": ", ".join(f"{y:+g}" for y in yaws),
        "controllers": ", ".join(dict.fromkeys(case.controller for case, _ in grid)),
        "threshold": f"{OPEN_THRESHOLD_DEG:g}",
        "headers": headers,
        "rows": table_rows,
        "figures": Markup(embedded),
        "adaptive_plot": bool(adaptive),
        "findings": list(section.findings),
    }
