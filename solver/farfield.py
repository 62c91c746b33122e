"""The FarField seam: what every wave model returns, and the BRDF computed from it once.

Conventions (ARCHITECTURE.md): lengths in µm, time dependence e^{+jωt}. The far field at
distance r in direction ω_o is E(ω_o)·e^{-jk₁r}/r; a FarField stores the amplitude E (volts) and
H (amperes) with that factor removed, for the two incident polarizations, on the
projected-hemisphere grid. Incident field amplitudes are normalised by each model (|E₀| = 1 V/µm
for plane-wave-like footprints); only ratios enter the BRDF.

Projected hemisphere: pixel (i, j) of an ``res × res`` image has direction cosines
u = 2(i+½)/res − 1 (x, rows) and v = 2(j+½)/res − 1 (y, columns), μ_o = √(1−u²−v²).

BRDF (sr⁻¹): f = |½ Re(E × H*)| / (Φ_i μ_o), per polarization with its own Φ_i;
unpolarized = the mean of the two. Albedo = Σ f Δu Δv over the disk.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

__all__ = [
    "ETA0",
    "POLARIZATIONS",
    "POLARIZATION_MODES",
    "BRDFResult",
    "FarField",
    "HemisphereGrid",
    "IntensityResult",
    "albedo",
    "combine_polarizations",
    "direction",
    "transverse_basis",
]

ETA0 = 376.730313412  # free-space impedance, ohm
POLARIZATIONS = ("s", "p")  # index 0: E ⟂ plane of incidence (TE); 1: E in it (TM)
POLARIZATION_MODES = ("unpolarized", *POLARIZATIONS)  # what a study computes: the mean of s and p, or one


def direction(theta: float | np.ndarray, phi: float | np.ndarray) -> np.ndarray:
    """Unit vector (..., 3) for polar angle θ from +z and azimuth φ (radians)."""
    theta = np.asarray(theta, dtype=float)
    phi = np.asarray(phi, dtype=float)
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=-1)


def transverse_basis(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(θ̂, φ̂) of the directions with projected coordinates (u, v), shape (..., 3) each.

    At the pole (u = v = 0) φ = 0 is used, so θ̂ = x̂ and φ̂ = ŷ.
    """
    rho = np.hypot(u, v)
    safe = np.where(rho > 0, rho, 1.0)
    cphi = np.where(rho > 0, u / safe, 1.0)
    sphi = np.where(rho > 0, v / safe, 0.0)
    mu = np.sqrt(np.clip(1.0 - rho**2, 0.0, None))
    theta_hat = np.stack([mu * cphi, mu * sphi, -rho], axis=-1)
    phi_hat = np.stack([-sphi, cphi, np.zeros_like(rho)], axis=-1)
    return theta_hat, phi_hat


@dataclass(frozen=True)
class HemisphereGrid:
    """The projected-hemisphere output grid of side ``resolution``."""

    resolution: int

    def __post_init__(self):
        if int(self.resolution) != self.resolution or self.resolution < 2:
            raise ValueError(f"output resolution must be an integer >= 2, got {self.resolution!r}")

    @cached_property
    def u(self) -> np.ndarray:
        """Pixel-centre direction cosines along one axis, shape (res,)."""
        return 2.0 * (np.arange(self.resolution) + 0.5) / self.resolution - 1.0

    @property
    def pixel_area(self) -> float:
        """Δu·Δv of one pixel."""
        return (2.0 / self.resolution) ** 2

    @cached_property
    def uv(self) -> tuple[np.ndarray, np.ndarray]:
        """(U, V) arrays of shape (res, res): U varies along rows (x), V along columns (y)."""
        return np.meshgrid(self.u, self.u, indexing="ij")

    @cached_property
    def inside(self) -> np.ndarray:
        """Boolean mask of pixels whose centre lies inside the unit disk."""
        U, V = self.uv
        return U**2 + V**2 < 1.0

    @cached_property
    def mu(self) -> np.ndarray:
        """cos θ_o per pixel (0 outside the disk)."""
        U, V = self.uv
        return np.sqrt(np.clip(1.0 - U**2 - V**2, 0.0, None))

    @cached_property
    def directions(self) -> np.ndarray:
        """Unit vectors ω_o, shape (res, res, 3) (z = 0 outside the disk)."""
        U, V = self.uv
        return np.stack([U, V, self.mu], axis=-1)


class BRDFResult:
    """What every surface model returns for one (wavelength, incident direction): the radiant
    intensity per polarization on the projected-hemisphere grid and the incident power Φ_i.

    BRDF normalization, albedo, polarization averaging and storage are written once against this
    type. :class:`FarField` (coherent models: complex E, H) and :class:`IntensityResult`
    (intensity-only models such as geometric optics) are its two kinds.
    """

    grid: HemisphereGrid
    incident_power: np.ndarray
    diagnostics: dict

    def intensity(self) -> np.ndarray:  # pragma: no cover - abstract
        """Radiant intensity |½Re(E×H*)| per polarization (W/sr), shape (2, res, res)."""
        raise NotImplementedError

    def brdf(self) -> np.ndarray:
        """BRDF per polarization (sr⁻¹), shape (2, res, res), NaN outside the unit disk."""
        mu = self.grid.mu
        inside = self.grid.inside
        out = np.full((2,) + mu.shape, np.nan)
        inten = self.intensity()
        for p in range(2):
            out[p][inside] = inten[p][inside] / (self.incident_power[p] * mu[inside])
        return out


def _check_incident_power(power) -> np.ndarray:
    power = np.asarray(power, dtype=float).reshape(2)
    if not np.all(power > 0):
        raise ValueError(f"incident power must be positive, got {power}")
    return power


@dataclass
class IntensityResult(BRDFResult):
    """Radiant intensity of an intensity-only model (no phase: cannot be steered).

    intensity: (2, res, res) per polarization s|p, W/sr with the model's Φ_i normalisation (0
    outside the disk); incident_power: Φ_i per polarization, shape (2,).
    """

    grid: HemisphereGrid
    wavelength_um: float
    theta_i: float
    phi_i: float
    radiant_intensity: np.ndarray
    incident_power: np.ndarray
    diagnostics: dict = field(default_factory=dict)

    def __post_init__(self):
        res = self.grid.resolution
        if self.radiant_intensity.shape != (2, res, res):
            raise ValueError(f"IntensityResult.radiant_intensity must have shape (2, {res}, {res}), "
                             f"got {self.radiant_intensity.shape}")
        self.incident_power = _check_incident_power(self.incident_power)

    def intensity(self) -> np.ndarray:
        return self.radiant_intensity


@dataclass
class FarField(BRDFResult):
    """Far-field amplitudes of one simulation (one wavelength, one incident direction).

    E, H: complex arrays (2, 3, res, res): [polarization s|p, Cartesian component, u, v].
    ``H = None`` means a transverse plane-wave far field, H = (n₁/η₀) ω_o × E (true for any
    radiated field in a lossless exterior); BRDFs then use |½Re(E×H*)| = n₁|E|²/(2η₀).
    incident_power: Φ_i per polarization (W, with the model's |E₀| normalisation), shape (2,).
    theta_i, phi_i: direction toward the light (radians); the s and p fields answer E ∥ ŝ_i and
    E ∥ −p̂_i of that direction (solver/polarimetry.py ``incident_frame``).
    """

    grid: HemisphereGrid
    wavelength_um: float
    exterior_index: float
    theta_i: float
    phi_i: float
    E: np.ndarray
    incident_power: np.ndarray
    H: np.ndarray | None = None
    diagnostics: dict = field(default_factory=dict)

    def __post_init__(self):
        res = self.grid.resolution
        if self.E.shape != (2, 3, res, res):
            raise ValueError(f"FarField.E must have shape (2, 3, {res}, {res}), got {self.E.shape}")
        if self.H is not None and self.H.shape != self.E.shape:
            raise ValueError("FarField.H must have the shape of E")
        self.incident_power = _check_incident_power(self.incident_power)

    @property
    def wavenumber(self) -> float:
        """k₁ = 2π n₁/λ in µm⁻¹."""
        return 2.0 * np.pi * self.exterior_index / self.wavelength_um

    def intensity(self) -> np.ndarray:
        """Radiant intensity |½Re(E×H*)| per polarization, shape (2, res, res)."""
        if self.H is None:
            return self.exterior_index / (2.0 * ETA0) * np.sum(np.abs(self.E) ** 2, axis=1)
        S = 0.5 * np.real(np.cross(self.E, np.conj(self.H), axis=1))
        return np.sqrt(np.sum(S**2, axis=1))

    def translated(self, offset_um: np.ndarray) -> "FarField":
        """The same field with its phase reference moved by ``offset_um`` (x, y, z).

        A source shifted by p radiates E(ω_o)·e^{+jk₁ p·ω_o} (far-field kernel e^{+jk₁ ω_o·r'}).
        """
        phase = np.exp(1j * self.wavenumber * (self.grid.directions @ np.asarray(offset_um)))
        phase = np.where(self.grid.inside, phase, 0.0)
        return FarField(
            grid=self.grid,
            wavelength_um=self.wavelength_um,
            exterior_index=self.exterior_index,
            theta_i=self.theta_i,
            phi_i=self.phi_i,
            E=self.E * phase,
            H=None if self.H is None else self.H * phase,
            incident_power=self.incident_power.copy(),
            diagnostics=dict(self.diagnostics),
        )


def combine_polarizations(brdf_sp: np.ndarray, polarization: str) -> np.ndarray:
    """Select "s", "p", or average them ("unpolarized") from a (2, ...) BRDF array."""
    if polarization == "unpolarized":
        return 0.5 * (brdf_sp[0] + brdf_sp[1])
    if polarization in POLARIZATIONS:
        return brdf_sp[POLARIZATIONS.index(polarization)]
    raise ValueError(f"polarization must be one of {POLARIZATION_MODES}, got {polarization!r}")


def albedo(brdf: np.ndarray, grid: HemisphereGrid) -> np.ndarray:
    """Σ f Δu Δv over the disk; ``brdf`` has shape (..., res, res) with NaN outside."""
    return np.nansum(brdf, axis=(-2, -1)) * grid.pixel_area
