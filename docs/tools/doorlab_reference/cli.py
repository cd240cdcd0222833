"""The command line's reference: every command and option of the parser, and the exit
codes."""

from __future__ import annotations

import argparse
import signal

from .text import _cell, _clean

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
    "controller_error": "a controller plug-in raised during a tick, or returned no valid command "
    "(7 + 7 finite numbers): the run stopped there, `log.npz` and `metrics.json` hold the logs "
    "and the error; a plug-in that does not load or has the wrong signature is `usage` "
    "([your own controller](../guides/controllers.md))",
}
"""What each status of :data:`doorlab.outputs.runs.EXIT_CODES` means (a new status without an entry
here stops the build)."""


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


def exit_codes_markdown() -> str:
    """``doorlab run``'s exit codes by status, and the signals' codes."""
    from doorlab.outputs.runs import EXIT_CODES
    from doorlab.runtime.interrupts import INTERRUPTS

    missing = [s for s in EXIT_CODES if s not in STATUS_MEANINGS]
    if missing:
        raise ValueError(
            f"exit statuses without a meaning: {', '.join(missing)} (add them to "
            "STATUS_MEANINGS in docs/tools/doorlab_reference/cli.py)"
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
