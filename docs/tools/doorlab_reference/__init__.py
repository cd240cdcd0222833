"""The site's reference, generated from the code: the Markdown behind each marker.

A page asks for a generated block with a marker on a line of its own (modules are doorlab's)::

    <!-- doorlab:cli -->            every command and option of cli.parser.build_parser()
    <!-- doorlab:scenario -->       every field of config.Scenario
    <!-- doorlab:scenario-yaml -->  the default scenario as YAML
    <!-- doorlab:exit-codes -->     outputs.runs.EXIT_CODES and the signals' codes
    <!-- doorlab:run-files -->      what a run folder holds
    <!-- doorlab:metrics -->        the keys of metrics.json (episode.metrics.DoorMetrics)
    <!-- doorlab:log-channels -->   the channels of log.npz (episode.result.EpisodeResult)
    <!-- doorlab:plan-log [MODULE] -->  a plan's own log (control.MODULE.LOG_CHANNELS; adaptive)
    <!-- doorlab:public-api -->     mkdocstrings blocks for every name of doorlab.__all__
    <!-- doorlab:packages -->       the package's parts, foundations first (API_GROUPS)
    <!-- doorlab:api GROUP -->      mkdocstrings blocks for the modules of API_GROUPS[GROUP]

The hook ``docs/tools/reference.py`` (``hooks:`` in mkdocs.yml) replaces the markers when MkDocs
builds (:func:`expand`), so a new CLI option, scenario field, exit code, run file or module
appears without editing a page. Descriptions come from where the code keeps them: an option's
``help``, the comment on a scenario field (its unit is the first ``[...]`` in it, as the team's
convention writes units), a dataclass's Google-style ``Attributes:``, a plot function's
docstring. A field without a description, a status without a meaning or a module in no API group
stops the build with a message saying what to add.

Print one block without MkDocs: ``python docs/tools/reference.py cli`` (or any marker's name).

One module per kind of block: :mod:`.text` (comments and docstrings as Markdown),
:mod:`.scenario`, :mod:`.cli` (commands, options, exit codes), :mod:`.outputs` (run files,
metrics, logs), :mod:`.api` (the package's parts, mkdocstrings blocks). What pages quote from
runs (figures, tables, times) is not written at build time but by the runs themselves, into
the pages' Markdown: :mod:`.measured`.
"""

from __future__ import annotations

import re

from .api import (
    API_GROUPS,
    api_coverage,
    api_markdown,
    package_modules,
    packages_markdown,
    public_api_markdown,
)
from .cli import STATUS_MEANINGS, cli_anchor, cli_commands, cli_markdown, exit_codes_markdown
from .outputs import (
    RUN_FILES,
    log_channels_markdown,
    metrics_markdown,
    plan_log_markdown,
    run_files_markdown,
)
from .scenario import FieldDoc, scenario_fields, scenario_markdown, scenario_yaml_markdown
from .text import attribute_comments, docstring_attributes

MARKER = re.compile(r"^<!-- doorlab:([a-z-]+)(?: ([\w./-]+))? -->[ \t]*$", re.M)
"""A generated block's marker: ``<!-- doorlab:NAME [ARG] -->`` on a line of its own."""

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
}
"""Marker name -> the function that writes its block (``api`` takes the group as argument)."""


def expand(markdown: str, where: str = "a page") -> str:
    """``markdown`` with every ``<!-- doorlab:NAME [ARG] -->`` marker replaced by its block."""

    def replace(match: re.Match) -> str:
        name, argument = match.group(1), match.group(2)
        if name not in GENERATORS:
            raise ValueError(f"{where}: unknown marker doorlab:{name}; valid: {list(GENERATORS)}")
        return GENERATORS[name](*([argument] if argument else []))

    return MARKER.sub(replace, markdown)


# ---------------------------------------------------------------------------------------------
# The MkDocs hook


__all__ = [
    "API_GROUPS",
    "GENERATORS",
    "MARKER",
    "RUN_FILES",
    "STATUS_MEANINGS",
    "FieldDoc",
    "api_coverage",
    "api_markdown",
    "attribute_comments",
    "cli_anchor",
    "cli_commands",
    "cli_markdown",
    "docstring_attributes",
    "exit_codes_markdown",
    "expand",
    "log_channels_markdown",
    "metrics_markdown",
    "package_modules",
    "packages_markdown",
    "plan_log_markdown",
    "public_api_markdown",
    "run_files_markdown",
    "scenario_fields",
    "scenario_markdown",
    "scenario_yaml_markdown",
]
