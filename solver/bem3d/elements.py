"""Element-pair integrals of the PMCHWT operators: OpenCL kernels, NumPy twins, orchestration.

For a test element A and a source element B (mesh.py for the slots a, b and weights c, t)::

    L_vec[a][b] = ∫∫ c_a c'_b (t_a·t'_b) G          (du dv du' dv')
    L_div       = ∫∫ G                               (L_div(a,b) = s_a s_b L_div)
    K[a][b]     = ∫∫ c_a c'_b ∇G·(t'_b × t_a),      ∇G = ∇_r G(r − r')

One *table* holds 33 complex numbers per medium, [L_vec (4a+b) | L_div | K (4a+b)]; a list of
element pairs gives an array of shape (P, 2, 33) (media 1, 2).

Quadrature (quadrature.py):

* pairs that share a point (self, edge-adjacent, vertex-adjacent): the static parts
  G₀ = 1/(4πR), ∇G₀ are integrated once per geometry with the singular transforms at
  ``static_order``; the per-wavelength remainder G − G₀ with the same transforms at an order
  chosen from |k|·size (it is smooth but, for metals, varies on the scale of the skin depth);
* all other pairs: tensor Gauss–Legendre with a distance- and decay-adaptive order.

Both kernels run for any list of element pairs (the dense matrix uses all of them; the AIM
near-field correction uses a sparse list). The static tables are cached per geometry
(:class:`StaticTables`), and a patch's wavelengths may share them (``[model.aim] reuse_setup``).
Kernels: kernels/bem_elements.cl (``bem_regular_pairs``, ``bem_singular_pairs``); NumPy twins
:func:`regular_pairs_numpy`, :func:`singular_pairs_numpy`.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from wavebrdf.solver.bem3d.mesh import SLOT_TANGENT, BEMMesh, bilinear_frame, slot_weight
from wavebrdf.solver.bem3d.quadrature import (
    CASE_NAMES,
    CASE_REGULAR,
    QuadratureOptions,
    orient,
    pair_case,
    regular_order,
    singular_orders,
    singular_rule,
    tensor_rule,
)
from wavebrdf.solver.precision import Precision

logger = logging.getLogger(__name__)

__all__ = [
    "ElementIntegrals",
    "KIND_FULL",
    "KIND_REMAINDER",
    "KIND_STATIC",
    "STATIC_BYTES_PER_ELEMENT",
    "TABLE",
    "StaticTables",
    "green_terms",
    "regular_pairs_numpy",
    "regular_pairs_opencl",
    "singular_pairs_numpy",
    "singular_pairs_opencl",
    "touching_pairs",
]

TABLE = 33  # complex numbers per medium and pair
KIND_FULL, KIND_REMAINDER, KIND_STATIC = 0, 1, 2  # = BEM_FULL, BEM_REMAINDER, BEM_STATIC
REMAINDER_SAMPLE = 8  # steepest (and as many random) elements whose touching pairs set the remainder orders
REMAINDER_REFERENCE_STEP = 3  # the remainder orders are checked against tables this many orders higher
INV_4PI = 1.0 / (4.0 * np.pi)
OUTPUT_BUDGET = 128 * 2**20  # bytes of kernel output per launch


# ---------------------------------------------------------------------------------------------
# NumPy twins


def one_minus_z_expz_minus_one(z):
    """(1 − z) e^z − 1 without cancellation (series for |z| < 1/2), like bem_green.h."""
    z = np.asarray(z, dtype=complex)
    small = np.abs(z) ** 2 < 0.25
    out = (1.0 - z) * np.exp(z) - 1.0
    zs = z[small]
    term = 0.5 * zs * zs
    total = -term
    for n in range(3, 23):
        term = term * zs / n
        total = total - (n - 1) * term
    out[small] = total
    return out


def green_terms(kind: int, k: complex, r: np.ndarray):
    """(g, gk) with G = g and ∇G = gk·(r − r'), for KIND_FULL or KIND_REMAINDER (see bem_green.h)."""
    r = np.asarray(r, dtype=float)
    z = -1j * k * r
    s1 = INV_4PI / r
    s3 = s1 / (r * r)
    if kind == KIND_REMAINDER:
        return np.expm1(z) * s1, -one_minus_z_expz_minus_one(z) * s3
    if kind == KIND_FULL:
        e = np.exp(z)
        return e * s1, -(1.0 - z) * e * s3
    raise ValueError(f"kind must be KIND_FULL or KIND_REMAINDER, got {kind!r}")


def _point_sums(gA, gB, h, uA, vA, uB, vB, w, wavenumbers, kind):
    """Σ_q over point pairs (axis 1) of the table integrands; returns (P, media, 33)."""
    rA, ruA, rvA = bilinear_frame(gA[:, None, :], h, uA, vA)
    rB, ruB, rvB = bilinear_frame(gB[:, None, :], h, uB, vB)
    R = rA - rB
    r = np.linalg.norm(R, axis=-1)
    tA = np.stack([ruA, rvA], axis=-2)  # (P, Q, 2, 3)
    tB = np.stack([ruB, rvB], axis=-2)
    T = np.einsum("pqic,pqjc->pqij", tA, tB)
    Qx = np.einsum("pqc,pqijc->pqij", R, np.cross(tB[:, :, None, :, :], tA[:, :, :, None, :]))
    T16 = T[:, :, SLOT_TANGENT][:, :, :, SLOT_TANGENT]
    Q16 = Qx[:, :, SLOT_TANGENT][:, :, :, SLOT_TANGENT]
    cA = slot_weight(*np.broadcast_arrays(uA, vA, r)[:2])
    cB = slot_weight(*np.broadcast_arrays(uB, vB, r)[:2])
    cc = np.einsum("apq,bpq->pqab", cA, cB)
    w = np.broadcast_to(w, r.shape)
    if kind == KIND_STATIC:
        kernels = [(INV_4PI / r, -INV_4PI / r**3)]
    else:
        kernels = [green_terms(kind, k, r) for k in wavenumbers]
    out = np.empty((r.shape[0], len(kernels), TABLE), dtype=complex)
    for m, (g, gk) in enumerate(kernels):
        out[:, m, :16] = np.einsum("pqab,pq->pab", cc * T16, w * g).reshape(-1, 16)
        out[:, m, 16] = np.sum(w * g, axis=1)
        out[:, m, 17:] = np.einsum("pqab,pq->pab", cc * Q16, w * gk).reshape(-1, 16)
    return out


def _chunks(n_pairs: int, points: int, budget: int = 40_000):
    step = max(1, budget // max(points, 1))
    for start in range(0, n_pairs, step):
        yield slice(start, min(n_pairs, start + step))


def regular_pairs_numpy(geometry, h, test, source, order, wavenumbers):
    """Tables (P, 2, 33) of element pairs by tensor Gauss of ``order`` (full kernel)."""
    u, v, w = tensor_rule(order)
    n2 = len(u)
    uA, uB = np.repeat(u, n2), np.tile(u, n2)
    vA, vB = np.repeat(v, n2), np.tile(v, n2)
    wq = np.repeat(w, n2) * np.tile(w, n2)
    test = np.asarray(test)
    source = np.asarray(source)
    out = np.empty((len(test), 2, TABLE), dtype=complex)
    for sl in _chunks(len(test), len(wq)):
        out[sl] = _point_sums(
            geometry[test[sl]], geometry[source[sl]], h, uA, vA, uB, vB, wq, wavenumbers, KIND_FULL
        )
    return out


def singular_pairs_numpy(geometry, h, test, source, code_test, code_source, rule, wavenumbers, kind):
    """Tables of touching pairs with a singular ``rule`` (P, 5); (P, 2, 33), or (P, 33) real for
    KIND_STATIC."""
    test = np.asarray(test)
    source = np.asarray(source)
    nmed = 1 if kind == KIND_STATIC else 2
    out = np.empty((len(test), nmed, TABLE), dtype=complex)
    for sl in _chunks(len(test), len(rule)):
        ct = np.asarray(code_test)[sl][:, None]
        cs = np.asarray(code_source)[sl][:, None]
        uA, vA = orient(ct, rule[None, :, 0], rule[None, :, 1])
        uB, vB = orient(cs, rule[None, :, 2], rule[None, :, 3])
        out[sl] = _point_sums(
            geometry[test[sl]], geometry[source[sl]], h, uA, vA, uB, vB, 16.0 * rule[None, :, 4],
            wavenumbers, kind,
        )
    return out[:, 0, :].real.copy() if kind == KIND_STATIC else out


# ---------------------------------------------------------------------------------------------
# OpenCL


def _cplx(value) -> np.ndarray:
    return np.array([complex(value).real, complex(value).imag], dtype=np.float64).view(np.complex128)[0]


WORK_GROUP = 8  # explicit small work-groups: PoCL keeps the large private tables of a whole
# work-group on a worker thread's stack, and its automatic (large) sizes overflow it


def launch_size(ctx, n: int) -> tuple[tuple[int], tuple[int]]:
    """(global, local) sizes for n items, WB_VW = ``ctx.vector_lanes(Precision.DOUBLE)`` items per
    work-item (SIMD lanes on CPUs, 1 on GPUs, where work-items are the lanes), padded to WORK_GROUP
    (or the device's largest work-group where smaller)."""
    lanes = ctx.vector_lanes(Precision.DOUBLE)
    group = ctx.work_group(WORK_GROUP)
    items = (n + lanes - 1) // lanes
    items = (items + group - 1) // group * group
    return (items,), (group,)


def _destination(out, shape, dtype) -> np.ndarray:
    """``out`` checked to be a C-contiguous array of ``shape`` and ``dtype`` (kernels write into
    it), or a fresh one."""
    if out is None:
        return np.empty(shape, dtype=dtype)
    if out.shape != shape or out.dtype != dtype or not out.flags.c_contiguous:
        raise ValueError(f"out must be C-contiguous {np.dtype(dtype)} of shape {shape}, got "
                         f"{out.dtype} {out.shape}")
    return out


def _launch_chunks(n_pairs: int, bytes_per_pair: int):
    step = max(1, OUTPUT_BUDGET // bytes_per_pair)
    for start in range(0, n_pairs, step):
        yield slice(start, min(n_pairs, start + step))


def _geometry_buffer(ctx, geometry):
    """The device buffer of the element geometry: ``geometry`` itself when it is one already (the
    caller uploaded it once for many launches), else a copy of the array."""
    return ctx.to_device(geometry, np.float64) if isinstance(geometry, np.ndarray) else geometry


def regular_pairs_opencl(ctx, geometry, h, test, source, order, wavenumbers, out=None):
    """OpenCL twin of :func:`regular_pairs_numpy` (kernel ``bem_regular_pairs``); written into
    ``out`` (C-contiguous (P, 2, 33) complex128) when given. ``geometry``: the (E, 8) element
    geometry or its device buffer."""
    knl = ctx.kernel("bem_elements.cl", "bem_regular_pairs",
                     ctx.defines(Precision.DOUBLE, lanes=ctx.vector_lanes(Precision.DOUBLE)))
    geom = _geometry_buffer(ctx, geometry)
    x, w = np.polynomial.legendre.leggauss(int(order))
    nodes, weights = ctx.to_device(x), ctx.to_device(w)
    test = np.ascontiguousarray(test, np.int32)
    source = np.ascontiguousarray(source, np.int32)
    out = _destination(out, (len(test), 2, TABLE), np.complex128)
    for sl in _launch_chunks(len(test), 2 * TABLE * 16):
        n = sl.stop - sl.start
        t_buf, s_buf = ctx.to_device(test[sl]), ctx.to_device(source[sl])
        o_buf = ctx.host_buffer(out[sl], "write")  # the kernel writes into out itself on CPU devices
        knl(ctx.queue, *launch_size(ctx, n), geom, np.float64(h), t_buf, s_buf, np.int32(n), nodes, weights,
            np.int32(order), _cplx(wavenumbers[0]), _cplx(wavenumbers[1]), o_buf)
        ctx.read_into(out[sl], o_buf)
    ctx.queue.finish()
    return out


def singular_pairs_opencl(ctx, geometry, h, test, source, code_test, code_source, rule, wavenumbers, kind,
                          out=None, medium: int | None = None):
    """OpenCL twin of :func:`singular_pairs_numpy` (kernel ``bem_singular_pairs``); written into
    ``out`` when given. ``medium`` (0 or 1, not KIND_STATIC): that medium's tables alone, the
    other's left as they are in ``out`` (which is then required)."""
    if medium is not None and (medium not in (0, 1) or kind == KIND_STATIC or out is None):
        raise ValueError(f"medium must be 0 or 1 with out given and a non-static kind, got medium={medium!r}")
    knl = ctx.kernel("bem_elements.cl", "bem_singular_pairs",
                     ctx.defines(Precision.DOUBLE, lanes=ctx.vector_lanes(Precision.DOUBLE), BEM_KIND=int(kind),
                                 BEM_MEDIUM=-1 if medium is None else int(medium)))
    geom = _geometry_buffer(ctx, geometry)
    rule_buf = ctx.to_device(rule, np.float64)
    arrays = [np.ascontiguousarray(a, np.int32) for a in (test, source, code_test, code_source)]
    static = kind == KIND_STATIC
    per_pair = TABLE * (8 if static else 32)
    out = _destination(out, (len(arrays[0]), TABLE) if static else (len(arrays[0]), 2, TABLE),
                       np.float64 if static else np.complex128)
    k1, k2 = (wavenumbers if not static else (0.0, 0.0))
    for sl in _launch_chunks(len(arrays[0]), per_pair):
        n = sl.stop - sl.start
        bufs = [ctx.to_device(a[sl]) for a in arrays]
        o_buf = ctx.host_buffer(out[sl], "write" if medium is None else "read_write")
        knl(ctx.queue, *launch_size(ctx, n), geom, np.float64(h), *bufs, np.int32(n), rule_buf,
            np.int32(len(rule)), _cplx(k1), _cplx(k2), o_buf)
        ctx.read_into(out[sl], o_buf)
    ctx.queue.finish()
    return out


def touching_pairs(cells: int, elements) -> tuple[np.ndarray, np.ndarray]:
    """(test, source): every element of ``elements`` (indices e = s·N + t of an N-cell mesh) with
    each element it touches (itself, its edge and its vertex neighbours inside the mesh)."""
    elements = np.asarray(elements, dtype=np.int64)
    s, t = np.divmod(elements, cells)
    tests, sources = [], []
    for ds in (-1, 0, 1):
        for dt in (-1, 0, 1):
            ok = (s + ds >= 0) & (s + ds < cells) & (t + dt >= 0) & (t + dt < cells)
            tests.append(elements[ok])
            sources.append((s[ok] + ds) * cells + t[ok] + dt)
    return np.concatenate(tests), np.concatenate(sources)


# ---------------------------------------------------------------------------------------------
# Orchestration

STATIC_BYTES_PER_ELEMENT = 9 * TABLE * 8  # the float64 static tables of an element's 9 touching pairs


class StaticTables:
    """The static singular tables (the G₀ = 1/(4πR) parts) of one mesh's touching element pairs at
    one quadrature order: real (33,) rows by test element and neighbour slot, filled as pairs are
    asked for (pages are touched only where written: at most :data:`STATIC_BYTES_PER_ELEMENT` per
    element). They depend on the geometry alone, not on the wavelength or the material, so the
    solves of one patch at several wavelengths can share them (:meth:`serves`)."""

    def __init__(self, mesh: BEMMesh, static_order: int):
        self.key = (mesh.digest, int(static_order))
        slots = 9 * mesh.n_elements
        self.values = np.empty((slots, TABLE))
        self.known = np.zeros(slots, dtype=bool)

    def serves(self, mesh: BEMMesh, static_order: int) -> bool:
        """Whether these are the tables of ``mesh``'s geometry at ``static_order``."""
        return self.key == (mesh.digest, int(static_order))

    def bytes(self) -> int:
        """Bytes of the rows filled so far (and their flags)."""
        return int(np.count_nonzero(self.known)) * TABLE * 8 + self.known.nbytes


class ElementIntegrals:
    """Tables of arbitrary element-pair lists of one mesh, with cached static singular parts.

    ``ctx`` None runs the NumPy twins (reference path); otherwise the OpenCL kernels. ``static``:
    the StaticTables of an earlier solve of this geometry, used (and filled further) when they
    serve this mesh at this static order (:meth:`StaticTables.serves`), else new ones are made.
    """

    def __init__(self, mesh: BEMMesh, options: QuadratureOptions | None = None, ctx=None,
                 static: StaticTables | None = None):
        self.mesh = mesh
        self.options = options or QuadratureOptions()
        self.ctx = ctx
        served = static is not None and static.serves(mesh, self.options.static_order)
        self.static = static if served else None  # made at the first touching pair otherwise
        self._scratch = None  # reused table buffer of indexed_tables(scratch=True)
        self._pair_map = np.zeros(0, dtype=np.int32)  # reused element-pair map (scratch_pair_map), all −1
        self._pair_map_held = False
        self._device_geometry = None  # the geometry's device buffer, uploaded at the first launch
        self.timings = {"static_s": 0.0, "singular_s": 0.0, "regular_s": 0.0}
        self._remainder_orders: dict = {}  # wavenumbers → [order per medium]
        self.counts = {"static": 0, "singular": 0, "regular": 0, "regular_points": 0}

    # -- backends ---------------------------------------------------------------------------
    def _geometry(self):
        """The element geometry for the kernels: its device buffer (uploaded once), or the array."""
        if self.ctx is None:
            return self.mesh.geometry
        if self._device_geometry is None:
            self._device_geometry = self.ctx.to_device(self.mesh.geometry, np.float64)
        return self._device_geometry

    def _regular(self, test, source, order, wavenumbers, out):
        g, h = self._geometry(), self.mesh.half
        if self.ctx is None:
            out[...] = regular_pairs_numpy(g, h, test, source, order, wavenumbers)
        else:
            regular_pairs_opencl(self.ctx, g, h, test, source, order, wavenumbers, out=out)

    def _singular(self, test, source, ct, cs, rule, wavenumbers, kind, out, medium=None):
        g, h = self._geometry(), self.mesh.half
        if self.ctx is not None:
            singular_pairs_opencl(self.ctx, g, h, test, source, ct, cs, rule, wavenumbers, kind, out=out,
                                  medium=medium)
        elif medium is None:
            out[...] = singular_pairs_numpy(g, h, test, source, ct, cs, rule, wavenumbers, kind)
        else:
            out[:, medium] = singular_pairs_numpy(g, h, test, source, ct, cs, rule, wavenumbers, kind)[:, medium]

    # -- classification ---------------------------------------------------------------------
    def classify(self, test, source):
        """(case, code_test, code_source) of each pair (quadrature.pair_case)."""
        st = self.mesh.element_st
        d = st[source] - st[test]
        return pair_case(d[:, 0], d[:, 1])

    def orders(self, test, source, wavenumbers) -> np.ndarray:
        """Adaptive Gauss order of each (non-touching) pair."""
        g = self.mesh.geometry
        centre_t = np.stack([g[test, 0], g[test, 1], g[test, 2]], axis=1)
        centre_s = np.stack([g[source, 0], g[source, 1], g[source, 2]], axis=1)
        distance = np.linalg.norm(centre_t - centre_s, axis=1)
        rad = self.mesh.element_radius
        ell = np.maximum(self.mesh.half_length[test], self.mesh.half_length[source])
        return regular_order(self.options, distance, rad[test], rad[source], ell, wavenumbers)

    # -- per-wavelength singular remainder --------------------------------------------------
    def remainder_orders(self, wavenumbers) -> list[int]:
        """Gauss order of the singular transforms for the remainder G − G₀ of each medium, measured
        on this mesh: from the a priori :func:`singular_orders` up, the smallest order whose
        remainder tables of a sample of touching pairs are within ``options.tolerance`` of those
        :data:`REMAINDER_REFERENCE_STEP` orders higher (each pair and medium relative to its own
        largest entry; the reference is raised while an order reaches it, up to ``max_order``).
        The sample is the self, edge and vertex pairs of the :data:`REMAINDER_SAMPLE` steepest
        elements and as many chosen at random (seed 0). Cached per wavenumbers.

        The a priori model alone (oscillation of e^{−jkR} over the half-length) misses the tolerance
        by 10–100× at |k|ℓ ≲ 1 (docs/bem3d.md, "Singular remainder orders"), where the bilinear
        geometry and the transforms' Jacobians, not the kernel, set the error.
        """
        key = tuple(complex(k) for k in wavenumbers)
        if key in self._remainder_orders:
            return self._remainder_orders[key]
        test, source = self._remainder_sample()
        case, code_t, code_s = self.classify(test, source)
        top = self.options.max_order

        def tables(medium, n):
            out = np.zeros((len(test), 2, TABLE), dtype=complex)
            for c in np.unique(case):
                sel = np.flatnonzero(case == c)
                part = out[sel]
                self._singular(test[sel], source[sel], code_t[sel], code_s[sel], singular_rule(int(c), n),
                               wavenumbers, KIND_REMAINDER, part, medium)
                out[sel] = part
            return out[:, medium]

        a_priori = singular_orders(self.options, self.mesh.half_length.max(), wavenumbers)
        orders = []
        for m, n in enumerate(a_priori):
            reference_order = min(top, n + REMAINDER_REFERENCE_STEP)
            reference = tables(m, reference_order)
            while True:
                scale = np.maximum(np.abs(reference).max(axis=-1), np.finfo(float).tiny)
                while n < reference_order and (np.abs(tables(m, n) - reference).max(axis=-1) / scale).max() \
                        > self.options.tolerance:
                    n += 1
                if n < reference_order or reference_order == top:
                    break
                reference_order = min(top, n + REMAINDER_REFERENCE_STEP)
                reference = tables(m, reference_order)
            if n >= top:
                logger.warning("singular remainder of medium %d (k = %s µm⁻¹): quadrature.max_order %d reached; "
                               "its tables may miss quadrature.tolerance %.1e", m, key[m], top, self.options.tolerance)
            orders.append(n)
        logger.debug("singular remainder orders %s (a priori %s)", orders, a_priori)
        self._remainder_orders[key] = orders
        return orders

    def _remainder_sample(self) -> tuple[np.ndarray, np.ndarray]:
        """(test, source) touching pairs of the sample elements (see :meth:`remainder_orders`)."""
        n = self.mesh.cells
        shape = np.abs(self.mesh.geometry[:, 3:6]).sum(axis=1)
        count = min(REMAINDER_SAMPLE, len(shape))
        steep = np.argsort(shape)[::-1][:count]
        chosen = np.unique(np.concatenate([steep, np.random.default_rng(0).choice(len(shape), count, replace=False)]))
        return touching_pairs(n, chosen)

    # -- static singular parts --------------------------------------------------------------
    def _touching_slot(self, test, source) -> np.ndarray:
        """test · 9 + 3(Δs + 1) + (Δt + 1): the cache row of a touching pair."""
        d = self.mesh.element_st[source] - self.mesh.element_st[test]
        return test.astype(np.int64) * 9 + 3 * (d[:, 0] + 1) + (d[:, 1] + 1)

    def static_tables(self, test, source, case, code_t, code_s) -> np.ndarray:
        """Real (P, 33) static tables of touching pairs, computed once per pair and cached
        (rows by test element and neighbour slot: lookups cost O(P) however large the cache)."""
        if self.static is None:
            self.static = StaticTables(self.mesh, self.options.static_order)
        cache = self.static
        slot = self._touching_slot(test, source)
        missing = np.flatnonzero(~cache.known[slot])
        if len(missing):
            t0 = time.perf_counter()
            _, first = np.unique(slot[missing], return_index=True)  # a pair listed twice: once
            missing = missing[first]
            for c in np.unique(case[missing]):
                sel = missing[case[missing] == c]
                rule = singular_rule(int(c), self.options.static_order)
                values = np.empty((len(sel), TABLE))
                self._singular(test[sel], source[sel], code_t[sel], code_s[sel], rule, (0.0, 0.0),
                               KIND_STATIC, values)
                cache.values[slot[sel]] = values
            cache.known[slot[missing]] = True
            self.timings["static_s"] += time.perf_counter() - t0
            self.counts["static"] += len(missing)
        return cache.values[slot]

    def release_scratch(self) -> None:
        """Free the scratch table buffer and pair map (the next scratch call allocates new ones)."""
        self._scratch = None
        self._pair_map = np.zeros(0, dtype=np.int32)

    def scratch_pair_map(self, n_test: int, n_source: int) -> np.ndarray:
        """An int32 (n_test, n_source) map of −1 over a kept buffer (grown by a quarter when short):
        assembly.basis_pair_entries' element-pair map, strip after strip without fresh pages. The
        caller sets the entries it wrote back to −1 and calls :meth:`release_pair_map`; a second
        caller before that is refused (the map is one buffer)."""
        if self._pair_map_held:
            raise RuntimeError("the element-pair map is in use by another basis_pair_entries call")
        n = n_test * n_source
        if len(self._pair_map) < n:
            self._pair_map = np.zeros(0, dtype=np.int32)
            self._pair_map = np.full(n + n // 4, -1, dtype=np.int32)
        self._pair_map_held = True
        return self._pair_map[:n].reshape(n_test, n_source)

    def release_pair_map(self) -> None:
        """The caller of :meth:`scratch_pair_map` is done (its entries are −1 again)."""
        self._pair_map_held = False

    def _scratch_tables(self, n: int) -> np.ndarray:
        """The first n rows of the scratch table buffer (grown by a quarter when short)."""
        if self._scratch is None or len(self._scratch) < n:
            self._scratch = None  # the old buffer goes before the new one is allocated
            self._scratch = np.empty((n + n // 4, 2, TABLE), dtype=complex)
        return self._scratch[:n]

    # -- tables -----------------------------------------------------------------------------
    def indexed_tables(self, test, source, wavenumbers, *, scratch: bool = False,
                       out: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(tables, index): complex (P, 2, 33) tables of the element pairs (test[p], source[p])
        for media k₁, k₂, stored grouped by quadrature (each kernel writes one contiguous block);
        pair p's table is ``tables[index[p]]``.

        ``scratch``: the tables live in a buffer that the next scratch call overwrites (callers
        that use them at once, strip after strip, then touch no fresh pages per call); ``out``:
        they are written into this complex array of shape (len(test), 2, 33) instead."""
        test = np.asarray(test, dtype=np.int64)
        source = np.asarray(source, dtype=np.int64)
        if len(test) == 0:
            return np.empty((0, 2, TABLE), dtype=complex), np.empty(0, dtype=np.int64)
        case, code_t, code_s = self.classify(test, source)
        group = case.astype(np.int64)  # touching: case 1..3; regular: 4 + Gauss order
        regular = np.flatnonzero(case == CASE_REGULAR)
        if len(regular):
            group[regular] = 4 + self.orders(test[regular], source[regular], wavenumbers)
        order = np.argsort(group, kind="stable")
        index = np.empty(len(test), dtype=np.int64)
        index[order] = np.arange(len(test))
        bounds = np.flatnonzero(np.diff(group[order])) + 1
        if out is None:
            out = self._scratch_tables(len(test)) if scratch else np.empty((len(test), 2, TABLE), dtype=complex)
        elif out.shape != (len(test), 2, TABLE) or out.dtype != complex:
            raise ValueError(f"out must be complex128 of shape {(len(test), 2, TABLE)}, got {out.dtype} {out.shape}")
        remainder_order = None
        for a, b in zip(np.concatenate([[0], bounds]), np.concatenate([bounds, [len(test)]])):
            sel = order[a:b]
            g = int(group[sel[0]])
            t0 = time.perf_counter()
            if g >= 4:
                self._regular(test[sel], source[sel], g - 4, wavenumbers, out[a:b])
                self.counts["regular_points"] += len(sel) * (g - 4) ** 4
                self.counts["regular"] += len(sel)
                self.timings["regular_s"] += time.perf_counter() - t0
                continue
            static = self.static_tables(test[sel], source[sel], case[sel], code_t[sel], code_s[sel])
            t0 = time.perf_counter()
            if remainder_order is None:
                remainder_order = self.remainder_orders(wavenumbers)
            # one launch for both media at a common order; each medium at its own where they differ
            launches = list(enumerate(remainder_order))
            if len(set(remainder_order)) == 1:
                launches = [(None, remainder_order[0])]
            for medium, n in launches:
                self._singular(test[sel], source[sel], code_t[sel], code_s[sel], singular_rule(g, n), wavenumbers,
                               KIND_REMAINDER, out[a:b], medium)
            out[a:b] += static[:, None, :]
            logger.debug("%d %s pairs, remainder orders %s", len(sel), CASE_NAMES[g], remainder_order)
            self.timings["singular_s"] += time.perf_counter() - t0
            self.counts["singular"] += len(sel)
        return out, index

    def tables(self, test, source, wavenumbers) -> np.ndarray:
        """Complex (P, 2, 33) tables of element pairs (test[p], source[p]) for media k₁, k₂."""
        out, index = self.indexed_tables(test, source, wavenumbers)
        return out[index]
