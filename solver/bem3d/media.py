"""The two media of the PMCHWT problem and the coefficients of the scaled system (bem3d.md §4).

Region 1 (exterior, above the surface) has a real index n₁; region 2 (the material) has
n₂ = n − jκ with κ ≥ 0 meaning loss (time dependence e^{+jωt}, G = e^{−jkR}/(4πR)). Wavenumbers
k_i = k₀ n_i in µm⁻¹, so a lossy k₂ = k₀(n − jκ) has Im k₂ = −k₀κ ≤ 0 and e^{−jk₂R} decays.

Scaled PMCHWT blocks for one basis pair (M̃ = M/η₀, H rows × η₀), from the per-medium
integrals L_vec,i, L_div,i, K_i (elements.py)::

    Z_EE = Σ_i [ jη₀k₀ L_vec,i − jη₀/(k₀ n_i²) L_div,i ]
    Z_MM = Σ_i [ −jη₀k₀ n_i² L_vec,i + jη₀/k₀ L_div,i ]      (= −Σ_i n_i² Z_EE,i)
    Z_EM = Z_ME = η₀ Σ_i K_i
"""

from __future__ import annotations

import cmath
import math
from dataclasses import dataclass

import numpy as np

from wavebrdf.solver.farfield import ETA0

__all__ = ["Media"]


@dataclass(frozen=True)
class Media:
    """Wavelength (µm, vacuum), exterior index n₁ (real) and material index n₂ = n − jκ."""

    wavelength_um: float
    index: complex
    exterior_index: float = 1.0

    def __post_init__(self):
        if not (math.isfinite(self.wavelength_um) and self.wavelength_um > 0):
            raise ValueError(f"wavelength_um must be a positive number, got {self.wavelength_um!r}")
        n2 = complex(self.index)
        if not (cmath.isfinite(n2) and n2.real > 0):
            raise ValueError(f"index must be n - j*kappa with n > 0, got {self.index!r}")
        if n2.imag > 0:
            raise ValueError(
                f"index = {n2!r} has a positive imaginary part: with the e^(+jwt) convention the "
                "index is n - j*kappa and kappa >= 0 is loss (a positive imaginary part is gain)"
            )
        n1 = self.exterior_index
        if not (isinstance(n1, (int, float, np.floating)) and math.isfinite(n1) and n1 > 0):
            raise ValueError(f"exterior_index must be a positive real number, got {n1!r}")
        object.__setattr__(self, "index", n2)
        object.__setattr__(self, "exterior_index", float(n1))

    @property
    def k0(self) -> float:
        """Vacuum wavenumber 2π/λ (µm⁻¹)."""
        return 2.0 * math.pi / self.wavelength_um

    @property
    def indices(self) -> tuple[complex, complex]:
        """(n₁, n₂)."""
        return complex(self.exterior_index), self.index

    @property
    def wavenumbers(self) -> tuple[complex, complex]:
        """(k₁, k₂) = k₀ (n₁, n₂) in µm⁻¹."""
        return tuple(self.k0 * n for n in self.indices)

    @property
    def kappa(self) -> float:
        return -self.index.imag

    def pmchwt_coefficients(self) -> dict[str, np.ndarray]:
        """Per-medium weights of L_vec and L_div in Z_EE and Z_MM, and of K in Z_EM.

        Returns arrays of shape (2,) (media 1, 2): ``ee_vec``, ``ee_div``, ``mm_vec``, ``mm_div``
        and the scalar ``em`` (= η₀).
        """
        k0 = self.k0
        n2 = np.array(self.indices) ** 2
        return {
            "ee_vec": np.full(2, 1j * ETA0 * k0),
            "ee_div": -1j * ETA0 / (k0 * n2),
            "mm_vec": -1j * ETA0 * k0 * n2,
            "mm_div": np.full(2, 1j * ETA0 / k0),
            "em": ETA0,
        }
