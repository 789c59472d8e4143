"""The package's shape, checked: no import circle between modules or between packages, the
boundaries docs/architecture.md draws, and no module over MAX_LINES.

Imports are read from the source (``ast``), at module level and inside functions alike;
imports under ``if TYPE_CHECKING:`` are for type checkers only and are left out. Importing
``a.b.c`` is an edge to ``a.b.c`` (not to ``a.b``'s ``__init__``).
"""

from __future__ import annotations

import ast
import re
from functools import cache
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("hilsim", "drivers")
#: no module is longer (lines)
MAX_LINES = 600


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


@cache
def _modules() -> dict[str, Path]:
    return {
        _module_name(p): p
        for pkg in PACKAGES
        for p in sorted((REPO / pkg).rglob("*.py"))
        if "__pycache__" not in p.parts
    }


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING"
    )


def _imports(path: Path, name: str) -> set[str]:
    """Modules of this repository that ``path`` imports (resolved to existing modules)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found: set[str] = set()
    is_pkg = path.name == "__init__.py"

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child):
                for other in child.orelse:
                    visit(other)
                continue
            if isinstance(child, ast.Import):
                found.update(a.name for a in child.names)
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:
                    anchor = name.split(".")
                    anchor = anchor[: len(anchor) - child.level + (1 if is_pkg else 0)]
                    base = ".".join([*anchor, base] if base else anchor)
                for a in child.names:  # a submodule by name, else a name from ``base``
                    sub = f"{base}.{a.name}"
                    found.add(sub if sub in _modules() else base)
            visit(child)

    visit(tree)
    mods = _modules()
    return {m for m in found if m in mods and m != name}


@cache
def _graph() -> dict[str, frozenset[str]]:
    return {name: frozenset(_imports(path, name)) for name, path in _modules().items()}


def _cycles(graph: dict[str, frozenset[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def strong(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            strong(v)
    return out


def _reach(start: str) -> set[str]:
    graph, seen, todo = _graph(), set(), [start]
    while todo:
        m = todo.pop()
        if m not in seen:
            seen.add(m)
            todo.extend(graph.get(m, ()))
    return seen


def test_the_import_walk_sees_the_known_edges() -> None:
    """The walk itself works: edges we know exist are found (else the tests below are void)."""
    g = _graph()
    assert "hilsim.show.loop" in g["hilsim.show.session"]
    assert "drivers.protocol2.wire_time" in g["hilsim.show.session"]
    assert "hilsim.show.session" in g["hilsim.cli.run"]  # an import inside a function
    assert "hilsim.show.session" not in g["hilsim.show.loop"]  # only under TYPE_CHECKING there


def test_no_import_circle() -> None:
    assert _cycles(_graph()) == []


def _package(module: str) -> str:
    """The room a module lives in: ``hilsim.show.loop`` -> ``hilsim.show``; a loose module
    (``hilsim.exit_codes``) is its own room."""
    return ".".join(module.split(".")[:2])


def _rooms(graph: dict[str, frozenset[str]]) -> dict[str, frozenset[str]]:
    """The module graph folded into packages (edges inside one package dropped)."""
    rooms: dict[str, set[str]] = {}
    for m, deps in graph.items():
        here = _package(m)
        rooms.setdefault(here, set()).update(p for d in deps if (p := _package(d)) != here)
    return {k: frozenset(v) for k, v in rooms.items()}


def test_no_import_circle_between_packages() -> None:
    """Rooms point one way: cli -> show -> {live, telemetry, rig, targets, safety, dynamics}
    -> drivers. A circle between two packages is a circle even when no two modules make one."""
    assert _cycles(_rooms(_graph())) == []


def test_the_package_walk_sees_a_package_circle() -> None:
    g = {
        "hilsim.rig.model": frozenset({"hilsim.telemetry.format"}),
        "hilsim.telemetry.plots": frozenset({"hilsim.rig"}),
    }
    assert _cycles(_rooms(g)) == [["hilsim.rig", "hilsim.telemetry"]]


def test_the_cycle_finder_finds_a_circle() -> None:
    g = {"a": frozenset({"b"}), "b": frozenset({"c"}), "c": frozenset({"a"}), "d": frozenset()}
    assert _cycles(g) == [["a", "b", "c"]]


@pytest.mark.parametrize(
    ("importer", "forbidden"),
    [
        ("drivers.dynamixel", "drivers.dxlsim"),  # the driver stands without the emulator
        ("drivers.dxlsim", "drivers.dynamixel"),  # the emulator speaks protocol2, not the SDK
        ("drivers.protocol2", "drivers.dynamixel"),
        ("drivers.protocol2", "drivers.dxlsim"),
        ("drivers.protocol1", "drivers.dynamixel"),  # both sides' facts, for either side
        ("drivers.protocol1", "drivers.dxlsim"),
        ("drivers.p1bus", "drivers.dxlsim"),  # the host side stands without the emulator
        ("drivers.dxlsim", "drivers.p1bus"),
        ("drivers", "hilsim"),
    ],
)
def test_package_boundaries(importer: str, forbidden: str) -> None:
    bad = sorted(
        f"{m} -> {d}"
        for m, deps in _graph().items()
        if m == importer or m.startswith(importer + ".")
        for d in deps
        if d == forbidden or d.startswith(forbidden + ".")
    )
    assert bad == []


def test_hilsim_run_does_not_reach_the_bench() -> None:
    reached = _reach("hilsim.cli.run")
    assert "hilsim.show.session" in reached and "hilsim.show.loop" in reached
    assert sorted(m for m in reached if m.startswith("hilsim.bench")) == []


def test_protocol2_imports_no_sdk() -> None:
    for name, path in _modules().items():
        if name.startswith(("drivers.protocol2", "drivers.protocol1")):
            code = path.read_text(encoding="utf-8")
            assert not re.search(r"^\s*(from|import) (dynamixel_sdk|scservo_sdk)", code, re.M), name


def test_no_module_is_over_the_limit() -> None:
    """A module does one job a reader can name; past MAX_LINES it does several. Function
    size and branching are ruff's (C901, PLR0912, PLR0915 in pyproject.toml)."""
    long = {
        str(p.relative_to(REPO)): n
        for p in _modules().values()
        if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_LINES
    }
    assert long == {}


def test_no_comment_points_outside_the_repository() -> None:
    """Documents a user of the package does not have: the team's shared folder, its design and
    style notes. The design paper is cited by its title; the facts the code uses live in docs/."""
    pattern = re.compile(
        r"\.\./shared|shared/(?:paper|reviews|reference)|\b(?:DESIGN|STYLE|dynamixel)\.md"
    )
    files = [REPO / "README.md"] + [
        p
        for root in ("hilsim", "drivers", "tests", "tools", "configs", "docs")
        for p in (REPO / root).rglob("*")
        if p.suffix in {".py", ".md", ".toml"} and p != Path(__file__)
    ]
    hits = [
        f"{p.relative_to(REPO)}:{n}: {line.strip()}"
        for p in files
        for n, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
        if pattern.search(line)
    ]
    assert hits == []


def test_no_issue_numbers_in_the_code() -> None:
    """An issue number means nothing to a reader of the package (the tracker is not in it):
    say what the code does and why; the history goes in the commit message."""
    pattern = re.compile(r"\bissue\s*#?\d+", re.I)
    hits = [
        f"{p.relative_to(REPO)}:{n}: {line.strip()}"
        for p in _modules().values()
        for n, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
        if pattern.search(line)
    ]
    assert hits == []
