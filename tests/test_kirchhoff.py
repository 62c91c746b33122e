"""Kirchhoff model against analytic references (VALIDATION.md items 1–3, approx.md §3.3)."""

from __future__ import annotations

import logging

import numpy as np
import pytest
import scipy.special

from wavebrdf.solver.approx.kirchhoff import (
    KirchhoffSetup,
    chebyshev_order,
    kirchhoff_farfield,
    kirchhoff_farfield_numpy,
)
from wavebrdf.solver.footprint import FootprintWarning, gaussian_footprint
from wavebrdf.solver.farfield import HemisphereGrid, albedo
from wavebrdf.solver.fresnel import fresnel_reflectance, fresnel_rs_rp
from references import ALUMINIUM_400NM
from references import fresnel_reflectance as reference_fresnel
from wavebrdf.solver.precision import Precision
from wavebrdf.solver.surface import HeightField, generate

logger = logging.getLogger(__name__)



def reference_reflectance(index, cos_theta):
    """(|r_s|², |r_p|²) from the textbook formulas of tests/references.py (air above ``index``)."""
    return reference_fresnel(1.0, index, np.arccos(np.clip(cos_theta, -1.0, 1.0)))


@pytest.fixture(scope="module")
def wide_flat():
    """Flat patch for Fresnel checks: waist 30 µm (angular spread ≈ λ/(πw) = 0.004), patch 5.4 w."""
    return generate("flat", cells=1620, size_um=162.0)


@pytest.mark.parametrize("index", [1.5, ALUMINIUM_400NM], ids=["n1.5", "aluminium"])
@pytest.mark.parametrize("theta_deg", [0.0, 30.0, 60.0])
def test_flat_albedo_equals_fresnel(cl_ctx, wide_flat, index, theta_deg):
    grid = HemisphereGrid(1024)
    theta, phi = np.deg2rad(theta_deg), np.deg2rad(25.0)
    ff = kirchhoff_farfield(cl_ctx, wide_flat, 0.4, index, theta, phi, grid, waist_um=30.0)
    brdf = ff.brdf()
    measured = albedo(brdf, grid)
    expected = np.array(reference_reflectance(index, np.cos(theta)))
    rel = np.abs(measured / expected - 1)
    logger.info("θ=%g %s: albedo %s vs Fresnel %s (rel %s)", theta_deg, index, measured, expected, rel)
    assert np.all(rel < 5e-3)
    # the lobe peaks at the mirror direction u_o = -u_i (within one pixel)
    peak = np.unravel_index(np.nanargmax(brdf[0]), brdf[0].shape)
    mirror = -np.sin(theta) * np.array([np.cos(phi), np.sin(phi)])
    assert np.all(np.abs(grid.u[list(peak)] - mirror) <= 2.0 / grid.resolution)


def test_sinusoidal_grating_orders(cl_ctx):
    """Per-order efficiency = |r|² Ω_K J_m²(k(μ_i+μ_m)a) (approx.md §3.3) within 1e-3."""
    lam, period, amp = 0.5, 2.0, 0.08
    index = 1.2 - 6.0j
    surface = generate("sinusoid", cells=1060, size_um=53.0, amplitude_um=amp, period_um=period)
    grid = HemisphereGrid(512)
    theta = np.deg2rad(20.0)
    ff = kirchhoff_farfield(cl_ctx, surface, lam, index, theta, 0.0, grid, waist_um=10.0)
    brdf = ff.brdf()
    U, V = grid.uv
    k = 2 * np.pi / lam
    u_i, mu_i = np.sin(theta), np.cos(theta)
    checked = 0
    for m in range(-3, 7):
        u_m = -u_i + m * lam / period
        if abs(u_m) > 0.95:
            continue
        mu_m = np.sqrt(1 - u_m**2)
        cos_io = u_i * u_m + mu_i * mu_m
        omega_k = (1 + cos_io) ** 2 / (mu_i * mu_m * (mu_i + mu_m) ** 2)
        rs2, rp2 = reference_reflectance(index, np.sqrt(0.5 * (1 + cos_io)))
        jm2 = scipy.special.jv(m, k * (mu_i + mu_m) * amp) ** 2
        near = (np.abs(U - u_m) < 0.5 * lam / period) & (np.abs(V) < 0.2)
        for p, r2 in enumerate((rs2, rp2)):
            eta = np.nansum(np.where(near, brdf[p], 0.0)) * grid.pixel_area
            expected = r2 * omega_k * jm2
            logger.info("order %d pol %d: %.6f vs %.6f", m, p, eta, expected)
            assert abs(eta - expected) < 1e-3
            checked += 1
    assert checked >= 10


def _rough(cells=160, size=10.0, rms=0.12, corr=1.0, seed=5):
    return generate("gaussian", cells=cells, size_um=size, rms_height_um=rms, correlation_um=corr, seed=seed)


def test_opencl_equals_numpy_reference(cl_ctx):
    surface = _rough()
    grid = HemisphereGrid(128)
    args = (surface, 0.5, 0.9 - 5.2j, np.deg2rad(35.0), np.deg2rad(-40.0), grid)
    a = kirchhoff_farfield(cl_ctx, *args, waist_um=1.8)
    b = kirchhoff_farfield_numpy(*args, waist_um=1.8)
    err = np.abs(a.E - b.E).max() / np.abs(b.E).max()
    logger.info("OpenCL vs NumPy: %.3g", err)
    assert err < 1e-9
    assert np.allclose(a.incident_power, b.incident_power, rtol=1e-14)


def test_against_direct_sum(cl_ctx, rng):
    """Chebyshev expansion + chirp-z transforms vs the brute-force Kirchhoff sum at random pixels."""
    surface = _rough(cells=120, size=8.0, rms=0.25, corr=0.8)  # k·max|h| ≈ 10: many Chebyshev terms
    grid = HemisphereGrid(96)
    lam, index = 0.45, 1.5 - 0.0j
    theta, phi = np.deg2rad(40.0), np.deg2rad(110.0)
    ff = kirchhoff_farfield(cl_ctx, surface, lam, index, theta, phi, grid, waist_um=1.5)
    brdf = ff.brdf()
    k = 2 * np.pi / lam
    X, Y = np.meshgrid(surface.x, surface.y, indexing="ij")
    W = gaussian_footprint(surface, 1.5)
    d2 = surface.spacing_um**2
    z = surface.z - surface.z.mean()
    u_i = np.sin(theta) * np.array([np.cos(phi), np.sin(phi)])
    mu_i = np.cos(theta)
    inside = np.argwhere(grid.inside)
    for i, j in inside[rng.choice(len(inside), 40, replace=False)]:
        uo, vo = grid.u[i], grid.u[j]
        mu_o = np.sqrt(1 - uo**2 - vo**2)
        integral = d2 * np.sum(W * np.exp(1j * k * ((u_i[0] + uo) * X + (u_i[1] + vo) * Y + (mu_i + mu_o) * z)))
        cos_io = u_i[0] * uo + u_i[1] * vo + mu_i * mu_o
        omega_k = (1 + cos_io) ** 2 / (mu_i * mu_o * (mu_i + mu_o) ** 2)
        reflect = reference_reflectance(index, np.sqrt(0.5 * (1 + cos_io)))
        for p in range(2):
            expected = reflect[p] * omega_k * abs(integral) ** 2 / (lam**2 * d2 * np.sum(W**2))
            assert brdf[p, i, j] == pytest.approx(expected, rel=1e-9, abs=1e-12 * np.nanmax(brdf))


def test_reciprocity(cl_ctx):
    """Kirchhoff with Ω_K and Fresnel at the half vector is reciprocal: f(i→o) = f(o→i)."""
    surface = _rough(seed=9)
    grid = HemisphereGrid(64)
    pairs = [((10, 40), (50, 22)), ((5, 30), (33, 58)), ((45, 12), (20, 20))]
    for a, b in pairs:
        values = []
        for src, dst in ((a, b), (b, a)):
            u, v = grid.u[src[0]], grid.u[src[1]]
            theta, phi = np.arcsin(np.hypot(u, v)), np.arctan2(v, u)
            ff = kirchhoff_farfield(cl_ctx, surface, 0.5, 1.1 - 6.1j, theta, phi, grid, waist_um=1.8)
            values.append(ff.brdf()[:, dst[0], dst[1]])
        assert np.allclose(values[0], values[1], rtol=1e-9)


def test_height_offset_changes_nothing(cl_ctx):
    surface = _rough(cells=100, size=8.0)
    shifted = HeightField(surface.z + 3.7, surface.size_um)
    grid = HemisphereGrid(64)
    a = kirchhoff_farfield(cl_ctx, surface, 0.5, 1.5, 0.3, 0.2, grid, waist_um=1.4).brdf()
    b = kirchhoff_farfield(cl_ctx, shifted, 0.5, 1.5, 0.3, 0.2, grid, waist_um=1.4).brdf()
    assert np.allclose(a, b, rtol=1e-9, equal_nan=True)


def test_single_precision_close_to_double(cl_ctx):
    surface = _rough(cells=100, size=8.0)
    grid = HemisphereGrid(64)
    args = (cl_ctx, surface, 0.5, 1.5, 0.3, 0.2, grid)
    dbl = kirchhoff_farfield(*args, waist_um=1.4).brdf()
    sgl = kirchhoff_farfield(*args, waist_um=1.4, precision=Precision.SINGLE).brdf()
    rel_l2 = np.sqrt(np.nansum((sgl - dbl) ** 2) / np.nansum(dbl**2))
    logger.info("single vs double relative L2: %.3g", rel_l2)
    assert 0 < rel_l2 < 1e-4


def test_chebyshev_truncation_is_exact_to_1e_11():
    """The truncated Jacobi–Anger series reproduces e^{jkμ_o z} over μ_o ∈ [0, 1]."""
    for x_max in (0.0, 0.3, 2.0, 9.0, 30.0):
        n_max = chebyshev_order(x_max)
        n = np.arange(n_max + 1)
        t = np.linspace(-1, 1, 201)
        for x in (x_max, -0.6 * x_max):
            series = np.sum(
                (np.where(n == 0, 1, 2) * (1j**n) * scipy.special.jv(n, x))[:, None]
                * np.cos(n[:, None] * np.arccos(t)[None]),
                axis=0,
            )
            assert np.max(np.abs(series - np.exp(1j * x * t))) < 1e-11


def test_footprint_warning_when_beam_exceeds_patch(cl_ctx):
    surface = _rough(cells=60, size=4.0)
    with pytest.warns(FootprintWarning):
        kirchhoff_farfield(cl_ctx, surface, 0.5, 1.5, 0.2, 0.0, HemisphereGrid(32), waist_um=1.5)


def test_fresnel_no_gain_and_pec_limit():
    """κ ≥ 0 never reflects more than it receives; κ → ∞ tends to r_s = −1, r_p = +1."""
    c = np.linspace(0.0, 1.0, 101)
    for eta in (1.5, 0.5 - 3j, 0.05 - 10j, 2.0 - 1e-4j, 1.3 - 0.5j):
        rs2, rp2 = fresnel_reflectance(eta, c)
        assert np.all(rs2 <= 1 + 1e-12) and np.all(rp2 <= 1 + 1e-12)
    rs, rp = fresnel_rs_rp(1e-3 - 1e6j, 0.7)
    assert rs == pytest.approx(-1, abs=1e-5) and rp == pytest.approx(1, abs=1e-5)
    # the model's Fresnel module equals the textbook reference (tests/references.py)
    for eta in (1.5, 0.5 - 3j, 0.05 - 10j, 2.0 - 1e-4j, 1.3 - 0.5j, ALUMINIUM_400NM):
        ours = np.array(fresnel_reflectance(eta, c))
        assert np.allclose(ours, np.array(reference_reflectance(eta, c)), rtol=1e-12, atol=1e-14), eta


def test_setup_rejects_bad_inputs():
    surface = _rough(cells=20, size=2.0)
    grid = HemisphereGrid(16)
    window = np.ones_like(surface.z)
    with pytest.raises(ValueError, match="wavelength"):
        KirchhoffSetup.build(surface, -0.5, 1.5, 0.1, 0.0, grid, window)
    with pytest.raises(ValueError, match="kappa"):
        KirchhoffSetup.build(surface, 0.5, 1.5 + 0.1j, 0.1, 0.0, grid, window)
    with pytest.raises(ValueError, match="theta"):
        KirchhoffSetup.build(surface, 0.5, 1.5, np.pi / 2, 0.0, grid, window)
