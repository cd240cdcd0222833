"""No import cycle among doorlab's modules, counting imports inside functions too."""

from __future__ import annotations

import ast
from pathlib import Path

import doorlab

PACKAGE_DIR = Path(doorlab.__file__).parent


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE_DIR.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph() -> dict[str, set[str]]:
    """Every doorlab module -> the doorlab modules it imports (at any depth of its code)."""
    modules = {module_name(p): p for p in PACKAGE_DIR.rglob("*.py")}
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join([*anchor, base] if base else anchor)
                # "from pkg import sub" imports the submodule pkg.sub when there is one.
                targets = [
                    f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base
                    for a in node.names
                ]
            for target in targets:
                while target and target not in modules:
                    target = target.rpartition(".")[0]
                if target and target != name:
                    graph[name].add(target)
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as a path [a, b, ..., a], or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return [*stack[stack.index(nxt) :], nxt]
            if nxt not in state and (cycle := visit(nxt)):
                return cycle
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)):
            return cycle
    return None


def test_no_import_cycle_among_doorlabs_modules():
    """Imports inside functions count too: a lazy import only hides a cycle from the
    interpreter, not from a reader. ``from pkg import sub`` is an edge to ``pkg.sub``."""
    graph = import_graph()
    assert len(graph) > 50  # the walk found the package's modules
    assert "doorlab.report.page" in graph["doorlab.report.runner"]  # edges are found
    cycle = find_cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_find_cycle_finds_one():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


LAYERS = (
    ("doorlab.errors", "doorlab.constants"),
    ("doorlab",),
    ("doorlab.kuka", "doorlab.runtime"),
    ("doorlab.config_checks",),
    ("doorlab.config",),
    ("doorlab.cell",),
    ("doorlab.control",),
    ("doorlab.episode",),
    ("doorlab.outputs",),
    ("doorlab.studies",),
    ("doorlab.hardware",),
    ("doorlab.report", "doorlab.sweep", "doorlab.pset"),
    ("doorlab.cli",),
)
"""doorlab's parts from the bottom up: a module imports only from its own part and from the
parts of lower layers. ``doorlab`` itself is its ``__init__``: it imports ``doorlab.errors``
and loads its public names from above on first use (by name, which this walk does not see),
and the modules that need ``doorlab.__version__`` import it. The folder tree reads as this
architecture (issue 28)."""


def part_of(module: str) -> str:
    """The part of LAYERS a module belongs to: ``doorlab.cell.station`` -> ``doorlab.cell``."""
    return ".".join(module.split(".")[:2])


def test_imports_only_go_down_the_layers():
    layer = {part: i for i, parts in enumerate(LAYERS) for part in parts}
    graph = import_graph()
    assert [m for m in graph if part_of(m) not in layer] == [], "a part missing from LAYERS"
    upward = [
        f"{a} -> {b}"
        for a, targets in graph.items()
        for b in targets
        if part_of(a) != part_of(b) and layer[part_of(b)] >= layer[part_of(a)]
    ]
    assert upward == [], "imports that do not go down the layers:\n" + "\n".join(sorted(upward))
    # the walk sees the layers: the episode uses the control laws, the CLI everything
    assert "doorlab.control.plan_base" in graph["doorlab.episode.schedule"]
    assert "doorlab.outputs.runs" in graph["doorlab.cli.commands"]


def test_every_flat_module_is_a_foundation():
    """Only the foundations sit at the top of the package: the rest is in sub-packages."""
    flat = sorted(p.stem for p in PACKAGE_DIR.glob("*.py"))
    assert flat == ["__init__", "config", "config_checks", "constants", "errors", "kuka"]
