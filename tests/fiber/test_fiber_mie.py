"""Mie series for infinite cylinders at oblique incidence (fiber.md §7, T1, T2): self-checks,
the reference table, and the independent T-matrix code treams (run inside the test)."""

from __future__ import annotations


import numpy as np
import pytest

from references import cylinder_widths_treams
from wavebrdf.solver.fiber import MieFiber, mie_cylinder, mie_scattering

DEG = np.pi / 180

# fiber.md T2: a = 1 µm, [P] normalization; (λ, m, θ_i°, C_x I, C_s I, C_x II, C_s II), None: = C_x
T2_TABLE = [
    (0.4, 1.55, 0, 5.167931, None, 5.230100, None),
    (0.4, 1.55, 60, 3.811081, None, 4.081160, None),
    (0.4, 1.55 - 0.05j, 30, 4.149860, 2.247348, 4.120593, 2.053894),
    (0.55, 1.55 - 0.01j, 0, 3.366534, 2.588188, 3.373551, 2.554640),
    (0.55, 1.55 - 0.2j, 20, 4.356369, 2.357340, 4.336881, 2.115846),
    (0.7, 1.55, 45, 3.812525, None, 3.915212, None),
]


@pytest.mark.parametrize("row", T2_TABLE, ids=lambda r: f"lam{r[0]}-m{r[1]}-th{r[2]}")
def test_t2_reference_table(row):
    lam, m, theta, cx1, cs1, cx2, cs2 = row
    mie = mie_cylinder(lam, 1.0, m, theta * DEG)
    np.testing.assert_allclose(mie.C_ext, [cx1, cx2], rtol=1e-5)
    np.testing.assert_allclose(mie.C_sca, [cs1 or cx1, cs2 or cx2], rtol=1e-5)


@pytest.mark.parametrize("lam, radius, theta", [(0.4, 1.0, 0.0), (0.55, 0.3, 40.0), (0.7, 2.5, 75.0)])
def test_t1_lossless_extinction_equals_scattering(lam, radius, theta):
    mie = mie_cylinder(lam, radius, 1.55, theta * DEG)
    np.testing.assert_allclose(mie.Q_ext, mie.Q_sca, rtol=1e-12)


def test_t1_rayleigh_limits():
    x, m = 0.01, 1.55
    mie = mie_cylinder(2 * np.pi, x, m, 0.0)  # k0 = 1, a = x
    np.testing.assert_allclose(mie.Q_sca, [2.4283e-6, 4.1929e-7], rtol=2e-5)  # fiber.md T1 values
    rayleigh = [np.pi**2 * x**3 / 8 * abs(m**2 - 1) ** 2,
                np.pi**2 * x**3 / 4 * abs((m**2 - 1) / (m**2 + 1)) ** 2]
    np.testing.assert_allclose(mie.Q_sca, rayleigh, rtol=1e-3)  # leading order in x


@pytest.mark.parametrize("m, theta", [(1.55, 60.0), (1.55 - 0.2j, 20.0), (2.0 - 1.0j, 80.0)])
def test_t1_angular_integral_equals_scattering(m, theta):
    mie = mie_cylinder(0.5, 0.8, m, theta * DEG)
    phi = 2 * np.pi * np.arange(4000) / 4000
    integral = mie.dCs_dphi(phi, phi_i=0.3).mean(axis=1) * 2 * np.pi
    np.testing.assert_allclose(integral, mie.C_sca, rtol=1e-12)


def test_extinction_paradox_large_fiber():
    """fiber.md T2 note: x = 200, m = 1.55, normal incidence."""
    mie = mie_cylinder(2 * np.pi, 200.0, 1.55, 0.0)
    np.testing.assert_allclose(mie.Q_ext, [1.86966, 1.86934], rtol=5e-6)


def test_t4_t6_reference_values():
    """The Mie numbers fiber.md uses as targets of the BEM tests T4 and T6."""
    t4 = mie_cylinder(0.5, 0.3, 1.55 - 0.05j, 30 * DEG)
    np.testing.assert_allclose(t4.C_ext, [2.01242, 1.94046], rtol=5e-6)
    np.testing.assert_allclose(t4.C_sca, [1.59435, 1.51714], rtol=5e-6)
    np.testing.assert_allclose(t4.C_abs, [0.41808, 0.42333], rtol=2e-5)
    t6 = mie_cylinder(0.5, 0.3, 1.55 - 0.02j, 89.9 * DEG)
    np.testing.assert_allclose([t6.C_ext[0], t6.C_sca[0]], [20.138, 18.845], rtol=5e-5)


def test_loss_sign_and_gain_rejected():
    lossy = mie_cylinder(0.5, 0.5, 1.55 - 0.1j, 20 * DEG)
    assert np.all(lossy.C_abs > 0)
    with pytest.raises(ValueError, match="n - jκ"):
        mie_cylinder(0.5, 0.5, 1.55 + 0.1j, 0.0)


def test_strong_absorber_large_fiber_is_finite():
    """Scaled Bessels: m = 1.55 - 2j, D = 13.1 µm at 0.65 µm (fiber.md T12 setting)."""
    mie = mie_cylinder(0.65, 6.55, 1.55 - 2j, 0.0)
    assert np.all(np.isfinite(mie.C_ext)) and np.all(mie.C_abs > 0)
    # an opaque fiber: extinction close to twice the geometric width
    assert np.all(np.abs(mie.C_ext / 13.1 - 2) < 0.15)  # opaque: about twice the width (2.05, 2.11)


def test_mie_scattering_result_layout():
    res = mie_scattering(0.5, 0.4, 1.55 - 0.01j, 0.3, phi_i=[0.0, 1.0], bins=360)
    assert res.dCs_dphi.shape == (2, 2, 360) and res.binned
    # rotation invariance: the pattern of φ_i = 1 rad is that of φ_i = 0 shifted (whole bins only)
    shifted = mie_scattering(0.5, 0.4, 1.55 - 0.01j, 0.3, phi_i=2 * np.pi * 40 / 360, bins=360)
    np.testing.assert_allclose(np.roll(res.dCs_dphi[:, 0], 40, axis=-1), shifted.dCs_dphi[:, 0], rtol=1e-12)
    np.testing.assert_allclose(res.dCs_dphi.mean(axis=-1) * 2 * np.pi, res.C_sca, rtol=1e-10)
    assert MieFiber(0.4).width(np.zeros(3)).tolist() == [0.8] * 3


CASES_TREAMS = [(0.4, 1.0, 1.55, 0.0), (0.4, 1.0, 1.55 - 0.05j, 30.0), (0.55, 0.7, 1.55 - 0.2j, 60.0),
                (0.6, 0.25, 0.5 - 3.0j, 45.0)]


@pytest.mark.parametrize("lam, radius, m, theta", CASES_TREAMS)
def test_against_treams_t_matrix(lam, radius, m, theta):
    """Independent code: treams' infinite-cylinder T-matrix (e^{-iωt}, ε = conj(m)²). Its cross
    width is normalised by the full incident intensity: C_treams = C·cosθ_i. Case I is the
    plane wave with E in the plane of the axis and k, case II the one with E ⟂ to it."""
    th = theta * DEG
    ext, sca = cylinder_widths_treams(lam, radius, m, th, orders=40)
    mie = mie_cylinder(lam, radius, m, th)
    np.testing.assert_allclose(mie.C_ext, ext, rtol=1e-8)
    np.testing.assert_allclose(mie.C_sca, sca, rtol=1e-8)


def _first_forward_minimum(mie, lam, diameter):
    theta = np.linspace(1e-4, 2.5 * lam / diameter, 4001)  # angle from the forward direction
    unpolarized = mie.dCs_dphi(np.pi + theta).mean(axis=0)
    first = np.argmax(np.diff(np.sign(np.diff(unpolarized))) > 0) + 1
    return theta[first]


def test_t12_babinet_forward_minimum():
    """fiber.md T12/§11: an absorbing fiber (m = 1.55 + 2i BH, D = 13.1 µm, λ = 0.65 µm) has its
    first forward minimum within 5% of λ/D (0.96 λ/D); a refractive one (m = 1.55) does not
    (0.041 rad instead of λ/D = 0.050)."""
    lam, diameter = 0.65, 13.1
    absorbing = _first_forward_minimum(mie_cylinder(lam, diameter / 2, 1.55 - 2j, 0.0), lam, diameter)
    assert absorbing / (lam / diameter) == pytest.approx(0.96, abs=0.01)
    refractive = _first_forward_minimum(mie_cylinder(lam, diameter / 2, 1.55, 0.0), lam, diameter)
    assert refractive == pytest.approx(0.041, abs=1e-3)


def test_near_grazing_incidence_keeps_a_lossless_fiber_lossless_and_says_when_the_series_rounds():
    """At θ_i = 89.999999° a 0.01 µm fiber has ξ = k a cos θ_i = 2e-9, where Re(b₀ + 2Σb_n)
    cancels (ε/ξ² ≈ 50): a lossless fiber must still absorb nothing (C_ext = C_sca; the series gave
    C_ext 9× C_sca), and every fiber says how uncertain its cross sections are there; a weakly
    absorbing one (κ = 1e-6) also where only its C_abs = C_ext − C_sca is (89.999°: ε/ξ² = 5e-5,
    C_abs ≈ 1e-4 of C_ext); at 60° all are silent."""
    import warnings

    from wavebrdf.solver.fiber.mie import mie_scattering
    from wavebrdf.solver.validity import ValidityWarning

    grazing = np.deg2rad(89.999999)
    lossless = mie_cylinder(0.5, 0.01, 1.55, grazing)
    assert np.all(lossless.C_abs == 0) and np.allclose(lossless.C_ext, lossless.C_sca, rtol=0)
    for theta_deg, index, said in ((89.999999, 1.55 - 0.1j, True), (89.999999, 1.55, True), (60.0, 1.55 - 0.1j, False),
                                   (89.999, 1.55 - 1e-6j, True), (89.999, 1.55, False), (60.0, 1.55 - 1e-6j, False)):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            mie_scattering(0.5, 0.01, index, np.deg2rad(theta_deg), bins=36)
        rounded = [w for w in caught
                   if issubclass(w.category, ValidityWarning) and "the series cancels" in str(w.message)]
        assert len(rounded) == int(said), (theta_deg, index, [str(w.message) for w in caught])
