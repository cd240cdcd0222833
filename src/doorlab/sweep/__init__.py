"""Sweeps: any scenario field over a grid or random samples, locally or on a Dask cluster.

``doorlab sweep SPEC.yaml`` and :func:`run_sweep` run every combination of controllers, door
states and axis values (:mod:`doorlab.sweep.spec`) through one executor
(:mod:`doorlab.executor`), collect one row per run (:mod:`doorlab.sweep.results`) and write
the sweep page (:mod:`doorlab.sweep.page`).
"""

from doorlab.sweep.execution import run_one, run_sweep
from doorlab.sweep.results import read_table
from doorlab.sweep.spec import Axis, PlannedRun, SweepSpec, load_spec, parse_spec, plan_runs

__all__ = [
    "Axis",
    "PlannedRun",
    "SweepSpec",
    "load_spec",
    "parse_spec",
    "plan_runs",
    "read_table",
    "run_one",
    "run_sweep",
]
