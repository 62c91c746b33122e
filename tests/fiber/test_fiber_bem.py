"""2.5D fiber BEM against the Mie series and physical identities (fiber.md §15: T3–T8, T11)."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from wavebrdf.solver.fiber import FiberBEM, circle, ellipse, mie_cylinder, polygon

logger = logging.getLogger(__name__)

DEG = np.pi / 180
PHI_720 = 2 * np.pi * np.arange(720) / 720


def _bem_vs_mie(ctx, shape, radius, lam, m, theta_deg):
    res = FiberBEM(ctx, shape).solve(lam, m, theta_deg * DEG, [0.0]).scattering(phi_r=PHI_720)
    mie = mie_cylinder(lam, radius, m, theta_deg * DEG)
    ref = mie.dCs_dphi(PHI_720)
    l2 = np.linalg.norm(res.dCs_dphi[:, 0] - ref, axis=1) / np.linalg.norm(ref, axis=1)
    return res, mie, l2


@pytest.mark.parametrize("theta_deg", [0.0, 60.0])
@pytest.mark.parametrize("preserve_area", [True, False], ids=["area-preserving", "inscribed"])
def test_t3_paper_validation_case(cl_ctx, theta_deg, preserve_area):
    """a = 1 µm, λ = 0.4 µm, m = 1.55, N = 300 ([P] Fig. 9: case I at 0°, case II at 60°; both
    polarizations checked at both angles). Bar: relative L2 of dC_s/dφ over 720 φ_r < 1e-3
    (the issue's aim; [P] claims < 1e-2). The area-preserving polygon does far better (~5e-5)."""
    shape = circle(1.0, 300, preserve_area=preserve_area)
    res, mie, l2 = _bem_vs_mie(cl_ctx, shape, 1.0, 0.4, 1.55, theta_deg)
    logger.info("T3 θ=%g %s: L2 %s, C_ext %s vs %s", theta_deg, shape.name, l2, res.C_ext[:, 0], mie.C_ext)
    assert np.all(l2 < 1e-3)
    np.testing.assert_allclose(res.C_ext[:, 0], mie.C_ext, rtol=1e-3)
    if preserve_area:
        assert np.all(l2 < 1e-4)
        np.testing.assert_allclose(res.C_sca[:, 0], mie.C_sca, rtol=1e-4)


def test_t4_lossy_oblique_and_t5_power_balance(cl_ctx):
    """a = 0.3 µm, λ = 0.5 µm, m = 1.55 - 0.05j, θ = 30°, N = 60: cross sections within 0.2%
    of fiber.md's Mie values, power balance < 1e-3."""
    res, mie, l2 = _bem_vs_mie(cl_ctx, circle(0.3, 60), 0.3, 0.5, 1.55 - 0.05j, 30.0)
    np.testing.assert_allclose(res.C_ext[:, 0], [2.01242, 1.94046], rtol=2e-3)
    np.testing.assert_allclose(res.C_sca[:, 0], [1.59435, 1.51714], rtol=2e-3)
    np.testing.assert_allclose(res.C_abs[:, 0], [0.41808, 0.42333], rtol=2e-3)
    assert np.all(l2 < 2e-3)
    assert np.all(res.power_balance_error < 1e-3)
    assert np.all(res.C_abs > 0)  # κ >= 0 is loss, never gain


def test_t5_lossless_absorbs_nothing(cl_ctx):
    res = FiberBEM(cl_ctx, ellipse(0.4, 0.25, 64)).solve(0.5, 1.55, 30 * DEG, [0.0, 1.0]).scattering()
    assert np.all(np.abs(res.C_abs) / res.C_ext < 1e-3)
    assert np.all(res.power_balance_error < 1e-3)


def test_t6_grazing_incidence(cl_ctx):
    """θ = 89.9°: the exterior Hankel arguments are tiny (k_ρ = k₀ cos θ); within 1% of Mie."""
    res, mie, l2 = _bem_vs_mie(cl_ctx, circle(0.3, 60), 0.3, 0.5, 1.55 - 0.02j, 89.9)
    assert res.C_ext[0, 0] == pytest.approx(20.138, rel=1e-2)
    assert res.C_sca[0, 0] == pytest.approx(18.845, rel=1e-2)
    np.testing.assert_allclose(res.C_ext[:, 0], mie.C_ext, rtol=1e-3)
    assert np.all(l2 < 1e-2)
    assert np.all(np.isfinite(res.dCs_dphi))


def test_t7_reciprocity_and_mirror_symmetry(cl_ctx):
    """Ellipse 0.4 × 0.25 µm, m = 1.55 - 0.02j, λ = 0.5 µm, θ = 30°, N = 64: unpolarized
    dC_s/dφ(φ_i → φ_r) = dC_s/dφ(φ_r → φ_i); mirror (φ_i, φ_r) → (π - φ_i, π - φ_r)."""
    a, b = 20 * DEG, 110 * DEG
    pairs = [(a, b), (0.3, 2.9), (1.0, 4.0)]
    incid = [p for ab in pairs for p in ab]
    sol = FiberBEM(cl_ctx, ellipse(0.4, 0.25, 64)).solve(0.5, 1.55 - 0.02j, 30 * DEG, incid + [np.pi - a, np.pi - b])
    out = incid[1::2] + incid[0::2] + [np.pi - b, np.pi - a]
    u = sol.scattering(phi_r=np.array(out)).dCs_dphi_unpolarized  # (P, R)
    for k, (pi_, pr_) in enumerate(pairs):
        forward = u[2 * k, k]  # φ_i = pairs[k][0] → φ_r = pairs[k][1]
        backward = u[2 * k + 1, len(pairs) + k]
        assert forward == pytest.approx(backward, rel=1e-8)
    assert u[0, 0] == pytest.approx(0.0526, rel=1e-2)  # [V] value at (20°, 110°)
    assert u[-2, -2] == pytest.approx(u[0, 0], rel=1e-6)
    assert u[-1, -1] == pytest.approx(u[1, len(pairs)], rel=1e-6)


def test_t8_circle_rotation_invariance(cl_ctx):
    """dC_s/dφ depends only on φ_r - φ_i: exactly under a rotation of the mesh (covariance of
    the implementation) and to the discretisation error for arbitrary φ_i on one mesh."""
    shape = circle(0.3, 60)
    phis = np.array([0.0, 0.2, 1.1, 2.9])
    offsets = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    sol = FiberBEM(cl_ctx, shape).solve(0.5, 1.55 - 0.02j, 30 * DEG, phis)
    vals = np.stack([sol.scattering(phi_r=p + offsets).dCs_dphi[:, i] for i, p in enumerate(phis)], axis=1)
    assert np.max(np.abs(vals - vals[:, :1])) / np.max(vals) < 1e-6
    alpha = 0.37
    rot = FiberBEM(cl_ctx, shape.rotated(alpha)).solve(0.5, 1.55 - 0.02j, 30 * DEG, phis + alpha)
    vals_rot = np.stack([rot.scattering(phi_r=p + alpha + offsets).dCs_dphi[:, i] for i, p in enumerate(phis)], axis=1)
    assert np.max(np.abs(vals_rot - vals)) / np.max(vals) < 1e-12


def test_polarization_labels_follow_bh_cases(cl_ctx):
    """At θ = 60° cases I and II differ by 7%: the BEM's "parallel" must match case I."""
    res, mie, _ = _bem_vs_mie(cl_ctx, circle(1.0, 300), 1.0, 0.4, 1.55, 60.0)
    assert abs(mie.C_ext[0] / mie.C_ext[1] - 1) > 0.05
    np.testing.assert_allclose(res.C_ext[:, 0], mie.C_ext, rtol=1e-4)


def test_binned_output_integrates_to_c_sca(cl_ctx):
    res = FiberBEM(cl_ctx, ellipse(0.4, 0.25, 64)).solve(0.45, 1.55 - 0.01j, 10 * DEG, [0.4]).scattering(bins=90)
    assert res.binned and res.phi_r.size == 90
    np.testing.assert_allclose(res.dCs_dphi.mean(axis=-1) * 2 * np.pi, res.C_sca, rtol=1e-12)
    np.testing.assert_allclose(res.N_wave.sum(axis=-1) * 2 * np.pi / 90, res.C_sca.mean(0) / res.C_ext.mean(0),
                               rtol=1e-12)


def test_reference_assembly_gives_the_same_solution(cl_ctx):
    bem = FiberBEM(cl_ctx, ellipse(0.4, 0.25, 32))
    a = bem.solve(0.5, 1.55 - 0.05j, 40 * DEG, [0.7]).scattering(bins=36)
    b = bem.solve(0.5, 1.55 - 0.05j, 40 * DEG, [0.7], reference=True).scattering(bins=36)
    np.testing.assert_allclose(a.dCs_dphi, b.dCs_dphi, rtol=1e-9)
    np.testing.assert_allclose(a.C_ext, b.C_ext, rtol=1e-10)


def test_gain_index_rejected(cl_ctx):
    with pytest.raises(ValueError, match="gain"):
        FiberBEM(cl_ctx, circle(0.3, 30)).solve(0.5, 1.55 + 0.1j, 0.0, [0.0])
    with pytest.raises(ValueError, match="theta_i"):
        FiberBEM(cl_ctx, circle(0.3, 30)).solve(0.5, 1.55, np.pi / 2, [0.0])


@pytest.mark.slow
def test_t11_smooth_convergence_order(cl_ctx):
    """Doubling N on a smooth shape cuts the error by at least 4× (area-preserving: about 8×)."""
    errs = []
    for n in (75, 150, 300):
        res, mie, _ = _bem_vs_mie(cl_ctx, circle(1.0, n), 1.0, 0.4, 1.55, 60.0)
        errs.append(np.max(np.abs(res.C_ext[:, 0] / mie.C_ext - 1)))
    logger.info("T11 circle errors %s", errs)
    assert errs[0] / errs[1] > 4 and errs[1] / errs[2] > 4


@pytest.mark.slow
def test_t11_square_corners(cl_ctx):
    """Square 0.6 µm, λ = 0.5 µm, m = 1.55, θ = 30°, φ_i = 20° (fiber.md T11, [V] values):
    uniform mesh in-plane-E C_x 1.878666 (N = 40) and 1.876199 (N = 320), limit ≈ 1.87609;
    E-in-axis-plane limit ≈ 1.88646; corner grading at N = 320 moves towards the limit."""
    square = [[0, 0], [0.6, 0], [0.6, 0.6], [0, 0.6]]
    values = {}
    for n, grading in ((40, 0), (320, 0), (320, 2)):
        bem = FiberBEM(cl_ctx, polygon(square, n, corner_grading=grading))
        values[n, grading] = bem.solve(0.5, 1.55, 30 * DEG, [20 * DEG]).scattering().C_ext[:, 0]
    logger.info("T11 square %s", values)
    assert values[40, 0][1] == pytest.approx(1.878666, rel=2e-5)
    assert values[320, 0][1] == pytest.approx(1.876199, rel=2e-5)
    assert values[320, 0][0] == pytest.approx(1.88646, rel=2e-5)
    assert abs(values[320, 2][1] - 1.87609) < abs(values[320, 0][1] - 1.87609) / 3
