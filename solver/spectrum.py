"""Spectra → CIE 1931 XYZ → sRGB.

Colour matching functions: the multi-lobe analytic fit of Wyman, Sloan & Shirley, "Simple
Analytic Approximations to the CIE XYZ Color Matching Functions", JCGT 2(2), 2013 (within a few
percent of the tabulated 2° observer). Illuminant: equal energy (E), chromatically adapted to
the sRGB white (D65) with the Bradford transform, so a spectrally flat reflectance renders grey.

A BRDF known at a few wavelengths is treated as piecewise linear in λ between the samples and
constant beyond the first/last one (over 380–780 nm).
"""

from __future__ import annotations

import numpy as np

__all__ = ["VISIBLE_UM", "cmf_xyz", "outside_visible", "spectral_weights", "xyz_to_linear_srgb", "srgb_encode"]

VISIBLE_UM = (0.38, 0.78)  # the colour matching functions' range (µm)

_LOBES = {
    "x": [(1.056, 599.8, 37.9, 31.0), (0.362, 442.0, 16.0, 26.7), (-0.065, 501.1, 20.4, 26.2)],
    "y": [(0.821, 568.8, 46.9, 40.5), (0.286, 530.9, 16.3, 31.1)],
    "z": [(1.217, 437.0, 11.8, 36.0), (0.681, 459.0, 26.0, 13.8)],
}

_XYZ_TO_SRGB = np.array(
    [[3.2404542, -1.5371385, -0.4985314], [-0.9692660, 1.8760108, 0.0415560], [0.0556434, -0.2040259, 1.0572252]]
)
_BRADFORD = np.array([[0.8951, 0.2664, -0.1614], [-0.7502, 1.7135, 0.0367], [0.0389, -0.0685, 1.0296]])
_WHITE_E = np.array([1.0, 1.0, 1.0])
_WHITE_D65 = np.array([0.95047, 1.0, 1.08883])


def cmf_xyz(wavelength_nm) -> np.ndarray:
    """x̄, ȳ, z̄ at wavelengths in nm, shape (3, ...)."""
    lam = np.asarray(wavelength_nm, dtype=float)
    out = []
    for name in "xyz":
        total = np.zeros_like(lam)
        for amp, mu, s1, s2 in _LOBES[name]:
            sigma = np.where(lam < mu, s1, s2)
            total = total + amp * np.exp(-0.5 * ((lam - mu) / sigma) ** 2)
        out.append(total)
    return np.array(out)


def outside_visible(wavelengths_um) -> str | None:
    """What colour made of ``wavelengths_um`` means when none of them lies in the visible
    (:data:`VISIBLE_UM`): the BRDF at the nearest one carried flat across it (a grey), or, with
    samples on both sides, interpolated linearly across it; None when one lies in it."""
    lams = np.asarray(wavelengths_um, dtype=float).ravel()
    if lams.size == 0 or np.any((lams >= VISIBLE_UM[0]) & (lams <= VISIBLE_UM[1])):
        return None
    below, above = lams[lams < VISIBLE_UM[0]], lams[lams > VISIBLE_UM[1]]
    span = f"{lams.min():g}–{lams.max():g} µm" if lams.size > 1 else f"{lams[0]:g} µm"
    if below.size and above.size:
        colour = (f"its colour is the BRDF interpolated linearly across the visible between {below.max():g} and "
                  f"{above.min():g} µm")
    else:
        colour = (f"its colour is the BRDF at {(above.min() if above.size else below.max()):g} µm carried flat across "
                  "the visible, a grey")
    return (f"no wavelength of the data ({span}) lies in the visible ({VISIBLE_UM[0]:g}–{VISIBLE_UM[1]:g} µm): "
            f"{colour}, not a measured colour")


def spectral_weights(wavelengths_um) -> np.ndarray:
    """Matrix W (3, n) with XYZ = W @ values for a spectrum sampled at ``wavelengths_um``.

    Normalised so that a flat spectrum of 1 has Y = 1.
    """
    lam_s = np.sort(np.asarray(wavelengths_um, dtype=float)) * 1000.0
    order = np.argsort(np.asarray(wavelengths_um, dtype=float))
    fine = np.linspace(380.0, 780.0, 2001)
    cmf = cmf_xyz(fine)
    n = lam_s.size
    hats = np.empty((n, fine.size))
    for i in range(n):
        unit = np.zeros(n)
        unit[i] = 1.0
        hats[i] = np.interp(fine, lam_s, unit) if n > 1 else 1.0
    dl = fine[1] - fine[0]
    weights_sorted = cmf @ hats.T * dl
    norm = np.sum(cmf[1]) * dl
    weights = np.empty_like(weights_sorted)
    weights[:, order] = weights_sorted / norm
    return weights


def xyz_to_linear_srgb(xyz: np.ndarray) -> np.ndarray:
    """XYZ (illuminant E, last axis = 3) → linear sRGB via Bradford adaptation to D65."""
    cone_e = _BRADFORD @ _WHITE_E
    cone_d65 = _BRADFORD @ _WHITE_D65
    adapt = np.linalg.inv(_BRADFORD) @ np.diag(cone_d65 / cone_e) @ _BRADFORD
    return xyz @ (_XYZ_TO_SRGB @ adapt).T


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """sRGB transfer function on values clipped to [0, 1]."""
    c = np.clip(linear, 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1 / 2.4) - 0.055)
