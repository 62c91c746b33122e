"""The result of a fiber scattering computation (BEM or Mie) for one (λ, θ_i).

Units: µm, radians; cross sections per unit length normalised by S₀ cosθ_i (fiber.md §6).
Arrays carry a leading polarization axis: 0 = "parallel" (BH case I, E in the plane of the
axis and ω_i), 1 = "perpendicular" (BH case II).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wavebrdf.solver.fiber.incidence import POLARIZATIONS

__all__ = ["ScatteringResult", "power_balance_error"]


def power_balance_error(C_ext, C_sca, C_abs) -> np.ndarray:
    """|C_ext − C_sca − C_abs| / |C_ext|: how far a fiber solve is from conserving power."""
    return np.abs(np.asarray(C_ext) - C_sca - C_abs) / np.abs(C_ext)


@dataclass
class ScatteringResult:
    """Angular scattering and cross sections for one (λ, θ_i) and several φ_i.

    Arrays carry a leading polarization axis ("parallel", "perpendicular").
    """

    wavelength_um: float
    index: complex
    theta_i: float  # radians
    phi_i: np.ndarray  # (P,) radians
    phi_r: np.ndarray  # (R,) radians: point samples or bin centres
    dCs_dphi: np.ndarray  # (2, P, R) µm/rad
    C_ext: np.ndarray  # (2, P) µm
    C_sca: np.ndarray  # (2, P) µm
    C_abs: np.ndarray  # (2, P) µm
    binned: bool = False  # dCs_dphi holds box averages over bins centred on phi_r
    timings: dict = field(default_factory=dict)
    polarizations: tuple = POLARIZATIONS

    @property
    def power_balance_error(self) -> np.ndarray:
        """|C_ext - C_sca - C_abs| / C_ext, shape (2, P)."""
        return power_balance_error(self.C_ext, self.C_sca, self.C_abs)

    @property
    def dCs_dphi_unpolarized(self) -> np.ndarray:
        return self.dCs_dphi.mean(axis=0)

    @property
    def C_ext_unpolarized(self) -> np.ndarray:
        return self.C_ext.mean(axis=0)

    @property
    def N_wave(self) -> np.ndarray:
        """Unpolarized azimuthal scattering function (dC_s/dφ)/C_ext, shape (P, R), 1/rad."""
        return self.dCs_dphi_unpolarized / self.C_ext_unpolarized[:, None]
