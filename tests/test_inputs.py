"""doorlab.runtime.inputs: YAML within a budget, files that are regular and small, short quotes.

These are the in-process checks of the reader; tests/test_hostile_cli.py runs the same
inputs through the ``doorlab`` command as a user would.
"""

from __future__ import annotations

import os

import pytest
import yaml

from doorlab.errors import ConfigError
from doorlab.runtime.inputs import (
    MAX_FILE_BYTES,
    MAX_YAML_DEPTH,
    MAX_YAML_NODES,
    QUOTE_CHARS,
    load_yaml,
    load_yaml_value,
    quote,
    quote_text,
    read_text_file,
    yaml_float_spelling,
)


def alias_bomb(levels: int = 9, width: int = 9) -> str:
    """The classic 'billion laughs': each level lists the previous one ``width`` times."""
    lines = ["a0: &a0 [" + ", ".join(["lol"] * width) + "]"]
    for i in range(1, levels):
        lines.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * width) + "]")
    return "\n".join(lines) + "\n"


def test_plain_documents_load_as_safe_load_does():
    text = "station:\n  time_step: 0.001\n  inner_loop: {kind: stiffness, kq: [1, 2]}\n"
    assert load_yaml(text) == yaml.safe_load(text)
    assert load_yaml("") is None


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        (alias_bomb(), "anchors"),
        ("a: &x 1\n", "anchors"),
        ("base: {a: 1}\nmore:\n  <<: *base\n", "aliases"),
        ("a: " + "[" * (MAX_YAML_DEPTH + 1) + "]" * (MAX_YAML_DEPTH + 1), "nests deeper"),
        ("[" * 100_000 + "]" * 100_000, "YAML"),
        ("[" + ",".join(["0"] * (MAX_YAML_NODES + 1)) + "]", f"more than {MAX_YAML_NODES}"),
        ("a: 1\n---\nb: 2\n", "more than one YAML document"),
        ("a: [\n", r"invalid YAML \(line 2"),
    ],
    ids=["alias bomb", "anchor", "merge key", "depth", "depth 100000", "nodes", "two docs", "bad"],
)
def test_documents_over_the_budget_are_refused(text, needle):
    with pytest.raises(ConfigError, match=needle) as info:
        load_yaml(text)
    assert len(str(info.value)) < 300


def test_depth_at_the_limit_loads():
    depth = MAX_YAML_DEPTH
    assert load_yaml("[" * depth + "]" * depth) is not None


@pytest.mark.parametrize(
    ("text", "value"),
    [
        ("0.002", 0.002),
        ("[1, 2]", [1, 2]),
        ("{kind: stiffness}", {"kind": "stiffness"}),
        ("ik", "ik"),
        ("", None),
        ("1.0e+300", 1e300),
    ],
)
def test_a_value_is_one_scalar_or_flow_value(text, value):
    assert load_yaml_value(text) == value


@pytest.mark.parametrize("text", ["0.002\ncontroller: ik", "1\r2", "a: b", "- 1", "&a 1", "*a"])
def test_a_value_with_a_line_break_or_block_structure_is_refused(text):
    with pytest.raises(ConfigError):
        load_yaml_value(text)


@pytest.mark.parametrize(
    ("text", "spelled"),
    [
        ("1e+300", "1.0e+300"),
        ("1e3", "1000.0"),
        ("-2E-5", "-2.0e-05"),
        ("nan", None),
        ("inf", None),
        ("-inf", None),
        ("abc", None),
    ],
)
def test_float_hints_are_spellings_yaml_reads_as_that_number(text, spelled):
    """The hint is a spelling PyYAML reads as the same float, or none at all (nan, inf)."""
    assert yaml_float_spelling(text) == spelled
    if spelled is not None:
        assert yaml.safe_load(spelled) == float(text)


def test_quotes_are_short_for_any_value():
    huge = {"a": ["x" * 10**6] * 1000, "b": list(range(10**5))}
    assert len(quote(huge)) < 4 * QUOTE_CHARS
    assert len(quote("x" * 10**6)) <= QUOTE_CHARS + 2
    assert len(quote_text("y" * 10**6)) < QUOTE_CHARS + 40


def test_only_small_regular_files_are_read(tmp_path):
    ok = tmp_path / "ok.yaml"
    ok.write_text("a: 1\n")
    assert read_text_file(ok, what="config file") == "a: 1\n"
    big = tmp_path / "big.yaml"
    big.write_bytes(b"#" * (MAX_FILE_BYTES + 1))
    cases = [
        (tmp_path / "missing.yaml", "does not exist"),
        (ok / "sub.yaml", "does not exist"),
        (tmp_path, "is a folder"),
        (big, "larger than"),
    ]
    if os.path.exists("/dev/zero"):
        cases.append((os.path.realpath("/dev/zero"), "not a regular file"))
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    cases.append((fifo, "not a regular file"))  # opened without waiting for a writer
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(b"\xff\xfe\x00")
    cases.append((binary, "not UTF-8"))
    for path, needle in cases:
        with pytest.raises(ConfigError, match=needle):
            read_text_file(path, what="config file")


@pytest.mark.parametrize(
    ("address", "ok"),
    [
        ("tcp://127.0.0.1:8786", True),
        ("tcp://[::1]:8786", True),
        ("tls://scheduler.example.org", True),
        ("tcp://127.0.0.1:99999999", False),
        ("tcp://127.0.0.1:0", False),
        ("tcp://host:", False),
        ("tcp://:8786", False),
        ("127.0.0.1:8786", False),
        ("inproc://x", False),
        ("tcp://a b:1", False),
        ("tcp://user@host:1", False),
        ("tcp://host:1/path", False),
    ],
)
def test_scheduler_addresses_are_checked_with_their_port(address, ok):
    from doorlab.runtime.executor import check_scheduler

    if ok:
        assert check_scheduler(address) == address
    else:
        with pytest.raises(ConfigError, match="1-65535"):
            check_scheduler(address)
