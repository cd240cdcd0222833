"""What doorlab does on the host around the science: bounded inputs (YAML files, argument
values), the output folders it writes (staged beside the target, a manifest of what it wrote,
``--force``'s rule), signals and worker processes, local or Dask executors, headless Chromium
for PDFs.

It imports nothing of doorlab but :mod:`doorlab.errors` (and ``doorlab.__version__``):
everything else may use it.
"""
