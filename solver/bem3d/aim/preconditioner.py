"""The near-field preconditioner of the AIM Krylov solve: a sparse LU of the exact near entries,
whole or in overlapping tiles (:class:`NearPreconditioner`), and the symmetric scaling
S = diag(I, jI) it and the unpreconditioned solve share."""

from __future__ import annotations

import logging
import time

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from wavebrdf.solver.bem3d.aim.nearfield import NearPattern
from wavebrdf.solver.bem3d.mesh import near_coords, near_first
from wavebrdf.solver.fitted import fitted
from wavebrdf.solver.resources import one_blas_thread, release_free_memory

logger = logging.getLogger(__name__)

__all__ = ["PRECONDITIONER_OVERLAP", "SUPERLU_BYTES", "NearPreconditioner", "preconditioner_tiles",
           "symmetric_scaling", "tiles_per_axis"]

PRECONDITIONER_OVERLAP = 3  # cells added on every side of a preconditioner tile
# resident bytes per factor entry of a complex64 SuperLU factorization: 8 + 4 of value and index,
# and SuperLU's supernodal storage (the measured figure: solver/data/aim_cost.csv)
SUPERLU_BYTES = fitted("aim_cost")["superlu_bytes_per_entry"]


def symmetric_scaling(n_b: int, dtype) -> np.ndarray:
    """S = diag(I, jI): S Z S keeps Z's symmetry and moves its spectrum into Re λ > 0."""
    s = np.ones(2 * n_b, dtype=dtype)
    s[n_b:] = 1j
    return s


class NearPreconditioner:
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
        n_b = near.n_bases
        self.scale = symmetric_scaling(n_b, np.complex64)
        S = scipy.sparse.diags(self.scale)
        A = (S @ near.exact_sparse(np.complex64) @ S).tocsc()
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

    def __call__(self, X: np.ndarray) -> np.ndarray:
        t0 = time.perf_counter()
        X = np.atleast_2d(X)
        Xs = np.ascontiguousarray((self.scale * X).T, dtype=np.complex64)  # (n, P)
        with one_blas_thread():
            if len(self.tiles) == 1:
                Y = self.tiles[0][3].solve(Xs)
            else:
                Y = np.empty_like(Xs)
                for extended, positions, own, lu in self.tiles:
                    Y[own] = lu.solve(np.ascontiguousarray(Xs[extended]))[positions]
        Y = self.scale * Y.T
        self.apply_s += time.perf_counter() - t0
        return Y.astype(X.dtype, copy=False)


def tiles_per_axis(cells: int, tile_cells: int) -> int:
    """Preconditioner tiles along each axis of an N-cell patch: 1 (one LU) unless 0 < T < N."""
    return max(1, round(cells / tile_cells)) if 0 < tile_cells < cells else 1


def preconditioner_tiles(pattern: NearPattern, tile_cells: int, overlap_cells: int):
    """(extended, own) unknown indices (sorted) of each preconditioner tile; one tile if tile_cells ≤ 0.

    Rooftops belong to the tile holding their centre (horizontal (x + 1, y + ½), vertical
    (x + ½, y + 1) in cells); the extended tile adds the rooftops within ``overlap_cells``.
    Unknowns are [J | M̃]: rooftop b gives b and b + N_b.
    """
    N, n_b = pattern.cells, 2 * pattern.rows
    per_axis = tiles_per_axis(N, tile_cells)
    if per_axis == 1:
        everything = np.arange(2 * n_b)
        yield everything, everything
        return
    x = np.empty(n_b)
    y = np.empty(n_b)
    for o in (0, 1):
        first = near_first(o, N)
        cx, cy = near_coords(o, N, np.arange(pattern.rows))
        x[first:first + pattern.rows] = cx + (1.0 if o == 0 else 0.5)
        y[first:first + pattern.rows] = cy + (0.5 if o == 0 else 1.0)
    edges = np.linspace(0.0, N, per_axis + 1)
    edges[-1] = np.inf
    for x0, x1 in zip(edges[:-1], edges[1:]):
        for y0, y1 in zip(edges[:-1], edges[1:]):
            own = np.flatnonzero((x >= x0) & (x < x1) & (y >= y0) & (y < y1))
            ext = np.flatnonzero((x >= x0 - overlap_cells) & (x < x1 + overlap_cells)
                                 & (y >= y0 - overlap_cells) & (y < y1 + overlap_cells))
            yield np.concatenate([ext, ext + n_b]), np.concatenate([own, own + n_b])
