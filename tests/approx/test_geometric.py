"""The geometric-optics rungs ``gs``/``gm`` (solver/approx/geometric.py): the closed-form
microfacet BRDF (Beckmann slopes, Smith shadowing) of Gaussian surfaces, the Kirchhoff rung in the
large-roughness limit, wavelength reuse of the traced geometry through the model, options and
checks, and the config/plan/CLI layer (intensity-only: steering refused; a study end to end).
"""

from __future__ import annotations

import logging

import h5py
import numpy as np
import pytest
import scipy.special
from scipy.ndimage import gaussian_filter

from references import fresnel_reflectance
from test_models import STEERING, refused, write_study
from wavebrdf.jobs.cli import main
from wavebrdf.solver.approx.raytrace import trace_paths
from wavebrdf.solver.farfield import HemisphereGrid, albedo
from wavebrdf.solver.models import SurfaceScene, get_model
from wavebrdf.solver.options import OptionsError
from wavebrdf.solver.surface import generate

logger = logging.getLogger(__name__)

DEG = np.pi / 180
GLASS = 1.5
ALUMINIUM = 0.46582 - 4.7119j


# ---------------------------------------------------------------------------------------------
# GS = F D G2 / (4 μ_i μ_o) for Gaussian surfaces (Beckmann slopes, height-correlated Smith)


def smith_lambda(mu, alpha):
    """Smith Λ of the Beckmann (Gaussian-slope) distribution with rms slope α (Walter et al. 2007)."""
    mu = np.clip(mu, 1e-9, 1.0)
    a = mu / (alpha * np.sqrt(1 - mu * mu) + 1e-300)
    return 0.5 * (scipy.special.erf(a) - 1) + np.exp(-a * a) / (2 * a * np.sqrt(np.pi))


def microfacet_brdf(omega_i, U, V, alpha, index):
    """Unpolarized F(ω_i·h) D(h) G2(ω_i, ω_o) / (4 μ_i μ_o) at projected directions (U, V):
    Beckmann D = exp(−tan²θ_h/α²)/(π α² cos⁴θ_h), G2 = 1/(1 + Λ(ω_i) + Λ(ω_o)); 0 outside the disk."""
    inside = U * U + V * V < 1
    mu = np.sqrt(np.clip(1 - U * U - V * V, 1e-12, 1))
    h = omega_i + np.stack([U, V, mu], axis=-1)
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    c = h[..., 2]
    D = np.exp(-(1 - c * c) / (c * c) / alpha**2) / (np.pi * alpha**2 * c**4)
    F = np.mean(fresnel_reflectance(1.0, index, np.arccos(np.clip(h @ omega_i, 0, 1))), axis=0)
    G = 1 / (1 + smith_lambda(omega_i[2], alpha) + smith_lambda(mu, alpha))
    return np.where(inside, F * D * G / (4 * omega_i[2] * mu), 0.0)


def beckmann_comparison(ctx, theta_deg, realizations, rays, res=32):
    """GS (mean over realizations of a 128 µm periodic Gaussian surface, σ = 0.5 µm, T = 2 µm,
    plane-wave illumination) against the closed form averaged over each pixel (the estimator's
    bin), over the lobe (pixels whose square lies inside θ_o < 70°, intensity ≥ 10% of the peak).
    Returns (relative L2 of f μ_o, albedo GS, albedo closed form, shadowed fraction, Smith's)."""
    grid = HemisphereGrid(res)
    surfaces = [generate("gaussian", cells=512, size_um=128.0, rms_height_um=0.5, correlation_um=2.0, seed=s)
                for s in range(1, realizations + 1)]
    alpha = float(np.sqrt(np.mean([s.statistics()["rms_slope"] ** 2 for s in surfaces])))  # the realizations'
    theta, phi = theta_deg * DEG, 0.4
    omega = np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    model = get_model("gs", {"rays": rays})
    runs = [model.run(ctx, SurfaceScene(s, 0.5, complex(GLASS), theta, phi, None, grid)) for s in surfaces]
    f = np.mean([r.brdf().mean(axis=0) for r in runs], axis=0)
    shadowed = float(np.mean([r.diagnostics["shadowed_fraction"] for r in runs]))
    k = 8
    offsets = ((np.arange(k) + 0.5) / k - 0.5) * grid.pixel_area**0.5
    U, V = grid.uv
    ref = np.mean([microfacet_brdf(omega, U + a, V + b, alpha, GLASS) for a in offsets for b in offsets], axis=0)
    rim = np.sin(70 * DEG)
    whole = (np.abs(U) + 1 / res) ** 2 + (np.abs(V) + 1 / res) ** 2 < rim**2
    I_ref, I_gs = np.where(whole, ref * grid.mu, 0), np.where(whole, np.nan_to_num(f) * grid.mu, 0)
    lobe = whole & (I_ref > 0.1 * I_ref.max())
    l2 = float(np.sqrt(np.sum((I_gs - I_ref)[lobe] ** 2) / np.sum(I_ref[lobe] ** 2)))
    # Smith's lit fraction: front-facing slopes (Gaussian along the azimuth) / (1 + Λ)
    front = 0.5 * (1 + scipy.special.erf(1 / np.tan(theta) / alpha))
    smith = 1 - front / (1 + smith_lambda(np.cos(theta), alpha))
    return l2, float(np.nansum(f) * grid.pixel_area), float(ref.sum() * grid.pixel_area), shadowed, smith


def _check_beckmann(cl_ctx, theta_deg, realizations, rays, l2_bar):
    l2, a_gs, a_ref, shadowed, smith = beckmann_comparison(cl_ctx, theta_deg, realizations, rays)
    logger.info("GS vs Beckmann–Smith θ_i = %g° (%d realizations, %d rays): lobe L2 %.4f, albedo %.5f vs %.5f, "
                "shadowed %.4f vs Smith %.4f", theta_deg, realizations, rays, l2, a_gs, a_ref, shadowed, smith)
    assert l2 < l2_bar
    assert abs(a_gs / a_ref - 1) < 0.02
    assert abs(shadowed - smith) < 0.05


def test_gs_matches_microfacet_beckmann_smith(cl_ctx):
    """θ_i = 60° (shadowing 8%), one realization: lobe L2 < 10% (the realization's own slope
    histogram differs from Beckmann by ~5% per pixel), albedo within 2%."""
    _check_beckmann(cl_ctx, 60.0, 1, 1 << 19, 0.10)


@pytest.mark.slow
@pytest.mark.parametrize("theta_deg", [30.0, 75.0])
def test_gs_matches_microfacet_beckmann_smith_ensemble(cl_ctx, theta_deg):
    """Four realizations: lobe L2 < 7%, albedo within 2%; at 75° a third of the surface is in shadow."""
    _check_beckmann(cl_ctx, theta_deg, 4, 1 << 20, 0.07)


# ---------------------------------------------------------------------------------------------
# The acceptance bar: GS/GM vs Kirchhoff in the large-roughness limit


@pytest.mark.slow
def test_gs_gm_match_kirchhoff_at_large_roughness(cl_ctx):
    """kσ = 6.3, rms slope 0.26 (σ = 0.5 µm, T = 4 µm, λ = 0.5 µm), one 96 µm periodic realization
    illuminated uniformly (waist ≫ patch; Kirchhoff then has grating orders λ/L apart and its
    intensities fluctuate from order to order like speckle), glass, θ_i = 20° and 50°: the
    unpolarized f μ_o of both, blurred by the same Gaussian (σ = 4 pixels of a 128² grid, 0.0625 in
    u, ~150 orders), agree within 10% relative L2 over the lobe (Kirchhoff ≥ 10% of its peak), and
    the unpolarized albedos within 3%. (Per polarization they differ by design: Kirchhoff keeps the
    global s/p frame, GO rotates into each facet's.)"""
    import warnings

    surface = generate("gaussian", cells=640, size_um=96.0, rms_height_um=0.5, correlation_um=4.0, seed=5)
    grid = HemisphereGrid(128)
    mu = np.where(grid.inside, grid.mu, 0.0)

    def blurred(result):
        return gaussian_filter(np.nan_to_num(np.mean(result.brdf(), axis=0)) * mu, 4.0, mode="constant")

    for theta_deg in (20.0, 50.0):
        scene = SurfaceScene(surface, 0.5, complex(GLASS), theta_deg * DEG, 0.3, 1e4, grid)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the uniform footprint reaches the patch edge (periodic tile)
            kirchhoff = get_model("kirchhoff").run(cl_ctx, scene)
        ref = blurred(kirchhoff)
        lobe = grid.inside & (ref > 0.1 * ref.max())
        a_k = albedo(kirchhoff.brdf(), grid).mean()
        for name in ("gs", "gm"):
            result = get_model(name, {"rays": 1 << 21}).run(cl_ctx, scene)
            got = blurred(result)
            l2 = np.sqrt(np.sum((got - ref)[lobe] ** 2) / np.sum(ref[lobe] ** 2))
            a = albedo(result.brdf(), grid).mean()
            logger.info("%s vs kirchhoff θ_i = %g°: lobe L2 %.4f, unpolarized albedo %.5f vs %.5f", name, theta_deg,
                        l2, a, a_k)
            assert l2 < 0.10
            assert abs(a / a_k - 1) < 0.03


# ---------------------------------------------------------------------------------------------
# Model behaviour


def test_wavelengths_reuse_the_traced_geometry(cl_ctx):
    """Another wavelength/index with the same surface, incidence, footprint and grid reweights
    the kept geometry (no trace: the instance's trace count stays) and equals a fresh run; another
    incidence traces; the first is still kept."""
    surface = generate("gaussian", cells=64, size_um=4.0, rms_height_um=0.3, correlation_um=0.6, seed=2)
    grid = HemisphereGrid(48)
    opts = {"rays": 1 << 15, "max_depth": 16}

    def sc(wl, index, theta=30.0):
        return SurfaceScene(surface, wl, complex(index), theta * DEG, 0.2, 1.5, grid)

    model = get_model("gm", opts)
    first = model.run(cl_ctx, sc(0.5, GLASS))
    assert model.traces == 1 and not first.diagnostics["geometry_reused"]
    second = model.run(cl_ctx, sc(0.6, ALUMINIUM))
    assert model.traces == 1 and second.diagnostics["geometry_reused"]
    fresh = get_model("gm", opts).run(cl_ctx, sc(0.6, ALUMINIUM))
    assert np.array_equal(second.intensity(), fresh.intensity())
    assert second.diagnostics["truncated_energy_fraction"] == fresh.diagnostics["truncated_energy_fraction"]
    model.run(cl_ctx, sc(0.5, GLASS, theta=40.0))
    assert model.traces == 2
    model.run(cl_ctx, sc(0.7, GLASS))
    assert model.traces == 2
    model.release()
    model.run(cl_ctx, sc(0.7, GLASS))
    assert model.traces == 3


def test_gs_is_the_single_part_of_gm(cl_ctx):
    """Same rays: GS's image is GM's depth-1 image bit for bit; on a perfect conductor GS's masked
    energy is what GM sends on (escaping after ≥ 2 reflections or truncated)."""
    surface = generate("gaussian", cells=64, size_um=4.0, rms_height_um=0.4, correlation_um=0.5, seed=3)
    for index in (ALUMINIUM, 1e-3 - 1e7j):
        scene = SurfaceScene(surface, 0.5, complex(index), 40 * DEG, 0.0, 1.5, HemisphereGrid(32))
        gs = get_model("gs", {"rays": 1 << 14}).run(cl_ctx, scene)
        gm = trace_paths(cl_ctx, scene, rays=1 << 14, max_depth=10)
        assert np.array_equal(gs.intensity(), gm.single)
        if abs(index) > 1e6:
            masked = np.array(gs.diagnostics["masked_energy_fraction"])
            onward = gm.escaped_by_depth[:, 2:].sum(axis=1) + gm.truncated
            assert masked.min() > 0.05 and np.allclose(masked, onward, atol=1e-5)


def test_options_and_checks():
    with pytest.raises(OptionsError, match=r'\[model.gs\] border = "wrap": must be one of'):
        get_model("gs", {"border": "wrap"})
    with pytest.raises(OptionsError, match=r"\[model.gm\] max_depth = 0: must be >= 1"):
        get_model("gm", {"max_depth": 0})
    with pytest.raises(OptionsError, match=r"\[model.gs\] max_depth: unknown key"):
        get_model("gs", {"max_depth": 3})
    with pytest.raises(OptionsError, match=r"\[model.gm\] rays = 0"):
        get_model("gm", {"rays": 0})
    surface = generate("flat", cells=8, size_um=1.0)
    model = get_model("gs")

    def sc(**kw):
        args = dict(surface=surface, wavelength_um=0.5, index=1.5 + 0j, theta_i=0.3, phi_i=0.0, waist_um=0.3,
                    grid=HemisphereGrid(16))
        args.update(kw)
        return SurfaceScene(**args)

    assert model.check(sc()) is None
    with pytest.raises(OptionsError, match=r"θ_i = 90°: must be in \[0°, 90°\)"):
        model.check(sc(theta_i=np.pi / 2))
    with pytest.raises(OptionsError, match="κ >= 0"):
        model.check(sc(index=1.5 + 0.1j))
    with pytest.raises(OptionsError, match="waist_um = 0"):
        model.check(sc(waist_um=0.0))
    est = get_model("gm").estimate(sc())
    assert est.memory_bytes > 0 and est.seconds > 0


def _study(folder, name, model, extra=""):
    """The conformance suite's small surface study (tests/test_models.py) with this model, 20000 rays."""
    return write_study(folder, name, model, model_extra="rays = 20000", extra=extra, resolution=32)


@pytest.mark.parametrize("model", ["gs", "gm"])
def test_steering_refused_at_plan(tmp_path, capsys, model):
    """Intensity-only: a [steering] study is refused by `wavebrdf plan`, naming the model."""
    cfg = _study(tmp_path, "steer", model, extra=STEERING)
    refused(capsys, ["plan", str(cfg)], "[steering]", repr(model), "cannot be steered")
    assert not (tmp_path / "steer.h5").exists()


def test_study_end_to_end(tmp_path, capsys):
    """A gm study through `wavebrdf run` (serial): every task done, albedo = the stored BRDF's,
    GO independent of λ at a fixed index (the second wavelength reuses the geometry)."""
    cfg = _study(tmp_path, "go", "gm")
    assert main(["run", str(cfg), "-q", "--no-render", "--executor", "serial"]) == 0, capsys.readouterr().err
    with h5py.File(tmp_path / "go.h5", "r") as h5:
        brdf, stored = h5["brdf"][()], h5["albedo"][()]
        status = set(h5["tasks/status"][()].astype(str))
        reused = [str(v) for v in h5["tasks/geometry_reused"][()].astype(str)]
    assert status == {"done"} and brdf.shape == (2, 2, 32, 32)
    assert np.array_equal(brdf[0], brdf[1], equal_nan=True)
    assert np.allclose(stored, np.nansum(brdf, axis=(-2, -1)) * (2 / 32) ** 2, rtol=1e-5)
    assert np.all((stored > 0.02) & (stored < 0.1))  # rough glass: near Fresnel (4–6%)
    assert reused == ["false", "false", "true", "true"]
