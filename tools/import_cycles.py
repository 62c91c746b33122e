"""Import circles of the installed package, counted from the sources (no import is executed).

    .venv/bin/python tools/import_cycles.py            # circles through any import
    .venv/bin/python tools/import_cycles.py --top      # circles through module-level imports only

Reads pyproject.toml's ``[tool.setuptools]`` packages and package-dir to map folders to packages
(``solver/approx/`` → ``wavebrdf.solver.approx``, ...), collects every ``import wavebrdf…`` / ``from wavebrdf…``
of every module (module level and inside functions, separately), and prints the strongly
connected components of the import graph with more than one module (each an import circle),
the function-level imports per module, and exits 1 when a circle exists.
"""

from __future__ import annotations

import argparse
import ast
import sys
import tomllib
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def modules() -> dict[str, Path]:
    """Module name → source file of every module of every package pyproject.toml installs."""
    setuptools = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    folders = setuptools["package-dir"]
    out = {}
    for package in setuptools["packages"]:
        base = max((k for k in folders if package == k or package.startswith(k + ".")), key=len)
        folder = ROOT / folders[base] / Path(*package[len(base):].lstrip(".").split(".")) if package != base \
            else ROOT / folders[base]
        for path in sorted(folder.glob("*.py")):
            out[package if path.stem == "__init__" else f"{package}.{path.stem}"] = path
    return out


def imports(path: Path, name: str, known: set[str]) -> list[tuple[str, bool, int]]:
    """(imported package module, at module level?, the import statement's line) for each import of
    ``path`` (module ``name``)."""
    tree = ast.parse(path.read_text(), str(path))
    top = {id(node) for node in tree.body}
    top |= {id(n) for node in tree.body if isinstance(node, (ast.If, ast.Try)) for n in ast.walk(node)}
    package = name if path.stem == "__init__" else name.rpartition(".")[0]
    out = []
    for node in ast.walk(tree):
        targets = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else []))
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names]
        for target in targets:
            while target and target not in known:
                target = target.rpartition(".")[0]
            if target and target != name:
                out.append((target, id(node) in top, node.lineno))
    return out


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    sys.setrecursionlimit(10_000)
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--top", action="store_true", help="only module-level imports make edges")
    args = parser.parse_args(argv)
    found = modules()
    graph, local = {}, Counter()
    for name, path in found.items():
        edges = imports(path, name, set(found))
        graph[name] = {t for t, at_top, _ in edges if at_top or not args.top}
        local[name] = len({line for _, at_top, line in edges if not at_top})
    cycles = circles(graph)
    print(f"{len(found)} modules, {sum(map(len, graph.values()))} import edges, "
          f"{sum(local.values())} function-level package import statements")
    for name, count in local.most_common(10):
        if count:
            print(f"  {count:3d} function-level in {name}")
    print(f"{len(cycles)} import circle(s)" + ("" if not cycles else ":"))
    for component in cycles:
        print("  " + " ↔ ".join(m.removeprefix("wavebrdf.") for m in component))
    return 1 if cycles else 0


if __name__ == "__main__":
    sys.exit(main())
