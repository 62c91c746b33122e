"""Oblique plane-wave incidence on a fiber: wavenumbers per medium, polarizations, test integrals.

Conventions (fiber.md §0, §5): fiber axis ẑ, time dependence e^{+jωt}, index m = n - jκ (κ >= 0
is loss), θ_i measured from the plane normal to the axis, ω_i = (cosθ cosφ, cosθ sinφ, sinθ)
points toward the light, E_i = ê e^{jk₀ ω_i·r} with |E₀| = 1. Every field varies as e^{jk_z z},
k_z = k₀ sinθ_i in both media; k_ρ,p = sqrt(k_p² - k_z²) with Im k_ρ <= 0.

Polarization index 0 = "parallel" (BH case I: E in the plane of ẑ and ω_i, E ∥ axis at θ = 0),
index 1 = "perpendicular" (BH case II).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wavebrdf.solver.fiber.shapes import CrossSection

__all__ = [
    "POLARIZATIONS",
    "FiberMedia",
    "fiber_media",
    "gauss_legendre_unit",
    "hat_phase_moments",
    "incident_amplitudes",
    "incident_fields",
    "polarization_vectors",
    "rhs_vectors",
]

POLARIZATIONS = ("parallel", "perpendicular")


@dataclass(frozen=True)
class FiberMedia:
    """Wavenumbers (1/µm) for one (λ, θ_i, index); medium 0 = outside (vacuum), 1 = fiber."""

    wavelength_um: float
    theta_i: float  # radians
    index: complex  # m = n - jκ of the fiber
    k0: float
    kz: float
    k: np.ndarray  # (2,) complex: k₀ m_p
    krho: np.ndarray  # (2,) complex, Im <= 0
    eps_r: np.ndarray  # (2,) complex: m_p²

    @property
    def mu_r(self) -> np.ndarray:
        return np.ones(2, dtype=complex)


def fiber_media(wavelength_um: float, index: complex, theta_i: float) -> FiberMedia:
    """Wavenumbers of the exterior (vacuum) and interior (index m = n - jκ) at incidence θ_i."""
    lam = float(wavelength_um)
    if not (np.isfinite(lam) and lam > 0):
        raise ValueError(f"wavelength_um must be a positive number, got {wavelength_um!r}")
    m = complex(index)
    if not np.isfinite(m) or m.real <= 0:
        raise ValueError(f"index must be a complex number n - jκ with n > 0, got {index!r}")
    if m.imag > 0:
        raise ValueError(
            f"index {index!r} has a positive imaginary part: with e^(+jωt) a lossy index is n - jκ "
            "(κ >= 0); n + jκ would be a gain medium"
        )
    theta = float(theta_i)
    if not (np.isfinite(theta) and abs(theta) < np.pi / 2):
        raise ValueError(f"theta_i must satisfy |theta_i| < 90° (radians < π/2), got {theta_i!r}")
    k0 = 2.0 * np.pi / lam
    kz = k0 * np.sin(theta)
    m_p = np.array([1.0, m], dtype=complex)
    k = k0 * m_p
    krho = np.sqrt(k * k - kz * kz)
    krho = np.where(krho.imag > 0, -krho, krho)  # decaying branch under e^{+jωt}
    krho[0] = k0 * np.cos(theta)  # exact, real
    return FiberMedia(lam, theta, m, k0, kz, k, krho, m_p * m_p)


def gauss_legendre_unit(n: int) -> tuple[np.ndarray, np.ndarray]:
    """n-point Gauss–Legendre nodes and weights on [0, 1]."""
    x, w = np.polynomial.legendre.leggauss(int(n))
    return 0.5 * (x + 1.0), 0.5 * w


def polarization_vectors(theta_i: float, phi_i) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ω_i, ê_parallel, ê_perpendicular), each of shape (P, 3), for azimuths ``phi_i`` (radians)."""
    phi = np.atleast_1d(np.asarray(phi_i, dtype=float))
    ct, st = np.cos(theta_i), np.sin(theta_i)
    cp, sp = np.cos(phi), np.sin(phi)
    omega = np.stack([ct * cp, ct * sp, np.full_like(phi, st)], axis=1)
    e_par = np.stack([-st * cp, -st * sp, np.full_like(phi, ct)], axis=1)
    e_perp = np.cross(e_par, omega)
    return omega, e_par, e_perp


def incident_amplitudes(media: FiberMedia, phi_i) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ω_i (P, 3), E₀ (2, P, 3), η₀H₀ (2, P, 3)) of the unit-amplitude plane waves."""
    omega, e_par, e_perp = polarization_vectors(media.theta_i, phi_i)
    e0 = np.stack([e_par, e_perp])  # (2, P, 3)
    return omega, e0, -np.cross(omega[None], e0)  # η₀H₀ = -ω_i × E₀


def incident_fields(media: FiberMedia, phi_i, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """E_i and η₀H_i at ``points`` (M, 2) in the z = 0 plane, shape (2 pol, P, M, 3)."""
    omega, e0, h0 = incident_amplitudes(media, phi_i)
    phase = np.exp(1j * media.k0 * (points @ omega[:, :2].T)).T  # (P, M)
    return e0[:, :, None, :] * phase[None, :, :, None], h0[:, :, None, :] * phase[None, :, :, None]


def hat_phase_moments(shape: CrossSection, wavevector: np.ndarray, points: int = 6):
    """∫ over each element of Λ_start e^{j k·ρ} and Λ_end e^{j k·ρ} for in-plane wavevectors
    ``wavevector`` (K, 2); returns (start, end), each (K, N)."""
    s, w = gauss_legendre_unit(points)
    pts = shape.nodes[:, None, :] + s[None, :, None] * shape.edges[:, None, :]  # (N, Q, 2)
    phase = np.exp(1j * np.einsum("kc,nqc->knq", wavevector, pts))
    dl = shape.lengths[:, None] * w[None, :]
    return np.einsum("knq,nq->kn", phase, dl * (1.0 - s)), np.einsum("knq,nq->kn", phase, dl * s)


def rhs_vectors(shape: CrossSection, media: FiberMedia, phi_i, points: int = 6) -> np.ndarray:
    """Right-hand sides, shape (4N, 2·P): rows [⟨Λ t̂,E_i⟩, ⟨Λ ẑ,E_i⟩, ⟨Λ t̂,η₀H_i⟩, ⟨Λ ẑ,η₀H_i⟩],
    columns (polarization, φ_i) flattened with polarization first.

    The plane-wave amplitude is constant, so each test integral is (t̂_e·E₀ or E₀z) times a
    hat-weighted phase integral over element e; hat m collects the start of element m and the
    end of element m-1.
    """
    omega, e0, h0 = incident_amplitudes(media, phi_i)
    start, end = hat_phase_moments(shape, media.k0 * omega[:, :2], points)  # (P, N)
    end_prev = np.roll(end, 1, axis=1)
    t, t_prev = shape.tangents, np.roll(shape.tangents, 1, axis=0)
    blocks = []
    for amp in (e0, h0):  # (2, P, 3)
        tangential = (np.einsum("kpc,nc->kpn", amp[..., :2], t) * start[None]
                      + np.einsum("kpc,nc->kpn", amp[..., :2], t_prev) * end_prev[None])
        axial = amp[..., 2:3] * (start + end_prev)[None]
        blocks += [tangential, axial]
    npol, nphi = e0.shape[:2]
    return np.concatenate([b.reshape(npol * nphi, -1).T for b in blocks], axis=0)
