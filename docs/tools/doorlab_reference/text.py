"""Comments and docstrings read as Markdown: the descriptions the reference shows."""

from __future__ import annotations

import ast
import inspect
import io
import re
import textwrap
import tokenize
import typing

UNIT = re.compile(r"\[([^\]\[,]+)\]")
"""A unit in a comment: the first ``[...]`` without a comma (``[0, 1]`` is a range)."""


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
