"""Fresnel amplitude reflection coefficients for e^{+jωt} and complex index n − jκ.

For relative index η = n₂/n₁ and cos θ = c > 0 of the incident angle,
t = √(η² − 1 + c²) (principal root: Im t ≤ 0, the transmitted wave decays into medium 2),
r_s = (c − t)/(c + t), r_p = (η²c − t)/(η²c + t). With this sign convention a perfect
conductor gives r_s → −1, r_p → +1, and |r| ≤ 1 for any κ ≥ 0.
"""

from __future__ import annotations

import numpy as np

__all__ = ["fresnel_rs_rp", "fresnel_reflectance"]


def fresnel_rs_rp(eta, cos_theta) -> tuple[np.ndarray, np.ndarray]:
    """Amplitude coefficients (r_s, r_p) for relative index ``eta`` at ``cos_theta`` ∈ [0, 1]."""
    eta = np.asarray(eta, dtype=complex)
    c = np.clip(np.asarray(cos_theta, dtype=float), 0.0, 1.0)
    eta2 = eta * eta
    t = np.sqrt(eta2 - 1.0 + c * c)
    r_s = (c - t) / (c + t)
    r_p = (eta2 * c - t) / (eta2 * c + t)
    return r_s, r_p


def fresnel_reflectance(eta, cos_theta) -> tuple[np.ndarray, np.ndarray]:
    """Power reflectances (|r_s|², |r_p|²)."""
    r_s, r_p = fresnel_rs_rp(eta, cos_theta)
    return np.abs(r_s) ** 2, np.abs(r_p) ** 2
