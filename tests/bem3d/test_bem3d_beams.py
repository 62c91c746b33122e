"""Incident beams: Maxwell's equations, power and flat-interface reflectance.

Derivatives by 4th-order central differences of the evaluated fields (independent of how the
fields were built). Units: µm, e^{+jωt}: ∇×E = −jη₀k₀H, ∇×H = j(k₀n₁²/η₀)E.
"""

from __future__ import annotations

import numpy as np
import pytest

from wavebrdf.solver.beams import ExactGaussianBeam, ParaxialGaussianBeam, PlaneWave, beam_frame, make_beam
from wavebrdf.solver.farfield import ETA0

LAMBDA = 0.4
K0 = 2 * np.pi / LAMBDA


def _maxwell_residuals(beam, points, h=2e-4):
    """Relative errors of ∇·E = 0, Faraday and Ampère at ``points``, per polarization (max)."""

    def derivative(axis):
        step = np.zeros(3)
        step[axis] = h
        f = [beam.fields(points + s * step) for s in (2, 1, -1, -2)]
        return [(-f[0][i] + 8 * f[1][i] - 8 * f[2][i] + f[3][i]) / (12 * h) for i in range(2)]

    d = [derivative(a) for a in range(3)]  # d[axis][E|H] shape (2, P, 3)
    E, H = beam.fields(points)

    def curl(i):
        D = [d[a][i] for a in range(3)]
        return np.stack([D[1][..., 2] - D[2][..., 1], D[2][..., 0] - D[0][..., 2], D[0][..., 1] - D[1][..., 0]], -1)

    n1 = beam.exterior_index
    div = sum(d[a][0][..., a] for a in range(3))
    scale_E = K0 * n1 * np.abs(E).max()
    faraday = np.abs(curl(0) + 1j * ETA0 * K0 * H).max() / (ETA0 * K0 * np.abs(H).max())
    ampere = np.abs(curl(1) - 1j * K0 * n1**2 / ETA0 * E).max() / (K0 * n1**2 / ETA0 * np.abs(E).max())
    return np.abs(div).max() / scale_E, faraday, ampere


@pytest.fixture
def sample_points(rng):
    pts = rng.uniform(-0.8, 0.8, (25, 3))
    pts[:, 2] *= 0.3
    return pts


@pytest.mark.parametrize("theta_deg", [0.0, 40.0, 75.0])
def test_exact_beam_satisfies_maxwell(sample_points, theta_deg):
    beam = ExactGaussianBeam(LAMBDA, np.deg2rad(theta_deg), 0.7, waist_um=0.6, patch_size_um=3.0)
    div, faraday, ampere = _maxwell_residuals(beam, sample_points)
    assert div < 1e-9 and faraday < 1e-9 and ampere < 1e-9


def test_paraxial_beam_satisfies_faraday_but_not_ampere(sample_points):
    """Faraday holds exactly by construction; Ampère only to paraxial accuracy (reported)."""
    beam = ParaxialGaussianBeam(LAMBDA, np.deg2rad(40.0), 0.7, waist_um=0.6)
    div, faraday, ampere = _maxwell_residuals(beam, sample_points)
    print(f"paraxial beam (w = 1.5 λ, 40°): div E {div:.2e}, Faraday {faraday:.2e}, Ampère {ampere:.2e}")
    assert faraday < 1e-9
    assert 1e-4 < ampere < 0.2  # paraxial error: present, and of the expected (λ/πw)² order
    wide = ParaxialGaussianBeam(LAMBDA, np.deg2rad(40.0), 0.7, waist_um=3.0)
    assert _maxwell_residuals(wide, sample_points)[2] < 0.2 * ampere  # improves with the waist


def test_paraxial_footprint_and_frame():
    """Footprint exp(−ρ²/w²) on the focal plane (z = 0); ω_i·z_b = −1; frame orthonormal."""
    theta, phi, w = np.deg2rad(35.0), 1.1, 2.0
    frame = beam_frame(theta, phi)
    assert np.allclose(frame @ frame.T, np.eye(3))
    assert np.allclose(np.cross(frame[0], frame[1]), frame[2])
    beam = ParaxialGaussianBeam(LAMBDA, theta, phi, waist_um=w)
    # U on z = 0 through the potential: |U| = exp(−ρ²/w²) along y_b (which lies in the plane)
    pts = np.outer([0.0, 0.5, 1.0, 2.0], frame[1])
    local = pts @ frame.T
    U = beam.potential_derivatives(local[:, 0], local[:, 1], local[:, 2])["U"]
    assert np.allclose(np.abs(U), np.exp(-np.sum(pts**2, axis=1) / w**2), rtol=1e-12)


def test_exact_beam_power_equals_flux_quadrature():
    """Φ_i from the spectrum = ∫ −S_z dA over the patch on z = 0 (beam well inside the patch)."""
    beam = ExactGaussianBeam(LAMBDA, np.deg2rad(30.0), 0.2, waist_um=0.5, patch_size_um=2.5)
    inside, larger = beam.plane_flux(2.5, order=5, extent=2)
    assert np.allclose(larger, beam.incident_power(), rtol=1e-8)
    assert np.allclose(inside, beam.incident_power(), rtol=1e-5)
    assert beam.outside_fraction(2.5) < 1e-5


@pytest.mark.parametrize("index", [1.5, 0.46582 - 4.7119j])
@pytest.mark.parametrize("theta_deg", [0.0, 45.0])
def test_exact_beam_reflectance_is_spectrum_weighted_fresnel(references, index, theta_deg):
    """The beam's reflectance = Σ power-weighted Fresnel over its plane waves (independent Fresnel
    formulas); a very wide beam tends to the plane-wave value."""
    fresnel = references["fresnel_power"]
    beam = ExactGaussianBeam(LAMBDA, np.deg2rad(theta_deg), 0.0, waist_um=0.5, patch_size_um=2.5)
    pw = beam.plane_waves
    khat = pw["kvec"] / np.linalg.norm(pw["kvec"], axis=1, keepdims=True)
    cos_i = -khat[:, 2]
    s_hat = np.cross([0, 0, 1.0], khat)
    norm = np.linalg.norm(s_hat, axis=1, keepdims=True)
    s_hat = np.where(norm > 0, s_hat / np.where(norm > 0, norm, 1), [0, 1.0, 0])
    p_hat = np.cross(s_hat, khat)
    Rs, Rp = fresnel(1.0, index, cos_i)
    for p in range(2):
        es = np.abs(pw["E"][p] @ s_hat.T).diagonal() ** 2
        ep = np.abs(pw["E"][p] @ p_hat.T).diagonal() ** 2
        expected = np.sum(cos_i * (es * Rs + ep * Rp)) / np.sum(cos_i * (es + ep))
        assert beam.reflectance(index)[p] == pytest.approx(expected, rel=1e-12)
    wide = ExactGaussianBeam(LAMBDA, np.deg2rad(theta_deg), 0.0, waist_um=20.0, patch_size_um=100.0)
    Rs0, Rp0 = fresnel(1.0, index, np.array([np.cos(np.deg2rad(theta_deg))]))
    assert wide.reflectance(index) == pytest.approx([Rs0[0], Rp0[0]], rel=2e-3)


def test_polarizations_follow_the_farfield_convention():
    """Index 0 = s (E ⟂ plane of incidence), 1 = p; the plane wave travels along −ω_i."""
    theta, phi = np.deg2rad(30.0), 0.4
    wave = PlaneWave(LAMBDA, theta, phi)
    E, H = wave.fields(np.zeros((1, 3)))
    omega_i = np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    plane_normal = np.cross(omega_i, [0, 0, 1.0])
    assert abs(np.dot(E[1, 0].real, plane_normal)) < 1e-12  # p lies in the plane of incidence
    assert abs(abs(np.dot(E[0, 0].real, plane_normal / np.linalg.norm(plane_normal))) - 1) < 1e-12
    S = 0.5 * np.real(np.cross(E[:, 0], np.conj(H[:, 0])))
    assert np.allclose(S / np.linalg.norm(S, axis=1, keepdims=True), -omega_i)


def test_make_beam_rejects_bad_input():
    with pytest.raises(ValueError, match="beam must be one of"):
        make_beam("gaussian", LAMBDA, 0.1, 0.0, 1.0, patch_size_um=5.0)
    with pytest.raises(ValueError, match="theta_i"):
        make_beam("exact", LAMBDA, 1.6, 0.0, 1.0, patch_size_um=5.0)
    with pytest.raises(ValueError, match="waist_um"):
        make_beam("paraxial", LAMBDA, 0.1, 0.0, None)


@pytest.mark.parametrize("index", [None, 1.3 - 2.0j])
@pytest.mark.parametrize("height_spread", [0.0, 0.35])
@pytest.mark.parametrize("partial_sum_bytes", [None, 2**16])
def test_exact_beam_on_a_lattice_is_the_plane_wave_sum(index, height_spread, partial_sum_bytes, monkeypatch):
    """Points on an x-y lattice (a mesh's quadrature points, many more than one chunk), in one
    plane or at random heights, take the factorized sum; it equals Σ_m E_m e^{−jk_m·(r − focus)}
    (plus the reflected waves) summed here directly. A small ``partial_sum_bytes`` makes the sum
    take its distinct y in many passes."""
    beam = make_beam("exact", 0.5, 0.35, 0.8, 1.2, patch_size_um=5.0, focus_um=(0.3, -0.2, 0.1))
    x, y = np.meshgrid(np.arange(-80, 81) * 0.025, np.arange(-60, 61) * 0.025 + 0.0125, indexing="ij")
    z = 0.04 + height_spread * np.random.default_rng(5).uniform(-1, 1, x.shape)
    points = np.stack([x, y, z], axis=-1)
    assert points[..., 0].size > 4096
    import wavebrdf.solver.beams as beams

    if partial_sum_bytes is not None:
        monkeypatch.setattr(beams, "LATTICE_SUM_BYTES", partial_sum_bytes)
    summed = []
    lattice_sum = beams._lattice_sum
    monkeypatch.setattr(beams, "_lattice_sum", lambda *a: summed.append(lattice_sum(*a)) or summed[-1])
    E, H = beam.fields(points, interface_index=index)
    assert summed and all(s is not None for s in summed)  # the lattice path ran, for every wave set
    assert E.shape == (2,) + x.shape + (3,)
    waves = [(beam.plane_waves, np.array(beam.focus_um))]
    if index is not None:
        waves.append((beam.reflected_waves(index), np.array(beam.focus_um) * [1, 1, -1]))
    pick = np.random.default_rng(3).integers(0, x.size, 200)
    r = points.reshape(-1, 3)[pick]
    expected_E = sum(np.einsum("nm,pmc->pnc", np.exp(-1j * (r - o) @ pw["kvec"].T), pw["E"]) for pw, o in waves)
    expected_H = sum(np.einsum("nm,pmc->pnc", np.exp(-1j * (r - o) @ pw["kvec"].T), pw["H"]) for pw, o in waves)
    got_E, got_H = E.reshape(2, -1, 3)[:, pick], H.reshape(2, -1, 3)[:, pick]
    assert np.max(np.abs(got_E - expected_E)) < 1e-12 * np.max(np.abs(expected_E))
    assert np.max(np.abs(got_H - expected_H)) < 1e-12 * np.max(np.abs(expected_H))


@pytest.mark.parametrize("theta_deg,waist_um", [(50.0, 0.6), (80.0, 1.2), (80.0, 0.6)])
def test_exact_beam_polarizations_carry_the_powers_of_its_spectrum(theta_deg, waist_um):
    """P_p / P_s of the exact beam against the same beam's definition integrated independently
    (tests/references.py ``gaussian_beam_power_ratio``): toward grazing the two differ by percents,
    which a per-polarization BRDF carries into its Mueller matrix (test_polarimetry.py)."""
    from references import gaussian_beam_power_ratio

    theta = np.deg2rad(theta_deg)
    beam = ExactGaussianBeam(LAMBDA, theta, 0.0, waist_um=waist_um, patch_size_um=4.0 * waist_um / np.cos(theta))
    power = beam.incident_power()
    expected = gaussian_beam_power_ratio(LAMBDA, waist_um, theta)
    assert power[1] / power[0] == pytest.approx(expected, rel=2e-3)
    assert abs(expected - 1.0) > 2e-3  # the effect is there to be seen


@pytest.mark.parametrize("theta_deg,waist_um", [(0.0, 1.6), (30.0, 0.6), (70.0, 3.6), (80.0, 2.4), (80.0, 1.2)])
def test_exact_beam_power_is_the_continuous_beams_for_any_period(theta_deg, waist_um):
    """The non-periodic beam's power, normalised to its central amplitude, against the same
    definition integrated independently (tests/references.py ``gaussian_beam_powers``), whatever the
    lattice period. Where the light cone cuts the spectrum (80°), the periodic beam's power per
    period cell samples that cut coarsely and differs by percents (a closed-form far field of the
    whole plane must not divide by it)."""
    from references import gaussian_beam_powers

    theta = np.deg2rad(theta_deg)
    expected = gaussian_beam_powers(LAMBDA, waist_um, theta)
    for patch in (2.4, 24.0, 50.0):
        beam = ExactGaussianBeam(LAMBDA, theta, 0.0, waist_um=waist_um, patch_size_um=patch)
        assert np.allclose(beam.continuous_power(), expected, rtol=5e-4), patch
        if theta_deg < 75.0:
            assert np.allclose(beam.incident_power(), expected, rtol=5e-4), patch
    coarse = ExactGaussianBeam(LAMBDA, theta, 0.0, waist_um=waist_um, patch_size_um=2.4)
    assert theta_deg < 75.0 or np.min(np.abs(coarse.incident_power() / expected - 1)) > 0.01


@pytest.mark.parametrize("theta_deg,waist_um", [(70.0, 1.2), (80.0, 0.6)])
def test_exact_beam_says_how_much_of_its_spectrum_the_light_cone_cuts(theta_deg, waist_um):
    """The share of the Gaussian footprint's spectrum beyond |κ| = k against a polar quadrature of
    the same Gaussian over the disk (scipy), and the excitation's warning toward grazing (none at 50°)."""
    import warnings

    from scipy.integrate import dblquad

    from wavebrdf.solver.bem3d.checks import FootprintWarning, check_beam_spectrum

    theta = np.deg2rad(theta_deg)
    k = 2 * np.pi / LAMBDA
    c = -k * np.sin(theta)
    inside, _ = dblquad(lambda r, a: r * np.exp(-0.5 * waist_um**2 * ((r * np.cos(a) - c) ** 2 + (r * np.sin(a)) ** 2)),
                        0.0, 2 * np.pi, 0.0, k, epsabs=0, epsrel=1e-10)
    expected = 1.0 - inside / (2 * np.pi / waist_um**2)
    beam = ExactGaussianBeam(LAMBDA, theta, 0.0, waist_um=waist_um, patch_size_um=5.0)
    assert beam.evanescent_fraction == pytest.approx(expected, rel=1e-2)  # a threshold's figure: midpoint sums
    diagnostics = {"warnings": []}
    with pytest.warns(FootprintWarning, match="light cone"):
        check_beam_spectrum(beam.evanescent_fraction, theta, waist_um, LAMBDA, diagnostics)
    assert diagnostics["beam_evanescent_fraction"] > 0.1
    moderate = ExactGaussianBeam(LAMBDA, np.deg2rad(50.0), 0.0, waist_um=1.2, patch_size_um=5.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_beam_spectrum(moderate.evanescent_fraction, np.deg2rad(50.0), 1.2, LAMBDA, {"warnings": []})
