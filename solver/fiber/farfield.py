"""Far field and cross sections of a solved fiber (fiber.md §6).

Given the solution block x (4N × columns; rows [η₀J_t, η₀J_z, M_t, M_z] hat coefficients):

- pattern U(φ) = A_⊥ - p̂ × F with A = ∫ η₀J e^{jk_ρ φ̂·ρ'} ds', F = ∫ M e^{jk_ρ φ̂·ρ'} ds',
  p̂ = (cosθ_i φ̂, -sinθ_i) the scattered direction on the cone; U ⟂ p̂, so it is stored by its
  two transverse components (φ̂ and p̂ × φ̂), each a matrix product with the solution;
- dC_s/dφ = k₀|U|²/(8π cosθ_i) (µm/rad, |E₀| = 1), i.e. scattered power per radian per unit
  length divided by S₀ cosθ_i, the power the fiber intercepts per unit width;
- C_ext = Re(Vᴴx)/cosθ_i (the flux of the cross terms, §6), C_abs from the tangential fields
  with the hat Gram matrix, C_sca = ∫ dC_s/dφ dφ (periodic trapezoid on a band-limit-resolving
  grid). Power balance: |C_ext - C_sca - C_abs| / C_ext.

Angular sampling (fiber.md §6, §14.8): U has harmonics up to about k₀ r_max + 10, so φ is
sampled with at least max(360, 4(k₀ r_max + 10)) points; :func:`angular_oversampling` gives
the factor s such that bins·s meets that, and :func:`bin_samples` the sample positions.
Bins are centred on i·2π/bins (bin i covers [(i-½), (i+½))·2π/bins), so φ = 0 and the forward
direction φ_i + π of φ_i = 0 fall on bin centres.
"""

from __future__ import annotations

import numpy as np

from wavebrdf.solver.fiber.incidence import FiberMedia, hat_phase_moments
from wavebrdf.solver.fiber.shapes import CrossSection

__all__ = [
    "absorption_cross_section",
    "angular_oversampling",
    "bin_average",
    "bin_centres",
    "bin_samples",
    "dcs_dphi",
    "extinction_cross_section",
    "far_field_pattern",
    "gram_matrix",
    "radiation_matrices",
    "required_samples",
    "sample_scattering",
]

MIN_ANGULAR_SAMPLES = 360


def required_samples(r_max_um: float, wavelength_um: float) -> int:
    """Minimum number of φ samples over 2π: max(360, 4(k₀ r_max + 10)) (fiber.md §14.8)."""
    k0 = 2.0 * np.pi / wavelength_um
    return int(max(MIN_ANGULAR_SAMPLES, np.ceil(4.0 * (k0 * r_max_um + 10.0))))


def angular_oversampling(bins: int, r_max_um: float, wavelength_um: float) -> int:
    """Samples per bin so that bins·s >= :func:`required_samples`."""
    return int(np.ceil(required_samples(r_max_um, wavelength_um) / bins))


def bin_centres(bins: int) -> np.ndarray:
    """Bin centres i·2π/bins (radians)."""
    return 2.0 * np.pi * np.arange(bins) / bins


def bin_samples(bins: int, per_bin: int) -> np.ndarray:
    """Midpoint samples, ``per_bin`` in each bin, shape (bins·per_bin,), bin-major order."""
    width = 2.0 * np.pi / bins
    j = (np.arange(per_bin) + 0.5) / per_bin - 0.5
    return (bin_centres(bins)[:, None] + width * j[None, :]).ravel()


def bin_average(values: np.ndarray, per_bin: int, axis: int = -1) -> np.ndarray:
    """Box-average consecutive groups of ``per_bin`` samples along ``axis``."""
    values = np.moveaxis(values, axis, -1)
    out = values.reshape(values.shape[:-1] + (-1, per_bin)).mean(axis=-1)
    return np.moveaxis(out, -1, axis)


def sample_scattering(dcs, r_max_um: float, wavelength_um: float, phi_r=None, bins: int = 360):
    """Sample an angular scattering function on the band-limit-resolving grid.

    ``dcs(phi)`` returns dC_s/dφ of shape (len(phi), C). Returns (phi_out, values (R, C), C_sca
    (C,)): point samples at ``phi_r`` if given, else box averages over ``bins`` bins centred on
    i·2π/bins; C_sca is the periodic-trapezoid integral on the fine grid.
    """
    per_bin = angular_oversampling(bins, r_max_um, wavelength_um)
    fine = dcs(bin_samples(bins, per_bin))
    c_sca = fine.mean(axis=0) * 2.0 * np.pi
    if phi_r is None:
        return bin_centres(bins), bin_average(fine, per_bin, axis=0), c_sca
    phi_out = np.atleast_1d(np.asarray(phi_r, dtype=float))
    return phi_out, dcs(phi_out), c_sca


def radiation_matrices(shape: CrossSection, media: FiberMedia, phi, points: int = 6) -> np.ndarray:
    """Matrices R (2, Nφ, 4N) with U_k(φ) = R[k] @ x: the far-field pattern in the transverse
    basis u₁ = φ̂ = (-sinφ, cosφ, 0), u₂ = p̂ × φ̂ = (sinθ cosφ, sinθ sinφ, cosθ).

    With A·u₁ + F·u₂ and A·u₂ - F·u₁ (U = A_⊥ - p̂ × F) and the radiation integrals of the hats
    r_t = ∫ Λ_n t̂ e^{jk_ρ φ̂·ρ} ds (split into φ̂ and ρ̂ = (cosφ, sinφ) parts) and
    r_z = ∫ Λ_n e^{jk_ρ φ̂·ρ} ds:  R₁ = [r_φ, 0, sinθ r_ρ, cosθ r_z], R₂ = [sinθ r_ρ, cosθ r_z, -r_φ, 0].
    """
    phi = np.atleast_1d(np.asarray(phi, dtype=float))
    cp, sp_ = np.cos(phi)[:, None], np.sin(phi)[:, None]
    k = float(media.krho[0].real)
    start, end = hat_phase_moments(shape, k * np.stack([np.cos(phi), np.sin(phi)], axis=1), points)
    end_prev = np.roll(end, 1, axis=1)  # element n-1 ends at node n
    t, t_prev = shape.tangents, np.roll(shape.tangents, 1, axis=0)
    r_x = start * t[None, :, 0] + end_prev * t_prev[None, :, 0]
    r_y = start * t[None, :, 1] + end_prev * t_prev[None, :, 1]
    r_phi = -sp_ * r_x + cp * r_y
    r_rho = cp * r_x + sp_ * r_y
    r_z = start + end_prev
    ct, st = np.cos(media.theta_i), np.sin(media.theta_i)
    zero = np.zeros_like(r_z)
    return np.stack([
        np.concatenate([r_phi, zero, st * r_rho, ct * r_z], axis=1),
        np.concatenate([st * r_rho, ct * r_z, -r_phi, zero], axis=1),
    ])


def far_field_pattern(shape: CrossSection, media: FiberMedia, x: np.ndarray, phi,
                      points: int = 6) -> np.ndarray:
    """U(φ) of the solutions ``x`` (4N, C) in the transverse basis (φ̂, p̂ × φ̂): (Nφ, 2, C)."""
    r = radiation_matrices(shape, media, phi, points)
    return np.stack([r[0] @ x, r[1] @ x], axis=1)


def dcs_dphi(media: FiberMedia, pattern: np.ndarray) -> np.ndarray:
    """dC_s/dφ = k₀|U|²/(8π cosθ_i) (µm/rad) from U of shape (Nφ, 2 or 3, C); returns (Nφ, C)."""
    return media.k0 * np.sum(np.abs(pattern) ** 2, axis=1) / (8.0 * np.pi * np.cos(media.theta_i))


def extinction_cross_section(media: FiberMedia, rhs: np.ndarray, x: np.ndarray) -> np.ndarray:
    """C_ext = Re(Vᴴx)/cosθ_i (µm) per column."""
    return np.real(np.sum(np.conj(rhs) * x, axis=0)) / np.cos(media.theta_i)


def gram_matrix(shape: CrossSection):
    """Cyclic tridiagonal Gram matrix ∫ Λ_i Λ_j ds of the hats (scipy.sparse, N×N)."""
    from scipy.sparse import diags

    n = shape.segments
    d = shape.lengths
    d_prev = np.roll(d, 1)
    g = diags([(d_prev + d) / 3.0, d[:-1] / 6.0, d[:-1] / 6.0], [0, 1, -1], shape=(n, n)).tolil()
    g[0, n - 1] += d[n - 1] / 6.0
    g[n - 1, 0] += d[n - 1] / 6.0
    return g.tocsr()


def absorption_cross_section(shape: CrossSection, media: FiberMedia, x: np.ndarray) -> np.ndarray:
    """C_abs = -Re(J̃_tᴴ G M_z - J̃_zᴴ G M_t)/cosθ_i (µm) per column: minus the outward flux of
    the total exterior field (fiber.md §6)."""
    n = shape.segments
    g = gram_matrix(shape)
    jt, jz, mt, mz = (x[i * n : (i + 1) * n] for i in range(4))
    flux = np.real(np.sum(np.conj(jt) * (g @ mz) - np.conj(jz) * (g @ mt), axis=0))
    return -flux / np.cos(media.theta_i)
