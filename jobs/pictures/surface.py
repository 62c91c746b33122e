"""Pictures of surface datasets (BRDFs of height fields).

- ``maps``: the BRDF over the projected hemisphere per (case, incidence): axes the direction
  cosines v (x of the picture) and u (y), equal aspect (the horizon is the circle), dotted
  circles at θ_o = 30° and 60°, a cross at the specular direction (u, v) = −sin θ_i (cos φ_i,
  sin φ_i), a log colour bar in 1/sr.
- ``slices``: the BRDF in the plane of incidence on log polar axes per (case, incidence), one
  curve per wavelength; the polar angle is θ_o, positive on the specular side (the specular
  direction at +θ_i, backscatter at −θ_i); nearest pixels along the line through the centre at
  azimuth φ_i.
- ``spectra``: BRDF vs λ at chosen outgoing directions per (case, incidence) (several
  wavelengths only): the mean over the pixels within 1° of each direction (the nearest pixel if
  none); default directions: specular and 5° and 15° from it toward the normal, in plane.
- ``albedo``: albedo vs θ_i (one line per wavelength) and vs λ (one line per incidence), per case.
- ``heights``: the height map (µm) with its measured statistics (dataset attributes), per case.
- ``polarization`` (datasets with Jones or Mueller matrices, ``[output] polarization``): the
  degree of polarization of the light scattered from unpolarized incidence, |M[1:, 0]|/M₀₀, per
  (case, incidence): its map over the projected hemisphere after the speckle average (Mueller
  matrices blurred by λ/(π w), the footprint's spread: an incoherent average, in the regular
  frames of solver/polarimetry.py, smooth across the pole) for the middle
  wavelength, and its in-plane curve per wavelength, raw (one coherent realization: thin) and
  averaged (thick).
"""

from __future__ import annotations

import numpy as np

from wavebrdf.jobs.pictures.common import (colours, draw_spectral_image, figure, finish, line_panel,
                                           polar_log_slices, some, spectral_note)

__all__ = ["KINDS", "PER_CASE", "PER_DIRECTION", "available", "direction_values", "in_plane", "specular_uv"]

KINDS = ("maps", "slices", "spectra", "albedo", "heights", "polarization")
CONE_DEG = 1.0  # spectra: half-angle of the cone averaged around each direction


def specular_uv(theta_i_deg: float, phi_i_deg: float) -> tuple[float, float]:
    """(u, v) of the mirror direction of ω_i = (θ_i, φ_i) (toward the light)."""
    s = np.sin(np.deg2rad(theta_i_deg))
    return -s * np.cos(np.deg2rad(phi_i_deg)), -s * np.sin(np.deg2rad(phi_i_deg))


def _uv(theta_deg, phi_deg) -> tuple[float, float]:
    s = np.sin(np.deg2rad(theta_deg))
    return s * np.cos(np.deg2rad(phi_deg)), s * np.sin(np.deg2rad(phi_deg))


class Case:
    """Reads one sweep case of a surface dataset."""

    def __init__(self, ds, case_index: tuple, flat: int, label: str):
        self.ds, self.index, self.flat, self.label = ds, case_index, flat, label
        self.coords = ds.coords
        self.brdf = ds.h5["brdf"]
        self.polarization = ds.brdf_polarization

    def cube(self, inc: int) -> np.ndarray:
        """BRDF (n_λ, res, res) of incidence ``inc``."""
        return np.asarray(self.brdf[self.index + (slice(None), inc)], dtype=float)

    def waist_um(self) -> float | None:
        """The footprint waist of this case's config (µm; None without one)."""
        import tomllib

        try:
            config = tomllib.loads(self.ds.config)
        except tomllib.TOMLDecodeError:
            return None
        swept = dict(zip(self.ds.sweep_keys, self.index))
        if "illumination.waist_um" in swept:
            return float(self.coords["illumination.waist_um"][swept["illumination.waist_um"]])
        waist = config.get("illumination", {}).get("waist_um")
        return float(waist) if waist else None

    def title(self, inc: int) -> str:
        c = self.coords
        text = f"θi={c['theta_i'][inc]:g}°, φi={c['phi_i'][inc]:g}°, {self.polarization}"
        return text + (f"\n{self.label}" if self.label else "")


def available(c: Case, kind: str) -> bool:
    """Whether picture ``kind`` exists for case ``c`` (spectra need several wavelengths)."""
    if kind == "heights":
        return c.ds.case_variable(c.flat) is not None
    if kind == "polarization":
        return c.ds.polarimetry != "intensity"
    return kind != "spectra" or len(c.coords["wavelength_um"]) > 1


def _map(c: Case, inc: int, opts):
    wl = c.coords["wavelength_um"]
    fig = figure()
    ax = fig.add_subplot()
    draw_spectral_image(fig, ax, c.cube(inc), wl, (-1, 1, -1, 1), "BRDF (1/sr)", opts)
    t = np.linspace(0, 2 * np.pi, 361)
    ax.plot(np.cos(t), np.sin(t), color="white", lw=0.8)
    for theta in (30, 60):
        r = np.sin(np.deg2rad(theta))
        ax.plot(r * np.cos(t), r * np.sin(t), color="white", lw=0.4, ls=":")
        ax.annotate(f"{theta}°", (r * np.cos(np.pi / 4), r * np.sin(np.pi / 4)), color="white", fontsize=6)
    u, v = specular_uv(c.coords["theta_i"][inc], c.coords["phi_i"][inc])
    ax.plot([v], [u], marker="+", ms=10, mew=1.2, color="cyan", ls="none", label="specular")
    ax.legend(loc="lower right", fontsize=7, frameon=False, labelcolor="white")
    ax.set_xlim(-1.02, 1.02)
    ax.set_ylim(-1.02, 1.02)
    return finish(fig, ax, "v (y direction cosine)", "u (x direction cosine)",
                  f"{c.title(inc)}\n{spectral_note(wl, opts.decades, opts.limits)}", aspect="equal")


def in_plane(cube: np.ndarray, phi_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """(θ_o signed, degrees; values (n_λ, n)) along the plane of incidence at azimuth φ_i:
    nearest pixels on the line (u, v) = −sin θ_o (cos φ_i, sin φ_i), so the specular side is θ_o > 0."""
    res = cube.shape[-1]
    s = np.linspace(-1, 1, 2 * res + 1)[1:-1]
    u, v = -s * np.cos(np.deg2rad(phi_deg)), -s * np.sin(np.deg2rad(phi_deg))
    i = np.clip(np.floor((u + 1) / 2 * res).astype(int), 0, res - 1)
    j = np.clip(np.floor((v + 1) / 2 * res).astype(int), 0, res - 1)
    return np.rad2deg(np.arcsin(s)), cube[:, i, j]


def _slice(c: Case, inc: int, opts):
    wl = c.coords["wavelength_um"]
    theta_o, values = in_plane(c.cube(inc), c.coords["phi_i"][inc])
    chosen = some(len(wl))
    palette = colours(len(chosen))
    curves = [(values[k], f"λ = {wl[k]:g} µm", palette[n]) for n, k in enumerate(chosen)]
    fig = figure((6.0, 3.6))
    theta_i = c.coords["theta_i"][inc]
    polar_log_slices(fig, theta_o, curves, "BRDF (1/sr)", opts, half=True,
                     marks=[(theta_i, "specular"), (-theta_i, "back")] if theta_i > 0 else [(0, "specular")],
                     title=f"in-plane BRDF, {c.title(inc)}")
    fig.tight_layout()
    return fig


def direction_values(cube: np.ndarray, theta_deg: float, phi_deg: float) -> np.ndarray:
    """BRDF (n_λ) toward (θ_o, φ_o): the mean over pixels within ``CONE_DEG`` (else the nearest pixel)."""
    res = cube.shape[-1]
    centres = 2.0 * (np.arange(res) + 0.5) / res - 1.0
    U, V = np.meshgrid(centres, centres, indexing="ij")
    W = np.sqrt(np.clip(1 - U**2 - V**2, 0, None))
    u, v = _uv(theta_deg, phi_deg)
    w = np.cos(np.deg2rad(theta_deg))
    cosine = np.where(U**2 + V**2 < 1, U * u + V * v + W * w, -2.0)
    inside = cosine >= np.cos(np.deg2rad(CONE_DEG))
    if not inside.any():
        inside = cosine == cosine.max()
    return np.nanmean(cube[:, inside], axis=1)


def _default_directions(theta_i: float, phi_i: float) -> list[tuple[float, float, str]]:
    out = []
    for offset in (0.0, 5.0, 15.0):
        signed = theta_i - offset  # in plane, positive on the specular side
        theta, phi = abs(signed), (phi_i + 180.0 if signed >= 0 else phi_i) % 360.0
        out.append((theta, phi, "specular" if offset == 0 else f"{offset:g}° from specular"))
    return out


def _spectra(c: Case, inc: int, opts):
    wl = c.coords["wavelength_um"]
    cube = c.cube(inc)
    theta_i, phi_i = c.coords["theta_i"][inc], c.coords["phi_i"][inc]
    directions = ([(t, p, "") for t, p in opts.directions] if opts.directions
                  else _default_directions(theta_i, phi_i))
    ys = [(direction_values(cube, t, p), f"θo={t:g}°, φo={p:g}°" + (f" ({note})" if note else ""))
          for t, p, note in directions]
    order = np.argsort(wl)
    fig = figure((5.6, 4.2))
    ax = fig.add_subplot()
    line_panel(ax, wl[order], [(y[order], label) for y, label in ys], "wavelength λ (µm)",
               "BRDF (1/sr)", log=True)
    ax.set_title(f"spectra (mean within {CONE_DEG:g}° of each direction)\n{c.title(inc)}", fontsize=9)
    fig.tight_layout()
    return fig


def _albedo(c: Case, opts):
    coords = c.coords
    wl, theta = coords["wavelength_um"], coords["theta_i"]
    albedo = np.asarray(c.ds.h5["albedo"][c.index], dtype=float)  # (n_λ, n_inc)
    fig = figure((9.0, 3.8))
    by_theta, by_wl = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    order = np.argsort(theta, kind="stable")
    chosen = some(len(wl))
    line_panel(by_theta, theta[order], [(albedo[k, order], f"λ = {wl[k]:g} µm") for k in chosen],
               "θi (degrees)", "albedo Σ f Δu Δv", colours=colours(len(chosen)), min_span=0.02)
    incs = some(len(theta))
    wl_order = np.argsort(wl)
    line_panel(by_wl, wl[wl_order], [(albedo[wl_order, k], f"θi={theta[k]:g}°, φi={coords['phi_i'][k]:g}°")
                                     for k in incs], "wavelength λ (µm)", "albedo Σ f Δu Δv",
               colours=colours(len(incs)), min_span=0.02)
    fig.suptitle(f"albedo ({c.polarization})" + (f", {c.label}" if c.label else ""), fontsize=9)
    fig.tight_layout()
    return fig


def _stat(attrs, key: str, unit: str = "") -> str:
    value = attrs.get(key)
    if value is None or not np.isfinite(np.asarray(value, dtype=float)).all():
        return "n/a"
    return f"{float(value):.4g}{unit}"


def _heights(c: Case, opts):
    dataset = c.ds.case_variable(c.flat)
    z = np.asarray(dataset[()], dtype=float)
    attrs = dict(dataset.attrs)
    size = float(attrs.get("size_um", z.shape[0] - 1))
    fig = figure((7.6, 4.4))
    ax, bar = fig.add_axes((0.09, 0.12, 0.5, 0.76)), fig.add_axes((0.6, 0.12, 0.02, 0.76))
    im = ax.imshow(z.T, origin="lower", extent=(0, size, 0, size), cmap="viridis", interpolation="nearest")
    fig.colorbar(im, cax=bar, label="height (µm)")
    ax.set_aspect("equal")
    ax.set_xlabel("x (µm)")
    ax.set_ylabel("y (µm)")
    lines = [f"rms height {_stat(attrs, 'rms_height_um', ' µm')}",
             f"peak to valley {_stat(attrs, 'peak_to_valley_um', ' µm')}",
             f"rms slope {_stat(attrs, 'rms_slope')}", f"max slope {_stat(attrs, 'max_slope')}",
             f"correlation x {_stat(attrs, 'correlation_length_x_um', ' µm')}",
             f"correlation y {_stat(attrs, 'correlation_length_y_um', ' µm')}",
             f"{z.shape[0]}×{z.shape[1]} nodes, spacing {_stat(attrs, 'spacing_um', ' µm')}"]
    generator = attrs.get("generator")
    if generator is not None:
        lines.insert(0, f"generator {generator.decode() if isinstance(generator, bytes) else generator}")
    fig.text(0.73, 0.5, "\n".join(lines), fontsize=8, va="center", ha="left", linespacing=1.5)
    ax.set_title("height map" + (f", {c.label}" if c.label else ""), fontsize=9)
    return fig


def _polarization(c: Case, inc: int, opts):
    from wavebrdf.solver.farfield import HemisphereGrid
    from wavebrdf.solver.metrics import blur, speckle_sigma_u
    from wavebrdf.solver.polarimetry import degree_of_polarization, to_regular_frames

    wl = c.coords["wavelength_um"]
    M = np.asarray(c.ds.mueller(c.index + (slice(None), inc)), dtype=float)  # (n_λ, 4, 4, res, res)
    grid = HemisphereGrid(M.shape[-1])
    waist = c.waist_um()
    raw = np.stack([degree_of_polarization(np.nan_to_num(m)) for m in M])
    sigmas = [speckle_sigma_u(w, waist, grid) for w in wl]
    U, V = grid.uv  # blurred in frames smooth across the pole (the degree of polarization is frame-free)
    regular = [to_regular_frames(np.nan_to_num(m), U, V, np.deg2rad(c.coords["phi_i"][inc])) for m in M]
    averaged = np.stack([degree_of_polarization(np.nan_to_num(blur(m, grid, sigma))) for m, sigma in zip(regular, sigmas)])
    raw[:, ~grid.inside] = np.nan
    averaged[:, ~grid.inside] = np.nan
    fig = figure((10.0, 4.2))
    ax_map, bar, ax = fig.add_axes((0.05, 0.13, 0.33, 0.74)), fig.add_axes((0.39, 0.13, 0.012, 0.74)), \
        fig.add_axes((0.52, 0.13, 0.45, 0.74))
    middle = int(np.argsort(wl)[len(wl) // 2])
    im = ax_map.imshow(averaged[middle], origin="lower", extent=(-1, 1, -1, 1), vmin=0, vmax=1, cmap="magma",
                       interpolation="nearest")
    fig.colorbar(im, cax=bar, label="degree of polarization")
    u, v = specular_uv(c.coords["theta_i"][inc], c.coords["phi_i"][inc])
    ax_map.plot([v], [u], marker="+", ms=10, mew=1.2, color="cyan", ls="none")
    ax_map.set_xlabel("v (y direction cosine)")
    ax_map.set_ylabel("u (x direction cosine)")
    ax_map.set_aspect("equal")
    ax_map.set_title(f"speckle-averaged (σ = {sigmas[middle]:.3g} in u), λ = {wl[middle]:g} µm", fontsize=8)
    chosen = some(len(wl))
    palette = colours(len(chosen))
    phi_i = c.coords["phi_i"][inc]
    for n, k in enumerate(chosen):
        theta_o, line_raw = in_plane(raw[k][None], phi_i)
        _, line_avg = in_plane(averaged[k][None], phi_i)
        ax.plot(theta_o, line_raw[0], color=palette[n], lw=0.5, alpha=0.6)
        ax.plot(theta_o, line_avg[0], color=palette[n], lw=1.8, label=f"λ = {wl[k]:g} µm")
    ax.axvline(c.coords["theta_i"][inc], color="grey", lw=0.6, ls=":")
    ax.set_xlim(-90, 90)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("θo in the plane of incidence (degrees; specular side > 0)")
    ax.set_ylabel("degree of polarization (unpolarized incidence)")
    ax.legend(fontsize=7, frameon=False)
    ax.set_title(f"thin: one coherent realization; thick: speckle average\n{c.title(inc)}", fontsize=8)
    return fig


PER_CASE = (("heights", "_heights", _heights), ("albedo", "_albedo", _albedo))  # kind, file suffix, draw
PER_DIRECTION = (("maps", "_inc{k}", _map), ("slices", "_slice_inc{k}", _slice),
                 ("spectra", "_spectra_inc{k}", _spectra), ("polarization", "_polarization_inc{k}", _polarization))
