"""Near-field correction C = A − B of the AIM operator: pattern, memory-lean offset storage, SpMV.

Near pairs (bem3d.md §5.3, §6.4) are rooftop pairs whose centres are within ``radius_cells``·d
of each other in x, y (Euclidean; heights only increase the true distance, so the far pairs of
this test are never closer than the radius). On the regular rooftop lattice the pattern is
translation invariant, so no column index is stored (the rooftop index spaces are in mesh.py,
twins of kernels/near_index.h):

* block "HH" (horizontal rows and columns) and "VV" keep the upper half of the offsets
  (a, b) with a² + b² ≤ r² and (b > 0 or b = 0, a ≥ 0), since Z is complex-symmetric;
* block "HV" keeps all offsets from a horizontal rooftop (x, y) to the vertical (x + a, y + b),
  centre offset (a − ½, b + ½).

Values [ee, em, mm] (Z_EE, Z_EM = Z_ME, Z_MM of the pair) are kept in diagonal storage on the
rooftop lattice (kernels/sparse.cl): rooftop (x, y) of either orientation sits at lattice site
(G + y) P + x, rows of pitch P ≥ N + max|a| (zero pad sites) and G zero guard rows above and
below, so offset (a, b) is the shift a + P b for every row and a shifted read stays on zeros
outside the patch. Rows are grouped in tiles of ``TILE_ROWS``; each block is one real array
(n_offsets, tiles, 3, [re, im], TILE_ROWS, P), so the values of one offset over one tile are 6
contiguous runs (what the SpMV streams). Entries are zero where the column falls outside the
patch and at sites without a rooftop. Stored in single precision by default
(``storage="single"``; the AIM error it sits next to is ~1e-4, float32 rounding 6e-8) or double.
Memory ≈ 24 B × (n_HH + n_VV + n_HV)/2 per unknown in single precision, times the pads and
guards (P · 8 tiles / N²: 1.26 at N = 96, 1.06 at N = 400).

The entries are computed by near_assembly.py. C x is applied by kernels/sparse.cl
(``near_tiles`` streams the shifted products tile by tile in SIMD vectors; ``near_move`` moves
the vectors on and off the lattice); :meth:`NearMatrix.apply_numpy` is the NumPy twin.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse

from wavebrdf.solver.bem3d.mesh import near_coords, near_first, near_row, near_valid
from wavebrdf.solver.precision import Precision

__all__ = [
    "BLOCKS",
    "STORAGE",
    "TILE_ROWS",
    "NearMatrix",
    "NearPattern",
    "offset_matrix",
]

STORAGE = {"single": np.complex64, "double": np.complex128}
LATTICE_ALIGN = 8  # row pitch and pads are multiples of the widest SIMD vector (WB_VW ≤ 8)
TILE_ROWS = 8  # lattice rows per tile of the SpMV (docs/aim.md: 4-16 measured alike)
# block name → (row orientation, column orientation, which offset set)
BLOCKS = {"HH": (0, 0, "same"), "VV": (1, 1, "same"), "HV": (0, 1, "cross")}


# ---------------------------------------------------------------------------------------------
# Pattern


@dataclass(frozen=True)
class NearPattern:
    """Offsets of the near pairs of an N×N-cell mesh within ``radius_cells`` (see module doc)."""

    cells: int
    radius_cells: float
    same: np.ndarray  # (n, 2) int32, upper half
    cross: np.ndarray  # (m, 2) int32

    @classmethod
    def build(cls, cells: int, radius_cells: float) -> "NearPattern":
        if not (np.isfinite(radius_cells) and radius_cells >= 1.0):
            raise ValueError(f"aim near_cells must be >= 1, got {radius_cells!r}")
        r = int(np.ceil(radius_cells)) + 1
        a, b = np.meshgrid(np.arange(-r, r + 1), np.arange(-r, r + 1), indexing="ij")
        a, b = a.ravel(), b.ravel()
        r2 = radius_cells**2 * (1 + 1e-12)
        upper = (b > 0) | ((b == 0) & (a >= 0))
        same = np.stack([a, b], axis=1)[(a**2 + b**2 <= r2) & upper]
        cross = np.stack([a, b], axis=1)[(a - 0.5) ** 2 + (b + 0.5) ** 2 <= r2]
        return cls(int(cells), float(radius_cells), same.astype(np.int32), cross.astype(np.int32))

    def offsets(self, block: str) -> np.ndarray:
        return self.same if BLOCKS[block][2] == "same" else self.cross

    @property
    def pitch(self) -> int:
        """Sites per lattice row P: N sites and at least max|a| zero pad sites, both aligned."""
        reach = int(np.max(np.abs(np.concatenate([self.same[:, 0], self.cross[:, 0]]))))
        return _aligned(self.cells) + _aligned(reach)

    @property
    def guard_rows(self) -> int:
        """Zero rows above and below the N lattice rows: max|b| + 1 (a shifted read stays inside)."""
        return int(np.max(np.abs(np.concatenate([self.same[:, 1], self.cross[:, 1]])))) + 1

    @property
    def tiles(self) -> int:
        """Tiles of ``TILE_ROWS`` rows covering the N rows and both guards."""
        return -(-(self.cells + 2 * self.guard_rows) // TILE_ROWS)

    @property
    def lattice_length(self) -> int:
        """Length L of one lattice array: tiles × TILE_ROWS rows of P sites."""
        return self.tiles * TILE_ROWS * self.pitch

    def site(self, o: int, rows) -> np.ndarray:
        """Lattice site (G + y) P + x of block-local rows of orientation o (kernels/sparse.cl)."""
        x, y = near_coords(o, self.cells, rows)
        return (self.guard_rows + np.asarray(y, np.int64)) * self.pitch + x

    def within(self, block: str, radius_cells: float) -> np.ndarray:
        """Indices of the block's offsets whose centre distance is ≤ ``radius_cells``."""
        off = self.offsets(block).astype(float)
        if BLOCKS[block][2] == "cross":
            off = off + [-0.5, 0.5]
        return np.flatnonzero(np.sum(off**2, axis=1) <= radius_cells**2 * (1 + 1e-12))

    @property
    def rows(self) -> int:
        """Rows per block: N(N−1) rooftops of each orientation."""
        return self.cells * (self.cells - 1)

    def stored_entries(self) -> int:
        """Stored (offset, site) slots of all blocks (including out-of-patch zeros and the guards)."""
        return self.lattice_length * (2 * len(self.same) + len(self.cross))

    def pairs(self, block: str, rows: np.ndarray, which: np.ndarray | None = None):
        """Valid pairs of ``rows`` (block-local row indices): (row geometric id, column id, offset j, row position);
        with ``which`` (indices into the block's offsets) only those offsets, j indexing ``which``."""
        orow, ocol, _ = BLOCKS[block]
        N = self.cells
        offsets = self.offsets(block) if which is None else self.offsets(block)[which]
        x, y = near_coords(orow, N, rows)
        cx = x[None, :] + offsets[:, 0:1]
        cy = y[None, :] + offsets[:, 1:2]
        j, pos = np.nonzero(near_valid(ocol, N, cx, cy))
        row_id = near_first(orow, N) + np.asarray(rows)[pos]
        col_id = near_first(ocol, N) + near_row(ocol, N, cx[j, pos], cy[j, pos])
        return row_id, col_id, j, pos

    def nnz(self) -> int:
        """Number of distinct nonzero basis pairs of Z covered (both triangles, 3 blocks each)."""
        total = 0
        for block in BLOCKS:
            rows = np.arange(self.rows)
            row_id, col_id, _, _ = self.pairs(block, rows)
            total += len(row_id) if block == "HV" else 2 * len(row_id) - np.count_nonzero(row_id == col_id)
        return total + len(self.pairs("HV", np.arange(self.rows))[0])


# ---------------------------------------------------------------------------------------------
# The matrix


def offset_matrix(pattern: NearPattern, entries, offset_index: dict | None = None, dtype=complex,
                  fmt: str = "csr", rows: tuple[np.ndarray, np.ndarray] | None = None) -> scipy.sparse.spmatrix:
    """Sparse 2N_b × 2N_b matrix (both triangles) of near-pattern entries.

    ``entries(block, j, pos)``: the (P, 3) [ee, em, mm] of stored offsets j at block-local rows
    pos; ``offset_index[block]`` maps the stored offsets to pattern offsets (default all).
    ``rows`` = (kept, reach), boolean per rooftop: only the rows of the kept rooftops (J and M, each
    complete), read from the pairs of the rooftops in ``reach`` (which must hold every rooftop within
    the pattern's radius of a kept one): a band of the matrix without building the rest.
    """
    nb = 2 * pattern.rows
    r_list, c_list, v_list = [], [], []
    for block in BLOCKS:
        local = np.arange(pattern.rows)
        if rows is not None:
            local = local[rows[1][near_first(BLOCKS[block][0], pattern.cells) + local]]
        row_id, col_id, j, pos = pattern.pairs(block, local, None if offset_index is None else offset_index[block])
        v = entries(block, j, local[pos])  # (P, 3)
        row_id, col_id = row_id.astype(np.int32), col_id.astype(np.int32)  # 4 bytes: 2·2N_b < 2³¹
        direct = slice(None) if rows is None else rows[0][row_id]
        mirror = row_id != col_id
        if rows is not None:
            mirror &= rows[0][col_id]
        for (ro, co, comp) in ((0, 0, 0), (0, nb, 1), (nb, 0, 1), (nb, nb, 2)):
            r_list += [row_id[direct] + ro, col_id[mirror] + ro]
            c_list += [col_id[direct] + co, row_id[mirror] + co]
            v_list += [v[direct, comp], v[mirror, comp]]
    ids = np.concatenate(r_list)
    cols = np.concatenate(c_list)
    vals = np.concatenate(v_list).astype(dtype, copy=False)
    del r_list, c_list, v_list
    return scipy.sparse.coo_matrix((vals, (ids, cols)), shape=(2 * nb, 2 * nb)).asformat(fmt)


def _aligned(n: int) -> int:
    return -(-int(n) // LATTICE_ALIGN) * LATTICE_ALIGN


@dataclass
class NearMatrix:
    """C in lattice diagonal storage: ``values[block]`` real (n_offsets, tiles, 3, 2, TILE_ROWS, P)
    (module doc).

    ``exact[block]`` (optional) keeps the exact entries A of the offsets ``exact_offsets[block]``
    (the pairs within the preconditioner radius) as complex (n, N(N−1), 3) [ee, em, mm].
    """

    pattern: NearPattern
    values: dict
    timings: dict = field(default_factory=dict)
    exact: dict | None = None
    exact_offsets: dict | None = None
    _device: dict | None = field(default=None, repr=False)
    _lattice_vectors: dict = field(default_factory=dict, repr=False)

    @staticmethod
    def zeros(pattern: NearPattern, storage: str) -> dict:
        """Zero value arrays of every block for ``storage`` ("single" | "double")."""
        real = np.finfo(STORAGE[storage]).dtype
        shape = (pattern.tiles, 3, 2, TILE_ROWS, pattern.pitch)
        return {b: np.zeros((len(pattern.offsets(b)),) + shape, dtype=real) for b in BLOCKS}

    def _place(self, block: str, rows):
        """(tile, row in tile, site in row) of block-local rows in the value arrays."""
        row, x = np.divmod(self.pattern.site(BLOCKS[block][0], rows), self.pattern.pitch)
        tile, in_tile = np.divmod(row, TILE_ROWS)
        return tile, in_tile, x

    def entries(self, block: str, j, rows) -> np.ndarray:
        """Complex (n, 3) [ee, em, mm] of pattern offsets j (n,) at block-local rows (n,)."""
        v = self.values[block]
        t, r, x = self._place(block, rows)
        return v[j, t, :, 0, r, x] + 1j * v[j, t, :, 1, r, x]

    def store(self, block: str, rows, staged: np.ndarray):
        """Write complex ``staged`` (n_offsets, len(rows), 3) as the entries of block-local ``rows``:
        each run of consecutive sites on one lattice row (whole rows of a strip) by one slice."""
        if len(rows) == 0:
            return
        t, r, x = self._place(block, rows)
        v = self.values[block]
        line = t * TILE_ROWS + r
        order = np.lexsort((x, line))
        line, x = line[order], x[order]
        # runs: same lattice row and consecutive sites
        starts = np.flatnonzero(np.concatenate([[True], (np.diff(line) != 0) | (np.diff(x) != 1)]))
        ends = np.append(starts[1:], len(order))
        identity = np.array_equal(order, np.arange(len(order)))
        for a, b in zip(starts.tolist(), ends.tolist()):
            part = staged[:, a:b] if identity else staged[:, order[a:b]]  # (n_offsets, run, 3)
            tile, row = divmod(int(line[a]), TILE_ROWS)
            sites = slice(int(x[a]), int(x[a]) + b - a)
            v[:, tile, :, 0, row, sites] = part.real.transpose(0, 2, 1)
            v[:, tile, :, 1, row, sites] = part.imag.transpose(0, 2, 1)

    @property
    def n_bases(self) -> int:
        return 2 * self.pattern.rows

    def bytes(self) -> int:
        return int(sum(v.nbytes for v in self.values.values()))

    def to_sparse(self) -> scipy.sparse.csr_matrix:
        """The full 2N_b × 2N_b correction matrix (both triangles) as scipy CSR (for tests)."""
        return offset_matrix(self.pattern, self.entries)

    def exact_sparse(self, dtype=complex, fmt: str = "csc", rows: tuple[np.ndarray, np.ndarray] | None = None):
        """The exact near entries kept by the assembly (``exact_cells``): all, or the band ``rows``
        (:func:`offset_matrix`)."""
        if self.exact is None:
            raise ValueError("the near field was assembled without exact_cells: no exact entries kept")
        return offset_matrix(self.pattern, lambda b, j, rows: self.exact[b][j, rows], self.exact_offsets, dtype, fmt,
                             rows)

    def apply_numpy(self, x: np.ndarray) -> np.ndarray:
        """C x for x (P, 2N_b) (NumPy twin of the sparse.cl kernels)."""
        return (self.to_sparse() @ np.atleast_2d(x).T).T

    # -- device --------------------------------------------------------------------------------
    def upload(self, ctx):
        """Device buffers of the values (split by offsets where a block exceeds max allocation)."""
        max_alloc = int(ctx.info.max_alloc_gib * 2**30)
        device = {}
        for block, values in self.values.items():
            offsets = self.pattern.offsets(block)
            per_offset = values[0].nbytes if len(values) else 1
            step = max(1, max_alloc // max(per_offset, 1))
            parts = []
            for j0 in range(0, len(values), step):
                j1 = min(len(values), j0 + step)
                parts.append((ctx.to_device(offsets[j0:j1], np.int32), j1 - j0, ctx.host_buffer(values[j0:j1])))
            device[block] = parts
        self._device = device

    def _vectors(self, ctx, batch: int, real: np.dtype):
        """Zeroed lattice vectors X, Y (batch, 2, 2, 2, L) on the device, kept for one batch size."""
        key = (batch, np.dtype(real).char)
        if key not in self._lattice_vectors:
            zeros = np.zeros(batch * 8 * self.pattern.lattice_length, dtype=real)
            self._lattice_vectors = {key: tuple(ctx.to_device(zeros, writable=True) for _ in range(2))}
        return self._lattice_vectors[key]

    def apply(self, ctx, x_buf, y_buf, batch: int, precision: Precision, lanes: int | None = None):
        """y += C x on the device for ``batch`` right-hand sides (buffers of 2N_b complex each) in
        ``precision``.

        ``lanes``: sites per SIMD vector (WB_VW); default 256-bit vectors on CPUs, where a
        work-item takes whole rows of a tile, and 1 on GPUs, one site per work-item.
        """
        if self._device is None:
            self.upload(ctx)
        storage64 = next(iter(self.values.values())).dtype == np.float64
        if lanes is None:
            lanes = ctx.vector_lanes(precision)
        defines = ctx.defines(precision, lanes=lanes, NEAR_BATCH=batch, NEAR_FP64=int(storage64))
        pattern = self.pattern
        N, P, L = np.int32(pattern.cells), np.int32(pattern.pitch), np.int32(pattern.lattice_length)
        first_row = np.int32(pattern.guard_rows)
        X, Y = self._vectors(ctx, batch, precision.real)
        queue = ctx.queue
        move = ctx.kernel("sparse.cl", "near_move", defines)
        move(queue, (self.n_bases,), None, np.int32(1), N, P, first_row, L, X, x_buf)
        tiles = ctx.kernel("sparse.cl", "near_tiles", defines)
        row_vectors = -(-pattern.cells // lanes)
        xvectors = row_vectors if lanes > 1 else 1  # CPU: whole rows per work-item; GPU: one site
        items = (pattern.tiles, -(-row_vectors // xvectors))
        local = (1, 1) if lanes > 1 else None  # CPU: one tile per work-group, spread over the cores
        for o, own in ((0, "HH"), (1, "VV")):
            for same, cross in itertools.zip_longest(self._device[own], self._device["HV"]):
                s_ab, s_n, s_vals = same or (self._device[own][0][0], 0, self._device[own][0][2])
                c_ab, c_n, c_vals = cross or (self._device["HV"][0][0], 0, self._device["HV"][0][2])
                tiles(queue, items, local, np.int32(o), N, P, np.int32(TILE_ROWS), np.int32(pattern.tiles), first_row,
                      np.int32(xvectors), s_ab, np.int32(s_n), s_vals, c_ab, np.int32(c_n), c_vals, X, Y)
        move(queue, (self.n_bases,), None, np.int32(0), N, P, first_row, L, Y, y_buf)
