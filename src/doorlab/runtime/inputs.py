"""Reading what a user hands doorlab, within bounds, and quoting it back briefly.

Every YAML document doorlab reads from a user (``--config``, a sweep SPEC, a ``--set`` or
``--grid`` value) goes through :func:`load_yaml`, which first scans the document's events
(libyaml, fast, nothing built) and refuses, before any object exists:

- anchors, aliases and merge keys (``&a``, ``*a``, ``<<: *a``): a 400-byte document of
  nested aliases expands to gigabytes; a scenario never needs them;
- nesting deeper than :data:`MAX_YAML_DEPTH` (a scenario nests 4 levels, a SPEC 6; the
  object builder is recursive, a deep document would exhaust the stack);
- more than :data:`MAX_YAML_NODES` values (building one costs ~1 kB and ~40 us);
- a key that appears twice in one mapping (YAML requires keys to be unique; PyYAML would
  keep the last one silently, so a setting written twice would quietly lose one of them).

Files are read by :func:`read_text_file`: regular files only (a folder, ``/dev/zero`` or a
pipe get a one-line message, and are never read), at most :data:`MAX_FILE_BYTES`.

Messages quote a value with :func:`quote`: at most a short prefix of it, however large.
"""

from __future__ import annotations

import os
import reprlib
import stat
from pathlib import Path

import yaml

from doorlab.errors import ConfigError

MAX_FILE_BYTES = 1 << 20
"""Largest YAML file doorlab reads [bytes] (1 MiB): a scenario file is ~2 kB, the shipped
SPECs under 1 kB; 1 MiB leaves room for long lists of axis values."""
MAX_YAML_DEPTH = 20
"""Deepest nesting of mappings and lists in a YAML document: a scenario nests 4 levels
(``station.inner_loop.kq[0]``), a SPEC 6."""
MAX_YAML_NODES = 20_000
"""Most values (scalars, lists, mappings) in one YAML document: a scenario has ~90, a SPEC
with a few hundred listed axis values well under 1,000."""
QUOTE_CHARS = 60
"""Longest prefix of a value a message quotes [characters]."""

_LINE_BREAKS = ("\n", "\r", "\x85", "\u2028", "\u2029")
"""What YAML counts as a line break."""

_Loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)

_repr = reprlib.Repr()
_repr.maxstring = QUOTE_CHARS
_repr.maxother = QUOTE_CHARS
_repr.maxlong = QUOTE_CHARS
_repr.maxlist = _repr.maxtuple = _repr.maxset = 8
_repr.maxdict = 6
_repr.maxlevel = 3


def quote(value: object) -> str:
    """``repr(value)``, shortened: long strings, lists and mappings are cut (``...``).

    Never builds the full repr of a large value (so it is cheap for any input); at most
    2 x :data:`QUOTE_CHARS` characters.
    """
    text = _repr.repr(value)
    return text if len(text) <= 2 * QUOTE_CHARS else text[: 2 * QUOTE_CHARS] + "..."


def quote_text(text: str) -> str:
    """A user's text in quotes, cut to its first :data:`QUOTE_CHARS` characters."""
    if len(text) <= QUOTE_CHARS:
        return repr(text)
    return repr(text[:QUOTE_CHARS]) + f"... ({len(text)} characters)"


def shorten(text: str) -> str:
    """A user's text (no quotes), cut to its first :data:`QUOTE_CHARS` characters."""
    return text if len(text) <= QUOTE_CHARS else f"{text[:QUOTE_CHARS]}... ({len(text)} chars)"


def read_text_file(path: str | Path, *, what: str, max_bytes: int = MAX_FILE_BYTES) -> str:
    """The text of a regular file of at most ``max_bytes``.

    Args:
        path: The file.
        what: How messages name it, e.g. ``config file``.
        max_bytes: Largest size read [bytes].

    Raises:
        ConfigError: Missing, a folder or not a regular file (a device, pipe or socket),
            unreadable, larger than ``max_bytes`` or not UTF-8 (one line naming the file).
    """
    name = f"{what} {str(path)!r}"
    try:
        # O_NONBLOCK: opening a pipe must not wait for a writer; fstat then decides.
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise ConfigError(f"{name} does not exist") from None
    except NotADirectoryError:
        raise ConfigError(f"{name} does not exist (a part of its path is a file)") from None
    except OSError as e:
        raise ConfigError(f"{name} cannot be read: {e.strerror or e}") from None
    try:
        mode = os.fstat(fd).st_mode
        if stat.S_ISDIR(mode):
            raise ConfigError(f"{name} is a folder, not a file")
        if not stat.S_ISREG(mode):
            raise ConfigError(f"{name} is not a regular file (a device, pipe or socket)")
        with os.fdopen(fd, "rb", closefd=False) as f:
            data = f.read(max_bytes + 1)
    except OSError as e:
        raise ConfigError(f"{name} cannot be read: {e.strerror or e}") from None
    finally:
        os.close(fd)
    if len(data) > max_bytes:
        raise ConfigError(f"{name} is larger than {max_bytes} bytes, the most doorlab reads")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ConfigError(f"{name} is not UTF-8 text (byte {e.start})") from None


def _where(error: yaml.YAMLError) -> str:
    mark = getattr(error, "problem_mark", None)
    return f" (line {mark.line + 1}, column {mark.column + 1})" if mark else ""


class _Mapping:
    """A mapping being scanned: the keys seen, whether its next node is a key."""

    __slots__ = ("keys", "key_next")

    def __init__(self) -> None:
        self.keys: set[str] = set()
        self.key_next = True


def _check_key(frames: list, event: yaml.Event) -> None:
    """Notes a node inside a mapping; refuses a scalar key seen before in that mapping."""
    frame = frames[-1] if frames else None
    if not isinstance(frame, _Mapping):
        return
    if frame.key_next and isinstance(event, yaml.ScalarEvent):
        if event.value in frame.keys:
            raise ConfigError(
                f"the key {quote_text(event.value)} appears twice in one mapping{_mark(event)}: "
                "keep one of them"
            )
        frame.keys.add(event.value)
    frame.key_next = not frame.key_next


def _scan(text: str) -> None:
    """Checks a document's events against the budget and its mappings' keys (nothing is
    built)."""
    depth = nodes = documents = 0
    frames: list = []  # per open collection: a _Mapping, or None for a list
    for event in yaml.parse(text, Loader=_Loader):
        if isinstance(event, yaml.DocumentStartEvent):
            documents += 1
            if documents > 1:
                raise ConfigError("holds more than one YAML document (a second '---')")
        if isinstance(event, yaml.AliasEvent):
            raise ConfigError(
                f"YAML aliases ('*{event.anchor}') are not accepted{_mark(event)}: "
                "write the values out"
            )
        if isinstance(event, yaml.CollectionEndEvent):
            depth -= 1
            frames.pop()
            continue
        if not isinstance(event, yaml.NodeEvent):
            continue
        _check_key(frames, event)
        if event.anchor is not None:
            raise ConfigError(
                f"YAML anchors ('&{event.anchor}') are not accepted{_mark(event)}: "
                "write the values out"
            )
        nodes += 1
        if nodes > MAX_YAML_NODES:
            raise ConfigError(f"has more than {MAX_YAML_NODES} YAML values")
        if isinstance(event, yaml.CollectionStartEvent):
            depth += 1
            frames.append(_Mapping() if isinstance(event, yaml.MappingStartEvent) else None)
            if depth > MAX_YAML_DEPTH:
                raise ConfigError(
                    f"nests deeper than {MAX_YAML_DEPTH} levels{_mark(event)} (a scenario nests 4)"
                )


def _mark(event: yaml.Event) -> str:
    mark = event.start_mark
    return f" (line {mark.line + 1}, column {mark.column + 1})" if mark else ""


def _check_scan(text: str) -> None:
    try:
        _scan(text)
    except yaml.YAMLError as e:
        problem = getattr(e, "problem", None) or type(e).__name__
        raise ConfigError(f"invalid YAML{_where(e)}: {problem}") from None


def load_yaml(text: str) -> object:
    """The data of one YAML document, within the budget (see the module docstring).

    Raises:
        ConfigError: Invalid YAML (with its line and column), anchors or aliases, too deep,
            too many values, or more than one document.
    """
    _check_scan(text)
    try:
        return yaml.load(text, Loader=_Loader)  # noqa: S506 - a safe loader
    except yaml.YAMLError as e:  # not expected after the scan
        problem = getattr(e, "problem", None) or type(e).__name__
        raise ConfigError(f"invalid YAML{_where(e)}: {problem}") from None


def load_yaml_value(text: str) -> object:
    """One YAML scalar or flow value on one line (``0.002``, ``[1, 2]``, ``{kind: pid}``).

    What ``--set KEY=VALUE`` and ``--grid KEY=V1,...`` accept: it can change only its key.

    Raises:
        ConfigError: A line break in ``text``, a block mapping or list (``a: b``), or what
            :func:`load_yaml` refuses.
    """
    if any(b in text for b in _LINE_BREAKS):
        raise ConfigError("the value holds a line break; give one YAML value on one line")
    _check_scan(text)
    try:
        node = yaml.compose(text, Loader=_Loader)
    except yaml.YAMLError as e:
        problem = getattr(e, "problem", None) or type(e).__name__
        raise ConfigError(f"invalid YAML{_where(e)}: {problem}") from None
    if isinstance(node, yaml.CollectionNode) and not node.flow_style:
        raise ConfigError(
            "the value must be one YAML scalar or a [list] or {mapping} in brackets, "
            f"got {quote_text(text)}"
        )
    return load_yaml(text)


def yaml_float_spelling(text: str) -> str | None:
    """How to write the number ``text`` reads as so that YAML reads it as a number.

    PyYAML (YAML 1.1) reads ``1e+300`` and ``1e3`` as text: it needs ``1.0e+300``. Returns
    None if ``text`` is no number, or is nan or inf (every doorlab number must be finite,
    so no spelling of those would be accepted).
    """
    try:
        value = float(text)
    except (TypeError, ValueError):
        return None
    if value != value or value in (float("inf"), float("-inf")):
        return None
    spelled = repr(value)
    if "e" in spelled:
        mantissa, exponent = spelled.split("e")
        if "." not in mantissa:
            mantissa += ".0"
        if exponent[0] not in "+-":
            exponent = "+" + exponent
        spelled = f"{mantissa}e{exponent}"
    try:
        parsed = yaml.load(spelled, Loader=_Loader)  # noqa: S506 - a safe loader
    except yaml.YAMLError:
        return None
    ok = isinstance(parsed, float) and parsed == value
    return spelled if ok else None
