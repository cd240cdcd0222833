"""The site's reference, generated from the code: a MkDocs hook and the Markdown it writes.

A page asks for a generated block with a marker on a line of its own (modules are doorlab's)::

    <!-- doorlab:cli -->            every command and option of cli.parser.build_parser()
    <!-- doorlab:scenario -->       every field of config.Scenario
    <!-- doorlab:scenario-yaml -->  the default scenario as YAML
    <!-- doorlab:exit-codes -->     outputs.runs.EXIT_CODES and the signals' codes
    <!-- doorlab:run-files -->      what a run folder holds
    <!-- doorlab:metrics -->        the keys of metrics.json (episode.metrics.DoorMetrics)
    <!-- doorlab:log-channels -->   the channels of log.npz (episode.result.EpisodeResult)
    <!-- doorlab:plan-log -->       the adaptive plan's own log (control.adaptive.LOG_CHANNELS)
    <!-- doorlab:public-api -->     mkdocstrings blocks for every name of doorlab.__all__
    <!-- doorlab:packages -->       the package's parts, foundations first (API_GROUPS)
    <!-- doorlab:api GROUP -->      mkdocstrings blocks for the modules of API_GROUPS[GROUP]
    <!-- doorlab:figure T/NAME -->  a figure of docs/figures with the command that made it
    <!-- doorlab:figure-text T/NAME -->  a text the figure script kept (a run's summary)

:func:`on_page_markdown` replaces the markers when MkDocs builds (``hooks:`` in mkdocs.yml), so
a new CLI option, scenario field, exit code, run file or module appears without editing a page.
Descriptions come from where the code keeps them: an option's ``help``, the comment on a
scenario field (its unit is the first ``[...]`` in it, as the team's convention writes units),
a dataclass's Google-style ``Attributes:``, a plot function's docstring. A field without a
description, a status without a meaning or a module in no API group stops the build with a
message saying what to add.

Print one block without MkDocs: ``python docs/tools/reference.py cli`` (or any marker's name).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import importlib
import inspect
import io
import pkgutil
import re
import signal
import sys
import textwrap
import tokenize
import typing
from pathlib import Path

MARKER = re.compile(r"^<!-- doorlab:([a-z-]+)(?: ([\w./-]+))? -->[ \t]*$", re.M)
"""A generated block's marker: ``<!-- doorlab:NAME [ARG] -->`` on a line of its own."""

STATUS_MEANINGS = {
    "ok": "the run finished; the folder holds its figures",
    "usage": "bad input (unknown option or value, invalid or over-budget config or SPEC, an "
    "output folder that exists without `--force`, holds files doorlab did not write, or is not "
    "writable, a scheduler that cannot be reached): one line on stderr, nothing written",
    "slipped": "the handle left the gripper (time in `metrics.json`)",
    "speed_limit": "a joint exceeded its data-sheet speed",
    "diverged": "the physics failed or the state became non-finite",
    "ik_failed": "no IK solution (knot and residual in `metrics.json`)",
    "driver_lost": "`--hardware`: no status from the arm's driver within `--wait` (nothing "
    "written), or none for 50 ms during the run (commanding stopped, the folder written)",
    "safety_stop": "a command broke a safety limit and was not sent (limit, joint and time in "
    "`metrics.json`; `--hardware`, or `station.safety.enabled` in simulation)",
}
"""What each status of :data:`doorlab.outputs.runs.EXIT_CODES` means (a new status without an entry
here stops the build)."""

RUN_FILES = {
    "metrics.json": "the run's figures: the keys below ([metrics.json](#metricsjson))",
    "log.npz": "named, time-stamped logs: the channels below ([log.npz](#lognpz)); reload with "
    "`doorlab.EpisodeResult.load`",
    "replay.html": "a self-contained 3-D replay (a Meshcat recording): open it in a browser "
    "(`--no-replay` skips it)",
    "scenario.yaml": "the exact scenario that produced the run",
    "hinge_estimate_error.png": "plans that estimate the hinge (`adaptive`): the distance of the "
    "running hinge estimate from the true axis over time",
}
"""Files of a run folder besides the plots of :data:`doorlab.outputs.plots.RUN_PLOT_NAMES` and the
manifest (a test compares a real run folder with this page)."""

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
    "pset": ("The problem set and its grader (doorlab pset)", ["doorlab.pset"]),
    "command-line": ("The command line", ["doorlab.cli"]),
}
"""The API reference's pages, from the bottom of the package up (a module imports only from
its own group and the groups above it in this table: tests/test_imports.py): page -> (title,
modules); a package stands for its submodules. Every module of ``src/doorlab`` must be in
exactly one group (else the build stops)."""

UNIT = re.compile(r"\[([^\]\[,]+)\]")
"""A unit in a comment: the first ``[...]`` without a comma (``[0, 1]`` is a range)."""


# ---------------------------------------------------------------------------------------------
# Comments and docstrings


def _clean(text: str) -> str:
    """Docstring text as Markdown: Sphinx roles and double backticks become code spans."""
    text = re.sub(r":(?:mod|func|class|data|meth|attr|exc|obj):`~?([^`]+)`", r"`\1`", text)
    return text.replace("``", "`")


def _cell(text: str) -> str:
    """Text for one Markdown table cell: one line, pipes escaped, and ``<``, ``>`` outside
    code spans written as entities (``<controller>`` is text, not an HTML tag)."""
    parts = " ".join(_clean(text).split()).replace("|", "\\|").split("`")
    for i in range(0, len(parts), 2):  # outside backticks
        parts[i] = parts[i].replace("<", "&lt;").replace(">", "&gt;")
    return "`".join(parts)


def attribute_comments(obj: object, names: typing.Iterable[str] | None = None) -> dict[str, str]:
    """The comments of a class's annotated fields, or of a module constant's tuple items.

    A field's comment is the block of comment lines right above it plus the comment at the end
    of its line(s). Pass ``names`` (a constant's name in a module) to read the comments at the
    end of the lines of that tuple's string items instead.

    Returns:
        name -> comment text (without ``#``), for every commented field or item.
    """
    source = textwrap.dedent(inspect.getsource(obj))
    comments: dict[int, tuple[str, bool]] = {}  # line -> (text, the line holds only it)
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type == tokenize.COMMENT:
            own_line = token.line.strip().startswith("#")
            comments[token.start[0]] = (token.string.lstrip("#").strip(), own_line)
    tree = ast.parse(source)
    out: dict[str, str] = {}
    if names is not None:  # a module's tuple constant: one comment per item
        wanted = set(names)
        for node in ast.walk(tree):
            if isinstance(node, ast.Assign) and isinstance(node.value, ast.Tuple):
                if not any(isinstance(t, ast.Name) and t.id in wanted for t in node.targets):
                    continue
                for item in node.value.elts:
                    if isinstance(item, ast.Constant) and item.lineno in comments:
                        out[str(item.value)] = comments[item.lineno][0]
        return out
    (body,) = [n for n in tree.body if isinstance(n, ast.ClassDef)][:1]
    for node in body.body:
        if not (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)):
            continue
        lead, line = [], node.lineno - 1
        while line in comments and comments[line][1]:
            lead.insert(0, comments[line][0])
            line -= 1
        trail = [
            comments[n][0]
            for n in range(node.lineno, node.end_lineno + 1)
            if n in comments and not comments[n][1]
        ]
        text = " ".join(lead + trail).strip()
        if text:
            out[node.target.id] = text
    return out


def docstring_attributes(cls: type) -> dict[str, str]:
    """The ``Attributes:`` section of a Google-style class docstring: name -> description."""
    doc = inspect.getdoc(cls) or ""
    match = re.search(r"^Attributes:\n((?:[ \t]+.*\n?|\n)*)", doc, flags=re.M)
    if not match:
        return {}
    section = textwrap.dedent(match.group(1))
    out: dict[str, str] = {}
    for entry in re.split(r"\n(?=\S)", section.strip()):
        name, _, text = entry.partition(":")
        for each in name.split(","):
            out[each.strip()] = " ".join(text.split())
    return out


def _summary(obj: object) -> str:
    """The first paragraph of an object's docstring, as one line."""
    doc = inspect.getdoc(obj) or ""
    return " ".join(doc.split("\n\n")[0].split())


def _unit_and_text(comment: str) -> tuple[str, str]:
    """(unit, description) of a field's comment: a leading ``[unit]`` is taken off the text."""
    match = UNIT.search(comment)
    unit = match.group(1).strip() if match else ""
    text = comment
    if match and match.start() == 0:
        text = comment[match.end() :].strip()
    return unit, text


def _expand_choices(text: str, module: object) -> str:
    """Names of the module's tuples of strings (``one of CONTROLLERS``) spelled out."""

    def spell(match: re.Match) -> str:
        value = getattr(module, match.group(0), None)
        if isinstance(value, tuple) and value and all(isinstance(v, str) for v in value):
            return ", ".join(f"`{v}`" for v in value)
        return match.group(0)

    return re.sub(r"\b[A-Z][A-Z0-9_]{2,}\b", spell, text)


# ---------------------------------------------------------------------------------------------
# The scenario


class FieldDoc(typing.NamedTuple):
    """One scenario field as the reference shows it."""

    name: str  # dotted name, e.g. station.inner_loop.kq
    type: str
    default: str
    unit: str
    text: str
    section: str  # dotted name of the dataclass that holds it ("" for Scenario itself)
    is_section: bool  # a nested dataclass (documented in its own section)


def _type_name(hint: object) -> str:
    if isinstance(hint, type) and not typing.get_args(hint):
        return hint.__name__
    text = str(hint).replace("typing.", "").replace("numpy.", "")
    return text.replace("NoneType", "None")


def _yaml_value(value: object) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:.6g}" if len(repr(value)) > 10 else repr(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_yaml_value(v) for v in value) + "]"
    return str(value)


def scenario_fields(cls: type | None = None, prefix: str = "") -> list[FieldDoc]:
    """Every field of the scenario (nested dataclasses first as a row, then their fields)."""
    if cls is None:
        from doorlab.config import Scenario

        cls = Scenario
    module = sys.modules[cls.__module__]
    comments = attribute_comments(cls)
    hints = typing.get_type_hints(cls)
    rows: list[FieldDoc] = []
    nested: list[tuple[type, str]] = []
    for f in dataclasses.fields(cls):
        dotted = f"{prefix}{f.name}"
        hint = hints[f.name]
        if dataclasses.is_dataclass(hint):
            rows.append(FieldDoc(dotted, hint.__name__, "", "", _summary(hint), prefix, True))
            nested.append((hint, dotted + "."))
            continue
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        unit, text = _unit_and_text(comments.get(f.name, ""))
        text = _expand_choices(text, module)
        rows.append(
            FieldDoc(dotted, _type_name(hint), _yaml_value(default), unit, text, prefix, False)
        )
    for hint, sub in nested:
        rows += scenario_fields(hint, sub)
    return rows


def _anchor(dotted: str) -> str:
    return "scenario" if not dotted else "scenario-" + dotted.replace(".", "-").replace("_", "-")


def scenario_markdown(cls: type | None = None) -> str:
    """Tables of every field of the scenario (or of ``cls``), one section per dataclass."""
    if cls is None:
        from doorlab.config import Scenario

        cls = Scenario
    rows = scenario_fields(cls)
    missing = [r.name for r in rows if not r.text and not r.is_section]
    if missing:
        raise ValueError(
            "scenario fields without a description (write a comment on the field in "
            f"src/doorlab/config.py, units first as [unit]): {', '.join(missing)}"
        )
    classes = {"": cls}
    for r in rows:
        if r.is_section:
            owner = classes[r.section]
            classes[r.name + "."] = typing.get_type_hints(owner)[r.name.rsplit(".", 1)[-1]]
    first = {}  # depth first: a section right after its parent's fields
    for i, r in enumerate(rows):
        first.setdefault(r.section, i)
    out = []
    for section, cls in sorted(classes.items(), key=lambda item: first.get(item[0], 0)):
        dotted = section.rstrip(".")
        title = f"`{dotted}`" if dotted else "The scenario (top level)"
        out.append(f"## {title} {{#{_anchor(dotted)}}}\n")
        doc = _clean(inspect.getdoc(cls) or "")
        out.append(f"{doc}\n\n*(`{cls.__module__}.{cls.__qualname__}`)*\n")
        out.append("| field | type | default | unit | what it does |")
        out.append("|---|---|---|---|---|")
        for r in rows:
            if r.section != section:
                continue
            if r.is_section:
                link = f"[`{r.name}`](#{_anchor(r.name)})"
                out.append(f"| {link} | {r.type} | | | {_cell(r.text)} |")
            else:
                default = f"`{r.default}`" if r.default else ""
                unit = r.unit.replace("|", "\\|")
                row = f"| `{r.name}` | {_cell(r.type)} | {default} | {unit} | {_cell(r.text)} |"
                out.append(row)
        out.append("")
    return "\n".join(out)


def scenario_yaml_markdown() -> str:
    """The default scenario as YAML (``yaml_dump_typed(Scenario())``)."""
    from pydrake.common.yaml import yaml_dump_typed

    from doorlab.config import Scenario

    return "```yaml\n" + yaml_dump_typed(Scenario()).rstrip() + "\n```\n"


# ---------------------------------------------------------------------------------------------
# The command line


def cli_commands(
    parser: argparse.ArgumentParser, words: tuple[str, ...] = ("doorlab",), summary: str = ""
) -> list[tuple[tuple[str, ...], argparse.ArgumentParser, str]]:
    """Every command of ``parser``: (words, its parser, its one-line help), depth first."""
    out = [(words, parser, summary)]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help or "" for a in action._choices_actions}
            for name, sub in action.choices.items():
                out += cli_commands(sub, (*words, name), helps.get(name, ""))
    return out


def cli_options(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    """The options and positional arguments of one command (not --help, not sub-commands)."""
    return [
        a
        for a in parser._actions
        if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))
    ]


def _argument(action: argparse.Action) -> str:
    if action.nargs == 0:
        return ""
    if action.metavar is not None:
        return str(action.metavar)
    if action.choices is not None:
        return "{" + ",".join(str(c) for c in action.choices) + "}"
    return action.dest.upper() if action.option_strings else action.dest


def _default(action: argparse.Action) -> str:
    value = action.default
    if value in (None, False, [], argparse.SUPPRESS) or action.nargs == 0:
        return ""
    return f"`{value}`"


def _usage(parser: argparse.ArgumentParser) -> str:
    formatter = parser.formatter_class(prog=parser.prog, width=80)
    formatter.add_usage(parser.usage, parser._actions, parser._mutually_exclusive_groups, "")
    return formatter.format_help().strip()


def cli_anchor(words: tuple[str, ...]) -> str:
    """The id of a command's section in the CLI reference (``doorlab-pset-grade``)."""
    return "-".join(words)


def cli_markdown() -> str:
    """One section per command: its help, usage and a table of its options."""
    from doorlab.cli.parser import build_parser

    parser = build_parser()
    out = []
    for words, command, summary in cli_commands(parser):
        level = "#" * min(len(words) + 1, 4)
        out.append(f"{level} `{' '.join(words)}` {{#{cli_anchor(words)}}}\n")
        text = summary or command.description or ""
        if text:
            out.append(_clean(text) + "\n")
        out.append(f"```text\n{_usage(command)}\n```\n")
        formatter = command._get_formatter()
        for group in command._action_groups:
            actions = [a for a in group._group_actions if a in cli_options(command)]
            if not actions:
                continue
            if group.title not in ("positional arguments", "options", "optional arguments"):
                out.append(f"*{group.title}*\n")
            out.append("| option | argument | default | what it does |")
            out.append("|---|---|---|---|")
            for action in actions:
                names = ", ".join(f"`{s}`" for s in action.option_strings) or f"`{action.dest}`"
                if not action.option_strings and action.metavar:
                    names = f"`{action.metavar}`"
                argument = _argument(action)
                argument = f"`{argument}`" if argument else ""
                help_text = formatter._expand_help(action) if action.help else ""
                out.append(f"| {names} | {argument} | {_default(action)} | {_cell(help_text)} |")
            out.append("")
        subs = [a for a in command._actions if isinstance(a, argparse._SubParsersAction)]
        for action in subs:
            links = ", ".join(
                f"[`{name}`](#{cli_anchor((*words, name))})" for name in action.choices
            )
            out.append(f"Commands: {links}.\n")
    return "\n".join(out)


# ---------------------------------------------------------------------------------------------
# Exit codes, output files, logs


def exit_codes_markdown() -> str:
    """``doorlab run``'s exit codes by status, and the signals' codes."""
    from doorlab.outputs.runs import EXIT_CODES
    from doorlab.runtime.interrupts import INTERRUPTS

    missing = [s for s in EXIT_CODES if s not in STATUS_MEANINGS]
    if missing:
        raise ValueError(
            f"exit statuses without a meaning: {', '.join(missing)} (add them to "
            "STATUS_MEANINGS in docs/tools/reference.py)"
        )
    out = ["| code | status | meaning |", "|---|---|---|"]
    for status, code in sorted(EXIT_CODES.items(), key=lambda item: item[1]):
        out.append(f"| {code} | `{status}` | {_cell(STATUS_MEANINGS[status])} |")
    signals = ", ".join(f"{128 + int(s)} ({signal.Signals(s).name})" for s in INTERRUPTS)
    out.append(
        f"| {signals} | | interrupted (128 + the signal), every command: one line on stderr; a "
        "`--hardware` run stops commanding at once and writes its folder (status "
        "`interrupted`), other commands leave no staging folder "
        "([interruptions](outputs.md#output-folders-force-and-interruptions)) |"
    )
    return "\n".join(out) + "\n"


def run_files_markdown() -> str:
    """The files of a run folder: the plots from doorlab.outputs.plots, the rest from RUN_FILES."""
    from doorlab.outputs import plots
    from doorlab.runtime.folders import MANIFEST_NAME

    out = ["| file | what |", "|---|---|"]
    for name, text in RUN_FILES.items():
        if name.endswith(".png"):
            continue
        out.append(f"| `{name}` | {_cell(text)} |")
    for name in plots.RUN_PLOT_NAMES:
        function = getattr(plots, f"plot_{name}", None)
        if function is None or not _summary(function):
            raise ValueError(
                f"run plot {name!r} has no documented doorlab.outputs.plots.plot_{name}"
            )
        out.append(f"| `{name}.png` | {_cell(_summary(function))} |")
    for name, text in RUN_FILES.items():
        if name.endswith(".png"):
            out.append(f"| `{name}` | {_cell(text)} |")
    out.append(
        f"| `{MANIFEST_NAME}` | the path, size and SHA-256 of every file doorlab wrote there "
        "(see [output folders](#output-folders-force-and-interruptions)) |"
    )
    return "\n".join(out) + "\n"


def _dataclass_table(cls: type, texts: dict[str, str], header: str) -> str:
    hints = typing.get_type_hints(cls)
    out = [f"| {header} | type | what |", "|---|---|---|"]
    missing = []
    for f in dataclasses.fields(cls):
        text = texts.get(f.name, "")
        if not text:
            missing.append(f.name)
        out.append(f"| `{f.name}` | {_cell(_type_name(hints[f.name]))} | {_cell(text)} |")
    if missing:
        raise ValueError(
            f"{cls.__module__}.{cls.__qualname__}: undocumented fields {', '.join(missing)} "
            "(document them in its docstring's Attributes: or with a comment on the field)"
        )
    return "\n".join(out) + "\n"


def metrics_markdown() -> str:
    """The keys of metrics.json: the fields of DoorMetrics."""
    from doorlab.episode.metrics import DoorMetrics

    texts = {**attribute_comments(DoorMetrics), **docstring_attributes(DoorMetrics)}
    return _dataclass_table(DoorMetrics, texts, "key")


def log_channels_markdown() -> str:
    """The channels of log.npz: the fields of EpisodeResult."""
    from doorlab.episode.result import EpisodeResult

    return _dataclass_table(EpisodeResult, docstring_attributes(EpisodeResult), "channel")


def plan_log_markdown() -> str:
    """The adaptive plan's per-tick channels (doorlab.control.adaptive.LOG_CHANNELS)."""
    from doorlab.control import adaptive

    comments = attribute_comments(adaptive, names=["LOG_CHANNELS"])
    out = ["| channel | unit | what |", "|---|---|---|"]
    previous = ""
    for name in adaptive.LOG_CHANNELS:
        unit, text = _unit_and_text(comments.get(name, ""))
        if not text and name[:-2] == previous[:-2] and name[-2:] == "_y":
            text = f"with `{previous}`"  # x, y pairs: the comment sits on the x
        out.append(f"| `plan_log.{name}` | {unit} | {_cell(text)} |")
        previous = name
    return "\n".join(out) + "\n"


# ---------------------------------------------------------------------------------------------
# The Python API (mkdocstrings)


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
            coverage[module] = shown[owners[0]]
    if missing:
        raise ValueError(
            f"modules in no API group: {', '.join(missing)} (add them to API_GROUPS in "
            "docs/tools/reference.py)"
        )
    return coverage


def api_markdown(group: str) -> str:
    """mkdocstrings blocks for one group's modules (a package with its submodules)."""
    api_coverage()
    if group not in API_GROUPS:
        raise ValueError(f"unknown API group {group!r}; valid: {', '.join(API_GROUPS)}")
    title, modules = API_GROUPS[group]
    out = [f"# {title}\n", "Modules: " + ", ".join(f"`{m}`" for m in modules) + ".\n"]
    for module in modules:
        is_package = (Path(importlib.util.find_spec(module).origin).name) == "__init__.py"
        out.append(f"::: {module}")
        if is_package:
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


def _figure_targets() -> dict:
    """docs/tools/make_figures.py's TARGETS (loaded from beside this file)."""
    path = Path(__file__).with_name("make_figures.py")
    spec = importlib.util.spec_from_file_location("doorlab_docs_make_figures", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module.TARGETS


def figure_markdown(name: str, page: str = "index.md") -> str:
    """A figure of docs/figures (``TARGET/NAME``) with its caption and the command that made
    it, for the page at ``page`` (its path under docs/)."""
    targets = _figure_targets()
    target_name, _, figure = name.partition("/")
    if target_name not in targets or figure not in targets[target_name].figures:
        known = [f"{t}/{f}" for t, target in targets.items() for f in target.figures]
        raise ValueError(f"unknown figure {name!r}; valid: {', '.join(known)}")
    target = targets[target_name]
    _, caption = target.figures[figure]
    depth = len(Path(page).parent.parts)
    src = "../" * depth + f"figures/{target_name}/{figure}.png"
    command = target.command.format(out="DIR")
    return (
        f"<figure markdown>\n![{caption}]({src})\n"
        f"<figcaption>{caption}. Made by <code>{command}</code> "
        f"(<code>python docs/tools/make_figures.py {target_name}</code>).</figcaption>\n"
        "</figure>\n"
    )


def figure_text_markdown(name: str, page: str = "index.md") -> str:  # noqa: ARG001
    """A text a figure target kept (``TARGET/NAME``, e.g. ``run/summary``) as a code block."""
    target_name, _, text = name.partition("/")
    path = Path(__file__).resolve().parents[1] / "figures" / target_name / f"{text}.txt"
    if not path.is_file():
        raise ValueError(f"{path} is missing: python docs/tools/make_figures.py {target_name}")
    return f"```text\n{path.read_text().rstrip()}\n```\n"


GENERATORS = {
    "cli": cli_markdown,
    "scenario": scenario_markdown,
    "scenario-yaml": scenario_yaml_markdown,
    "exit-codes": exit_codes_markdown,
    "run-files": run_files_markdown,
    "metrics": metrics_markdown,
    "log-channels": log_channels_markdown,
    "plan-log": plan_log_markdown,
    "public-api": public_api_markdown,
    "packages": packages_markdown,
    "api": api_markdown,
    "figure": figure_markdown,
    "figure-text": figure_text_markdown,
}
"""Marker name -> the function that writes its block (``api`` takes the group as argument)."""


def expand(markdown: str, where: str = "a page") -> str:
    """``markdown`` with every ``<!-- doorlab:NAME [ARG] -->`` marker replaced by its block."""

    def replace(match: re.Match) -> str:
        name, argument = match.group(1), match.group(2)
        if name not in GENERATORS:
            raise ValueError(f"{where}: unknown marker doorlab:{name}; valid: {list(GENERATORS)}")
        if name in ("figure", "figure-text"):
            return GENERATORS[name](argument, where)
        return GENERATORS[name](*([argument] if argument else []))

    return MARKER.sub(replace, markdown)


# ---------------------------------------------------------------------------------------------
# The MkDocs hook


def on_page_markdown(markdown: str, page, config, files) -> str:  # noqa: ARG001 (MkDocs' API)
    """MkDocs hook: expands the page's markers (an error stops the build, naming the page)."""
    from mkdocs.exceptions import PluginError

    try:
        return expand(markdown, page.file.src_uri)
    except ValueError as e:
        raise PluginError(f"doorlab reference, {page.file.src_uri}: {e}") from None


_ROLE_IN_HTML = re.compile(r":(?:mod|func|class|data|meth|attr|exc|obj):(?=<code\b)")


def on_page_content(html: str, page, config, files) -> str:  # noqa: ARG001 (MkDocs' API)
    """MkDocs hook: the API pages' Sphinx roles (``:func:`x```) are shown as plain code."""
    return _ROLE_IN_HTML.sub("", html)


if __name__ == "__main__":
    if len(sys.argv) < 2 or sys.argv[1] not in GENERATORS:
        sys.exit(f"usage: python {sys.argv[0]} {{{','.join(GENERATORS)}}} [GROUP]")
    print(GENERATORS[sys.argv[1]](*sys.argv[2:]))
