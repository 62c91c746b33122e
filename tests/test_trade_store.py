"""The trade benchmark's kept solves (benchmarks/trade.py ``keep_solve`` / ``stored_solve``): a
full-wave solve is kept the moment it is made and taken again only for the same scene (surface,
wavelength, direction, material, grid, precision) and the same fixed solver options."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from wavebrdf.jobs.compare import Measurement
from wavebrdf.solver.farfield import HemisphereGrid
from wavebrdf.solver.models import SurfaceScene, model_class
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


def _bem_options(**aim):
    return parse_options(model_class("bem").Options, {"method": "aim", "aim": aim}, "model.bem")


@pytest.fixture
def scene():
    surface = generate("hemispheres", cells=40, size_um=2.0, radius_um=0.3, fill=0.3, placement="random", seed=1)
    return SurfaceScene(surface, 0.5, 0.96 - 6.69j, 0.0, 0.0, 1.0, HemisphereGrid(8))


def test_a_kept_solve_is_taken_only_for_its_scene_and_options(trade, tmp_path, scene):
    label = "hemispheres λ=0.5 µm θi=0°"
    options = _bem_options(preconditioner="flat-patch", fit_memory=False)
    brdf = np.random.default_rng(0).random((2, 8, 8))
    solved = Measurement("bem", label, wall_s=12.5, cpu_s=20.25, peak_mb=700.0, brdf=brdf,
                         diagnostics={"products": 42})

    assert trade.keep_solve("study", label, scene, options, solved, "flat patch") is not None
    logged = []
    again = trade.stored_solve("study", label, scene, options, logged.append)
    assert (again.wall_s, again.cpu_s, again.peak_mb, again.model, again.scene) == (12.5, 20.25, 700.0, "bem", label)
    np.testing.assert_array_equal(again.brdf, brdf)
    assert again.diagnostics["products"] == 42 and again.diagnostics["measured_before"].startswith("study_bem_")
    assert "flat patch" in logged[-1]
    other_surface = generate("hemispheres", cells=40, size_um=2.0, radius_um=0.3, fill=0.3, placement="random", seed=2)
    for other in (dataclasses.replace(scene, surface=other_surface), dataclasses.replace(scene, wavelength_um=0.7),
                  dataclasses.replace(scene, index=1.5 + 0j), dataclasses.replace(scene, phi_i=np.pi / 2),
                  dataclasses.replace(scene, waist_um=2.5), dataclasses.replace(scene, grid=HemisphereGrid(16)),
                  dataclasses.replace(scene, precision="single")):
        assert trade.stored_solve("study", label, other, options) is None
    assert trade.stored_solve("study", label, scene, _bem_options(preconditioner="flat-patch", fit_memory=False,
                                                                   restart=30)) is None
    assert trade.stored_solve("other_study", label, scene, options) is None
    # the memory budget the solve was given does not change what fixed options compute
    assert trade.stored_solve("study", label, dataclasses.replace(scene, memory_budget_bytes=2**33), options)
    assert not list(tmp_path.glob(".*.tmp"))  # written whole


def test_a_failed_solve_or_one_fitted_to_the_memory_at_hand_is_not_kept(trade, tmp_path, scene):
    fixed = _bem_options(fit_memory=False)
    failed = Measurement("bem", "s", wall_s=1.0, cpu_s=1.0, peak_mb=1.0, failure="did not converge")
    assert trade.keep_solve("study", "s", scene, fixed, failed) is None
    fitted = _bem_options()  # fit_memory: the settings that ran depend on the machine's memory
    solved = Measurement("bem", "s", wall_s=1.0, cpu_s=1.0, peak_mb=1.0, brdf=np.ones((2, 8, 8)))
    assert trade.keep_solve("study", "s", scene, fitted, solved) is None
    assert trade.stored_solve("study", "s", scene, fitted) is None
    assert not list(tmp_path.iterdir())


# hemispheres 0.54 µm across: 4 grid spacings at the 12 cells of the pair below the config (16 cells)
TINY_SCENE = """
[study]
name = "tiny_hemispheres"
output = "{out}"

[surface]
size_um = 1.6
cells = 16
generator = "hemispheres"
radius_um = 0.27
fill = 0.3
placement = "random"
seed = 3

[material]
n = 1.5

[illumination]
wavelengths_um = [0.5]
directions_deg = [[0, 0]]
waist_um = 0.5

[model]
name = "bem"
method = "aim"

[model.aim]
preconditioner = "flat-patch"
solver = "gmres"
restart = 30
deflate = 0
fit_memory = false

[output]
resolution = 16

[compare]
models = ["kirchhoff"]
reference = "bem"
"""


def test_a_pairs_solves_are_kept_and_taken_by_the_pair_its_convergence_row_and_the_comparison(trade, tmp_path,
                                                                                            monkeypatch, models_run):
    """The wiring of the kept solves through the benchmark: a ``finer_pair`` at the config's cells
    with the config's own settings solves twice; run again, it solves nothing; the convergence row
    takes its fine solve, and the comparison its coarse one as BEM's (only the other rung runs); a
    pair below the config's cells is listed with the pairs beside the table's spacing."""
    monkeypatch.setattr(trade, "ROOT", tmp_path)
    monkeypatch.setattr(trade, "WORK", tmp_path / "work")
    config = tmp_path / "suite" / "tiny.toml"
    config.parent.mkdir()
    config.write_text(TINY_SCENE.format(out=tmp_path / "tiny.h5"))
    ran = models_run
    log = []

    pair = trade.finer_pair(config, 16, log.append, "flat-patch")
    assert ran == [("bem", 16), ("bem", 24)]
    fine, coarse, settings = trade._stored_pair("tiny_hemispheres", trade.hardest_scene(config)[0],
                                                trade.hardest_scene(config)[1].surface, 24)
    assert not fine.failure and not coarse.failure and settings.startswith("the flat patch")

    ran.clear()
    assert trade.finer_pair(config, 16, log.append, "flat-patch") == pair
    assert ran == []
    again, _, _ = trade._stored_pair("tiny_hemispheres", trade.hardest_scene(config)[0],
                                     trade.hardest_scene(config)[1].surface, 24)
    np.testing.assert_array_equal(again.brdf, fine.brdf)

    row = trade.convergence(config, False, log.append, run=False)
    assert ran == [] and row["cells"] == 16 and row["fine_cells"] == 24 and not row["failure"]
    assert (row["cpu_s"], row["fine_cpu_s"]) == (coarse.cpu_s, fine.cpu_s)

    # the convergence store's fine solve is the next pair's coarse one, for the same surface only
    # (other settings than the kept solves': only the store can supply the 24² solve)
    trade.finer_pair(config, 24, log.append, "flat-patch", restart=20)
    assert ran == [("bem", 36)]
    import h5py

    with h5py.File(trade.WORK / "tiny_hemispheres_converged.h5", "a") as h5:
        h5.attrs["fine_surface_digest"] = "another surface"
    ran.clear()
    trade.finer_pair(config, 24, log.append, "flat-patch", restart=20)
    assert ran == [("bem", 24)] and any("converged.h5's 24² solve is not known to be of this surface" in line
                                        for line in log)
    ran.clear()

    trade.compare_suite([config], False, log.append)
    assert ran == [("kirchhoff", 16)]
    label = trade.hardest_scene(config)[0]
    bem = trade.stored_measurements(trade._stored(config))[label, "bem"]
    np.testing.assert_array_equal(bem.brdf, coarse.brdf.astype(np.float32))  # comparison files keep float32
    assert bem.cpu_s == coarse.cpu_s
    assert trade.stored_measurements(trade._stored(config))[label, "kirchhoff"].brdf is not None

    # a pair below the config's cells (its surface rebuilt there) is listed beside the table's own check
    ran.clear()
    trade.finer_pair(config, 12, log.append, "flat-patch")
    assert ran == [("bem", 12), ("bem", 18)]
    rows = trade.finer_pairs([config])
    assert [(r["cells"], r["fine_cells"], r["refinement"]) for r in rows] == [(12, 18, "refined"), (24, 36, "refined")]


def test_a_random_realization_keeps_its_digest_at_its_own_cells_and_is_refused_below_them(trade, tmp_path,
                                                                                          monkeypatch, models_run):
    """A pair at a random config's own cells is of the config's own surface (its kept solve is then
    the comparison's); below them the realization does not exist, and the pair is refused before
    anything is solved or written."""
    from wavebrdf.solver.surface import SurfaceError

    rough = generate("gaussian", cells=24, size_um=2.0, rms_height_um=0.05, correlation_um=0.5, seed=4)
    assert trade.surface_at(rough, 24) is rough
    assert np.allclose(trade.surface_at(rough, 48).z[::2, ::2], rough.z, atol=1e-13, rtol=0)  # refined: same nodes
    monkeypatch.setattr(trade, "ROOT", tmp_path)
    monkeypatch.setattr(trade, "WORK", tmp_path / "work")
    config = tmp_path / "suite" / "rough.toml"
    config.parent.mkdir()
    config.write_text(TINY_SCENE.format(out=tmp_path / "rough.h5").replace(
        'generator = "hemispheres"\nradius_um = 0.27\nfill = 0.3\nplacement = "random"',
        'generator = "gaussian"\nrms_height_um = 0.03\ncorrelation_um = 0.4'))
    ran = models_run
    with pytest.raises(SurfaceError, match="'gaussian' realization is drawn on its grid"):
        trade.finer_pair(config, 12, lambda line: None, "flat-patch")
    assert ran == [] and not (tmp_path / "work").exists()  # nothing solved or written

    # at its own cells the pair's coarse solve is the config's own surface: the comparison takes it
    trade.finer_pair(config, 16, lambda line: None, "flat-patch")
    assert ran == [("bem", 16), ("bem", 24)]
    ran.clear()
    trade.compare_suite([config], False, lambda line: None)
    assert ran == [("kirchhoff", 16)]


TINY_STUDY = """
[study]
name = "tiny_flat"
output = "tiny_flat.h5"
[surface]
size_um = 1.6
cells = 24
generator = "gaussian"
rms_height_um = 0.005
correlation_um = 0.4
seed = 3
[material]
name = "glass"
[illumination]
wavelengths_um = [{wavelength}]
directions_deg = [[30, 0]]
waist_um = 0.3
[model]
name = "bem"
method = "aim"
[output]
resolution = 24
[compare]
reference = "bem"
models = {models}
{extra}"""


def _tiny_study(trade, tmp_path, monkeypatch) -> Path:
    """The path of a one-scene glass study (24 cells, AIM BEM) in a suite folder of ``tmp_path``,
    which the benchmark then takes as its root; written by :func:`_write_tiny_study`."""
    monkeypatch.setattr(trade, "ROOT", tmp_path)
    suite = tmp_path / "tiny"
    suite.mkdir()
    return suite / "flat.toml"


def _write_tiny_study(config: Path, trade, wavelength: float = 0.5, models=("bem", "po"), extra: str = "") -> None:
    config.write_text(TINY_STUDY.format(wavelength=wavelength, models=json.dumps(list(models)), extra=extra))
    trade._scenes.cache_clear()  # the benchmark plans a config's scenes once per run


def test_rerun_runs_again_only_the_named_rungs_on_a_stored_comparison(trade, tmp_path, monkeypatch):
    """``--rerun po``: po runs again with its current options while BEM's and the other rungs'
    stored BRDFs and times are taken as they are; without it a stored comparison is not rerun."""
    config = _tiny_study(trade, tmp_path, monkeypatch)
    models = ("bem", "kirchhoff", "po")
    _write_tiny_study(config, trade, models=models)
    log = lambda message: None  # noqa: E731
    trade.compare_suite([config], False, log)
    before = trade.stored_measurements(trade._stored(config))
    label = next(label for label, model in before if model == "po")
    trade.compare_suite([config], False, log)  # stored: nothing runs again
    assert trade.stored_measurements(trade._stored(config))[label, "po"].wall_s == before[label, "po"].wall_s
    _write_tiny_study(config, trade, models=models, extra='[compare.po]\nincidence = "beam"')
    trade.compare_suite([config], False, log, rerun=("po",))
    after = trade.stored_measurements(trade._stored(config))
    for model in ("bem", "kirchhoff"):
        assert np.array_equal(after[label, model].brdf, before[label, model].brdf, equal_nan=True)
        assert after[label, model].cpu_s == before[label, model].cpu_s
    assert not np.array_equal(after[label, "po"].brdf, before[label, "po"].brdf, equal_nan=True)  # lit by the beam


def test_rerun_compares_whole_a_config_whose_stored_scenes_changed(trade, tmp_path, monkeypatch):
    """A stored comparison of other scenes (the config's wavelengths changed since) is not reused
    by ``--rerun``: the config is compared whole, BEM included, on its current scenes."""
    config = _tiny_study(trade, tmp_path, monkeypatch)
    _write_tiny_study(config, trade, wavelength=0.5)
    log = lambda message: None  # noqa: E731
    trade.compare_suite([config], False, log)
    _write_tiny_study(config, trade, wavelength=0.55)
    trade.compare_suite([config], False, log, rerun=("po",))
    after = trade.stored_measurements(trade._stored(config))
    assert {label for label, _ in after} == {label for label, _ in trade._scenes(config)}
    assert all("λ=0.55 µm" in label for label, _ in after)
    assert all(m.failure is None and m.brdf is not None for m in after.values())
