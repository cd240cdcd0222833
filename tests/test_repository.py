"""The repository names no place of one machine: what a clone holds reads the same on every
machine (issue 34). A result file records which code it measured by commit
(``benchmarks/common.py``'s ``source_label``), a test finds its checkout from ``__file__``."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# A place of one machine: a home folder with its user's name, a workspace folder, or a
# checkout of doorlab elsewhere (a path into some ``src/doorlab`` that is not an installed
# package's). Generic places (/tmp, /usr, /root's pyenv as an example of where a standard
# library may live, /proc, /sys/fs/cgroup) are not one machine's.
MACHINE_PATH = re.compile(
    r"(?<![\w.])("
    r"/home/[A-Za-z0-9_][\w.-]*/"  # a user's home
    r"|/Users/[A-Za-z0-9_][\w.-]*/"
    r"|/work/[\w.-]+"  # a workspace
    r"|/[\w./-]*/src/doorlab(?=[/\"'\s]|$)(?<!site-packages/src/doorlab)"
    r")"
)


def _tracked() -> list[Path]:
    out = subprocess.run(
        ["git", "-C", str(ROOT), "ls-files", "-z"], capture_output=True, check=True
    ).stdout
    return [ROOT / name for name in out.decode().split("\0") if name]


def _findings(paths: list[Path], checkout: str) -> list[str]:
    found = []
    for path in paths:
        try:
            text = path.read_text()
        except (UnicodeDecodeError, IsADirectoryError, FileNotFoundError):
            continue  # a binary (a figure) or a file removed in the work tree
        for number, line in enumerate(text.splitlines(), 1):
            hit = MACHINE_PATH.search(line)
            if hit is None and checkout not in line:
                continue
            where = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path
            found.append(f"{where}:{number}: {hit.group(0) if hit else checkout}")
    return found


def test_no_file_names_a_path_of_one_machine():
    """No tracked file holds this checkout's absolute path, a home folder, a workspace folder
    or a path into another checkout's ``src/doorlab``."""
    checkout = str(ROOT)
    if checkout.count("/") < 2:  # a checkout at /x: its path is too short to look for
        checkout = "\0"
    here = Path(__file__).resolve()  # this file's samples below are such paths
    assert _findings([p for p in _tracked() if p.resolve() != here], checkout) == []


def test_the_search_finds_such_paths(tmp_path: Path):
    """The search is not blind: each kind of path it forbids is found in a file that has it,
    and the generic places beside them are not."""
    sample = tmp_path / "sample.txt"
    bad = [
        "clones=['/work/main']",
        '"this": "/tmp/wt26_main/src/doorlab/__init__.py"',
        "cd /home/alice/doorlab",
        "see /Users/bob/code",
        f"root = {tmp_path}/x",
    ]
    good = [
        "/root/.pyenv/versions/3.11.7/lib/python3.11",
        "/usr/lib/python3/dist-packages",
        "/tmp/doorlab_grade_*",
        "/venv/lib/python3.11/site-packages/doorlab/pset",
        "src/doorlab/pset/isolation/bwrap_root.py",
    ]
    sample.write_text("\n".join(bad + good) + "\n")
    found = _findings([sample], str(tmp_path))
    assert [int(f.split(":")[1]) for f in found] == list(range(1, len(bad) + 1)), found


def _quick_start() -> list[str]:
    """The README's quick-start commands: the lines of the first bash block under its
    "Quick start" heading that are not comments."""
    text = (ROOT / "README.md").read_text()
    section = text.split("\n## Quick start\n", 1)[1].split("\n## ", 1)[0]
    block = re.search(r"```bash\n(.*?)```", section, re.S)
    assert block, "README.md: no bash block under 'Quick start'"
    lines = [line.strip() for line in block.group(1).splitlines()]
    return [line for line in lines if line and not line.startswith("#")]


def test_ci_runs_the_readme_s_quick_start_as_written():
    """.ci/run runs the README's two commands, each exactly as written, in the README's
    order: what CI passes is what a new user runs (the main job's run included)."""
    commands = _quick_start()
    assert len(commands) == 2 and commands[0].endswith("doorlab run"), commands
    assert commands[1].endswith("-m pytest"), commands
    ci = [line.strip() for line in (ROOT / ".ci" / "run").read_text().splitlines()]
    where = [ci.index(command) if command in ci else None for command in commands]
    assert None not in where, f".ci/run lacks a README command as written: {commands}"
    assert where == sorted(where), "the README's commands run out of order in .ci/run"
    # Getting started repeats the quick start: the same commands.
    started = (ROOT / "docs" / "getting-started.md").read_text()
    assert all(command in started.splitlines() for command in commands)


def test_every_default_output_folder_is_ignored_by_git():
    """What a command writes where the reader did not say (its default output folder, in
    the clone's root, where the README's commands run) is not offered to git as new files."""
    import argparse

    from doorlab.cli.parser import build_parser

    defaults = {"doorlab_out"}  # doorlab run's doorlab_out/<controller>_<doors>

    def walk(parser: argparse.ArgumentParser) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub in action.choices.values():
                    walk(sub)
            elif action.dest == "out" and isinstance(action.default, Path):
                defaults.add(action.default.parts[0])

    walk(build_parser())
    assert len(defaults) >= 3, defaults  # run, report, sweep at least
    ignored = subprocess.run(
        ["git", "-C", str(ROOT), "check-ignore", *[f"{name}/x" for name in sorted(defaults)]],
        capture_output=True,
        text=True,
    ).stdout.split()
    assert sorted(ignored) == sorted(f"{name}/x" for name in defaults), (defaults, ignored)
