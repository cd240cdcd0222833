"""The Python API's reference: the package's parts (API_GROUPS), mkdocstrings blocks per
part, and a table of ``doorlab.__all__``."""

from __future__ import annotations

import ast
import importlib
import importlib.util
import inspect
import pkgutil
from pathlib import Path

from .text import _cell, _summary

API_GROUPS = {
    "configuration": (
        "Configuration, errors and constants",
        [
            "doorlab.config",
            "doorlab.config_checks",
            "doorlab.errors",
            "doorlab.constants",
            "doorlab.kuka",
        ],
    ),
    "runtime": ("Inputs, output folders, signals and processes", ["doorlab.runtime"]),
    "cell": ("The cell: models, station, the lab arm, the door", ["doorlab.cell"]),
    "control": ("Control laws and plans", ["doorlab.control"]),
    "episodes": (
        "Episodes: timeline, wiring, simulation, controllers, metrics",
        ["doorlab.episode"],
    ),
    "outputs": ("A run's outputs: folder, plots, replay, pages", ["doorlab.outputs"]),
    "studies": (
        "Studies: robustness, the original station, the former design",
        ["doorlab.studies"],
    ),
    "hardware": ("The real arm and the simulated driver", ["doorlab.hardware"]),
    "report": ("The report (doorlab report)", ["doorlab.report"]),
    "sweep": ("Sweeps (doorlab sweep)", ["doorlab.sweep"]),
    "bench": ("The benchmark card (doorlab bench)", ["doorlab.bench"]),
    "pset": ("The problem set (doorlab pset): its parts", ["doorlab.pset"]),
    "pset-rules": (
        "The problem set's rules: the graded tests, the assignment, a test's time",
        ["doorlab.pset.rules"],
    ),
    "pset-handout": (
        "What students get and run: the 2019 API, the folder, the course's settings",
        ["doorlab.pset.handout"],
    ),
    "pset-isolation": (
        "The student's code contained: intake, process, view, limits, channel, guard",
        ["doorlab.pset.isolation"],
    ),
    "pset-grading": (
        "The grader's judgement: supervisor, jobs, unit tests, episodes, answer key, results",
        ["doorlab.pset.grading"],
    ),
    "pset-classroom": (
        "A class over a semester: grade-all, regrades, feedback, Gradescope, the handout",
        ["doorlab.pset.classroom"],
    ),
    "command-line": ("The command line", ["doorlab.cli"]),
}
"""The API reference's pages, from the bottom of the package up (a module imports only from
its own group and the groups above it in this table: tests/test_imports.py): page -> (title,
modules); a package stands for its submodules but those of a group of their own (the
problem set's page holds its package's docstring, the map of its parts; each part has its
page). Every module of ``src/doorlab`` must be in exactly one group (else the build stops)."""


def package_modules(root: Path | None = None) -> list[str]:
    """Every module and package of ``doorlab`` (from the source tree, not imported)."""
    import doorlab

    root = root or Path(doorlab.__file__).parent
    names = ["doorlab"]
    for info in pkgutil.walk_packages([str(root)], prefix="doorlab."):
        names.append(info.name)
    return sorted(names)


def api_coverage() -> dict[str, str]:
    """module -> the API group that shows it; raises if a module is in none or in two."""
    shown: dict[str, str] = {}
    for group, (_, modules) in API_GROUPS.items():
        for module in modules:
            if module in shown:
                raise ValueError(f"{module} is in two API groups: {shown[module]}, {group}")
            shown[module] = group
    coverage = {}
    missing = []
    for module in package_modules():
        if module == "doorlab":
            continue
        owners = [m for m in shown if module == m or module.startswith(m + ".")]
        if not owners:
            missing.append(module)
        else:
            coverage[module] = shown[max(owners, key=len)]  # the most specific group
    if missing:
        raise ValueError(
            f"modules in no API group: {', '.join(missing)} (add them to API_GROUPS in "
            "docs/tools/doorlab_reference/api.py)"
        )
    return coverage


def api_markdown(group: str) -> str:
    """mkdocstrings blocks for one group's modules (a package with its submodules)."""
    api_coverage()
    if group not in API_GROUPS:
        raise ValueError(f"unknown API group {group!r}; valid: {', '.join(API_GROUPS)}")
    title, modules = API_GROUPS[group]
    out = [f"# {title}\n", "Modules: " + ", ".join(f"`{m}`" for m in modules) + ".\n"]
    grouped = [m for _, listed in API_GROUPS.values() for m in listed]
    for module in modules:
        is_package = (Path(importlib.util.find_spec(module).origin).name) == "__init__.py"
        out.append(f"::: {module}")
        if is_package and not any(m.startswith(module + ".") for m in grouped):
            out.append("    options:\n      show_submodules: true")
        out.append("")
    return "\n".join(out)


def packages_markdown() -> str:
    """The package's architecture: one row per API page, from the foundations up, with the
    first paragraph of its package's docstring (or the page's title) and its modules."""
    api_coverage()
    out = ["| part | what it holds |", "|---|---|"]
    for group, (title, modules) in API_GROUPS.items():
        first = importlib.import_module(modules[0])
        if len(modules) == 1 and hasattr(first, "__path__"):  # a sub-package
            names = sorted(
                m.rsplit(".", 1)[1]
                for m in package_modules()
                if m.startswith(modules[0] + ".")
                and m.count(".") == modules[0].count(".") + 1
                and not m.rsplit(".", 1)[1].startswith("_")  # not cli's __main__
            )
            part = f"[`{modules[0]}`]({group}.md)"
            text = f"{_summary(first)} *Modules:* {', '.join(names)}."
        else:  # modules at the top of the package
            part = f"[`doorlab`]({group}.md)"
            names = ", ".join(m.rsplit(".", 1)[1] for m in modules)
            text = f"{title}, at the package's top. *Modules:* {names}."
        out.append(f"| {_cell(part)} | {_cell(text)} |")
    return "\n".join(out) + "\n"


def _attribute_docstring(module: str, name: str) -> str:
    """The first line of the string literal that follows ``name = ...`` at the top of
    ``module`` (the convention this package documents its constants by), or ""."""
    source = Path(inspect.getsourcefile(importlib.import_module(module))).read_text()
    body = ast.parse(source).body
    for node, after in zip(body, body[1:], strict=False):
        targets = node.targets if isinstance(node, ast.Assign) else [getattr(node, "target", None)]
        if any(isinstance(t, ast.Name) and t.id == name for t in targets):
            if isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant):
                return str(after.value.value).strip().split("\n\n")[0].replace("\n", " ")
    return ""


def public_api_markdown() -> str:
    """A table of every name of ``doorlab.__all__``: where it is defined (linked to its
    documentation on the module pages) and its docstring's first line."""
    import doorlab

    out = ["| name | defined in | what |", "|---|---|---|"]
    for name in doorlab.__all__:
        value = getattr(doorlab, name)
        module = getattr(value, "__module__", None)
        if not isinstance(module, str) or not hasattr(value, "__qualname__"):
            module = doorlab._LAZY[name]  # a constant: its docstring follows it in its module
            summary = _attribute_docstring(module, name)
        else:
            summary = _summary(value)
        out.append(f"| [`{name}`][{module}.{name}] | `{module}` | {_cell(summary)} |")
    return "\n".join(out) + "\n"
