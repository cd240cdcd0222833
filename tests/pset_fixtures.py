"""Shared, session-cached problem-set runs for the grader's tests (not a conftest: import
the helpers explicitly, as with ``report_fixtures``).

:func:`solutions_run` writes a ``--solutions`` folder and runs the seed notebook's code cells in
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

from doorlab.pset.folder import init_folder

SEED = Path(__file__).resolve().parents[2] / "shared" / "seed" / "000_f5f6c01857f13f46.txt"
"""The seed notebook as text (read at test time; its code is not copied into the project)."""
if not SEED.exists():
    SEED = Path("/work/shared/seed/000_f5f6c01857f13f46.txt")
SEED_CELLS_TIMEOUT_S = 900
"""The seed's cells: three episodes and a full grading (~1-2 min on a busy 2-core machine)."""


def _code_cells(text: str) -> list[str]:
    """The seed's code cells: after each ``In [ ]:`` marker, the longest run of lines that
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
        exec(compile(source, f"<seed cell {i}>", "exec"), namespace)
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


def seed_cells() -> list[str]:
    """The seed notebook's code cells (skips the test if the seed is not there)."""
    if not SEED.exists():
        pytest.skip(f"the seed notebook is not at {SEED}")
    return _code_cells(SEED.read_text())


@functools.cache
def _solutions_run() -> tuple[Path, subprocess.CompletedProcess]:
    folder = _root() / "solutions"
    init_folder(folder, solutions=True)
    cells_file = _root() / "cells.json"
    cells_file.write_text(json.dumps([_adapt(c) for c in seed_cells()]))
    env = dict(os.environ, MPLBACKEND="Agg")
    # The seed's last cell runs `python3 ./test_pset_5a.py`: python3 must be this interpreter.
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env["PYTHONPATH"] = str(folder)
    proc = subprocess.run(
        [sys.executable, "-c", DRIVER, str(cells_file)],
        cwd=folder,
        env=env,
        capture_output=True,
        text=True,
        timeout=SEED_CELLS_TIMEOUT_S,
    )
    return folder, proc


def solutions_run() -> tuple[Path, subprocess.CompletedProcess]:
    """A fresh ``--solutions`` folder in which the seed's cells ran in order (once)."""
    seed_cells()
    return _solutions_run()


@functools.cache
def _reference() -> str:
    if SEED.exists():
        folder, _ = solutions_run()
        data = json.loads((folder / "test_results.json").read_text())
        return json.dumps(data["extra_data"]["reference"])
    from doorlab.pset.grader import TESTS, grade

    folder = init_folder(_root() / "reference", solutions=True)
    episodes = [t.name for t in TESTS if "episode" in t.name]
    return json.dumps(grade(folder, only=episodes)["extra_data"]["reference"])


def reference() -> dict:
    """The reference episodes' figures (from the seed cells' full grading when the seed is
    there; else from a grading of the episodes), a fresh copy each call."""
    return json.loads(_reference())
