"""The docs' commands, run as a reader runs them: every block of README.md,
docs/getting-started.md and docs/guides/*.md, in the order the page gives them.

A page's blocks run in a folder of their own holding a copy of the repository's tracked files
(the clone's root, where the README's commands leave a reader), with this environment's venv
as ``.venv`` and its ``bin`` first on PATH (as ``source .venv/bin/activate`` does: the guides
call ``doorlab`` and ``dask`` bare). What a block may hold:

- ``bash``: each command (lines joined at a trailing ``\\``) runs through bash in that folder,
  its placeholders replaced by named values (:class:`Page`'s ``values``: SUBMISSION, EXPORT/,
  HOST, N); it must exit 0 unless the test names another code. A command that serves until
  stopped (:data:`SERVERS`: ``doorlab sim-driver``, ``dask scheduler``, ``dask worker``,
  ``mkdocs serve``) starts in the background, as in a terminal of its own, and is stopped with
  Ctrl-C (SIGINT) where the page says so (a comment ``# then Ctrl-C ...``) or at the page's end.
  A command that asks the reader (``doorlab run --hardware``: "Move the arm? [y/N]") gets the
  reader's answer on a terminal of its own.
- ``python``: the block runs as a script in that folder.
- ``yaml``: a sweep SPEC the page shows is loaded as one (``doorlab.sweep.load_spec``); other
  YAML is parsed.
- ``toml``: an excerpt of a pyproject.toml: parsed.
- no language: not a command (a layout, a table of text): listed, not run.

A block that cannot run here says why on the line before it, ``<!-- docs-test: skip (REASON)
-->``; one that another test runs as written says which, ``<!-- docs-test: run by
tests/FILE.py -->`` (the teaching guide's semester, the README's quick start, which .ci/run
runs exactly). Each block's time is recorded (:func:`report`).
"""

from __future__ import annotations

import atexit
import contextlib
import functools
import json
import os
import pty
import re
import select
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import realtime_priority
from realtime_host import page_in_real_time
from shared_cache import run_dir

ROOT = Path(__file__).resolve().parents[1]
PAGES = (
    "README.md",
    "docs/getting-started.md",
    *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs" / "guides").glob("*.md")),
)
"""The pages whose commands a reader is told to run."""
MARKER = re.compile(r"<!--\s*docs-test:\s*(skip|run by)\s*\(?(.*?)\)?\s*-->")
COMMAND_TIMEOUT_S = 900.0
"""The longest one command of a page may take [s] (the default report is the longest)."""
RESULTS = "docs_commands.jsonl"
"""In the run's folder: one line per block run (page, block, first command, seconds, how)."""


@dataclass(frozen=True)
class Block:
    """One fenced block of a page."""

    page: str  # its path from the repository's root
    number: int  # 1, 2, ... in the page's order
    line: int  # the line of its opening fence (1-based)
    lang: str  # the fence's info string ("bash", "python", "yaml", "toml" or "")
    text: str
    skip: str | None = None  # why it cannot run here
    run_by: str | None = None  # the test that runs it as written

    @property
    def first(self) -> str:
        lines = [line for line in self.text.splitlines() if line.strip()]
        return lines[0].strip() if lines else ""


def blocks(page: str) -> list[Block]:
    """The page's fenced blocks, in order, with their markers."""
    lines = (ROOT / page).read_text().splitlines()
    out: list[Block] = []
    i = 0
    while i < len(lines):
        fence = re.match(r"^(\s*)```(\w*)\s*$", lines[i])
        if not fence:
            i += 1
            continue
        end = i + 1
        while end < len(lines) and not re.match(r"^\s*```\s*$", lines[end]):
            end += 1
        above = []  # the comment lines right above the fence (blank lines between)
        for j in range(i - 1, -1, -1):
            if lines[j].strip().startswith("<!--") and lines[j].strip().endswith("-->"):
                above.append(lines[j])
            elif lines[j].strip():
                break
        marker = next(filter(None, map(MARKER.search, above)), None)
        kind, why = (marker.group(1), marker.group(2).strip()) if marker else (None, None)
        out.append(
            Block(
                page=page,
                number=len(out) + 1,
                line=i + 1,
                lang=fence.group(2),
                text="\n".join(line[len(fence.group(1)) :] for line in lines[i + 1 : end]),
                skip=why if kind == "skip" else None,
                run_by=why if kind == "run by" else None,
            )
        )
        i = end + 1
    return out


def commands(text: str) -> list[str]:
    """A bash block's commands and comments, a line each (continuations joined)."""
    out, pending = [], ""
    for raw in text.splitlines():
        line = raw.rstrip()
        if line.endswith("\\"):
            pending += line[:-1] + " "
            continue
        line = (pending + line).strip()
        pending = ""
        if line:
            out.append(line)
    return out


@dataclass(frozen=True)
class Server:
    """A command that serves until stopped, and how to tell it is ready."""

    pattern: str  # a regex on the command
    ready: Callable[[subprocess.Popen, dict], bool]  # (process, the page's values) -> ready
    paced: bool = False  # paced to the wall clock: real-time priority where it can be had


def _port_open(port: int) -> bool:
    with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), 0.5):
        return True
    return False


def _http_ok(url: str) -> bool:
    with contextlib.suppress(OSError), urllib.request.urlopen(url, timeout=2) as answer:
        return answer.status == 200
    return False


SERVERS = (
    Server(r"^doorlab sim-driver\b", lambda p, v: time.sleep(2.0) is None, paced=True),
    Server(r"^dask scheduler\b", lambda p, v: _port_open(8786)),
    Server(r"^dask worker\b", lambda p, v: time.sleep(3.0) is None),
    Server(r"^(\.venv/bin/)?mkdocs serve\b", lambda p, v: _http_ok("http://127.0.0.1:8000/")),
)
PACED = (r"^doorlab run --hardware\b", r"^doorlab identify\b")
"""Clients of the arm's bus, paced to the wall clock (real-time priority where it can be had)."""
ASKS = {r"^doorlab run --hardware\b(?!.*--yes)": ("Move the arm? [y/N]", "y")}
"""Commands that ask the reader: (the question, the reader's answer)."""


@dataclass
class Outcome:
    """What one block did."""

    block: Block
    how: str  # "ran", "skipped: ...", "run by ...", "not a command"
    seconds: float = 0.0
    outputs: list[str] = field(default_factory=list)  # each command's stdout and stderr


class Page:
    """A page's blocks run in order in a workspace of their own (see the module).

    Args:
        page: The page's path from the repository's root.
        work: An empty folder for the workspace.
        values: Placeholder -> value (a regex-free word: ``SUBMISSION``, ``EXPORT/``, ...).
        env: Extra environment variables (``LCM_DEFAULT_URL``: the page's own bus).
        codes: Command regex -> the exit code the page says it gives (default 0).
    """

    def __init__(
        self,
        page: str,
        work: Path,
        values: dict[str, str] | None = None,
        env: dict[str, str] | None = None,
        codes: dict[str, int] | None = None,
    ):
        self.page = page
        self.root = work
        self.values = dict(values or {})
        self.codes = dict(codes or {})
        self.servers: list[tuple[str, subprocess.Popen, Path]] = []
        if not (self.root / "README.md").is_file():  # a test may have put inputs there
            copy_checkout(self.root)
        bin_dir = Path(sys.executable).parent
        self.env = {
            **os.environ,
            "VIRTUAL_ENV": str(bin_dir.parent),
            "PATH": f"{bin_dir}:{os.environ.get('PATH', '/usr/bin:/bin')}",
            **(env or {}),
        }
        self.env.pop("PYTHONPATH", None)

    def substitute(self, command: str) -> str:
        for name, value in self.values.items():
            command = re.sub(rf"(?<!\w){re.escape(name)}(?!\w)", value, command)
        return command

    def run_blocks(self, check: Callable[[Block, Outcome, Path], None] | None = None):
        """Runs every block; ``check(block, outcome, workspace)`` after each one that ran.
        Returns the outcomes."""
        outcomes = []
        try:
            for block in blocks(self.page):
                outcome = self.run_block(block)
                outcomes.append(outcome)
                _record(outcome)
                if check is not None and outcome.how == "ran":
                    check(block, outcome, self.root)
        finally:
            self.stop_servers()
        return outcomes

    def run_block(self, block: Block) -> Outcome:
        if block.skip is not None:
            return Outcome(block, f"skipped: {block.skip}")
        if block.run_by is not None:
            return Outcome(block, f"run by {block.run_by}")
        start = time.monotonic()
        outcome = Outcome(block, "ran")
        if block.lang in ("bash", "sh", "console"):
            for command in commands(block.text):
                if command.startswith("#"):
                    if re.search(r"\bCtrl-C\b", command):
                        self.stop_servers()
                    continue
                outcome.outputs.append(self.run_command(self.substitute(command)))
        elif block.lang == "python":
            script = self.root / f".docs_block_{block.number}.py"
            script.write_text(block.text)
            outcome.outputs.append(self.run_command(f"python {script.name}"))
        elif block.lang == "yaml":
            _check_yaml(block, self.root)
        elif block.lang == "toml":  # a pyproject.toml excerpt: it parses
            import tomllib  # Python 3.11+ (the project's tests run on 3.11 and later)

            tomllib.loads(block.text)
        else:
            return Outcome(block, "not a command")
        outcome.seconds = time.monotonic() - start
        return outcome

    def run_command(self, command: str) -> str:
        """Runs one command (a server in the background); returns what it printed."""
        for server in SERVERS:
            if re.search(server.pattern, command):
                return self.start_server(command, server)
        expected = next((c for p, c in self.codes.items() if re.search(p, command)), 0)
        preexec = realtime_priority.preexec() if _matches(PACED, command) else None
        asks = next((a for p, a in ASKS.items() if re.search(p, command)), None)
        if asks is not None:
            code, text = _answering(command, self.root, self.env, *asks, preexec=preexec)
        else:
            done = subprocess.run(
                ["bash", "-o", "pipefail", "-c", command],
                cwd=self.root,
                env=self.env,
                capture_output=True,
                text=True,
                timeout=COMMAND_TIMEOUT_S,
                preexec_fn=preexec,
            )
            code, text = done.returncode, done.stdout + done.stderr
        assert code == expected, (
            f"{self.page}: `{command}` exited {code} (the page expects {expected}):\n{text[-4000:]}"
        )
        return text

    def start_server(self, command: str, server: Server) -> str:
        log = self.root / f".server_{len(self.servers)}.log"
        with open(log, "w") as sink:
            process = subprocess.Popen(
                ["bash", "-c", f"exec {command}"],
                cwd=self.root,
                env=self.env,
                stdout=sink,
                stderr=subprocess.STDOUT,
                start_new_session=True,
                preexec_fn=realtime_priority.preexec() if server.paced else None,
            )
        self.servers.append((command, process, log))
        deadline = time.monotonic() + 300  # mkdocs serve builds the site first
        while not server.ready(process, self.values):
            assert process.poll() is None, f"`{command}` ended: {log.read_text()[-3000:]}"
            assert time.monotonic() < deadline, f"`{command}` not ready: {log.read_text()[-3000:]}"
            time.sleep(0.2)
        return f"(started: {command})"

    def stop_servers(self) -> None:
        """Ctrl-C to each server, as in its terminal; killed if it does not end."""
        while self.servers:
            command, process, log = self.servers.pop()
            if process.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(process.pid, signal.SIGINT)
                try:
                    process.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    os.killpg(process.pid, signal.SIGKILL)
                    process.wait()


def _matches(patterns, command: str) -> bool:
    return any(re.search(p, command) for p in patterns)


def _answering(command, cwd, env, question, answer, preexec=None) -> tuple[int, str]:
    """Runs ``command`` on a terminal of its own, typing ``answer`` after ``question``."""
    parent, child = pty.openpty()
    process = subprocess.Popen(
        ["bash", "-c", command],
        cwd=cwd,
        env=env,
        stdin=child,
        stdout=child,
        stderr=child,
        start_new_session=True,
        preexec_fn=preexec,
    )
    os.close(child)
    seen, answered = b"", False
    deadline = time.monotonic() + COMMAND_TIMEOUT_S
    while time.monotonic() < deadline:
        ready, _, _ = select.select([parent], [], [], 0.5)
        if ready:
            try:
                chunk = os.read(parent, 65536)
            except OSError:  # the terminal closed: the command ended
                break
            if not chunk:
                break
            seen += chunk
            if not answered and question.encode() in seen:
                os.write(parent, (answer + "\n").encode())
                answered = True
        elif process.poll() is not None:
            break
    os.close(parent)
    code = process.wait(timeout=60)
    return code, seen.decode(errors="replace")


def _check_yaml(block: Block, workspace: Path) -> None:
    import yaml

    data = yaml.safe_load(block.text)
    if isinstance(data, dict) and "axes" in data:  # a sweep SPEC, beside the example scenario
        from doorlab.sweep import load_spec

        path = workspace / "examples" / f".docs_spec_{block.number}.yaml"
        path.write_text(block.text)
        load_spec(path)


def copy_checkout(dest: Path, after_readme: bool = True) -> None:
    """The repository's tracked files (as a clone holds them) into ``dest``, and this
    environment's venv as ``dest/.venv``; ``after_readme``: with what the README's quick
    start leaves there besides, its main job's folder ``doorlab_out/velocity_closed/`` (a
    page whose command writes that folder again fails as it would for a reader)."""
    listed = subprocess.run(
        ["git", "-C", str(ROOT), "ls-files", "-z"], capture_output=True, check=False
    )
    if listed.returncode == 0:
        names = [n for n in listed.stdout.decode().split("\0") if n]
    else:  # not a git checkout: the files but the outputs and the venv
        skip = {".venv", ".git", "site", "doorlab_out", "doorlab_report", "doorlab_sweep"}
        names = [
            str(p.relative_to(ROOT))
            for p in ROOT.rglob("*")
            if p.is_file() and not set(p.relative_to(ROOT).parts) & skip
        ]
    for name in names:
        source = ROOT / name
        if not source.is_file():
            continue  # removed in the work tree
        target = dest / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(source, target)
    (dest / ".venv").symlink_to(Path(sys.executable).parent.parent)
    if after_readme:
        shutil.copytree(_main_job(), dest / "doorlab_out" / "velocity_closed", symlinks=True)


@functools.cache
def _main_job() -> Path:
    """The README's main job's folder (``doorlab run``), made once per process."""
    out = Path(tempfile.mkdtemp(prefix="doorlab_docs_main_job_")) / "velocity_closed"
    atexit.register(shutil.rmtree, out.parent, True)
    done = subprocess.run(
        [str(Path(sys.executable).parent / "doorlab"), "run", "--out", str(out), "--no-replay"],
        capture_output=True,
        text=True,
        timeout=COMMAND_TIMEOUT_S,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return out


def rehearsed(
    page: str, tmp_path: Path, realtime: Callable, lcm_url: str, what: str
) -> tuple[Path, list[Outcome]]:
    """A page whose blocks hold a rehearsal on the arm's bus (``lcm_url``, the test's own), run
    in real time (the ``realtime`` fixture) in ``tmp_path/clone``, or once more in
    ``tmp_path/again`` when the host stopped the first run's processes
    (:func:`realtime_host.page_in_real_time`; ``what``: what failed, for the skip). Returns
    the workspace that ran and the outcomes."""

    def run(work: Path) -> tuple[Path, list[Outcome]]:
        return work, Page(page, work, env={"LCM_DEFAULT_URL": lcm_url}).run_blocks()

    folders = [tmp_path / "clone", tmp_path / "again"]
    return page_in_real_time(realtime, run, folders, what)


def _record(outcome: Outcome) -> None:
    folder = run_dir()
    if folder is None:
        return
    row = {
        "page": outcome.block.page,
        "block": outcome.block.number,
        "line": outcome.block.line,
        "first": outcome.block.first,
        "how": outcome.how,
        "seconds": round(outcome.seconds, 1),
    }
    with open(folder / RESULTS, "a") as f:
        f.write(json.dumps(row) + "\n")


def report() -> list[dict]:
    """What the run's docs tests recorded: a row per block."""
    folder = run_dir()
    path = None if folder is None else folder / RESULTS
    if path is None or not path.is_file():
        return []
    return [json.loads(line) for line in path.read_text().splitlines()]


@contextlib.contextmanager
def page_workspace(tmp_path: Path) -> Iterator[Path]:
    """An empty folder for a page's workspace."""
    work = tmp_path / "clone"
    work.mkdir()
    yield work
