"""Near-field correction C = A − B of the AIM operator, in a memory-lean offset format.

Near pairs (bem3d.md §5.3, §6.4) are rooftop pairs whose centres are within ``radius_cells``·d
of each other in x, y (Euclidean; heights only increase the true distance, so the far pairs of
this test are never closer than the radius). On the regular rooftop lattice the pattern is
translation invariant, so no column index is stored (kernels/near_index.h for the index spaces):

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

Assembly, per strip of rows (one chunk of y lines):

1. A: the exact entries from the part-1 element integrals (assembly.basis_pair_entries, the
   static singular tables cached per geometry; element pairs of repeating geometry, e.g.
   flat or 1-D periodic patches, are computed once, :class:`RepeatingTables`);
2. B: the grid approximation of the same pairs with exactly the sampled kernel of the FFT path
   (kernels/aim_near.cl: grid potentials of each row's stencil on a window, then the column's
   stencil sum), subtracted in double precision for every grid medium.

C x is applied by kernels/sparse.cl (``near_tiles`` streams the shifted products tile by tile in
SIMD vectors; ``near_move`` moves the vectors on and off the lattice).
"""

from __future__ import annotations

import itertools
import logging
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse

from wavebrdf.solver.bem3d.aim_base import int4_arg, shared_buffer
from wavebrdf.solver.bem3d.aim_green import lattice_green
from wavebrdf.solver.bem3d.assembly import basis_pair_entries
from wavebrdf.solver.bem3d.elements import ElementIntegrals, vector_lanes
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import BEMMesh
from wavebrdf.solver.bem3d.projection import Projection
from wavebrdf.solver.farfield import ETA0

logger = logging.getLogger(__name__)

__all__ = [
    "BLOCKS",
    "TILE_ROWS",
    "NearMatrix",
    "NearPattern",
    "RepeatingTables",
    "assemble_near",
    "near_base_numpy",
    "near_coords",
    "near_first",
    "near_row",
    "near_valid",
]

STORAGE = {"single": np.complex64, "double": np.complex128}
LATTICE_ALIGN = 8  # row pitch and pads are multiples of the widest SIMD vector (WB_VW ≤ 8)
TILE_ROWS = 8  # lattice rows per tile of the SpMV (docs/aim.md: 4-16 measured alike)
# block name → (row orientation, column orientation, which offset set)
BLOCKS = {"HH": (0, 0, "same"), "VV": (1, 1, "same"), "HV": (0, 1, "cross")}
PAIRS_PER_CHUNK = 600_000  # stored pairs per assembly chunk (element tables ≈ 1 KB per element pair)
POTENTIAL_BUDGET = 256 * 2**20  # bytes of grid potentials per launch


# ---------------------------------------------------------------------------------------------
# Index spaces (NumPy twins of kernels/near_index.h)


def near_valid(o, N, x, y):
    x, y = np.asarray(x), np.asarray(y)
    if o == 0:
        return (x >= 0) & (x <= N - 2) & (y >= 0) & (y <= N - 1)
    return (x >= 0) & (x <= N - 1) & (y >= 0) & (y <= N - 2)


def near_row(o, N, x, y):
    return (N - 1) * np.asarray(y) + np.asarray(x) if o == 0 else (N - 1) * np.asarray(x) + np.asarray(y)


def near_first(o, N) -> int:
    return 0 if o == 0 else N * (N - 1)


def near_coords(o, N, row):
    row = np.asarray(row)
    return (row % (N - 1), row // (N - 1)) if o == 0 else (row // (N - 1), row % (N - 1))


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

    def pairs(self, block: str, rows: np.ndarray):
        """Valid pairs of ``rows`` (block-local row indices): (row geometric id, column id, offset j, row position)."""
        orow, ocol, _ = BLOCKS[block]
        N = self.cells
        offsets = self.offsets(block)
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
# Element tables of repeating geometry


class RepeatingTables:
    """Drop-in for ElementIntegrals.tables that computes each geometrically distinct pair once.

    Two element pairs are identical when the index offset, the shapes (z10, z01, z11) of both
    elements and the height offset Δz00 are equal bit for bit (flat, tilted or 1-D periodic
    patches). Tables are cached across calls, so strips of a large patch share them.
    """

    def __init__(self, integrals: ElementIntegrals):
        self.integrals = integrals
        mesh = integrals.mesh
        _, self.shape_ids = np.unique(mesh.geometry[:, 3:6], axis=0, return_inverse=True)
        self.shape_ids = self.shape_ids.ravel()
        self.z00 = mesh.geometry[:, 2].copy()
        self.st = mesh.element_st
        self._keys: dict = {}
        self._tables: list = []

    @staticmethod
    def worthwhile(mesh: BEMMesh, fraction: float = 0.25) -> bool:
        return len(np.unique(mesh.geometry[:, 3:6], axis=0)) <= max(1, fraction * mesh.n_elements)

    def tables(self, test, source, wavenumbers) -> np.ndarray:
        test = np.asarray(test)
        source = np.asarray(source)
        d = self.st[source] - self.st[test]
        dz = (self.z00[source] - self.z00[test]).view(np.int64)
        keys = np.stack([d[:, 0], d[:, 1], self.shape_ids[test], self.shape_ids[source], dz], axis=1)
        unique, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
        index = np.empty(len(unique), dtype=np.int64)
        missing = []
        for u, key in enumerate(map(tuple, unique)):
            pos = self._keys.get(key)
            if pos is None:
                missing.append(u)
            else:
                index[u] = pos
        if missing:
            missing = np.asarray(missing)
            fresh = self.integrals.tables(test[first[missing]], source[first[missing]], wavenumbers)
            base = sum(len(t) for t in self._tables)
            self._tables.append(fresh)
            for i, u in enumerate(missing):
                self._keys[tuple(unique[u])] = base + i
                index[u] = base + i
        store = np.concatenate(self._tables) if len(self._tables) > 1 else self._tables[0]
        if len(self._tables) > 1:
            self._tables = [store]
        return store[index[inverse.ravel()]]


# ---------------------------------------------------------------------------------------------
# B of near pairs: NumPy twin (explicit S × S double sum)


def near_base_numpy(projection: Projection, k: complex, coefficients: np.ndarray, n_horizontal: int,
                    rows: np.ndarray, cols: np.ndarray, chunk: int = 256):
    """B entries (ee, em, mm) of basis pairs for one grid medium of wavenumber k.

    ``coefficients`` (ee_vec, ee_div, mm_vec, mm_div) of that medium; the K part uses η₀.
    """
    grid = projection.grid
    W = projection.weights
    out = np.zeros((3, len(rows)), dtype=complex)
    for s in range(0, len(rows), chunk):
        m, n = rows[s : s + chunk], cols[s : s + chunk]
        delta = grid.stencil_points(m)[:, :, None, :] - grid.stencil_points(n)[:, None, :, :]
        g, grad = lattice_green(k, grid.spacing, delta)  # (P, S, S), (P, S, S, 3)

        def vectors(b):
            v = np.zeros((len(b), grid.stencil_size, 3), dtype=W.dtype if np.iscomplexobj(W) else float)
            horizontal = b < n_horizontal
            v[horizontal, :, 0] = W[0, b[horizontal]]
            v[~horizontal, :, 1] = W[0, b[~horizontal]]
            v[:, :, 2] = W[1, b]
            return v

        vm, vn = vectors(m), vectors(n)
        lvec = np.einsum("psc,pst,ptc->p", vm, g, vn)
        ldiv = np.einsum("ps,pst,pt->p", W[2, m], g, W[2, n])
        cross = np.cross(grad, vn[:, None, :, :])  # ∇g(p − q) × f_n(q)
        kk = np.einsum("psc,pstc->p", vm, cross)
        out[0, s : s + chunk] = coefficients[0] * lvec + coefficients[1] * ldiv
        out[1, s : s + chunk] = ETA0 * kk
        out[2, s : s + chunk] = coefficients[2] * lvec + coefficients[3] * ldiv
    return out


# ---------------------------------------------------------------------------------------------
# The matrix


def offset_matrix(pattern: NearPattern, entries, offset_index: dict | None = None, dtype=complex,
                  fmt: str = "csr") -> scipy.sparse.spmatrix:
    """Sparse 2N_b × 2N_b matrix (both triangles) of near-pattern entries.

    ``entries(block, j, pos)``: the (P, 3) [ee, em, mm] of stored offsets j at block-local rows
    pos; ``offset_index[block]`` maps the stored offsets to pattern offsets (default all).
    """
    nb = 2 * pattern.rows
    rows_all = np.arange(pattern.rows)
    r_list, c_list, v_list = [], [], []
    for block in BLOCKS:
        row_id, col_id, j, pos = pattern.pairs(block, rows_all)
        if offset_index is not None:
            lookup = np.full(len(pattern.offsets(block)), -1)
            lookup[offset_index[block]] = np.arange(len(offset_index[block]))
            keep = lookup[j] >= 0
            row_id, col_id, j, pos = row_id[keep], col_id[keep], lookup[j[keep]], pos[keep]
        v = entries(block, j, pos)  # (P, 3)
        mirror = row_id != col_id
        for (ro, co, comp) in ((0, 0, 0), (0, nb, 1), (nb, 0, 1), (nb, nb, 2)):
            r_list += [row_id + ro, col_id[mirror] + ro]
            c_list += [col_id + co, row_id[mirror] + co]
            v_list += [v[:, comp], v[mirror, comp]]
    rows = np.concatenate(r_list)
    cols = np.concatenate(c_list)
    vals = np.concatenate(v_list).astype(dtype)
    return scipy.sparse.coo_matrix((vals, (rows, cols)), shape=(2 * nb, 2 * nb)).asformat(fmt)


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
        """Write complex ``staged`` (n_offsets, len(rows), 3) as the entries of block-local ``rows``."""
        t, r, x = self._place(block, rows)
        v = self.values[block]
        v[:, t, :, 0, r, x] = staged.real.transpose(1, 0, 2)
        v[:, t, :, 1, r, x] = staged.imag.transpose(1, 0, 2)

    @property
    def n_bases(self) -> int:
        return 2 * self.pattern.rows

    def bytes(self) -> int:
        return int(sum(v.nbytes for v in self.values.values()))

    def to_sparse(self) -> scipy.sparse.csr_matrix:
        """The full 2N_b × 2N_b correction matrix (both triangles) as scipy CSR (for tests)."""
        return offset_matrix(self.pattern, self.entries)

    def exact_sparse(self, dtype=complex) -> scipy.sparse.csc_matrix:
        """The exact near entries kept by the assembly (``exact_cells``), CSC."""
        if self.exact is None:
            raise ValueError("the near field was assembled without exact_cells: no exact entries kept")
        return offset_matrix(self.pattern, lambda b, j, rows: self.exact[b][j, rows], self.exact_offsets, dtype, "csc")

    def apply_numpy(self, x: np.ndarray) -> np.ndarray:
        """C x for x (P, 2N_b) (NumPy twin of the sparse.cl kernels)."""
        return (self.to_sparse() @ np.atleast_2d(x).T).T

    # -- device --------------------------------------------------------------------------------
    def upload(self, ctx):
        """Device buffers of the values (split by offsets where a block exceeds max allocation)."""
        import pyopencl as cl

        max_alloc = int(ctx.info.max_alloc_gib * 2**30)
        device = {}
        for block, values in self.values.items():
            offsets = self.pattern.offsets(block)
            per_offset = values[0].nbytes if len(values) else 1
            step = max(1, max_alloc // max(per_offset, 1))
            parts = []
            for j0 in range(0, len(values), step):
                j1 = min(len(values), j0 + step)
                off = cl.Buffer(ctx.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                                hostbuf=np.ascontiguousarray(offsets[j0:j1], np.int32))
                parts.append((off, j1 - j0, shared_buffer(ctx, values[j0:j1])))
            device[block] = parts
        self._device = device

    def _vectors(self, ctx, batch: int, real: np.dtype):
        """Zeroed lattice vectors X, Y (batch, 2, 2, 2, L) on the device, kept for one batch size."""
        import pyopencl as cl

        key = (batch, np.dtype(real).char)
        if key not in self._lattice_vectors:
            zeros = np.zeros(batch * 8 * self.pattern.lattice_length, dtype=real)
            mf = cl.mem_flags
            self._lattice_vectors = {key: tuple(cl.Buffer(ctx.context, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=zeros)
                                                for _ in range(2))}
        return self._lattice_vectors[key]

    def apply(self, ctx, x_buf, y_buf, batch: int, precision_fp64: bool, lanes: int | None = None):
        """y += C x on the device for ``batch`` right-hand sides (buffers of 2N_b complex each).

        ``lanes``: sites per SIMD vector (WB_VW); default 256-bit vectors on CPUs, where a
        work-item takes whole rows of a tile, and 1 on GPUs, one site per work-item.
        """
        if self._device is None:
            self.upload(ctx)
        storage64 = next(iter(self.values.values())).dtype == np.float64
        if lanes is None:
            lanes = vector_lanes(ctx) * (1 if precision_fp64 else 2)
        defines = {"WB_FP64": int(precision_fp64), "NEAR_BATCH": batch, "NEAR_FP64": int(storage64), "WB_VW": lanes}
        pattern = self.pattern
        N, P, L = np.int32(pattern.cells), np.int32(pattern.pitch), np.int32(pattern.lattice_length)
        first_row = np.int32(pattern.guard_rows)
        X, Y = self._vectors(ctx, batch, np.float64 if precision_fp64 else np.float32)
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


# ---------------------------------------------------------------------------------------------
# Assembly


def _windows(grid, pattern: NearPattern, rows_by_block: dict):
    """Window base and size (grid units) covering the columns' stencils of each source orientation."""
    out = {}
    for o in (0, 1):
        rel = []
        for block, (orow, ocol, _) in BLOCKS.items():
            if orow != o or len(rows_by_block[block]) == 0:
                continue
            row_id, col_id, _, _ = pattern.pairs(block, rows_by_block[block])
            rel.append(grid.origins[col_id] - grid.origins[row_id])
        if rel:
            rel = np.concatenate(rel)
            lo = rel.min(axis=0)
            out[o] = (lo, rel.max(axis=0) - lo + np.asarray(grid.stencil))
    return out


def _kernel_table(k, grid, wbase, wdim):
    """g, ∇g on the lattice offsets a window needs: (lo, dims, green (T,), gradient (3, T))."""
    lo = np.asarray(wbase) - (np.asarray(grid.stencil) - 1)
    dims = np.asarray(wdim) + np.asarray(grid.stencil) - 1
    ax = [lo[i] + np.arange(dims[i]) for i in range(3)]
    offsets = np.stack(np.meshgrid(*ax, indexing="ij"), axis=-1)
    g, grad = lattice_green(k, grid.spacing, offsets)
    return lo, dims, g.ravel(), np.moveaxis(grad, -1, 0).reshape(3, -1)


class _NearBaseOpenCL:
    """Device state of the B subtraction: weights of each projection, origins."""

    def __init__(self, ctx, projections):
        import pyopencl as cl

        self.ctx = ctx
        mf = cl.mem_flags
        grid = projections[0].grid
        self.origins = cl.Buffer(ctx.context, mf.READ_ONLY | mf.COPY_HOST_PTR,
                                 hostbuf=np.ascontiguousarray(grid.origins, np.int32))
        self.weights = {id(p): cl.Buffer(ctx.context, mf.READ_ONLY | mf.COPY_HOST_PTR,
                                         hostbuf=np.ascontiguousarray(p.weights, np.result_type(p.weights, np.float64)))
                        for p in projections}

    def subtract(self, projection, k, coef, pattern, block, rows, staged, window, n_horizontal):
        """Subtract B (one medium) from ``staged`` (n_offsets, len(rows), 3) complex128 in place."""
        import pyopencl as cl

        ctx, queue = self.ctx, self.ctx.queue
        mf = cl.mem_flags
        grid = projection.grid
        orow, ocol, _ = BLOCKS[block]
        wbase, wdim = window
        lo, dims, green, gradient = _kernel_table(k, grid, wbase, wdim)
        defines = {"WB_FP64": 1, "AIM_COMPLEX_W": int(np.iscomplexobj(projection.weights))}
        pot_knl = ctx.kernel("aim_near.cl", "aim_near_potentials", defines)
        cor_knl = ctx.kernel("aim_near.cl", "aim_near_correct", defines)
        tables = [cl.Buffer(ctx.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(a, np.complex128))
                  for a in (green, gradient)]
        offsets = pattern.offsets(block)
        off_buf = cl.Buffer(ctx.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(offsets))
        coef_buf = cl.Buffer(ctx.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.asarray(coef, np.complex128))
        nW = int(np.prod(wdim))
        sources = (near_first(orow, pattern.cells) + np.asarray(rows)).astype(np.int32)
        step = max(1, POTENTIAL_BUDGET // (6 * nW * 16))
        weights = self.weights[id(projection)]
        sx, sy, sz = grid.stencil
        for s0 in range(0, len(rows), step):
            s1 = min(len(rows), s0 + step)
            n = s1 - s0
            src_buf = cl.Buffer(ctx.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=sources[s0:s1])
            row_buf = cl.Buffer(ctx.context, mf.READ_ONLY | mf.COPY_HOST_PTR,
                                hostbuf=np.ascontiguousarray(rows[s0:s1], np.int32))
            pot = cl.Buffer(ctx.context, mf.READ_WRITE, n * 6 * nW * 16)
            pot_knl(queue, (n * nW,), None, src_buf, np.int32(n), self.origins, np.int32(2 * pattern.rows),
                    np.int32(n_horizontal), weights, np.int32(sx), np.int32(sy), np.int32(sz), int4_arg(wdim),
                    int4_arg(wbase), int4_arg(lo), int4_arg(dims), *tables, pot)
            chunk = np.ascontiguousarray(staged[:, s0:s1])
            val_buf = cl.Buffer(ctx.context, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=chunk)
            cor_knl(queue, (len(offsets) * n,), None, np.int32(orow), np.int32(ocol), np.int32(pattern.cells),
                    off_buf, np.int32(len(offsets)), row_buf, np.int32(n), self.origins, np.int32(2 * pattern.rows),
                    weights, np.int32(sx), np.int32(sy), np.int32(sz), int4_arg(wdim), int4_arg(wbase), pot,
                    coef_buf, val_buf)
            cl.enqueue_copy(queue, chunk, val_buf)
            staged[:, s0:s1] = chunk
        queue.finish()


def _strips(pattern: NearPattern):
    """Chunks of y lines: rows of each block with their y in the strip (block-local indices)."""
    N = pattern.cells
    per_line = 2 * (N - 1) * (len(pattern.same) + len(pattern.cross) // 2 + 1)
    lines = max(1, PAIRS_PER_CHUNK // max(per_line, 1))
    for y0 in range(0, N, lines):
        y1 = min(N, y0 + lines)
        h_rows = np.arange(y0 * (N - 1), min(y1, N) * (N - 1))  # horizontal rows y ∈ [y0, y1)
        vx, vy = np.meshgrid(np.arange(N), np.arange(y0, min(y1, N - 1)), indexing="ij")
        v_rows = np.sort(near_row(1, N, vx.ravel(), vy.ravel()))
        yield {"HH": h_rows, "HV": h_rows, "VV": v_rows}


def assemble_near(ctx, mesh: BEMMesh, media: Media, pattern: NearPattern, groups, *,
                  integrals: ElementIntegrals | None = None, storage: str = "single",
                  exact_cells: float | None = None, progress=None) -> NearMatrix:
    """C = A − B of all near pairs. ``groups``: list of (Projection, grid-media indices).

    ``exact_cells``: also keep the exact entries A of pairs within this radius (for the
    near-field preconditioner). ``ctx`` None runs the NumPy twins (tiny meshes only).
    """
    if storage not in STORAGE:
        raise ValueError(f"aim near_storage must be one of {tuple(STORAGE)}, got {storage!r}")
    t_start = time.perf_counter()
    integrals = integrals or ElementIntegrals(mesh, ctx=ctx)
    tables = RepeatingTables(integrals) if RepeatingTables.worthwhile(mesh) else integrals
    coef_all = media.pmchwt_coefficients()
    nrows = pattern.rows
    near = NearMatrix(pattern, NearMatrix.zeros(pattern, storage))
    exact_offsets = exact = None
    if exact_cells is not None:
        exact_offsets = {b: pattern.within(b, min(exact_cells, pattern.radius_cells)) for b in BLOCKS}
        exact = {b: np.zeros((len(exact_offsets[b]), nrows, 3), dtype=STORAGE[storage]) for b in BLOCKS}
    device = _NearBaseOpenCL(ctx, [p for p, _ in groups]) if ctx is not None else None
    timings = {"exact_s": 0.0, "base_s": 0.0}
    strips = list(_strips(pattern))
    for i_strip, rows_by_block in enumerate(strips):
        t0 = time.perf_counter()
        pairs = {b: pattern.pairs(b, rows_by_block[b]) for b in BLOCKS}
        all_rows = np.concatenate([p[0] for p in pairs.values()])
        all_cols = np.concatenate([p[1] for p in pairs.values()])
        ee, mm, em = basis_pair_entries(ctx, mesh, media, all_rows, all_cols, integrals=tables)
        staged, start = {}, 0
        for b, (row_id, col_id, j, pos) in pairs.items():
            s = np.zeros((len(pattern.offsets(b)), len(rows_by_block[b]), 3), dtype=complex)
            sl = slice(start, start + len(row_id))
            s[j, pos, 0], s[j, pos, 1], s[j, pos, 2] = ee[sl], em[sl], mm[sl]
            staged[b] = s
            start += len(row_id)
            if exact is not None:
                exact[b][:, rows_by_block[b]] = s[exact_offsets[b]]
        t1 = time.perf_counter()
        windows = _windows(groups[0][0].grid, pattern, rows_by_block) if device is not None else None
        for projection, medium_indices in groups:
            for i in medium_indices:
                k = media.wavenumbers[i]
                coef = [coef_all["ee_vec"][i], coef_all["ee_div"][i], coef_all["mm_vec"][i], coef_all["mm_div"][i]]
                for b, (row_id, col_id, j, pos) in pairs.items():
                    if len(row_id) == 0:
                        continue
                    if device is None:
                        B = near_base_numpy(projection, k, coef, mesh.n_horizontal, row_id, col_id)
                        for comp in range(3):
                            staged[b][j, pos, comp] -= B[comp]
                    else:
                        device.subtract(projection, k, coef + [ETA0], pattern, b, rows_by_block[b], staged[b],
                                        windows[BLOCKS[b][0]], mesh.n_horizontal)
        for b in BLOCKS:
            if not np.all(np.isfinite(staged[b])):
                raise FloatingPointError(f"near-field block {b}: non-finite entries (window or quadrature failure)")
            near.store(b, rows_by_block[b], staged[b])
        t2 = time.perf_counter()
        timings["exact_s"] += t1 - t0
        timings["base_s"] += t2 - t1
        if progress is not None:
            progress("near field", (i_strip + 1) / len(strips))
        logger.debug("near strip %d/%d: %d pairs, exact %.2f s, base %.2f s", i_strip + 1, len(strips),
                     len(all_rows), t1 - t0, t2 - t1)
    timings["total_s"] = time.perf_counter() - t_start
    timings.update({f"element_{k}": v for k, v in integrals.timings.items()})
    near.timings, near.exact, near.exact_offsets = timings, exact, exact_offsets
    return near
