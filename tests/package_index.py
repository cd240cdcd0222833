"""The tests that install from the package index (a handout's wheel, the autograder image):
whether the index answers, and a fresh virtual environment to install into.

They reuse pip's cache (pip's default: nothing here disables it) and skip, saying why, when
the index cannot be reached; no other test needs the network.
"""

from __future__ import annotations

import functools
import os
import subprocess
import sys
from pathlib import Path

import pytest

INSTALL_TIMEOUT_S = 1500
"""One ``pip install`` of drake, numpy, matplotlib (and Jupyter for a handout): about a
minute with pip's cache warm, a few on a slow link."""


@functools.cache
def _index_problem() -> str | None:
    """None if pip reaches the package index (as configured here), else why not."""
    try:
        proc = subprocess.run(  # drake: only the index has it (no local wheel here)
            [sys.executable, "-m", "pip", "index", "versions", "drake"],
            capture_output=True,
            text=True,
            timeout=60,
        )
    except subprocess.TimeoutExpired:
        return "pip could not reach the package index within 60 s"
    if proc.returncode != 0 or "drake" not in proc.stdout:
        lines = [x for x in proc.stderr.strip().splitlines() if not x.startswith("WARNING")]
        return f"pip cannot reach the package index ({lines[-1] if lines else 'no answer'})"
    return None


def require_index() -> None:
    """Skips the test, with the reason, when the package index cannot be reached."""
    problem = _index_problem()
    if problem is not None:
        pytest.skip(f"needs the package index to install doorlab's dependencies: {problem}")


def fresh_venv(path: Path) -> Path:
    """A new virtual environment (with pip) at ``path``; returns its python."""
    subprocess.run([sys.executable, "-m", "venv", str(path)], check=True)
    return path / "bin" / "python"


def pip_install(python: Path, *args: str, cwd: Path | None = None, compile: bool = True) -> None:
    """``python -m pip install ARGS`` (pip's cache reused); fails the test with pip's tail.

    ``compile=False``: ``--no-compile``, no ``.pyc`` written for the thousands of modules of
    drake, matplotlib and Jupyter; Python compiles what it imports. For a test that is not
    about the installed tree's files."""
    flags = [] if compile else ["--no-compile"]
    proc = subprocess.run(
        [str(python), "-m", "pip", "install", "--quiet", *flags, *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=INSTALL_TIMEOUT_S,
    )
    if proc.returncode != 0:
        pytest.fail(f"pip install {' '.join(args)} failed:\n{proc.stderr[-3000:]}")


def clean_environment(venv: Path, home: Path | None = None) -> dict[str, str]:
    """The environment of a command in ``venv``: its bin first on PATH, nothing of the test
    environment's Python (PYTHON*, VIRTUAL_ENV), Jupyter's own folders under ``home``."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "PYTEST"))}
    env.pop("VIRTUAL_ENV", None)
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    env["MPLBACKEND"] = "Agg"
    if home is not None:
        for name, sub in (
            ("JUPYTER_CONFIG_DIR", "config"),
            ("JUPYTER_DATA_DIR", "data"),
            ("JUPYTER_RUNTIME_DIR", "runtime"),
            ("IPYTHONDIR", "ipython"),
            ("MPLCONFIGDIR", "mpl"),
        ):
            (home / sub).mkdir(parents=True, exist_ok=True)  # else each falls back to a tempdir
            env[name] = str(home / sub)
        env["JUPYTER_PATH"] = ""
    return env
