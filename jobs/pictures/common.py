"""What every picture shares: figures (matplotlib, Agg, no pyplot state), log colour scales,
spectra as sRGB, log polar slices and line panels.

Values spanning many decades are shown on log scales: ``decades`` below the peak (default 5), or
fixed ``limits`` (vmin, vmax) so that pictures of several datasets compare. Several wavelengths
become one colour per pixel (CIE XYZ → sRGB, solver/spectrum.py) through a log tone map that
keeps chromaticity; its colour bar is the luminance-weighted value Y (a flat spectrum f has
Y = f), in the variable's units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from wavebrdf.jobs.errors import ConfigError
from wavebrdf.solver.spectrum import VISIBLE_UM, spectral_weights, srgb_encode, xyz_to_linear_srgb

__all__ = ["DECADES", "MAX_CURVES", "MAX_DECADES", "Picture", "PictureOptions", "check_decades", "colours",
           "draw_spectral_image", "figure", "finish", "line_panel", "log_limits", "log_tone_map", "polar_log_slices",
           "some", "spectral_note"]

DECADES = 5.0  # dynamic range shown below the peak
MAX_DECADES = 100.0  # a log scale over more shows nothing more (and 10^-decades underflows beyond ~300)
MAX_CURVES = 8  # curves per panel (wavelengths or directions are subsampled evenly beyond)


@dataclass(frozen=True)
class PictureOptions:
    """What to draw: ``plots`` (kinds), ``incidences`` (indices along incidence/theta_i; None:
    all), ``decades`` (log range below the peak), ``limits`` ((vmin, vmax) instead), ``directions``
    (outgoing (θ_o, φ_o) in degrees for spectra; None: around the specular direction)."""

    plots: tuple[str, ...]
    incidences: tuple[int, ...] | None = None
    decades: float = DECADES
    limits: tuple[float, float] | None = None
    directions: tuple[tuple[float, float], ...] | None = None

    def __post_init__(self):
        check_decades(self.decades)


def check_decades(decades) -> float:
    """``decades`` (the log range below the peak) if it is a number in (0, MAX_DECADES], else a
    ConfigError naming ``--decades`` and the value."""
    if isinstance(decades, bool) or not isinstance(decades, (int, float)) or not (
            math.isfinite(decades) and 0 < decades <= MAX_DECADES):
        raise ConfigError(f"--decades {decades}: must be a number in (0, {MAX_DECADES:g}] (the log range shown "
                          f"below the peak; default {DECADES:g})")
    return float(decades)


@dataclass(frozen=True)
class Picture:
    """One PNG: its file-name suffix, its kind and how to draw it (returns a Figure)."""

    suffix: str
    kind: str
    draw: Callable


def figure(size=(5.6, 4.8)):
    """A new matplotlib Figure (Agg; not registered with pyplot, so nothing to close)."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    return Figure(figsize=size, dpi=120)


def some(n: int, limit: int = MAX_CURVES) -> list[int]:
    """At most ``limit`` indices of range(n), evenly spread, first and last included."""
    return list(range(n)) if n <= limit else sorted({round(i * (n - 1) / (limit - 1)) for i in range(limit)})


def log_limits(values: np.ndarray, decades: float, limits=None) -> tuple[float, float] | None:
    """(vmin, vmax) of a log scale: ``limits``, or ``decades`` below the largest positive finite
    value; None when there is none."""
    if limits is not None:
        return float(limits[0]), float(limits[1])
    finite = values[np.isfinite(values) & (values > 0)]
    if finite.size == 0:
        return None
    top = float(finite.max())
    return max(top * 10.0**-decades, np.finfo(float).tiny), top


def log_tone_map(rgb_linear: np.ndarray, luminance: np.ndarray, vmin: float, vmax: float) -> np.ndarray:
    """Scale colours so that log₁₀ luminance from ``vmin`` to ``vmax`` maps to [0, 1] (chromaticity kept)."""
    lum = np.where(np.isfinite(luminance), luminance, 0.0)
    level = np.clip(np.log10(np.maximum(lum, vmin) / vmin) / np.log10(vmax / vmin), 0, 1)
    scale = np.where(lum > 0, level / np.maximum(lum, 1e-300), 0.0)
    rgb = rgb_linear * scale[..., None]
    return rgb / max(1.0, float(rgb.max()))


def _visible(wavelengths: np.ndarray) -> bool:
    return len(wavelengths) > 1 and np.any((wavelengths >= VISIBLE_UM[0]) & (wavelengths <= VISIBLE_UM[1]))


def spectral_note(wavelengths: np.ndarray, decades: float, limits) -> str:
    scale = "fixed limits" if limits is not None else f"{decades:g} decades"
    if _visible(wavelengths):
        return f"{wavelengths.min():g}–{wavelengths.max():g} µm as sRGB, log tone map ({scale})"
    if len(wavelengths) > 1:
        return f"mean over {wavelengths.min():g}–{wavelengths.max():g} µm (outside the visible), log ({scale})"
    return f"λ = {wavelengths[0]:g} µm, log scale ({scale})"


def draw_spectral_image(fig, ax, cube: np.ndarray, wavelengths: np.ndarray, extent, unit: str, opts) -> None:
    """Spectral cube (n_λ, rows, cols) as sRGB with a log tone map and a luminance colour bar
    (several visible λ), else false colour on a log colour bar; NaN is black."""
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import LogNorm

    ax.set_facecolor("black")
    cube = np.asarray(cube, dtype=float)
    if _visible(wavelengths):
        xyz = np.einsum("kw,wij->ijk", spectral_weights(wavelengths), np.nan_to_num(cube))
        lum = xyz[..., 1]
        lim = log_limits(lum, opts.decades, opts.limits) or (1e-300, 1.0)
        ax.imshow(srgb_encode(log_tone_map(xyz_to_linear_srgb(xyz), lum, *lim)), origin="lower", extent=extent,
                  interpolation="nearest")
        fig.colorbar(ScalarMappable(LogNorm(*lim), "gray"), ax=ax, label=f"Y, luminance-weighted {unit} (log)")
        return
    image = np.nanmean(cube, axis=0) if len(cube) > 1 else cube[0]
    lim = log_limits(image, opts.decades, opts.limits) or (1e-300, 1.0)
    shown = np.where(image > 0, np.clip(image, *lim), np.nan)
    im = ax.imshow(shown, origin="lower", extent=extent, cmap="magma", norm=LogNorm(*lim), interpolation="nearest")
    fig.colorbar(im, ax=ax, label=f"{unit} (log)")


def polar_log_slices(fig, angles_deg: np.ndarray, curves: list[tuple[np.ndarray, str, str]], unit: str, opts, *,
                     half: bool, marks: list[tuple[float, str]] = (), title: str = ""):
    """Curves r(angle) on polar axes with a log radial scale (decades from the centre out).

    ``curves``: (values, label, colour); ``half``: angles in [−90°, 90°] with 0 up (in-plane
    slices), else the full circle; ``marks``: (angle, label) drawn as dashed radial lines."""
    ax = fig.add_subplot(projection="polar")
    ax.set_theta_zero_location("N")
    ax.set_theta_direction(-1)
    if half:
        ax.set_thetamin(-90)
        ax.set_thetamax(90)
    stacked = np.concatenate([np.ravel(values) for values, _, _ in curves]) if curves else np.zeros(0)
    lim = log_limits(stacked, opts.decades, opts.limits)
    if lim is None:
        ax.set_title(f"{title}\n(no positive values)", fontsize=9)
        return ax
    low, high = math.floor(math.log10(lim[0])), math.ceil(math.log10(lim[1]))
    theta = np.deg2rad(angles_deg)
    for values, label, colour in curves:
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.log10(np.clip(values, 10.0**low, None)) - low
        ax.plot(theta, r, lw=1.0, label=label, color=colour)
    ax.set_rlim(0, high - low)
    step = max(1, math.ceil((high - low) / 4))
    ticks = list(range(high - low, -1, -step))[::-1]
    ax.set_rticks(ticks)
    ax.set_yticklabels([f"$10^{{{low + t}}}$" for t in ticks], fontsize=7)
    ax.set_rlabel_position(-8 if half else 100)
    for angle, label in marks:
        ax.plot([np.deg2rad(angle)] * 2, [0, high - low], ls="--", lw=0.8, color="0.3")
        ax.annotate(label, (np.deg2rad(angle), high - low), fontsize=7, ha="center", va="bottom", color="0.3")
    ax.set_title(f"{title}\nradius: {unit}, log scale", fontsize=9)
    if curves:
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(0.98, 1.0) if half else (1.02, 1.0), frameon=False)
    return ax


def finish(fig, ax, xlabel: str, ylabel: str, title: str, aspect="auto"):
    """Axis labels, a small title, the aspect (``"equal"``: one unit is as long on both axes),
    a tight layout; returns ``fig``."""
    ax.set_aspect(aspect)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    return fig


def line_panel(ax, x: np.ndarray, ys: list[tuple[np.ndarray, str]], xlabel: str, ylabel: str, *,
               log: bool = False, colours=None, min_span: float = 0.0) -> None:
    """Lines with markers (one per label) sharing ``x``; log y when ``log``; a linear y axis spans
    at least ``min_span`` (round-off of a constant, e.g. a lossless albedo of 1, stays flat)."""
    for k, (y, label) in enumerate(ys):
        ax.plot(x, y, marker="o", ms=3, lw=1.0, label=label, color=None if colours is None else colours[k])
    if log:
        ax.set_yscale("log")
    else:
        ax.ticklabel_format(axis="y", useOffset=False)
        values = np.concatenate([np.ravel(y) for y, _ in ys]) if ys else np.zeros(0)
        values = values[np.isfinite(values)]
        if values.size and values.max() - values.min() < min_span:
            mid = 0.5 * (values.max() + values.min())
            ax.set_ylim(mid - min_span / 2, mid + min_span / 2)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    if ys:
        ax.legend(fontsize=7, frameon=False)


def colours(n: int) -> list:
    """``n`` distinguishable line colours (viridis-like, dark to light)."""
    import matplotlib

    cmap = matplotlib.colormaps["viridis"]
    return [cmap(0.9 * i / max(1, n - 1)) for i in range(n)]
