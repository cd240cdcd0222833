"""The options several ``doorlab`` commands share: a Dask cluster (``--scheduler``,
``--scheduler-timeout``) and a scenario with its output folder (``--config``, ``--set``,
``--force``). :mod:`doorlab.cli.parser` and :mod:`doorlab.cli.pset_parser` add them to their
commands' parsers."""

from __future__ import annotations

import argparse
from pathlib import Path

from doorlab.runtime.argtypes import seconds


def add_scheduler_options(parser: argparse.ArgumentParser) -> None:
    """``--scheduler tcp://HOST:PORT`` and ``--scheduler-timeout SECONDS``: a Dask cluster
    instead of local processes (``doorlab report``, ``sweep``, ``pset grade-all``)."""
    from doorlab.runtime.executor import CONNECT_TIMEOUT_S

    parser.add_argument(
        "--scheduler",
        default=None,
        metavar="tcp://HOST:PORT",
        help="run on this Dask cluster instead of local processes (workers need doorlab)",
    )
    parser.add_argument(
        "--scheduler-timeout",
        type=seconds(0.1, 600.0),
        default=CONNECT_TIMEOUT_S,
        metavar="SECONDS",
        help="how long each step of connecting to --scheduler may take "
        f"(default {CONNECT_TIMEOUT_S:g}; 0.1-600)",
    )


def add_config_options(parser: argparse.ArgumentParser) -> None:
    """``--config FILE``, ``--set KEY=VALUE`` (repeatable) and ``--force``: the scenario and
    the output folder (``doorlab run``, ``report``, ``sim-driver``, ``identify``)."""
    parser.add_argument(
        "--config",
        type=Path,
        default=None,
        help="scenario YAML (see examples/scenario.yaml); options override it",
    )
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override one scenario field, e.g. --set station.time_step=0.001",
    )
    parser.add_argument("--force", action="store_true", help="replace an existing output folder")
