"""Assembly of the near-field correction C = A − B (the storage and SpMV are in nearfield.py).

Per strip of rows (one chunk of y lines):

1. A: the exact entries from the part-1 element integrals (assembly.basis_pair_entries, the
   static singular tables cached per geometry; element pairs of repeating geometry, e.g.
   flat or 1-D periodic patches, are computed once, :class:`RepeatingTables`);
2. B: the grid approximation of the same pairs with exactly the sampled kernel of the FFT path
   (kernels/aim_near.cl: grid potentials of each row's stencil on a window, then the column's
   stencil sum), subtracted in double precision for every grid medium; NumPy twin
   :func:`near_base_numpy` (explicit S × S double sum).
"""

from __future__ import annotations

import logging
import time

import numpy as np

from wavebrdf.solver.bem3d.aim.convolution import int4_arg
from wavebrdf.solver.bem3d.aim.green import lattice_green
from wavebrdf.solver.bem3d.aim.nearfield import BLOCKS, STORAGE, NearMatrix, NearPattern
from wavebrdf.solver.bem3d.aim.projection import Projection
from wavebrdf.solver.bem3d.assembly import basis_pair_entries
from wavebrdf.solver.bem3d.elements import ElementIntegrals
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import BEMMesh, near_first, near_row
from wavebrdf.solver.farfield import ETA0
from wavebrdf.solver.precision import Precision

logger = logging.getLogger(__name__)

__all__ = ["RepeatingTables", "assemble_near", "near_base_numpy"]

PAIRS_PER_CHUNK = 600_000  # stored pairs per assembly chunk (element tables ≈ 1 KB per element pair)
POTENTIAL_BUDGET = 256 * 2**20  # bytes of grid potentials per launch


# ---------------------------------------------------------------------------------------------
# Element tables of repeating geometry


class RepeatingTables:
    """Drop-in for ElementIntegrals.indexed_tables that computes each geometrically distinct pair
    once.

    Two element pairs are identical when the index offset, the shapes (z10, z01, z11) of both
    elements and the height offset Δz00 are equal bit for bit (flat, tilted or 1-D periodic
    patches). Tables are cached across calls, so strips of a large patch share them; a call
    returns the whole cache and each pair's row in it (nothing is copied per pair).
    """

    def __init__(self, integrals: ElementIntegrals):
        self.integrals = integrals
        mesh = integrals.mesh
        _, self.shape_ids = np.unique(mesh.geometry[:, 3:6], axis=0, return_inverse=True)
        self.shape_ids = self.shape_ids.ravel().astype(np.int64)
        self.n_shapes = int(self.shape_ids.max()) + 1
        self.z00 = mesh.geometry[:, 2].copy()
        self.st = mesh.element_st
        self.cells = mesh.cells
        self._keys: dict = {}
        self._store = np.zeros((0, 2, 33), dtype=complex)

    @staticmethod
    def worthwhile(mesh: BEMMesh, fraction: float = 0.25) -> bool:
        return len(np.unique(mesh.geometry[:, 3:6], axis=0)) <= max(1, fraction * mesh.n_elements)

    def _distinct(self, test, source):
        """(keys of the distinct pairs, first pair of each, inverse) — one int64 sort key for the
        offset and shapes, Δz00 compared bit for bit."""
        d = self.st[source] - self.st[test]
        span = 2 * self.cells + 1
        columns = [d[:, 0] + self.cells, d[:, 1] + self.cells, self.shape_ids[test], self.shape_ids[source]]
        if span * span * self.n_shapes**2 < 2**62:  # one int64 key for all but Δz00
            key = ((columns[0] * span + columns[1]) * self.n_shapes + columns[2]) * self.n_shapes + columns[3]
            columns = [key]
        columns.append((self.z00[source] - self.z00[test]).view(np.int64))
        order = np.lexsort(columns[::-1])
        new = np.zeros(len(order), dtype=bool)
        new[:1] = True
        for c in columns:
            sorted_c = c[order]
            new[1:] |= sorted_c[1:] != sorted_c[:-1]
        first = order[new]
        inverse = np.empty(len(order), dtype=np.int64)
        inverse[order] = np.cumsum(new) - 1
        return list(zip(*(c[first].tolist() for c in columns))), first, inverse

    def indexed_tables(self, test, source, wavenumbers, *, scratch: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """As ElementIntegrals.indexed_tables (the cache is returned, so ``scratch`` changes nothing)."""
        test = np.asarray(test, dtype=np.int64)
        source = np.asarray(source, dtype=np.int64)
        keys, first, inverse = self._distinct(test, source)
        index = np.array([self._keys.get(key, -1) for key in keys], dtype=np.int64)
        missing = np.flatnonzero(index < 0)
        if len(missing):
            fresh, order = self.integrals.indexed_tables(test[first[missing]], source[first[missing]], wavenumbers)
            index[missing] = len(self._store) + order
            self._store = np.concatenate([self._store, fresh])
            self._keys.update(zip((keys[u] for u in missing), index[missing].tolist()))
        return self._store, index[inverse]


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
    """Device state of the B subtraction: weights of each projection, origins, and the grid
    potentials' buffer (kept across launches and strips: fresh buffers of this size cost a page
    fault per page every launch)."""

    def __init__(self, ctx, projections):
        self.ctx = ctx
        self.origins = ctx.to_device(projections[0].grid.origins, np.int32)
        self.weights = {id(p): ctx.to_device(p.weights, np.result_type(p.weights, np.float64)) for p in projections}
        self._potentials = None

    def _potential_buffer(self, nbytes: int):
        import pyopencl as cl

        if self._potentials is None or self._potentials.size < nbytes:
            self._potentials = None
            self._potentials = cl.Buffer(self.ctx.context, cl.mem_flags.READ_WRITE, nbytes)
        return self._potentials

    def subtract(self, projection, k, coef, pattern, blocks, rows, staged, window, n_horizontal):
        """Subtract B (one medium) from ``staged[block]`` (n_offsets, len(rows), 3) complex128 in
        place for each of ``blocks``, which share the row orientation and ``rows``: the grid
        potentials of the rows' stencils are computed once and tested by every block's columns."""
        import pyopencl as cl

        ctx, queue = self.ctx, self.ctx.queue
        grid = projection.grid
        orow = BLOCKS[blocks[0]][0]
        if any(BLOCKS[b][0] != orow for b in blocks):
            raise ValueError(f"blocks {blocks} do not share the row orientation")
        wbase, wdim = window
        lo, dims, green, gradient = _kernel_table(k, grid, wbase, wdim)
        defines = ctx.defines(Precision.DOUBLE, AIM_COMPLEX_W=int(np.iscomplexobj(projection.weights)))
        pot_knl = ctx.kernel("aim_near.cl", "aim_near_potentials", defines)
        cor_knl = ctx.kernel("aim_near.cl", "aim_near_correct", defines)
        tables = [ctx.to_device(a, np.complex128) for a in (green, gradient)]
        offset_bufs = {b: (ctx.to_device(pattern.offsets(b)), len(pattern.offsets(b))) for b in blocks}
        coef_buf = ctx.to_device(coef, np.complex128)
        nW = int(np.prod(wdim))
        sources = (near_first(orow, pattern.cells) + np.asarray(rows)).astype(np.int32)
        step = max(1, POTENTIAL_BUDGET // (6 * nW * 16))
        weights = self.weights[id(projection)]
        sx, sy, sz = grid.stencil
        for s0 in range(0, len(rows), step):
            s1 = min(len(rows), s0 + step)
            n = s1 - s0
            src_buf = ctx.to_device(sources[s0:s1])
            row_buf = ctx.to_device(rows[s0:s1], np.int32)
            pot = self._potential_buffer(n * 6 * nW * 16)
            pot_knl(queue, (n * nW,), None, src_buf, np.int32(n), self.origins, np.int32(2 * pattern.rows),
                    np.int32(n_horizontal), weights, np.int32(sx), np.int32(sy), np.int32(sz), int4_arg(wdim),
                    int4_arg(wbase), int4_arg(lo), int4_arg(dims), *tables, pot)
            whole = n == len(rows)  # each block's staged array is the chunk: no staging copy
            for b in blocks:
                off_buf, n_off = offset_bufs[b]
                chunk = staged[b] if whole else np.ascontiguousarray(staged[b][:, s0:s1])
                val_buf = ctx.to_device(chunk, writable=True)
                cor_knl(queue, (n_off * n,), None, np.int32(orow), np.int32(BLOCKS[b][1]), np.int32(pattern.cells),
                        off_buf, np.int32(n_off), row_buf, np.int32(n), self.origins, np.int32(2 * pattern.rows),
                        weights, np.int32(sx), np.int32(sy), np.int32(sz), int4_arg(wdim), int4_arg(wbase), pot,
                        coef_buf, val_buf)
                cl.enqueue_copy(queue, chunk, val_buf)
                if not whole:
                    staged[b][:, s0:s1] = chunk
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
        windows = _windows(groups[0][0].grid, pattern, rows_by_block) if device is not None else None
        for projection, medium_indices in groups:
            for i in medium_indices:
                k = media.wavenumbers[i]
                coef = [coef_all["ee_vec"][i], coef_all["ee_div"][i], coef_all["mm_vec"][i], coef_all["mm_div"][i]]
                if device is not None:  # blocks of one row orientation share their grid potentials
                    for o in (0, 1):
                        blocks = [b for b in BLOCKS if BLOCKS[b][0] == o and len(pairs[b][0])]
                        if blocks:
                            device.subtract(projection, k, coef + [ETA0], pattern, blocks, rows_by_block[blocks[0]],
                                            staged, windows[o], mesh.n_horizontal)
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
    timings["total_s"] = time.perf_counter() - t_start
    timings.update({f"element_{k}": v for k, v in integrals.timings.items()})
    near.timings, near.exact, near.exact_offsets = timings, exact, exact_offsets
    return near
