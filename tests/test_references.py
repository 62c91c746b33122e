"""The independent reference formulas (tests/references.py) against published values and identities."""

from __future__ import annotations

import numpy as np
import pytest

from references import (
    ALUMINIUM_400NM,
    beam_fresnel_reflectance,
    brewster_angle,
    fresnel_reflectance,
    fresnel_transmittance,
    normal_reflectance,
)


def test_glass_normal_incidence_is_four_percent():
    rs, rp = fresnel_reflectance(1.0, 1.5, 0.0)
    assert rs == pytest.approx(0.04, abs=1e-15) and rp == pytest.approx(0.04, abs=1e-15)
    assert normal_reflectance(1.0, 1.5) == pytest.approx(0.04, abs=1e-15)


def test_glass_at_45_degrees_textbook_values():
    """Hecht, Optics: n = 1.5 at 45°: R_s = 0.0920, R_p = 0.00846 (R_p = R_s²)."""
    rs, rp = fresnel_reflectance(1.0, 1.5, np.deg2rad(45.0))
    assert rs == pytest.approx(0.09202, abs=1e-5) and rp == pytest.approx(0.008466, abs=1e-6)
    assert rp == pytest.approx(rs**2, rel=1e-12)  # exact at 45° for any real index


def test_brewster_zero_of_rp():
    theta_b = brewster_angle(1.0, 1.5)
    assert np.rad2deg(theta_b) == pytest.approx(56.3099, abs=1e-4)
    rs, rp = fresnel_reflectance(1.0, 1.5, theta_b)
    assert rp < 1e-30 and rs > 0.14
    _, rp_near = fresnel_reflectance(1.0, 1.5, theta_b + np.array([-0.02, 0.02]))
    assert np.all(rp_near > 1e-5)  # a minimum, not a plateau


def test_aluminium_at_400nm():
    """|(1 − n)/(1 + n)|² with n = 0.46582 − 4.7119j: 22.4876 / 24.3508 = 0.92349."""
    rs, rp = fresnel_reflectance(1.0, ALUMINIUM_400NM, 0.0)
    assert rs == pytest.approx(0.92349, abs=2e-5) and rp == pytest.approx(rs, rel=1e-14)
    # a metal: R_p has a shallow minimum (principal angle) above R_s, both < 1 at every angle
    theta = np.deg2rad(np.linspace(0, 89.9, 500))
    rs, rp = fresnel_reflectance(1.0, ALUMINIUM_400NM, theta)
    assert np.all(rp <= rs + 1e-15) and np.all(rs < 1) and np.all(rp > 0.5)


def test_total_internal_reflection_and_critical_angle():
    """Glass → air beyond θ_c = asin(1/1.5) = 41.81°: R = 1 for both polarizations; below it < 1."""
    theta_c = np.arcsin(1 / 1.5)
    rs, rp = fresnel_reflectance(1.5, 1.0, np.array([theta_c + 1e-6, np.deg2rad(60.0), np.deg2rad(89.0)]))
    assert np.allclose(rs, 1, atol=1e-12) and np.allclose(rp, 1, atol=1e-12)
    rs, rp = fresnel_reflectance(1.5, 1.0, np.deg2rad(30.0))
    assert rs < 0.5 and rp < 0.5
    # a weakly absorbing rarer medium: the decaying branch keeps R ≤ 1 (the growing one gives R > 1)
    rs, rp = fresnel_reflectance(1.5, 1.0 - 1e-3j, np.deg2rad([50.0, 70.0]))
    assert np.all(rs < 1) and np.all(rp < 1) and np.all(rs > 0.99)


@pytest.mark.parametrize("n1,n2", [(1.0, 1.5), (1.0, 2.4), (1.5, 1.0), (1.33, 1.0)])
def test_reflectance_plus_transmittance_is_one_for_lossless_media(n1, n2):
    theta = np.deg2rad(np.linspace(0, 89.5, 200))
    rs, rp = fresnel_reflectance(n1, n2, theta)
    ts, tp = fresnel_transmittance(n1, n2, theta)
    assert np.allclose(rs + ts, 1, atol=1e-12) and np.allclose(rp + tp, 1, atol=1e-12)


def test_no_gain_for_any_loss_and_grazing_limit():
    theta = np.deg2rad(np.linspace(0, 90, 181))
    for n2 in (1.5, 0.5 - 3j, 0.05 - 10j, 2.0 - 1e-4j, 1.3 - 0.5j, ALUMINIUM_400NM, 1.5 - 0.1j, 0.5 - 5j):
        rs, rp = fresnel_reflectance(1.0, n2, theta)
        assert np.all(rs <= 1 + 1e-12) and np.all(rp <= 1 + 1e-12), n2
        assert rs[-1] == pytest.approx(1, abs=1e-9) and rp[-1] == pytest.approx(1, abs=1e-9)  # θ → 90°
    with pytest.raises(ValueError, match="kappa"):
        fresnel_reflectance(1.0, 1.5 + 0.1j, 0.3)


def test_perfect_conductor_limit():
    rs, rp = fresnel_reflectance(1.0, 1e-3 - 1e6j, np.deg2rad([0.0, 45.0, 80.0]))
    assert np.allclose(rs, 1, atol=1e-5) and np.allclose(rp, 1, atol=1e-5)


def test_beam_reflectance_of_a_single_plane_wave_is_fresnel():
    theta = np.deg2rad(35.0)
    khat = np.array([[np.sin(theta), 0.0, -np.cos(theta)]])
    s = np.array([0.0, 1.0, 0.0])
    p = np.cross(s, khat[0])
    E = np.stack([s[None], p[None]])  # (2, 1, 3)
    got = beam_fresnel_reflectance(10.0 * khat, E, 1.0, ALUMINIUM_400NM)
    assert np.allclose(got, fresnel_reflectance(1.0, ALUMINIUM_400NM, theta), rtol=1e-14)
