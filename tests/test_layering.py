"""The package's layering (docs/architecture.md), read from the sources by tools/import_cycles.py:
no import circle through any import (module level or inside a function); ``solver`` never
imports ``jobs`` or the Mitsuba plugins; the method packages ``solver.approx``, ``solver.bem3d``
and ``solver.fiber`` never import each other."""

from __future__ import annotations

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
METHOD_PACKAGES = ("wavebrdf.solver.approx", "wavebrdf.solver.bem3d", "wavebrdf.solver.fiber")


def _checker():
    spec = importlib.util.spec_from_file_location("import_cycles", ROOT / "tools" / "import_cycles.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _graph():
    checker = _checker()
    found = checker.modules()
    return checker, {name: {t for t, _, _ in checker.imports(path, name, set(found))} for name, path in found.items()}


def test_no_import_circle():
    checker, graph = _graph()
    assert len(graph) > 90, "the checker found too few modules: its package-dir mapping is wrong"
    assert checker.circles(graph) == []


def test_the_checker_finds_a_planted_circle():
    checker = _checker()
    assert checker.circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_solver_never_imports_the_batch_layer_or_the_plugins():
    _, graph = _graph()
    bad = {(m, t) for m, targets in graph.items() if m.startswith("wavebrdf.solver") for t in targets
           if t.startswith(("wavebrdf.jobs", "wavebrdf.mitsuba"))}
    assert not bad, sorted(bad)


def test_method_packages_never_import_each_other():
    _, graph = _graph()

    def package(name):
        return next((p for p in METHOD_PACKAGES if name == p or name.startswith(p + ".")), None)

    bad = {(m, t) for m, targets in graph.items() for t in targets
           if package(m) and package(t) and package(m) != package(t)}
    assert not bad, sorted(bad)
