"""The shipped examples work: the notebook executes cleanly, the example scenario is valid.

The notebook runs in a kernel started from THIS interpreter (``sys.executable -m
ipykernel_launcher``, through a kernelspec written to a temporary folder), so it sees the same
doorlab and pydrake as the tests, whatever kernelspecs the machine has installed.
"""

from __future__ import annotations

import json
import os
import re
import sys
from pathlib import Path

import pytest

import doorlab
from doorlab import Scenario, load_scenario

EXAMPLES_DIR = Path(__file__).resolve().parents[1] / "examples"
NOTEBOOK = EXAMPLES_DIR / "open_door.ipynb"
SCENARIO_YAML = EXAMPLES_DIR / "scenario.yaml"
NOTEBOOK_TIMEOUT_S = 300
"""Per-cell timeout; the whole notebook takes ~15-40 s (three episodes)."""
KERNEL_NAME = "doorlab-test-python"
EXPECTED_RUNS = 3
"""Rows of the notebook's metrics table (tasks 1-3)."""


def _kernel_manager(tmp_path: Path):
    """A KernelManager whose only kernelspec runs ``sys.executable -m ipykernel_launcher``."""
    from jupyter_client import KernelManager
    from jupyter_client.kernelspec import KernelSpecManager

    spec_dir = tmp_path / "kernels" / KERNEL_NAME
    spec_dir.mkdir(parents=True)
    spec = {
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "doorlab tests",
        "language": "python",
    }
    (spec_dir / "kernel.json").write_text(json.dumps(spec))
    specs = KernelSpecManager(kernel_dirs=[str(spec_dir.parent)], ensure_native_kernel=False)
    # the connection file in tmp_path: by default a tempfile in $TMPDIR, left there
    connection = str(tmp_path / "kernel-connection.json")
    return KernelManager(
        kernel_name=KERNEL_NAME, kernel_spec_manager=specs, connection_file=connection
    )


def _stream_text(cell) -> str:
    return "".join(o.get("text", "") for o in cell.outputs if o.output_type == "stream")


@pytest.mark.slow
def test_notebook_executes_without_errors(tmp_path, monkeypatch):
    """Every cell runs without error, the plots render as PNG, the metrics table has numbers."""
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")

    # The kernel inherits the environment: make this doorlab importable even without
    # `pip install -e .`, and keep matplotlib off any GUI.
    src = str(Path(doorlab.__file__).resolve().parents[1])
    monkeypatch.setenv(
        "PYTHONPATH", os.pathsep.join(p for p in (src, os.environ.get("PYTHONPATH", "")) if p)
    )
    monkeypatch.setenv("MPLBACKEND", "Agg")

    nb = nbformat.read(NOTEBOOK, as_version=4)
    assert all(not c.get("outputs") for c in nb.cells if c.cell_type == "code"), (
        "the notebook is shipped without stored outputs"
    )
    client = nbclient.NotebookClient(
        nb,
        km=_kernel_manager(tmp_path),
        timeout=NOTEBOOK_TIMEOUT_S,
        resources={"metadata": {"path": str(tmp_path)}},  # the kernel's working folder
    )
    client.execute()  # raises CellExecutionError on the first failing cell

    code_cells = [c for c in nb.cells if c.cell_type == "code"]
    errors = [o for c in code_cells for o in c.outputs if o.output_type == "error"]
    assert not errors, errors
    images = [o for c in code_cells for o in c.outputs if "image/png" in o.get("data", {})]
    assert len(images) >= 3 * EXPECTED_RUNS + 1  # 3 tracking plots per task + the door angle

    metrics_cells = [c for c in code_cells if "metrics" in c.metadata.get("tags", [])]
    assert len(metrics_cells) == 1
    assert metrics_cells[0] is code_cells[-1], "the metrics table is the last code cell"
    table = _stream_text(metrics_cells[0]).strip().splitlines()
    rows = [line for line in table if line.startswith("task ")]
    assert len(rows) == EXPECTED_RUNS, table
    for row in rows:
        numbers = re.findall(r"-?\d+\.\d+", row)
        assert len(numbers) >= 5, row  # radial max/rms, orientation, door opened, RTF


def test_example_scenario_is_the_default_impedance_closed_scenario():
    """examples/scenario.yaml validates and equals the defaults except controller and doors."""
    scenario = load_scenario(SCENARIO_YAML)
    assert scenario.controller == "impedance"
    assert scenario.doors == "closed"
    assert scenario == Scenario(controller="impedance", doors="closed")
