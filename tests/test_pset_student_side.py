"""The student's side of the problem-set folder: Jupyter comes with the ``pset`` extra, the
notebook shows each figure once, ``InterpolateYawAngle`` returns what its docstring says."""

from __future__ import annotations

import importlib.util
import math
import subprocess
import sys
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest

import doorlab
from doorlab.pset.handout.folder import STUDENT_FILES, init_folder, render_folder
from doorlab.pset.handout.notebook import NOTEBOOK_NAME

NOTEBOOK_TIMEOUT_S = 300
"""Per cell; the cells below plot synthetic logs (no simulation), a few seconds each."""

_SYNTHETIC_LOGS = """\
# Not in the folder's notebook: logs like RunSimulation's (every 0.01 s for 22 s), synthetic.
from pydrake.systems.primitives import VectorLog
from open_left_door import p_L7Q, q_home

def _log(offset):
    log = VectorLog(7)
    for t in np.arange(0.0, 22.0, 0.01):
        log.AddData(t, q_home + 0.01 * np.sin(t + offset + np.arange(7)))
    return log

iiwa_position_command_log, iiwa_position_measured_log = _log(0.0), _log(0.1)
iiwa_velocity_estimated_log, iiwa_external_torque_log = _log(0.2), _log(0.3)"""


def _images(cell) -> int:
    return sum("image/png" in o.get("data", {}) for o in cell.outputs)


@pytest.mark.slow
def test_the_notebooks_plot_cells_show_each_figure_once(tmp_path, monkeypatch):
    """The folder's setup cell, its tracking-plot cell and its three joint-log cells run in a
    real kernel in a stub folder, on synthetic logs: every plotting cell shows one figure
    (a plot function that returned its figure showed it twice: plt.show() and the cell's
    value)."""
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    from test_examples import _kernel_manager

    folder = init_folder(tmp_path / "pset")
    shipped = nbformat.read(folder / NOTEBOOK_NAME, as_version=4)
    code = [c for c in shipped.cells if c.cell_type == "code"]
    setup = next(c for c in code if "%matplotlib inline" in c.source)
    tracking = next(c for c in code if "def plot_arc_tracking" in c.source)
    logs = [c for c in code if c.source.startswith(("PlotJointLog(", "PlotIiwaPositionLog("))]
    assert len(logs) == 3, [c.source for c in code]
    nb = nbformat.v4.new_notebook(metadata=shipped.metadata)
    nb.cells = [setup, nbformat.v4.new_code_cell(_SYNTHETIC_LOGS), tracking, *logs]
    monkeypatch.setenv("PYTHONPATH", str(folder))
    client = nbclient.NotebookClient(
        nb,
        km=_kernel_manager(tmp_path),
        timeout=NOTEBOOK_TIMEOUT_S,
        resources={"metadata": {"path": str(folder)}},
    )
    client.execute()
    errors = [o for c in nb.cells for o in c.outputs if o.output_type == "error"]
    assert not errors, errors
    assert [_images(c) for c in nb.cells] == [0, 0, 1, 1, 1, 1], [
        [o.output_type for o in c.outputs] for c in nb.cells
    ]


def _load(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_InterpolateYawAngle_returns_the_RotationMatrix_its_docstring_names(tmp_path):
    from pydrake.math import RollPitchYaw, RotationMatrix

    folder = init_folder(tmp_path / "pset")
    old = _load(folder / "open_left_door.py", "pset_open_left_door_under_test")
    doc = old.InterpolateYawAngle.__doc__
    assert "a RotationMatrix" in doc
    for tau in (0.0, 0.37, 1.0):
        R = old.InterpolateYawAngle(tau)
        assert isinstance(R, RotationMatrix)
        yaw = -(old.angle_end - old.theta0_hinge) * tau
        expected = RollPitchYaw(0.0, 3 * math.pi / 4, yaw).ToRotationMatrix()
        np.testing.assert_allclose(R.matrix(), expected.matrix(), atol=1e-12)


@pytest.mark.slow
def test_the_pset_extra_gives_the_jupyter_notebook_the_folder_readme_runs():
    pset = [r for r in metadata.requires("doorlab") or [] if 'extra == "pset"' in r]
    assert any(r.startswith("notebook") for r in pset), pset
    readme = render_folder(solutions=False)["README.md"]
    # The install line works from the handout alone (doorlab is not on PyPI): the wheel.
    assert f'pip install "./doorlab-{doorlab.__version__}-py3-none-any.whl[pset]"' in readme
    assert 'pip install "doorlab[pset]"' not in readme
    assert "doorlab report" not in readme  # doorlab's own answers to the graded questions
    assert f"jupyter notebook {NOTEBOOK_NAME}" in readme
    for rel in STUDENT_FILES:
        assert f"`{rel}`" in readme  # what to submit
    # The extra is part of the test environment (doorlab[test] needs doorlab[pset]).
    jupyter = Path(sys.executable).with_name("jupyter")
    proc = subprocess.run(
        [str(jupyter), "notebook", "--version"], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    assert int(proc.stdout.strip().split(".")[0]) >= 7


def test_the_stub_files_are_the_files_a_submission_may_replace():
    """Every stub lives in STUDENT_FILES, and each of those files holds one at least, so the
    autograder takes exactly the files students edit."""
    stubs = render_folder(solutions=False)
    with_stubs = {rel for rel, text in stubs.items() if "raise NotImplementedError" in text}
    assert with_stubs == set(STUDENT_FILES)
