"""PMCHWT matrix entries for lists of basis-function pairs, and the dense matrix Z.

Two steps (the same for the dense matrix and for sparse near-field lists):

1. element-pair tables for every element pair the basis pairs touch (elements.py);
2. the OpenCL gather ``bem_basis_block`` / ``bem_basis_list`` (kernels/bem_assembly.cl) sums the
   2×2 half-basis contributions of each basis pair and applies the PMCHWT coefficients (media.py),
   giving the three blocks ee = Z_EE, mm = Z_MM, em = Z_EM = Z_ME of that pair.

The dense matrix in the documented unknown ordering [J_h | J_v | M̃_h | M̃_v] is::

    Z = [[ee, em],
         [em, mm]]        (each block N_b × N_b, complex-symmetric)

It is assembled in blocks of element columns (memory stays bounded, PoCL's 1 GiB allocation
limit is respected). Surfaces whose elements repeat exactly (flat or tilted patches) reuse the
tables of geometrically identical element pairs (exact, no approximation).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from wavebrdf.solver.bem3d.elements import TABLE, ElementIntegrals
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import SLOT_SIGN, BEMMesh
from wavebrdf.solver.precision import Precision

logger = logging.getLogger(__name__)

__all__ = [
    "AssemblyReport",
    "assemble_dense",
    "basis_entries_numpy",
    "basis_entries_opencl",
    "basis_pair_entries",
    "dense_blocks",
    "dense_layout",
]

SEGMENT = 64  # columns per work-item of the block gather
TABLE_BUDGET = 192 * 2**20  # bytes of element tables per block
SHAPE_REUSE_FRACTION = 0.25  # reuse tables when at most this fraction of element shapes are distinct


def _coefficients(media: Media) -> np.ndarray:
    c = media.pmchwt_coefficients()
    return np.concatenate([c["ee_vec"], c["ee_div"], c["mm_vec"], c["mm_div"], [c["em"]]]).astype(np.complex128)


# ---------------------------------------------------------------------------------------------
# The gather: NumPy twin and OpenCL


def basis_entries_numpy(tables, pair_map, row_elem, row_slot, col_elem, col_slot, rows, cols, coef):
    """ee, mm, em of basis pairs (rows[p], cols[p]); twin of ``bem_basis_list``.

    tables (T, 2, 33); pair_map (n_test, n_source) → table row r, or −1 − r where row r holds the
    table of the pair's other order (source, test), read transposed (its slots (b, a)); row_elem /
    row_slot (n_rows, 2) local element index and slot of each row basis' two halves (likewise for
    columns).
    """
    rows = np.asarray(rows)
    cols = np.asarray(cols)
    lv = np.zeros((len(rows), 2), dtype=complex)
    ld = np.zeros((len(rows), 2), dtype=complex)
    kk = np.zeros(len(rows), dtype=complex)
    for s in range(2):
        for t in range(2):
            code = pair_map[row_elem[rows, s], col_elem[cols, t]]
            turned = code < 0
            tab = tables[np.where(turned, -1 - code, code)]  # (P, 2, 33)
            a = row_slot[rows, s]
            b = col_slot[cols, t]
            ab = np.where(turned, 4 * b + a, 4 * a + b)
            sign = SLOT_SIGN[a] * SLOT_SIGN[b]
            idx = np.arange(len(rows))
            lv += tab[idx, :, ab]
            ld += tab[:, :, 16] * sign[:, None]
            kk += tab[idx, 0, 17 + ab] + tab[idx, 1, 17 + ab]
    ee = lv @ coef[0:2] + ld @ coef[2:4]
    mm = lv @ coef[4:6] + ld @ coef[6:8]
    return ee, mm, coef[8] * kk


def basis_entries_opencl(ctx, tables, pair_map, row_elem, row_slot, col_elem, col_slot, coef,
                         rows=None, cols=None):
    """OpenCL gather: the full block rows × columns (``rows is None``) or a list of pairs.

    Returns ee, mm, em of shape (n_rows, n_cols) or (P,).
    """
    import pyopencl as cl

    buf = ctx.to_device
    n_source = pair_map.shape[1]
    args = [
        ctx.host_buffer(np.ascontiguousarray(tables, np.complex128)),
        ctx.host_buffer(np.ascontiguousarray(pair_map, np.int32)), np.int32(n_source),
        buf(row_elem, np.int32), buf(row_slot, np.int32), buf(col_elem, np.int32), buf(col_slot, np.int32),
    ]
    coef_buf = buf(coef, np.complex128)
    if rows is None:
        shape = (len(row_elem), len(col_elem))
        knl = ctx.kernel("bem_assembly.cl", "bem_basis_block", ctx.defines(Precision.DOUBLE, BEM_SEGMENT=SEGMENT))
        args += [np.int32(shape[0]), np.int32(shape[1])]
        items = shape[0] * ((shape[1] + SEGMENT - 1) // SEGMENT)
    else:
        shape = (len(rows),)
        knl = ctx.kernel("bem_assembly.cl", "bem_basis_list", ctx.defines(Precision.DOUBLE))
        args += [buf(rows, np.int32), buf(cols, np.int32), np.int32(shape[0])]
        items = shape[0]
    n = int(np.prod(shape))
    outs = [cl.Buffer(ctx.context, cl.mem_flags.WRITE_ONLY, max(n, 1) * 16) for _ in range(3)]
    if n:
        knl(ctx.queue, (items,), None, *args, coef_buf, *outs)
    result = []
    for o in outs:
        host = np.empty(shape, dtype=np.complex128)
        if n:
            cl.enqueue_copy(ctx.queue, host, o)
        result.append(host)
    ctx.queue.finish()
    return tuple(result)


# ---------------------------------------------------------------------------------------------
# Element-table sources for blocks


class _DirectTables:
    """Tables computed for every element pair of each block."""

    reuse = False

    def __init__(self, integrals: ElementIntegrals, wavenumbers):
        self.integrals = integrals
        self.wavenumbers = wavenumbers

    def block(self, test_elems, source_elems):
        t = np.repeat(test_elems, len(source_elems))
        s = np.tile(source_elems, len(test_elems))
        tables, index = self.integrals.indexed_tables(t, s, self.wavenumbers)
        return tables, index.astype(np.int32).reshape(len(test_elems), len(source_elems))


class _ReusedTables:
    """Tables of geometrically distinct element pairs only (exact reuse).

    Two pairs are identical when their index offset (Δs, Δt), the shapes (z10, z01, z11) of both
    elements and the height offset Δz00 are equal bit for bit.
    """

    reuse = True

    def __init__(self, integrals: ElementIntegrals, wavenumbers, shape_ids, n_shapes):
        mesh = integrals.mesh
        n = mesh.cells
        ne = mesh.n_elements
        st = mesh.element_st
        z00 = mesh.geometry[:, 2]
        ds = (st[None, :, 0] - st[:, None, 0] + (n - 1)).astype(np.int64)
        dt = (st[None, :, 1] - st[:, None, 1] + (n - 1)).astype(np.int64)
        dz = z00[None, :] - z00[:, None]
        if np.all(dz == 0.0):
            dz_id, n_dz = np.zeros((ne, ne), dtype=np.int64), 1
        else:
            values, inverse = np.unique(dz.ravel(), return_inverse=True)
            dz_id, n_dz = inverse.reshape(ne, ne).astype(np.int64), len(values)
        key = ds * (2 * n - 1) + dt
        key = (key * n_shapes + shape_ids[:, None]) * n_shapes + shape_ids[None, :]
        key = key * n_dz + dz_id
        unique, first, inverse = np.unique(key.ravel(), return_index=True, return_inverse=True)
        test, source = np.divmod(first, ne)
        logger.info("table reuse: %d distinct element pairs of %d", len(unique), ne * ne)
        self.tables, index = integrals.indexed_tables(test, source, wavenumbers)
        self.map = index[inverse].reshape(ne, ne).astype(np.int32)

    def block(self, test_elems, source_elems):
        return self.tables, self.map[np.ix_(test_elems, source_elems)]


def _table_source(integrals: ElementIntegrals, wavenumbers, allow_reuse: bool):
    shapes = integrals.mesh.geometry[:, 3:6]
    unique, shape_ids = np.unique(shapes, axis=0, return_inverse=True)
    n_shapes = len(unique)
    ne = integrals.mesh.n_elements
    if allow_reuse and n_shapes <= max(1, SHAPE_REUSE_FRACTION * ne) and ne * ne <= 2**28:
        return _ReusedTables(integrals, wavenumbers, shape_ids.ravel().astype(np.int64), n_shapes)
    return _DirectTables(integrals, wavenumbers)


# ---------------------------------------------------------------------------------------------
# Dense assembly


GATHER_ROWS = 1024  # rows of one gather block when the element tables are reused


@dataclass
class AssemblyReport:
    """What the dense assembly did (goes into FarField.diagnostics)."""

    unknowns: int
    seconds: float = 0.0
    table_reuse: bool = False
    blocks: int = 0
    element_pairs: int = 0
    unknown_order: np.ndarray | None = None
    timings: dict = field(default_factory=dict)
    counts: dict = field(default_factory=dict)


@dataclass(frozen=True)
class DenseLayout:
    """Partition of the rooftops into chunks, and the *blocked* unknown ordering it implies.

    ``chunks[i]`` = (bases, elements): documented basis indices of chunk i (in blocked order) and
    the elements their supports touch. Blocked ordering: [J of order | M̃ of order] with
    ``order`` = the chunks' bases concatenated; Z_blocked = Z[np.ix_(unknown_order, unknown_order)].
    """

    chunks: tuple
    offsets: np.ndarray
    n_bases: int

    @property
    def order(self) -> np.ndarray:
        return np.concatenate([c[0] for c in self.chunks])

    @property
    def unknown_order(self) -> np.ndarray:
        order = self.order
        return np.concatenate([order, self.n_bases + order])

    @property
    def is_identity(self) -> bool:
        return bool(np.array_equal(self.order, np.arange(self.n_bases)))


def dense_layout(mesh: BEMMesh, reuse: bool) -> DenseLayout:
    """Chunks of element columns (fresh tables per block) or contiguous ranges (reused tables)."""
    n = mesh.cells
    chunks = []
    if reuse:
        for g0 in range(0, mesh.n_bases, GATHER_ROWS):
            bases = np.arange(g0, min(mesh.n_bases, g0 + GATHER_ROWS))
            chunks.append((bases, np.unique(mesh.basis_elements[bases])))
    else:
        per_column = n * 2 * TABLE * 16  # table bytes of one element column against one column
        width = int(np.clip(int(np.sqrt(TABLE_BUDGET / (per_column * n))) - 1, 1, n))
        owner = mesh.basis_elements[:, 0] % n  # element column t of each basis' plus half
        t_of_e = mesh.element_st[:, 1]
        for c0 in range(0, n, width):
            c1 = min(n, c0 + width)
            bases = np.flatnonzero((owner >= c0) & (owner < c1))
            elements = np.flatnonzero((t_of_e >= c0) & (t_of_e <= min(c1, n - 1)))
            chunks.append((bases, elements))
    sizes = [len(c[0]) for c in chunks]
    return DenseLayout(tuple(chunks), np.concatenate([[0], np.cumsum(sizes)]), mesh.n_bases)


def _distinct(values: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """np.unique(values, return_inverse=True) of integers in [0, ``size``) by marking them: no
    sort, linear in len(values) + size (a strip's hundreds of thousands of basis indices)."""
    mark = np.zeros(size, dtype=bool)
    mark[values] = True
    return np.flatnonzero(mark), (np.cumsum(mark, dtype=np.int64) - 1)[values]


def _local(elements_loaded: np.ndarray, ne: int) -> np.ndarray:
    lookup = np.full(ne, -1, dtype=np.int64)
    lookup[elements_loaded] = np.arange(len(elements_loaded))
    return lookup


def dense_blocks(ctx, mesh: BEMMesh, media: Media, integrals: ElementIntegrals, *,
                 exploit_symmetry: bool = True, allow_reuse: bool = True, report=None):
    """Yield (layout, i, j, ee, mm, em): the basis-pair blocks chunk i × chunk j of the layout.

    With ``exploit_symmetry`` only j ≥ i is yielded; the consumer mirrors (Z is complex-symmetric).
    The first item yielded is the layout itself (``(layout, None, None, None, None, None)``).
    """
    ne = mesh.n_elements
    coef = _coefficients(media)
    source = _table_source(integrals, media.wavenumbers, allow_reuse)
    layout = dense_layout(mesh, source.reuse)
    if report is not None:
        report.table_reuse = source.reuse
    yield layout, None, None, None, None, None
    for i, (rows, test_elems) in enumerate(layout.chunks):
        lt = _local(test_elems, ne)
        for j, (cols, source_elems) in enumerate(layout.chunks):
            if exploit_symmetry and j < i:
                continue
            ls = _local(source_elems, ne)
            tables, pair_map = source.block(test_elems, source_elems)
            row_elem, col_elem = lt[mesh.basis_elements[rows]], ls[mesh.basis_elements[cols]]
            row_slot, col_slot = mesh.basis_slots[rows], mesh.basis_slots[cols]
            if ctx is None:
                R, C = np.meshgrid(np.arange(len(rows)), np.arange(len(cols)), indexing="ij")
                ee, mm, em = (x.reshape(R.shape) for x in basis_entries_numpy(
                    tables, pair_map, row_elem, row_slot, col_elem, col_slot, R.ravel(), C.ravel(), coef))
            else:
                ee, mm, em = basis_entries_opencl(ctx, tables, pair_map, row_elem, row_slot,
                                                  col_elem, col_slot, coef)
            if report is not None:
                report.blocks += 1
                report.element_pairs += pair_map.size
            yield layout, i, j, ee, mm, em


def assemble_dense(ctx, mesh: BEMMesh, media: Media, integrals: ElementIntegrals | None = None, *,
                   exploit_symmetry: bool = True, allow_reuse: bool = True, ordering: str = "documented"):
    """The dense 2N_b × 2N_b PMCHWT matrix Z (complex128) and an :class:`AssemblyReport`.

    ``ordering`` "documented" ([J_h | J_v | M̃_h | M̃_v], mesh.py) or "blocked" (the layout's
    order, cheaper to build: ``report.unknown_order`` maps blocked to documented indices).
    ``ctx`` None uses the NumPy twins throughout (slow; for tests on tiny meshes).
    """
    if ordering not in ("documented", "blocked"):
        raise ValueError(f"ordering must be 'documented' or 'blocked', got {ordering!r}")
    t0 = time.perf_counter()
    integrals = integrals or ElementIntegrals(mesh, ctx=ctx)
    nb = mesh.n_bases
    Z = np.empty((2 * nb, 2 * nb), dtype=np.complex128)
    report = AssemblyReport(unknowns=2 * nb)
    blocks = dense_blocks(ctx, mesh, media, integrals, exploit_symmetry=exploit_symmetry,
                          allow_reuse=allow_reuse, report=report)
    layout = next(blocks)[0]
    off = layout.offsets
    for _, i, j, ee, mm, em in blocks:
        placements = [(slice(off[i], off[i + 1]), slice(off[j], off[j + 1]), False)]
        if exploit_symmetry and i != j:
            placements.append((placements[0][1], placements[0][0], True))
        for r, c, transpose in placements:
            for block, (ro, co) in ((ee, (0, 0)), (em, (0, nb)), (em, (nb, 0)), (mm, (nb, nb))):
                Z[r.start + ro : r.stop + ro, c.start + co : c.stop + co] = block.T if transpose else block
    report.unknown_order = layout.unknown_order
    if ordering == "documented" and not layout.is_identity:
        inverse = np.argsort(report.unknown_order)
        Z = Z[np.ix_(inverse, inverse)]
        report.unknown_order = np.arange(2 * nb)
    report.seconds = time.perf_counter() - t0
    report.timings = dict(integrals.timings)
    report.counts = dict(integrals.counts)
    logger.info("dense Z (%d unknowns) assembled in %.2f s (%d blocks, reuse=%s)",
                2 * nb, report.seconds, report.blocks, report.table_reuse)
    return Z, report


# ---------------------------------------------------------------------------------------------
# Arbitrary basis-pair lists (the entry point the AIM near-field correction uses)


def basis_pair_entries(ctx, mesh: BEMMesh, media: Media, rows, cols,
                       integrals: ElementIntegrals | None = None):
    """ee, mm, em (each (P,)) of the basis pairs (rows[p], cols[p]) (geometric basis indices).

    Computes the tables of exactly the element pairs these basis pairs touch; ``integrals`` is
    anything with ``indexed_tables(test, source, wavenumbers, scratch=True)`` (ElementIntegrals,
    or the AIM's RepeatingTables and TransposedTables, whose index −1 − r says that row r holds
    the pair's other order); its tables are used before this returns, so they may live in a
    buffer that the next call reuses.
    """
    rows = np.asarray(rows, dtype=np.int64)
    cols = np.asarray(cols, dtype=np.int64)
    integrals = integrals or ElementIntegrals(mesh, ctx=ctx)
    ne = mesh.n_elements
    ub_r, inv_r = _distinct(rows, mesh.n_bases)
    ub_c, inv_c = _distinct(cols, mesh.n_bases)
    # the elements of those bases, and each basis half's index among them
    test_elems, row_elem = _distinct(mesh.basis_elements[ub_r].ravel(), ne)
    source_elems, col_elem = _distinct(mesh.basis_elements[ub_c].ravel(), ne)
    row_elem, col_elem = row_elem.reshape(-1, 2), col_elem.reshape(-1, 2)
    # the element pairs actually needed: marked on the dense local map (cheaper than a sort or hash),
    # the integrals' kept one where they have it (all −1; the marked entries are reset on the way out)
    scratch = getattr(integrals, "scratch_pair_map", None)
    shape = (len(test_elems), len(source_elems))
    pair_map = scratch(*shape) if scratch is not None else np.full(shape, -1, dtype=np.int32)
    pairs = np.zeros(0, dtype=np.int64)
    try:
        pair_map[row_elem[inv_r][:, :, None], col_elem[inv_c][:, None, :]] = 0
        pairs = np.flatnonzero(pair_map.ravel() == 0)
        # rows of the table store this call hands the gather (TransposedTables keeps tables for later calls)
        table_rows, held = integrals.store_rows(len(pairs)) if hasattr(integrals, "store_rows") else (len(pairs), 0)
        if ctx is not None and held * 2 * TABLE * 16 > ctx.info.max_alloc_gib * 2**30:
            raise MemoryError(f"the element tables kept for later strips ({held} tables, "
                              f"{held * 2 * TABLE * 16 / 2**30:.2f} GiB) exceed the device's largest buffer "
                              f"({ctx.info.max_alloc_gib:.2f} GiB): assemble in smaller strips")
        split = ctx is not None and len(rows) > 1 and \
            max(table_rows * 2 * TABLE * 16, pair_map.nbytes) > ctx.info.max_alloc_gib * 2**30
        if not split:
            lt_idx, ls_idx = np.divmod(pairs, len(source_elems))
            tables, index = integrals.indexed_tables(test_elems[lt_idx], source_elems[ls_idx], media.wavenumbers,
                                                     scratch=True)
            pair_map.ravel()[pairs] = index
            coef = _coefficients(media)
            row_slot, col_slot = mesh.basis_slots[ub_r], mesh.basis_slots[ub_c]
            if ctx is None:
                return basis_entries_numpy(tables, pair_map, row_elem, row_slot, col_elem, col_slot, inv_r, inv_c, coef)
            return basis_entries_opencl(ctx, tables, pair_map, row_elem, row_slot, col_elem, col_slot, coef,
                                        rows=inv_r, cols=inv_c)
    finally:
        if scratch is not None:
            pair_map.ravel()[pairs] = -1
            integrals.release_pair_map()
    # the tables or the pair map would exceed the device's largest buffer: the pairs in two halves
    half = len(rows) // 2
    parts = [basis_pair_entries(ctx, mesh, media, rows[sl], cols[sl], integrals)
             for sl in (slice(0, half), slice(half, None))]
    return tuple(np.concatenate(arrays) for arrays in zip(*parts))
