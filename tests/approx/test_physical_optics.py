"""The ``po`` rung (vector physical optics, approx.md §3.6) against independent references:

* a flat perfect conductor: the textbook PO far field of the current sheet J = 2 n̂ × H_i under a
  Gaussian footprint, f = (2πw²/λ²) e^{−k²w²|s|²/2} (1 − (ω_o·ê)²)/μ_o (peak A_eff/λ², A_eff = 2πw²);
* a flat metal: exactly |r_s|², |r_p|² × A_eff/λ² at the mirror direction (tests/references.py);
* a tilted, azimuthally rotated facet h = ax + by: peak at the facet mirror, the reflected field
  r_s(ê·ŝ')ŝ' + r_p(ê·p̂')p̂'_r of the facet's own plane of incidence (polarization rotation and
  cross-polarization), albedo (ω_i·m̃/μ_i)(|r_s|²|ê·ŝ'|² + |r_p|²|ê·p̂'|²);
* Kirchhoff on a gently rough surface at normal incidence (the issue's bar: 2% per polarization);
* lit by the exact beam's plane waves (``incidence = "beam"``), a flat interface under a tight beam:
  the whole lobe is every plane wave of the beam's spectrum reflected with textbook Fresnel at its
  own angle (far field (2πk μ_o)²|Ê_r(κ)|² of the reflected spectrum), and the albedo the beam's
  Fresnel reflectance; its incident fields are the full-wave solver's beam, whose flux is Φ_i;
* OpenCL = NumPy twins (ray-traced shadowing included), single ≈ double, the shared incident
  beam and its power, options;
* slow: PO and Kirchhoff against dense BEM on a moderately rough aluminium patch (figures logged).
"""

from __future__ import annotations

import logging

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from references import (ALUMINIUM_400NM, beam_fresnel_reflectance, fresnel_coefficients, fresnel_reflectance,
                        reflected_spectrum_brdf)
from wavebrdf.solver.approx.kirchhoff import kirchhoff_farfield
from wavebrdf.solver.approx.physical_optics import po_farfield
from wavebrdf.solver.beams import BeamWaves, make_beam
from wavebrdf.solver.farfield import ETA0, HemisphereGrid, albedo, transverse_basis
from wavebrdf.solver.models import SurfaceScene, get_model
from wavebrdf.solver.options import OptionsError
from wavebrdf.solver.surface import HeightField, generate
from wavebrdf.solver.validity import ValidityWarning

logger = logging.getLogger(__name__)

DEG = np.pi / 180
PEC = 1e-3 - 1e6j  # |r_s + 1|, |r_p − 1| ~ 1e-6


def _pixel_incidence(grid: HemisphereGrid, i: int, j: int) -> tuple[float, float]:
    """(θ_i, φ_i) whose mirror direction −u_i is the centre of pixel (i, j)."""
    u_i = -np.array([grid.u[i], grid.u[j]])
    return float(np.arcsin(np.hypot(*u_i))), float(np.arctan2(u_i[1], u_i[0]))


def _lobe_l2(f: np.ndarray, ref: np.ndarray, floor: float = 1e-3) -> float:
    f, ref = np.nan_to_num(f), np.nan_to_num(ref)
    lobe = ref > floor * ref.max()
    return float(np.linalg.norm((f - ref)[lobe]) / np.linalg.norm(ref[lobe]))


@pytest.fixture(scope="module")
def plate():
    """Flat 24 µm patch, λ = 0.5 µm, waist 3 µm (patch 8 w: Σ W Δ² = πw² to 1e-12)."""
    return dict(surface=generate("flat", cells=240, size_um=24.0), lam=0.5, waist=3.0, grid=HemisphereGrid(128))


def test_flat_pec_plate_lobe(cl_ctx, plate):
    """Normal incidence on a PEC plate: the whole lobe equals the analytic PO lobe of the reflected
    field's currents J' = ẑ × η₁H_r = ê W, M = −ẑ × E_r = ẑ × ê W, whose far-field vector
    ω(ω·ê) − ê + ω × (ẑ × ê) has |·|² = (1 + μ_o)² for either polarization (ê_s = ŷ, ê_p = −x̂)."""
    grid, lam, w = plate["grid"], plate["lam"], plate["waist"]
    ff = po_farfield(cl_ctx, SurfaceScene(plate["surface"], lam, PEC, 0.0, 0.0, w, grid))
    U, V = grid.uv
    k = 2 * np.pi / lam
    gauss = (2 * np.pi * w**2 / lam**2) * np.exp(-0.5 * (k * w) ** 2 * (U**2 + V**2)) / np.where(grid.inside, grid.mu, 1)
    for p in range(2):
        expected = np.where(grid.inside, gauss * (1 + grid.mu) ** 2 / 4, np.nan)
        err = _lobe_l2(ff.brdf()[p], expected)
        logger.info("PEC plate, pol %d: relative L2 over the lobe vs the analytic PO lobe %.2e", p, err)
        assert err < 1e-4
    assert np.all(albedo(ff.brdf(), grid) <= 1.0 + 1e-3)


@pytest.mark.parametrize("pixel", [(64, 64), (80, 70), (100, 64), (110, 90)])
def test_flat_metal_mirror_peak_is_fresnel(cl_ctx, plate, pixel):
    """Aluminium: at the mirror direction (a pixel centre) f = |r_s|², |r_p|² × 2πw²/λ²."""
    grid, lam, w = plate["grid"], plate["lam"], plate["waist"]
    theta, phi = _pixel_incidence(grid, *pixel)
    ff = po_farfield(cl_ctx, SurfaceScene(plate["surface"], lam, ALUMINIUM_400NM, theta, phi, w, grid))
    peak = ff.brdf()[:, pixel[0], pixel[1]] / (2 * np.pi * w**2 / lam**2)
    expected = np.array(fresnel_reflectance(1.0, ALUMINIUM_400NM, theta))
    logger.info("θ_i = %.2f°: mirror-direction f/(A/λ²) s,p %s vs Fresnel %s", theta / DEG, peak, expected)
    assert np.allclose(peak, expected, rtol=1e-5)


def test_tilted_facet_reflects_in_its_own_frame(cl_ctx):
    """h = 0.08 x + 0.05 y (facet normal out of the plane of incidence): the lobe peaks at the
    facet mirror ω_r (a pixel centre), where the field is the Fresnel reflection in the facet's
    s/p frame — rotated polarization, cross-polarized component — and the albedo is
    (ω_i·m̃/μ_i)(|r_s|²|ê·ŝ'|² + |r_p|²|ê·p̂'|²)."""
    lam, w, a, b = 0.5, 3.2, 0.08, 0.05
    size, cells = 20.0, 100
    x = -0.5 * size + size / cells * np.arange(cells + 1)
    surface = HeightField(a * x[:, None] + b * x[None, :], size)
    grid = HemisphereGrid(128)
    i, j = 42, 76  # ω_i ≈ 20° with its azimuth across the tilt: the facet's plane of incidence turns by ~15°
    omega_r = grid.directions[i, j]
    mt = np.array([-a, -b, 1.0])
    m = mt / np.linalg.norm(mt)
    omega_i = 2 * (omega_r @ m) * m - omega_r
    theta, phi = float(np.arccos(omega_i[2])), float(np.arctan2(omega_i[1], omega_i[0]))
    ff = po_farfield(cl_ctx, SurfaceScene(surface, lam, ALUMINIUM_400NM, theta, phi, w, grid), border="clamp")
    assert ff.diagnostics["shadowed_fraction"] == 0.0 and ff.diagnostics["back_facing_fraction"] == 0.0
    brdf = ff.brdf()
    intensity = np.nan_to_num(brdf.mean(axis=0)) * grid.mu
    assert np.unravel_index(np.argmax(intensity), intensity.shape) == (i, j)
    # the facet's plane of incidence
    k_hat = -omega_i
    c = float(omega_i @ m)
    s = np.cross(k_hat, m)
    s /= np.linalg.norm(s)
    p_i, p_r = np.cross(s, k_hat), np.cross(s, omega_r)
    r_s, r_p = fresnel_coefficients(1.0, ALUMINIUM_400NM, np.arccos(c))
    e_s = np.array([-np.sin(phi), np.cos(phi), 0.0])
    theta_hat, phi_hat = transverse_basis(grid.u[i], grid.u[j])
    W = np.exp(-(x[:, None] ** 2 + x[None, :] ** 2) / w**2)
    area = (np.sum(W) ** 2 / np.sum(W**2) * (size / cells) ** 2 / lam**2  # A_eff/λ² of the footprint
            * (omega_i @ mt) * (omega_r @ mt) / (omega_i[2] * omega_r[2]))  # facet area and obliquities
    for pol, e in enumerate((e_s, np.cross(e_s, k_hat))):
        E_r = r_s * (e @ s) * s + r_p * (e @ p_i) * p_r
        E = ff.E[pol, :, i, j]
        ratio = (E @ p_r) / (E @ s)
        cross = abs(E @ (theta_hat if pol == 0 else phi_hat)) ** 2 / np.sum(np.abs(E) ** 2)
        cross_expected = abs(E_r @ (theta_hat if pol == 0 else phi_hat)) ** 2 / np.sum(np.abs(E_r) ** 2)
        peak = brdf[pol, i, j]
        albedo_expected = (omega_i @ mt) / omega_i[2] * (abs(r_s * (e @ s)) ** 2 + abs(r_p * (e @ p_i)) ** 2)
        measured = albedo(brdf, grid)[pol]
        logger.info("pol %d: E·p̂'/E·ŝ' %s vs %s; cross-polarized fraction %.5f vs %.5f; peak f %.6f vs %.6f; "
                    "albedo %.6f vs %.6f", pol, ratio, (E_r @ p_r) / (E_r @ s), cross, cross_expected, peak,
                    np.sum(np.abs(E_r) ** 2) * area, measured, albedo_expected)
        assert ratio == pytest.approx((E_r @ p_r) / (E_r @ s), rel=1e-6)
        assert cross == pytest.approx(cross_expected, abs=1e-6) and cross > 0.02
        assert peak == pytest.approx(np.sum(np.abs(E_r) ** 2) * area, rel=1e-5)
        assert measured == pytest.approx(albedo_expected, rel=3e-3)


def _reflected_beam_lobe(beam, index: complex, grid: HemisphereGrid, k: float) -> np.ndarray:
    """(2, res, res) BRDF of the beam's continuous angular spectrum reflected by a flat interface
    wave by wave (tests/references.py ``reflected_spectrum_brdf``)."""
    U, V = grid.uv
    u, v = U[grid.inside], V[grid.inside]
    E, _ = beam.spectrum(k * u, k * v)
    out = np.full((2,) + grid.mu.shape, np.nan)
    out[:, grid.inside] = reflected_spectrum_brdf(E, u, v, index, k, beam.continuous_power())
    return out


@pytest.mark.parametrize("index, theta_deg, w", [(1.5, 30.0, 0.6), (ALUMINIUM_400NM, 45.0, 0.8), (1.5, 0.0, 0.5)])
def test_beam_incidence_reflects_every_plane_wave_at_its_own_angle(cl_ctx, index, theta_deg, w):
    """Glass at 30° under a beam of waist 0.6 µm (1.2 λ: a spread of ±15°) and aluminium at 45°
    under one of 0.8 µm: lit by the exact beam, the lobe is the beam's spectrum reflected wave by
    wave (≤ 1 % relative L2 over the lobe) and the albedo the beam's Fresnel reflectance (1e-3);
    lit by the footprint plane wave, every direction gets θ_i's Fresnel coefficients and the lobe
    is ≥ 3 % off. (Where the light cone cuts the spectrum — ≥ 0.5 % of it evanescent — the
    lattice of plane waves the beam is made of samples that cut coarsely and parts from the
    continuous spectrum this reference reflects; the full-wave solver is lit by the same lattice.)
    Lit by the footprint, po's waist warning names the beam incidence; lit by the beam it predicts
    no spread error."""
    lam, size = 0.5, 8.0  # the footprint, w/cos θ_i long, is ≤ 1e-5 of its peak at the patch edge
    grid = HemisphereGrid(128)
    scene = SurfaceScene(generate("flat", cells=160, size_um=size), lam, index, theta_deg * DEG, 0.0, w, grid)
    beam = make_beam("exact", lam, theta_deg * DEG, 0.0, w, patch_size_um=size)
    expected = _reflected_beam_lobe(beam, index, grid, 2 * np.pi / lam)
    lit_by_beam = po_farfield(cl_ctx, scene, incidence="beam")
    with pytest.warns(ValidityWarning, match=r'incidence = "beam" in \[model\.po\]'):
        footprint = po_farfield(cl_ctx, scene, incidence="footprint")
    assert 'incidence = "beam" in [model.po]' in footprint.diagnostics["warnings"]
    assert "waist_spread_error" not in lit_by_beam.diagnostics
    waves = beam.plane_waves
    reflectance = beam_fresnel_reflectance(waves["kvec"], waves["E"], 1.0, index)
    for p in range(2):
        err = _lobe_l2(lit_by_beam.brdf()[p], expected[p])
        err_footprint = _lobe_l2(footprint.brdf()[p], expected[p])
        logger.info("index %s, θ_i %g°, pol %d: lobe vs the beam reflected wave by wave %.2e (footprint %.3f); "
                    "albedo %.6f vs %.6f", index, theta_deg, p, err, err_footprint,
                    albedo(lit_by_beam.brdf()[p], grid), reflectance[p])
        assert err < 0.01
        assert err_footprint > 0.03
        assert albedo(lit_by_beam.brdf()[p], grid) == pytest.approx(reflectance[p], rel=1e-3)
    assert lit_by_beam.diagnostics["incidence"] == "beam" and lit_by_beam.diagnostics["plane_waves"] > 100


def test_beam_waves_rebuild_the_full_wave_beam_on_the_nodes():
    """The plane waves po and ws-v sum, with their phase table relative to e^{+jk ω_i·r}, are the
    full-wave solver's beam: Σ_m E_m e^{j(φ_m − q_m·r)} e^{+jk ω_i·r} equals the beam's own field
    (solver/beams.py, its lattice sums) on a rough patch focused off its centre, to the 1e-8 tail
    the table leaves out."""
    surface = generate("gaussian", cells=30, size_um=3.0, rms_height_um=0.1, correlation_um=0.4, seed=3)
    scene = SurfaceScene(surface, 0.5, 1.5, 35 * DEG, 50 * DEG, 0.5, HemisphereGrid(16), footprint_centre_um=(0.3, -0.2))
    waves = BeamWaves.of(scene)
    X, Y = np.meshgrid(surface.x, surface.y, indexing="ij")
    points = np.stack([X, Y, surface.z - surface.z.mean()], axis=-1)
    omega_i = np.array([np.sin(35 * DEG) * np.cos(50 * DEG), np.sin(35 * DEG) * np.sin(50 * DEG), np.cos(35 * DEG)])
    k = 2 * np.pi / 0.5
    phase = np.exp(1j * (waves.phases[:, 3] - points @ waves.phases[:, :3].T)) * np.exp(1j * k * points @ omega_i)[..., None]
    rebuilt = np.einsum("...m,mpc->p...c", phase, waves.amplitudes)
    E, _ = make_beam("exact", 0.5, 35 * DEG, 50 * DEG, 0.5, focus_um=(0.3, -0.2, 0.0), patch_size_um=3.0).fields(points)
    err = np.abs(rebuilt - E).max() / np.abs(E).max()
    logger.info("beam rebuilt from %d plane waves: %.2e", len(waves.directions), err)
    assert err < 1e-6


def test_beam_incident_fields_are_the_full_wave_beam_and_carry_its_power(cl_ctx):
    """With ``incidence = "beam"`` po is steered with the full-wave solver's exact beam, and its
    FarField's Φ_i is that beam's flux through the focal plane (Poynting vector summed on a
    patch 8 waists wide)."""
    surface = generate("flat", cells=80, size_um=8.0)
    scene = SurfaceScene(surface, 0.5, 1.5, 0.5, 0.7, 1.0, HemisphereGrid(16), footprint_centre_um=(0.4, -0.2))
    X, Y = np.meshgrid(surface.x, surface.y, indexing="ij")
    points = np.stack([X, Y, np.zeros_like(X)], axis=-1)
    po = get_model("po", {"incidence": "beam"})
    E, H = po.incident_fields(scene, points)
    E_bem, H_bem = get_model("bem").incident_fields(scene, points)
    assert np.array_equal(E, E_bem) and np.array_equal(H, H_bem)
    S_z = 0.5 * np.real(E[:, 0] * np.conj(H[:, 1]) - E[:, 1] * np.conj(H[:, 0]))
    flux = -np.sum(S_z, axis=(-2, -1)) * surface.spacing_um**2
    assert np.allclose(po.run(cl_ctx, scene).incident_power, flux, rtol=1e-3)
    assert not np.array_equal(get_model("po").incident_fields(scene, points)[0], E)


def test_po_equals_kirchhoff_per_polarization_at_normal_incidence(cl_ctx):
    """Gently rough aluminium (rms slope 0.04), θ_i = 0: PO = Kirchhoff within 2% (relative L2 over
    the lobe, each polarization)."""
    surface = generate("gaussian", cells=160, size_um=10.0, rms_height_um=0.03, correlation_um=1.5, seed=9)
    grid = HemisphereGrid(96)
    po = po_farfield(cl_ctx, SurfaceScene(surface, 0.4, ALUMINIUM_400NM, 0.0, 0.0, 1.8, grid)).brdf()
    ki = kirchhoff_farfield(cl_ctx, surface, 0.4, ALUMINIUM_400NM, 0.0, 0.0, grid, waist_um=1.8).brdf()
    for p in range(2):
        err = _lobe_l2(po[p], ki[p])
        logger.info("PO vs Kirchhoff, pol %d: relative L2 over the lobe %.4f", p, err)
        assert err < 0.02


def test_opencl_equals_numpy_with_ray_traced_shadowing(cl_ctx):
    """A steep patch at 70°: part of the footprint is shadowed; both paths agree to round-off."""
    surface = generate("gaussian", cells=60, size_um=5.0, rms_height_um=0.15, correlation_um=0.6, seed=4)
    grid = HemisphereGrid(48)
    scene = SurfaceScene(surface, 0.5, 0.9 - 5.2j, 70 * DEG, 20 * DEG, 0.9, grid)
    a = po_farfield(cl_ctx, scene)
    b = po_farfield(None, scene)
    err = np.abs(a.E - b.E).max() / np.abs(b.E).max()
    logger.info("OpenCL vs NumPy %.2e; shadowed %.4f, back-facing %.4f", err, a.diagnostics["shadowed_fraction"],
                a.diagnostics["back_facing_fraction"])
    assert err < 1e-10
    assert a.diagnostics["shadowed_fraction"] == b.diagnostics["shadowed_fraction"] > 0.01
    assert a.diagnostics["back_facing_fraction"] == b.diagnostics["back_facing_fraction"]
    unshadowed = po_farfield(cl_ctx, scene, shadowing="none")
    assert unshadowed.diagnostics["shadowed_fraction"] == 0.0
    assert np.abs(unshadowed.E - a.E).max() > 1e-3 * np.abs(a.E).max()


def test_beam_incidence_opencl_equals_numpy(cl_ctx):
    """The beam's plane waves on a steep, partly shadowed glass patch: both paths agree to round-off."""
    surface = generate("gaussian", cells=40, size_um=3.0, rms_height_um=0.12, correlation_um=0.3, seed=7)
    scene = SurfaceScene(surface, 0.5, 1.5, 65 * DEG, 20 * DEG, 0.5, HemisphereGrid(32))
    a = po_farfield(cl_ctx, scene, incidence="beam")
    b = po_farfield(None, scene, incidence="beam")
    err = np.abs(a.E - b.E).max() / np.abs(b.E).max()
    logger.info("beam incidence: OpenCL vs NumPy %.2e over %d plane waves", err, a.diagnostics["plane_waves"])
    assert err < 1e-10
    assert a.diagnostics["shadowed_fraction"] > 0.01
    assert np.array_equal(a.incident_power, b.incident_power)


@pytest.mark.parametrize("incidence", ["footprint", "beam"])
def test_single_precision_close_to_double(cl_ctx, incidence):
    surface = generate("gaussian", cells=80, size_um=6.0, rms_height_um=0.05, correlation_um=1.0, seed=1)
    grid = HemisphereGrid(48)
    model = get_model("po", {"incidence": incidence})
    dbl, sgl = (model.run(cl_ctx, SurfaceScene(surface, 0.5, 1.5, 0.4, 0.3, 1.1, grid, precision=p)).brdf()
                for p in ("double", "single"))
    rel_l2 = np.sqrt(np.nansum((sgl - dbl) ** 2) / np.nansum(dbl**2))
    logger.info("PO single vs double relative L2: %.3g", rel_l2)
    assert 0 < rel_l2 < 1e-4


def test_incident_beam_is_shared_and_normalised():
    """kirchhoff, ohs, ghs and po illuminate with one beam, whose flux through the mean plane is
    the FarField's incident power n₁/(2η₀) μ_i Δ² Σ W²."""
    surface = generate("flat", cells=80, size_um=8.0)
    scene = SurfaceScene(surface, 0.5, 1.5, 0.5, 0.7, 1.3, HemisphereGrid(16), footprint_centre_um=(0.4, -0.2))
    X, Y = np.meshgrid(surface.x, surface.y, indexing="ij")
    points = np.stack([X, Y, np.zeros_like(X)], axis=-1)
    fields = [get_model(name).incident_fields(scene, points) for name in ("kirchhoff", "ohs", "ghs", "po")]
    for E, H in fields[1:]:
        assert np.array_equal(E, fields[0][0]) and np.array_equal(H, fields[0][1])
    E, H = fields[0]
    S_z = 0.5 * np.real(E[:, 0] * np.conj(H[:, 1]) - E[:, 1] * np.conj(H[:, 0]))
    W2 = np.exp(-2 * ((X - 0.4) ** 2 + (Y + 0.2) ** 2) / 1.3**2)
    expected = np.cos(0.5) / (2 * ETA0) * np.sum(W2) * surface.spacing_um**2
    assert np.allclose(-np.sum(S_z, axis=(-2, -1)) * surface.spacing_um**2, expected, rtol=1e-12)  # downward
    for name in ("ohs", "ghs", "po"):
        assert np.allclose(get_model(name).run(None, scene).incident_power, expected, rtol=1e-12)


def test_options():
    assert get_model("po").options.shadowing == "rays"
    with pytest.raises(OptionsError, match=r"\[model.po\] shadowing"):
        get_model("po", {"shadowing": "sometimes"})
    with pytest.raises(OptionsError, match=r"\[model.po\] border"):
        get_model("po", {"border": "mirror"})
    assert get_model("po").options.incidence == "footprint"
    with pytest.raises(OptionsError, match=r"\[model.po\] incidence = \"focused\""):
        get_model("po", {"incidence": "focused"})


def _unpolarized_blurred(result, sigma_px: float = 1.0) -> np.ndarray:
    f = np.nan_to_num(0.5 * (result.brdf()[0] + result.brdf()[1]))
    return np.where(result.grid.inside, gaussian_filter(f, sigma_px), 0.0)


@pytest.mark.slow
def test_po_and_kirchhoff_against_dense_bem(cl_ctx):
    """Moderately rough aluminium patch (2 µm, rms λ/10, rms slope 0.24), λ = 0.4 µm, waist L/5 = λ,
    θ_i = 0° and 60°: relative L2 over the lobe of the unpolarized BRDF (1-pixel blur) of PO and of
    Kirchhoff against dense BEM, logged side by side.

    Measured: 0°: PO 0.069, Kirchhoff 0.086 (blurred albedo BEM 0.909, PO 0.919, Kirchhoff 0.951);
    60°: PO 0.50, Kirchhoff 0.38 (BEM 0.862, PO 0.666, Kirchhoff 0.671). At 60° the comparison
    measures the beams, not the rungs: with w = λ, 41% of the footprint plane wave's angular
    spectrum lies beyond the horizon (GHS's evanescent fraction), which the exact beam of BEM does
    not lose. Bar: at 0°, PO within 10% and not worse than Kirchhoff; at 60° the figures are logged."""
    import warnings

    lam, cells, size = 0.4, 32, 2.0
    surface = generate("gaussian", cells=cells, size_um=size, rms_height_um=0.04, correlation_um=0.35, seed=7)
    grid = HemisphereGrid(64)
    bem, po, kir = get_model("bem", {"method": "dense"}), get_model("po"), get_model("kirchhoff")
    logger.info("patch %s", surface.statistics())
    errors = {}
    for theta_deg in (0.0, 60.0):
        scene = SurfaceScene(surface, lam, ALUMINIUM_400NM, theta_deg * DEG, 0.0, size / 5, grid)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            f_bem, f_po, f_kir = (_unpolarized_blurred(m.run(cl_ctx, scene)) for m in (bem, po, kir))
        err_po, err_kir = _lobe_l2(f_po, f_bem, 1e-2), _lobe_l2(f_kir, f_bem, 1e-2)
        a_bem, a_po, a_kir = (float(np.sum(f) * grid.pixel_area) for f in (f_bem, f_po, f_kir))
        message = (f"θ_i = {theta_deg:g}°: relative L2 over the lobe vs dense BEM: PO {err_po:.4f}, Kirchhoff "
                   f"{err_kir:.4f}; albedo BEM {a_bem:.4f}, PO {a_po:.4f}, Kirchhoff {a_kir:.4f}")
        logger.info(message)
        print(message)
        errors[theta_deg] = (err_po, err_kir)
        assert np.isfinite(err_po) and np.isfinite(err_kir)
    err_po, err_kir = errors[0.0]
    assert err_po < 0.10 and err_po <= err_kir
