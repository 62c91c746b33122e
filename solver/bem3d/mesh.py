"""Bilinear quadrilaterals on the height grid and rooftop basis functions on interior edges.

Geometry (bem3d.md §3.2). Cell (s, t) of an N×N height grid (s ↔ x, rows; t ↔ y, columns) is the
bilinear patch over (u, v) ∈ [−1, 1]²::

    x = x_c + h u,  y = y_c + h v,  z = z00 + z10 u + z01 v + z11 u v,   h = d/2

with a = z[s, t], b = z[s+1, t], c = z[s, t+1], e = z[s+1, t+1] and
z00 = (a+b+c+e)/4, z10 = (−a+b−c+e)/4, z01 = (−a−b+c+e)/4, z11 = (a−b−c+e)/4.
Tangents r_u = (h, 0, z10 + z11 v), r_v = (0, h, z01 + z11 u). Element index e = s·N + t.

Half-basis functions (bem3d.md §3.3), numbered by *slot* 0..3 on every element::

    slot 0: u⁻ = (1−u) r_u / J     slot 1: u⁺ = (1+u) r_u / J
    slot 2: v⁻ = (1−v) r_v / J     slot 3: v⁺ = (1+v) r_v / J

with surface divergence sign (−, +, −, +)/J. In every Galerkin integral f dA = c(u,v) t du dv with
c ∈ {1−u, 1+u, 1−v, 1+v} and t ∈ {r_u, r_v}, so the Jacobian J cancels.

Rooftops (unknowns) live on interior edges only; the current has no normal flow out of the patch.

* horizontal (x-directed) basis m = (N−1)·m_y + m_x, m_x ∈ [0, N−2], m_y ∈ [0, N−1]:
  u⁺ on element (m_x, m_y) and u⁻ on element (m_x+1, m_y); shared edge x = x_{m_x+1}.
* vertical (y-directed) basis N(N−1) + (N−1)·m_x + m_y: v⁺ on (m_x, m_y), v⁻ on (m_x, m_y+1).

Geometric basis index g ∈ [0, N_b), N_b = 2N(N−1) (horizontal first). The unknown vector is
**[J_h | J_v | M̃_h | M̃_v]**: J coefficient of basis g at position g, M̃ = M/η₀ at N_b + g.

Rooftop index spaces (NumPy twins of kernels/near_index.h): rooftop (x, y) of orientation o
(0 horizontal, 1 vertical) has the block-local *row* :func:`near_row` and the geometric index
:func:`near_first` (o) + row; :func:`near_coords` inverts it, :func:`near_valid` tells which (x, y)
exist. The AIM near field, its preconditioner tiles and the flat continuation count rooftops
through these.
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from wavebrdf.solver.surface import HeightField

logger = logging.getLogger(__name__)

__all__ = [
    "BEMMesh",
    "SLOT_SIGN",
    "SLOT_TANGENT",
    "embedded_bases",
    "near_coords",
    "near_first",
    "near_row",
    "near_valid",
    "slot_weight",
    "unknown_indices",
]

SLOT_SIGN = np.array([-1.0, 1.0, -1.0, 1.0])  # divergence sign of each half-basis slot
SLOT_TANGENT = np.array([0, 0, 1, 1])  # 0: r_u, 1: r_v


def slot_weight(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The four half-basis weights c = (1−u, 1+u, 1−v, 1+v), shape (4,) + u.shape."""
    u = np.asarray(u, dtype=float)
    v = np.asarray(v, dtype=float)
    return np.stack([1.0 - u, 1.0 + u, 1.0 - v, 1.0 + v])


@dataclass(frozen=True)
class BEMMesh:
    """Elements and rooftop bases of a height field (patch coordinates, µm).

    ``z_reference`` is subtracted from the heights (default: the patch mean, bem3d.md §3.1), so
    z = 0 is the beam focus plane and the far-field phase reference.
    """

    surface: HeightField
    z_reference: float | None = None

    # ---- geometry ------------------------------------------------------------------------
    @property
    def cells(self) -> int:
        """N, cells per side."""
        return self.surface.cells

    @property
    def spacing_um(self) -> float:
        """d, the cell size (µm)."""
        return self.surface.spacing_um

    @property
    def half(self) -> float:
        """h = d/2, the (u, v) → (x, y) scale."""
        return 0.5 * self.surface.spacing_um

    @cached_property
    def heights(self) -> np.ndarray:
        """Corner heights minus the reference (µm), shape (N+1, N+1)."""
        ref = float(np.mean(self.surface.z)) if self.z_reference is None else float(self.z_reference)
        return self.surface.z - ref

    @cached_property
    def digest(self) -> tuple:
        """What makes two meshes the same geometry: a hash of the heights (reference subtracted),
        their shape and the patch size (µm)."""
        heights = np.ascontiguousarray(self.heights, dtype=float)
        return (hashlib.sha1(heights.tobytes()).hexdigest(), heights.shape, float(self.surface.size_um))

    @property
    def n_elements(self) -> int:
        return self.cells**2

    @cached_property
    def element_st(self) -> np.ndarray:
        """(s, t) cell indices of each element, shape (N², 2); e = s·N + t."""
        n = self.cells
        s, t = np.divmod(np.arange(n * n), n)
        return np.stack([s, t], axis=1)

    @cached_property
    def geometry(self) -> np.ndarray:
        """Per-element coefficients (x_c, y_c, z00, z10, z01, z11, 0, 0), shape (N², 8), float64."""
        z = self.heights
        a, b, c, e = z[:-1, :-1], z[1:, :-1], z[:-1, 1:], z[1:, 1:]
        x = self.surface.x
        xc = 0.5 * (x[:-1] + x[1:])
        XC, YC = np.meshgrid(xc, xc, indexing="ij")
        g = np.zeros((self.n_elements, 8))
        g[:, 0] = XC.ravel()
        g[:, 1] = YC.ravel()
        g[:, 2] = (0.25 * (a + b + c + e)).ravel()
        g[:, 3] = (0.25 * (-a + b - c + e)).ravel()
        g[:, 4] = (0.25 * (-a - b + c + e)).ravel()
        g[:, 5] = (0.25 * (a - b - c + e)).ravel()
        return g

    def points(self, elements: np.ndarray, u: np.ndarray, v: np.ndarray):
        """Positions r and tangents r_u, r_v at (u, v) on ``elements`` (broadcast), each (..., 3)."""
        g = self.geometry[np.asarray(elements)]
        return bilinear_frame(g, self.half, u, v)

    @cached_property
    def element_radius(self) -> np.ndarray:
        """Distance from each element's centre point (u = v = 0) to its farthest corner (µm)."""
        g = self.geometry
        centre = np.stack([g[:, 0], g[:, 1], g[:, 2]], axis=1)
        radius = np.zeros(self.n_elements)
        for cu in (-1.0, 1.0):
            for cv in (-1.0, 1.0):
                r, _, _ = bilinear_frame(g, self.half, np.full(len(g), cu), np.full(len(g), cv))
                radius = np.maximum(radius, np.linalg.norm(r - centre, axis=1))
        return radius

    @cached_property
    def half_length(self) -> np.ndarray:
        """Largest parameter half-length max(|r_u|, |r_v|) over each element's corners (µm)."""
        g = self.geometry
        longest = np.zeros(self.n_elements)
        for cu in (-1.0, 1.0):
            for cv in (-1.0, 1.0):
                _, ru, rv = bilinear_frame(g, self.half, np.full(len(g), cu), np.full(len(g), cv))
                longest = np.maximum(longest, np.maximum(np.linalg.norm(ru, axis=1), np.linalg.norm(rv, axis=1)))
        return longest

    # ---- bases ---------------------------------------------------------------------------
    @property
    def n_horizontal(self) -> int:
        return (self.cells - 1) * self.cells

    @property
    def n_bases(self) -> int:
        """N_b = 2N(N−1) geometric rooftops (J and M̃ each use all of them)."""
        return 2 * self.cells * (self.cells - 1)

    @property
    def n_unknowns(self) -> int:
        """4N(N−1): [J_h | J_v | M̃_h | M̃_v]."""
        return 2 * self.n_bases

    @cached_property
    def basis_elements(self) -> np.ndarray:
        """Element indices of each basis' two halves, shape (N_b, 2): [plus side, minus side]."""
        n = self.cells
        mx, my = np.meshgrid(np.arange(n - 1), np.arange(n), indexing="xy")  # m = (N−1)·my + mx
        horizontal = np.stack([mx.ravel() * n + my.ravel(), (mx.ravel() + 1) * n + my.ravel()], axis=1)
        ax, ay = np.meshgrid(np.arange(n), np.arange(n - 1), indexing="ij")  # m = (N−1)·mx + my
        vertical = np.stack([ax.ravel() * n + ay.ravel(), ax.ravel() * n + ay.ravel() + 1], axis=1)
        return np.concatenate([horizontal, vertical]).astype(np.int64)

    @cached_property
    def basis_slots(self) -> np.ndarray:
        """Half-basis slot on each of the two elements, shape (N_b, 2): (1, 0) or (3, 2)."""
        slots = np.empty((self.n_bases, 2), dtype=np.int64)
        slots[: self.n_horizontal] = (1, 0)
        slots[self.n_horizontal :] = (3, 2)
        return slots

    @cached_property
    def element_bases(self) -> np.ndarray:
        """Basis index occupying each (element, slot), −1 on the patch boundary; shape (N², 4)."""
        table = np.full((self.n_elements, 4), -1, dtype=np.int64)
        for side in range(2):
            table[self.basis_elements[:, side], self.basis_slots[:, side]] = np.arange(self.n_bases)
        return table

    @cached_property
    def basis_centres(self) -> np.ndarray:
        """Midpoint of each basis' shared edge (µm), shape (N_b, 3)."""
        plus = self.basis_elements[:, 0]
        horizontal = np.arange(self.n_bases) < self.n_horizontal
        u = np.where(horizontal, 1.0, 0.0)
        v = np.where(horizontal, 0.0, 1.0)
        r, _, _ = self.points(plus, u, v)
        return r


def bilinear_frame(geometry: np.ndarray, half: float, u, v):
    """r, r_u, r_v of bilinear elements with coefficients ``geometry`` (..., 8) at (u, v)."""
    g = np.asarray(geometry)
    u = np.asarray(u, dtype=float)
    v = np.asarray(v, dtype=float)
    xc, yc, z00, z10, z01, z11 = (g[..., i] for i in range(6))
    x = xc + half * u
    y = yc + half * v
    z = z00 + z10 * u + z01 * v + z11 * u * v
    zu = z10 + z11 * v
    zv = z01 + z11 * u
    zero = np.zeros_like(zu)
    hh = np.full_like(zu, half)
    r = np.stack(np.broadcast_arrays(x, y, z), axis=-1)
    ru = np.stack(np.broadcast_arrays(hh, zero, zu), axis=-1)
    rv = np.stack(np.broadcast_arrays(zero, hh, zv), axis=-1)
    return r, ru, rv


# ---------------------------------------------------------------------------------------------
# Rooftop index spaces (NumPy twins of kernels/near_index.h; see the module docstring)


def near_valid(o, N, x, y):
    """Whether rooftop (x, y) of orientation o exists on an N-cell mesh."""
    x, y = np.asarray(x), np.asarray(y)
    if o == 0:
        return (x >= 0) & (x <= N - 2) & (y >= 0) & (y <= N - 1)
    return (x >= 0) & (x <= N - 1) & (y >= 0) & (y <= N - 2)


def near_row(o, N, x, y):
    """Block-local row of rooftop (x, y) of orientation o."""
    return (N - 1) * np.asarray(y) + np.asarray(x) if o == 0 else (N - 1) * np.asarray(x) + np.asarray(y)


def near_first(o, N) -> int:
    """Geometric index of the first rooftop of orientation o (0 or N(N−1))."""
    return 0 if o == 0 else N * (N - 1)


def near_coords(o, N, row):
    """(x, y) of block-local rows of orientation o (inverse of :func:`near_row`)."""
    row = np.asarray(row)
    return (row % (N - 1), row // (N - 1)) if o == 0 else (row // (N - 1), row % (N - 1))


def embedded_bases(cells: int, margin: int) -> np.ndarray:
    """Geometric index of every rooftop of an N-cell mesh in the mesh grown by ``margin`` cells on
    every side (both in this numbering)."""
    n, N = cells, cells + 2 * margin
    out = []
    for o in (0, 1):  # horizontal, vertical
        x, y = near_coords(o, n, np.arange(n * (n - 1)))
        out.append(near_first(o, N) + near_row(o, N, x + margin, y + margin))
    return np.concatenate(out)


def unknown_indices(bases: np.ndarray, n_bases: int) -> np.ndarray:
    """Positions of the J and M̃ coefficients of ``bases`` in a [J | M̃] vector of n_bases rooftops."""
    return np.concatenate([bases, n_bases + bases])
