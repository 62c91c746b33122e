"""Flat patches: albedo = the exact beam's Fresnel reflectance, energy balance, no gain, extremes.

Independent references: the beam's spectrum-weighted Fresnel reflectance — the textbook Fresnel
formulas of tests/references.py applied to each plane wave of the exact beam (the beam is the
scene's input; its reflection is computed here, not by the model) — and energy conservation
(reflected power + power entering the material through the surface = incident power).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from wavebrdf.solver.bem3d import (
    BEMSolver,
    BEMWarning,
    DenseTooLarge,
    FootprintWarning,
    MaterialWarning,
    ResolutionWarning,
    bem_farfield,
    estimate_dense,
)
from wavebrdf.solver.beams import ExactGaussianBeam
from wavebrdf.solver.farfield import HemisphereGrid, albedo
from wavebrdf.solver.surface import generate

from references import beam_fresnel_reflectance

LAMBDA = 0.4
AL = 0.46582 - 4.7119j


def _flat(cells, size):
    return generate("flat", cells=cells, size_um=size)


def reference_beam_reflectance(ff, index, size_um):
    """(s, p) reflectance of the exact beam of ``ff`` (θ_i, φ_i, waist, focus at the origin) on the
    flat interface over ``index``: tests/references.py's Fresnel per plane wave."""
    beam = ExactGaussianBeam(LAMBDA, ff.theta_i, ff.phi_i, waist_um=ff.diagnostics["waist_um"],
                             patch_size_um=size_um)
    waves = beam.plane_waves
    expected = beam_fresnel_reflectance(waves["kvec"], waves["E"], 1.0, index)
    # the model's own figure for the same beam (solver/beams.py with solver/fresnel.py) agrees
    assert np.allclose(ff.diagnostics["beam_reflectance"], expected, rtol=1e-10)
    return expected


def _check_albedo(ff, grid, tolerance, label="", *, index, size_um):
    measured = albedo(ff.brdf(), grid)
    expected = reference_beam_reflectance(ff, index, size_um)
    into = ff.diagnostics["into_material_fraction"]
    print(f"{label} albedo s,p = {measured}, exact beam {expected}, rel. error "
          f"{measured / expected - 1}, into material {into}, energy {measured + into}")
    assert np.all(np.abs(measured / expected - 1) < tolerance)
    assert np.all(np.abs(measured + into - 1) < tolerance)
    return measured


@pytest.fixture(scope="module")
def small_grid():
    return HemisphereGrid(64)


@pytest.mark.parametrize("index", [1.5, AL])
def test_small_flat_patch_albedo_equals_exact_beam_reflectance(cl_ctx, small_grid, index):
    """2.5λ patch, d = λ/6.4, waist L/5, normal incidence: within 1% (both polarizations)."""
    surface = _flat(16, 1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ResolutionWarning)
        ff = bem_farfield(cl_ctx, surface, LAMBDA, index, 0.0, 0.0, 0.2, small_grid)
    _check_albedo(ff, small_grid, 0.01, f"n = {index}", index=index, size_um=surface.size_um)
    assert np.all(ff.diagnostics["residual"] < 1e-10)
    assert ff.diagnostics["unknowns"] == 4 * 16 * 15
    # the reflected lobe peaks at the mirror direction (the pole)
    brdf = np.nan_to_num(ff.brdf()[0])
    i, j = np.unravel_index(np.argmax(brdf), brdf.shape)
    assert abs(small_grid.u[i]) < 0.05 and abs(small_grid.u[j]) < 0.05


def test_metal_absorbs_never_gains(cl_ctx, small_grid):
    """κ ≥ 0 is loss: power flows into the metal and the albedo is below 1; a gain index is refused."""
    surface = _flat(12, 0.75)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BEMWarning)
        ff = bem_farfield(cl_ctx, surface, LAMBDA, AL, 0.3, 0.0, 0.15, small_grid)
    into = ff.diagnostics["into_material_fraction"]
    assert np.all(into > 0.03) and np.all(albedo(ff.brdf(), small_grid) < 0.97)
    with pytest.raises(ValueError, match="kappa >= 0 is loss"):
        bem_farfield(cl_ctx, surface, LAMBDA, np.conj(AL), 0.3, 0.0, 0.15, small_grid)


def test_dense_path_refuses_what_does_not_fit(cl_ctx, small_grid):
    surface = _flat(40, 2.0)
    est = estimate_dense(surface, memory_limit_bytes=2**30)
    assert est["unknowns"] == 4 * 40 * 39 and est["matrix_bytes"] == 16 * est["unknowns"] ** 2
    assert not est["fits"]
    with pytest.raises(DenseTooLarge, match=r"6240 unknowns.*GiB"):
        bem_farfield(cl_ctx, surface, LAMBDA, 1.5, 0.0, 0.0, 0.4, small_grid, memory_limit_bytes=2**30)


def _run_with_warnings(cl_ctx, grid, index, theta, cells=12, size=0.75, waist=0.15):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ff = bem_farfield(cl_ctx, _flat(cells, size), LAMBDA, index, theta, 0.0, waist, grid)
    assert np.all(np.isfinite(ff.E)) and np.all(np.isfinite(ff.H))
    assert np.all(np.isfinite(ff.brdf()[:, grid.inside]))
    return ff, [w.category for w in caught if issubclass(w.category, (BEMWarning, FootprintWarning))]


def test_grazing_incidence_warns_and_stays_finite(cl_ctx, small_grid):
    ff, categories = _run_with_warnings(cl_ctx, small_grid, 1.5, np.deg2rad(85.0))
    assert FootprintWarning in categories
    assert any("FootprintWarning" in w for w in ff.diagnostics["warnings"])
    assert ff.diagnostics["incident_outside_fraction"] > 1e-3


def test_extreme_materials_warn_and_are_continuous_in_kappa(cl_ctx, small_grid):
    """κ = 1e-4 (weak absorber) and κ = 10 (strong conductor) warn; no jump between κ = 0 and 1e-4."""
    ff0, cat0 = _run_with_warnings(cl_ctx, small_grid, 1.5, 0.0)
    ff_weak, cat_weak = _run_with_warnings(cl_ctx, small_grid, 1.5 - 1e-4j, 0.0)
    ff_strong, cat_strong = _run_with_warnings(cl_ctx, small_grid, 1.0 - 10j, 0.0)
    assert MaterialWarning not in cat0
    assert MaterialWarning in cat_weak
    assert MaterialWarning in cat_strong and ResolutionWarning in cat_strong
    a0, a_weak = albedo(ff0.brdf(), small_grid), albedo(ff_weak.brdf(), small_grid)
    assert np.allclose(a_weak, a0, rtol=1e-3)
    a_strong = albedo(ff_strong.brdf(), small_grid)
    assert np.all((a_strong > 0.9) & (a_strong <= 1.0))


def test_dense_solver_reuses_the_factorization(cl_ctx, small_grid):
    """One dense BEMSolver serves several directions and beams; the residual is reported per polarization."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BEMWarning)
        solver = BEMSolver(cl_ctx, _flat(12, 0.75), LAMBDA, 1.5)
        a = solver.farfield(0.2, 0.5, small_grid, waist_um=0.15, beam="exact")
        b = solver.farfield(0.2, 0.5, small_grid, waist_um=0.15, beam="paraxial")
        c = solver.farfield(0.4, 1.0, small_grid, waist_um=0.15)
    for ff in (a, b, c):
        assert ff.diagnostics["residual"].shape == (2,) and np.all(ff.diagnostics["residual"] < 1e-10)
    assert a.diagnostics["beam"] == "exact" and b.diagnostics["beam"] == "paraxial"


@pytest.mark.slow
@pytest.mark.parametrize("index", [1.5, AL])
def test_acceptance_flat_patch(cl_ctx, index):
    """8λ × 8λ patch (the largest dense problem that runs in minutes here: 16128 unknowns), d = λ/8,
    waist L/5, exact beam, θ_i = 0° and 45°: albedo within 1% of the beam's exact reflectance per
    polarization, both from the output grid and from the hemisphere quadrature (the paraxial beam
    is reported, not asserted). On 6λ patches (waist 1.2λ) the 45° case misses 1% for the weak
    p reflection of glass: the beam's grazing plane waves leak past the patch (docs/bem3d.md)."""
    grid = HemisphereGrid(128)
    surface = _flat(64, 8 * LAMBDA)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BEMWarning)
        solver = BEMSolver(cl_ctx, surface, LAMBDA, index)
        for theta in (0.0, 45.0):
            ff = solver.farfield(np.deg2rad(theta), 0.0, grid, waist_um=surface.size_um / 5)
            _check_albedo(ff, grid, 0.01, f"n = {index}, θ = {theta}°, exact beam:", index=index,
                          size_um=surface.size_um)
            reference = reference_beam_reflectance(ff, index, surface.size_um)
            hemisphere = ff.diagnostics["reflected_fraction"] / reference - 1
            print(f"   hemisphere-quadrature albedo / exact reflectance − 1 = {hemisphere}")
            assert np.all(np.abs(hemisphere) < 0.01)
            par = solver.farfield(np.deg2rad(theta), 0.0, grid, waist_um=surface.size_um / 5, beam="paraxial")
            print(f"n = {index}, θ = {theta}°, paraxial beam: albedo {albedo(par.brdf(), grid)}, hemisphere "
                  f"{par.diagnostics['reflected_fraction']} (exact beam's reflectance "
                  f"{ff.diagnostics['beam_reflectance']})")


def test_a_beam_without_positive_power_is_an_error_not_a_result(cl_ctx, small_grid):
    """A paraxial 'beam' of waist λ/5 at 45° on a λ patch has no positive flux through it: refused."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BEMWarning)
        with pytest.raises(FloatingPointError, match="not positive"):
            bem_farfield(cl_ctx, _flat(8, 0.4), LAMBDA, 1.5, np.deg2rad(45.0), 0.0, 0.08, small_grid,
                         beam="paraxial")
