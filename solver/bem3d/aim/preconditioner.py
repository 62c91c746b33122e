"""The near-field preconditioners of the AIM Krylov solve, both built from the exact near entries:
a sparse LU, whole or in overlapping tiles (:class:`NearPreconditioner`), and the local inverses
of small overlapping tiles that fit a memory budget (:class:`LocalInversePreconditioner`); and
the symmetric scaling S = diag(I, jI) they and the unpreconditioned solve share."""

from __future__ import annotations

import logging
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from wavebrdf.solver.bem3d.aim.nearfield import NearPattern
from wavebrdf.solver.bem3d.mesh import near_coords, near_first
from wavebrdf.solver.fitted import fitted
from wavebrdf.solver.opencl import fft_workers
from wavebrdf.solver.resources import one_blas_thread, release_free_memory

logger = logging.getLogger(__name__)

__all__ = ["LOCAL_OVERLAP", "PRECONDITIONER_OVERLAP", "SUPERLU_BYTES", "LocalInversePreconditioner",
           "NearPreconditioner", "inverse_rows", "local_inverse_entries", "preconditioner_tiles", "rooftop_centres",
           "symmetric_scaling", "tiles_per_axis"]

PRECONDITIONER_OVERLAP = 3  # cells added on every side of a preconditioner LU tile
# cells added on every side of a local-inverse tile: without overlap (block Jacobi) GMRES needed
# more products than with no preconditioner at all; one cell cuts them 3.5-5x (docs/aim.md)
LOCAL_OVERLAP = 1
# resident bytes per factor entry of a complex64 SuperLU factorization: 8 + 4 of value and index,
# and SuperLU's supernodal storage (the measured figure: solver/data/aim_cost.csv)
SUPERLU_BYTES = fitted("aim_cost")["superlu_bytes_per_entry"]


def symmetric_scaling(n_b: int, dtype) -> np.ndarray:
    """S = diag(I, jI): S Z S keeps Z's symmetry and moves its spectrum into Re λ > 0."""
    s = np.ones(2 * n_b, dtype=dtype)
    s[n_b:] = 1j
    return s


class _ScaledPreconditioner:
    """What both preconditioners share: the exact near block rescaled by S = diag(I, jI), and
    M(X) = S M̃(S X) with M̃ applied in complex64 to the columns of X (P, n) (:meth:`_solve`)."""

    scale: np.ndarray
    apply_s: float

    def _scaled_near(self, near, layout: str, rows=None) -> scipy.sparse.spmatrix:
        """S A_near S of the exact near entries (``layout`` "csc" or "csr"; ``rows``: a band,
        nearfield.offset_matrix), scaled in place (entry (i, k) times j^([i ≥ N_b] + [k ≥ N_b]));
        sets ``scale``."""
        n_b = near.n_bases
        self.scale = symmetric_scaling(n_b, np.complex64)
        A = near.exact_sparse(np.complex64, layout, rows)
        A.eliminate_zeros()  # the J–M entries of coplanar rooftops: a flat patch's LU keeps its blocks apart
        major = np.repeat(np.arange(A.shape[0]) >= n_b, np.diff(A.indptr)).astype(np.int8)  # row (csr) / column (csc)
        major += A.indices >= n_b
        A.data *= np.array([1, 1j, -1], dtype=np.complex64)[major]
        return A

    def _solve(self, Xs: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def __call__(self, X: np.ndarray) -> np.ndarray:
        t0 = time.perf_counter()
        X = np.atleast_2d(X)
        Y = self._solve(np.ascontiguousarray((self.scale * X).T, dtype=np.complex64))  # (n, P)
        Y = self.scale * Y.T
        self.apply_s += time.perf_counter() - t0
        return Y.astype(X.dtype, copy=False)


class NearPreconditioner(_ScaledPreconditioner):
    """M(X) ≈ Z⁻¹X from the exact entries A_near of the pairs within the preconditioner radius.

    The sparse LU (SuperLU, minimum-degree ordering of A + Aᵀ) of S A_near S, S = diag(I, jI),
    with diagonal pivots only: S keeps Z complex-symmetric and gives its diagonal blocks the same
    sign, so the diagonal is dominant enough. Kept in complex64: it only steers the iteration.
    M = S (S A S)⁻¹ S.

    ``tile_cells`` > 0 splits the patch into square tiles of about that many cells and factors
    each tile's block, extended by ``overlap_cells`` on every side, on its own (restricted
    additive Schwarz: each tile's solve writes only the unknowns of its own tile). The fill of
    one LU grows with its size (8.9 at 2·10⁴ unknowns, 13.1 at 1.6·10⁵, 16.6 at 6.4·10⁵), so
    tiles keep the memory and time linear in the patch size; measured at 1.6·10⁵ unknowns they
    saved 17–24% of the LU memory for 2.6× the GMRES products (docs/aim.md). 0: one LU of the
    whole patch (the default).

    Measured (docs/aim.md, radius 2.3 cells, ~67 entries per row): fill 8–12 × nnz(A_near) at
    1.6·10⁴–4·10⁴ unknowns, 1.4 s and 9 s, ‖M A x − x‖/‖x‖ = 9e-5 (complex64). Partial pivoting
    (threshold 0.1) pivoted off the diagonal for aluminium at d = λ/8 (fill 29–37, 10× slower);
    SuperLU's incomplete LU was no cheaper and far less accurate (error 0.07 at drop 1e-3; with
    its fill capped at 4 and drop 1e-2, 155: GMRES then stalled).
    """

    def __init__(self, near, tile_cells: int = 0, overlap_cells: int = PRECONDITIONER_OVERLAP):
        t0 = time.perf_counter()
        A = self._scaled_near(near, "csc")
        self.nnz = A.nnz
        self.tiles = []  # (unknowns of the extended tile, positions of its own unknowns in them, own unknowns, LU)
        self.factor_nnz = 0
        for extended, own in preconditioner_tiles(near.pattern, tile_cells, overlap_cells):
            block = A if len(extended) == A.shape[0] else A[extended][:, extended].tocsc()
            with one_blas_thread():  # SuperLU's many small BLAS calls: threads only spin (see there)
                lu = scipy.sparse.linalg.splu(block, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0)
            self.factor_nnz += lu.L.nnz + lu.U.nnz
            self.tiles.append((extended, np.searchsorted(extended, own), own, lu))  # both sorted, own ⊂ extended
        del A
        release_free_memory()
        self.seconds = time.perf_counter() - t0
        self.apply_s = 0.0
        logger.info("near preconditioner: LU of %d entries in %d tile(s), fill %.1f, %.1f s", self.nnz,
                    len(self.tiles), self.factor_nnz / self.nnz, self.seconds)

    def bytes(self) -> int:
        return int(self.factor_nnz * SUPERLU_BYTES)

    def _solve(self, Xs: np.ndarray) -> np.ndarray:
        with one_blas_thread():
            if len(self.tiles) == 1:
                return self.tiles[0][3].solve(Xs)
            Y = np.empty_like(Xs)
            for extended, positions, own, lu in self.tiles:
                Y[own] = lu.solve(np.ascontiguousarray(Xs[extended]))[positions]
            return Y


class LocalInversePreconditioner(_ScaledPreconditioner):
    """M(X) ≈ Z⁻¹X from the local inverses of small overlapping tiles (restricted additive Schwarz
    with explicit local inverses).

    The patch is split into square tiles of about ``tile_cells`` cells; each is extended by
    ``overlap_cells`` (:data:`LOCAL_OVERLAP`) on every side, and of the inverse of its exact near
    block (S A S, S = diag(I, jI), as :class:`NearPreconditioner`) the rows of the tile's own
    unknowns are kept, dense, in complex64. M = S R S, R the stacked rows: a product is one batched
    small matrix product per tile shape. Memory: 4 (T + 2·overlap)² entries per unknown in the
    patch's interior (144 at T = 4: 1.15 KB per unknown, :func:`local_inverse_entries`), against
    fill × ~70 entries for the near LU; the inverses are computed in complex128, tile by tile.
    The rows are not truncated: the local inverse decays slowly, and keeping only entries within
    2.3–3 cells of the row's rooftop made GMRES stall (docs/aim.md).
    """

    def __init__(self, near, tile_cells: int, overlap_cells: int = LOCAL_OVERLAP, chunk: int = 256):
        t0 = time.perf_counter()
        pattern = near.pattern
        n_b = near.n_bases
        per_axis = tiles_per_axis(pattern.cells, tile_cells)
        tiles = list(preconditioner_tiles(pattern, tile_cells, overlap_cells))  # x index outer, per_axis per band
        shapes: dict[tuple[int, int], list[int]] = {}
        for i, (extended, own) in enumerate(tiles):
            shapes.setdefault((len(extended), len(own)), []).append(i)
        slot = {i: (shape, k) for shape, members in shapes.items() for k, i in enumerate(members)}
        # (extended (g, m) int32, own (g, k) int32, rows of the inverses (g, k, m) complex64) per tile shape
        self.groups = [(np.array([tiles[i][0] for i in members], dtype=np.int32),
                        np.array([tiles[i][1] for i in members], dtype=np.int32),
                        np.empty((len(members), k, m), dtype=np.complex64)) for (m, k), members in shapes.items()]
        group_of = {shape: g for shape, g in zip(shapes, self.groups)}
        x, _ = rooftop_centres(pattern)
        reach = pattern.radius_cells + 1.0
        self.nnz = 0
        threads = fft_workers()  # the worker's share of the CPUs (the batch layer caps it)
        with one_blas_thread(), ThreadPoolExecutor(threads) as pool:  # small LAPACK calls: one BLAS thread each
            for band in range(per_axis):  # one band of tiles at a time: its rows of A, not all of A
                members = range(band * len(tiles) // per_axis, (band + 1) * len(tiles) // per_axis)
                kept = np.zeros(n_b, dtype=bool)
                for i in members:
                    kept[tiles[i][0][tiles[i][0] < n_b]] = True
                low, high = x[kept].min() - reach, x[kept].max() + reach
                A = self._scaled_near(near, "csr", (kept, (x >= low) & (x <= high)))
                self.nnz += int(np.diff(A.indptr)[np.concatenate([tiles[i][1] for i in members])].sum())
                for c0 in range(0, len(members), chunk):
                    part = members[c0:c0 + chunk]
                    block = {}
                    for i in part:
                        block.setdefault(slot[i][0], []).append(i)
                    for shape, ids in block.items():
                        extended, own, rows = group_of[shape]
                        dense = np.stack([A[tiles[i][0]][:, tiles[i][0]].toarray() for i in ids]).astype(np.complex128)
                        positions = np.stack([np.searchsorted(tiles[i][0], tiles[i][1]) for i in ids])
                        rows[[slot[i][1] for i in ids]] = inverse_rows(dense, positions, pool, threads)
                del A
        self.factor_nnz = sum(rows.size for _, _, rows in self.groups)  # stored entries, as the LU's factors
        self.seconds = time.perf_counter() - t0
        self.apply_s = 0.0
        logger.info("local-inverse preconditioner: %d tiles of %d shapes, %.0f entries per unknown, %.1f s",
                    len(tiles), len(self.groups), self.factor_nnz / self.scale.size, self.seconds)

    def bytes(self) -> int:
        return int(sum(e.nbytes + o.nbytes + r.nbytes for e, o, r in self.groups))

    def _solve(self, Xs: np.ndarray) -> np.ndarray:
        Y = np.empty_like(Xs)
        for extended, own, rows in self.groups:
            Y[own] = rows @ Xs[extended]
        return Y


def inverse_rows(blocks: np.ndarray, positions: np.ndarray, pool: ThreadPoolExecutor | None = None,
                 threads: int = 1) -> np.ndarray:
    """Rows ``positions`` (g, k) of the inverses of ``blocks`` (g, m, m), shape (g, k, m): the
    solutions of Aᵀ X = E for the k unit columns E (an LU and k right-hand sides, 1.8× faster than
    the whole inverse at m = 144, k = 64), the stack split in ``threads`` parts run on ``pool``
    (LAPACK releases the GIL)."""
    g, m, _ = blocks.shape
    k = positions.shape[1]
    unit = np.zeros((g, m, k), dtype=blocks.dtype)
    unit[np.arange(g)[:, None], positions, np.arange(k)[None, :]] = 1.0

    def solve(part: slice) -> np.ndarray:
        return np.linalg.solve(blocks[part].transpose(0, 2, 1), unit[part]).transpose(0, 2, 1)

    threads = 1 if pool is None else min(threads, g)
    if threads <= 1:
        return solve(slice(None))
    parts = [slice(i * g // threads, (i + 1) * g // threads) for i in range(threads)]
    return np.concatenate(list(pool.map(solve, parts)))


def local_inverse_entries(cells: int, tile_cells: int, overlap_cells: int = LOCAL_OVERLAP) -> float:
    """Entries of :class:`LocalInversePreconditioner` per unknown on an N-cell patch (4 unknowns
    per cell, ``4 (T + 2·overlap)²`` per row; tiles at the border extend less)."""
    per_axis = tiles_per_axis(cells, tile_cells)
    side = cells / per_axis
    if per_axis == 1:
        return 4.0 * cells**2
    # along one axis: interior tiles extend on both sides, the two border tiles on one
    extended = ((per_axis - 2) * (side + 2 * overlap_cells) + 2 * (side + overlap_cells)) / per_axis
    return 4.0 * extended**2


def tiles_per_axis(cells: int, tile_cells: int) -> int:
    """Preconditioner tiles along each axis of an N-cell patch: 1 (one LU) unless 0 < T < N."""
    return max(1, round(cells / tile_cells)) if 0 < tile_cells < cells else 1


def rooftop_centres(pattern: NearPattern) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) in cells of every rooftop's centre: horizontal (x + 1, y + ½), vertical (x + ½, y + 1)."""
    N = pattern.cells
    x = np.empty(2 * pattern.rows)
    y = np.empty(2 * pattern.rows)
    for o in (0, 1):
        first = near_first(o, N)
        cx, cy = near_coords(o, N, np.arange(pattern.rows))
        x[first:first + pattern.rows] = cx + (1.0 if o == 0 else 0.5)
        y[first:first + pattern.rows] = cy + (0.5 if o == 0 else 1.0)
    return x, y


def preconditioner_tiles(pattern: NearPattern, tile_cells: int, overlap_cells: int):
    """(extended, own) unknown indices (sorted) of each preconditioner tile; one tile if tile_cells ≤ 0.

    Rooftops belong to the tile holding their centre (:func:`rooftop_centres`); the extended
    tile adds the rooftops within ``overlap_cells``. Unknowns are [J | M̃]: rooftop b gives b and
    b + N_b. Linear in the unknowns (a rooftop lies in at most 3 × 3 extended tiles while the
    overlap is below the tile side).
    """
    N, n_b = pattern.cells, 2 * pattern.rows
    per_axis = tiles_per_axis(N, tile_cells)
    if per_axis == 1:
        everything = np.arange(2 * n_b)
        yield everything, everything
        return
    x, y = rooftop_centres(pattern)
    edges = np.linspace(0.0, N, per_axis + 1)
    if overlap_cells >= edges[1]:
        raise ValueError(f"preconditioner tiles of {edges[1]:g} cells cannot overlap by {overlap_cells} cells")
    low, high = edges[:-1] - overlap_cells, edges[1:] + overlap_cells
    high[-1] = np.inf

    def axis(c):  # (rooftop, tile along the axis, owned) of every tile whose extended range holds c
        own = np.clip(np.searchsorted(edges, c, side="right") - 1, 0, per_axis - 1)
        cand = np.clip(own[:, None] + np.array([-1, 0, 1]), 0, per_axis - 1)
        inside = (low[cand] <= c[:, None]) & (c[:, None] < high[cand])
        inside[:, 0] &= cand[:, 0] != cand[:, 1]  # clipped duplicates at the patch border
        inside[:, 2] &= cand[:, 2] != cand[:, 1]
        return cand, inside, cand == own[:, None]

    cx, ix, ox = axis(x)
    cy, iy, oy = axis(y)
    tile = (cx[:, :, None] * per_axis + cy[:, None, :]).reshape(n_b, 9)
    member = (ix[:, :, None] & iy[:, None, :]).reshape(n_b, 9)
    owned = (ox[:, :, None] & oy[:, None, :]).reshape(n_b, 9) & member
    rooftop = np.broadcast_to(np.arange(n_b)[:, None], (n_b, 9))
    order = np.lexsort((rooftop[member], tile[member]))
    tiles, rooftops, owns = tile[member][order], rooftop[member][order], owned[member][order]
    bounds = np.flatnonzero(np.diff(tiles)) + 1
    for ext, own in zip(np.split(rooftops, bounds), np.split(owns, bounds)):
        mine = ext[own]
        yield np.concatenate([ext, ext + n_b]), np.concatenate([mine, mine + n_b])
