"""Error metrics between BRDF slices on the projected-hemisphere grid (approx.md §6).

Every function takes BRDFs f (sr⁻¹) of one incident direction on a :class:`HemisphereGrid`:
arrays of shape (res, res) (or (..., res, res), reduced over the last two axes), NaN or anything
outside the unit disk ignored. Pixels are bins of equal projected solid angle d²u = μ_o dω, so
∫ f d²u is the albedo and every integral below is a plain sum times ``grid.pixel_area``.

* :func:`misplaced_energy` — E₁ = ½∫|f_a − f_b| d²u, a fraction of the incident power in [0, 1]
  (the primary metric: robust to delta-like peaks);
* :func:`relative_l2` — ‖f_a − f_b‖ / ‖f_b‖ in L²(d²u), over the lobe of ``f_b`` by default
  (:func:`lobe_mask`), or over any mask;
* :func:`log_error` — median |log₁₀(f_a+ε) − log₁₀(f_b+ε)| where f_b > ε (dynamic range);
* :func:`peak_direction` / :func:`angular_distance_deg` — sub-pixel centroid of the BRDF's peak and the angle
  between two directions;
* :func:`cone_fraction` — the share of the reflected power within a cone around a direction
  (e.g. the retroreflected fraction around ω_i);
* :func:`blur` — a Gaussian blur on the disk (mask-aware), to compare speckled slices at a common
  resolution.
"""

from __future__ import annotations

import numpy as np
import scipy.ndimage

from wavebrdf.solver.farfield import HemisphereGrid

__all__ = [
    "LOBE_FRACTION",
    "angular_distance_deg",
    "blur",
    "cone_fraction",
    "direction_to_u",
    "lobe_mask",
    "log_error",
    "misplaced_energy",
    "peak_direction",
    "relative_l2",
    "speckle_errors",
    "speckle_sigma_u",
    "worst_speckle_error",
]

LOBE_FRACTION = 1e-3  # the lobe: pixels whose radiance f·μ_o exceeds this fraction of the peak


def _inside(f: np.ndarray, grid: HemisphereGrid) -> np.ndarray:
    """``f`` with 0 outside the disk and NaN → 0 (shape checked against the grid)."""
    f = np.asarray(f, dtype=float)
    if f.shape[-2:] != (grid.resolution, grid.resolution):
        raise ValueError(f"BRDF shape {f.shape} does not match the {grid.resolution}² grid")
    return np.where(grid.inside, np.nan_to_num(f, nan=0.0), 0.0)


def direction_to_u(theta: float, phi: float) -> np.ndarray:
    """Projected coordinates u = (sin θ cos φ, sin θ sin φ) of a direction (radians)."""
    return np.sin(theta) * np.array([np.cos(phi), np.sin(phi)])


def lobe_mask(f: np.ndarray, grid: HemisphereGrid, fraction: float = LOBE_FRACTION) -> np.ndarray:
    """Pixels of the lobe of ``f`` (res, res): radiance f·μ_o ≥ ``fraction`` × its maximum."""
    radiance = _inside(f, grid) * grid.mu
    peak = radiance.max()
    if not peak > 0:
        raise ValueError("the BRDF is zero everywhere: no lobe")
    return grid.inside & (radiance >= fraction * peak)


def misplaced_energy(f_a: np.ndarray, f_b: np.ndarray, grid: HemisphereGrid) -> np.ndarray:
    """E₁ = ½ ∫ |f_a − f_b| d²u (fraction of the incident power)."""
    return 0.5 * np.sum(np.abs(_inside(f_a, grid) - _inside(f_b, grid)), axis=(-2, -1)) * grid.pixel_area


def relative_l2(f_a: np.ndarray, f_b: np.ndarray, grid: HemisphereGrid, mask: np.ndarray | None = None) -> np.ndarray:
    """‖f_a − f_b‖ / ‖f_b‖ in L²(d²u) over ``mask`` (default: the lobe of ``f_b``, or of the
    polarization average when the arrays carry a leading axis)."""
    a, b = _inside(f_a, grid), _inside(f_b, grid)
    if mask is None:
        mask = lobe_mask(b.reshape((-1,) + b.shape[-2:]).mean(axis=0), grid)
    num = np.sqrt(np.sum(np.where(mask, (a - b) ** 2, 0.0), axis=(-2, -1)))
    den = np.sqrt(np.sum(np.where(mask, b**2, 0.0), axis=(-2, -1)))
    return num / den


def log_error(f_a: np.ndarray, f_b: np.ndarray, grid: HemisphereGrid, floor: float | None = None) -> float:
    """Median |log₁₀(f_a + ε) − log₁₀(f_b + ε)| over pixels with f_b > ε (ε default: 1e-6 × max f_b)."""
    a, b = _inside(f_a, grid), _inside(f_b, grid)
    eps = 1e-6 * b.max() if floor is None else floor
    keep = grid.inside & (b > eps)
    return float(np.median(np.abs(np.log10(np.clip(a[keep], 0, None) + eps) - np.log10(b[keep] + eps))))


def peak_direction(f: np.ndarray, grid: HemisphereGrid, radius_px: int = 3) -> np.ndarray:
    """Sub-pixel centroid u of f within ``radius_px`` pixels of its maximum."""
    f = _inside(f, grid)
    i, j = np.unravel_index(np.argmax(f), f.shape)
    sl = (slice(max(i - radius_px, 0), i + radius_px + 1), slice(max(j - radius_px, 0), j + radius_px + 1))
    w = f[sl]
    U, V = grid.uv
    return np.array([np.sum(w * U[sl]), np.sum(w * V[sl])]) / np.sum(w)


def _unit(u: np.ndarray) -> np.ndarray:
    u = np.asarray(u, dtype=float)
    return np.concatenate([u, [np.sqrt(max(0.0, 1.0 - u @ u))]])


def angular_distance_deg(u_a: np.ndarray, u_b: np.ndarray) -> float:
    """Angle (degrees) between the upper-hemisphere directions with projections u_a, u_b."""
    return float(np.rad2deg(np.arccos(np.clip(_unit(u_a) @ _unit(u_b), -1.0, 1.0))))


def cone_fraction(f: np.ndarray, grid: HemisphereGrid, theta: float, phi: float, half_angle_deg: float) -> float:
    """Share of the reflected power ∫ f d²u that leaves within ``half_angle_deg`` of (θ, φ)
    (radians): e.g. the retroreflected fraction with (θ, φ) = ω_i."""
    f = _inside(f, grid)
    axis = _unit(direction_to_u(theta, phi))
    cos = grid.directions @ axis
    inside_cone = grid.inside & (cos >= np.cos(np.deg2rad(half_angle_deg)))
    total = f.sum()
    if not total > 0:
        raise ValueError("the BRDF reflects nothing: no fraction to take")
    return float(f[inside_cone].sum() / total)


def blur(f: np.ndarray, grid: HemisphereGrid, sigma_u: float) -> np.ndarray:
    """Gaussian blur of width ``sigma_u`` (in u units) within the disk, normalized by the blurred
    disk mask so the rim is not darkened; NaN outside the disk as in ``BRDFResult.brdf``."""
    sigma_px = sigma_u / (2.0 / grid.resolution)
    f = _inside(f, grid)
    axes = tuple(range(f.ndim - 2))
    sigma = (0,) * len(axes) + (sigma_px, sigma_px)
    weight = scipy.ndimage.gaussian_filter(grid.inside.astype(float), sigma_px, mode="constant")
    out = scipy.ndimage.gaussian_filter(f, sigma, mode="constant") / np.where(grid.inside, weight, 1.0)
    return np.where(grid.inside, out, np.nan)


def speckle_sigma_u(wavelength_um: float, waist_um: float | None, grid: HemisphereGrid,
                    exterior_index: float = 1.0) -> float:
    """Blur width (u units) of the speckle-averaged metrics: the footprint's angular spread
    λ₁/(π w), at least one pixel."""
    spread = 0.0 if not waist_um else wavelength_um / exterior_index / (np.pi * waist_um)
    return max(2.0 / grid.resolution, spread)


def speckle_errors(brdf_sp: np.ndarray, reference_sp: np.ndarray, grid: HemisphereGrid,
                   sigma_u: float) -> dict[str, float]:
    """Relative L2 over the reference's lobe of (s, p) BRDFs (2, res, res) against a reference:
    per polarization and unpolarized, raw and speckle-averaged (both blurred by ``sigma_u``):
    keys ``s``, ``p``, ``unpolarized`` (speckle-averaged) and ``raw_s``, ``raw_p``, ``raw``."""
    out = {}
    for key, f, g in (("s", brdf_sp[0], reference_sp[0]), ("p", brdf_sp[1], reference_sp[1]),
                      ("unpolarized", 0.5 * (brdf_sp[0] + brdf_sp[1]), 0.5 * (reference_sp[0] + reference_sp[1]))):
        out[key] = float(relative_l2(blur(f, grid, sigma_u), blur(g, grid, sigma_u), grid))
        out["raw" if key == "unpolarized" else f"raw_{key}"] = float(relative_l2(f, g, grid))
    return out


def worst_speckle_error(errors: dict[str, float]) -> float:
    """The largest speckle-averaged figure of :func:`speckle_errors` (``s``, ``p``, ``unpolarized``;
    NaN where one is NaN): what ``auto``'s tolerance bounds."""
    return float(np.max([errors["s"], errors["p"], errors["unpolarized"]]))
