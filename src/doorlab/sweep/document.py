"""The typed keys of a SPEC file, loaded with ``yaml_load_typed`` like the scenario.

No ``from __future__ import annotations`` here: Drake's YAML loader reads the field types at
run time, as it does for :class:`doorlab.config.Scenario`.
"""

from dataclasses import dataclass


@dataclass
class SpecDocument:
    """The typed keys of a SPEC file (``scenario`` and ``axes`` are checked on their own:
    a scenario mapping, and per axis a list of values or a range)."""

    base: str | None = None  # scenario file, relative to the SPEC
    controllers: list[str] | None = None  # None: every registered controller
    doors: list[str] | None = None  # None: the base scenario's
    samples: int = 0  # 0: the full grid; N: N random draws
    seed: int = 0  # of the random draws
