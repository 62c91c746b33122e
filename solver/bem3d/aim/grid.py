"""The AIM grid: a uniform 3-D lattice of point sources around the surface (bem3d.md §6.1).

Grid points sit at x_i = (i₀ + i)Δx, y_j = (j₀ + j)Δy, z_l = (l₀ + l)Δz (µm) with lattice
offsets (i₀, j₀, l₀) chosen so that every basis function's stencil lies inside the grid (no
trimming of the patch). Defaults (bem3d.md §6.1): Δx = Δy = 1.6 d, Δz = (4/3)·1.6 d, stencil
4 × 4 × 3 points placed around each rooftop's centre (the midpoint of its shared edge):

* an even stencil size s along an axis takes the points ⌊ξ⌋ − (s/2 − 1) … ⌊ξ⌋ + s/2,
* an odd size takes round(ξ) − (s − 1)/2 … round(ξ) + (s − 1)/2,

with ξ the centre coordinate in units of the spacing. The plane z = 0 (the patch's reference
height) is a lattice plane, so a flat patch lies exactly on one plane; flat patches get a
one-plane stencil in z (``z_stencil = "auto"``).

Convolutions on the grid are linear (not cyclic): every array is zero-padded to FFT lengths
P ≥ 2n − 1 that are 2·3·5(·7)-smooth (:func:`wavebrdf.solver.czt.fast_length`). Sources and
results both occupy indices [0, n) of the padded arrays; the kernel sample for the lattice
offset δ sits at index δ mod P.

The scatter Λᵀ is race-free through the inverse map "grid point → entries (basis·S + slot)"
(:meth:`AIMGrid.inverse_map`, CSR), S = s_x s_y s_z.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from wavebrdf.solver.bem3d.mesh import BEMMesh
from wavebrdf.solver.czt import fast_length

logger = logging.getLogger(__name__)

__all__ = ["AIMGrid", "GridOptions", "build_grid", "stencil_first"]


@dataclass(frozen=True)
class GridOptions:
    """AIM grid settings (spacings in units of the cell size d).

    spacing_cells      Δx = Δy in units of d (default 1.6, bem3d.md §6.1)
    z_spacing_cells    Δz in units of d (default 4/3 · 1.6)
    stencil            points per axis (s_x, s_y, s_z); s_z = 0 means "auto": 1 for a flat
                       horizontal patch (it lies on the plane z = 0), else 3
    """

    spacing_cells: float = 1.6
    z_spacing_cells: float = 1.6 * 4.0 / 3.0
    stencil: tuple[int, int, int] = (4, 4, 0)

    def __post_init__(self):
        for name in ("spacing_cells", "z_spacing_cells"):
            value = getattr(self, name)
            if not (np.isfinite(value) and 0.25 <= value <= 8.0):
                raise ValueError(f"aim grid {name} must be in [0.25, 8] cells, got {value!r}")
        stencil = tuple(int(s) for s in self.stencil)
        if len(stencil) != 3 or any(s < 0 or s > 8 for s in stencil) or min(stencil[:2]) < 1:
            raise ValueError(f"aim stencil must be 3 integers (s_x, s_y >= 1, s_z >= 0 (auto)) <= 8, got {self.stencil!r}")
        object.__setattr__(self, "stencil", stencil)


def stencil_first(xi: np.ndarray, size: int) -> np.ndarray:
    """Lattice index of the first stencil point for coordinates ``xi`` (units of the spacing)."""
    xi = np.asarray(xi, dtype=float)
    if size % 2 == 0:
        return (np.floor(xi) - (size // 2 - 1)).astype(np.int64)
    return (np.floor(xi + 0.5) - (size - 1) // 2).astype(np.int64)


@dataclass(frozen=True)
class AIMGrid:
    """Grid geometry, per-basis stencil origins and FFT sizes (see the module docstring)."""

    spacing: tuple[float, float, float]  # Δx, Δy, Δz (µm)
    lattice_start: tuple[int, int, int]  # (i₀, j₀, l₀)
    shape: tuple[int, int, int]  # (n_x, n_y, n_z)
    stencil: tuple[int, int, int]  # (s_x, s_y, s_z)
    origins: np.ndarray  # (N_b, 3) int32: grid index of each basis' first stencil point

    @property
    def stencil_size(self) -> int:
        """S = s_x s_y s_z points per basis."""
        return int(np.prod(self.stencil))

    @property
    def points(self) -> int:
        return int(np.prod(self.shape))

    @cached_property
    def padded(self) -> tuple[int, int, int]:
        """FFT lengths P ≥ 2n − 1 (smooth) per axis."""
        return tuple(fast_length(2 * n - 1) for n in self.shape)

    @property
    def padded_points(self) -> int:
        return int(np.prod(self.padded))

    def axis_coordinates(self, axis: int) -> np.ndarray:
        """Coordinates (µm) of the grid points along ``axis``."""
        return (self.lattice_start[axis] + np.arange(self.shape[axis])) * self.spacing[axis]

    @cached_property
    def stencil_offsets(self) -> np.ndarray:
        """(S, 3) index offsets of the stencil slots from the origin (slot = (a·s_y + b)·s_z + c)."""
        sx, sy, sz = self.stencil
        a, b, c = np.meshgrid(np.arange(sx), np.arange(sy), np.arange(sz), indexing="ij")
        return np.stack([a.ravel(), b.ravel(), c.ravel()], axis=1)

    def stencil_points(self, bases=None) -> np.ndarray:
        """Grid indices (…, S, 3) of the stencil points of ``bases`` (default all)."""
        o = self.origins if bases is None else self.origins[bases]
        return o[..., None, :] + self.stencil_offsets

    def stencil_positions(self, bases=None) -> np.ndarray:
        """Coordinates (µm) of the stencil points, shape (…, S, 3)."""
        idx = self.stencil_points(bases) + np.asarray(self.lattice_start)
        return idx * np.asarray(self.spacing)

    def linear_index(self, ijk: np.ndarray) -> np.ndarray:
        """Row-major linear index into the compact (n_x, n_y, n_z) grid."""
        ijk = np.asarray(ijk)
        nx, ny, nz = self.shape
        return (ijk[..., 0] * ny + ijk[..., 1]) * nz + ijk[..., 2]

    def inverse_map(self) -> tuple[np.ndarray, np.ndarray]:
        """CSR map grid point → entries e = basis·S + slot touching it: (pointer (points+1,), entries)."""
        flat = self.linear_index(self.stencil_points()).ravel()
        order = np.argsort(flat, kind="stable")
        counts = np.bincount(flat, minlength=self.points)
        pointer = np.zeros(self.points + 1, dtype=np.int64)
        np.cumsum(counts, out=pointer[1:])
        if pointer[-1] >= 2**31:
            raise ValueError(f"AIM inverse map has {pointer[-1]} entries, more than int32 indexing allows")
        return pointer.astype(np.int32), order.astype(np.int32)

    def describe(self) -> str:
        dx, dy, dz = self.spacing
        return (
            f"AIM grid {self.shape[0]}x{self.shape[1]}x{self.shape[2]} (Δ = {dx:.4g}, {dy:.4g}, {dz:.4g} µm), "
            f"stencil {self.stencil[0]}x{self.stencil[1]}x{self.stencil[2]}, FFT {self.padded[0]}x{self.padded[1]}x{self.padded[2]}"
        )


def _lattice_range(first: np.ndarray, size: int) -> tuple[int, int]:
    return int(first.min()), int(first.max()) + size - int(first.min())


def build_grid(mesh: BEMMesh, options: GridOptions | None = None) -> AIMGrid:
    """The AIM grid of ``mesh``: spacings, stencil origins of every basis, grid extent."""
    options = options or GridOptions()
    d = mesh.spacing_um
    sx, sy, sz = options.stencil
    if sz == 0:
        sz = 1 if np.ptp(mesh.heights) == 0.0 and float(mesh.heights.flat[0]) == 0.0 else 3
    spacing = (options.spacing_cells * d, options.spacing_cells * d, options.z_spacing_cells * d)
    centres = mesh.basis_centres
    first = np.stack(
        [stencil_first(centres[:, axis] / spacing[axis], size) for axis, size in enumerate((sx, sy, sz))], axis=1
    )
    starts, shape = zip(*(_lattice_range(first[:, axis], size) for axis, size in enumerate((sx, sy, sz))))
    origins = (first - np.asarray(starts)).astype(np.int32)
    grid = AIMGrid(spacing=spacing, lattice_start=tuple(starts), shape=tuple(shape), stencil=(sx, sy, sz),
                   origins=origins)
    logger.info("%s", grid.describe())
    return grid
