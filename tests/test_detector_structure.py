"""The detector package's own structure: its modules share only public names and import one
another without a cycle (function-level imports included), read from the source."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "detector"
#: Cycles known and owned elsewhere (none today).
KNOWN_CYCLES: list[set[str]] = []


def _imports() -> dict[str, list[tuple[str, list[str]]]]:
    """Per detector module: (imported detector module, names taken from it) of every import
    statement anywhere in its source."""
    out: dict[str, list[tuple[str, list[str]]]] = {}
    for path in sorted(PACKAGE.glob("*.py")):
        name = f"detector.{path.stem}" if path.stem != "__init__" else "detector"
        edges: list[tuple[str, list[str]]] = []
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                if node.module == "detector":
                    # ``from detector import fit_kernels``: submodules, or the package's names
                    for alias in node.names:
                        if (PACKAGE / f"{alias.name}.py").exists():
                            edges.append((f"detector.{alias.name}", []))
                        else:
                            edges.append(("detector", [alias.name]))
                elif node.module.startswith("detector."):
                    edges.append((node.module, [a.name for a in node.names]))
            elif isinstance(node, ast.Import):
                edges += [(a.name, []) for a in node.names if a.name.startswith("detector.")]
        out[name] = edges
    return out


def test_no_private_names_are_imported_between_detector_modules() -> None:
    private = [
        (module, target, name)
        for module, edges in _imports().items()
        for target, names in edges
        for name in names
        if name.startswith("_") and target != module
    ]
    assert private == []


def test_detector_modules_import_one_another_without_a_cycle() -> None:
    graph = {m: {t for t, _ in edges if t != m} for m, edges in _imports().items()}
    # the package's __init__ re-exports; the modules below it must not need it
    graph = {m: ts - {"detector"} if m != "detector" else ts for m, ts in graph.items()}
    state: dict[str, int] = {}
    cycles: list[list[str]] = []

    def visit(m: str, path: list[str]) -> None:
        state[m] = 1
        for t in sorted(graph.get(m, ())):
            if state.get(t) == 1:
                cycles.append(path[path.index(t) :] + [t] if t in path else [m, t])
            elif t not in state:
                visit(t, path + [t])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])
    assert [c for c in cycles if set(c) not in KNOWN_CYCLES] == []
    assert "detector.long_bend" not in graph["detector.branches"] or (
        "detector.branches" not in graph["detector.long_bend"]
    )
