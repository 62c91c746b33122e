"""Element integrals and assembly: OpenCL kernels = NumPy twins, and properties of the operator."""

from __future__ import annotations

import numpy as np
import pytest

from wavebrdf.solver.bem3d import assembly
from wavebrdf.solver.bem3d import elements as el
from wavebrdf.solver.bem3d.assembly import (
    assemble_dense,
    basis_entries_numpy,
    basis_entries_opencl,
    basis_pair_entries,
)
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import BEMMesh
from wavebrdf.solver.bem3d.quadrature import QuadratureOptions, pair_case, singular_rule
from wavebrdf.solver.surface import HeightField, generate


def _ks(references, index):
    k0 = 2 * np.pi / references["wavelength"]
    return (k0, k0 * index)


def _rel(a, b):
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def _random_pairs(mesh, rng, count, touching):
    st = mesh.element_st
    test = rng.integers(0, mesh.n_elements, 4 * count)
    source = rng.integers(0, mesh.n_elements, 4 * count)
    d = np.abs(st[source] - st[test])
    keep = (np.max(d, axis=1) <= 1) if touching else (np.max(d, axis=1) >= 2)
    return test[keep][:count], source[keep][:count]


@pytest.mark.parametrize("order", [2, 3, 5])
def test_regular_kernel_matches_numpy(cl_ctx, curved_mesh, rng, references, order):
    test, source = _random_pairs(curved_mesh, rng, 37, touching=False)
    ks = _ks(references, references["al_400"])
    a = el.regular_pairs_opencl(cl_ctx, curved_mesh.geometry, curved_mesh.half, test, source, order, ks)
    b = el.regular_pairs_numpy(curved_mesh.geometry, curved_mesh.half, test, source, order, ks)
    assert _rel(a, b) < 1e-10


@pytest.mark.parametrize("kind", [el.KIND_STATIC, el.KIND_REMAINDER, el.KIND_FULL])
@pytest.mark.parametrize("offset", [(0, 0), (1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)])
def test_singular_kernel_matches_numpy(cl_ctx, curved_mesh, references, kind, offset):
    n = curved_mesh.cells
    test = np.array([n + 1, 2 * n + 2, 3 * n + 3, 2 * n + 3, 3 * n + 2])  # 5 pairs: partial vector lanes
    source = test + offset[0] * n + offset[1]
    case, ct, cs = pair_case(np.full(5, offset[0]), np.full(5, offset[1]))
    rule = singular_rule(int(case[0]), 4)
    ks = _ks(references, 1.3 - 2.0j)
    g, h = curved_mesh.geometry, curved_mesh.half
    a = el.singular_pairs_opencl(cl_ctx, g, h, test, source, ct, cs, rule, ks, kind)
    b = el.singular_pairs_numpy(g, h, test, source, ct, cs, rule, ks, kind)
    assert _rel(a, b) < 1e-10


def test_remainder_series_matches_direct_formula():
    """(1 − z)e^z − 1: the small-|z| series agrees with the closed form where both are accurate."""
    z = np.array([0.3 + 0.2j, -0.1 - 0.45j, 0.49j])
    series = el.one_minus_z_expz_minus_one(z)  # |z| < 1/2: series branch
    direct = (1 - z) * np.exp(z) - 1
    assert np.allclose(series, direct, rtol=1e-13, atol=0)
    tiny = np.array([1e-9j])
    assert el.one_minus_z_expz_minus_one(tiny)[0] == pytest.approx(-0.5 * tiny[0] ** 2, rel=1e-12)


def test_remainder_plus_static_equals_full_kernel(cl_ctx, curved_mesh, references):
    """For touching pairs, static + remainder = the full kernel integrated by the same rule."""
    n = curved_mesh.cells
    test = np.array([2 * n + 2])
    source = test + 1
    case, ct, cs = pair_case(np.array([0]), np.array([1]))
    rule = singular_rule(int(case[0]), 6)
    ks = _ks(references, 1.5)
    g, h = curved_mesh.geometry, curved_mesh.half
    static = el.singular_pairs_opencl(cl_ctx, g, h, test, source, ct, cs, rule, ks, el.KIND_STATIC)
    rem = el.singular_pairs_opencl(cl_ctx, g, h, test, source, ct, cs, rule, ks, el.KIND_REMAINDER)
    full = el.singular_pairs_opencl(cl_ctx, g, h, test, source, ct, cs, rule, ks, el.KIND_FULL)
    assert _rel(rem + static[:, None, :], full) < 1e-12


def test_tilted_plane_has_no_double_layer_part(cl_ctx, references):
    """All elements of a plane are coplanar: R·(t'×t) = 0, so every K table vanishes."""
    d = references["wavelength"] / 8
    x = np.arange(6) * d
    X, Y = np.meshgrid(x, x, indexing="ij")
    mesh = BEMMesh(HeightField(0.4 * X - 0.7 * Y, 5 * d))
    integrals = el.ElementIntegrals(mesh, ctx=cl_ctx)
    test = np.repeat(np.arange(mesh.n_elements), mesh.n_elements)
    source = np.tile(np.arange(mesh.n_elements), mesh.n_elements)
    tables = integrals.tables(test, source, _ks(references, 1.5))
    assert np.max(np.abs(tables[:, :, 17:])) < 1e-10 * np.max(np.abs(tables[:, :, :16]))


def test_gather_kernel_matches_numpy(cl_ctx, rng):
    tables = rng.standard_normal((50, 2, 33)) + 1j * rng.standard_normal((50, 2, 33))
    pair_map = rng.integers(0, 50, (7, 9)).astype(np.int32)
    row_elem, col_elem = rng.integers(0, 7, (11, 2)), rng.integers(0, 9, (13, 2))
    row_slot, col_slot = rng.integers(0, 4, (11, 2)), rng.integers(0, 4, (13, 2))
    coef = rng.standard_normal(9) + 1j * rng.standard_normal(9)
    block = basis_entries_opencl(cl_ctx, tables, pair_map, row_elem, row_slot, col_elem, col_slot, coef)
    R, C = np.meshgrid(np.arange(11), np.arange(13), indexing="ij")
    ref = basis_entries_numpy(tables, pair_map, row_elem, row_slot, col_elem, col_slot, R.ravel(), C.ravel(), coef)
    rows, cols = rng.integers(0, 11, 20), rng.integers(0, 13, 20)
    listed = basis_entries_opencl(cl_ctx, tables, pair_map, row_elem, row_slot, col_elem, col_slot, coef,
                                  rows=rows, cols=cols)
    for k in range(3):
        assert _rel(block[k], ref[k].reshape(11, 13)) < 1e-13
        assert _rel(listed[k], ref[k].reshape(11, 13)[rows, cols]) < 1e-13


@pytest.fixture(scope="module")
def rough_setup(cl_ctx, references):
    surface = generate("gaussian", cells=10, size_um=0.5, seed=2, rms_height_um=0.03, correlation_um=0.15)
    mesh = BEMMesh(surface)
    media = Media(references["wavelength"], references["al_400"])
    with pytest.MonkeyPatch.context() as mp:  # small blocks: exercise the multi-block layout
        mp.setattr(assembly, "TABLE_BUDGET", 4 * 2**20)
        Z, report = assemble_dense(cl_ctx, mesh, media, exploit_symmetry=False)
    return mesh, media, Z, report


def test_dense_matrix_is_complex_symmetric(rough_setup):
    """Every block is computed independently (no mirroring): ‖Z − Zᵀ‖/‖Z‖ < 1e-10."""
    _, _, Z, report = rough_setup
    assert not report.table_reuse and report.blocks > 1
    assert np.linalg.norm(Z - Z.T) / np.linalg.norm(Z) < 1e-10


@pytest.mark.parametrize("cells", [3, pytest.param(5, marks=pytest.mark.slow)])
def test_dense_matrix_opencl_matches_numpy_twins(cl_ctx, references, cells):
    """CI: 3 × 3 cells, every kind of pair (self, edge, vertex, far) at the twins' cost of seconds per element."""
    surface = generate("gaussian", cells=cells, size_um=0.05 * cells, seed=4, rms_height_um=0.03, correlation_um=0.1)
    mesh = BEMMesh(surface)
    media = Media(references["wavelength"], references["al_400"])
    Z, _ = assemble_dense(cl_ctx, mesh, media)
    Zr, _ = assemble_dense(None, mesh, media)
    assert np.linalg.norm(Z - Zr) / np.linalg.norm(Zr) < 1e-10


def test_blocked_ordering_is_a_permutation_of_the_documented_one(cl_ctx, rough_setup):
    mesh, media, Z, _ = rough_setup
    Zb, report = assemble_dense(cl_ctx, mesh, media, ordering="blocked")
    order = report.unknown_order
    assert np.array_equal(np.sort(order), np.arange(mesh.n_unknowns))
    assert np.linalg.norm(Zb - Z[np.ix_(order, order)]) / np.linalg.norm(Z) < 1e-12


def test_basis_pair_list_equals_dense_entries(cl_ctx, rough_setup, rng):
    """The sparse entry point (AIM near field) gives the dense matrix's entries."""
    mesh, media, Z, _ = rough_setup
    nb = mesh.n_bases
    rows, cols = rng.integers(0, nb, 60), rng.integers(0, nb, 60)
    ee, mm, em = basis_pair_entries(cl_ctx, mesh, media, rows, cols)
    scale = np.abs(Z).max()
    assert np.abs(ee - Z[rows, cols]).max() < 1e-12 * scale
    assert np.abs(mm - Z[nb + rows, nb + cols]).max() < 1e-12 * scale
    assert np.abs(em - Z[rows, nb + cols]).max() < 1e-12 * scale
    assert np.abs(em - Z[nb + rows, cols]).max() < 1e-12 * scale


def test_basis_pair_lists_share_one_pair_map_call_after_call(cl_ctx, rough_setup, rng):
    """Calls on one ElementIntegrals reuse its pair map: each call's entries are the dense matrix's
    (none sees a pair marked by the one before), the map is all −1 after each, and a call while
    the map is held is refused."""
    mesh, media, Z, _ = rough_setup
    nb = mesh.n_bases
    integrals = el.ElementIntegrals(mesh, ctx=cl_ctx)
    scale = np.abs(Z).max()
    for size in (80, 30, 120):
        rows, cols = rng.integers(0, nb, size), rng.integers(0, nb, size)
        ee, mm, em = basis_pair_entries(cl_ctx, mesh, media, rows, cols, integrals=integrals)
        assert np.abs(ee - Z[rows, cols]).max() < 1e-12 * scale
        assert np.abs(mm - Z[nb + rows, nb + cols]).max() < 1e-12 * scale
        assert np.abs(em - Z[rows, nb + cols]).max() < 1e-12 * scale
        assert len(integrals._pair_map) and np.all(integrals._pair_map == -1)
    integrals.scratch_pair_map(3, 4)  # a caller holds the map: a second one is refused, not served stale
    with pytest.raises(RuntimeError, match="in use"):
        basis_pair_entries(cl_ctx, mesh, media, rows, cols, integrals=integrals)
    integrals.release_pair_map()


def test_distinct_indices_by_marking_are_numpys_unique(rng):
    """The pair list's distinct bases and elements (marked, not sorted) are np.unique's, inverse
    included, for unsorted input with repeats and for values at both ends of the range."""
    values = np.concatenate([rng.integers(0, 1000, 5000), [0, 999, 999]])
    distinct, inverse = assembly._distinct(values, 1000)
    expected, expected_inverse = np.unique(values, return_inverse=True)
    assert np.array_equal(distinct, expected) and np.array_equal(inverse, expected_inverse)
    assert np.array_equal(distinct[inverse], values)


def test_basis_pairs_whose_tables_exceed_the_devices_largest_buffer_are_split(cl_ctx, rough_setup, rng, monkeypatch):
    """A device whose largest allocation (8 MiB here: above the quadrature rules' 6.6 MB at order
    12, below the 8 000 pairs' tables; PoCL reports 1 GiB when the host's free memory is low, GPUs a
    quarter of theirs) gets the same entries, the list assembled in parts, no buffer above that size."""
    import dataclasses

    from wavebrdf.solver.opencl import ComputeContext

    mesh, media, Z, _ = rough_setup
    nb = mesh.n_bases
    rows, cols = rng.integers(0, nb, 8000), rng.integers(0, nb, 8000)
    limit = 8 * 2**20
    small = dataclasses.replace(cl_ctx, info=dataclasses.replace(cl_ctx.info, max_alloc_gib=limit / 2**30),
                                _programs={}, _kernels={})
    sizes = []
    for method in ("to_device", "host_buffer"):
        real = getattr(ComputeContext, method)

        def recording(self, array, *args, _real=real, **kwargs):
            sizes.append(np.asarray(array).nbytes)
            return _real(self, array, *args, **kwargs)

        monkeypatch.setattr(ComputeContext, method, recording)
    ee, mm, em = basis_pair_entries(small, mesh, media, rows, cols)
    scale = np.abs(Z).max()
    assert np.abs(ee - Z[rows, cols]).max() < 1e-12 * scale
    assert np.abs(mm - Z[nb + rows, nb + cols]).max() < 1e-12 * scale
    assert np.abs(em - Z[rows, nb + cols]).max() < 1e-12 * scale
    assert max(sizes) <= limit


def test_identical_element_pairs_reuse_tables_exactly(cl_ctx, references):
    """A tilted plane: reused tables (one per distinct pair geometry) = fresh tables per pair."""
    i, j = np.meshgrid(np.arange(9), np.arange(9), indexing="ij")
    heights = (3 * i - j) / 256.0  # dyadic: every element has bit-identical coefficients
    mesh = BEMMesh(HeightField(heights, 0.4), z_reference=0.0)
    media = Media(references["wavelength"], 1.5)
    Za, ra = assemble_dense(cl_ctx, mesh, media, allow_reuse=True)
    Zb, rb = assemble_dense(cl_ctx, mesh, media, allow_reuse=False)
    assert ra.table_reuse and not rb.table_reuse
    assert np.linalg.norm(Za - Zb) / np.linalg.norm(Zb) < 1e-13


def test_tables_of_overlapping_lists_match_a_fresh_computation(cl_ctx, curved_mesh, rng, references):
    """The static cache (rows by touching slot) and the grouped, indexed tables: two lists sharing
    touching pairs (one listed twice), in any order, give exactly what a fresh object gives."""
    ks = _ks(references, references["al_400"])
    near_t, near_s = _random_pairs(curved_mesh, rng, 60, touching=True)
    far_t, far_s = _random_pairs(curved_mesh, rng, 40, touching=False)
    first_t, first_s = np.concatenate([near_t[:40], far_t[:20]]), np.concatenate([near_s[:40], far_s[:20]])
    second_t = np.concatenate([far_t[20:], near_t[20:], near_t[25:26], near_t[45:46]])  # one cached,
    second_s = np.concatenate([far_s[20:], near_s[20:], near_s[25:26], near_s[45:46]])  # one new twice
    cached = el.ElementIntegrals(curved_mesh, ctx=cl_ctx)
    cached.tables(first_t, first_s, ks)
    static_before = cached.counts["static"]
    tables, index = cached.indexed_tables(second_t, second_s, ks)
    known = set(zip(near_t[:40].tolist(), near_s[:40].tolist()))
    new = set(zip(near_t[20:].tolist(), near_s[20:].tolist())) - known
    assert cached.counts["static"] - static_before == len(new) > 0
    fresh = el.ElementIntegrals(curved_mesh, ctx=cl_ctx).tables(second_t, second_s, ks)
    assert sorted(index.tolist()) == list(range(len(second_t)))
    assert np.array_equal(tables[index], fresh)
    every = slice(None, None, 5)  # the NumPy twins on every fifth pair, far and touching (they take seconds per pair)
    reference = el.ElementIntegrals(curved_mesh, ctx=None).tables(second_t[every], second_s[every], ks)
    assert _rel(fresh[every], reference) < 1e-10


def test_static_tables_serve_another_wavelength_of_their_geometry_and_no_other(cl_ctx, curved_mesh, rng, references):
    """The static tables (G₀ parts) of one solve, given to the next wavelength's integrals of the
    same geometry, are used without computing any again, and the tables there equal a fresh
    computation exactly (and the NumPy twins); another geometry or static order gets its own."""
    near_t, near_s = _random_pairs(curved_mesh, rng, 60, touching=True)
    first = el.ElementIntegrals(curved_mesh, ctx=cl_ctx)
    first.tables(near_t, near_s, _ks(references, references["al_400"]))
    assert first.counts["static"] > 0 and first.static.bytes() > 0
    other_k = (2 * np.pi / 0.55, 2 * np.pi / 0.55 * (0.96 - 6.69j))  # another wavelength and index
    again = el.ElementIntegrals(curved_mesh, ctx=cl_ctx, static=first.static)
    assert again.static is first.static
    tables = again.tables(near_t, near_s, other_k)
    assert again.counts["static"] == 0 and again.timings["static_s"] == 0.0
    assert np.array_equal(tables, el.ElementIntegrals(curved_mesh, ctx=cl_ctx).tables(near_t, near_s, other_k))
    every = slice(None, None, 5)  # the NumPy twins on every fifth pair
    assert _rel(tables[every], el.ElementIntegrals(curved_mesh, ctx=None).tables(near_t[every], near_s[every],
                                                                                 other_k)) < 1e-10
    # the mesh geometry is the heights minus the reference: another reference is another key
    shifted = BEMMesh(curved_mesh.surface, z_reference=float(np.mean(curved_mesh.surface.z)) + 0.01)
    assert not first.static.serves(shifted, first.options.static_order)
    bumped = BEMMesh(HeightField(curved_mesh.surface.z * 1.01, curved_mesh.surface.size_um))
    refused = el.ElementIntegrals(bumped, ctx=cl_ctx, static=first.static)
    assert refused.static is None
    refused.tables(near_t, near_s, other_k)
    assert refused.counts["static"] > 0 and refused.static is not first.static
    higher = QuadratureOptions(static_order=first.options.static_order + 1)
    assert el.ElementIntegrals(curved_mesh, higher, ctx=cl_ctx, static=first.static).static is None
