"""The page machinery shared by the report and the sweep page: Jinja2 templates
(``doorlab/templates``), embedded figures and number formatting.

Every page is one self-contained HTML file: images are base64 data URIs, the CSS is inline
(with a print stylesheet: figures and answers do not break across pages), nothing is fetched.
"""

from __future__ import annotations

import base64
import datetime
import functools
import math
import os
import platform
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

import jinja2
import numpy as np

SIGNIFICANT_DIGITS = 3
"""Significant digits of the numbers on the pages."""

_DEG_PER_RAD = 180.0 / math.pi


@functools.cache
def environment() -> jinja2.Environment:
    """The Jinja2 environment of doorlab's templates (HTML autoescaped, undefined is an error)."""
    return jinja2.Environment(
        loader=jinja2.PackageLoader("doorlab", "templates"),
        autoescape=jinja2.select_autoescape(["html", "html.j2"], default=True),
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )


def render(template: str, **context: object) -> str:
    """Renders a template of ``doorlab/templates`` with ``context``."""
    return environment().get_template(template).render(**context)


@dataclass(frozen=True)
class EmbeddedFigure:
    """A figure saved as PNG, ready for the page.

    Attributes:
        path: The PNG file. data: Its bytes, base64. caption: The caption (plain text).
    """

    path: Path
    data: str
    caption: str


class Figures:
    """Saves a page's figures to a folder and returns them embedded (base64)."""

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.paths: list[Path] = []

    def add(self, name: str, fig, caption: str) -> EmbeddedFigure:
        """Saves ``fig`` as ``<folder>/<name>.png`` and returns it embedded."""
        from doorlab.outputs.plots import save_figure

        path = save_figure(fig, self.folder / f"{name}.png")
        self.paths.append(path)
        data = base64.b64encode(path.read_bytes()).decode("ascii")
        return EmbeddedFigure(path, data, caption)

    def embed(self, name: str, fig, caption: str) -> str:
        """Saves ``fig`` and returns its ``<figure>`` HTML."""
        return render_macro("figure", self.add(name, fig, caption))


def render_macro(name: str, *args: object) -> str:
    """Calls a macro of ``macros.html.j2`` and returns its HTML."""
    module = environment().get_template("macros.html.j2").module
    return str(getattr(module, name)(*args))


def format_number(value: float | None, digits: int = SIGNIFICANT_DIGITS) -> str:
    """``value`` with ``digits`` significant digits, positional (no exponent); "n/a" if absent."""
    if value is None or not isinstance(value, (int, float)) or not math.isfinite(value):
        return "n/a"
    if value == 0:
        return "0"
    text = np.format_float_positional(
        float(value), precision=digits, unique=False, fractional=False, trim="k"
    )
    return text.rstrip(".")


def metric_unit(key: str) -> tuple[str, float]:
    """Display unit and scale of a metrics.json key: ``_m`` -> mm, ``_rad`` -> deg, ..."""
    if key.endswith("_rad_s"):
        return "rad/s", 1.0
    if key.endswith("_m"):
        return "mm", 1000.0
    if key.endswith("_rad"):
        return "deg", _DEG_PER_RAD
    if key.endswith("_Nm"):
        return "N m", 1.0
    if key.endswith("_s"):
        return "s", 1.0
    return "", 1.0


def metric_header(key: str) -> str:
    """A table header for a metrics.json key, e.g. ``max radial error [mm]``."""
    unit, _ = metric_unit(key)
    name = key
    for suffix in ("_rad_s", "_Nm", "_m", "_rad", "_s"):
        if name.endswith(suffix):
            name = name[: -len(suffix)]
            break
    name = name.replace("_cmd", " (cmd)").replace("_", " ")
    return f"{name} [{unit}]" if unit else name


def drake_version() -> str:
    """The installed drake's version ("unknown" if not found)."""
    try:
        return metadata.version("drake")
    except metadata.PackageNotFoundError:
        return "unknown"


def machine_rows() -> list[tuple[str, str]]:
    """Header rows every page shows: drake, date, machine."""
    now = datetime.datetime.now().astimezone()
    return [
        ("drake", drake_version()),
        ("date", now.isoformat(timespec="seconds")),
        (
            "machine",
            f"{os.cpu_count()} cores, {platform.machine()}, {platform.system()} "
            f"{platform.release()}, Python {platform.python_version()}",
        ),
    ]
