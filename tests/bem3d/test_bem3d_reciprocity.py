"""Reciprocity, and the pointwise BRDF of a flat patch against the exact reflected beam.

* Plane-wave scattering amplitudes of the discrete PMCHWT system are exactly reciprocal (Z is
  complex-symmetric and the far-field operator is the transpose of the right-hand-side operator):
  f(ω_i, ω_o) = f(ω_o, ω_i) to rounding on a rough metal patch.
* A *beam*-BRDF is not reciprocal when the beam's angular spread λ/(πw) is not small: for a flat
  interface f(ω_i, ω_o) = k² μ_o |Ê_r(k u_o)|² / ∫|Ê_inc|² μ d²κ (stationary phase, Fresnel per
  plane wave), so f(i,o)/f(o,i) ≈ (μ_o/μ_i)² near the mirror direction. The BEM reproduces this
  reference pointwise — it is physics of the finite beam, not an error of the solver.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from wavebrdf.solver.bem3d import BEMSolver, BEMWarning
from wavebrdf.solver.farfield import ETA0, direction
from wavebrdf.solver.surface import generate

LAMBDA = 0.4
AL = 0.46582 - 4.7119j


def _solver(cl_ctx, surface, index):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BEMWarning)
        return BEMSolver(cl_ctx, surface, LAMBDA, index)


def exact_flat_beam_brdf(beam, index, directions, fresnel_power):
    """Reference BRDF (s, p) of an infinite flat interface lit by ``beam`` (ExactGaussianBeam)."""
    k = beam.k
    kappa = k * directions[:, :2]
    E, _ = beam.spectrum(kappa[:, 0], kappa[:, 1])  # (2, M, 3)
    kvec = np.concatenate([kappa, -k * directions[:, 2:3]], axis=1)
    khat = kvec / k
    s_hat = np.cross([0.0, 0.0, 1.0], khat)
    norm = np.linalg.norm(s_hat, axis=1, keepdims=True)
    s_hat = np.where(norm > 1e-12, s_hat / np.maximum(norm, 1e-300), [0.0, 1.0, 0.0])  # normal: r_s = r_p
    p_hat = np.cross(s_hat, khat)
    Rs, Rp = fresnel_power(beam.exterior_index, index, directions[:, 2])
    reflected = (np.abs(np.einsum("pmc,mc->pm", E, s_hat)) ** 2 * Rs
                 + np.abs(np.einsum("pmc,mc->pm", E, p_hat)) ** 2 * Rp)
    # ∫|Ê|² μ d²κ from the incident power Φ = (n₁/2η₀)(2π)² ∫|Ê|² μ d²κ
    denominator = beam.incident_power() / (beam.exterior_index / (2 * ETA0) * (2 * np.pi) ** 2)
    return k**2 * directions[:, 2] * reflected / denominator[:, None]


def _mirror_offsets(theta_i, phi_i, offsets):
    """Outgoing directions at projected offsets from the mirror direction of (θ_i, φ_i)."""
    u0 = -np.sin(theta_i) * np.array([np.cos(phi_i), np.sin(phi_i)])
    u = u0[None, :] + np.asarray(offsets)
    return np.concatenate([u, np.sqrt(1 - np.sum(u**2, axis=1, keepdims=True))], axis=1)


@pytest.fixture(scope="module")
def flat_metal(cl_ctx):
    return _solver(cl_ctx, generate("flat", cells=32, size_um=4 * LAMBDA), AL)


@pytest.mark.parametrize("theta_deg", [0.0, 20.0])
def test_flat_patch_brdf_equals_exact_reflected_beam(flat_metal, references, theta_deg):
    """Pointwise BRDF in the specular lobe (4λ patch, w = L/5) within 2% of the exact reference."""
    from wavebrdf.solver.beams import ExactGaussianBeam

    theta = np.deg2rad(theta_deg)
    waist = flat_metal.mesh.surface.size_um / 5
    dirs = _mirror_offsets(theta, 0.3, [(0, 0), (0.1, 0), (-0.1, 0.05), (0, -0.15), (0.12, 0.12)])
    bem = flat_metal.brdf_at(theta, 0.3, dirs, waist_um=waist)
    beam = ExactGaussianBeam(LAMBDA, theta, 0.3, waist_um=waist, patch_size_um=flat_metal.mesh.surface.size_um)
    ref = exact_flat_beam_brdf(beam, AL, dirs, references["fresnel_power"])
    print(f"θ_i = {theta_deg}°: BEM/reference − 1 = {bem / ref - 1}")
    assert np.all(np.abs(bem / ref - 1) < 0.02)


def test_beam_brdf_nonreciprocity_is_that_of_the_exact_reflected_beam(flat_metal, references):
    from wavebrdf.solver.beams import ExactGaussianBeam

    L = flat_metal.mesh.surface.size_um
    theta_i, theta_o = np.deg2rad(10.0), np.deg2rad(25.0)
    wi, wo = direction(theta_i, 0.0), direction(theta_o, np.pi)
    f_io = flat_metal.brdf_at(theta_i, 0.0, wo[None], waist_um=L / 5)[:, 0]
    f_oi = flat_metal.brdf_at(theta_o, np.pi, wi[None], waist_um=L / 5)[:, 0]
    ref_io = exact_flat_beam_brdf(ExactGaussianBeam(LAMBDA, theta_i, 0.0, waist_um=L / 5, patch_size_um=L),
                                  AL, wo[None], references["fresnel_power"])[:, 0]
    ref_oi = exact_flat_beam_brdf(ExactGaussianBeam(LAMBDA, theta_o, np.pi, waist_um=L / 5, patch_size_um=L),
                                  AL, wi[None], references["fresnel_power"])[:, 0]
    print(f"f(i,o)/f(o,i): BEM {f_io / f_oi}, exact beam reference {ref_io / ref_oi}, "
          f"(μ_o/μ_i)² = {(np.cos(theta_o) / np.cos(theta_i)) ** 2:.4f}")
    assert np.all(np.abs((f_io / f_oi) / (ref_io / ref_oi) - 1) < 0.03)
    assert np.all(np.abs(ref_io / ref_oi - 1) > 0.1)  # the effect is real and large at w = 0.8 λ


@pytest.mark.parametrize("pair", [(15.0, 0.0, 35.0, 160.0), (30.0, 60.0, 50.0, 220.0), (45.0, 200.0, 20.0, 10.0)])
def test_plane_wave_reciprocity_on_rough_metal(rough_metal, pair):
    """f(ω_i, ω_o) = f(ω_o, ω_i) for plane waves on a rough aluminium patch (θ ≤ 60°)."""
    ti, pi, to, po = np.deg2rad(pair)
    f_io = rough_metal.brdf_at(ti, pi, direction(to, po)[None], waist_um=None, beam="plane")
    f_oi = rough_metal.brdf_at(to, po, direction(ti, pi)[None], waist_um=None, beam="plane")
    # unpolarized BRDF (mean over the incident polarization, summed over the outgoing ones)
    assert np.mean(f_io) == pytest.approx(np.mean(f_oi), rel=1e-8)
    assert np.all(f_io > 0)


@pytest.fixture(scope="module")
def rough_metal(cl_ctx):
    surface = generate("gaussian", cells=16, size_um=2 * LAMBDA, seed=11, rms_height_um=0.04, correlation_um=0.2)
    assert surface.statistics()["rms_slope"] > 0.2
    return _solver(cl_ctx, surface, AL)
