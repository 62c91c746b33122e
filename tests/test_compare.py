"""``wavebrdf compare`` machinery (jobs/compare.py): measured runs, metrics against the reference,
failures reported in the table, and the files written."""

from __future__ import annotations

import csv

import h5py
import numpy as np
import pytest

from references import fresnel_reflectance
from wavebrdf.jobs.compare import Measurement, choose_reference, compare_scenes, warning_kinds
from wavebrdf.jobs.store import StoreError, read_comparison
from wavebrdf.solver.farfield import HemisphereGrid
from wavebrdf.solver.models import SurfaceScene, rung_order
from wavebrdf.solver.surface import generate


@pytest.fixture(scope="module")
def flat_scene():
    surface = generate("flat", cells=100, size_um=20.0)
    return SurfaceScene(surface, 0.5, 1.5 + 0j, np.deg2rad(30.0), 0.2, 4.0, HemisphereGrid(96))


def test_a_model_against_itself_and_a_failing_one(flat_scene, tmp_path):
    """kirchhoff as its own reference: every error 0 and its albedo Fresnel's; a model that fails
    on the scene (an option the scene cannot satisfy) becomes a row with its failure, not a crash."""
    comparison = compare_scenes([("flat glass 30°", flat_scene)], ["kirchhoff", "bem"], reference="kirchhoff",
                                options={"bem": {"method": "dense", "no_such_key": 1}})
    rows = {r["model"]: r for r in comparison.rows}
    ref = rows["kirchhoff"]
    assert ref["rel_l2"] == 0 and ref["misplaced"] == 0 and ref["albedo_diff"] == 0
    assert ref["albedo"] == pytest.approx(np.mean(fresnel_reflectance(1.0, 1.5, np.deg2rad(30.0))), rel=5e-3)
    assert ref["wall_s"] > 0 and ref["cpu_s"] >= 0 and ref["peak_mb"] >= 0
    assert rows["bem"]["failure"] and "no_such_key" in rows["bem"]["failure"]
    paths = comparison.write(tmp_path / "al_waist0.6_trade")  # a dot in the study's name is kept
    assert [p.name for p in paths] == [f"al_waist0.6_trade{e}" for e in (".csv", ".md", ".png", ".h5", "_gallery.png")]
    assert all(p.stat().st_size > 0 for p in paths)
    with open(paths[0]) as fh:
        table = list(csv.DictReader(fh))
    assert [r["model"] for r in table] == ["kirchhoff", "bem"]
    with h5py.File(paths[3]) as h5:
        assert list(h5["table/model"].asstr()) == ["kirchhoff", "bem"]
        assert h5["brdf"]["0000"].shape == (2, 96, 96)
    table, brdfs = read_comparison(paths[3])
    assert table["model"] == ["kirchhoff", "bem"] and table["failure"][1] == rows["bem"]["failure"]
    assert list(brdfs) == [("flat glass 30°", "kirchhoff")]  # the failed model has no BRDF
    assert not list(tmp_path.glob(".*.tmp"))  # written atomically: no temporary left
    nothing = compare_scenes([("flat glass 30°", flat_scene)], ["bem"], reference="bem",
                             options={"bem": {"method": "dense", "no_such_key": 1}})
    nothing.write(tmp_path / "failed")  # no row has a metric: the columns are still numbers
    table, _ = read_comparison(tmp_path / "failed.h5")
    assert np.isnan(table["albedo"][0]) and np.isnan(table["rel_l2"][0]) and "no_such_key" in table["failure"][0]
    with pytest.raises(StoreError, match="not a comparison file"):
        read_comparison(write_small_h5(tmp_path / "other.h5"))


def test_every_row_carries_what_its_model_warned_and_a_warned_reference_is_listed(tmp_path, capsys):
    """Rough gold at θ_i = 88° lit by a 1 µm waist: the tangent-plane rungs return more power than
    falls on the patch (a passive surface reflects at most all of it), and each row whose albedo
    exceeds 1 says so in its ``warnings`` (EnergyWarning, as a run's task table), beside the waist
    warning its model raised; flat glass at 30° lit by a waist its patch holds (Fresnel's 0.04)
    carries none. The Markdown
    gives the kinds and lists the warned reference's text in full; ``wavebrdf inspect`` prints the
    file's table the same way, and ``render`` (a study's pictures) refuses it saying what it is."""
    from wavebrdf.solver.materials import Material

    rough = generate("gaussian", cells=120, size_um=6.0, rms_height_um=0.05, correlation_um=0.8, seed=3)
    gold = complex(Material.from_name("gold").index(0.9))
    grazing = SurfaceScene(rough, 0.9, gold, np.deg2rad(88.0), 0.0, 1.0, HemisphereGrid(48))
    comparison = compare_scenes([("gold 88°", grazing)], ["kirchhoff", "stam"], reference="kirchhoff")
    held = SurfaceScene(generate("flat", cells=100, size_um=20.0), 0.5, 1.5 + 0j, np.deg2rad(30.0), 0.0, 3.0,
                        HemisphereGrid(48))
    calm = compare_scenes([("flat glass 30°", held)], ["kirchhoff"], reference="kirchhoff")
    for row in comparison.rows:
        assert row["albedo"] > 1.0 + 1e-3, row  # the scene is beyond these rungs' validity
        assert "EnergyWarning: albedo (s, p)" in row["warnings"] and f"{row['model']} returns" in row["warnings"]
        assert f"ValidityWarning: {row['model']}: the footprint of waist 1 µm" in row["warnings"]
    assert calm.rows[0]["albedo"] < 0.1 and calm.rows[0]["warnings"] == ""
    table = comparison.markdown()
    assert "| EnergyWarning, ValidityWarning |" in table
    assert warning_kinds("a solve's note stored without its kind") == "warned" and warning_kinds("") == ""
    listed = table.split("- gold 88°, kirchhoff: ")[-1]
    assert "The reference warned on 1 scene(s)" in table and "EnergyWarning: albedo (s, p)" in listed
    assert "warned" not in calm.markdown()
    comparison.write(tmp_path / "grazing")
    with open(tmp_path / "grazing.csv") as fh:
        assert all("EnergyWarning" in r["warnings"] for r in csv.DictReader(fh))
    assert "EnergyWarning" in read_comparison(tmp_path / "grazing.h5")[0]["warnings"][1]
    from wavebrdf.jobs.cli import main

    assert main(["inspect", str(tmp_path / "grazing.h5")]) == 0  # the table as compare printed it
    shown = capsys.readouterr().out
    assert "wavebrdf compare of 2 model(s) on 1 scene(s), 2 BRDF(s) stored" in shown
    assert "| gold 88° | stam | kirchhoff |" in shown and listed in shown
    assert main(["render", str(tmp_path / "grazing.h5")]) == 2  # a study's pictures: refused, saying why
    error = capsys.readouterr().err
    assert "is a file of `wavebrdf compare`" in error and "damaged" not in error, error


def write_small_h5(path):
    with h5py.File(path, "w") as h5:
        h5["x"] = 1
    return path


def test_a_measurement_made_before_is_taken_instead_of_running_the_model_again(flat_scene, models_run):
    """``measured``: the stored solve is the scene's reference (its times in the row, the other
    models' errors against its BRDF) and the model is not run: kirchhoff's BRDF scaled by 2 puts
    po's relative L2 near 1/2, not at po's small error against kirchhoff itself."""
    label = "flat glass 30°"
    first = compare_scenes([(label, flat_scene)], ["kirchhoff", "po"], reference="kirchhoff")
    kirchhoff, po = first.measurements
    before = Measurement("kirchhoff", label, wall_s=1234.0, cpu_s=2345.0, peak_mb=3456.0, brdf=2 * kirchhoff.brdf)
    models_run.clear()
    again = compare_scenes([(label, flat_scene)], ["kirchhoff", "po"], reference="kirchhoff",
                           measured={(label, "kirchhoff"): before})
    rows = {r["model"]: r for r in again.rows}
    assert (rows["kirchhoff"]["wall_s"], rows["kirchhoff"]["cpu_s"], rows["kirchhoff"]["peak_mb"]) == (1234.0, 2345.0,
                                                                                                        3456.0)
    assert again.measurements[0] is before and [name for name, _ in models_run] == ["po"]
    e = {r["model"]: r for r in first.rows}["po"]["rel_l2"]  # po against kirchhoff: P = K + δ, |δ| = e |K|
    assert e < 0.05
    assert abs(rows["po"]["rel_l2"] - 0.5) <= e / 2 + 1e-12  # |K − δ| / |2K| lies in 1/2 ± e/2 in any norm


def test_a_stored_measurement_is_checked_like_one_run_here(flat_scene, tmp_path, capsys):
    """A solve taken from before is held to what a run is held to: with its BRDF scaled past unit
    albedo (flat glass reflects 4 %: ×40 is 1.6 of the incident power) its row carries the
    EnergyWarning naming the rung that ran, listed under the table as the reference's; with a NaN
    inside the disk it is a failure saying so (a run's task fails the same way), and the other
    rows keep their own figures. The file of the first reads back, failures and all, as printed."""
    label = "flat glass 30°"
    first = compare_scenes([(label, flat_scene)], ["kirchhoff", "stam"], reference="kirchhoff")
    kirchhoff = first.measurements[0]
    bright = Measurement("kirchhoff", label, wall_s=1.0, cpu_s=1.0, peak_mb=1.0, brdf=40 * kirchhoff.brdf,
                         diagnostics={"model": "ghs"})  # its diagnostics name the rung that ran, as auto's do
    holed = kirchhoff.brdf.copy()
    u, v = np.nonzero(flat_scene.grid.inside)
    holed[1, u[:3], v[:3]] = np.nan  # three pixels of p inside the disk
    broken = Measurement("stam", label, wall_s=1.0, cpu_s=1.0, peak_mb=1.0, brdf=holed)
    again = compare_scenes([(label, flat_scene)], ["kirchhoff", "stam"], reference="kirchhoff",
                           measured={(label, "kirchhoff"): bright, (label, "stam"): broken})
    rows = {r["model"]: r for r in again.rows}
    assert rows["kirchhoff"]["albedo"] > 1.5
    assert "EnergyWarning: albedo (s, p)" in rows["kirchhoff"]["warnings"] and "ghs returns" in rows["kirchhoff"][
        "warnings"]
    assert rows["stam"]["failure"] == "FloatingPointError: 3 BRDF value(s) NaN/inf inside the unit disk"
    assert "rel_l2" not in rows["stam"]
    assert "- flat glass 30°, kirchhoff: EnergyWarning:" in again.markdown()
    again.write(tmp_path / "checked")
    from wavebrdf.jobs.cli import main

    assert main(["inspect", str(tmp_path / "checked.h5")]) == 0
    shown = capsys.readouterr().out
    assert f"| {label} | kirchhoff | kirchhoff | 1 | 1 | 1 | {rows['kirchhoff']['albedo']:.3g} |" in shown, shown
    assert "NaN/inf inside the unit disk" in shown


def test_the_reference_is_the_highest_rung_that_fits(flat_scene):
    name, why = choose_reference(["kirchhoff", "bem"], flat_scene, 64 * 2**30)
    assert name == "bem" and rung_order("bem") > rung_order("kirchhoff")
    from wavebrdf.solver.models import get_model

    needs = {n: get_model(n).estimate(flat_scene).memory_bytes for n in ("kirchhoff", "bem")}
    assert needs["kirchhoff"] < needs["bem"]
    name, why = choose_reference(["kirchhoff", "bem"], flat_scene, 0.5 * (needs["kirchhoff"] + needs["bem"]))
    assert name == "kirchhoff" and "bem needs" in why
    with pytest.raises(ValueError, match="no model fits"):
        choose_reference(["kirchhoff"], flat_scene, 1.0)


COMPARE_STUDY = """
[study]
name = "trade"
output = "{out}"

[surface]
generator = "gaussian"
size_um = 8.0
cells = 64
rms_height_um = 0.05
correlation_um = 1.0

[material]
n = 1.5

[illumination]
wavelengths_um = [0.5]
directions_deg = [[20, 0]]
waist_um = 1.4

[model]
name = "kirchhoff"

[output]
resolution = 48

[compare]
models = ["gs", "kirchhoff", "stam"]
reference = "kirchhoff"

[compare.gs]
rays = 65536
"""


def test_compare_command_end_to_end(tmp_path, capsys):
    """`wavebrdf compare CONFIG`: [compare] models, reference and per-model options; every file
    written next to the output; a bad [compare.<model>] option refused in one line, exit 2."""
    from wavebrdf.jobs.cli import main

    cfg = tmp_path / "trade.toml"
    cfg.write_text(COMPARE_STUDY.format(out=tmp_path / "trade.h5"))
    assert main(["compare", str(cfg), "-q"]) == 0
    out = capsys.readouterr().out
    assert "| trade λ=0.5 µm θi=20° | gs | kirchhoff |" in out
    for suffix in (".csv", ".md", ".png", ".h5", "_gallery.png"):
        assert (tmp_path / f"trade_compare{suffix}").is_file()
    with h5py.File(tmp_path / "trade_compare.h5") as h5:
        models = list(h5["table/model"].asstr())
        assert models == ["kirchhoff", "gs", "stam"]
        assert np.all(np.isfinite(h5["table/rel_l2"][1:]))
    cfg.write_text(COMPARE_STUDY.format(out=tmp_path / "trade.h5").replace("rays = 65536", "rays = 0"))
    assert main(["compare", str(cfg), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "[compare.gs] rays = 0" in err[0]


def test_compare_replaces_only_a_previous_comparisons_files(tmp_path, capsys):
    """`compare --out` at a stem whose .h5 is a study's dataset or a user's file, or beside which a
    user's Markdown lies with no comparison, is refused before anything runs and nothing changes;
    a previous comparison at the stem is replaced; --force overwrites."""
    from wavebrdf.jobs.cli import main

    cfg = tmp_path / "trade.toml"
    cfg.write_text(COMPARE_STUDY.format(out=tmp_path / "trade.h5"))
    study = tmp_path / "study.h5"
    assert main(["run", str(cfg), "-q", "--no-render", "-o", str(study)]) == 0
    notes = tmp_path / "notes.md"
    notes.write_text("my notes")
    with h5py.File(tmp_path / "mine.h5", "w") as h5:
        h5["x"] = 1
    before = {p: p.read_bytes() for p in (study, notes, tmp_path / "mine.h5")}
    capsys.readouterr()
    for stem, said in ((tmp_path / "study", "is not a file of `wavebrdf compare`"),
                       (tmp_path / "mine", "is not a file of `wavebrdf compare`"),
                       (tmp_path / "notes", "has no comparison's .h5 beside it")):
        assert main(["compare", str(cfg), "-q", "--out", str(stem)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and said in err[0] and "--force" in err[0], err
    assert all(p.read_bytes() == data for p, data in before.items())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.h5", "notes.md", "study.h5", "trade.toml"]
    for _ in range(2):  # a comparison's own files are replaced
        assert main(["compare", str(cfg), "-q", "--out", str(tmp_path / "again")]) == 0
    assert main(["compare", str(cfg), "-q", "--out", str(tmp_path / "notes"), "--force"]) == 0
    assert notes.read_text().startswith("|")


def test_a_measuring_process_that_dies_is_a_failure_and_the_next_model_still_runs(flat_scene):
    """The measuring process killed during a model (as the OOM killer would): that model's row
    says how the process ended; the next model gets a fresh process; each model's peak memory is
    its own (a 2²⁰-ray gm allocates more than the Kirchhoff run after it)."""
    import threading

    from wavebrdf.jobs.compare import MeasuringProcess

    with MeasuringProcess() as process:
        first = process.measure("kirchhoff", None, flat_scene, "warm-up")
        threading.Timer(3.0, lambda: process._proc.kill()).start()
        killed = process.measure("gm", {"rays": 1 << 26}, flat_scene, "killed")
        gm = process.measure("gm", {"rays": 1 << 20}, flat_scene, "after")
        kirchhoff = process.measure("kirchhoff", None, flat_scene, "after")
    assert first.failure is None
    assert killed.failure and "exited with -9" in killed.failure
    assert gm.failure is None and kirchhoff.failure is None
    assert gm.peak_mb > kirchhoff.peak_mb > 0


def test_a_measuring_process_appends_its_solves_progress_to_the_file_it_is_given(tmp_path):
    """``MeasuringProcess(progress_path=…)``: a full-wave solve in the measuring process leaves
    timestamped lines of its stages in the file, the Krylov stage with its products and residual,
    so a solve of hours can be watched; the file is appended to, not replaced."""
    import re

    from wavebrdf.jobs.compare import MeasuringProcess

    surface = generate("gaussian", cells=16, size_um=0.8, rms_height_um=0.03, correlation_um=0.2, seed=3)
    scene = SurfaceScene(surface, 0.5, 1.5 + 0j, 0.0, 0.0, 0.2, HemisphereGrid(32))
    path = tmp_path / "solve.progress"
    path.write_text("an earlier line\n")
    with MeasuringProcess(progress_path=path) as process:
        m = process.measure("bem", {"method": "aim"}, scene, "rough glass")
    assert m.failure is None
    lines = path.read_text().splitlines()
    assert lines[0] == "an earlier line"
    stamp = r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d "
    assert all(re.match(stamp, line) for line in lines[1:]), lines
    krylov = [line for line in lines if " krylov " in line]
    assert krylov and all(re.search(r"products=\d+ residual=[0-9.e+-]+$", line) for line in krylov), lines
    assert any(" far field" in line for line in lines), lines


def test_the_progress_reporter_limits_its_rate_and_a_file_it_cannot_write_ends_the_reports(tmp_path):
    """One line per stage change and at most one per interval within a stage; NumPy figures are
    formatted; a path in a missing folder warns once and stops reporting without raising."""
    from wavebrdf.jobs.compare import _ProgressFile

    path = tmp_path / "p.progress"
    report = _ProgressFile(str(path), seconds=60.0)
    report("near field", 0.5)
    report("near field", 0.6)  # within the interval: dropped
    report("krylov", None, products=np.int64(3), residual=np.float32(0.0123456))
    report("krylov", None, products=4, residual=0.01)  # dropped
    lines = path.read_text().splitlines()
    assert [line.split(" ", 2)[2] for line in lines] == ["near field 50 %", "krylov products=3 residual=0.0123"]
    lost = _ProgressFile(str(tmp_path / "missing" / "p.progress"))
    lost("krylov", None, residual=0.5)
    assert lost.path is None
    lost("far field", 0.0)  # no further attempt, no exception


def test_every_scene_has_its_own_label(tmp_path):
    """Directions that differ only in φ_i, or in θ_i by less than a degree, are other scenes: their
    labels (the table's ``scene`` column, the key of the stored BRDFs) differ; φ_i = 0 adds nothing
    (the trade table's labels)."""
    from wavebrdf.jobs.compare import plan_scenes
    from wavebrdf.jobs.config import load_config
    from wavebrdf.jobs.plan import plan_study

    cfg = tmp_path / "scenes.toml"
    cfg.write_text(COMPARE_STUDY.format(out=tmp_path / "scenes.h5").replace(
        "directions_deg = [[20, 0]]", "directions_deg = [[20, 0], [20, 90], [20.5, 0], [30, 359.9999]]"))
    labels = [label for label, _ in plan_scenes(plan_study(load_config(cfg)))]
    assert len(set(labels)) == len(labels) == 4, labels
    assert labels[0] == "trade λ=0.5 µm θi=20°" and labels[1] == "trade λ=0.5 µm θi=20° φi=90°", labels
    assert labels[2] == "trade λ=0.5 µm θi=20.5°" and labels[3].endswith("θi=30° φi=359.9999°"), labels
