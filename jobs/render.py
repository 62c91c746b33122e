"""PNG pictures of BRDF datasets (``wavebrdf render``).

One picture per (sweep case, incident direction): with several wavelengths the spectral BRDF is
converted to colour (CIE XYZ → sRGB, solver/spectrum.py) with a logarithmic tone map that keeps
chromaticity (the dynamic range of a BRDF spans many decades); with one wavelength a false-colour
log₁₀ map with a colour bar. Axes are the projected-hemisphere direction cosines u (x, vertical)
and v (y, horizontal); the white circle is the horizon.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from wavebrdf.jobs.store import Dataset
from wavebrdf.solver.spectrum import spectral_weights, srgb_encode, xyz_to_linear_srgb

__all__ = ["render_dataset", "log_tone_map"]

DECADES = 5.0  # dynamic range shown


def log_tone_map(rgb_linear: np.ndarray, luminance: np.ndarray, decades: float = DECADES) -> np.ndarray:
    """Scale colours so that log₁₀ luminance over ``decades`` below the peak maps to [0, 1]."""
    lum = np.where(np.isfinite(luminance), luminance, 0.0)
    peak = lum.max()
    if peak <= 0:
        return np.zeros_like(rgb_linear)
    level = np.clip((np.log10(np.maximum(lum, peak * 10**-decades)) - np.log10(peak)) / decades + 1.0, 0, 1)
    scale = np.where(lum > 0, level / np.maximum(lum, 1e-300), 0.0)
    rgb = rgb_linear * scale[..., None]
    return rgb / max(1.0, rgb.max())


def _figure(title: str):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.6, 4.8), dpi=120)
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("v (y direction cosine)")
    ax.set_ylabel("u (x direction cosine)")
    t = np.linspace(0, 2 * np.pi, 361)
    ax.plot(np.cos(t), np.sin(t), color="white", lw=0.6)
    ax.set_xlim(-1, 1)
    ax.set_ylim(-1, 1)
    ax.set_aspect("equal")
    return fig, ax, plt


def _case_label(keys: list[str], coords: dict, case_index: tuple) -> str:
    return ", ".join(f"{k}={coords[k][i]}" for k, i in zip(keys, case_index))


def render_dataset(path: str | Path, out_dir: str | Path | None = None, *, max_images: int = 200) -> list[Path]:
    """Write the PNGs of dataset ``path`` into ``out_dir`` (default ``<stem>_png``); return paths."""
    path = Path(path)
    out_dir = Path(out_dir) if out_dir else path.with_name(path.stem + "_png")
    out_dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    with Dataset(path) as ds:
        coords = ds.coords
        keys = ds.sweep_keys
        brdf = ds.h5["brdf"]
        wl = coords["wavelength_um"]
        lead_shape = brdf.shape[: len(keys)]
        pol = ds.h5["brdf"].attrs.get("polarization", "")
        extent = (-1, 1, -1, 1)
        for case_index in np.ndindex(*lead_shape) if lead_shape else [()]:
            case_txt = _case_label(keys, coords, case_index)
            suffix = "".join(f"_c{i}" for i in case_index)
            for inc in range(brdf.shape[len(keys) + 1]):
                if len(written) >= max_images:
                    return written
                head = f"θi={coords['theta_i'][inc]:g}°, φi={coords['phi_i'][inc]:g}°, {pol}"
                if case_txt:
                    head += f"\n{case_txt}"
                cube = np.asarray(brdf[case_index + (slice(None), inc)], dtype=float)  # (n_wl, res, res)
                target = out_dir / f"{path.stem}{suffix}_inc{inc}.png"
                if len(wl) > 1:
                    xyz = np.einsum("kw,wij->ijk", spectral_weights(wl), np.nan_to_num(cube))
                    rgb = log_tone_map(xyz_to_linear_srgb(xyz), xyz[..., 1])
                    fig, ax, plt = _figure(f"{head}\n{wl.min():g}–{wl.max():g} µm, sRGB, log tone map "
                                           f"({DECADES:g} decades)")
                    ax.set_facecolor("black")
                    ax.imshow(srgb_encode(rgb), origin="lower", extent=extent, interpolation="nearest")
                else:
                    data = cube[0]
                    with np.errstate(divide="ignore", invalid="ignore"):
                        logf = np.log10(data)
                    top = np.nanmax(logf[np.isfinite(logf)]) if np.any(np.isfinite(logf)) else 0.0
                    fig, ax, plt = _figure(f"{head}\nλ = {wl[0]:g} µm")
                    ax.set_facecolor("black")
                    im = ax.imshow(logf, origin="lower", extent=extent, cmap="magma", vmin=top - DECADES,
                                   vmax=top, interpolation="nearest")
                    fig.colorbar(im, ax=ax, label="log₁₀ BRDF (1/sr)")
                fig.tight_layout()
                fig.savefig(target)
                plt.close(fig)
                written.append(target)
    return written
