"""The package's layers: no import cycles between subpackages, counting imports made inside functions too (not
those under ``if TYPE_CHECKING:``, which never run).

A cycle makes the import order matter and ties layers that should change independently (issue 14 removed four:
assembly -> design, flightlog -> runtime, firmware -> runtime, sim <-> runtime).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _layer(module: str) -> str:
    """``groundstation.runtime.fly`` -> ``groundstation.runtime``; top-level modules (``groundstation.errors``) and
    ``sim.*`` are layers of their own."""
    parts = module.split(".")
    return ".".join(parts[:2]) if parts[0] == "groundstation" else parts[0]


def _type_only(tree: ast.Module) -> set[int]:
    """ids of the statements inside ``if TYPE_CHECKING:`` blocks: imports for annotations, never executed."""
    return {id(n) for block in ast.walk(tree) if isinstance(block, ast.If)
            and isinstance(block.test, ast.Name) and block.test.id == "TYPE_CHECKING"
            for stmt in block.body for n in ast.walk(stmt)}


def _imports(path: Path, module: str) -> set[str]:
    out = set()
    tree = ast.parse(path.read_text())
    skip = _type_only(tree)
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")[: -node.level + (path.name == "__init__.py") or None]
                out.add(".".join(base + ([node.module] if node.module else [])))
            elif node.module:
                out.add(node.module)
    return {m for m in out if m.split(".")[0] in ("groundstation", "sim")}


def layer_graph() -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {}
    for pkg in ("groundstation", "sim"):
        for path in (ROOT / pkg).rglob("*.py"):
            module = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
            src = _layer(module)
            graph.setdefault(src, set()).update(_layer(m) for m in _imports(path, module) if _layer(m) != src)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Every elementary cycle's smallest representative found by depth-first search from each node."""
    found = set()
    for start in graph:
        stack = [(start, [start])]
        while stack:
            node, path = stack.pop()
            for nxt in graph.get(node, ()):
                if nxt == start:
                    i = path.index(min(path))
                    found.add(tuple(path[i:] + path[:i]))
                elif nxt not in path and nxt > start:
                    stack.append((nxt, path + [nxt]))
    return sorted(list(c) for c in found)


def test_the_cycle_finder_finds_a_cycle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycles_between_layers():
    graph = layer_graph()
    assert "groundstation.runtime" in graph["groundstation.cli"]  # the graph sees real imports
    assert cycles(graph) == []


def test_nothing_imports_the_command_line():
    users = [layer for layer, deps in layer_graph().items() if "groundstation.cli" in deps]
    assert users == ["groundstation.launch"]  # the entry point (``groundstation``, ``python -m``) and nothing else
