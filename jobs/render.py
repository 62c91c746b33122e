"""PNG pictures of datasets (``wavebrdf render``).

Surfaces: one picture per (sweep case, incident direction); axes are the projected-hemisphere
direction cosines u (x, vertical) and v (y, horizontal); the white circle is the horizon.
Fibers: one φ_i–φ_r map of the azimuthal scattering function N_wave per (sweep case, θ_i);
circular fibers (one φ_i) are drawn over all φ_i by their rotation invariance.
With several wavelengths the spectrum is converted to colour (CIE XYZ → sRGB,
solver/spectrum.py) with a logarithmic tone map that keeps chromaticity (these functions span many
decades); with one wavelength a false-colour log₁₀ map with a colour bar.
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import numpy as np

from wavebrdf.jobs.parts import storage_error
from wavebrdf.jobs.store import Dataset, StoreError
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


def _figure(title: str, hemisphere: bool = True):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.6, 4.8), dpi=120)
    ax.set_title(title, fontsize=9)
    if hemisphere:
        ax.set_xlabel("v (y direction cosine)")
        ax.set_ylabel("u (x direction cosine)")
        t = np.linspace(0, 2 * np.pi, 361)
        ax.plot(np.cos(t), np.sin(t), color="white", lw=0.6)
        ax.set_xlim(-1, 1)
        ax.set_ylim(-1, 1)
        ax.set_aspect("equal")
    else:
        ax.set_xlabel("φ_r (degrees)")
        ax.set_ylabel("φ_i (degrees)")
    return fig, ax, plt


def _draw(fig, ax, cube: np.ndarray, wavelengths: np.ndarray, extent, unit: str) -> None:
    """Spectral cube (n_wl, rows, cols) as sRGB (several λ) or false-colour log₁₀ (one λ)."""
    ax.set_facecolor("black")
    if len(wavelengths) > 1:
        xyz = np.einsum("kw,wij->ijk", spectral_weights(wavelengths), np.nan_to_num(cube))
        rgb = log_tone_map(xyz_to_linear_srgb(xyz), xyz[..., 1])
        ax.imshow(srgb_encode(rgb), origin="lower", extent=extent, interpolation="nearest", aspect="auto")
        return
    with np.errstate(divide="ignore", invalid="ignore"):
        logf = np.log10(cube[0])
    top = np.nanmax(logf[np.isfinite(logf)]) if np.any(np.isfinite(logf)) else 0.0
    im = ax.imshow(logf, origin="lower", extent=extent, cmap="magma", vmin=top - DECADES, vmax=top,
                   interpolation="nearest", aspect="auto")
    fig.colorbar(im, ax=ax, label=f"log₁₀ {unit}")


def _spectral_note(wavelengths: np.ndarray) -> str:
    if len(wavelengths) > 1:
        return f"{wavelengths.min():g}–{wavelengths.max():g} µm, sRGB, log tone map ({DECADES:g} decades)"
    return f"λ = {wavelengths[0]:g} µm"


def _case_label(keys: list[str], coords: dict, case_index: tuple) -> str:
    return ", ".join(f"{k}={coords[k][i]}" for k, i in zip(keys, case_index))


def render_dataset(path: str | Path, out_dir: str | Path | None = None, *, max_images: int = 200) -> list[Path]:
    """Write the PNGs of dataset ``path`` into ``out_dir`` (default ``<stem>_png``); return paths.

    The dataset is opened and checked before anything is created. The pictures are drawn into a
    temporary folder beside ``out_dir`` and moved into place only when all of them are written,
    so a failure (a damaged dataset, a full disk) leaves no partial set and an existing folder as
    it was."""
    path = Path(path)
    out_dir = Path(out_dir) if out_dir else path.with_name(path.stem + "_png")
    with Dataset(path) as ds, ds.reading():
        if out_dir.exists() and not out_dir.is_dir():
            raise StoreError(f"cannot write PNGs into {str(out_dir)!r}: it is not a folder")
        if not out_dir.parent.is_dir():
            raise StoreError(f"cannot write PNGs into {str(out_dir)!r}: folder {str(out_dir.parent)!r} does not exist")
        _remove_abandoned(out_dir)
        pictures = _fiber_pictures(ds) if ds.kind == "fiber" else _surface_pictures(ds)
        wl = ds.coords["wavelength_um"]
        staging = out_dir.with_name(f".{out_dir.name}.{os.getpid()}.tmp")
        names = []
        try:
            staging.mkdir()
            for suffix, title, cube, extent, unit, hemisphere in pictures:
                if len(names) >= max_images:
                    break
                fig, ax, plt = _figure(f"{title}\n{_spectral_note(wl)}", hemisphere)
                try:
                    _draw(fig, ax, cube, wl, extent, unit)
                    fig.tight_layout()
                    names.append(f"{path.stem}{suffix}.png")
                    fig.savefig(staging / names[-1])
                finally:
                    plt.close(fig)
            if out_dir.is_dir():
                for name in names:
                    os.replace(staging / name, out_dir / name)
                staging.rmdir()
            else:
                os.rename(staging, out_dir)
        except BaseException as exc:
            shutil.rmtree(staging, ignore_errors=True)
            if isinstance(exc, OSError):
                raise storage_error(out_dir, exc) from None
            raise
    return [out_dir / name for name in names]


def _remove_abandoned(out_dir: Path) -> None:
    """Remove the staging folders of renders into ``out_dir`` whose process is gone."""
    pattern = re.compile(rf"\.{re.escape(out_dir.name)}\.(\d+)\.tmp")
    for entry in out_dir.parent.iterdir():
        found = pattern.fullmatch(entry.name)
        if found and entry.is_dir() and not _alive(int(found.group(1))):
            shutil.rmtree(entry, ignore_errors=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _cases(ds: Dataset, variable: str):
    keys = ds.sweep_keys
    coords = ds.coords
    lead = ds.h5[variable].shape[: len(keys)]
    for case_index in np.ndindex(*lead) if lead else [()]:
        yield case_index, _case_label(keys, coords, case_index), "".join(f"_c{i}" for i in case_index)


def _surface_pictures(ds: Dataset):
    coords = ds.coords
    brdf = ds.h5["brdf"]
    pol = brdf.attrs.get("polarization", "")
    n_lead = len(ds.sweep_keys)
    for case_index, case_txt, suffix in _cases(ds, "brdf"):
        for inc in range(brdf.shape[n_lead + 1]):
            title = f"θi={coords['theta_i'][inc]:g}°, φi={coords['phi_i'][inc]:g}°, {pol}"
            if case_txt:
                title += f"\n{case_txt}"
            cube = np.asarray(brdf[case_index + (slice(None), inc)], dtype=float)  # (n_wl, res, res)
            yield f"{suffix}_inc{inc}", title, cube, (-1, 1, -1, 1), "BRDF (1/sr)", True


def _fiber_pictures(ds: Dataset):
    coords = ds.coords
    bcsdf = ds.h5["bcsdf"]
    n_lead = len(ds.sweep_keys)
    phi_r = coords["phi_r"]
    for case_index, case_txt, suffix in _cases(ds, "bcsdf"):
        for ti in range(bcsdf.shape[n_lead + 1]):
            cube = np.asarray(bcsdf[case_index + (slice(None), ti)], dtype=float)  # (n_wl, P, R)
            if cube.shape[1] == 1:  # circle: N(φ_i, φ_r) = N(0, φ_r − φ_i)
                cube = np.stack([np.stack([np.roll(c[0], i) for i in range(len(phi_r))]) for c in cube])
            title = f"fiber N_wave, θi={coords['theta_i'][ti]:g}° (unpolarized)"
            if case_txt:
                title += f"\n{case_txt}"
            step = 360.0 / len(phi_r)
            phi_i = coords["phi_i"] if bcsdf.shape[n_lead + 2] > 1 else phi_r
            extent = (phi_r[0] - step / 2, phi_r[-1] + step / 2, phi_i[0], phi_i[-1] + (phi_i[1] - phi_i[0]
                                                                                          if len(phi_i) > 1 else 1))
            yield f"{suffix}_theta{ti}", title, cube, extent, "N_wave (1/rad)", False
