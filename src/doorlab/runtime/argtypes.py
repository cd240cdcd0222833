"""The CLI's argument types: one-line errors (exit code 2) with values quoted short, and the
bounded numbers the options take. Shared by ``doorlab`` and ``run_autograder``."""

from __future__ import annotations

import argparse
import math
import re
from typing import NoReturn

from doorlab.runtime.inputs import QUOTE_CHARS, quote_text

USAGE_ERROR = 2


class OneLineParser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage block), values quoted short, exit code 2."""

    def error(self, message: str) -> NoReturn:
        message = " ".join(_LONG_QUOTE.sub(_shorten, message).split())
        self.exit(USAGE_ERROR, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


_LONG_QUOTE = re.compile("'([^']{" + str(QUOTE_CHARS + 1) + ",})'")


def _shorten(match: re.Match) -> str:
    return quote_text(match.group(1))


def bounded_int(low: int, high: int | None = None):
    """An argparse type: an integer in [low, high] (no upper bound if high is None)."""
    valid = f"an integer in [{low}, {high}]" if high is not None else f"an integer >= {low}"

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {valid}, got {quote_text(text)}") from None
        if value < low or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"must be {valid}, got {value}")
        return value

    return parse


MIN_REALTIME_RATE = 0.01
"""Slowest ``--realtime`` rate: 1/100 of real time already stretches the default episode to
40 minutes; a slower one would outlast anyone watching it (0 still means as fast as possible)."""


def realtime_rate(text: str) -> float:
    """An argparse type: ``--realtime``'s rate, 0 or at least :data:`MIN_REALTIME_RATE`."""
    valid = f"0 (as fast as possible) or a number >= {MIN_REALTIME_RATE}"
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be {valid}, got {quote_text(text)}") from None
    if not (math.isfinite(value) and (value == 0 or value >= MIN_REALTIME_RATE)):
        why = " (slower would take over 40 min)" if 0 < value < MIN_REALTIME_RATE else ""
        raise argparse.ArgumentTypeError(f"must be {valid}{why}, got {quote_text(text)}")
    return value


def seconds(low: float, high: float):
    """An argparse type: a duration in [low, high] seconds."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(
                f"must be a number of seconds in [{low:g}, {high:g}], got {quote_text(text)}"
            )
        return value

    return parse
