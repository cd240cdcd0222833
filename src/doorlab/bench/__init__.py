"""``doorlab bench``: the benchmark card. Each controller opens the same N closed cupboards,
drawn from a distribution stated in the configuration (:mod:`doorlab.bench.distribution`), on
local processes or a Dask cluster through the sweep's runner (:mod:`doorlab.bench.runner`);
success defined once, and under robosuite's definition, each rate with its Wilson 95 %
interval (:mod:`doorlab.bench.measures`, :mod:`doorlab.bench.stats`); ``bench.json`` and a
self-contained ``index.html`` (:mod:`doorlab.bench.card`).

In Python: ``doorlab.bench.run_bench(["velocity", "examples/dls_controller.py:dls"], "out",
episodes=20)``. Running and the card (pandas) are imported on first use.
"""

_LAZY = {
    "run_bench": "runner",
    "bench_base": "runner",
    "BenchDistribution": "document",
    "load_distribution": "distribution",
    "plan_bench": "distribution",
    "wilson_interval": "stats",
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f"doorlab.bench.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'doorlab.bench' has no attribute {name!r}")


__all__ = sorted(_LAZY)
