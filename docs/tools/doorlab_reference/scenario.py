"""The scenario's reference: every field of ``doorlab.config.Scenario`` with its type,
default, unit and description, and the default scenario as YAML."""

from __future__ import annotations

import dataclasses
import inspect
import sys
import typing

from .text import _cell, _clean, _expand_choices, _summary, _unit_and_text, attribute_comments


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
