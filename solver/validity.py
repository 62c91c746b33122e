"""Validity checks of the approximate rungs: situations where a rung's figure is known to be off
by more than its tolerance, said out loud (a :class:`ValidityWarning` through :func:`warnings.warn`,
which the batch layer stores in the dataset's diagnostics, and a figure in the result's
diagnostics). Found by the extremes suite (tests/extremes.py, docs/extremes.md).

* :func:`check_waist` — a footprint of waist w spreads over λ₁/(πw) in angle, across which the
  rungs' obliquity and Fresnel factors vary: the flat albedo is off by ≈ 0.3 (λ₁/(πw))²/μ_i²
  (measured on flat aluminium at 0°: +3.1% for w = 0.38 µm, +0.18% for w = 1.5 µm at λ = 0.4 µm,
  Kirchhoff and Stam alike; OHS −2.9%, PO +2.7% at w = 0.15 µm). GHS renormalizes it away.
* :func:`check_evanescent_loss` — OHS keeps only the part of the reflected angular spectrum
  inside the unit disk (GHS renormalizes it): on rough patches the rest is simply missing.
"""

from __future__ import annotations

import warnings

import numpy as np


__all__ = ["EVANESCENT_LOSS", "SPREAD_ERROR", "SPREAD_COEFFICIENT", "ValidityWarning", "check_evanescent_loss",
           "check_waist"]

EVANESCENT_LOSS = 0.01  # OHS: warn when this share of the reflected spectrum is dropped
SPREAD_COEFFICIENT = 0.3  # albedo error ≈ this × (λ₁/(πw))²/μ_i² (fitted on flat aluminium, see above)
SPREAD_ERROR = 0.005  # warn above this predicted relative albedo error (the rungs' flat tolerance)


class ValidityWarning(UserWarning):
    """An approximate rung is outside the range where its figure holds to its tolerance."""


def _append(diagnostics: dict, message: str) -> None:
    recorded = diagnostics.get("warnings")
    line = f"ValidityWarning: {message}"
    if isinstance(recorded, list):
        recorded.append(line)
    else:
        diagnostics["warnings"] = "; ".join(w for w in (recorded or "", line) if w)


def check_evanescent_loss(fraction: float, diagnostics: dict, theta_i: float) -> None:
    """Warn when OHS drops more than EVANESCENT_LOSS of the reflected angular spectrum."""
    if np.isfinite(fraction) and fraction > EVANESCENT_LOSS:
        message = (f"ohs: {fraction:.3g} of the reflected angular spectrum lies beyond the horizon at θ_i = "
                   f"{np.rad2deg(theta_i):.4g}° and is dropped: that share of R(θ_i) is missing from the albedo "
                   "(rough patch; ghs renormalizes it)")
        _append(diagnostics, message)
        warnings.warn(message, ValidityWarning, stacklevel=3)


def check_waist(scene, diagnostics: dict, model: str) -> None:
    """Warn when the footprint's angular spread makes the albedo err by more than SPREAD_ERROR
    (``diagnostics["waist_spread_error"]``: the predicted relative error)."""
    if scene.waist_um is None:
        return
    lambda1 = scene.wavelength_um / scene.exterior_index
    mu_i = max(float(np.cos(scene.theta_i)), 1e-12)
    error = SPREAD_COEFFICIENT * (lambda1 / (np.pi * scene.waist_um)) ** 2 / mu_i**2
    diagnostics["waist_spread_error"] = float(error)
    if error > SPREAD_ERROR:
        message = (f"{model}: the footprint of waist {scene.waist_um:g} µm spreads over λ₁/(πw) = "
                   f"{lambda1 / (np.pi * scene.waist_um):.3g} rad at θ_i = {np.rad2deg(scene.theta_i):.4g}°, so the "
                   f"albedo is off by about {error:.2g} (relative; obliquity and Fresnel vary across the spread): use a "
                   f"waist ≥ {lambda1 / np.pi * np.sqrt(SPREAD_COEFFICIENT / SPREAD_ERROR) / mu_i:.3g} µm, or ghs")
        _append(diagnostics, message)
        warnings.warn(message, ValidityWarning, stacklevel=3)
