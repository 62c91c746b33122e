"""The Harvey–Shack rungs ``ohs`` and ``ghs`` (approx.md §3.3, "Unified discrete form") against
independent references:

* the all-incidence transform (one s grid per surface, λ and footprint) against the exact
  per-incidence chirp-z evaluation of the same formula on the pixel centres (≤ 1e-3 over the lobe);
* sinusoidal gratings: order positions from the grating equation u_m = −u_i + mλ/Λ, OHS
  efficiencies |r(θ_i)|² (μ_m/μ_i) J_m²(2ka) (phase 2kh whatever the angles), GHS efficiencies
  K |r(θ_i)|² (μ_m/μ_i) J_m²(k(μ_i+μ_m)a) with K = 1/Σ_m (μ_m/μ_i) J_m²(k(μ_i+μ_m)a) over the
  propagating orders (Krywonos' renormalization: the total is the specular reflectance);
* GHS on a rough patch: albedo = |r_s(θ_i)|², |r_p(θ_i)|² (tests/references.py), K and the
  evanescent fraction equal to their definitions evaluated here by brute-force sums;
* OpenCL = NumPy twins, single ≈ double, a constant height offset changes nothing, options and
  refusals name the key.
"""

from __future__ import annotations

import dataclasses
import logging
import warnings

import numpy as np
import pytest
import scipy.special

from references import ALUMINIUM_400NM, fresnel_reflectance
from wavebrdf.solver.approx.harvey_shack import SGrid, harvey_shack_farfield
from wavebrdf.solver.farfield import HemisphereGrid, albedo
from wavebrdf.solver.footprint import gaussian_footprint
from wavebrdf.solver.models import SurfaceScene, get_model
from wavebrdf.solver.options import OptionsError
from wavebrdf.solver.surface import HeightField, generate

logger = logging.getLogger(__name__)

DEG = np.pi / 180


def _rough(cells=160, size=10.0, rms=0.12, corr=1.0, seed=5):
    return generate("gaussian", cells=cells, size_um=size, rms_height_um=rms, correlation_um=corr, seed=seed)


def _relative_errors(f: np.ndarray, ref: np.ndarray, floor: float = 1e-3) -> tuple[float, float]:
    """(relative L2 over the lobe f_ref > floor·max, max |f − f_ref| / max f_ref), both polarizations."""
    f, ref = np.nan_to_num(f), np.nan_to_num(ref)
    lobe = ref > floor * ref.max()
    return (float(np.linalg.norm((f - ref)[lobe]) / np.linalg.norm(ref[lobe])),
            float(np.abs(f - ref).max() / ref.max()))


@pytest.mark.parametrize("variant", ["ohs", "ghs"])
def test_all_incidence_equals_per_incidence(cl_ctx, variant):
    """One s grid serves every incidence: its gridding matches the exact chirp-z transform on the
    pixel centres within 1e-3 (relative L2 over the lobe and max error), at several θ_i, φ_i."""
    surface = _rough()
    grid = HemisphereGrid(128)
    sgrid = None
    for theta_deg, phi_deg in ((0.0, 0.0), (35.0, 70.0), (70.0, -120.0)):
        scene = SurfaceScene(surface, 0.4, ALUMINIUM_400NM, theta_deg * DEG, phi_deg * DEG, 1.8, grid)
        sgrid = sgrid or SGrid.build(cl_ctx, scene, variant)
        direct = harvey_shack_farfield(cl_ctx, scene, variant)
        gridded = harvey_shack_farfield(cl_ctx, scene, variant, sgrid)
        rel_l2, rel_max = _relative_errors(gridded.brdf(), direct.brdf())
        logger.info("%s θ=%g°: all-incidence vs per-incidence: relative L2 over the lobe %.2e, max %.2e (%d orders)",
                    variant, theta_deg, rel_l2, rel_max, sgrid.orders)
        assert rel_l2 < 1e-3 and rel_max < 1e-3
        assert gridded.diagnostics["transform"] == "all_incidence"
        assert direct.diagnostics["transform"] == "per_incidence"


@pytest.mark.parametrize("variant", ["ohs", "ghs"])
def test_opencl_equals_numpy(cl_ctx, variant):
    scene = SurfaceScene(_rough(cells=100, size=8.0), 0.5, 0.9 - 5.2j, 40 * DEG, -30 * DEG, 1.4, HemisphereGrid(64))
    for build in (None, SGrid.build):  # per incidence, all incidences
        a = harvey_shack_farfield(cl_ctx, scene, variant, build and build(cl_ctx, scene, variant))
        b = harvey_shack_farfield(None, scene, variant, build and build(None, scene, variant))
        err = np.abs(a.E - b.E).max() / np.abs(b.E).max()
        logger.info("%s %s: OpenCL vs NumPy %.2e", variant, a.diagnostics["transform"], err)
        assert err < 1e-10
        assert np.allclose(a.incident_power, b.incident_power, rtol=1e-14)


def _grating_orders(brdf, grid, u_i, lam, period, m_range):
    """Per order m: (efficiency Σ f ΔuΔv over the band around u_m, peak u of the band) for the
    propagating orders well inside the disk; the band is half the order spacing wide."""
    U, V = grid.uv
    out = {}
    for m in m_range:
        u_m = -u_i + m * lam / period
        if abs(u_m) > 0.95:
            continue
        band = (np.abs(U - u_m) < 0.5 * lam / period) & (np.abs(V) < 0.2)
        eff = [float(np.nansum(np.where(band, b, 0.0)) * grid.pixel_area) for b in brdf]
        inten = np.where(band, np.nan_to_num(brdf[0]) * grid.mu, 0.0)
        peak = grid.u[np.unravel_index(np.argmax(inten), inten.shape)[0]]
        out[m] = (u_m, eff, peak)
    return out


@pytest.fixture(scope="module")
def grating():
    """Sinusoid h = a cos(2πx/Λ), a = 0.08 µm, Λ = 2 µm at λ = 0.5 µm, θ_i = 20°: orders 0.25 apart
    in u, none within 0.05 of the horizon."""
    return dict(surface=generate("sinusoid", cells=600, size_um=30.0, amplitude_um=0.08, period_um=2.0),
                lam=0.5, period=2.0, amp=0.08, theta=20 * DEG, index=1.2 - 6.0j, waist=5.6, grid=HemisphereGrid(256))


def test_ohs_grating_orders_and_efficiencies(cl_ctx, grating):
    """OHS: orders where the grating equation puts them (within a pixel), efficiencies
    |r(θ_i)|² (μ_m/μ_i) J_m²(2ka) within 1e-3 absolute."""
    g = grating
    ff = get_model("ohs").run(cl_ctx, SurfaceScene(g["surface"], g["lam"], g["index"], g["theta"], 0.0, g["waist"],
                                                   g["grid"]))
    k = 2 * np.pi / g["lam"]
    u_i, mu_i = np.sin(g["theta"]), np.cos(g["theta"])
    rs2, rp2 = fresnel_reflectance(1.0, g["index"], g["theta"])
    orders = _grating_orders(ff.brdf(), g["grid"], u_i, g["lam"], g["period"], range(-4, 8))
    assert len(orders) >= 6
    for m, (u_m, eff, peak) in orders.items():
        omega = np.sqrt(1 - u_m**2) / mu_i
        jm2 = scipy.special.jv(m, 2 * k * g["amp"]) ** 2
        expected = (rs2 * omega * jm2, rp2 * omega * jm2)
        logger.info("OHS order %d at u = %.4f (peak %.4f): efficiency s,p %s vs %s", m, u_m, peak, eff, expected)
        assert abs(peak - u_m) <= 2.0 / g["grid"].resolution
        assert np.allclose(eff, expected, atol=1e-3, rtol=0)


def test_ghs_grating_renormalization(cl_ctx, grating):
    """GHS: efficiencies K |r(θ_i)|² (μ_m/μ_i) J_m²(k(μ_i+μ_m)a) with K from the analytic orders,
    the reported K equal to it, and the orders summing to the specular reflectance."""
    g = grating
    ff = get_model("ghs", {"transform": "per_incidence"}).run(cl_ctx, SurfaceScene(g["surface"], g["lam"], g["index"], g["theta"], 0.0, g["waist"],
                                                   g["grid"]))
    k = 2 * np.pi / g["lam"]
    u_i, mu_i = np.sin(g["theta"]), np.cos(g["theta"])
    propagating = [m for m in range(-10, 11) if abs(-u_i + m * g["lam"] / g["period"]) < 1]
    mu = {m: np.sqrt(1 - (-u_i + m * g["lam"] / g["period"]) ** 2) for m in propagating}
    unnormalized = {m: mu[m] / mu_i * scipy.special.jv(m, k * (mu_i + mu[m]) * g["amp"]) ** 2 for m in propagating}
    K = 1.0 / sum(unnormalized.values())
    reported = ff.diagnostics["ghs_renormalization"]
    logger.info("GHS grating: K = %.6f analytic, %.6f reported; evanescent fraction %.4g", K, reported,
                ff.diagnostics["evanescent_fraction"])
    assert reported == pytest.approx(K, rel=1e-3)
    rs2, rp2 = fresnel_reflectance(1.0, g["index"], g["theta"])
    orders = _grating_orders(ff.brdf(), g["grid"], u_i, g["lam"], g["period"], propagating)
    for m, (u_m, eff, peak) in orders.items():
        expected = (K * rs2 * unnormalized[m], K * rp2 * unnormalized[m])
        logger.info("GHS order %d at u = %.4f: efficiency s,p %s vs %s", m, u_m, eff, expected)
        assert abs(peak - u_m) <= 2.0 / g["grid"].resolution
        assert np.allclose(eff, expected, atol=1e-3, rtol=0)
    assert np.allclose(albedo(ff.brdf(), g["grid"]), (rs2, rp2), rtol=1e-9)


def test_ghs_renormalization_on_a_rough_patch(cl_ctx):
    """Rough aluminium patch: GHS albedo = |r_s(θ_i)|², |r_p(θ_i)|²; the reported K and evanescent
    fraction equal 1/Σ Ω|I|²/(λ²ΔΣW²)Δu² and 1 − Σ|I|²Δu²/(λ²Δ²ΣW²) evaluated by brute-force
    sums of I(ω_o) = Δ² Σ W e^{jk[(u_i+u_o)·x + (μ_i+μ_o) z]} over every pixel; a rougher patch
    sends more of its angular spectrum beyond the horizon."""
    lam, waist = 0.4, 0.95
    grid = HemisphereGrid(32)
    U, V = grid.uv
    inside = grid.inside
    k = 2 * np.pi / lam
    evanescent = []
    for rms in (0.05, 0.15):
        surface = _rough(cells=50, size=5.0, rms=rms, corr=0.8, seed=3)
        X, Y = np.meshgrid(surface.x, surface.y, indexing="ij")
        W = gaussian_footprint(surface, waist)
        d2 = surface.spacing_um**2
        z = surface.z - surface.z.mean()
        norm = lam**2 * d2 * np.sum(W**2)
        for theta_deg in (0.0, 70.0):
            theta, phi = theta_deg * DEG, 0.3
            ff = harvey_shack_farfield(cl_ctx, SurfaceScene(surface, lam, ALUMINIUM_400NM, theta, phi, waist, grid),
                                       "ghs")
            u_i = np.sin(theta) * np.array([np.cos(phi), np.sin(phi)])
            mu_i = np.cos(theta)
            I2 = np.zeros(U.shape)
            u, v = U[inside], V[inside]
            phase = (np.outer(u_i[0] + u, X) + np.outer(u_i[1] + v, Y)
                     + np.outer(mu_i + np.sqrt(1 - u**2 - v**2), z))  # (pixels, nodes)
            I2[inside] = np.abs(d2 * np.exp(1j * k * phase) @ W.ravel()) ** 2
            omega = np.where(inside, grid.mu / mu_i, 0.0)
            K = 1.0 / (np.sum(omega * I2) / norm * grid.pixel_area)
            fraction = 1.0 - np.sum(I2) / norm * grid.pixel_area
            measured = albedo(ff.brdf(), grid)
            expected = np.array(fresnel_reflectance(1.0, ALUMINIUM_400NM, theta))
            d = ff.diagnostics
            logger.info("rms %.2f µm θ=%g°: albedo %s vs Fresnel %s; K %.6f vs %.6f; evanescent %.5f vs %.5f", rms,
                        theta_deg, measured, expected, d["ghs_renormalization"], K, d["evanescent_fraction"], fraction)
            assert np.allclose(measured, expected, rtol=1e-9)
            assert d["ghs_renormalization"] == pytest.approx(K, rel=1e-8)
            assert d["evanescent_fraction"] == pytest.approx(fraction, rel=1e-8, abs=1e-12)
            assert 0.0 < d["evanescent_fraction"] < 1.0
            evanescent.append(d["evanescent_fraction"])
    assert np.all(np.array(evanescent[2:]) > np.array(evanescent[:2]))  # rougher: more beyond the horizon


@pytest.mark.parametrize("name", ["ohs", "ghs"])
def test_model_keeps_the_s_grid_between_incidences(cl_ctx, name):
    """The instance transforms once per (surface, λ, footprint); a height offset changes nothing."""
    surface = _rough(cells=80, size=6.0)
    grid = HemisphereGrid(48)
    model = get_model(name, {"transform": "all_incidence"})
    first = model.run(cl_ctx, SurfaceScene(surface, 0.5, 1.5, 0.2, 0.0, 1.1, grid))
    again = model.run(cl_ctx, SurfaceScene(HeightField(surface.z.copy(), surface.size_um), 0.5, 1.5, 0.6, 1.0, 1.1,
                                           grid))
    assert not first.diagnostics["sgrid_reused"] and again.diagnostics["sgrid_reused"]
    shifted = model.run(cl_ctx, SurfaceScene(HeightField(surface.z + 3.7, surface.size_um), 0.5, 1.5, 0.2, 0.0, 1.1,
                                             grid))
    assert np.allclose(shifted.brdf(), first.brdf(), rtol=1e-9, atol=1e-12 * np.nanmax(first.brdf()), equal_nan=True)
    model.release()
    assert not model.run(cl_ctx, SurfaceScene(surface, 0.5, 1.5, 0.2, 0.0, 1.1, grid)).diagnostics["sgrid_reused"]


def test_single_precision_close_to_double(cl_ctx):
    surface = _rough(cells=100, size=8.0)
    grid = HemisphereGrid(64)
    for transform in ("per_incidence", "all_incidence"):
        model = get_model("ghs", {"transform": transform})
        scenes = [SurfaceScene(surface, 0.5, 1.5, 0.3, 0.2, 1.4, grid, precision=p) for p in ("double", "single")]
        dbl, sgl = (model.run(cl_ctx, s).brdf() for s in scenes)
        rel_l2 = np.sqrt(np.nansum((sgl - dbl) ** 2) / np.nansum(dbl**2))
        logger.info("GHS %s single vs double relative L2: %.3g", transform, rel_l2)
        assert 0 < rel_l2 < 1e-4


def test_options_and_refusals():
    with pytest.raises(OptionsError, match=r"\[model.ohs\] transform"):
        get_model("ohs", {"transform": "sometimes"})
    with pytest.raises(OptionsError, match=r"\[model.ghs\] spread"):
        get_model("ghs", {"spread": 1})
    scene = SurfaceScene(_rough(cells=40, size=4.0), 0.5, 1.5, 0.2, 0.0, 0.7, HemisphereGrid(32))
    with pytest.raises(ValueError, match=r"\[model.ghs\] transform = \"all_incidence\""):
        get_model("ghs", {"transform": "all_incidence", "max_grid_mb": 0.01}).check(scene)
    auto = get_model("ghs", {"max_grid_mb": 0.01})  # auto falls back to per incidence
    assert auto.check(scene) is None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(ValueError, match="kappa"):
            harvey_shack_farfield(None, dataclasses.replace(scene, index=1.5 + 0.1j), "ohs")
    with pytest.raises(ValueError, match="variant"):
        harvey_shack_farfield(None, scene, "rghs")
