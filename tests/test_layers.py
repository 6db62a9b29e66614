"""The project's layers point only down, and no module imports itself back: read from the source.

Layers, lowest first (docs/design.md, "Layers"):

0. ``detector``: scans, structure options and their maths, the geometry of poses.
1. ``pipe_env`` simulation: networks, generator, world, robot, LiDAR, ray casting, plotting.
2. ``primitives``: motion primitives, sequences and the executor.
3. ``pipe_env.envs``: the Gymnasium environments, the plants, the sensing models.
4. ``agents``: policies, training, evaluation, scenarios and the CLI.

Every ``import`` statement counts, function-level ones included. Imports under
``if TYPE_CHECKING:`` never run, so they may form cycles, but they must still point down.
The one deliberate exception is not an import: ``pipe_env/__init__.py`` registers the
environment ids with Gymnasium by entry-point *strings* (``"pipe_env.envs:PipeNavEnv"``), which
Gymnasium imports only when an environment is made.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("detector", "pipe_env", "primitives", "agents")
LAYER_NAMES = ("detector", "pipe_env simulation", "primitives", "pipe_env.envs", "agents")
#: Cycles still to be taken apart (none).
KNOWN_CYCLES: list[list[str]] = []


def layer_of(module: str) -> int:
    """The layer index of a project module (see the module docstring)."""
    if module == "pipe_env.envs" or module.startswith("pipe_env.envs."):
        return 3
    return {"detector": 0, "pipe_env": 1, "primitives": 2, "agents": 4}[module.split(".")[0]]


def _modules() -> dict[str, Path]:
    out: dict[str, Path] = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _imports(module: str, path: Path, modules: dict[str, Path]) -> list[tuple[str, int, bool]]:
    """(imported project module, line, under TYPE_CHECKING) for every import in ``path``."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: list[tuple[str, int, bool]] = []

    def visit(node: ast.AST, typing_only: bool) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node):
            for child in node.body:
                visit(child, True)
            for child in node.orelse:
                visit(child, typing_only)
            return
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                source = ".".join(base + ([node.module] if node.module else []))
            else:
                source = node.module or ""
            for alias in node.names:  # ``from pkg import submodule`` imports the submodule
                sub = f"{source}.{alias.name}"
                targets.append(sub if sub in modules else source)
        for target in targets:
            # ``import a.b.c`` runs a.b.c; keep the longest project module it names
            while target and target not in modules:
                target = target.rpartition(".")[0]
            if target and target != module:
                found.append((target, getattr(node, "lineno", 0), typing_only))
        for child in ast.iter_child_nodes(node):
            visit(child, typing_only)

    visit(ast.parse(path.read_text()), False)
    return found


MODULES = _modules()
EDGES = {m: _imports(m, p, MODULES) for m, p in MODULES.items()}


def test_layers_are_assigned_as_documented() -> None:
    assert len(MODULES) > 50, "the module reader found too few modules"
    assert layer_of("detector.scan") == 0
    assert layer_of("pipe_env.network") == layer_of("pipe_env.robot_limits") == 1
    assert layer_of("primitives.executor") == 2
    assert layer_of("pipe_env.envs") == layer_of("pipe_env.envs.plant_full") == 3
    assert layer_of("agents.cli") == 4
    # every Python package at the top of the project is one of the layered ones
    top = {p.parent.name for p in ROOT.glob("*/__init__.py")}
    assert top <= set(PACKAGES), top - set(PACKAGES)


def test_imports_point_only_down() -> None:
    upward = [
        f"{m} (layer {LAYER_NAMES[layer_of(m)]}) imports {t} (layer {LAYER_NAMES[layer_of(t)]}) "
        f"at line {line}"
        for m, edges in EDGES.items()
        for t, line, _ in edges
        if layer_of(t) > layer_of(m)
    ]
    assert upward == []


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def connect(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            connect(v)
    return out


def test_no_module_cycle() -> None:
    # A package's __init__ re-exports its modules; a module below it never needs it.
    graph = {
        m: {t for t, _, typing_only in edges if not typing_only and not m.startswith(t + ".")}
        for m, edges in EDGES.items()
    }
    assert [c for c in _cycles(graph) if c not in KNOWN_CYCLES] == []


@pytest.mark.parametrize(
    ("graph", "expected"),
    [
        ({"a": {"b"}, "b": {"a"}}, [["a", "b"]]),
        ({"a": {"b"}, "b": {"c"}, "c": set()}, []),
        ({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}, [["a", "b", "c"]]),
    ],
)
def test_cycle_finder_finds_cycles(graph: dict[str, set[str]], expected: list[list[str]]) -> None:
    assert _cycles(graph) == expected


def test_import_reader_sees_function_level_and_relative_imports(tmp_path: Path) -> None:
    source = tmp_path / "mod.py"
    source.write_text(
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n    from agents import cli\n"
        "def f():\n    from primitives.steps import Step\n"
    )
    modules = {"x.mod": source, "agents.cli": source, "primitives.steps": source}
    edges = _imports("x.mod", source, modules)
    assert ("agents.cli", 3, True) in edges
    assert ("primitives.steps", 5, False) in edges
