"""Running the ``doorlab`` command as a user would, for the hostile-input tests (issue 19).

:func:`run_doorlab` starts ``python -m doorlab.cli.entry ARGS`` (what the console script runs) in
a new session (its own process group, so a signal goes to it and its workers, as Ctrl-C in
a terminal does), through a small launcher process that waits for it with ``os.wait4``: the
child's peak resident memory (``ru_maxrss``) is then its own. (A pytest process that forks
it directly would seed the child's ``ru_maxrss`` with its own, far larger, resident size: Linux
counts the address space the child replaces at exec.) Each child gets its own HOME, TMPDIR
and working folder.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import doorlab

SRC_DIR = Path(doorlab.__file__).resolve().parents[1]
MAX_STDERR_BYTES = 10_000
"""The acceptance bound on what a refusal or an interruption prints."""
REFUSAL_S = 5.0
"""The acceptance bound on the CPU time of a refusal, interpreter start included [s] (its work,
counted whatever else the host runs: a loaded host stretches its wall time, not this)."""
MAX_REFUSAL_RSS_MB = 300.0
"""The acceptance bound on the peak memory of a refused sweep or config."""

_LAUNCHER = r"""
import json, os, signal, subprocess, sys
argv, report, umask = json.loads(sys.argv[1]), sys.argv[2], int(sys.argv[3])
def ignore(signum, frame):  # a handler, not SIG_IGN: the child must start with the defaults
    pass
for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
    signal.signal(signum, ignore)
if umask >= 0:
    os.umask(umask)
child = subprocess.Popen(argv)
while True:
    try:
        _, status, usage = os.wait4(child.pid, 0)
        break
    except InterruptedError:
        continue
with open(report, "w") as f:
    facts = {"code": os.waitstatus_to_exitcode(status), "maxrss_kb": usage.ru_maxrss}
    json.dump({**facts, "cpu_s": usage.ru_utime + usage.ru_stime}, f)
"""


@dataclass
class Outcome:
    """How a ``doorlab`` command ended.

    Attributes:
        code: Its exit code (negative: killed by that signal).
        stdout, stderr: What it printed.
        wall_s: From start to exit [s] (after the signal, for :func:`interrupt_doorlab`).
        peak_rss_mb: Its peak resident memory [MB] (``ru_maxrss`` of the process itself).
        cpu_s: The CPU time it (and the children it waited for) used [s]: what it did, whatever
            else the host was doing.
    """

    code: int
    stdout: str
    stderr: str
    wall_s: float
    peak_rss_mb: float
    cpu_s: float = float("nan")


def environment(home: Path) -> dict[str, str]:
    """The child's environment: doorlab importable, its own HOME and TMPDIR, no display."""
    tmp = home / "tmp"
    tmp.mkdir(parents=True, exist_ok=True)
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTEST", "COV_"))}
    env.update(
        PYTHONPATH=os.pathsep.join(p for p in (str(SRC_DIR), env.get("PYTHONPATH", "")) if p),
        HOME=str(home),
        TMPDIR=str(tmp),
        MPLBACKEND="Agg",
        MPLCONFIGDIR=str(home / ".mpl"),
        PYTHONDONTWRITEBYTECODE="1",
    )
    return env


def start_doorlab(
    argv: list[str], *, cwd: Path, home: Path, umask: int | None = None
) -> tuple[subprocess.Popen, Path]:
    """Starts ``doorlab ARGV`` in a new session; returns the launcher and its report file."""
    report = home / f"wait4-{time.monotonic_ns()}.json"
    command = [sys.executable, "-m", "doorlab.cli.entry", *argv]
    process = subprocess.Popen(
        [
            sys.executable,
            "-c",
            _LAUNCHER,
            json.dumps(command),
            str(report),
            str(-1 if umask is None else umask),
        ],
        cwd=cwd,
        env=environment(home),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    return process, report


def finish(process: subprocess.Popen, report: Path, *, timeout: float, start: float) -> Outcome:
    """Waits for a started command (killing its group past ``timeout``) and reads its end."""
    try:
        stdout, stderr = process.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        stdout, stderr = process.communicate()
        message = f"doorlab did not end within {timeout} s; stderr: {stderr[-2000:]}"
        raise AssertionError(message) from None
    wall = time.monotonic() - start
    data = json.loads(report.read_text())
    report.unlink()
    return Outcome(data["code"], stdout, stderr, wall, data["maxrss_kb"] / 1024.0, data["cpu_s"])


def run_doorlab(
    argv: list[str], *, cwd: Path, home: Path, timeout: float = 120.0, umask: int | None = None
) -> Outcome:
    """Runs ``doorlab ARGV`` to its end (see the module docstring)."""
    start = time.monotonic()
    process, report = start_doorlab(argv, cwd=cwd, home=home, umask=umask)
    return finish(process, report, timeout=timeout, start=start)


def interrupt_doorlab(
    argv: list[str],
    signum: int,
    *,
    cwd: Path,
    home: Path,
    when: Callable[[], bool],
    timeout: float = 120.0,
    settle_s: float = 0.0,
) -> Outcome:
    """Starts ``doorlab ARGV``, waits until ``when()`` holds (then ``settle_s`` more), sends
    ``signum`` to its process group, and waits for it; ``wall_s`` counts from the signal."""
    process, report = start_doorlab(argv, cwd=cwd, home=home)
    deadline = time.monotonic() + timeout
    while not when():
        if process.poll() is not None:
            out, err = process.communicate()
            raise AssertionError(f"doorlab ended before the signal: {out[-1000:]} {err[-2000:]}")
        if time.monotonic() > deadline:
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
            raise AssertionError("the moment to send the signal never came")
        time.sleep(0.02)
    time.sleep(settle_s)
    start = time.monotonic()
    os.killpg(process.pid, signum)
    return finish(process, report, timeout=timeout, start=start)


def leftovers(*folders: Path) -> list[Path]:
    """Staging folders, their ``.old`` twins and temporary files doorlab left anywhere under
    ``folders`` (hidden ones included)."""
    found = []
    for folder in folders:
        for path in folder.rglob("*"):
            name = path.name
            if ".partial" in name or name.endswith((".tmp", ".probe")) or "doorlab_run_" in name:
                found.append(path)
    return found


def assert_clean_exit(outcome: Outcome, code: int, *, lines: int | None = None) -> None:
    """The acceptance checks on any exit: its code, no traceback (nor an exception Python
    ignored at exit), stderr under 10 kB."""
    assert outcome.code == code, (outcome.code, outcome.stderr[-3000:])
    assert "Traceback" not in outcome.stderr + outcome.stdout, outcome.stderr[-3000:]
    assert "Exception ignored" not in outcome.stderr, outcome.stderr[-3000:]  # issue 25
    assert len(outcome.stderr.encode()) < MAX_STDERR_BYTES, len(outcome.stderr)
    if lines is not None:
        assert len(outcome.stderr.strip().splitlines()) == lines, outcome.stderr


def assert_refused(outcome: Outcome, *needles: str, memory: bool = False) -> None:
    """A refusal: exit 2, one line naming ``needles``, within 5 s (and 300 MB)."""
    assert_clean_exit(outcome, 2, lines=1)
    for needle in needles:
        assert needle in outcome.stderr, (needle, outcome.stderr)
    assert outcome.cpu_s < REFUSAL_S, (outcome.cpu_s, outcome.wall_s)
    if memory:
        assert outcome.peak_rss_mb < MAX_REFUSAL_RSS_MB, outcome.peak_rss_mb


class User:
    """A user's machine: a home folder (HOME, TMPDIR inside) and a working folder."""

    def __init__(self, root: Path) -> None:
        self.home = root / "home"
        self.work = root / "work"
        self.home.mkdir()
        self.work.mkdir()

    def run(self, *argv: str, **kwargs):
        return run_doorlab(list(argv), cwd=self.work, home=self.home, **kwargs)

    def clean(self) -> bool:
        """No staging folder, .old twin or temporary file anywhere, TMPDIR empty."""
        return not leftovers(self.work, self.home) and not any((self.home / "tmp").iterdir())
