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
    ("doorlab.bench",),
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


PSET_LAYERS = (
    ("doorlab.pset",),
    ("doorlab.pset.rules",),
    ("doorlab.pset.handout",),
    ("doorlab.pset.isolation",),
    ("doorlab.pset.grading",),
    ("doorlab.pset.classroom",),
)
"""The problem set's parts from the bottom up (issue 34): a module of ``doorlab.pset`` imports
only from its own part and from the parts of lower layers. ``doorlab.pset`` itself is its
``__init__`` (a docstring). The rules (the graded tests, the assignment, a test's time) are
what the handout shows, isolation enforces and grading applies; the handout's folder and
station API are what the student's process runs (the worker, in isolation, imports them); the
grading drives the isolated student process; the classroom grades a class with all of them.
The handout's templates are not among them: they are the files of a student's folder (package
data that ``doorlab pset init`` copies), run from there, and import what such a folder does
(``test_pset_5a.py`` runs the grader)."""
PSET_TEMPLATES = "doorlab.pset.handout.templates"


def pset_part_of(module: str) -> str:
    """The part of PSET_LAYERS a module of the problem set belongs to:
    ``doorlab.pset.grading.jobs`` -> ``doorlab.pset.grading``."""
    return ".".join(module.split(".")[:3])


def test_the_problem_sets_imports_only_go_down_its_layers():
    layer = {part: i for i, parts in enumerate(PSET_LAYERS) for part in parts}
    graph = {
        m: t
        for m, t in import_graph().items()
        if part_of(m) == "doorlab.pset" and not m.startswith(PSET_TEMPLATES + ".")
    }
    assert [m for m in graph if pset_part_of(m) not in layer] == [], "a part missing from LAYERS"
    upward = [
        f"{a} -> {b}"
        for a, targets in graph.items()
        for b in targets
        if part_of(b) == "doorlab.pset"
        and pset_part_of(a) != pset_part_of(b)
        and layer[pset_part_of(b)] >= layer[pset_part_of(a)]
    ]
    assert upward == [], "imports that do not go down the layers:\n" + "\n".join(sorted(upward))
    # the walk sees the layers: the worker runs the handout's API, the grader uses the rules
    assert "doorlab.pset.handout.station_api" in graph["doorlab.pset.isolation.worker"]
    assert "doorlab.pset.rules.verdicts" in graph["doorlab.pset.grading.grader"]
    assert "doorlab.pset.grading.grader" in graph["doorlab.pset.classroom.grade_all"]


def test_the_problem_set_is_all_in_its_sub_packages():
    """``doorlab/pset/`` holds only its ``__init__`` and one folder per part of PSET_LAYERS."""
    pset = PACKAGE_DIR / "pset"
    assert sorted(p.name for p in pset.glob("*.py")) == ["__init__.py"]
    folders = sorted(p.name for p in pset.iterdir() if p.is_dir() and p.name != "__pycache__")
    assert folders == sorted(part.rsplit(".", 1)[1] for (part,) in PSET_LAYERS[1:])


def test_the_problem_sets_packages_import_nothing():
    """The packages' ``__init__`` are docstrings: importing one module of a part loads nothing
    else of it (the student's view holds a few modules of some parts)."""
    for package in [p for (p,) in PSET_LAYERS]:
        init = PACKAGE_DIR.parent / Path(*package.split(".")) / "__init__.py"
        body = ast.parse(init.read_text()).body
        assert len(body) == 1 and isinstance(body[0], ast.Expr), package  # the docstring
        assert len(ast.get_docstring(ast.parse(init.read_text())) or "") > 200, package


def test_no_two_modules_of_the_problem_set_are_named_a_letter_apart():
    """``view.py`` beside ``views.py`` was one (issue 34): a name says what a module holds."""

    def one_edit_apart(a: str, b: str) -> bool:
        if abs(len(a) - len(b)) > 1:
            return False
        if len(a) == len(b):
            return sum(x != y for x, y in zip(a, b, strict=True)) <= 1
        short, long = sorted((a, b), key=len)
        return any(long[:i] + long[i + 1 :] == short for i in range(len(long)))

    names = sorted({m.rsplit(".", 1)[1] for m in import_graph() if m.startswith("doorlab.pset.")})
    assert len(names) > 40
    close = [(a, b) for i, a in enumerate(names) for b in names[i + 1 :] if one_edit_apart(a, b)]
    assert close == []
