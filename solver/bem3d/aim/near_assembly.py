"""Assembly of the near-field correction C = A − B (the storage and SpMV are in nearfield.py).

Per strip of rows (one chunk of y lines):

1. A: the exact entries from the part-1 element integrals (assembly.basis_pair_entries, the
   static singular tables cached per geometry); each unordered element pair is computed once
   (its other order is the transposed table), and element pairs of repeating geometry, e.g.
   flat or 1-D periodic patches, once for all of them (near_tables.py);
2. B: the grid approximation of the same pairs with exactly the sampled kernel of the FFT path:
   the grid potentials of each row's stencil on a window (one BLAS product per chunk of rows:
   their weights times the window's kernel matrices, :func:`window_kernels`), then the column's
   stencil sum (kernels/aim_near.cl), subtracted in double precision for every grid medium;
   NumPy twin :func:`near_base_numpy` (explicit S × S double sum).
"""

from __future__ import annotations

import logging
import time

import numpy as np

from wavebrdf.solver.bem3d.aim.convolution import int4_arg
from wavebrdf.solver.bem3d.aim.green import lattice_green
from wavebrdf.solver.bem3d.aim.near_tables import RepeatingTables, TransposedTables
from wavebrdf.solver.bem3d.aim.nearfield import BLOCKS, STORAGE, NearMatrix, NearPattern
from wavebrdf.solver.bem3d.aim.projection import Projection
from wavebrdf.solver.bem3d.assembly import basis_pair_entries
from wavebrdf.solver.bem3d.elements import ElementIntegrals
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import BEMMesh, near_first, near_row
from wavebrdf.solver.farfield import ETA0
from wavebrdf.solver.precision import Precision

logger = logging.getLogger(__name__)

__all__ = ["assemble_near", "near_base_numpy", "stencil_product", "window_kernels"]

PAIRS_PER_CHUNK = 600_000  # stored pairs per assembly chunk (element tables ≈ 1 KB per element pair)
POTENTIAL_BUDGET = 256 * 2**20  # bytes of grid potentials per launch


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
# Assembly


def _windows(grid, pairs: dict):
    """Window base and size (grid units) covering the columns' stencils of each source orientation,
    from each block's pairs (NearPattern.pairs: row and column ids first)."""
    out = {}
    for o in (0, 1):
        lo = hi = None
        for block, (orow, _, _) in BLOCKS.items():
            row_id, col_id = pairs[block][:2]
            if orow != o or len(row_id) == 0:
                continue
            rel = grid.origins[col_id] - grid.origins[row_id]
            low, high = rel.min(axis=0), rel.max(axis=0)
            lo = low if lo is None else np.minimum(lo, low)
            hi = high if hi is None else np.maximum(hi, high)
        if lo is not None:
            out[o] = (lo, hi - lo + np.asarray(grid.stencil))
    return out


def _kernel_table(k, grid, wbase, wdim):
    """g, ∇g on the lattice offsets a window needs: (lo, dims, green (T,), gradient (3, T))."""
    lo = np.asarray(wbase) - (np.asarray(grid.stencil) - 1)
    dims = np.asarray(wdim) + np.asarray(grid.stencil) - 1
    ax = [lo[i] + np.arange(dims[i]) for i in range(3)]
    offsets = np.stack(np.meshgrid(*ax, indexing="ij"), axis=-1)
    g, grad = lattice_green(k, grid.spacing, offsets)
    return lo, dims, g.ravel(), np.moveaxis(grad, -1, 0).reshape(3, -1)


def window_kernels(k, grid, wbase, wdim) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(g, ∂x g, ∂y g, ∂z g), each complex (S, n_W): the kernel from stencil slot b of a rooftop
    with origin o to window point w (o + wbase + w, window points in C order over ``wdim``, slots
    in C order over the stencil), the same for every rooftop: its grid potentials on the window
    are its weights (n, S) times these matrices."""
    lo, dims, green, gradient = _kernel_table(k, grid, wbase, wdim)
    slot = np.stack(np.meshgrid(*(np.arange(n) for n in grid.stencil), indexing="ij"), axis=-1).reshape(-1, 3)
    point = np.stack(np.meshgrid(*(np.arange(n) for n in wdim), indexing="ij"), axis=-1).reshape(-1, 3)
    d = (np.asarray(wbase) - lo)[None, None, :] + point[None, :, :] - slot[:, None, :]  # (S, n_W, 3)
    index = (d[..., 0] * dims[1] + d[..., 1]) * dims[2] + d[..., 2]
    return green[index], gradient[0][index], gradient[1][index], gradient[2][index]


def stencil_product(weights: np.ndarray, kernel: np.ndarray, out: np.ndarray) -> np.ndarray:
    """out (n, m) complex128 = weights (n, S) @ kernel (S, m) complex128 by one BLAS product
    (real weights act on the kernel's real and imaginary parts as one real matrix)."""
    if np.iscomplexobj(weights):
        return np.matmul(weights.astype(np.complex128, copy=False), kernel, out=out)
    np.matmul(weights.astype(np.float64, copy=False), kernel.view(np.float64), out=out.view(np.float64))
    return out


class _NearBaseOpenCL:
    """Device state of the B subtraction: weights of each projection, origins, and the host array
    of the grid potentials (kept across chunks and strips: fresh arrays of this size cost a page
    fault per page every chunk)."""

    def __init__(self, ctx, projections):
        self.ctx = ctx
        self.origins = ctx.to_device(projections[0].grid.origins, np.int32)
        self.weights = {id(p): ctx.to_device(p.weights, np.result_type(p.weights, np.float64)) for p in projections}
        self._potentials = np.zeros(0, dtype=np.complex128)

    def _potential_array(self, size: int) -> np.ndarray:
        if len(self._potentials) < size:
            self._potentials = np.zeros(0, dtype=np.complex128)
            self._potentials = np.empty(size, dtype=np.complex128)
        return self._potentials[:size]

    def subtract(self, projection, k, coef, pattern, blocks, rows, staged, window):
        """Subtract B (one medium) from ``staged[block]`` (n_offsets, len(rows), 3) complex128 in
        place for each of ``blocks``, which share the row orientation and ``rows``.

        The grid potentials of the rows' stencils on the window are computed once (host BLAS,
        double precision: the rows' weights times :func:`window_kernels`) and tested by every
        block's columns (``aim_near_correct``). Per row, 7 planes of n_W points: the tangential
        weight times (g, ∂₁g, ∂₂g) with (∂₁, ∂₂) = (∂y, ∂z) for horizontal rows, (∂z, ∂x) for
        vertical ones; the normal weight times (g, ∂x g, ∂y g); the divergence weight times g.
        """

        ctx, queue = self.ctx, self.ctx.queue
        grid = projection.grid
        orow = BLOCKS[blocks[0]][0]
        if any(BLOCKS[b][0] != orow for b in blocks):
            raise ValueError(f"blocks {blocks} do not share the row orientation")
        wbase, wdim = window
        g, gx, gy, gz = window_kernels(k, grid, wbase, wdim)
        tangential = np.concatenate([g, gy, gz] if orow == 0 else [g, gz, gx], axis=1)
        normal = np.concatenate([g, gx, gy], axis=1)
        defines = ctx.defines(Precision.DOUBLE, AIM_COMPLEX_W=int(np.iscomplexobj(projection.weights)))
        cor_knl = ctx.kernel("aim_near.cl", "aim_near_correct", defines)
        offset_bufs = {b: (ctx.to_device(pattern.offsets(b)), len(pattern.offsets(b))) for b in blocks}
        coef_buf = ctx.to_device(coef, np.complex128)
        nW = int(np.prod(wdim))
        sources = near_first(orow, pattern.cells) + np.asarray(rows)
        step = max(1, POTENTIAL_BUDGET // (7 * nW * 16))
        weights = self.weights[id(projection)]
        sx, sy, sz = grid.stencil
        for s0 in range(0, len(rows), step):
            s1 = min(len(rows), s0 + step)
            n = s1 - s0
            W = projection.weights[:, sources[s0:s1]]  # (3, n, S)
            flat = self._potential_array(n * 7 * nW)
            stencil_product(W[0], tangential, flat[: 3 * n * nW].reshape(n, 3 * nW))
            stencil_product(W[1], normal, flat[3 * n * nW : 6 * n * nW].reshape(n, 3 * nW))
            stencil_product(W[2], g, flat[6 * n * nW :].reshape(n, nW))
            pot = ctx.host_buffer(flat)
            row_buf = ctx.to_device(rows[s0:s1], np.int32)
            whole = n == len(rows)  # each block's staged array is the chunk: no staging copy
            for b in blocks:
                off_buf, n_off = offset_bufs[b]
                chunk = staged[b] if whole else np.ascontiguousarray(staged[b][:, s0:s1])
                val_buf = ctx.host_buffer(chunk, "read_write")
                cor_knl(queue, (n_off * n,), None, np.int32(orow), np.int32(BLOCKS[b][1]), np.int32(pattern.cells),
                        off_buf, np.int32(n_off), row_buf, np.int32(n), self.origins, np.int32(2 * pattern.rows),
                        weights, np.int32(sx), np.int32(sy), np.int32(sz), int4_arg(wdim), int4_arg(wbase), pot,
                        coef_buf, val_buf)
                ctx.read_into(chunk, val_buf)  # waits: the potentials are free again after it
                if not whole:
                    staged[b][:, s0:s1] = chunk
            del pot
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
    tables = RepeatingTables(integrals) if RepeatingTables.worthwhile(mesh) else TransposedTables(integrals)
    coef_all = media.pmchwt_coefficients()
    nrows = pattern.rows
    near = NearMatrix(pattern, NearMatrix.zeros(pattern, storage))
    exact_offsets = exact = None
    if exact_cells is not None:
        exact_offsets = {b: pattern.within(b, min(exact_cells, pattern.radius_cells)) for b in BLOCKS}
        exact = {b: np.zeros((len(exact_offsets[b]), nrows, 3), dtype=STORAGE[storage]) for b in BLOCKS}
    device = _NearBaseOpenCL(ctx, [p for p, _ in groups]) if ctx is not None else None
    timings = {"exact_s": 0.0, "entries_s": 0.0, "base_s": 0.0}  # exact_s: pair lists, entries, staging
    strips = list(_strips(pattern))
    for i_strip, rows_by_block in enumerate(strips):
        t0 = time.perf_counter()
        pairs = {b: pattern.pairs(b, rows_by_block[b]) for b in BLOCKS}
        all_rows = np.concatenate([p[0] for p in pairs.values()])
        all_cols = np.concatenate([p[1] for p in pairs.values()])
        t_entries = time.perf_counter()
        ee, mm, em = basis_pair_entries(ctx, mesh, media, all_rows, all_cols, integrals=tables)
        timings["entries_s"] += time.perf_counter() - t_entries
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
        windows = _windows(groups[0][0].grid, pairs) if device is not None else None
        for projection, medium_indices in groups:
            for i in medium_indices:
                k = media.wavenumbers[i]
                coef = [coef_all["ee_vec"][i], coef_all["ee_div"][i], coef_all["mm_vec"][i], coef_all["mm_div"][i]]
                if device is not None:  # blocks of one row orientation share their grid potentials
                    for o in (0, 1):
                        blocks = [b for b in BLOCKS if BLOCKS[b][0] == o and len(pairs[b][0])]
                        if blocks:
                            device.subtract(projection, k, coef + [ETA0], pattern, blocks, rows_by_block[blocks[0]],
                                            staged, windows[o])
                    continue
                for b, (row_id, col_id, j, pos) in pairs.items():
                    if len(row_id):
                        B = near_base_numpy(projection, k, coef, mesh.n_horizontal, row_id, col_id)
                        for comp in range(3):
                            staged[b][j, pos, comp] -= B[comp]
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
    integrals.release_scratch()  # one strip's tables (~1 KB per element pair) go before the solve
    del tables  # and the kept ones
    timings["total_s"] = time.perf_counter() - t_start
    timings.update({f"element_{k}": v for k, v in integrals.timings.items()})
    near.timings, near.exact, near.exact_offsets = timings, exact, exact_offsets
    return near
