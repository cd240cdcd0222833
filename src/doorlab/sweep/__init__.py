"""Sweeps: any scenario field over a grid or random samples, locally or on a Dask cluster.

``doorlab sweep SPEC.yaml`` and :func:`run_sweep` run every combination of controllers, door
states and axis values (:mod:`doorlab.sweep.spec`) through one executor
(:mod:`doorlab.runtime.executor`), collect one row per run (:mod:`doorlab.sweep.results`) and write
the sweep page (:mod:`doorlab.sweep.page`). The runner itself,
:func:`doorlab.sweep.execution.execute_runs`, also runs ``doorlab bench``'s episodes
(:mod:`doorlab.bench`).

Running and the table (pandas) are imported on first use, so reading and checking a SPEC
(:func:`load_spec`) costs no pandas import: a refused SPEC stays small and fast.
"""

from doorlab.sweep.spec import Axis, PlannedRun, SweepSpec, load_spec, parse_spec, plan_runs

_LAZY = {"run_one": "execution", "run_sweep": "execution", "read_table": "results"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f"doorlab.sweep.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'doorlab.sweep' has no attribute {name!r}")


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
