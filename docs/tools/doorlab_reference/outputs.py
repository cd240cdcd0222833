"""Output files' reference: a run folder's files, metrics.json's keys, log.npz's channels,
the adaptive plan's log."""

from __future__ import annotations

import dataclasses
import typing

from .scenario import _type_name
from .text import _cell, _summary, _unit_and_text, attribute_comments, docstring_attributes

RUN_FILES = {
    "metrics.json": "the run's figures: the keys below ([metrics.json](#metricsjson))",
    "log.npz": "named, time-stamped logs: the channels below ([log.npz](#lognpz)); reload with "
    "`doorlab.EpisodeResult.load`",
    "replay.html": "a self-contained 3-D replay (a Meshcat recording): open it in a browser "
    "(`--no-replay` skips it)",
    "scenario.yaml": "the exact scenario that produced the run",
    "hinge_estimate_error.png": "plans that estimate the hinge (`adaptive`): the distance of the "
    "running hinge estimate from the true axis over time",
}
"""Files of a run folder besides the plots of :data:`doorlab.outputs.plots.RUN_PLOT_NAMES` and the
manifest (a test compares a real run folder with this page)."""


def run_files_markdown() -> str:
    """The files of a run folder: the plots from doorlab.outputs.plots, the rest from RUN_FILES."""
    from doorlab.outputs import plots
    from doorlab.runtime.folders import MANIFEST_NAME

    out = ["| file | what |", "|---|---|"]
    for name, text in RUN_FILES.items():
        if name.endswith(".png"):
            continue
        out.append(f"| `{name}` | {_cell(text)} |")
    for name in plots.RUN_PLOT_NAMES:
        function = getattr(plots, f"plot_{name}", None)
        if function is None or not _summary(function):
            raise ValueError(
                f"run plot {name!r} has no documented doorlab.outputs.plots.plot_{name}"
            )
        out.append(f"| `{name}.png` | {_cell(_summary(function))} |")
    for name, text in RUN_FILES.items():
        if name.endswith(".png"):
            out.append(f"| `{name}` | {_cell(text)} |")
    out.append(
        f"| `{MANIFEST_NAME}` | the path, size and SHA-256 of every file doorlab wrote there "
        "(see [output folders](#output-folders-force-and-interruptions)) |"
    )
    return "\n".join(out) + "\n"


def _dataclass_table(cls: type, texts: dict[str, str], header: str) -> str:
    hints = typing.get_type_hints(cls)
    out = [f"| {header} | type | what |", "|---|---|---|"]
    missing = []
    for f in dataclasses.fields(cls):
        text = texts.get(f.name, "")
        if not text:
            missing.append(f.name)
        out.append(f"| `{f.name}` | {_cell(_type_name(hints[f.name]))} | {_cell(text)} |")
    if missing:
        raise ValueError(
            f"{cls.__module__}.{cls.__qualname__}: undocumented fields {', '.join(missing)} "
            "(document them in its docstring's Attributes: or with a comment on the field)"
        )
    return "\n".join(out) + "\n"


def metrics_markdown() -> str:
    """The keys of metrics.json: the fields of DoorMetrics."""
    from doorlab.episode.metrics import DoorMetrics

    texts = {**attribute_comments(DoorMetrics), **docstring_attributes(DoorMetrics)}
    return _dataclass_table(DoorMetrics, texts, "key")


def log_channels_markdown() -> str:
    """The channels of log.npz: the fields of EpisodeResult."""
    from doorlab.episode.result import EpisodeResult

    return _dataclass_table(EpisodeResult, docstring_attributes(EpisodeResult), "channel")


def plan_log_markdown(module: str = "adaptive") -> str:
    """A plan's per-tick channels (doorlab.control.<module>.LOG_CHANNELS: the adaptive plan's,
    or ``diffik``'s)."""
    import importlib

    plan = importlib.import_module(f"doorlab.control.{module}")
    comments = attribute_comments(plan, names=["LOG_CHANNELS"])
    out = ["| channel | unit | what |", "|---|---|---|"]
    previous = ""
    for name in plan.LOG_CHANNELS:
        unit, text = _unit_and_text(comments.get(name, ""))
        if not text and name[:-2] == previous[:-2] and name[-2:] == "_y":
            text = f"with `{previous}`"  # x, y pairs: the comment sits on the x
        out.append(f"| `plan_log.{name}` | {unit} | {_cell(text)} |")
        previous = name
    return "\n".join(out) + "\n"
