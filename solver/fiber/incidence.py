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


def incident_fields(media: FiberMedia, phi_i, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """E_i and η₀H_i at ``points`` (M, 2) in the z = 0 plane, shape (2 pol, P, M, 3)."""
    omega, e_par, e_perp = polarization_vectors(media.theta_i, phi_i)
    e0 = np.stack([e_par, e_perp])  # (2, P, 3)
    h0 = -np.cross(omega[None], e0)  # η₀H₀ = -ω_i × E₀
    phase = np.exp(1j * media.k0 * (points @ omega[:, :2].T)).T  # (P, M)
    return e0[:, :, None, :] * phase[None, :, :, None], h0[:, :, None, :] * phase[None, :, :, None]


def rhs_vectors(shape: CrossSection, media: FiberMedia, phi_i, points: int = 6) -> np.ndarray:
    """Right-hand sides, shape (4N, 2·P): rows [⟨Λ t̂,E_i⟩, ⟨Λ ẑ,E_i⟩, ⟨Λ t̂,η₀H_i⟩, ⟨Λ ẑ,η₀H_i⟩],
    columns (polarization, φ_i) flattened with polarization first."""
    n = shape.segments
    s, w = gauss_legendre_unit(points)
    pts = shape.nodes[:, None, :] + s[None, :, None] * shape.edges[:, None, :]  # (N, Q, 2)
    e, h = incident_fields(media, phi_i, pts.reshape(-1, 2))
    npol, nphi = e.shape[0], e.shape[1]
    out = np.zeros((4 * n, npol * nphi), dtype=complex)
    t = np.concatenate([shape.tangents, np.zeros((n, 1))], axis=1)  # (N, 3)
    dl = shape.lengths[:, None] * w[None, :]  # (N, Q)
    for block, field in enumerate((e, h)):
        f = field.reshape(npol * nphi, n, len(s), 3)
        ft = np.einsum("pnqc,nc->pnq", f, t)
        fz = f[..., 2]
        for comp, val in enumerate((ft, fz)):
            start = np.einsum("pnq,nq->np", val, dl * (1.0 - s)[None, :])  # hat of the start node
            end = np.einsum("pnq,nq->np", val, dl * s[None, :])  # hat of the end node
            row = (2 * block + comp) * n
            out[row : row + n] = start + np.roll(end, 1, axis=0)
    return out
