"""The Green's function sampled on the AIM grid, its FFTs, and which media go on the grid.

One function, :func:`lattice_green`, gives g(δ) = e^{−jkR}/(4πR) and ∇g(δ) = R·gk(R),
gk = −(1 + jkR) e^{−jkR}/(4πR³), at integer lattice offsets δ (R = δ·Δ); the self point δ = 0 is
0. Both the FFT path (:func:`kernel_spectra`) and the near-field subtraction (near_assembly.py) use
it, so C = A − B subtracts exactly what the FFT adds.

Spectra are computed once per wavelength on the zero-padded grid (grid.py): sample δ sits at
index δ mod P for |δ| < n, zeros elsewhere. Per grid medium i the FFT of g_i and of the three
components of ∇g_i; the FFT convolution (convolution.py) combines them with the PMCHWT coefficients.

Interior medium of a lossy material (bem3d.md §6.7, §14.2): its far interactions are left out
of the grid only when they have decayed, i.e. when w·e^{−|Im k₂| r_near} ≤ tolerance with
w = max(1, |n₂/n₁|²) (the weight of the interior in Z_MM). The test is on the decay itself,
never on κ ≠ 0: a weak absorber keeps its interior on the grid (with complex k₂).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.fft

from wavebrdf.solver.bem3d.aim.grid import AIMGrid
from wavebrdf.solver.bem3d.media import Media

logger = logging.getLogger(__name__)

__all__ = [
    "DECAY_TOLERANCE",
    "KernelSpectra",
    "grid_media",
    "interior_decay",
    "kernel_spectra",
    "lattice_green",
    "padded_offsets",
]

SPECTRA_SLAB_POINTS = 2**18  # grid points sampled at once by kernel_spectra (~40 MB of temporaries)
DECAY_TOLERANCE = 1e-4  # dropped interior entries ≤ 1e-4·d/r_near of the near ones, decaying as e^{−|Im k₂|R}


def lattice_green(k: complex, spacing, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(g, ∇g) at integer lattice offsets (…, 3): shapes (…) and (…, 3), complex128."""
    R = np.asarray(offsets, dtype=float) * np.asarray(spacing, dtype=float)
    r = np.sqrt(np.sum(R * R, axis=-1))
    self_point = r == 0.0
    r_safe = np.where(self_point, 1.0, r)
    e = np.exp(-1j * k * r_safe)
    g = np.where(self_point, 0.0, e / (4.0 * np.pi * r_safe))
    gk = np.where(self_point, 0.0, -(1.0 + 1j * k * r_safe) * e / (4.0 * np.pi * r_safe**3))
    return g, R * gk[..., None]


def padded_offsets(n: int, length: int) -> tuple[np.ndarray, np.ndarray]:
    """Lattice offset held at each index of a padded axis of ``length``, and a validity mask."""
    i = np.arange(length)
    offset = np.where(i < n, i, i - length)
    valid = (i < n) | (i > length - n)
    return offset, valid


def interior_decay(media: Media, near_radius_um: float) -> float:
    """w·e^{−|Im k₂| r_near}: size of the interior far interactions relative to the exterior's."""
    weight = max(1.0, (abs(media.index) / media.exterior_index) ** 2)
    return weight * float(np.exp(-abs(media.wavenumbers[1].imag) * near_radius_um))


def grid_media(media: Media, near_radius_um: float, tolerance: float = DECAY_TOLERANCE) -> tuple[int, ...]:
    """Indices of the media whose far interactions go on the grid: (0,) or (0, 1)."""
    if not (0 < tolerance < 1):
        raise ValueError(f"aim interior_decay_tolerance must be in (0, 1), got {tolerance!r}")
    return (0,) if interior_decay(media, near_radius_um) <= tolerance else (0, 1)


@dataclass
class KernelSpectra:
    """FFTs of the grid kernels of each grid medium: ``green[i]`` (P…) and ``gradient[i]`` (3, P…)."""

    media: tuple[int, ...]
    green: list
    gradient: list


def kernel_spectra(grid: AIMGrid, media: Media, grid_medium_indices, dtype=np.complex128,
                   workers: int | None = None) -> KernelSpectra:
    """Sample g_i, ∇g_i on the padded grid and FFT them (once per wavelength): sampled in slabs of
    x planes into one array of the four fields, each transformed in place."""
    (ox, vx), (oy, vy), (oz, vz) = (padded_offsets(n, p) for n, p in zip(grid.shape, grid.padded))
    padded = tuple(int(p) for p in grid.padded)
    yz = np.stack(np.meshgrid(oy, oz, indexing="ij"), axis=-1)  # (Py, Pz, 2)
    valid_yz = vy[:, None] & vz[None, :]
    slab = max(1, SPECTRA_SLAB_POINTS // (padded[1] * padded[2]))
    green, gradient = [], []
    for i in grid_medium_indices:
        k = media.wavenumbers[i]
        fields = np.empty((4,) + padded, dtype=np.complex128)  # g, ∂x g, ∂y g, ∂z g
        for x0 in range(0, padded[0], slab):
            xs = slice(x0, min(padded[0], x0 + slab))
            offsets = np.empty((xs.stop - x0,) + yz.shape[:2] + (3,))
            offsets[..., 0] = ox[xs, None, None]
            offsets[..., 1:] = yz[None]
            g, grad = lattice_green(k, grid.spacing, offsets)
            valid = vx[xs, None, None] & valid_yz[None]
            fields[0, xs] = np.where(valid, g, 0.0)
            fields[1:, xs] = np.where(valid[None], np.moveaxis(grad, -1, 0), 0.0)
        for c in range(4):  # in place (a copy back where the FFT did not write into its input)
            spectrum = scipy.fft.fftn(fields[c], workers=workers, overwrite_x=True)
            if not np.shares_memory(spectrum, fields[c]):
                fields[c] = spectrum
            del spectrum
        if np.dtype(dtype) == fields.dtype:  # views of the one array: no copies
            green.append(fields[0])
            gradient.append(fields[1:])
        else:
            green.append(fields[0].astype(dtype))
            gradient.append(fields[1:].astype(dtype))
        del fields
    logger.debug("kernel spectra of media %s on %s", tuple(grid_medium_indices), grid.padded)
    return KernelSpectra(tuple(grid_medium_indices), green, gradient)
