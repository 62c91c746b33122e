"""``[model] name = "auto"`` (solver/auto.py, docs/auto.md): the cheapest rung expected to meet a
tolerance, from scene features and a rule fitted to the trade table of record (docs/trade.md).

* On the suites the rule was fitted to (configs/compare/trade/<suite>/*.toml: aluminium at waist
  ≈ λ and 5 λ, glass at waist ≈ λ), the chosen rung's *measured* error (solver/data/trade.csv,
  against AIM BEM) is within the tolerance in every scene — also with the scene's config left out
  of the fit — and it is the cheapest such rung in a quarter at least.
* Scenes generated fresh here (new seeds, new parameters): cube corners and spherical pits never
  get a single-scattering rung; smooth low-slope random surfaces are never expected to need BEM
  where spot checks measure.
* End to end: a study with ``name = "auto"`` plans (choice, predicted error, avoided cost) and runs,
  storing the rung and its reason per task.
* slow: a second suite of fresh scenes (aluminium and glass at waist ≈ λ, one-task studies at the
  reference simulator's waist 5 λ) against the full-wave reference — the same figures.
"""

from __future__ import annotations

import logging
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from wavebrdf.jobs.compare import plan_scenes
from wavebrdf.jobs.config import load_config
from wavebrdf.jobs.plan import plan_study
from wavebrdf.solver.auto import (FEATURES, REFERENCE, SINGLE_SCATTERING, AutoModel, AutoOptions, Rule, choose,
                                  VALIDATED_TOLERANCE, default_rule, measure_scene, read_table, table_error)
from wavebrdf.solver.farfield import HemisphereGrid, albedo
from wavebrdf.solver.materials import Material
from wavebrdf.solver.models import SurfaceScene
from wavebrdf.solver.surface import generate

logger = logging.getLogger(__name__)
ROOT = Path(__file__).resolve().parents[1]
SUITE = sorted((ROOT / "configs" / "compare" / "trade").glob("*/*.toml"))
TOLERANCE = 0.05
DEG = np.pi / 180


def aluminium(wavelength_um: float) -> complex:
    return complex(Material.from_name("aluminium").index(wavelength_um))


def test_on_the_suite_auto_picks_a_rung_within_tolerance_also_when_the_scene_was_left_out_of_the_fit():
    """The rule fitted to the whole table (on which its margin makes every prediction at least the
    measured error), and — the real check — fitted with each scene config left out in turn and
    asked about that config's scenes: the chosen rung's measured error (the worst of s, p and
    unpolarized) is within the tolerance."""
    table = read_table()
    assert len(SUITE) >= 11 and len({r["scene"] for r in table}) >= 36
    picks, cheapest = [], 0
    for path in SUITE:
        config = str(path.resolve().relative_to(ROOT))
        left_out = Rule.fit([r for r in table if r["config"] != config])
        for label, scene in plan_scenes(plan_study(load_config(path))):
            rows = {r["model"]: r for r in table if r["scene"] == label}
            assert rows, f"{label} is missing from solver/data/trade.csv: regenerate with benchmarks/trade.py"
            measured = measure_scene(scene)  # the table's features are what auto measures today
            first = next(iter(rows.values()))
            assert np.allclose([getattr(measured, k) for k in FEATURES], [float(first[k]) for k in FEATURES],
                               rtol=1e-6, atol=1e-9), label
            within = sorted((float(r["cpu_s"]), m) for m, r in rows.items() if table_error(r) <= TOLERANCE)
            for rule, kind in ((Rule.fit(table), "fitted"), (left_out, "left out")):
                choice = choose(scene, TOLERANCE, rule, measured)
                error = table_error(rows[choice.model])
                picks.append((label, kind, choice.model, error, within[0][1]))
                assert error <= TOLERANCE, f"{label} ({kind}): auto picked {choice.model}, measured error {error:.3g}"
                cheapest += kind == "fitted" and choice.model == within[0][1]
    logger.info("auto on the suite: %s", picks)
    print("\n".join(f"{p[0]} ({p[1]}): auto {p[2]} (measured {p[3]:.3g}), cheapest within tolerance {p[4]}"
                    for p in picks))
    assert cheapest >= len(picks) / 4  # the cheapest in most scenes, with the rule fitted to all of them


def fresh_scene(generator: str, wavelength_um: float, theta_deg: float, seed: int, **params) -> SurfaceScene:
    surface = generate(generator, cells=64, size_um=4.0, seed=seed, **params)
    return SurfaceScene(surface, wavelength_um, aluminium(wavelength_um), theta_deg * DEG, 0.0, 0.6, HemisphereGrid(48))


def test_grazing_share_of_a_phase_grating_is_the_bessel_power_of_its_grazing_orders():
    """A sinusoid h = a cos(2πx/P) under a wide beam is a phase grating: order m carries
    J_m(2k cosθ_i a)² of the power (Jacobi–Anger, independent of the code), at
    sinθ_m = sinθ_i + mλ/P. Period 1 µm at λ 0.5 µm and θ_i 30°: orders +1 and −3 leave at grazing,
    0, −1, −2 do not, +2 is evanescent beyond the band; tilting to θ_i 10° takes every order out of
    the band but the evanescent edge."""
    from scipy.special import jv

    lam, amplitude = 0.5, 0.03
    surface = generate("sinusoid", cells=480, size_um=24.0, seed=0, amplitude_um=amplitude, period_um=1.0)
    share = {}
    for theta in (30.0, 10.0):
        scene = SurfaceScene(surface, lam, aluminium(lam), theta * DEG, 0.0, 5.0, HemisphereGrid(16))
        share[theta] = measure_scene(scene).grazing_share
    beta = 2 * (2 * np.pi / lam) * np.cos(30 * DEG) * amplitude
    power = {m: jv(m, beta) ** 2 for m in (-3, -2, -1, 0, 1)}
    assert share[30.0] == pytest.approx((power[1] + power[-3]) / sum(power.values()), rel=2e-3)
    assert share[10.0] < 1e-3 * share[30.0]


def test_polarization_contrast_of_a_flat_interface_against_brewsters_angle():
    """The least R_p/R_s over the incidences the light meets, on flat glass (n = 1.5, so the rms
    slope adds nothing): at Brewster's angle arctan(n₂/n₁) (the closed form, independent of the
    code) R_p is 0, in air and under water (n₁ = 1.33); a beam of waist 0.6 µm at λ 0.5 µm spreads
    ±λ/(πw) = ±15.2°, which reaches Brewster's 56.3° from θ_i 45° (the zero) and not from θ_i 20°
    (the least ratio at the spread's upper edge, 35.2°, from the Fresnel formulas written out
    here); through measure_scene the same figure; an index-matched material reflects nothing and
    has no contrast (1)."""
    from wavebrdf.solver.auto import polarization_contrast

    n = 1.5
    surface = generate("flat", cells=16, size_um=4.0, seed=0)

    def scene(theta_deg: float, waist_um: float | None, index: float = n, exterior: float = 1.0) -> SurfaceScene:
        return SurfaceScene(surface, 0.5, complex(index), theta_deg * DEG, 0.0, waist_um, HemisphereGrid(16),
                            exterior_index=exterior)

    def contrast(*args, **kwargs) -> float:
        return polarization_contrast(scene(*args, **kwargs), rms_slope=0.0)

    assert contrast(np.degrees(np.arctan(n)), None) < 1e-12
    assert contrast(np.degrees(np.arctan(n / 1.33)), None, exterior=1.33) < 1e-12
    assert contrast(np.degrees(np.arctan(n)), None, exterior=1.33) > 0.05  # in water Brewster's angle is 48.4°
    assert contrast(45.0, 0.6) < 1e-4  # sampled every 0.17°: within one step of the zero
    edge = np.radians(20.0) + 0.5 / (np.pi * 0.6)
    cos_t = np.sqrt(1 - (np.sin(edge) / n) ** 2)
    r_s = (np.cos(edge) - n * cos_t) / (np.cos(edge) + n * cos_t)
    r_p = (n * np.cos(edge) - cos_t) / (n * np.cos(edge) + cos_t)
    assert contrast(20.0, 0.6) == pytest.approx(r_p ** 2 / r_s ** 2, rel=1e-9)
    assert measure_scene(scene(20.0, 0.6)).polarization_contrast == pytest.approx(r_p ** 2 / r_s ** 2, rel=1e-9)
    assert contrast(30.0, 0.6, index=1.0) == 1.0


def _censored_cost(x, y, censored, ridge):
    """The censored least-squares cost and its gradient, written out here (independent of the rule)."""
    def residual(w):
        r = y - x @ w
        return np.where(censored, np.maximum(r, 0.0), r)

    def cost(w):
        r = residual(w)
        return r @ r + ridge * w @ w

    def gradient(w):
        return -2 * x.T @ residual(w) + 2 * ridge * w

    return cost, gradient


def test_the_rules_censored_fit_against_a_general_minimizer():
    """Rows at the error ceiling are censored: each costs (ceiling − prediction)² only where predicted
    below it. The rule's Newton steps against scipy's L-BFGS on that cost, written out here: on
    data where 14 of 60 rows sit at the ceiling, and where the minimum sits on the kink (an
    intercept whose uncensored rows average exactly the ceiling, censored rows at it: rounding
    flips them in and out, the fit must still end there)."""
    from scipy.optimize import minimize

    from wavebrdf.solver.auto import ERROR_CEILING, _least_squares

    rng = np.random.default_rng(5)
    x = np.column_stack([np.ones(60), rng.normal(size=(60, 3))])
    ceiling = np.log10(ERROR_CEILING)
    y = np.minimum(x @ np.array([-0.8, 0.5, -0.3, 0.8]) + 0.1 * rng.normal(size=60), ceiling)
    censored = y >= ceiling
    assert censored.sum() == 14
    ridge = 1e-3
    cost, gradient = _censored_cost(x, y, censored, ridge)
    best = minimize(cost, np.zeros(4), jac=gradient, method="L-BFGS-B", options={"gtol": 1e-12, "ftol": 1e-15})
    assert _least_squares(x, y, censored, ridge) == pytest.approx(best.x, abs=1e-6)
    plain = np.linalg.solve(x.T @ x + ridge * np.eye(4), x.T @ y)
    assert np.max(np.abs(plain - best.x)) > 1e-2  # the censoring matters on these data

    for seed in range(200):
        draw = np.random.default_rng(seed)
        free = ceiling + 0.1 * draw.normal(size=draw.integers(3, 9))
        y = np.concatenate([free - free.mean() + ceiling, np.full(draw.integers(1, 5), ceiling)])
        censored = np.arange(len(y)) >= len(free)
        fit = _least_squares(np.ones((len(y), 1)), y, censored, 0.0)
        assert fit[0] == pytest.approx(ceiling, abs=1e-9), seed


def test_a_material_unlike_the_tables_gets_no_predicted_rung():
    """The trade table measured aluminium (Re ε −22 … −60 over λ 0.4–0.7 µm) and glass (+2.25). Gold
    at λ 0.6 µm (Re ε −8.0, from the catalogue's Lorentz–Drude model) is unlike both: on steep
    hemispheres at waist 4.2 λ its tangent-plane rungs measured 0.56–0.63 where the rule bounds
    them at 0.30–0.36 (aluminium's measured 0.26–0.29 there; docs/auto.md). So on a smooth surface
    where aluminium gets a cheap rung at tolerance 0.2 (said UNVALIDATED: above the tolerances at
    which the rule's bounds held off its table), gold
    (and silver, Re ε −12.6) gets the full wave, the reason naming the material; water-clear
    n = 1.33 (Re ε 1.77) is like glass within the slack. Where the full wave does not fit the
    budget, the best approximation runs, said not to meet the tolerance and with no predicted
    error."""
    surface = generate("gaussian", cells=64, size_um=4.0, seed=8, rms_height_um=0.01, correlation_um=0.8)

    def choice(index: complex, budget: float | None = None):
        return choose(SurfaceScene(surface, 0.6, index, 20 * DEG, 0.0, 0.6, HemisphereGrid(48),
                                   memory_budget_bytes=budget), 0.2)

    loose = choice(aluminium(0.6))
    assert loose.model != REFERENCE and not loose.unlike
    assert loose.unvalidated == (0.2 > VALIDATED_TOLERANCE) and ("UNVALIDATED" in loose.reason) == loose.unvalidated
    wide = generate("gaussian", cells=180, size_um=9.0, seed=41, rms_height_um=0.01, correlation_um=1.2)
    validated = choose(SurfaceScene(wide, 0.5, aluminium(0.5), 20 * DEG, 0.0, 2.5, HemisphereGrid(48)),
                       VALIDATED_TOLERANCE)  # the second suite's smooth scene at waist 5 λ: a cheap rung, relied on
    assert validated.model != REFERENCE and not validated.unvalidated and "UNVALIDATED" not in validated.reason
    assert choice(complex(1.33)).model != REFERENCE
    for metal in ("gold", "silver"):
        picked = choice(complex(Material.from_name(metal).index(0.6)))
        assert picked.model == REFERENCE and "outside the trade table's metals" in picked.unlike, picked.reason
    starved = choice(complex(Material.from_name("gold").index(0.6)), budget=1e6)
    assert starved.model != REFERENCE and not starved.within and np.isnan(starved.predicted_error), starved.reason


def test_a_spot_check_records_the_rules_prediction_only_for_a_material_like_the_tables(cl_ctx):
    """A spot check's JSON holds each checked rung's measured error and, beside it, what the rule
    predicted — which it must not claim for a material the rule relies on no prediction for (gold
    at λ 0.6 µm); aluminium on the same patch keeps it."""
    import json

    surface = generate("gaussian", cells=40, size_um=2.0, seed=8, rms_height_um=0.01, correlation_um=0.6)
    for index, like in ((aluminium(0.6), True), (complex(Material.from_name("gold").index(0.6)), False)):
        scene = SurfaceScene(surface, 0.6, index, 20 * DEG, 0.0, 0.5, HemisphereGrid(16))
        auto = AutoModel({"tolerance": TOLERANCE})
        checked = json.loads(auto.spot_check(cl_ctx, scene).diagnostics["spot_check"])
        auto.release()
        assert checked and all(m["error"] is not None for m in checked.values()), checked
        assert all(("predicted" in m) == like for m in checked.values()), (like, checked)
        fitted = [n for n in checked if n in default_rule().coefficients]  # stam is checked, not fitted
        assert fitted and all(checked[n]["predicted"] is not None for n in fitted if like), checked


def _subwavelength_grating(budget: float | None = None) -> SurfaceScene:
    """Aluminium grating of period 0.4 µm at λ 0.5 µm (only the specular order propagates),
    amplitude 0.05 µm, 8 µm patch, waist 1.5 µm, normal incidence: the rule, which has seen no
    grating finer than λ, predicts kirchhoff within 0.05, whose tangent plane drops ≈ 60 % of the
    power into evanescent orders (tests/test_sampling_validity.py)."""
    grating = generate("sinusoid", cells=160, size_um=8.0, amplitude_um=0.05, period_um=0.4)
    return SurfaceScene(grating, 0.5, aluminium(0.5), 0.0, 0.0, 1.5, HemisphereGrid(48), memory_budget_bytes=budget)


def _run_auto(cl_ctx, scene: SurfaceScene):
    auto = AutoModel({"tolerance": TOLERANCE})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = auto.run(cl_ctx, scene)
    auto.release()
    return result, [f"{w.category.__name__}: {w.message}" for w in caught]


def test_a_rung_its_own_run_measures_outside_is_not_returned_silently(cl_ctx):
    """On the sub-wavelength grating with a budget the full wave does not fit, auto runs the rung
    the rule predicts within tolerance; that run measures its albedo 58 % below its lit facets'
    (its error at least about that), so auto says it misses the tolerance — in a ToleranceWarning
    and the reason — beside the rung's own ValidityWarning."""
    scene = _subwavelength_grating(budget=3e8)
    assert choose(scene, TOLERANCE).model not in (REFERENCE,)  # the rule alone would rely on a cheap rung
    result, said = _run_auto(cl_ctx, scene)
    name = result.diagnostics["model"]
    assert name != REFERENCE and result.diagnostics["lit_facet_deficit"] > 0.5
    assert "below its lit facets'" in result.diagnostics["model_reason"]
    assert any(w.startswith("ToleranceWarning") and "below its lit facets'" in w for w in said), said
    assert any(w.startswith("ValidityWarning") and f"{name}: albedo" in w for w in said), said


def test_a_measured_loss_escalates_only_beyond_the_tolerance_and_its_slack():
    """A rung's own measure decides beyond tolerance + LIT_FACET_SLACK only (the deficit exceeded
    the measured error by up to that on the trade table), not where the pixels' sampling explains
    it, and a task already warned of the tolerance is not warned twice. The rung is a stand-in
    returning set figures; the full wave does not fit the budget."""
    from wavebrdf.solver.validity import LIT_FACET_SLACK

    class Figures:
        def __init__(self, deficit: float, sampling: float = 0.0):
            self.diagnostics = {"lit_facet_deficit": deficit, "lit_facet_sampling": sampling}

    class StandIn:
        figures = None

        def run(self, ctx, scene):
            return StandIn.figures

        def release(self):
            pass

    scene = _subwavelength_grating(budget=3e8)
    auto = AutoModel({"tolerance": TOLERANCE})
    auto._rungs["kirchhoff"] = StandIn()
    for deficit, sampling, warned, expected in ((TOLERANCE + LIT_FACET_SLACK - 1e-3, 0.0, False, 0),
                                                (TOLERANCE + LIT_FACET_SLACK + 1e-3, 0.0, False, 1),
                                                (TOLERANCE + LIT_FACET_SLACK + 1e-3, 0.5, False, 0),
                                                (TOLERANCE + LIT_FACET_SLACK + 1e-3, 0.0, True, 0)):
        StandIn.figures = Figures(deficit, sampling)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            name, _, reason = auto._run_measured(None, scene, "kirchhoff", "rule", [], warned=warned)
        said = [w for w in caught if w.category.__name__ == "ToleranceWarning"]
        assert name == "kirchhoff" and len(said) == expected, (deficit, sampling, warned, reason)
        assert ("below its lit facets'" in reason) == (expected == 1 or warned), reason


@pytest.mark.slow
def test_a_rung_its_own_run_measures_outside_is_replaced_by_the_full_wave(cl_ctx):
    """The same grating within the budget: auto replaces the rung by the full wave, whose albedo
    is far above what the rung returned (the full wave keeps the evanescent orders' power in the
    specular one), and the rung's warnings are set aside, not the task's."""
    result, said = _run_auto(cl_ctx, _subwavelength_grating())
    assert result.diagnostics["model"] == REFERENCE and "escalated to bem" in result.diagnostics["model_reason"]
    assert float(np.mean(albedo(result.brdf(), result.grid))) > 0.7
    assert "lit facet" in result.diagnostics["escalation_check_warnings"]
    assert not any("lit facet" in w or w.startswith("ToleranceWarning") for w in said), said


def test_multiple_scattering_scenes_never_get_a_single_scattering_rung():
    rng = np.random.default_rng(2026)
    picks = []
    for k in range(6):
        lam, theta = rng.uniform(0.4, 0.8), rng.choice([0.0, 20.0, 45.0])
        if k % 2 == 0:
            period = float(rng.choice([0.8, 1.0, 2.0]))
            scene = fresh_scene("corner-cubes", lam, theta, k, period_um=period, shape=rng.choice(["full", "triangular"]))
        else:
            radius = rng.uniform(0.35, 0.5)
            scene = fresh_scene("spherical-pits", lam, theta, k, radius_um=radius, depth_um=rng.uniform(0.5, 0.8) * radius,
                                period_um=1.0)
        choice = choose(scene, TOLERANCE)
        picks.append((scene.surface.parameters["generator"], round(lam, 3), theta, choice.model))
        assert choice.model not in SINGLE_SCATTERING, choice.reason
    logger.info("multiple-scattering scenes: %s", picks)


def test_smooth_low_slope_random_surfaces_are_expected_cheap_where_spot_checks_measure():
    """Where a study's spot checks decide (several tasks), ``plan`` expects the rung the checks are
    expected to measure within the tolerance: the rule's fit without its margin, times the option's
    ``margin``. On smooth low-slope aluminium that is never the full wave. (A one-task study takes
    the rule's bound, fit times its jackknife margin: the full wave at oblique
    incidence here — docs/auto.md, Limits; tests/test_auto_measured.py runs such a study.)"""
    rng = np.random.default_rng(7)
    picks = []
    for k in range(6):
        lam, theta = rng.uniform(0.4, 0.8), rng.uniform(0.0, 60.0)
        scene = fresh_scene("gaussian", lam, theta, 100 + k, rms_height_um=rng.uniform(0.002, 0.012),
                            correlation_um=rng.uniform(0.4, 1.0))
        expected = AutoModel({"tolerance": TOLERANCE}).choice(scene, checked=True)
        alone = AutoModel({"tolerance": TOLERANCE}).choice(scene)
        picks.append((round(lam, 3), round(theta), expected.model, alone.model))
        assert expected.model != REFERENCE, expected.reason
        assert expected.predicted_error * AutoOptions().margin <= TOLERANCE
    logger.info("smooth random scenes (λ, θ_i, expected with spot checks, one task): %s", picks)


def test_an_auto_study_plans_and_runs_storing_the_rung_and_its_reason(tmp_path):
    """The rule's path (no spot checks: ``spot_check_share = 0``; tests/test_auto_measured.py has
    the measured one): plan shows the choice, run stores the rung and its reason per task. A smooth
    patch at θ_i ≤ 20°, where the one-task rule's bound takes ghs (beyond ≈ 25° it expects the full
    wave at this waist: docs/auto.md, Limits)."""
    import h5py

    config = tmp_path / "auto.toml"
    config.write_text(
        '[study]\nname = "auto"\noutput = "auto.h5"\n'
        '[surface]\ngenerator = "gaussian"\nsize_um = 4.0\ncells = 64\nrms_height_um = 0.008\ncorrelation_um = 0.6\n'
        'seed = 5\n[material]\nname = "aluminium"\n'
        '[illumination]\nwavelengths_um = [0.6]\ndirections_deg = [[0, 0], [20, 0]]\nwaist_um = 0.6\n'
        '[model]\nname = "auto"\ntolerance = 0.05\nspot_check_share = 0\n[output]\nresolution = 48\n')
    wavebrdf = [sys.executable, "-m", "wavebrdf"]
    plan = subprocess.run(wavebrdf + ["plan", str(config)], cwd=tmp_path, capture_output=True, text=True)
    assert plan.returncode == 0, plan.stderr
    assert plan.stdout.count("auto → ") == 2 and "avoids bem" in plan.stdout and "auto: " in plan.stdout
    run = subprocess.run(wavebrdf + ["run", str(config), "-q"], cwd=tmp_path, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    with h5py.File(tmp_path / "auto.h5") as h5:
        models = [m.decode() if isinstance(m, bytes) else m for m in h5["tasks/model"][()]]
        reasons = [m.decode() if isinstance(m, bytes) else m for m in h5["tasks/model_reason"][()]]
        albedo = h5["albedo"][()]
    assert all(m not in ("auto", REFERENCE, "") for m in models), models
    assert all("predicted" in r and any(w in r for w in ("checked against", "escalated", "nothing to check"))
               for r in reasons), reasons
    assert np.all((albedo > 0.8) & (albedo < 1.0))  # smooth aluminium at 0.6 µm: Fresnel 0.91


SMALL = dict(size_um=3.2, cells=48, waist_um=0.5)  # the table's waist-≈λ suites: 4 µm, 80 cells, waist 0.6 µm
WIDE = dict(size_um=9.0, cells=180, waist_um=2.5)  # the reference simulator's waist, 5 λ at 0.5 µm
SECOND_SUITE = [  # (generator, parameters, λ µm, θ_i°, patch, material: a catalogue name or n): new seeds, parameters
    ("gaussian", dict(rms_height_um=0.006, correlation_um=0.7, seed=31), 0.6, 30.0, SMALL, "aluminium"),
    ("gaussian", dict(rms_height_um=0.09, correlation_um=0.6, seed=32), 0.6, 60.0, SMALL, "aluminium"),
    ("brushed", dict(rms_height_um=0.03, correlation_um=[1.5, 0.25], angle_deg=-20.0, seed=33), 0.6, 30.0, SMALL,
     "aluminium"),
    ("sinusoid", dict(amplitude_um=0.025, period_um=0.8), 0.6, 20.0, SMALL, "aluminium"),
    ("hemispheres", dict(radius_um=0.4, fill=0.3, placement="random", seed=34), 0.6, 30.0, SMALL, "aluminium"),
    ("corner-cubes", dict(period_um=0.8, shape="full"), 0.6, 10.0, SMALL, "aluminium"),
    ("spherical-pits", dict(radius_um=0.4, depth_um=0.25, period_um=0.8), 0.6, 30.0, SMALL, "aluminium"),
    ("gaussian", dict(rms_height_um=0.008, correlation_um=0.8, seed=35), 0.55, 45.0, SMALL, "glass"),
    ("gaussian", dict(rms_height_um=0.1, correlation_um=0.5, seed=36), 0.55, 0.0, SMALL, "glass"),
    ("gaussian", dict(rms_height_um=0.01, correlation_um=1.2, seed=41), 0.5, 20.0, WIDE, "aluminium"),
    ("gaussian", dict(rms_height_um=0.1, correlation_um=1.0, seed=42), 0.5, 20.0, WIDE, "aluminium"),
    ("hemispheres", dict(radius_um=0.5, fill=0.3, placement="random", seed=43), 0.5, 20.0, WIDE, "aluminium"),
    # the same at λ 0.6 µm: the tangent-plane errors rise (0.26–0.29) while the regressors say the scene got easier
    ("hemispheres", dict(radius_um=0.5, fill=0.3, placement="random", seed=43), 0.6, 20.0, WIDE, "aluminium"),
    # other metals (copper, silver: Re ε within the table's metals' slack), dielectrics of other index (a number: n),
    # grazing incidence, small hemispheres at normal incidence
    ("gaussian", dict(rms_height_um=0.02, correlation_um=0.8, seed=51), 0.7, 45.0, SMALL, "copper"),
    ("gaussian", dict(rms_height_um=0.05, correlation_um=0.7, seed=52), 0.7, 0.0, SMALL, "silver"),
    ("brushed", dict(rms_height_um=0.04, correlation_um=[1.2, 0.3], angle_deg=30.0, seed=53), 0.7, 20.0, SMALL,
     "copper"),
    ("sinusoid", dict(amplitude_um=0.04, period_um=3.2 / 3), 0.7, 30.0, SMALL, "silver"),
    ("gaussian", dict(rms_height_um=0.004, correlation_um=0.9, seed=55), 0.45, 70.0, SMALL, "aluminium"),
    ("hemispheres", dict(radius_um=0.3, fill=0.2, placement="random", seed=56), 0.45, 0.0, SMALL, "aluminium"),
    ("gaussian", dict(rms_height_um=0.03, correlation_um=0.8, seed=57), 0.65, 20.0, SMALL, 1.5),
    ("gaussian", dict(rms_height_um=0.01, correlation_um=1.0, seed=58), 0.5, 10.0, SMALL, 1.7),
    ("brushed", dict(rms_height_um=0.02, correlation_um=[1.5, 0.4], angle_deg=0.0, seed=59), 0.55, 30.0, SMALL, 1.33),
    ("spherical-pits", dict(radius_um=0.35, depth_um=0.15, period_um=3.2 / 3), 0.7, 20.0, SMALL, "copper"),
    ("gaussian", dict(rms_height_um=0.04, correlation_um=0.8, seed=61), 0.55, 40.0, WIDE, "aluminium"),
    ("gaussian", dict(rms_height_um=0.06, correlation_um=1.5, seed=62), 0.7, 10.0, WIDE, "silver"),
]
SECOND_SUITE_TOLERANCES = (TOLERANCE, 0.01, 0.1, 0.2)


def second_suite_scenes() -> list[tuple[str, SurfaceScene]]:
    scenes = []
    for generator, params, lam, theta, patch, material in SECOND_SUITE:
        params = dict(params)
        seed = params.pop("seed", 0)
        surface = generate(generator, cells=patch["cells"], size_um=patch["size_um"], seed=seed, **params)
        named = isinstance(material, str)
        index = complex(Material.from_name(material).index(lam)) if named else complex(material)
        rms = f" σ {params['rms_height_um']:g} µm" if "rms_height_um" in params else ""
        label = (f"{generator}{rms} {material if named else f'n={material:g}'} w={patch['waist_um']:g} λ={lam:g} "
                 f"θi={theta:.0f}°")
        scenes.append((label, SurfaceScene(surface, lam, index, theta * DEG, 0.0, patch["waist_um"], HemisphereGrid(96))))
    return scenes


def compare_second_suite():
    """Every rung and AIM BEM on the second suite (the slow part: 25 full-wave solves, six of them
    on 9 µm patches)."""
    from wavebrdf.jobs.compare import compare_scenes

    rungs = ["gs", "gm", "ohs", "ghs", "kirchhoff", "ws-v", "wm", "po"]
    return compare_scenes(second_suite_scenes(), rungs + [REFERENCE], {REFERENCE: {"method": "aim"}},
                          reference=REFERENCE)


def evaluate_auto_on(comparison, tolerance: float = TOLERANCE) -> list[dict]:
    """auto (escalation check included) on each scene of ``comparison``: its rung, error against
    the reference's BRDF, CPU time (pilot and check included), and the cheapest rung within
    ``tolerance`` by the comparison's measured errors (each the worst of s, p and unpolarized)."""
    from wavebrdf.jobs.compare import MeasuringProcess, comparison_metrics, speckle_sigma_u
    from wavebrdf.solver.auto import AutoModel

    out = []
    with MeasuringProcess() as process:
        for label, scene in second_suite_scenes():
            rows = {r["model"]: r for r in comparison.rows if r["scene"] == label}
            ref = next(m for m in comparison.measurements if m.scene == label and m.model == REFERENCE)
            choice = AutoModel({"tolerance": tolerance}).choice(scene)
            picked = choice.model
            if picked == REFERENCE:  # the same full-wave run: nothing to approximate
                error, cpu, ran = 0.0, rows[REFERENCE]["cpu_s"], REFERENCE
            else:
                run = process.measure("auto", {"tolerance": tolerance}, scene, label)
                assert run.failure is None, run.failure
                sigma = speckle_sigma_u(scene.wavelength_um, scene.waist_um, comparison.grid)
                error = table_error(comparison_metrics(run, ref, comparison.grid, sigma, scene.theta_i, scene.phi_i))
                cpu, ran = run.cpu_s, run.diagnostics["model"]
            within = sorted((r["cpu_s"], m) for m, r in rows.items() if table_error(r) <= tolerance)
            out.append(dict(scene=label, picked=picked, ran=ran, error=error, cpu=cpu, bem_cpu=rows[REFERENCE]["cpu_s"],
                            unvalidated=choice.unvalidated,
                            cheapest=within[0][1] if within else REFERENCE))
    return out


# 25 full-wave solves: 16 min on the idle 2-core machine, past the suite's 30-minute limit when the
# machine is shared
@pytest.mark.slow
@pytest.mark.timeout(7200)
def test_second_suite_against_the_full_wave_reference():
    """Fresh scenes (new seeds, parameters and patches; aluminium, copper, silver, glass and
    dielectrics of n 1.33 and 1.7 at waist 0.5 µm ≈ λ, θ_i 0–70°; aluminium and silver one-task
    studies at waist 2.5 µm: smooth, bumpy and steep at λ 0.5 µm (5 λ), steep at 0.6 µm (4.2 λ))
    through auto and every rung, against AIM BEM: the rung auto ran within the tolerance in every
    scene at 0.01 and 0.05 (up to VALIDATED_TOLERANCE), and at 0.1 and 0.2 within or said
    UNVALIDATED — never a silent miss; the cheapest such rung in most at 0.05; printed: the rule's
    predicted error of each rung beside the measured one, the CPU time saved against BEM everywhere
    and the worst error."""
    comparison = compare_second_suite()
    rule = default_rule()
    print("| scene | rung | predicted (bound) | rule's fit | measured | CPU (s) |")
    for label, scene in second_suite_scenes():
        features = measure_scene(scene)
        for r in sorted((r for r in comparison.rows if r["scene"] == label), key=lambda r: r.get("cpu_s", np.inf)):
            print(f"| {label} | {r['model']} | {rule.predict(r['model'], features):.3g} | "
                  f"{rule.predict(r['model'], features, central=True):.3g} | {table_error(r):.3g} | "
                  f"{r.get('cpu_s', np.nan):.3g} |")
    for tolerance in SECOND_SUITE_TOLERANCES:
        results = evaluate_auto_on(comparison, tolerance)
        for r in results:
            print(f"tolerance {tolerance:g}, {r['scene']}: auto → {r['ran']} (chose {r['picked']}"
                  f"{', UNVALIDATED' if r['unvalidated'] else ''}) error {r['error']:.3g}, CPU {r['cpu']:.3g} s; "
                  f"cheapest within tolerance {r['cheapest']}")
        within = sum(r["error"] <= tolerance for r in results)
        cheapest = sum(r["ran"] == r["cheapest"] for r in results)
        saved = sum(r["bem_cpu"] for r in results) / sum(r["cpu"] for r in results)
        print(f"second suite, tolerance {tolerance:g}: within {within}/{len(results)}, cheapest {cheapest}/{len(results)}, "
              f"worst error {max(r['error'] for r in results):.3g}, CPU of BEM everywhere / auto {saved:.3g}")
        silent = [r["scene"] for r in results if r["error"] > tolerance and not r["unvalidated"]]
        assert not silent, f"tolerance {tolerance:g}: missed without a word on {silent}"
        if tolerance <= VALIDATED_TOLERANCE:
            assert within == len(results)
        if tolerance == TOLERANCE:
            assert cheapest >= len(results) / 2
