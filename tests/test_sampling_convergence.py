"""benchmarks/sampling_convergence.py: a stored full-wave pair split into the specular cone and the
rest, and a cheap rung's BRDF on a surface generated at several cells."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from test_trade_store import TINY_SCENE

from wavebrdf.jobs.compare import Measurement
from wavebrdf.solver.surface import HeightField, generate

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def _load():
    if str(BENCHMARKS) not in sys.path:
        sys.path.insert(0, str(BENCHMARKS))
    spec = importlib.util.spec_from_file_location("sampling_convergence", BENCHMARKS / "sampling_convergence.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def sampling(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    module = _load()
    monkeypatch.setattr(module.trade, "WORK", tmp_path)
    return module


def _lobe(scene, centre_u: float, width: float) -> np.ndarray:
    """A smooth (s, p) BRDF pair peaked at (centre_u, 0)."""
    U, V = scene.grid.uv
    f = 1.0 + 50.0 * np.exp(-((U - centre_u) ** 2 + V**2) / width**2)
    return np.stack([f, 1.2 * f])


def test_a_pair_scaled_everywhere_differs_by_the_scale_in_and_out_of_the_cone(sampling, tmp_path):
    config = tmp_path / "tiny.toml"  # blur σ_u = λ/(π w) = 0.08: the cone |Δu| ≤ 0.16
    config.write_text(TINY_SCENE.format(out=tmp_path / "tiny.h5").replace("waist_um = 0.5", "waist_um = 2.0")
                      .replace("resolution = 16", "resolution = 64"))
    label, scene = sampling.trade.hardest_scene(config)
    fine = _lobe(scene, 0.0, 0.3)
    pair = tmp_path / "tiny_hemispheres_pair_16_24.h5"
    sampling.trade._write_refinement(pair, label, 24, Measurement("bem", label, 1.0, 1.0, 1.0, fine),
                                     Measurement("bem", label, 1.0, 1.0, 1.0, 1.05 * fine), "test")
    r = sampling.pair_split(config, 16)
    assert r["relative_l2"] == pytest.approx(0.05, rel=1e-9)  # the blur is linear
    assert r["cone_power"] == pytest.approx(1.05) and r["rest_power"] == pytest.approx(1.05)

    # a difference far from the mirror direction lies outside the cone
    U, V = scene.grid.uv
    bump = fine + 500.0 * np.exp(-((U - 0.8) ** 2 + V**2) / 0.05**2)
    sampling.trade._write_refinement(pair, label, 24, Measurement("bem", label, 1.0, 1.0, 1.0, fine),
                                     Measurement("bem", label, 1.0, 1.0, 1.0, bump), "test")
    r = sampling.pair_split(config, 16)
    assert r["cone_share"] < 0.01 and r["cone_power"] == pytest.approx(1.0, abs=0.01) and r["rest_power"] > 1.1


def test_the_specular_cone_sits_at_the_mirror_direction_of_oblique_incidence(sampling, tmp_path):
    config = tmp_path / "oblique.toml"  # θ_i = 30° toward +x: the mirror direction at u = −0.5
    config.write_text(TINY_SCENE.format(out=tmp_path / "oblique.h5").replace("waist_um = 0.5", "waist_um = 2.0")
                      .replace("resolution = 16", "resolution = 64").replace("[[0, 0]]", "[[30, 0]]"))
    label, scene = sampling.trade.hardest_scene(config)
    U, V = scene.grid.uv
    fine = _lobe(scene, -0.5, 0.3)
    pair = tmp_path / "tiny_hemispheres_pair_16_24.h5"
    for centre, in_cone in ((-0.5, True), (0.5, False)):
        coarse = fine + 500.0 * np.exp(-((U - centre) ** 2 + V**2) / 0.05**2)
        sampling.trade._write_refinement(pair, label, 24, Measurement("bem", label, 1.0, 1.0, 1.0, fine),
                                         Measurement("bem", label, 1.0, 1.0, 1.0, coarse), "test")
        r = sampling.pair_split(config, 16)
        assert (r["cone_share"] > 0.9) if in_cone else (r["cone_share"] < 0.01), (centre, r)  # blurred: 0.96


def test_a_small_patch_keeps_the_generator_and_its_own_parameters_only():
    sampling_module = _load()
    pits = generate("spherical-pits", cells=40, size_um=2.0, period_um=1.0, radius_um=0.4, depth_um=0.2, seed=4)
    small = sampling_module.small_surface(pits, 1.0, 20)  # the pits record their rim radius, count and fill too
    assert (small.cells, small.size_um, small.parameters["generator"]) == (20, 1.0, "spherical-pits")
    assert {k: small.parameters[k] for k in ("period_um", "radius_um", "depth_um")} == \
        {"period_um": 1.0, "radius_um": 0.4, "depth_um": 0.2}
    np.testing.assert_allclose(small.z, pits.z[:21, :21], atol=1e-12)  # the same pit, on half the patch
    with pytest.raises(SystemExit, match="no generator"):
        sampling_module.small_surface(HeightField(pits.z, 2.0), 1.0, 20)


def test_a_missing_or_unfinished_pair_is_refused_with_the_command_that_makes_it(sampling, tmp_path):
    config = tmp_path / "tiny.toml"
    config.write_text(TINY_SCENE.format(out=tmp_path / "tiny.h5"))
    with pytest.raises(SystemExit, match="--finer-pair"):
        sampling.pair_split(config, 16)
    label, scene = sampling.trade.hardest_scene(config)
    sampling.trade._write_refinement(tmp_path / "tiny_hemispheres_pair_16_24.h5", label, 24,
                                     Measurement("bem", label, 1.0, 1.0, 1.0, None, {}, "stopped"),
                                     Measurement("bem", label, 1.0, 1.0, 1.0, _lobe(scene, 0.0, 0.3)), "test")
    with pytest.raises(SystemExit, match="stopped"):
        sampling.pair_split(config, 16)


def test_a_cheap_rung_on_the_rebuilt_surface_settles_as_the_cells_grow(sampling, tmp_path):
    config = tmp_path / "tiny.toml"
    config.write_text(TINY_SCENE.format(out=tmp_path / "tiny.h5").replace("resolution = 16", "resolution = 64"))
    rows = sampling.rung_convergence(config, "kirchhoff", [64, 16, 32, 128])
    assert [r["cells"] for r in rows] == [16, 32, 64, 128]
    assert rows[-1]["vs_finest"] == 0 and rows[-1]["vs_next"] is None and rows[-1]["cone_power"] == 1
    # the height field converges: each doubling of the cells moves the BRDF less
    assert rows[0]["vs_next"] > rows[1]["vs_next"] > rows[2]["vs_next"] > 0
