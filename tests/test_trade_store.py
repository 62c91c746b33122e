"""The trade benchmark's stored solves (benchmarks/trade.py ``keep_solve`` / ``stored_solve``): a
full-wave solve is kept the moment it is made and taken again only for the same scene, surface and
options."""

from __future__ import annotations

import dataclasses
import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from wavebrdf.jobs.compare import Measurement
from wavebrdf.solver.models import model_class
from wavebrdf.solver.options import parse_options
from wavebrdf.solver.surface import generate

TRADE = Path(__file__).resolve().parents[1] / "benchmarks" / "trade.py"


@pytest.fixture
def trade(tmp_path, monkeypatch):
    spec = importlib.util.spec_from_file_location("trade_benchmark", TRADE)
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)  # its dataclasses resolve their module
    spec.loader.exec_module(module)
    monkeypatch.setattr(module, "WORK", tmp_path)
    return module


def test_a_kept_solve_is_taken_only_for_its_scene_surface_and_options(trade, tmp_path):
    label = "hemispheres λ=0.5 µm θi=0°"
    surface = generate("hemispheres", cells=40, size_um=2.0, radius_um=0.3, fill=0.3, placement="random", seed=1)
    other_surface = generate("hemispheres", cells=40, size_um=2.0, radius_um=0.3, fill=0.3, placement="random", seed=2)
    options = parse_options(model_class("bem").Options, {"method": "aim", "aim": {"preconditioner": "flat-patch"}},
                            "model.bem")
    other_options = dataclasses.replace(options, aim=dataclasses.replace(options.aim, restart=30))
    brdf = np.random.default_rng(0).random((2, 8, 8))
    solved = Measurement("bem", label, wall_s=12.5, cpu_s=20.25, peak_mb=700.0, brdf=brdf)

    assert trade.keep_solve("study", label, surface, options, solved, "flat patch") is not None
    logged = []
    again = trade.stored_solve("study", label, surface, options, logged.append)
    assert (again.wall_s, again.cpu_s, again.peak_mb, again.model, again.scene) == (12.5, 20.25, 700.0, "bem", label)
    np.testing.assert_array_equal(again.brdf, brdf)
    assert trade.stored_solve("study", label, surface, other_options, logged.append) is None
    assert "other options (flat patch): not used" in logged[-1]
    assert trade.stored_solve("study", label, other_surface, options) is None  # another realization: another file
    assert trade.stored_solve("study", "hemispheres λ=0.7 µm θi=0°", surface, options) is None
    assert trade.stored_solve("other_study", label, surface, options) is None
    assert not list(tmp_path.glob(".*.tmp"))  # written whole


def test_a_failed_solve_is_not_kept(trade, tmp_path):
    surface = generate("flat", cells=20, size_um=1.0)
    options = parse_options(model_class("bem").Options, {"method": "aim"}, "model.bem")
    failed = Measurement("bem", "flat", wall_s=1.0, cpu_s=1.0, peak_mb=1.0, failure="did not converge")
    assert trade.keep_solve("study", "flat", surface, options, failed) is None
    assert trade.stored_solve("study", "flat", surface, options) is None
    assert not list(tmp_path.iterdir())
