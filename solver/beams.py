"""Incident fields: Gaussian beams (paraxial and exact) and plane waves, both polarizations.

Conventions (ARCHITECTURE.md): µm, e^{+jωt}, ω_i = (sinθ cosφ, sinθ sinφ, cosθ) points toward the
light, the beam travels along −ω_i. Polarization index 0 = s (E ⟂ plane of incidence), 1 = p, as
in :mod:`wavebrdf.solver.farfield`. Beam frame (bem3d.md §8)::

    x_b = (−cosθ cosφ, −cosθ sinφ, sinθ)   (in the plane of incidence)
    y_b = (−sinφ, cosφ, 0)                 (perpendicular to it)
    z_b = −ω_i                             (propagation)

Both Gaussian beams derive from a vector potential A = U ŷ_b (s) or U x̂_b (p):
H = ∇ × A, E = (∇∇·A + k²A)/(jωε₁), so Faraday's law holds exactly; Ampère's law holds exactly
iff ∇²U + k²U = 0.

* ``"paraxial"`` (:class:`ParaxialGaussianBeam`): U is the astigmatic paraxial Gaussian with
  waists w·cosθ (along x_b) and w (along y_b), focus at ``focus_um``, so its footprint on the
  plane z = focus is the circle of radius w. U satisfies the wave equation only to paraxial
  accuracy (poor when the waist is a few λ or at grazing incidence). Φ_i by quadrature over
  the patch.
* ``"exact"`` (:class:`ExactGaussianBeam`, default): U is a superposition of propagating plane
  waves whose amplitudes are the 2-D Fourier transform of the same footprint
  exp(−|ρ|²/w²)·e^{−jk_∥·ρ} on the focal plane, sampled on a lattice of pitch 2π/P and truncated
  to |κ| < k. It is an exact solution of Maxwell's equations (periodic with period P ≫ the patch,
  so the neighbouring copies do not reach it); its incident power (per period cell) and its
  flat-interface reflectance follow exactly from the plane-wave amplitudes. The normalisation
  (central amplitude) and ``continuous_power`` / ``continuous_reflectance`` are those of the
  non-periodic beam, by a polar quadrature of the spectrum that ends at the light cone: where the
  cone cuts the spectrum (toward grazing) the lattice samples that cut coarsely, and its power per
  period cell moves by percents with P.
* ``"plane"`` (:class:`PlaneWave`): unit amplitude plane wave, for tests.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from wavebrdf.solver.farfield import ETA0
from wavebrdf.solver.footprint import incident_basis
from wavebrdf.solver.fresnel import fresnel_rs_rp

logger = logging.getLogger(__name__)

__all__ = [
    "BEAMS",
    "BEAM_TAIL",
    "Beam",
    "INCIDENCE",
    "BeamWaves",
    "ExactGaussianBeam",
    "ParaxialGaussianBeam",
    "PlaneWave",
    "beam_frame",
    "make_beam",
    "scene_beam",
    "steering_fields",
]

BEAMS = ("exact", "paraxial", "plane")
SPECTRUM_TAIL = 1e-16  # drop plane waves whose Gaussian weight is below this (relative)
REPLICA_LEVEL = 1e-9  # amplitude of the neighbouring periodic copies on the patch
BEAM_TAIL = 1e-8  # BeamWaves leaves out the plane waves below this share of the largest amplitude
INCIDENCE = ("footprint", "beam")  # what lights the approximate wave rungs: the footprint plane wave, or BeamWaves


def beam_frame(theta: float, phi: float) -> np.ndarray:
    """Rows x_b, y_b, z_b (world coordinates) of the beam frame, shape (3, 3)."""
    ct, st, cp, sp = np.cos(theta), np.sin(theta), np.cos(phi), np.sin(phi)
    return np.array([[-ct * cp, -ct * sp, st], [-sp, cp, 0.0], [-st * cp, -st * sp, -ct]])


def _check_angles(theta_i: float, phi_i: float):
    if not (np.isfinite(theta_i) and 0.0 <= theta_i < 0.5 * np.pi):
        raise ValueError(f"theta_i must be in [0, pi/2) radians, got {theta_i!r}")
    if not np.isfinite(phi_i):
        raise ValueError(f"phi_i must be finite, got {phi_i!r}")


@dataclass
class Beam:
    """Common parameters; subclasses implement :meth:`fields` and :meth:`incident_power`."""

    wavelength_um: float
    theta_i: float
    phi_i: float
    exterior_index: float = 1.0
    focus_um: tuple[float, float, float] = (0.0, 0.0, 0.0)

    kind = "abstract"

    def __post_init__(self):
        _check_angles(self.theta_i, self.phi_i)
        if not (np.isfinite(self.wavelength_um) and self.wavelength_um > 0):
            raise ValueError(f"wavelength_um must be > 0, got {self.wavelength_um!r}")
        self.focus_um = np.asarray(self.focus_um, dtype=float).reshape(3)

    @property
    def k0(self) -> float:
        return 2.0 * np.pi / self.wavelength_um

    @property
    def k(self) -> float:
        """k₁ = k₀ n₁ (µm⁻¹)."""
        return self.k0 * self.exterior_index

    @property
    def frame(self) -> np.ndarray:
        return beam_frame(self.theta_i, self.phi_i)

    def fields(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """E, H at ``points`` (..., 3) µm; each of shape (2, ..., 3), polarization s, p."""
        raise NotImplementedError

    def incident_power(self, patch_size_um: float) -> np.ndarray:
        """Φ_i per polarization (W for the beam's amplitude normalisation), shape (2,)."""
        raise NotImplementedError

    def plane_flux(self, patch_size_um: float, order: int = 4, cells: int | None = None,
                   extent: int = 3) -> tuple[np.ndarray, np.ndarray]:
        """Flux −S_z through z = focus: (inside the patch, inside an ``extent``× larger square).

        Gauss quadrature of order ``order`` on ``cells``² cells per patch (default: λ/4 cells).
        Returns two arrays of shape (2,) (polarizations).
        """
        L = float(patch_size_um)
        if cells is None:
            cells = int(np.ceil(4 * L * self.exterior_index / self.wavelength_um))
        x, w = np.polynomial.legendre.leggauss(order)
        d = L / cells
        centres = -0.5 * extent * L + d * (np.arange(extent * cells) + 0.5)
        xs = (centres[:, None] + 0.5 * d * x[None, :]).ravel()
        ws = np.tile(0.5 * d * w, extent * cells)
        X, Y = np.meshgrid(xs, xs, indexing="ij")
        W = np.outer(ws, ws)
        pts = np.stack([X, Y, np.full_like(X, self.focus_um[2])], axis=-1) + [self.focus_um[0], self.focus_um[1], 0.0]
        E, H = self.fields(pts)
        Sz = -0.5 * np.real(np.cross(E, np.conj(H))[..., 2])  # (2, n, n), downward flux
        inside = (np.abs(X) <= 0.5 * L) & (np.abs(Y) <= 0.5 * L)
        return np.sum(Sz * W * inside, axis=(1, 2)), np.sum(Sz * W, axis=(1, 2))

    def outside_fraction(self, patch_size_um: float) -> float:
        """Largest fraction (over polarizations) of the incident flux on z = focus outside the patch."""
        inside, total = self.plane_flux(patch_size_um)
        return float(np.max(1.0 - inside / total))


def _from_beam_frame(frame: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """Beam-frame components (..., 3) → world components."""
    return vectors @ frame


@dataclass
class PlaneWave(Beam):
    """E = ê e^{−jk·r} with |E| = 1, ê = ŷ_b (s) or x̂_b (p); H = k × E/(ωμ₀)."""

    kind = "plane"

    def fields(self, points):
        points = np.asarray(points, dtype=float)
        f = self.frame
        kvec = self.k * f[2]
        phase = np.exp(-1j * ((points - self.focus_um) @ kvec))[..., None]
        E = np.stack([f[1] * phase, f[0] * phase])
        H = np.cross(kvec, E) / (ETA0 * self.k0)
        return E, H

    def incident_power(self, patch_size_um):
        flux = self.exterior_index / (2 * ETA0) * np.cos(self.theta_i) * patch_size_um**2
        return np.array([flux, flux])


@dataclass
class _GaussianBeam(Beam):
    """A beam with a waist w (µm): footprint exp(−ρ²/w²) on the focal plane."""

    waist_um: float = 1.0

    def __post_init__(self):
        super().__post_init__()
        if not (np.isfinite(self.waist_um) and self.waist_um > 0):
            raise ValueError(f"waist_um must be > 0, got {self.waist_um!r}")


@dataclass
class ParaxialGaussianBeam(_GaussianBeam):
    """Astigmatic paraxial Gaussian beam of bem3d.md §8 (waists w cosθ_i, w; |E| ≈ 1 at the focus)."""

    kind = "paraxial"

    @property
    def rayleigh_ranges(self) -> tuple[float, float]:
        """(z_Rx, z_Ry) = k w_a²/2 with w_x = w cosθ_i, w_y = w."""
        wx = self.waist_um * np.cos(self.theta_i)
        return 0.5 * self.k * wx**2, 0.5 * self.k * self.waist_um**2

    def potential_derivatives(self, xb, yb, zb):
        """U and its first and second derivatives in beam coordinates (dict of arrays)."""
        k = self.k
        zrx, zry = self.rayleigh_ranges
        qx = zb + 1j * zrx
        qy = zb + 1j * zry
        amp = 1j * np.sqrt(zrx * zry) / (np.sqrt(qx) * np.sqrt(qy))  # separate roots: continuous in z
        U = amp * np.exp(-1j * k * (zb + xb**2 / (2 * qx) + yb**2 / (2 * qy)))
        Ux = -1j * k * xb / qx * U
        Uy = -1j * k * yb / qy * U
        dz = -0.5 / qx - 0.5 / qy + 1j * k * (xb**2 / (2 * qx**2) + yb**2 / (2 * qy**2) - 1.0)
        Uz = dz * U
        Uxx = (-1j * k / qx - (k * xb / qx) ** 2) * U
        Uyy = (-1j * k / qy - (k * yb / qy) ** 2) * U
        Uxy = -(k**2) * xb * yb / (qx * qy) * U
        Uxz = -1j * k * xb * (-U / qx**2 + Uz / qx)
        Uyz = -1j * k * yb * (-U / qy**2 + Uz / qy)
        return dict(U=U, Ux=Ux, Uy=Uy, Uz=Uz, Uxx=Uxx, Uyy=Uyy, Uxy=Uxy, Uxz=Uxz, Uyz=Uyz)

    @cached_property
    def _normalisation(self) -> complex:
        zrx, _ = self.rayleigh_ranges
        return (self.k**2 - self.k / zrx) * ETA0 / (1j * self.k0 * self.exterior_index**2)

    def fields(self, points):
        points = np.asarray(points, dtype=float)
        f = self.frame
        local = (points - self.focus_um) @ f.T
        d = self.potential_derivatives(local[..., 0], local[..., 1], local[..., 2])
        k2 = self.k**2
        scale = ETA0 / (1j * self.k0 * self.exterior_index**2) / self._normalisation
        zero = np.zeros_like(d["U"])
        # s: A = U y_b ; p: A = U x_b   (beam-frame components)
        E_s = np.stack([d["Uxy"], d["Uyy"] + k2 * d["U"], d["Uyz"]], axis=-1) * scale
        E_p = np.stack([d["Uxx"] + k2 * d["U"], d["Uxy"], d["Uxz"]], axis=-1) * scale
        H_s = np.stack([-d["Uz"], zero, d["Ux"]], axis=-1) / self._normalisation
        H_p = np.stack([zero, d["Uz"], -d["Uy"]], axis=-1) / self._normalisation
        E = np.stack([_from_beam_frame(f, E_s), _from_beam_frame(f, E_p)])
        H = np.stack([_from_beam_frame(f, H_s), _from_beam_frame(f, H_p)])
        return E, H

    def incident_power(self, patch_size_um):
        inside, _ = self.plane_flux(patch_size_um, extent=1)
        return inside


@dataclass
class ExactGaussianBeam(_GaussianBeam):
    """Angular-spectrum Gaussian beam: an exact Maxwell solution with the paraxial footprint.

    ``patch_size_um`` sets the lattice period P of the spectrum so that the periodic copies of
    the beam are below ``REPLICA_LEVEL`` on the patch.
    """

    patch_size_um: float = 1.0
    kind = "exact"

    def __post_init__(self):
        super().__post_init__()
        if not (np.isfinite(self.patch_size_um) and self.patch_size_um > 0):
            raise ValueError(f"patch_size_um must be > 0, got {self.patch_size_um!r}")

    @property
    def period_um(self) -> float:
        """Lattice period P: the copies at distance P are at REPLICA_LEVEL on the patch corners."""
        w = self.waist_um
        reach = w * np.sqrt(np.log(1.0 / REPLICA_LEVEL))
        return max(np.sqrt(0.5) * self.patch_size_um + reach, 2.0 * reach)

    def _densities(self, kx: np.ndarray, ky: np.ndarray):
        """Unnormalised spectral densities (per unit κ area) of E and H at propagating (κx, κy)."""
        k, w = self.k, self.waist_um
        f = self.frame
        k_par = self.k * f[2][:2]
        a = (w**2 / (4 * np.pi)) * np.exp(-0.25 * w**2 * ((kx - k_par[0]) ** 2 + (ky - k_par[1]) ** 2))
        kvec = np.stack([kx, ky, -np.sqrt(np.clip(k**2 - kx**2 - ky**2, 0.0, None))], axis=-1)
        factor = ETA0 / (1j * self.k0 * self.exterior_index**2)
        E = np.empty((2,) + kvec.shape, dtype=complex)
        H = np.empty((2,) + kvec.shape, dtype=complex)
        for p, axis in ((0, f[1]), (1, f[0])):  # s: A = U y_b, p: A = U x_b
            E[p] = factor * a[..., None] * (k**2 * axis - kvec * (kvec @ axis)[..., None])
            H[p] = -1j * a[..., None] * np.cross(kvec, axis)
        return kvec, E, H

    @cached_property
    def evanescent_fraction(self) -> float:
        """Share of the footprint's spectrum |â(κ)|² ∝ exp(−w²|κ − κ_c|²/2) beyond the light cone
        |κ| ≥ k, which the exact beam drops (midpoint sums over ±8/w about κ_c, to ~1 %). Toward grazing it
        is large (≈ 0.4 at 80° for w = 3λ): the beam's footprint is then not the Gaussian of radius
        w but has long tails along the plane of incidence."""
        k, w = self.k, self.waist_um
        centre = self.k * self.frame[2][:2]
        n = 801
        axis = (np.arange(n) + 0.5) * (16.0 / w / n) - 8.0 / w
        KX, KY = np.meshgrid(centre[0] + axis, centre[1] + axis, indexing="ij")
        weight = np.exp(-0.5 * w**2 * (axis[:, None] ** 2 + axis[None, :] ** 2))
        return float(np.sum(weight[KX**2 + KY**2 >= k**2]) / np.sum(weight))

    @cached_property
    def _spectral_rule(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(κx, κy, weights): a quadrature of d²κ over the propagating disk |κ| < k where the
        Gaussian weight is ≥ SPECTRUM_TAIL, in polar coordinates κ = k sin t (cos φ, sin φ) with
        d²κ = k² sin t cos t dt dφ, so the cone's cut is an end point and the integrands stay smooth
        in t (k_z = k cos t): Gauss–Legendre panels of ≤ 1/(2wk) in t and of ≤ 1/(2wκ_max) in φ
        (trapezoid over the whole circle when the Gaussian covers κ = 0)."""
        k, w = self.k, self.waist_um
        centre = self.k * self.frame[2][:2]
        kc = float(np.hypot(*centre))
        reach = 2.0 * np.sqrt(np.log(1.0 / SPECTRUM_TAIL)) / w
        lo, hi = max(0.0, kc - reach), min(k, kc + reach)
        t_lo, t_hi = np.arcsin(lo / k), np.arcsin(hi / k)
        t, wt = _panels(t_lo, t_hi, 0.5 / (w * k))
        if kc <= reach:
            n = int(np.ceil(8.0 * np.pi * hi * w)) + 64
            phi, wp = 2.0 * np.pi * np.arange(n) / n, np.full(n, 2.0 * np.pi / n)
        else:
            half = float(np.arcsin(reach / kc))
            phi, wp = _panels(-half, half, 0.5 / (w * hi))
            phi = phi + np.arctan2(centre[1], centre[0])
        T, PHI = np.meshgrid(t, phi, indexing="ij")
        rho = k * np.sin(T)
        weights = np.outer(wt, wp) * k * rho * np.cos(T)
        return (rho * np.cos(PHI)).ravel(), (rho * np.sin(PHI)).ravel(), weights.ravel()

    @cached_property
    def _continuum(self) -> dict:
        """The non-periodic beam's central amplitude ``norm`` (x_b component of the unnormalised p
        field at the focus, ∫ Ê_p·x̂_b d²κ) and downward ``power`` per polarization (2,) after that
        normalisation, (2π)² ∫ |Ê|² k_z / (2η₀k₀) d²κ, by ``_spectral_rule``."""
        kx, ky, wq = self._spectral_rule
        kvec, E, _ = self._densities(kx, ky)
        norm = np.sum(wq * (E[1] @ self.frame[0]))
        flux = (2.0 * np.pi) ** 2 * np.sum(np.abs(E) ** 2, axis=2) * (-kvec[:, 2]) / (2 * ETA0 * self.k0)
        return {"norm": norm, "power": np.sum(wq * flux, axis=1) / abs(norm) ** 2}

    @cached_property
    def plane_waves(self) -> dict:
        """The plane-wave content: ``kvec`` (M, 3), ``E`` and ``H`` (2, M, 3) amplitudes.

        E(r) = Σ_m E[:, m] e^{−j kvec_m·(r − focus)}, normalised like the paraxial beam: the x_b
        component of the non-periodic beam's p field at the focus is 1 (the periodic one's differs
        where the lattice samples a cut spectrum coarsely; BRDFs divide by a power of the same
        normalisation, so it cancels).
        """
        P = self.period_um
        dk = 2.0 * np.pi / P
        KX, KY, keep = self._lattice(SPECTRUM_TAIL)
        kvec, E, H = self._densities(KX[keep], KY[keep])
        E, H = E * dk**2, H * dk**2
        norm = self._continuum["norm"]  # the non-periodic beam's x_b component of the p field at the focus
        logger.debug("exact beam: %d plane waves, period %.3g µm", len(kvec), P)
        lattice = np.nonzero(keep)  # (κx, κy) lattice indices of each wave
        return {"kvec": kvec, "E": E / norm, "H": H / norm, "period_um": P, "norm": norm,
                "lattice": lattice, "kx_axis": KX[:, 0], "ky_axis": KY[0, :]}

    def _lattice(self, tail: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(κx, κy, keep) of the spectral lattice of pitch 2π/P about the beam's κ_c, out to a
        Gaussian weight of ``tail``; ``keep``: the points of weight ≥ ``tail`` inside the light cone."""
        w, dk = self.waist_um, 2.0 * np.pi / self.period_um
        k_par = self.k * self.frame[2][:2]
        m = int(np.ceil(2.0 * np.sqrt(np.log(1.0 / tail)) / w / dk))
        i = np.arange(-m, m + 1)
        KX, KY = np.meshgrid(k_par[0] + dk * i, k_par[1] + dk * i, indexing="ij")
        gauss = np.exp(-0.25 * w**2 * ((KX - k_par[0]) ** 2 + (KY - k_par[1]) ** 2))
        return KX, KY, (gauss >= tail) & (KX**2 + KY**2 < self.k**2)

    def lattice_size(self, tail: float) -> int:
        """How many of ``plane_waves``' lattice points inside the light cone have a Gaussian weight
        of at least ``tail`` (about how many waves of amplitude ≥ ``tail`` of the largest the beam
        has), without evaluating the beam: for cost estimates."""
        return int(np.count_nonzero(self._lattice(tail)[2]))

    def spectrum(self, kx, ky) -> tuple[np.ndarray, np.ndarray]:
        """Continuous angular spectrum (E, H densities per unit κ area, shape (2, ..., 3)) at
        propagating transverse wavevectors (κx, κy): E(r) = ∫ Ê(κ) e^{−jk(κ)·(r − focus)} d²κ."""
        kx, ky = np.broadcast_arrays(np.asarray(kx, dtype=float), np.asarray(ky, dtype=float))
        _, E, H = self._densities(kx, ky)
        norm = self.plane_waves["norm"]
        return E / norm, H / norm

    def fields(self, points, chunk: int = 4096, interface_index: complex | None = None,
               weights: np.ndarray | None = None):
        """E, H (2, ..., 3) at ``points``; with ``interface_index``, the total field above the flat
        interface z = 0 with that material below: the beam plus its Fresnel reflection. ``weights``
        (M,) scales each plane wave of ``plane_waves`` (and its reflection) before the sum."""
        waves = [(self.plane_waves, self.focus_um)]
        if interface_index is not None:
            waves.append((self.reflected_waves(interface_index), self.focus_um * [1.0, 1.0, -1.0]))
        points = np.asarray(points, dtype=float)
        shape = points.shape[:-1]
        flat_points = points.reshape(-1, 3)
        out = np.zeros((len(flat_points), 12), dtype=complex)
        distinct = _distinct_xy(flat_points) if len(flat_points) > chunk else None
        on_lattice = distinct is not None and _lattice_sum_applies(len(flat_points), distinct)
        for pw, origin in waves:
            flat = flat_points - origin
            m = len(pw["kvec"])
            # columns: E_s, E_p, H_s, H_p (x, y, z each)
            amps = np.concatenate([pw["E"].transpose(1, 0, 2).reshape(m, 6), pw["H"].transpose(1, 0, 2).reshape(m, 6)],
                                  axis=1)
            if weights is not None:
                amps = amps * np.asarray(weights)[:, None]
            summed = _lattice_sum(pw, amps, flat, _shifted(distinct, origin)) if on_lattice else None
            if summed is not None:
                out += summed
                continue
            for s in range(0, len(flat), chunk):
                out[s : s + chunk] += np.exp(-1j * (flat[s : s + chunk] @ pw["kvec"].T)) @ amps
        out = out.reshape(shape + (2, 2, 3))  # (..., E|H, pol, xyz)
        E = np.moveaxis(out[..., 0, :, :], -2, 0)
        H = np.moveaxis(out[..., 1, :, :], -2, 0)
        return E, H

    def reflected_waves(self, index: complex) -> dict:
        """The plane waves reflected by the flat interface z = 0 over a material of ``index``
        (``kvec``, ``E``, ``H`` like ``plane_waves``; phases about the mirrored focus; ``_reflect``).
        """
        pw = self.plane_waves
        kr, E, H = self._reflect(pw["kvec"], pw["E"], pw["H"], index)
        return {"kvec": kr, "E": E, "H": H, "lattice": pw["lattice"], "kx_axis": pw["kx_axis"],
                "ky_axis": pw["ky_axis"]}

    def interface_spectrum(self, kx, ky, index: complex) -> tuple[np.ndarray, np.ndarray]:
        """The continuous beam's total field on the flat interface z = 0 over a material of
        ``index``, as spectral densities (E, H of shape (2, ..., 3), per unit κ area) at (κx, κy)
        (propagating ones; beyond the light cone k_z is taken as 0, values to be masked):
        E(x, y, 0) = ∫ Ê(κ) e^{−jκ·(x, y)} d²κ, incident plus Fresnel-reflected wave
        (``reflected_waves``), the focus's phase included. The beam is the non-periodic one whose
        lattice samples ``plane_waves`` are."""
        kx, ky = np.broadcast_arrays(np.asarray(kx, dtype=float), np.asarray(ky, dtype=float))
        kvec, E, H = self._densities(kx, ky)
        norm = self.plane_waves["norm"]
        _, E_r, H_r = self._reflect(kvec, E / norm, H / norm, index)
        f = self.focus_um
        phase = np.exp(1j * (kx * f[0] + ky * f[1] + kvec[..., 2] * f[2]))[..., None]
        return (E / norm + E_r) * phase, (H / norm + H_r) * phase

    def _flux_weights(self) -> np.ndarray:
        """Downward power of each plane wave per period cell, shape (2, M)."""
        pw = self.plane_waves
        kz = -pw["kvec"][:, 2]
        return pw["period_um"] ** 2 * np.sum(np.abs(pw["E"]) ** 2, axis=2) * kz / (2 * ETA0 * self.k0)

    def incident_power(self, patch_size_um=None):
        """Exact downward power of the periodic beam ``plane_waves`` through any plane z = const,
        per period cell: what lights a patch (its copies being negligible there)."""
        return np.sum(self._flux_weights(), axis=1)

    def continuous_power(self) -> np.ndarray:
        """Downward power of the non-periodic beam, per polarization (``_continuum``): what the
        whole plane's closed-form reflection carries (a flat continuation's far field). The
        power per period cell tends to it as the period grows; where the light cone cuts the
        spectrum (toward grazing) the lattice samples that cut coarsely and the two differ by
        percents."""
        return self._continuum["power"].copy()

    def continuous_reflectance(self, index: complex) -> np.ndarray:
        """Flat-interface reflectance of the non-periodic beam per polarization (``_spectral_rule``;
        ``reflectance`` is the periodic beam's)."""
        kx, ky, wq = self._spectral_rule
        kvec, E, H = self._densities(kx, ky)
        return _flux_ratio(wq * (-kvec[:, 2]), self._reflect(kvec, E, H, index)[1], E)

    def _reflect(self, kvec, E, H, index: complex):
        """``_reflect`` by the flat interface over a material of ``index``, in this beam's medium."""
        return _reflect(kvec, E, H, complex(index) / self.exterior_index, ETA0 / self.exterior_index, self.frame[1])

    def outside_fraction(self, patch_size_um: float) -> float:
        """Fraction of the exact incident power (one beam) crossing z = focus outside the patch."""
        inside, _ = self.plane_flux(patch_size_um, extent=1)
        return float(np.max(1.0 - inside / self.incident_power()))

    def reflectance(self, index: complex) -> np.ndarray:
        """Exact flat-interface reflectance per polarization: Σ_m |k_z,m| |E_r,m|² / Σ_m |k_z,m| |E_m|²."""
        pw = self.plane_waves
        return _flux_ratio(-pw["kvec"][:, 2], self.reflected_waves(index)["E"], pw["E"])


def _flux_ratio(weights: np.ndarray, reflected: np.ndarray, incident: np.ndarray) -> np.ndarray:
    """Σ w |E_r|² / Σ w |E|² per polarization for plane-wave amplitudes (2, M, 3) and weights (M,)."""
    return (np.sum(weights * np.sum(np.abs(reflected) ** 2, axis=-1), axis=1)
            / np.sum(weights * np.sum(np.abs(incident) ** 2, axis=-1), axis=1))


def _panels(a: float, b: float, width: float, order: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Composite Gauss–Legendre nodes and weights on [a, b] with panels of at most ``width``."""
    n = max(1, int(np.ceil((b - a) / width)))
    x, w = np.polynomial.legendre.leggauss(order)
    edges = np.linspace(a, b, n + 1)
    half = 0.5 * np.diff(edges)
    nodes = (0.5 * (edges[:-1] + edges[1:]))[:, None] + half[:, None] * x[None, :]
    return nodes.ravel(), (half[:, None] * w[None, :]).ravel()


def _reflect(kvec: np.ndarray, E: np.ndarray, H: np.ndarray, relative_index: complex, eta1: float,
             normal_s: np.ndarray):
    """Plane waves (kvec (..., 3) with k_z < 0, E and H (2, ..., 3)) reflected by the flat interface
    z = 0 at ``relative_index`` n₂/n₁: (k_r, E_r, H_r). Every wave k goes to k_r = (k_x, k_y, −k_z):
    TE by r_s on E·ŝ, TM by r_p on H·ŝ (fresnel.py's r_p is the ratio of the magnetic amplitudes),
    ŝ = ẑ × k̂ / |ẑ × k̂| (``normal_s`` at normal incidence); a plane wave has H = k̂ × E / η₁."""
    khat = kvec / np.linalg.norm(kvec, axis=-1, keepdims=True)
    s_hat = np.cross([0.0, 0.0, 1.0], khat)
    norm = np.linalg.norm(s_hat, axis=-1, keepdims=True)
    s_hat = np.where(norm > 1e-12, s_hat / np.where(norm > 0, norm, 1.0), normal_s)
    r_s, r_p = fresnel_rs_rp(relative_index, -khat[..., 2])
    flip = np.array([1.0, 1.0, -1.0])
    kr_hat = khat * flip
    E_te = (r_s * np.sum(E * s_hat, axis=-1))[..., None] * s_hat
    H_tm = (r_p * np.sum(H * s_hat, axis=-1))[..., None] * s_hat
    return kvec * flip, E_te + eta1 * np.cross(H_tm, kr_hat), H_tm + np.cross(kr_hat, E_te) / eta1


LATTICE_SUM_BYTES = 64 * 2**20  # field values of one block of x columns in _lattice_sum
SERIES_TAIL = 1e-17  # last Jacobi–Anger coefficient kept, relative to the amplitudes


def _distinct_xy(points: np.ndarray) -> tuple:
    """The points' distinct x and y and each point's index into them: (ux, inv_x, uy, inv_y)."""
    ux, inv_x = np.unique(points[:, 0], return_inverse=True)
    uy, inv_y = np.unique(points[:, 1], return_inverse=True)
    return ux, inv_x, uy, inv_y


def _shifted(distinct: tuple, origin) -> tuple:
    """:func:`_distinct_xy` of the points less ``origin`` (µm; x and y shift, the indices stay)."""
    ux, inv_x, uy, inv_y = distinct
    return ux - origin[0], inv_x, uy - origin[1], inv_y


def _lattice_sum_applies(n_points: int, distinct: tuple) -> bool:
    """Whether ``n_points`` points with these distinct x and y (:func:`_distinct_xy`) take each
    (x, y) a few times at most (a mesh's quadrature points; not a volume grid)."""
    columns = len(distinct[0]) * len(distinct[2])
    return n_points / 4 <= columns <= 4 * n_points


def _series_terms(reach: float) -> int:
    """Jacobi–Anger terms for |(k_z − k̄) h| ≤ ``reach``: up to the first n > reach with |J_n| < SERIES_TAIL."""
    from scipy.special import jv

    terms = 1
    while reach > 0 and (terms <= reach or abs(jv(terms, reach)) >= SERIES_TAIL):
        terms += 1
    return terms


def _lattice_sum(pw: dict, amps: np.ndarray, offsets: np.ndarray, distinct: tuple) -> np.ndarray | None:
    """Σ_m amps_m e^{−j k_m·r} (N, 12) at points r = ``offsets`` (N, 3) with distinct x and y
    ``distinct`` (:func:`_distinct_xy` of the offsets), for waves on the
    (κx, κy) lattice of ``pw`` (``lattice``, ``kx_axis``, ``ky_axis``), with real k_z.

    The phase factorizes, e^{−jκx x} e^{−jκy y} e^{−jk_z z}, and over the points' height range
    z = c + h t (|t| ≤ 1) the last factor is e^{−jk_z c} e^{−jk̄ h t} times the Jacobi–Anger series
    Σ_n ε_n (−j)^n J_n((k_z − k̄) h) T_n(t) (ε_0 = 1, else 2), k̄ the middle of the waves' k_z (the
    point factor e^{−jk̄ h t} leaves the series only the spread of k_z: 9 terms instead of 27 for a
    2.5 µm waist at λ = 0.4 µm on 0.6 µm of relief), cut where J_n(max |k_z − k̄| h) <
    SERIES_TAIL (one term for points in a plane). Each term's sum over the wave lattice is two
    matrix products on the points' distinct x and y, instead of one complex exponential per
    point and wave; the distinct y are taken in passes that keep the partial sums within 4
    LATTICE_SUM_BYTES. None (use the direct sum) where the series would need as many terms as
    there are waves or one y alone would exceed that."""
    from scipy.special import jv

    ix, iy = pw["lattice"]
    kx, ky, kz = pw["kx_axis"], pw["ky_axis"], pw["kvec"][:, 2]
    ux, inv_x, uy, inv_y = distinct
    z0, z1 = float(offsets[:, 2].min()), float(offsets[:, 2].max())
    c, h = 0.5 * (z0 + z1), 0.5 * (z1 - z0)
    k_mid = 0.5 * (float(np.max(kz)) + float(np.min(kz)))
    spread = kz - k_mid
    terms = _series_terms(float(np.max(np.abs(spread))) * h)
    width = 12 * terms
    # distinct y per pass: the partial sums (nx, y's, 12·T) within 4 LATTICE_SUM_BYTES
    y_step = 4 * LATTICE_SUM_BYTES // (len(kx) * width * 16)
    if terms >= len(kz) or y_step < 1:
        return None
    n = np.arange(terms)
    series = np.where(n == 0, 1.0, 2.0) * (-1j) ** n * jv(n[None, :], h * spread[:, None])  # (M, T)
    lattice = np.zeros((len(kx), len(ky), 12, terms), dtype=complex)
    lattice[ix, iy] = (amps * np.exp(-1j * kz * c)[:, None])[:, :, None] * series[:, None, :]
    by_ky = lattice.transpose(1, 0, 2, 3).reshape(len(ky), -1)  # (ny, nx·12·T)
    ex = np.exp(-1j * np.outer(ux, kx))  # (Ux, nx)
    t = (offsets[:, 2] - c) / h if h else np.zeros(len(offsets))
    out = np.empty((len(offsets), 12), dtype=complex)
    y_order = np.argsort(inv_y, kind="stable")
    sorted_y = inv_y[y_order]
    for y0 in range(0, len(uy), y_step):
        y1 = min(len(uy), y0 + y_step)
        r0, r1 = np.searchsorted(sorted_y, [y0, y1])
        ey = np.exp(-1j * np.outer(uy[y0:y1], ky))  # (y's, ny)
        # over κy first: (y's, ny) @ (ny, nx·12·T) → per x wave number, these y's
        by_y = (ey @ by_ky).reshape(y1 - y0, len(kx), width).transpose(1, 0, 2).reshape(len(kx), -1)
        pass_rows = y_order[r0:r1]
        order = pass_rows[np.argsort(inv_x[pass_rows], kind="stable")]
        starts = np.searchsorted(inv_x[order], np.arange(len(ux) + 1))
        step = max(1, LATTICE_SUM_BYTES // ((y1 - y0) * width * 16))
        for x0 in range(0, len(ux), step):
            x1 = min(len(ux), x0 + step)
            rows = order[starts[x0] : starts[x1]]
            if len(rows) == 0:
                continue
            block = (ex[x0:x1] @ by_y).reshape(x1 - x0, y1 - y0, 12, terms)
            chebyshev = np.cos(np.arccos(np.clip(t[rows], -1.0, 1.0))[:, None] * n[None, :])  # T_n(t)
            out[rows] = np.einsum("pct,pt->pc", block[inv_x[rows] - x0, inv_y[rows] - y0], chebyshev)
            out[rows] *= np.exp(-1j * k_mid * h * t[rows])[:, None]
    return out


def make_beam(kind: str, wavelength_um: float, theta_i: float, phi_i: float, waist_um: float | None,
              *, exterior_index: float = 1.0, focus_um=(0.0, 0.0, 0.0), patch_size_um: float | None = None) -> Beam:
    """The beam named ``kind`` ("exact" | "paraxial" | "plane")."""
    common = dict(wavelength_um=wavelength_um, theta_i=theta_i, phi_i=phi_i,
                  exterior_index=exterior_index, focus_um=focus_um)
    if kind == "plane":
        return PlaneWave(**common)
    if waist_um is None:
        raise ValueError(f"illumination.waist_um is required for the {kind!r} beam")
    if kind == "paraxial":
        return ParaxialGaussianBeam(**common, waist_um=waist_um)
    if kind == "exact":
        if patch_size_um is None:
            raise ValueError("the exact beam needs patch_size_um (sets its spectral lattice)")
        return ExactGaussianBeam(**common, waist_um=waist_um, patch_size_um=patch_size_um)
    raise ValueError(f"illumination.beam must be one of {BEAMS}, got {kind!r}")


def scene_beam(scene, kind: str | None = None) -> Beam:
    """The beam that lights a surface scene in the full-wave solver: ``kind`` (default the scene's
    ``beam``) toward its (θ_i, φ_i), waist and exterior index, focused at its footprint centre on
    the phase-reference plane z = 0, its spectral lattice set by the patch size."""
    return make_beam(kind or scene.beam, scene.wavelength_um, scene.theta_i, scene.phi_i, scene.waist_um,
                     exterior_index=scene.exterior_index,
                     focus_um=(scene.footprint_centre_um[0], scene.footprint_centre_um[1], 0.0),
                     patch_size_um=scene.surface.size_um)


def steering_fields(beam: Beam, points) -> tuple[np.ndarray, np.ndarray]:
    """(E, H) of ``beam`` at ``points`` (..., 3), each (2 pol, 3, ...): the layout of a model's
    ``incident_fields`` (beams return (2, ..., 3))."""
    E, H = beam.fields(np.asarray(points, dtype=float))
    return np.moveaxis(E, -1, 1), np.moveaxis(H, -1, 1)


@dataclass(frozen=True)
class BeamWaves:
    """A surface scene's exact Gaussian beam as the approximate wave rungs' incident field (po,
    ws-v, wm with ``incidence = "beam"``): its plane waves of direction ``directions`` (M, 3) k̂_m
    and amplitudes ``amplitudes`` (M, 2, 3) (E per beam polarization s|p, |E| = 1 V/µm at the focus
    like the footprint), ``phases`` (M, 4): q_m = k k̂_m + k ω_i and φ_m = k k̂_m·f, so that wave m
    on node r relative to the rungs' transform phase e^{+jk ω_i·r} is e^{j(φ_m − q_m·r)};
    ``incident_power`` (2,) Φ_i per polarization (W), the full-wave solver's normalisation;
    ``axis`` (θ_i, φ_i) of the beam axis (radians)."""

    directions: np.ndarray
    amplitudes: np.ndarray
    phases: np.ndarray
    incident_power: np.ndarray
    axis: tuple[float, float]

    @classmethod
    def of(cls, scene) -> "BeamWaves":
        """The plane waves of the scene's exact beam (focus at the footprint centre on the phase
        reference plane, as the full-wave solver's) whose amplitude is at least
        :data:`BEAM_TAIL` of the largest. The exact beam whatever the scene's ``beam``: a paraxial
        Gaussian is not a sum of plane waves (the full-wave solver's default is the exact one)."""
        beam = scene_beam(scene, "exact")
        waves = beam.plane_waves
        size = np.abs(waves["E"]).max(axis=(0, 2))
        keep = size >= BEAM_TAIL * size.max()
        kvec = waves["kvec"][keep]
        k = float(np.linalg.norm(kvec[0]))
        omega_i, _, _ = incident_basis(scene.theta_i, scene.phi_i)
        phases = np.concatenate([kvec + k * omega_i, (kvec @ np.asarray(beam.focus_um, dtype=float))[:, None]], axis=1)
        return cls(kvec / k, np.ascontiguousarray(np.moveaxis(waves["E"][:, keep], 0, 1)), phases,
                   np.asarray(beam.incident_power(), dtype=float), (float(scene.theta_i), float(scene.phi_i)))

    @staticmethod
    def count(scene) -> int:
        """About how many plane waves :meth:`of` keeps for ``scene`` (the beam's lattice points of
        Gaussian weight ≥ :data:`BEAM_TAIL` inside the light cone), counted in a fraction of a
        millisecond without evaluating the beam: for estimates."""
        return scene_beam(scene, "exact").lattice_size(BEAM_TAIL)

    def table(self) -> np.ndarray:
        """(M, 7) rows k̂_m, q_m, φ_m: what the OpenCL kernels read (kernels/wb_beam_waves.h)."""
        return np.concatenate([self.directions, self.phases], axis=1)

    def power(self) -> np.ndarray:
        """(M, 2) |E_m|² per beam polarization."""
        return np.sum(np.abs(self.amplitudes) ** 2, axis=-1)

    def scalar_amplitudes(self) -> np.ndarray:
        """(M, 2) amplitudes of the scalar beam the scalar rungs are lit by: per polarization,
        each wave's |E_m| with the phase of its component along the beam's own ê_s or ê_p (its
        flux is the vector beam's, ``incident_power``)."""
        _, e_s, e_p = incident_basis(*self.axis)
        along = np.einsum("mpc,pc->mp", self.amplitudes, np.stack([e_s, e_p]))
        return np.linalg.norm(self.amplitudes, axis=-1) * np.exp(1j * np.angle(along))

