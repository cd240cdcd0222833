"""The problem set's experiment set, run in parallel, and one self-contained HTML page answering it.

- :mod:`doorlab.report.experiments`: the experiment set as data (:data:`EXPERIMENTS`, the
  robustness grid, :class:`RunRecord`);
- :mod:`doorlab.report.runner`: :func:`run_report` (the runs through
  :mod:`doorlab.runtime.executor`, locally or on a Dask cluster, then the page);
- :mod:`doorlab.report.folders`: reading run folders (metrics, logs, trackings);
- :mod:`doorlab.report.context`, :mod:`doorlab.report.answers` and
  :mod:`doorlab.report.closed_door`: the problem set's six questions
  and answers GENERATED from the measured metrics; :mod:`doorlab.report.robustness_page`:
  the robustness section (every controller against the cupboard's yaw error);
- :mod:`doorlab.report.page`: ``index.html`` from the Jinja2 templates in
  ``doorlab/templates`` (shared with the sweep page), ``summary.json`` and ``figures/``.

:func:`build_page` only READS run folders (``metrics.json``, ``log.npz``, ``scenario.yaml``),
so a page can be rebuilt without simulating.
"""

from doorlab.outputs.pages import SIGNIFICANT_DIGITS, format_number, metric_unit
from doorlab.report.answers import QUESTIONS, TASK_TITLES
from doorlab.report.experiments import (
    EXPERIMENTS,
    IK_KNOTS,
    ArmCase,
    RobustnessCase,
    RunRecord,
    make_arm_cases,
    make_experiments,
    make_robustness_cases,
)
from doorlab.report.folders import CONTROLLER_COLORS, discover_runs
from doorlab.report.page import build_page
from doorlab.report.runner import run_report

__all__ = [
    "CONTROLLER_COLORS",
    "EXPERIMENTS",
    "IK_KNOTS",
    "QUESTIONS",
    "SIGNIFICANT_DIGITS",
    "TASK_TITLES",
    "ArmCase",
    "RobustnessCase",
    "RunRecord",
    "build_page",
    "discover_runs",
    "format_number",
    "make_arm_cases",
    "make_experiments",
    "make_robustness_cases",
    "metric_unit",
    "run_report",
]
