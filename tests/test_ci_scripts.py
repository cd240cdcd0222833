"""CI's newest-Drake stage (.ci/newest_drake.sh, issue 45) finds its Python >= 3.12 on PATH or
under pyenv, and says in one line when there is none."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / ".ci" / "newest_drake.sh"


def fake_python(path: Path, version: tuple[int, int]) -> Path:
    """An executable that answers the script's version check as Python ``version`` would."""
    path.parent.mkdir(parents=True, exist_ok=True)
    new_enough = 0 if version >= (3, 12) else 1
    path.write_text(f"#!/bin/sh\nexit {new_enough}\n")
    path.chmod(0o755)
    return path


def run(tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    """The script with a PATH of fakes first (every name it tries: 3.11) and a HOME of its own."""
    bin_dir = tmp_path / "bin"
    for name in ("python3.12", "python3.13", "python3.14", "python3"):
        fake_python(bin_dir / name, (3, 11))
    env = {**os.environ, "PATH": f"{bin_dir}:/usr/bin:/bin", "HOME": str(tmp_path / "home")}
    return subprocess.run(
        ["bash", str(SCRIPT), *args], env=env, capture_output=True, text=True, timeout=60
    )


def test_without_a_python_312_it_fails_in_one_line(tmp_path):
    proc = run(tmp_path, "--which")
    assert proc.returncode == 1 and proc.stdout == ""
    assert proc.stderr.count("\n") == 1 and "no Python >= 3.12" in proc.stderr


def test_it_takes_the_oldest_pyenv_python_of_312_or_later(tmp_path):
    versions = tmp_path / "home" / ".pyenv" / "versions"
    fake_python(versions / "3.11.7" / "bin" / "python", (3, 11))
    fake_python(versions / "3.13.0" / "bin" / "python", (3, 13))
    chosen = fake_python(versions / "3.12.1" / "bin" / "python", (3, 12))
    proc = run(tmp_path, "--which")
    assert (proc.returncode, proc.stdout.strip()) == (0, str(chosen)), proc.stderr
