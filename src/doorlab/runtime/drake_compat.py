"""What differs between the Drake releases doorlab supports (1.51.1 to 1.58), in one place.

doorlab runs on every Drake from 1.51.1 (the newest for Python 3.10 and 3.11) to 1.58 (the
newest tested; 1.52 on need Python >= 3.12, drake#24222). The rest of the code asks here
instead of testing versions itself. What is asked of pydrake, not of its version number, so a
release that brings a feature back, or a build from source, gets the right answer:

- **TAMSI**: ``DiscreteContactApproximation.kTamsi`` up to 1.56; removed in 1.57
  (drake#24831). :func:`contact_approximations` is what the running Drake has; a scenario
  asking for one it lacks is refused at validation (``doorlab.config``), before anything is
  built.
- **Bindings**: pybind11 up to 1.57, nanobind from 1.58 (drake#24971). Nothing of doorlab's
  depends on which (the suite runs on both: ``.ci/newest_drake.sh``).

Not a difference between releases, but a pydrake fact doorlab works around on all of them:
a Python LCM handler must never be called from inside ``Simulator.AdvanceTo``
(:mod:`doorlab.hardware.link`, issue 45).
"""

from __future__ import annotations

import functools
from importlib import metadata

OLDEST = "1.51.1"
"""The oldest Drake doorlab supports (``pyproject.toml``'s lower bound)."""
NEWEST_TESTED = "1.58.0"
"""The newest Drake tested (``pyproject.toml`` admits releases below the next minor)."""

_APPROXIMATIONS = {"kSap": "sap", "kLagged": "lagged", "kSimilar": "similar", "kTamsi": "tamsi"}
"""pydrake's ``DiscreteContactApproximation`` members -> the names ``MultibodyPlantConfig``
takes (``station.contact_approximation``)."""
TAMSI_RELEASES = "Drake 1.56 and earlier; 1.57 removed it, drake#24831"
"""Which releases have TAMSI, for messages and the docs."""


def drake_version() -> str:
    """The installed Drake's version ("1.58.0"; "unknown" for a build without the package's
    metadata, e.g. from source)."""
    try:
        return metadata.version("drake")
    except metadata.PackageNotFoundError:
        return "unknown"


@functools.cache
def contact_approximations() -> tuple[str, ...]:
    """The discrete contact approximations the running Drake has, in doorlab's order (sap,
    lagged, similar, then tamsi where there is one)."""
    from pydrake.multibody.plant import DiscreteContactApproximation

    return tuple(
        name
        for member, name in _APPROXIMATIONS.items()
        if hasattr(DiscreteContactApproximation, member)
    )


def missing_contact_approximation(name: str) -> str | None:
    """Why ``name`` (one doorlab knows) cannot run on this Drake, in one line; None if it can."""
    available = contact_approximations()
    if name in available:
        return None
    when = f" (TAMSI: {TAMSI_RELEASES})" if name == "tamsi" else ""
    return (
        f"station.contact_approximation {name!r} is not in Drake {drake_version()}{when}; "
        f"this Drake has {', '.join(available)}"
    )
