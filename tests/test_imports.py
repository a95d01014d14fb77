"""The module import graph of warp_sph/, kernels/ and benchmarks/ has no cycle (issue #33).

Built from the source with ``ast`` (no import runs): every ``import`` and ``from ... import``, at
module level or inside a function, is an arrow from the importing module to the module it names
(``from pkg import name`` points at ``pkg.name`` when that is a module, else at ``pkg``). A function-
level import does not make a circle go away, so it counts like any other.
"""
from __future__ import annotations

import ast
import functools
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# source folder -> the dotted package it is installed as (pyproject.toml's package-dir)
PACKAGES = {"warp_sph": "warp_sph", "kernels": "warp_sph.kernels", "benchmarks": "warp_sph.benchmarks"}


def _modules() -> dict[str, tuple[Path, bool]]:
    """Dotted module name -> (file, is a package's __init__)."""
    mods = {}
    for folder, dotted in PACKAGES.items():
        for p in (ROOT / folder).rglob("*.py"):
            rel = p.relative_to(ROOT / folder).with_suffix("").parts
            is_pkg = rel[-1] == "__init__"
            name = ".".join((dotted,) + (rel[:-1] if is_pkg else rel))
            mods[name] = (p, is_pkg)
    return mods


@functools.cache
def import_graph() -> dict[str, set[str]]:
    """Module -> the project modules it imports (anywhere in its body)."""
    mods = _modules()
    graph = {}
    for name, (path, is_pkg) in mods.items():
        package = name if is_pkg else name.rpartition(".")[0]
        deps = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")
                    base = base[:len(base) - (node.level - 1)]
                    stem = ".".join(base + ([node.module] if node.module else []))
                else:
                    stem = node.module or ""
                targets = [f"{stem}.{a.name}" if f"{stem}.{a.name}" in mods else stem for a in node.names]
            else:
                continue
            for t in targets:
                while t and t not in mods:  # `import a.b.c` of a name inside a module: its module
                    t = t.rpartition(".")[0]
                if t and t != name:
                    deps.add(t)
        graph[name] = deps
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle as a path (first == last), or None."""
    state, stack = {}, []

    def visit(n):
        state[n] = "open"
        stack.append(n)
        for d in sorted(graph.get(n, ())):
            if state.get(d) == "open":
                return stack[stack.index(d):] + [d]
            if d not in state:
                found = visit(d)
                if found:
                    return found
        stack.pop()
        state[n] = "done"
        return None

    for n in sorted(graph):
        if n not in state:
            found = visit(n)
            if found:
                return found
    return None


def test_the_graph_sees_function_level_and_relative_imports():
    # the oracle itself: a known arrow of each kind is found
    g = import_graph()
    assert "warp_sph.core.errors" in g["warp_sph.cli"]  # inside a function, relative
    assert "warp_sph.benchmarks.records" in g["warp_sph.benchmarks.cases"]  # module level, relative
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


def test_no_import_cycle():
    cycle = find_cycle({k: set(v) for k, v in import_graph().items()})
    assert cycle is None, "import cycle: " + " -> ".join(cycle)
