"""Shared, session-cached problem-set runs for the grader's tests (not a conftest: import
the helpers explicitly, as with ``report_fixtures``).

:func:`solutions_run` writes a ``--solutions`` folder and runs the 2019 notebook's code cells in
it (three episodes; the last cell runs the full grader, reference episodes included);
:func:`reference` returns that grading's reference figures, which every other grading of the
session reuses (``reference=``), so the reference episodes are simulated once per session.
"""

from __future__ import annotations

import atexit
import functools
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from shared_cache import shared_folder, shared_text

from doorlab.pset.handout.folder import init_folder

NOTEBOOK_ENV = "DOORLAB_PSET5_NOTEBOOK"
"""The one setting the notebook tests need: the path of a copy of the 2019 notebook,
``robot_control/pset5_open_cabinet_door.ipynb`` of github.com/pangtao22/6-881-examples (or of
its text, with ``In [ ]:`` before each code cell). Its code is read at test time, never copied
into the project; without it those tests skip and say how to run them."""
NOTEBOOK_CELLS_TIMEOUT_S = 900
"""The notebook's cells: three episodes and a full grading (~1-2 min on a busy 2-core machine)."""


def notebook_path() -> Path | None:
    """The notebook the environment names (None when ``$DOORLAB_PSET5_NOTEBOOK`` is unset)."""
    value = os.environ.get(NOTEBOOK_ENV, "").strip()
    return Path(value).expanduser() if value else None


def _ipynb_code_cells(text: str) -> list[str]:
    """The code cells of an ``.ipynb`` (nbformat 4 JSON), in order, empty ones left out."""
    cells = []
    for cell in json.loads(text).get("cells", []):
        if cell.get("cell_type") == "code":
            source = cell.get("source", "")
            source = "".join(source) if isinstance(source, list) else source
            if source.strip():
                cells.append(source)
    return cells


def _code_cells(text: str) -> list[str]:
    """The notebook text's code cells: after each ``In [ ]:`` marker, the longest run of lines that
    parses as Python once IPython magics are removed (the prose that follows does not)."""
    cells = []
    for part in re.split(r"^In\s*\[\s*\]:\s*$", text, flags=re.M)[1:]:
        lines = part.strip("\n").splitlines()
        for k in range(len(lines), 0, -1):
            source = "\n".join(lines[:k])
            try:
                compile(strip_magics(source), "<cell>", "exec")
            except SyntaxError:
                continue
            if source.strip():
                cells.append(source)
            break
    return cells


def strip_magics(source: str) -> str:
    return "\n".join(line for line in source.splitlines() if not line.lstrip().startswith("%"))


def _adapt(source: str) -> str:
    """IPython magics removed; the standalone ``meshcat`` server cells replaced by Drake's
    Meshcat (documented in the folder's README)."""
    out = []
    for line in strip_magics(source).splitlines():
        if re.match(r"\s*import meshcat(\.geometry as g)?\s*$", line):
            continue
        if re.match(r"\s*vis = meshcat\.Visualizer\(\)\s*$", line):
            out.append("from manip_station_sim.manipulation_station_simulator import StartMeshcat")
            out.append("vis = StartMeshcat()")
            continue
        out.append(line.replace("vis.delete()", "vis.Delete()"))
    return "\n".join(out)


DRIVER = """
import json, sys, traceback
cells = json.load(open(sys.argv[1]))
namespace = {"__name__": "__main__"}
for i, source in enumerate(cells):
    print(f"--- cell {i}", flush=True)
    try:
        exec(compile(source, f"<notebook cell {i}>", "exec"), namespace)
    except BaseException:
        traceback.print_exc()
        sys.exit(10 + i)
print("--- all cells ran", flush=True)
log = namespace.get("iiwa_position_command_log")
if log is not None:
    facts = {"t": log.sample_times().tolist(), "t_plan": list(map(float, namespace["t_plan"]))}
    print("FACTS " + json.dumps(facts), flush=True)
"""


@functools.cache
def _root() -> Path:
    """A temporary folder for the session's problem-set runs, removed when the process exits."""
    root = Path(tempfile.mkdtemp(prefix="doorlab_pset_tests_"))
    atexit.register(shutil.rmtree, root, ignore_errors=True)
    return root


def notebook_cells() -> list[str]:
    """The 2019 notebook's code cells; skips the test (saying how to run it) when
    ``$DOORLAB_PSET5_NOTEBOOK`` is unset, fails it when it names no readable file."""
    path = notebook_path()
    if path is None:
        pytest.skip(
            f"needs the 2019 notebook: set {NOTEBOOK_ENV} to a copy of "
            "pset5_open_cabinet_door.ipynb (github.com/pangtao22/6-881-examples, "
            "robot_control/) or of its text (docs/development.md)"
        )
    try:
        text = path.read_text()
    except OSError as e:
        pytest.fail(f"{NOTEBOOK_ENV}={str(path)!r}: {e.strerror or e}")
    cells = _ipynb_code_cells(text) if path.suffix == ".ipynb" else _code_cells(text)
    if not cells:
        pytest.fail(f"{NOTEBOOK_ENV}={str(path)!r} holds no code cells")
    return cells


@functools.cache
def _solutions_run() -> tuple[Path, subprocess.CompletedProcess]:
    """The notebook's run (about half a minute), once per test run: the workers share it."""
    folder, text = shared_folder("pset_solutions", _run_notebook, _root() / "run")
    proc = subprocess.CompletedProcess(**json.loads(text))
    return folder / "solutions", proc


def _run_notebook(root: Path) -> str:
    """Writes ``root/solutions``, runs the notebook's cells in it; returns the process's
    ``args``, ``returncode``, ``stdout`` and ``stderr`` (JSON)."""
    folder = root / "solutions"
    init_folder(folder, solutions=True)
    cells_file = root / "cells.json"
    cells_file.write_text(json.dumps([_adapt(c) for c in notebook_cells()]))
    env = dict(os.environ, MPLBACKEND="Agg")
    # The notebook's last cell runs `python3 ./test_pset_5a.py`: python3 must be this interpreter.
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env["PYTHONPATH"] = str(folder)
    proc = subprocess.run(
        [sys.executable, "-c", DRIVER, str(cells_file)],
        cwd=folder,
        env=env,
        capture_output=True,
        text=True,
        timeout=NOTEBOOK_CELLS_TIMEOUT_S,
    )
    return json.dumps({k: getattr(proc, k) for k in ("args", "returncode", "stdout", "stderr")})


def solutions_run() -> tuple[Path, subprocess.CompletedProcess]:
    """A fresh ``--solutions`` folder in which the notebook's cells ran in order (once per
    test run, shared by the workers: read it, do not change it)."""
    notebook_cells()
    return _solutions_run()


@functools.cache
def _reference() -> str:
    return shared_text("pset_reference.json", _compute_reference)


def _compute_reference() -> str:
    if notebook_path() is not None:
        folder, _ = solutions_run()
        data = json.loads((folder / "test_results.json").read_text())
        return json.dumps(data["extra_data"]["reference"])
    from doorlab.pset.grading.grader import TESTS, grade

    folder = init_folder(_root() / "reference", solutions=True)
    episodes = [t.name for t in TESTS if "episode" in t.name]
    return json.dumps(grade(folder, only=episodes)["extra_data"]["reference"])


def reference() -> dict:
    """The reference episodes' figures (from the notebook cells' full grading when the
    notebook is given; else from a grading of the episodes), a fresh copy each call."""
    return json.loads(_reference())


def grade_in_thread(files, intake, supervisor) -> tuple:
    """``grade_taken(files, intake)`` with no reference, one job, under ``supervisor``, in a
    thread of its own, started. Returns (the thread, a dict that gets ``"error"``: the
    :class:`GradingError`'s text, if the grading raises one)."""
    import threading

    from doorlab.pset.grading.grader import GradingError, grade_taken

    outcome: dict = {}

    def run() -> None:
        try:
            grade_taken(files, intake, reference={}, jobs=1, supervisor=supervisor)
        except GradingError as e:
            outcome["error"] = str(e)

    thread = threading.Thread(target=run)
    thread.start()
    return thread, outcome
