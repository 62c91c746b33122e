"""``auto`` that measures (solver/auto.py, jobs/spot_checks.py, docs/auto.md).

* The spot-check selection spans the study (extremes of θ_i and λ, the steepest sub-area) within
  its share of the all-full-wave estimate (both ends of the spectrum whatever the share), and
  represents every task by checks at least as oblique and as steep as itself (the most oblique and
  steepest where none is).
* End to end, against an all-BEM run of the same study (the independent reference): every task of
  an ``auto`` study is within the tolerance, the dataset stores the checks' measured errors and the
  rung per task, and ``inspect`` prints them.
* An honest tolerance: the full-wave fallback is fitted to the task's memory budget (not dropped for
  its default settings' need), and a tolerance nothing within the budget can meet is said in the
  task table, ``plan`` and ``inspect``.
* A steered ``auto`` study plans spot checks of sub-areas among the coherent rungs.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import h5py
import numpy as np
import pytest

from wavebrdf.jobs.config import load_config
from wavebrdf.jobs.plan import plan_study
from wavebrdf.solver.auto import REFERENCE, CheckUnit, check_slope, choose, select_spot_checks
from wavebrdf.solver.farfield import HemisphereGrid
from wavebrdf.solver.materials import Material
from wavebrdf.solver.metrics import speckle_errors, speckle_sigma_u
from wavebrdf.solver.models import SurfaceScene, model_class
from wavebrdf.solver.surface import generate

WAVEBRDF = [sys.executable, "-m", "wavebrdf"]


def units(thetas, lams, slopes=(0.1,), seconds=10.0):
    out = []
    for t in thetas:
        for s in slopes:
            for lam in lams:
                out.append(CheckUnit(len(out), (t, s), lam, t, s, seconds, True))
    return out


def test_a_task_is_represented_at_every_checked_wavelength_by_its_nearest_covering_check():
    """Checks at (25°, λ 0.5), (25°, λ 0.65) and (0°, λ 0.5) — a larger share adds the third: the
    task at (0°, λ 0.65) is represented by (0°, 0.5) and by (25°, 0.65), the nearest covering check
    at each checked λ. Taking the nearest θ_i over all λ first left only (0°, 0.5): a rung measured
    0.038 there was taken at λ 0.65, where it measured 0.086 (a probe's silent miss at 0.05)."""
    from wavebrdf.solver.auto import _representatives

    def unit(task, theta_deg, lam):
        return CheckUnit(task, (np.deg2rad(theta_deg), 0.1), lam, np.deg2rad(theta_deg), 0.1, 10.0, True)

    checks = [unit(1, 25.0, 0.5), unit(3, 25.0, 0.65), unit(0, 0.0, 0.5)]
    red = unit(2, 0.0, 0.65)
    assert _representatives(red, checks, mix_wavelengths=False) == (1, 2)
    assert _representatives(red, checks, mix_wavelengths=True) == (1,)  # the nearest checked λ only
    assert _representatives(unit(0, 0.0, 0.5), checks, mix_wavelengths=False) == (1, 2)  # one rung per series
    assert _representatives(unit(5, 10.0, 0.5), checks, mix_wavelengths=False) == (0, 1)


def test_spot_checks_span_the_study_within_their_share():
    study = units(thetas=(0.0, 0.2, 0.5, 1.0), lams=(0.4, 0.5, 0.6))
    total = sum(u.full_wave_seconds for u in study)
    for share in (0.01, 0.2, 0.5, 1.0):
        checks, represented = select_spot_checks(study, share)
        spent = sum(c.full_wave_seconds for c in checks)
        forced = sum(c.full_wave_seconds for c in checks[:2])  # the hardest at each end of the spectrum
        assert spent <= max(share * total, forced) + 1e-9, (share, len(checks))
        assert checks[0].theta_i == 1.0 and checks[0].wavelength_um == 0.4  # the hardest first
        assert {c.wavelength_um for c in checks} == {0.4, 0.6}  # both ends of the spectrum, whatever the share
        assert all(c.theta_i == 1.0 for c in checks[:2])
        for u in study:
            reps = [checks[i] for i in represented[u.task]]
            assert reps and all(c.theta_i >= u.theta_i for c in reps)  # never represented by an easier check
            for lam in {c.wavelength_um for c in checks}:  # at every checked λ, the nearest checked θ_i at or above
                above = [c.theta_i for c in checks if c.wavelength_um == lam and c.theta_i >= u.theta_i]
                assert {c.theta_i for c in reps if c.wavelength_um == lam} == ({min(above)} if above else set())
    checks, represented = select_spot_checks(study, 1.0)
    assert {(c.theta_i, c.wavelength_um) for c in checks} == {(t, l) for t in (0.0, 0.5, 1.0) for l in (0.4, 0.6)}
    normal = next(u for u in study if u.theta_i == 0.0 and u.wavelength_um == 0.5)
    assert {checks[i].theta_i for i in represented[normal.task]} == {0.0}
    # with mixed wavelengths a task is represented by the nearest checked λ only
    checks, represented = select_spot_checks(study, 1.0, mix_wavelengths=True)
    red = next(u for u in study if u.theta_i == 0.2 and u.wavelength_um == 0.6)
    assert [(checks[i].theta_i, checks[i].wavelength_um) for i in represented[red.task]] == [(0.5, 0.6)]
    # nothing to check: one task, a zero share, or a full wave that fits nowhere
    assert select_spot_checks(study[:1], 1.0) == ([], {})
    assert select_spot_checks(study, 0.0) == ([], {})
    assert select_spot_checks([dataclasses.replace(u, full_wave_fits=False) for u in study], 1.0) == ([], {})
    # one wavelength: one check where the share allows no more
    checks, _ = select_spot_checks(units(thetas=(0.0, 0.5), lams=(0.5,)), 0.01)
    assert [(c.theta_i, c.wavelength_um) for c in checks] == [(0.5, 0.5)]


def test_an_end_of_the_spectrum_without_the_listed_angles_is_still_checked_and_the_share_counts_it():
    # the longest λ only at a middle θ_i (not the largest, smallest or median of the study's)
    study = units(thetas=(0.0, 0.3, 0.6), lams=(0.4, 0.5)) + [CheckUnit(6, (0.15, 0.1), 0.7, 0.15, 0.1, 10.0, True)]
    total = sum(u.full_wave_seconds for u in study)
    checks, represented = select_spot_checks(study, 0.25)  # 17.5 s: the two forced checks only (20 s)
    assert [(c.theta_i, c.wavelength_um) for c in checks] == [(0.6, 0.4), (0.15, 0.7)]
    # at each checked λ the nearest θ_i at or above: its own scene at λ 0.7, the hardest check at λ 0.4
    assert [checks[i].task for i in represented[6]] == [4, 6]
    # the forced checks are charged first: one more fits 31.5 s (20 + 10), not 28 s
    assert len(select_spot_checks(study, 0.4)[0]) == 2
    checks, _ = select_spot_checks(study, 0.45)
    assert len(checks) == 3 and sum(c.full_wave_seconds for c in checks) <= 0.45 * total


def test_the_most_oblique_task_is_checked_first_and_represents_tasks_harder_than_every_check():
    # the largest θ_i only at a middle wavelength: it is still the first candidate
    study = units(thetas=(0.0, 0.3), lams=(0.4, 0.7)) + [CheckUnit(4, (0.6, 0.1), 0.5, 0.6, 0.1, 10.0, True)]
    checks, represented = select_spot_checks(study, 1.0)
    assert (checks[0].theta_i, checks[0].wavelength_um) in {(0.3, 0.4), (0.3, 0.7)}  # the forced ends first
    assert any(c.theta_i == 0.6 for c in checks)
    assert {checks[i].theta_i for i in represented[4]} == {0.6}
    # a task whose full wave fits nowhere, more oblique than every check: the most oblique checks
    beyond = CheckUnit(5, (0.9, 0.1), 0.4, 0.9, 0.1, 10.0, False)
    checks, represented = select_spot_checks(study + [beyond], 1.0)
    assert {checks[i].theta_i for i in represented[5]} == {0.6}


def test_a_study_of_few_tasks_is_checked_at_both_ends_of_its_spectrum():
    # 4 sub-areas x 3 wavelengths, one direction: one check is 1/12 of the all-full-wave estimate, so a
    # share of 0.1 pays for one; the longest wavelength is checked too, and represents its tasks
    study = units(thetas=(0.0,), lams=(0.5, 0.58, 0.66), slopes=(0.10, 0.12, 0.13, 0.14))
    checks, represented = select_spot_checks(study, 0.1)
    assert [(c.wavelength_um, c.slope) for c in checks] == [(0.5, 0.14), (0.66, 0.14)]
    for u in study:
        assert {checks[i].wavelength_um for i in represented[u.task]} == {0.5, 0.66}


def test_spot_checks_of_sub_areas_take_the_steepest_and_represent_by_slope():
    study = units(thetas=(0.0, 0.3), lams=(0.4, 0.7), slopes=(0.05, 0.1, 0.2, 0.4))
    checks, represented = select_spot_checks(study, 1.0)
    assert all(c.slope == 0.4 for c in checks[:4])  # the steepest sub-area at every (θ_i, λ) corner
    assert any(c.slope == 0.2 for c in checks)  # and the median one at the hardest corner
    for u in study:
        reps = [checks[i] for i in represented[u.task]]
        assert all(c.slope >= u.slope and c.theta_i >= u.theta_i for c in reps)
    gentle = next(u for u in study if u.slope == 0.05 and u.theta_i == 0.3)
    # at each checked λ the nearest steeper check there: the median sub-area at λ 0.4, the steepest at 0.7
    assert {(checks[i].slope, checks[i].wavelength_um) for i in represented[gentle.task]} == {(0.2, 0.4), (0.4, 0.7)}


def test_a_less_oblique_but_steeper_task_is_checked_too():
    """Lit at 0.8 rad along an anisotropic surface's grooves (slope 0.12) and at 0.7 rad across them
    (0.17), plus gentler tasks: the most oblique task alone is not as steep as the across one, so at
    each end of the spectrum both are checked whatever the share, and every task is represented by
    checks as oblique and as steep as itself."""
    study = [CheckUnit(i, (t, s), lam, t, s, 10.0, True) for i, (t, s, lam) in enumerate(
        (t, s, lam) for t, s in ((0.8, 0.12), (0.7, 0.17), (0.3, 0.10), (0.5, 0.15)) for lam in (0.45, 0.55, 0.65))]
    checks, represented = select_spot_checks(study, 0.01)
    assert [(c.theta_i, c.slope, c.wavelength_um) for c in checks] == [
        (0.8, 0.12, 0.45), (0.7, 0.17, 0.45), (0.8, 0.12, 0.65), (0.7, 0.17, 0.65)]
    for u in study:
        reps = [checks[i] for i in represented[u.task]]
        assert reps and all(c.theta_i >= u.theta_i and c.slope >= u.slope for c in reps), u
    across = next(u for u in study if u.slope == 0.17)
    assert {checks[i].slope for i in represented[across.task]} == {0.17}
    # a steeper task whose full wave fits nowhere: every check no other covers, the worst of them standing for it
    beyond = CheckUnit(len(study), (0.7, 0.2), 0.55, 0.7, 0.2, 10.0, False)
    checks, represented = select_spot_checks(study + [beyond], 0.01)
    assert {(checks[i].theta_i, checks[i].slope) for i in represented[beyond.task]} == {(0.8, 0.12), (0.7, 0.17)}


def test_slopes_within_the_tie_take_no_check_of_their_own():
    """An isotropic surface's in-plane slope moves by a few % with the azimuth: a less oblique task
    2 % steeper than the most oblique one is covered by it, one 10 % steeper is checked too."""
    study = [CheckUnit(i, (t, s), lam, t, s, 10.0, True) for i, (t, s, lam) in enumerate(
        (t, s, lam) for t, s in ((0.6, 0.200), (0.4, 0.204), (0.2, 0.202)) for lam in (0.5, 0.6))]
    checks, represented = select_spot_checks(study, 0.01)
    assert [(c.theta_i, c.wavelength_um) for c in checks] == [(0.6, 0.5), (0.6, 0.6)]
    assert all(represented[u.task] for u in study)
    steeper = study + [CheckUnit(len(study) + k, (0.4, 0.22), lam, 0.4, 0.22, 10.0, True)
                       for k, lam in enumerate((0.5, 0.6))]
    checks, _ = select_spot_checks(steeper, 0.01)
    assert [(c.theta_i, c.slope) for c in checks] == [(0.6, 0.2), (0.4, 0.22)] * 2


def test_the_slope_a_check_is_ranked_by_is_the_in_plane_one_where_larger():
    """A grating lit across its grooves (the plane of incidence along k) ranks at √2 × its in-plane
    rms slope a|k|/√2, i.e. a|k|; lit along them, or at normal incidence, at its rms slope a|k|/√2."""
    a, period = 0.05, 0.8
    grating = generate("sinusoid", cells=160, size_um=4.0, amplitude_um=a, period_um=period)  # k along x
    ak = a * 2 * np.pi / period
    assert check_slope(grating, np.radians(40), 0.0) == pytest.approx(ak, rel=2e-3)
    assert check_slope(grating, np.radians(40), np.pi / 2) == pytest.approx(ak / np.sqrt(2), rel=2e-3)
    assert check_slope(grating, 0.0, 0.0) == pytest.approx(ak / np.sqrt(2), rel=2e-3)


BRUSHED = """
[study]
name = "brushed"
output = "brushed.h5"
[surface]
generator = "brushed"
size_um = 2.4
cells = 48
rms_height_um = 0.02
correlation_um = [1.2, 0.15]
angle_deg = 0.0
seed = 3
[material]
name = "aluminium"
[illumination]
wavelengths_um = [0.5, 0.6]
directions_deg = [[40, 0], [40, 90], [20, 0]]
waist_um = 0.45
[model]
name = "auto"
tolerance = 0.05
[output]
resolution = 32
"""


def test_spot_checks_of_an_anisotropic_surface_take_the_azimuth_across_its_grooves(tmp_path):
    """Grooves along x, lit at θ_i 40° along them (listed first) and across them: the checks at both
    ends of the spectrum are the across-grooves tasks (the harder: a brushed patch at 40° measured
    kirchhoff 0.047 along and 0.135 across, docs/auto.md), and they represent the along-grooves ones."""
    path = tmp_path / "brushed.toml"
    path.write_text(BRUSHED)
    plan = plan_study(load_config(path))
    checks = [t for t in plan.tasks if t.kind == "check"]
    assert len(checks) >= 2
    scenes = {t.id: plan.scene(t) for t in plan.tasks}
    forced = checks[:2]  # the hardest task at each end of the spectrum
    assert {scenes[t.id].wavelength_um for t in forced} == {0.5, 0.6}
    for t in forced:
        assert np.degrees(scenes[t.id].theta_i) == pytest.approx(40)
        assert np.degrees(scenes[t.id].phi_i) == pytest.approx(90)
    along = [t for t in plan.tasks if t.kind == "direct" and np.degrees(scenes[t.id].phi_i) == pytest.approx(0)
             and np.degrees(scenes[t.id].theta_i) == pytest.approx(40)]
    assert along and all(t.checks for t in along)
    for t in along:
        assert all(np.degrees(scenes[i].phi_i) == pytest.approx(90) for i in t.checks)


STUDY = """
[study]
name = "{name}"
output = "{name}.h5"
[surface]
generator = "gaussian"
size_um = 2.4
cells = 32
rms_height_um = {rms}
correlation_um = 0.6
seed = 5
[material]
name = "aluminium"
[illumination]
wavelengths_um = [0.5, 0.65]
directions_deg = [[0, 0], [25, 0]]
waist_um = 0.45
[model]
name = "{model}"
{options}
[output]
resolution = 32
per_polarization = true
"""


def write_study(tmp_path, name, model, rms=0.006, options=""):
    path = tmp_path / f"{name}.toml"
    path.write_text(STUDY.format(name=name, model=model, rms=rms, options=options))
    return path


def run(tmp_path, *args):
    done = subprocess.run(WAVEBRDF + list(map(str, args)), cwd=tmp_path, capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout


def task_table(path) -> dict:
    with h5py.File(path) as h5:
        return {k: [x.decode() if isinstance(x, bytes) else x for x in h5["tasks"][k][()]] for k in h5["tasks"]}


def test_auto_measures_on_spot_checks_and_stays_within_tolerance_of_the_full_wave(tmp_path):
    """A smooth aluminium patch at 2 λ × 2 θ_i: auto checks the hardest corner(s), takes the
    cheapest rung measured within the tolerance, and every task is within it of an all-BEM run."""
    tolerance = 0.05
    # two checks (both λ at the largest θ_i, taken at any share) and no more: a share below the next one's
    auto = write_study(tmp_path, "auto", "auto", options=f"tolerance = {tolerance}\nspot_check_share = 0.55")
    plan = run(tmp_path, "plan", auto)
    assert "auto spot checks: 2 task(s)" in plan and "of the all-full-wave estimate" in plan
    assert "above [model] spot_check_share" not in plan
    small_share = run(tmp_path, "plan", auto, "--set", "model.spot_check_share=0.1")
    assert "auto spot checks: 2 task(s)" in small_share  # both ends of the spectrum, and said so
    assert "above [model] spot_check_share = 0.1: the hardest task at each end of the spectrum" in small_share
    run(tmp_path, "run", auto, "-q")
    run(tmp_path, "run", write_study(tmp_path, "bem", "bem", options='method = "aim"'), "-q")
    rows = task_table(tmp_path / "auto.h5")
    checks = [i for i, k in enumerate(rows["kind"]) if k == "check"]
    decided = [i for i, k in enumerate(rows["kind"]) if k == "direct"]
    assert len(checks) == 2 and len(decided) == 4
    for i in checks:
        measured = json.loads(rows["spot_check"][i])
        assert rows["model"][i] == REFERENCE and measured and all(m["error"] is None or m["error"] >= 0
                                                                  for m in measured.values())
    assert all(rows["model"][i] not in ("auto", "") for i in decided)
    assert any(rows["model"][i] != REFERENCE for i in decided), "a smooth patch needs no full wave everywhere"
    rung = {(rows["wavelength_index"][i], rows["incidence_index"][i]): rows["model"][i] for i in decided}
    assert all(rung[(0, d)] == rung[(1, d)] for d in range(2)), rung  # one rung per direction across λ
    with h5py.File(tmp_path / "auto.h5") as a, h5py.File(tmp_path / "bem.h5") as b:
        grid = HemisphereGrid(32)
        for w in range(2):
            for d in range(2):
                sigma = speckle_sigma_u((0.5, 0.65)[w], 0.45, grid)
                errors = speckle_errors(a["brdf_sp"][w, d], b["brdf_sp"][w, d], grid, sigma)
                assert max(errors["s"], errors["p"], errors["unpolarized"]) <= tolerance, (w, d, errors)
                # and in plain numpy, unblurred: ‖f − f_BEM‖ / ‖f_BEM‖ over the pixels of the BEM lobe
                f, g = np.nan_to_num(a["brdf"][w, d]), np.nan_to_num(b["brdf"][w, d])
                lobe = g * grid.mu >= 1e-3 * np.max(g * grid.mu)
                assert np.linalg.norm((f - g)[lobe]) / np.linalg.norm(g[lobe]) <= 2 * tolerance, (w, d)
    shown = run(tmp_path, "inspect", "auto.h5")
    assert "auto spot checks" in shown and "rungs run:" in shown


def test_the_full_wave_fallback_is_fitted_to_the_task_budget():
    """The issue's scene (rough aluminium 12.5 µm at λ 0.4 µm, waist 2.5 µm), at a tolerance no
    cheap rung is predicted to meet (0.003: the rule's bound for po there is 0.0049, for kirchhoff
    0.015 — kirchhoff was measured at 0.0038): the default AIM settings need more than 80 % of a
    24 GiB node, the memory-fitted ones ~5.5 GiB, so the full wave is chosen; under a 4 GiB task
    budget nothing can meet the tolerance, and the choice says so."""
    surface = generate("gaussian", cells=500, size_um=12.5, seed=7, rms_height_um=0.09, correlation_um=1.8)
    index = complex(Material.from_name("aluminium").index(0.4))
    scene = SurfaceScene(surface, 0.4, index, 0.0, 0.0, 2.5, HemisphereGrid(128), memory_budget_bytes=12 * 2**30)
    default = model_class("bem")({"method": "aim", "aim": {"fit_memory": False}}).estimate(scene)
    assert default.memory_bytes > 12 * 2**30  # the default settings alone would not fit this task
    chosen = choose(scene, 0.003)
    assert chosen.model == REFERENCE and chosen.within, chosen.reason
    starved = choose(dataclasses.replace(scene, memory_budget_bytes=4 * 2**30), 0.003)
    assert starved.model != REFERENCE and not starved.within and "4.0 GiB" in starved.reason


def test_a_tolerance_nothing_within_the_budget_can_meet_is_said(tmp_path):
    """One rough task, tolerance 0.01, 1 GiB for the task: the full wave does not fit, so the best
    approximation runs and the ToleranceWarning is in plan, the task table and inspect; with 8 GiB
    the full wave runs and nothing is said of the tolerance."""
    single = STUDY.replace("wavelengths_um = [0.5, 0.65]", "wavelengths_um = [0.5]").replace(
        "directions_deg = [[0, 0], [25, 0]]", "directions_deg = [[20, 0]]")
    # the premise: the full wave needs more than 1 GiB here (even fitted), the approximations far less
    premise = plan_study(load_config(write_study(tmp_path, "premise", "kirchhoff", rms=0.1)))
    scene = dataclasses.replace(premise.scene(premise.tasks[0]), memory_budget_bytes=2**30)
    assert model_class("bem")({"method": "aim"}).estimate(scene).memory_bytes > 2**30
    assert model_class("po")().estimate(scene).memory_bytes < 0.5 * 2**30
    path = tmp_path / "tight.toml"
    path.write_text(single.format(name="tight", model="auto", rms=0.1, options="tolerance = 0.01")
                    + "[run]\nmemory_gb = 1.0\n")
    plan = run(tmp_path, "plan", path)
    assert "WARNING: 1 of 1 task(s) cannot meet the tolerance" in plan
    run(tmp_path, "run", path, "-q")
    rows = task_table(tmp_path / "tight.h5")
    assert rows["model"][0] != REFERENCE and "ToleranceWarning" in rows["warnings"][0]
    assert "ToleranceWarning" in run(tmp_path, "inspect", "tight.h5")
    roomy = tmp_path / "roomy.toml"
    roomy.write_text(single.format(name="roomy", model="auto", rms=0.1, options="tolerance = 0.01")
                     + "[run]\nmemory_gb = 8.0\n")
    said = [line for line in run(tmp_path, "plan", roomy).splitlines() if "WARNING" in line]
    # nothing of the tolerance; the full wave's own mesh check (d = 0.075 µm on aluminium) only
    assert said and all("bem: d is too coarse for the interior field" in line for line in said), said
    run(tmp_path, "run", roomy, "-q")
    rows = task_table(tmp_path / "roomy.h5")
    assert rows["model"][0] == REFERENCE and "ToleranceWarning" not in rows["warnings"][0]
    # the mesh warning once, from the full wave that ran, not again through auto's seam
    assert "ResolutionWarning: d is too coarse" in rows["warnings"][0]
    assert "ValidityWarning: bem:" not in rows["warnings"][0], rows["warnings"][0]


def test_a_steered_auto_study_checks_sub_areas_among_coherent_rungs(tmp_path):
    path = tmp_path / "steer.toml"
    path.write_text(STUDY.format(name="steer", model="auto", rms=0.006, options="tolerance = 0.05")
                    .replace("size_um = 2.4\ncells = 32", "size_um = 4.8\ncells = 64")
                    + "[steering]\npatches = [2, 2]\npatch_size_um = 2.4\nshift_um = 0.45\n")
    plan = plan_study(load_config(path))
    checks = [t for t in plan.tasks if t.kind == "check"]
    patches = [t for t in plan.tasks if t.kind == "patch"]
    assert checks and all(t.on_patch for t in checks) and all(t.checks for t in patches)
    model = plan.model_spec(checks[0]).build()
    for t in checks:
        scene = plan.model_scene(t)
        assert scene.coherent
        assert all(model_class(n).capabilities.steerable for n in model.checked_rungs(scene))
        assert model.choice(scene).model in {n for n in model.choice(scene).candidates}


@pytest.mark.slow
def test_mixed_wavelengths_report_their_spectral_seams(tmp_path):
    """``mix_wavelengths = true``: each wavelength takes the rung measured at its nearest checked λ,
    and ``inspect`` lists every place where a direction's rung changes along the spectrum."""
    path = tmp_path / "mixed.toml"
    path.write_text(STUDY.format(name="mixed", model="auto", rms=0.01, options="tolerance = 0.05\nspot_check_share = 1.0\n"
                                 "mix_wavelengths = true")
                    .replace("wavelengths_um = [0.5, 0.65]", "wavelengths_um = [0.5, 0.6, 0.7]")
                    .replace("directions_deg = [[0, 0], [25, 0]]", "directions_deg = [[0, 0], [60, 0]]"))
    run(tmp_path, "run", path, "-q", "--no-render")
    rows = task_table(tmp_path / "mixed.h5")
    rung = {(rows["wavelength_index"][i], rows["incidence_index"][i]): rows["model"][i]
            for i, k in enumerate(rows["kind"]) if k == "direct"}
    changes = sum(rung[(k, d)] != rung[(k + 1, d)] for k in range(2) for d in range(2))
    shown = run(tmp_path, "inspect", "mixed.h5")
    assert shown.count(" → ") == changes and (changes == 0) == ("spectral seams" not in shown), shown


@pytest.mark.parametrize("lost", ["every check", "the long end's check"])
def test_a_failed_spot_check_leaves_its_tasks_to_the_rule(tmp_path, monkeypatch, lost):
    """A spot check that fails (here: its full wave raises) fails alone; the tasks it would have
    represented run on the rule's choice, also where another of their checks was measured (that
    one represents them at its own wavelength only: a probe's tasks took a rung measured 0.0495 at
    λ 0.5 µm and missed 0.0625 at 0.65 µm, 0.086, without a word), and the dataset is complete."""
    import wavebrdf
    from wavebrdf.solver.auto import AutoModel

    spot_check = AutoModel.spot_check

    def broken(self, ctx, scene):
        if lost == "every check" or scene.wavelength_um > 0.6:
            raise RuntimeError("full wave lost (test)")
        return spot_check(self, ctx, scene)

    monkeypatch.setattr(AutoModel, "spot_check", broken)
    config = write_study(tmp_path, "broken", "auto", options="tolerance = 0.05\nspot_check_share = 0.5")
    monkeypatch.chdir(tmp_path)
    with pytest.warns(RuntimeWarning, match="failed"):
        wavebrdf.run(str(config), **{"run.retries": 0}).close()
    rows = task_table(tmp_path / "broken.h5")
    status = dict(zip(rows["id"], rows["status"]))
    checks = [i for i, k in zip(rows["id"], rows["kind"]) if k == "check"]
    decided = [n for n, k in enumerate(rows["kind"]) if k == "direct"]
    failed = [i for i in checks if status[i] == "failed"]
    assert failed and len(failed) == (len(checks) if lost == "every check" else 1), status
    assert all(status[rows["id"][n]] == "done" for n in decided), status
    measured = rows.get("model_measured_error", [np.nan] * len(rows["kind"]))  # no column: nothing measured
    for n in decided:  # every task had the failed check among its representatives: the rule decided
        assert "spot check" not in rows["model_reason"][n], rows["model_reason"][n]
        assert not np.isfinite(measured[n]), measured[n]
    with h5py.File(tmp_path / "broken.h5") as h5:
        assert np.all(np.isfinite(h5["albedo"][()]))


@pytest.mark.slow
def test_a_steered_auto_study_is_within_tolerance_of_the_steered_full_wave(tmp_path):
    """2 × 2 sub-areas, 2 wavelengths, normal incidence plus a steered direction: the synthesized
    BRDFs of auto (spot checks on the steepest sub-area) against the same study all-BEM."""
    tolerance = 0.05
    steering = "[steering]\npatches = [2, 2]\npatch_size_um = 2.4\nshift_um = 0.45\n"
    for name, model, options in (("steer_auto", "auto", f"tolerance = {tolerance}"), ("steer_bem", "bem", 'method = "aim"')):
        text = (STUDY.format(name=name, model=model, rms=0.006, options=options)
                .replace("size_um = 2.4\ncells = 32", "size_um = 2.85\ncells = 38")
                .replace("directions_deg = [[0, 0], [25, 0]]", "directions_deg = [[0, 0], [1.5, 0]]") + steering)
        (tmp_path / f"{name}.toml").write_text(text)
        run(tmp_path, "run", tmp_path / f"{name}.toml", "-q", "--no-render")
    rows = task_table(tmp_path / "steer_auto.h5")
    assert "check" in rows["kind"] and all(rows["model"][i] in {"bem", "kirchhoff", "po", "ghs", "ohs"}
                                           for i, k in enumerate(rows["kind"]) if k == "patch")
    with h5py.File(tmp_path / "steer_auto.h5") as a, h5py.File(tmp_path / "steer_bem.h5") as b:
        grid = HemisphereGrid(32)
        for w in range(2):
            for d in range(2):
                errors = speckle_errors(a["brdf_sp"][w, d], b["brdf_sp"][w, d], grid,
                                        speckle_sigma_u((0.5, 0.65)[w], 0.45, grid))
                assert max(errors["s"], errors["p"], errors["unpolarized"]) <= tolerance, (w, d, errors)
