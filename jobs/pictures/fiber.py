"""Pictures of fiber datasets (BCSDF tables).

- ``maps``: N_wave over (φ_r, φ_i) per (case, θ_i), log colour bar in 1/rad; circular fibers
  (one φ_i) are drawn over all φ_i by their rotation invariance N(φ_i, φ_r) = N(0, φ_r − φ_i).
- ``slices``: N_wave(φ_r) on log polar axes per (case, θ_i) at the first φ_i, one curve per
  wavelength; φ_r = 0 up, dashed lines toward the light (φ_i) and forward (φ_i + 180°).
- ``albedo``: C_sca/C_ext (unpolarized, mean over φ_i) vs θ_i and vs λ, per case.
- ``cross-sections``: C_ext, C_sca, C_abs per unit length (µm, unpolarized, mean over φ_i) vs λ,
  one line per θ_i, and the cross-section outline, per case.
"""

from __future__ import annotations

import numpy as np

from wavebrdf.jobs.pictures.common import (colours, draw_spectral_image, figure, finish, line_panel,
                                           polar_log_slices, some, spectral_note)

__all__ = ["KINDS", "PER_CASE", "PER_DIRECTION", "available"]

KINDS = ("maps", "slices", "albedo", "cross-sections")


class Case:
    def __init__(self, ds, case_index: tuple, flat: int, label: str):
        self.ds, self.index, self.flat, self.label = ds, case_index, flat, label
        self.coords = ds.coords

    def cube(self, ti: int) -> np.ndarray:
        """N_wave (n_λ, n_φi, n_φr) at θ_i index ``ti``."""
        return np.asarray(self.ds.h5["bcsdf"][self.index + (slice(None), ti)], dtype=float)

    def unpolarized(self, name: str) -> np.ndarray:
        """``name`` (C_ext, ...) averaged over polarization and φ_i: (n_λ, n_θ)."""
        return np.asarray(self.ds.h5[name][self.index], dtype=float).mean(axis=(-2, -1))

    def title(self, ti: int) -> str:
        return f"fiber, θi={self.coords['theta_i'][ti]:g}° (unpolarized)" + (f"\n{self.label}" if self.label else "")


def available(c: Case, kind: str) -> bool:
    """Every kind exists for every fiber case."""
    return True


def _map(c: Case, ti: int, opts):
    wl, phi_r = c.coords["wavelength_um"], c.coords["phi_r"]
    cube = c.cube(ti)
    circle = cube.shape[1] == 1
    if circle:
        cube = np.stack([np.stack([np.roll(plane[0], i) for i in range(len(phi_r))]) for plane in cube])
    phi_i = phi_r if circle else c.coords["phi_i"]
    step_r = 360.0 / len(phi_r)
    step_i = phi_i[1] - phi_i[0] if len(phi_i) > 1 else 1.0
    extent = (phi_r[0] - step_r / 2, phi_r[-1] + step_r / 2, phi_i[0] - step_i / 2, phi_i[-1] + step_i / 2)
    fig = figure()
    ax = fig.add_subplot()
    draw_spectral_image(fig, ax, cube, wl, extent, "N_wave (1/rad)", opts)
    return finish(fig, ax, "φ_r (degrees)", "φ_i (degrees)",
                  f"N_wave, {c.title(ti)}\n{spectral_note(wl, opts.decades, opts.limits)}")


def _slice(c: Case, ti: int, opts):
    wl, phi_r = c.coords["wavelength_um"], c.coords["phi_r"]
    phi_i = float(c.coords["phi_i"][0])
    values = c.cube(ti)[:, 0, :]  # (n_λ, n_φr) at the first φ_i
    chosen = some(len(wl))
    palette = colours(len(chosen))
    closed = np.append(phi_r, phi_r[0] + 360.0)
    curves = [(np.append(values[k], values[k, 0]), f"λ = {wl[k]:g} µm", palette[n]) for n, k in enumerate(chosen)]
    fig = figure((5.6, 5.0))
    polar_log_slices(fig, closed, curves, "N_wave (1/rad)", opts, half=False,
                     marks=[(phi_i, "light"), (phi_i + 180.0, "forward")],
                     title=f"N_wave(φ_r) at φi={phi_i:g}°, {c.title(ti)}")
    fig.tight_layout()
    return fig


def _albedo(c: Case, opts):
    wl, theta = c.coords["wavelength_um"], c.coords["theta_i"]
    albedo = c.unpolarized("C_sca") / c.unpolarized("C_ext")  # (n_λ, n_θ)
    fig = figure((9.0, 3.8))
    by_theta, by_wl = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    chosen = some(len(wl))
    order = np.argsort(theta)
    line_panel(by_theta, theta[order], [(albedo[k, order], f"λ = {wl[k]:g} µm") for k in chosen], "θi (degrees)",
               "albedo C_sca / C_ext", colours=colours(len(chosen)), min_span=0.02)
    thetas = some(len(theta))
    line_panel(by_wl, wl, [(albedo[:, k], f"θi={theta[k]:g}°") for k in thetas], "wavelength λ (µm)",
               "albedo C_sca / C_ext", colours=colours(len(thetas)), min_span=0.02)
    fig.suptitle("fiber albedo (unpolarized, mean over φ_i)" + (f", {c.label}" if c.label else ""), fontsize=9)
    fig.tight_layout()
    return fig


def _cross_sections(c: Case, opts):
    wl, theta = c.coords["wavelength_um"], c.coords["theta_i"]
    fig = figure((10.0, 3.6))
    thetas = some(len(theta))
    palette = colours(len(thetas))
    span = 0.05 * float(np.nanmax(c.unpolarized("C_ext")))  # C_abs of a lossless fiber: 0, not its round-off
    for n, name in enumerate(("C_ext", "C_sca", "C_abs")):
        ax = fig.add_subplot(1, 4, n + 1)
        values = c.unpolarized(name)
        line_panel(ax, wl, [(values[:, k], f"θi={theta[k]:g}°") for k in thetas], "λ (µm)", f"{name} (µm)",
                   colours=palette, min_span=span)
        if n:
            ax.get_legend().remove()
    outline = c.ds.case_variable(c.flat)
    ax = fig.add_subplot(1, 4, 4)
    if outline is not None:
        nodes = np.asarray(outline[()], dtype=float)
        closed = np.vstack([nodes, nodes[:1]])
        ax.fill(closed[:, 0], closed[:, 1], color="0.8", edgecolor="0.2", lw=0.8)
    ax.set_aspect("equal")
    ax.set_xlabel("x (µm)")
    ax.set_ylabel("y (µm)")
    ax.set_title("cross section", fontsize=8)
    fig.suptitle("cross sections per unit length (unpolarized, mean over φ_i)"
                 + (f", {c.label}" if c.label else ""), fontsize=9)
    fig.tight_layout()
    return fig


PER_CASE = (("cross-sections", "_cross_sections", _cross_sections), ("albedo", "_albedo", _albedo))
PER_DIRECTION = (("maps", "_theta{k}", _map), ("slices", "_slice_theta{k}", _slice))
