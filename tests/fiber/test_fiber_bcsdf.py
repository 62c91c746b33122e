"""BCSDF tables and d'Eon's M₀ (fiber.md §6, §14.8–9, T10)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from wavebrdf.solver.fiber import FiberBEM, MieFiber, bcsdf_table, circle, ellipse, longitudinal_m0

DEG = np.pi / 180


@pytest.mark.parametrize("v", [0.005, 0.05, 0.3, 1.0])
@pytest.mark.parametrize("theta_i", [0.0, 0.5, 1.2])
def test_t10_m0_normalization(v, theta_i):
    value = quad(lambda t: longitudinal_m0(theta_i, t, v) * np.cos(t), -np.pi / 2, np.pi / 2,
                 points=[-theta_i], limit=200, epsabs=1e-12, epsrel=1e-12)[0]
    assert value == pytest.approx(1.0, abs=1e-6)


def test_m0_peak_and_small_variance():
    t = np.linspace(-np.pi / 2, np.pi / 2, 20001)
    m0 = longitudinal_m0(0.6, t, 0.02)
    assert t[np.argmax(m0)] == pytest.approx(-0.6, abs=1e-2)  # near the specular cone θ_r = -θ_i
    tiny = longitudinal_m0(0.6, t, 1e-3)  # the direct formula overflows: sinh(1000), I0(1000)
    assert np.all(np.isfinite(tiny)) and np.trapezoid(tiny * np.cos(t), t) == pytest.approx(1.0, rel=1e-4)
    with pytest.raises(ValueError, match="variance"):
        longitudinal_m0(0.0, 0.0, 0.0)


@pytest.fixture(scope="module")
def ellipse_table(cl_ctx):
    calls = []
    table = bcsdf_table(FiberBEM(cl_ctx, ellipse(0.4, 0.25, 48)), [0.5, 0.6], lambda lam: 1.55 - 0.01j * lam,
                        [0.0, 40 * DEG], n_phi_i=36, n_phi_r=36,
                        progress=lambda done, total, sl: calls.append((done, total)))
    return table, calls


def test_table_layout_and_progress(ellipse_table):
    table, calls = ellipse_table
    assert table.dCs_dphi.shape == (2, 2, 2, 36, 36)
    assert table.bcsdf.shape == (2, 2, 36, 36) and table.bcsdf.dtype == np.float32
    assert calls == [(k, 4) for k in range(1, 5)]
    np.testing.assert_allclose(table.index, [1.55 - 0.005j, 1.55 - 0.006j])
    np.testing.assert_allclose(table.C_geom[[0, 9]], [0.5, 0.8], rtol=5e-3)


def test_table_bcsdf_integrates_to_albedo(ellipse_table):
    table, _ = ellipse_table
    albedo = table.C_sca.mean(axis=2) / table.C_ext.mean(axis=2)
    np.testing.assert_allclose(table.bcsdf.sum(axis=-1) * table.phi_r_width, albedo, rtol=1e-6)
    assert np.all(albedo < 1) and np.all(table.power_balance_error < 1e-3)


def test_table_reciprocity_and_mirror_symmetry(ellipse_table):
    """Same bins and sampling on both axes: dC_s/dφ(φ_i → φ_r) = dC_s/dφ(φ_r → φ_i);
    the x-axis mirror of the ellipse maps bin i to bin -i on both axes."""
    table, _ = ellipse_table
    unpol = table.dCs_dphi.mean(axis=2, dtype=np.float64)
    np.testing.assert_allclose(unpol, np.swapaxes(unpol, -1, -2), rtol=1e-5)
    mirror = (-np.arange(36)) % 36
    np.testing.assert_allclose(unpol, unpol[..., mirror, :][..., mirror], rtol=1e-5)


def test_circle_table_bem_matches_mie(cl_ctx):
    lams, thetas = [0.45, 0.55], [0.0, 30 * DEG]
    bem = bcsdf_table(FiberBEM(cl_ctx, circle(0.5, 200)), lams, 1.55, thetas, n_phi_i=1, n_phi_r=72)
    mie = bcsdf_table(MieFiber(0.5), lams, 1.55, thetas, n_phi_i=1, n_phi_r=72)
    assert bem.phi_i.tolist() == [0.0]
    np.testing.assert_allclose(bem.C_ext, mie.C_ext, rtol=5e-4)  # N^-3 discretisation error
    err = np.linalg.norm(bem.bcsdf - mie.bcsdf, axis=-1) / np.linalg.norm(mie.bcsdf, axis=-1)
    assert np.all(err < 1e-3)


def test_effective_width_clamped_near_grazing():
    table = bcsdf_table(MieFiber(0.3), [0.5], 1.55 - 0.02j, [0.0, 89.9 * DEG], n_phi_i=1, n_phi_r=36)
    assert table.C_eff_clamped.tolist() == [[[False], [True]]]
    assert table.C_eff[0, 1, 0] == pytest.approx(6 * 0.6)
    assert table.C_eff[0, 0, 0] == pytest.approx(table.C_ext[0, 0, :, 0].mean())


def test_table_rejects_grazing_and_bad_bins():
    with pytest.raises(ValueError, match="90"):
        bcsdf_table(MieFiber(0.3), [0.5], 1.55, [np.pi / 2], n_phi_i=1)
    with pytest.raises(ValueError, match="n_phi_r"):
        bcsdf_table(MieFiber(0.3), [0.5], 1.55, [0.0], n_phi_i=1, n_phi_r=0)


def test_table_with_explicit_incidence_azimuths(cl_ctx):
    """A config's phi_i_deg list: point samples, identical to single solves."""
    model = FiberBEM(cl_ctx, ellipse(0.4, 0.25, 48))
    phi = np.radians([0.0, 30.0, 75.0])
    table = bcsdf_table(model, [0.5], 1.55, [20 * DEG], n_phi_r=36, phi_i=phi)
    np.testing.assert_allclose(table.phi_i, phi)
    single = model.scattering(0.5, 1.55, 20 * DEG, phi[1], bins=36)
    np.testing.assert_allclose(table.C_ext[0, 0, :, 1], single.C_ext[:, 0], rtol=1e-12)
    np.testing.assert_allclose(table.dCs_dphi[0, 0, :, 1], single.dCs_dphi[:, 0], rtol=1e-5)
