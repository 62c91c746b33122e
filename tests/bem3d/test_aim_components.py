"""AIM building blocks: grid, projections, sampled Green's function, decay criterion, and every
OpenCL kernel against its NumPy twin (scatter / Fourier / gather, near-field SpMV, near B)."""

from __future__ import annotations

import numpy as np
import pytest

from wavebrdf.solver.bem3d.aim.convolution import BaseOperator, GridGroup, forward_pruned, inverse_pruned
from wavebrdf.solver.bem3d.aim.green import grid_media, interior_decay, kernel_spectra, lattice_green
from wavebrdf.solver.bem3d.aim.grid import GridOptions, build_grid
from wavebrdf.solver.bem3d.aim.near_assembly import assemble_near, near_base_numpy
from wavebrdf.solver.bem3d.aim.nearfield import BLOCKS, TILE_ROWS, NearMatrix, NearPattern
from wavebrdf.solver.bem3d.aim.projection import basis_quadrature, fibonacci_directions, project
from wavebrdf.solver.bem3d.assembly import basis_pair_entries
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import BEMMesh, near_first
from wavebrdf.solver.precision import Precision
from wavebrdf.solver.surface import HeightField, generate

LAMBDA = 0.5


@pytest.fixture(scope="module")
def rough_mesh():
    """8×8 cells at d = λ/10, Gaussian roughness (several z planes)."""
    d = LAMBDA / 10
    return BEMMesh(generate("gaussian", cells=8, size_um=8 * d, seed=5, rms_height_um=0.06, correlation_um=0.2))


def test_grid_contains_every_stencil_and_fft_sizes_are_smooth(rough_mesh):
    grid = build_grid(rough_mesh)
    pts = grid.stencil_points()
    assert pts.min() >= 0
    assert np.all(pts.max(axis=(0, 1)) < np.asarray(grid.shape))
    for n, p in zip(grid.shape, grid.padded):
        assert p >= 2 * n - 1
        m = p
        for f in (2, 3, 5, 7, 11):
            while m % f == 0:
                m //= f
        assert m == 1
    # stencil surrounds the rooftop centre in x and y (even stencil: centre in the middle cell)
    centre = rough_mesh.basis_centres / np.asarray(grid.spacing) - np.asarray(grid.lattice_start)
    rel = centre - grid.origins
    assert np.all((rel[:, :2] >= 1.0) & (rel[:, :2] < 2.0))
    assert np.all(np.abs(rel[:, 2] - 1.0) <= 0.5)


def test_flat_patch_gets_a_one_plane_stencil():
    mesh = BEMMesh(generate("flat", cells=6, size_um=0.3))
    grid = build_grid(mesh)
    assert grid.stencil == (4, 4, 1) and grid.shape[2] == 1
    assert build_grid(mesh, GridOptions(stencil=(4, 4, 3))).stencil == (4, 4, 3)


def test_inverse_map_lists_every_stencil_entry_once(rough_mesh):
    grid = build_grid(rough_mesh)
    pointer, entries = grid.inverse_map()
    assert pointer[-1] == rough_mesh.n_bases * grid.stencil_size
    assert np.array_equal(np.sort(entries), np.arange(pointer[-1]))
    flat = grid.linear_index(grid.stencil_points()).ravel()
    for p in (0, len(pointer) // 2, len(pointer) - 2):
        assert np.all(flat[entries[pointer[p] : pointer[p + 1]]] == p)


def test_moment_matching_reproduces_the_basis_moments(rough_mesh):
    """Σ_p Λ_p (p − o)^α = ∫ψ (r − o)^α dA for every α in the stencil's tensor set."""
    grid = build_grid(rough_mesh)
    proj = project(rough_mesh, grid, "moments")
    r, psi = basis_quadrature(rough_mesh, 6)
    pos = grid.stencil_positions()
    origin = pos[:, :1, :]
    sx, sy, sz = grid.stencil
    worst = 0.0
    for a in range(sx):
        for b in range(sy):
            for c in range(sz):
                mono_q = np.prod((r - origin) ** [a, b, c], axis=-1)
                mono_p = np.prod((pos - origin) ** [a, b, c], axis=-1)
                exact = np.einsum("cbq,bq->cb", psi, mono_q)
                approx = np.einsum("cbs,bs->cb", proj.weights, mono_p)
                scale = np.einsum("cbq,bq->cb", np.abs(psi), np.abs(mono_q)) + 1e-300
                worst = max(worst, np.max(np.abs(approx - exact) / scale))
    assert worst < 1e-10


def test_farfield_matching_reproduces_plane_waves(rough_mesh):
    """Σ_p Λ_p e^{jk d̂·p} vs ∫ψ e^{jk d̂·r} dA at directions not in the matching set."""
    grid = build_grid(rough_mesh)
    k = 2 * np.pi / LAMBDA
    proj = project(rough_mesh, grid, "farfield", k=k, regularization=1e-4)
    dirs = fibonacci_directions(77)  # different from the 3S = 144 matching directions
    r, psi = basis_quadrature(rough_mesh, 6)
    exact = np.einsum("cbq,bql->cbl", psi, np.exp(1j * k * r @ dirs.T))
    approx = np.einsum("cbs,bsl->cbl", proj.weights, np.exp(1j * k * grid.stencil_positions() @ dirs.T))
    err = np.linalg.norm(approx - exact, axis=-1) / np.linalg.norm(exact, axis=-1)
    print("far-field matching: max relative error", err.max())
    assert err.max() < 5e-3


def test_lattice_green_matches_the_formula_and_is_odd():
    k = 2 * np.pi / LAMBDA * (1.5 - 0.01j)
    spacing = (0.07, 0.07, 0.09)
    offsets = np.array([[1, 2, -1], [-3, 0, 2], [0, 0, 0]])
    g, grad = lattice_green(k, spacing, offsets)
    R = offsets[0] * spacing
    r = np.linalg.norm(R)
    assert np.isclose(g[0], np.exp(-1j * k * r) / (4 * np.pi * r), rtol=1e-14)
    assert np.allclose(grad[0], -R * (1 + 1j * k * r) * np.exp(-1j * k * r) / (4 * np.pi * r**3), rtol=1e-13)
    assert g[2] == 0 and np.all(grad[2] == 0)
    g2, grad2 = lattice_green(k, spacing, -offsets)
    assert np.allclose(g2, g) and np.allclose(grad2, -grad)


def test_pruned_fft_convolution_is_the_linear_convolution(rough_mesh, rng):
    """Spectra × pruned FFTs = direct linear convolution with the sampled kernel."""
    grid = build_grid(rough_mesh)
    media = Media(LAMBDA, 1.5)
    spectra = kernel_spectra(grid, media, (0,))
    q = rng.standard_normal(grid.shape) + 1j * rng.standard_normal(grid.shape)
    conv = inverse_pruned(forward_pruned(q, grid.padded) * spectra.green[0], grid.shape)
    ix = np.stack(np.meshgrid(*(np.arange(n) for n in grid.shape), indexing="ij"), axis=-1).reshape(-1, 3)
    for p in (0, 17, len(ix) - 1):
        g, _ = lattice_green(media.wavenumbers[0], grid.spacing, ix[p] - ix)
        assert np.isclose(conv.ravel()[p], np.sum(g * q.ravel()), rtol=1e-10)


@pytest.mark.parametrize("compact, padded", [((7, 3), (14, 6)), ((3, 7), (6, 14)), ((5, 5), (10, 12))])
def test_pruned_plane_transforms_are_numpys_zero_padded_fft(rng, compact, padded):
    """The slab's (y, z) transforms, in either order of the pruning (the longer compact axis first),
    are numpy's 2-D FFT of the zero-padded block, and the inverse keeps its compact block."""
    from wavebrdf.solver.bem3d.aim.convolution import _pruned_plane_fft

    shape = (2, 3)
    q = rng.standard_normal(shape + compact) + 1j * rng.standard_normal(shape + compact)
    S = np.full(shape + padded, np.nan + 0j)  # stale contents must not leak into the padding
    _pruned_plane_fft(S, q.copy(), workers=1)
    assert np.allclose(S, np.fft.fft2(q, s=padded), rtol=0, atol=1e-12)
    F = rng.standard_normal(shape + padded) + 1j * rng.standard_normal(shape + padded)
    out = np.zeros(shape + compact, dtype=complex)
    _pruned_plane_fft(F.copy(), out, workers=1, inverse=True)
    assert np.allclose(out, np.fft.ifft2(F)[..., : compact[0], : compact[1]], rtol=0, atol=1e-14)


def test_interior_leaves_the_grid_only_when_it_has_decayed():
    """Decay criterion, not κ ≠ 0: a weak absorber keeps its interior on the grid; continuity in κ."""
    r = 0.2
    assert grid_media(Media(0.4, 0.46582 - 4.7119j), r) == (0,)  # aluminium: e^{−74·0.2}·22 ≈ 8e-6
    assert grid_media(Media(0.4, 1.5 - 1e-4j), r) == (0, 1)  # weak absorber: not truncated
    assert grid_media(Media(0.4, 1.5), r) == (0, 1)
    kappas = np.linspace(0.0, 6.0, 61)
    decay = [interior_decay(Media(0.4, 1.5 - 1j * k), r) for k in kappas]
    assert np.all(np.diff(np.log(decay[1:])) < 0)  # monotone: one switch point, no jumps back


@pytest.mark.parametrize("projection, precision, batch", [
    ("farfield", "double", 2), ("farfield", "single", 2), ("moments", "double", 2), ("moments", "single", 2),
    ("farfield", "double", 1), ("farfield", "single", 4), ("moments", "double", 3)])
def test_base_operator_kernels_match_numpy(cl_ctx, rough_mesh, rng, projection, precision, batch):
    """B x on the device = its NumPy twin: both projections and precisions, every packed batch
    size of aim.cl (1, 2, 4 right-hand sides per launch) and one it splits (3 = 2 + 1)."""
    media = Media(LAMBDA, 1.5)
    grid = build_grid(rough_mesh)
    spectra = kernel_spectra(grid, media, (0, 1))
    dtype = np.complex128 if precision == "double" else np.complex64
    if projection == "moments":
        groups = [GridGroup.build(project(rough_mesh, grid, "moments"), spectra, media, (0, 1), dtype)]
    else:
        groups = [GridGroup.build(project(rough_mesh, grid, "farfield", k=media.wavenumbers[i].real), spectra,
                                  media, (i,), dtype) for i in (0, 1)]
    op = BaseOperator(cl_ctx, rough_mesh, groups, precision=Precision(precision))
    x = rng.standard_normal((batch, rough_mesh.n_unknowns)) + 1j * rng.standard_normal((batch, rough_mesh.n_unknowns))
    y = op.apply(x)
    ref = op.apply_numpy(x)
    err = np.linalg.norm(y - ref) / np.linalg.norm(ref)
    print(projection, precision, "OpenCL vs NumPy", err)
    assert err < (1e-12 if precision == "double" else 2e-5)


@pytest.mark.parametrize("precision, lanes", [("double", 4), ("single", 8), ("single", 1), ("double", 2)])
def test_fourier_lanes_and_their_remainder(cl_ctx, rng, precision, lanes):
    """aim_fourier with 1, 2, 4, 8 samples per work-item, on a grid whose sample count is not a
    multiple of the lanes (the remainder goes through the one-lane build)."""
    mesh = BEMMesh(generate("gaussian", cells=11, size_um=11 * LAMBDA / 10, seed=5, rms_height_um=0.06,
                            correlation_um=0.2))
    media = Media(LAMBDA, 1.5 - 0.1j)
    grid = build_grid(mesh)
    spectra = kernel_spectra(grid, media, (0, 1))
    dtype = np.complex128 if precision == "double" else np.complex64
    groups = [GridGroup.build(project(mesh, grid, "moments"), spectra, media, (0, 1), dtype)]
    op = BaseOperator(cl_ctx, mesh, groups, precision=Precision(precision))
    op.fourier_lanes = lanes
    assert lanes == 1 or grid.padded_points % lanes
    x = rng.standard_normal((2, mesh.n_unknowns)) + 1j * rng.standard_normal((2, mesh.n_unknowns))
    err = np.linalg.norm(op.apply(x) - op.apply_numpy(x)) / np.linalg.norm(op.apply_numpy(x))
    assert err < (1e-12 if precision == "double" else 2e-5)


def test_device_fft_path_matches_host(cl_ctx, rough_mesh, rng):
    """fft = "vkfft" (zero-padded device arrays, VkFFT) gives the host path's product."""
    pytest.importorskip("pyvkfft.opencl")
    media = Media(LAMBDA, 0.46582 - 4.7119j)
    grid = build_grid(rough_mesh)
    spectra = kernel_spectra(grid, media, (0,))
    groups = [GridGroup.build(project(rough_mesh, grid, "farfield", k=media.wavenumbers[0].real), spectra, media,
                              (0,), np.complex128)]
    x = rng.standard_normal((2, rough_mesh.n_unknowns)) + 1j * rng.standard_normal((2, rough_mesh.n_unknowns))
    host = BaseOperator(cl_ctx, rough_mesh, groups, fft="host").apply(x)
    device = BaseOperator(cl_ctx, rough_mesh, groups, fft="vkfft").apply(x)
    assert np.linalg.norm(device - host) / np.linalg.norm(host) < 1e-12


def test_host_fft_slabs_and_kept_arrays_give_the_numpy_product(cl_ctx, rough_mesh, rng, monkeypatch):
    """The host path in many slabs of x frequencies (the last one shorter), its arrays kept between
    products of one batch size and rebuilt when it changes (2, 2, 1, 1, 2 right-hand sides), equals
    the NumPy twin every time, even with the kept arrays filled with NaN in between (nothing is
    read that the product did not write, padding included); release_work frees them."""
    import wavebrdf.solver.bem3d.aim.convolution as convolution

    media = Media(LAMBDA, 1.5)
    grid = build_grid(rough_mesh)
    spectra = kernel_spectra(grid, media, (0, 1))
    groups = [GridGroup.build(project(rough_mesh, grid, "moments"), spectra, media, (0, 1), np.complex128)]
    op = BaseOperator(cl_ctx, rough_mesh, groups, precision=Precision.DOUBLE, fft="host")
    plane_bytes = 8 * 2 * grid.padded[1] * grid.padded[2] * 16
    planes = next(p for p in (4, 5, 7) if grid.padded[0] % p)  # a shorter last slab
    monkeypatch.setattr(convolution, "SLAB_BYTES", planes * plane_bytes)
    assert op.slab_planes(2) == planes
    for batch in (2, 2, 1, 1, 2):
        if op._host:
            op._host["A"][...] = np.nan
            op._host["slab"][...] = np.nan
        shape = (batch, rough_mesh.n_unknowns)
        x = rng.standard_normal(shape) + 1j * rng.standard_normal(shape)
        ref = op.apply_numpy(x)
        assert np.linalg.norm(op.apply(x) - ref) / np.linalg.norm(ref) < 1e-12
        assert op._host["P"] == batch
    op.release_work()
    assert op._host == {}


@pytest.fixture(scope="module")
def near_setup(cl_ctx, rough_mesh):
    media = Media(LAMBDA, 1.5)
    grid = build_grid(rough_mesh)
    groups = [(project(rough_mesh, grid, "farfield", k=media.wavenumbers[i].real), (i,)) for i in (0, 1)]
    pattern = NearPattern.build(rough_mesh.cells, 3.5)
    near = assemble_near(cl_ctx, rough_mesh, media, pattern, groups, storage="double", exact_cells=2.3)
    return media, groups, pattern, near


def test_near_correction_is_exact_minus_grid_entries(cl_ctx, rough_mesh, near_setup):
    """C of the assembly (B by BLAS potentials and the aim_near_correct kernel) = A (part-1
    entries from fresh element tables) − B (explicit S×S double sum)."""
    media, groups, pattern, near = near_setup
    coef = media.pmchwt_coefficients()
    rows = np.arange(pattern.rows)
    for block in BLOCKS:
        row_id, col_id, j, pos = pattern.pairs(block, rows)
        ee, mm, em = basis_pair_entries(cl_ctx, rough_mesh, media, row_id, col_id)
        expected = np.stack([ee, em, mm])
        for projection, (i,) in groups:
            c = [coef["ee_vec"][i], coef["ee_div"][i], coef["mm_vec"][i], coef["mm_div"][i]]
            expected = expected - near_base_numpy(projection, media.wavenumbers[i], c, rough_mesh.n_horizontal,
                                                  row_id, col_id)
        got = near.entries(block, j, pos).T
        err = np.linalg.norm(got - expected) / np.linalg.norm(expected)
        print(block, "C: OpenCL vs A − B(NumPy)", err)
        assert err < 1e-11
        # exact entries kept for the preconditioner
        keep = np.isin(j, near.exact_offsets[block])
        lookup = np.full(len(pattern.offsets(block)), -1)
        lookup[near.exact_offsets[block]] = np.arange(len(near.exact_offsets[block]))
        kept = near.exact[block][lookup[j[keep]], pos[keep]].T
        # from one order of each element pair (the other's table transposed): the same to rounding
        direct = np.stack([ee, em, mm])[:, keep]
        print(block, "kept exact entries vs direct", np.abs(kept - direct).max() / np.abs(direct).max())
        assert np.abs(kept - direct).max() <= 1e-13 * np.abs(direct).max()


def test_near_correction_with_real_single_precision_weights(cl_ctx, rough_mesh):
    """Moment-matched (real) weights stored in single precision, one projection for both media of
    aluminium: C = A − B with B of the explicit S×S double sum."""
    media = Media(LAMBDA, 0.49 - 4.86j)
    projection = project(rough_mesh, build_grid(rough_mesh), "moments", dtype=np.float32)
    pattern = NearPattern.build(rough_mesh.cells, 3.0)
    near = assemble_near(cl_ctx, rough_mesh, media, pattern, [(projection, (0, 1))], storage="double")
    coef = media.pmchwt_coefficients()
    rows = np.arange(pattern.rows)
    for block in BLOCKS:
        row_id, col_id, j, pos = pattern.pairs(block, rows)
        expected = np.stack(basis_pair_entries(cl_ctx, rough_mesh, media, row_id, col_id))[[0, 2, 1]]
        for i in (0, 1):
            c = [coef["ee_vec"][i], coef["ee_div"][i], coef["mm_vec"][i], coef["mm_div"][i]]
            expected = expected - near_base_numpy(projection, media.wavenumbers[i], c, rough_mesh.n_horizontal,
                                                  row_id, col_id)
        got = near.entries(block, j, pos).T
        assert np.linalg.norm(got - expected) / np.linalg.norm(expected) < 1e-11


def test_near_assembly_in_small_chunks_is_the_numpy_twin(cl_ctx, rough_mesh, near_setup, monkeypatch):
    """Many strips, potential chunks and element-kernel launches (the chunked paths of large
    patches: partial staging, reused scratch tables, outputs written at an offset) give the
    NumPy twin's C, and the C of one strip (checked against fresh element tables above): the
    tables kept across strips are those of their pairs."""
    import wavebrdf.solver.bem3d.aim.near_assembly as near_assembly
    import wavebrdf.solver.bem3d.elements as elements

    media, groups, pattern, whole = near_setup
    monkeypatch.setattr(near_assembly, "PAIRS_PER_CHUNK", 300)
    monkeypatch.setattr(near_assembly, "POTENTIAL_BUDGET", 1)  # one row per potential chunk
    monkeypatch.setattr(elements, "OUTPUT_BUDGET", 2 * 33 * 16 * 50)
    assert len(list(near_assembly._strips(pattern))) > 3
    chunked = assemble_near(cl_ctx, rough_mesh, media, pattern, groups, storage="double").to_sparse()
    twin = assemble_near(None, rough_mesh, media, pattern, groups, storage="double").to_sparse()
    err = abs(chunked - twin).max() / abs(twin).max()
    print("chunked OpenCL vs NumPy twin", err)
    assert err < 1e-11
    one_strip = whole.to_sparse()
    assert abs(chunked - one_strip).max() < 1e-12 * abs(one_strip).max()


@pytest.mark.parametrize("batch, precision, lanes, split", [
    (1, "double", None, False), (2, "double", None, False), (2, "single", None, False),
    (2, "double", 1, False), (2, "double", None, True)])
def test_near_spmv_kernels_match_scipy(cl_ctx, rough_mesh, near_setup, rng, batch, precision, lanes, split):
    """Lattice SpMV = scipy product of the same entries: SIMD lanes (CPU) and one site per
    work-item (the GPU path), single precision, values split over several buffers."""
    import dataclasses

    import pyopencl as cl

    _, _, _, near = near_setup
    ctx = cl_ctx
    if split:  # a device whose largest allocation holds ~3 offsets forces several value buffers
        per_offset = near.values["HV"][0].nbytes
        ctx = dataclasses.replace(cl_ctx, info=dataclasses.replace(cl_ctx.info, max_alloc_gib=3.5 * per_offset / 2**30),
                                  _programs={}, _kernels={})
    near = dataclasses.replace(near, _device=None, _lattice_vectors={})
    n = rough_mesh.n_unknowns
    dtype = np.complex128 if precision == "double" else np.complex64
    x = (rng.standard_normal((batch, n)) + 1j * rng.standard_normal((batch, n))).astype(dtype)
    y = np.zeros_like(x)
    mf = cl.mem_flags
    xb = cl.Buffer(ctx.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=x)
    yb = cl.Buffer(ctx.context, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=y)
    near.apply(ctx, xb, yb, batch, Precision(precision), lanes=lanes)
    if split:
        assert all(len(parts) > 1 for parts in near._device.values())
    cl.enqueue_copy(ctx.queue, y, yb)
    ref = near.apply_numpy(x)
    assert np.linalg.norm(y - ref) / np.linalg.norm(ref) < (1e-13 if precision == "double" else 1e-6)
    # the stored pattern is symmetric: C = Cᵀ
    C = near.to_sparse()
    assert abs(C - C.T).max() == 0


def test_near_lattice_shifts_are_the_rooftop_offsets():
    """Every rooftop has its own lattice site, site(column) − site(row) is the offset's shift, and
    every shifted read of the SpMV (sites [0, N) rounded up to whole vectors, moved by ±(a, b))
    stays on the row's pad sites and inside the guard rows."""
    pattern = NearPattern.build(7, 2.5)
    N, P, G, rows = pattern.cells, pattern.pitch, pattern.guard_rows, np.arange(pattern.rows)
    lattice_rows = pattern.lattice_length // P
    for o in (0, 1):
        x, row = np.divmod(pattern.site(o, rows), P)[::-1]
        assert len(np.unique(pattern.site(o, rows))) == len(rows)
        assert x.max() < N and row.min() == G and row.max() < G + N
    for block in BLOCKS:
        row_id, col_id, j, pos = pattern.pairs(block, rows)
        orow, ocol, _ = BLOCKS[block]
        row_site = pattern.site(orow, row_id - near_first(orow, N))
        col_site = pattern.site(ocol, col_id - near_first(ocol, N))
        offsets = pattern.offsets(block).astype(np.int64)
        assert np.array_equal(col_site - row_site, (offsets[:, 0] + P * offsets[:, 1])[j])  # the kernel's a + P b
        a, b = np.abs(offsets).max(axis=0)
        assert -(-N // 8) * 8 + a <= P  # reads x ± a of the widest vectors stay in [−pad, P)
        assert G - b >= 1 and G + N - 1 + b < lattice_rows
    assert lattice_rows % TILE_ROWS == 0 and lattice_rows >= N + 2 * G


def test_near_store_reads_back_for_rows_in_any_order(rng):
    """Entries stored for a shuffled subset of rows (runs of consecutive sites, single sites, both
    orientations) read back as written; rows not stored stay zero."""
    pattern = NearPattern.build(13, 3.2)
    near = NearMatrix(pattern, NearMatrix.zeros(pattern, "double"))
    for block in BLOCKS:
        rows = rng.permutation(pattern.rows)[: pattern.rows // 2]
        rows = np.concatenate([np.sort(rows[:20]), rows[20:]])  # a sorted stretch and scattered rows
        n_off = len(pattern.offsets(block))
        staged = rng.standard_normal((n_off, len(rows), 3)) + 1j * rng.standard_normal((n_off, len(rows), 3))
        near.store(block, rows, staged)
        j = np.repeat(np.arange(n_off), len(rows))
        got = near.entries(block, j, np.tile(rows, n_off)).reshape(n_off, len(rows), 3)
        assert np.array_equal(got, staged)
        others = np.setdiff1d(np.arange(pattern.rows), rows)
        assert not np.any(near.entries(block, np.zeros(len(others), int), others))


@pytest.mark.parametrize("cells, batch, precision, lanes", [
    (11, 1, "double", None), (11, 4, "single", None), (13, 2, "double", 1), (13, 2, "double", 2)])
def test_near_spmv_random_entries_match_scipy(cl_ctx, rng, cells, batch, precision, lanes):
    """Lattice SpMV = scipy product for random entries on every valid pair of a pattern whose
    rows are not whole vectors and span several tiles (pads, guards and tile edges)."""
    import pyopencl as cl

    pattern = NearPattern.build(cells, 4.2)
    assert pattern.tiles > 2 and cells % 8
    near = NearMatrix(pattern, NearMatrix.zeros(pattern, "double"))
    rows = np.arange(pattern.rows)
    for block in BLOCKS:
        _, _, j, pos = pattern.pairs(block, rows)
        staged = np.zeros((len(pattern.offsets(block)), len(rows), 3), complex)
        staged[j, pos] = rng.standard_normal((len(j), 3)) + 1j * rng.standard_normal((len(j), 3))
        near.store(block, rows, staged)
    dtype = np.complex128 if precision == "double" else np.complex64
    n = 2 * near.n_bases
    x = (rng.standard_normal((batch, n)) + 1j * rng.standard_normal((batch, n))).astype(dtype)
    y = np.zeros_like(x)
    mf = cl.mem_flags
    xb = cl.Buffer(cl_ctx.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=x)
    yb = cl.Buffer(cl_ctx.context, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=y)
    for _ in range(2):  # the second product checks that the lattice output was zeroed
        y[:] = 0
        cl.enqueue_copy(cl_ctx.queue, yb, y)
        near.apply(cl_ctx, xb, yb, batch, Precision(precision), lanes=lanes)
        cl.enqueue_copy(cl_ctx.queue, y, yb)
        ref = near.apply_numpy(x)
        assert np.linalg.norm(y - ref) / np.linalg.norm(ref) < (1e-13 if precision == "double" else 1e-6)


def test_near_pattern_counts_and_symmetry():
    pattern = NearPattern.build(10, 2.5)
    # same-orientation upper half + mirror + diagonal = all integer offsets within the radius
    full = {(a, b) for a in range(-3, 4) for b in range(-3, 4) if a * a + b * b <= 6.25}
    upper = {tuple(o) for o in pattern.same}
    assert upper | {(-a, -b) for a, b in upper} == full and len(upper) == (len(full) + 1) // 2
    assert all((a - 0.5) ** 2 + (b + 0.5) ** 2 <= 6.25 for a, b in pattern.cross)
    with pytest.raises(ValueError, match="near_cells"):
        NearPattern.build(10, 0.5)


def test_options_errors_name_the_parameter():
    from wavebrdf.solver.bem3d.aim.options import AIMOptions

    with pytest.raises(ValueError, match="aim.projection"):
        AIMOptions(projection="multipole")
    with pytest.raises(ValueError, match="aim.solver"):
        AIMOptions(solver="cg")
    with pytest.raises(ValueError, match=r"\[model.aim\] near_radius: unknown key"):
        AIMOptions.from_mapping({"near_radius": 3})
    with pytest.raises(ValueError, match="csym"):
        AIMOptions(solver="csym")  # the near preconditioner needs gmres/bicgstab
    with pytest.raises(ValueError, match="csym.*'local'"):
        AIMOptions(solver="csym", preconditioner="local")
    with pytest.raises(ValueError, match=r"\[model.aim\] local_tile_cells"):
        AIMOptions.from_mapping({"local_tile_cells": 0})
    with pytest.raises(ValueError, match="stencil"):
        GridOptions(stencil=(0, 4, 3))
    for bad in (-1, 2.5, True):
        with pytest.raises(ValueError, match="aim.preconditioner_tile_cells"):
            AIMOptions(preconditioner_tile_cells=bad)
    with pytest.raises(ValueError, match="aim.deflate .*restart = 30.*got 30"):
        AIMOptions(restart=30, deflate=30)
    with pytest.raises(ValueError, match="aim.deflate .*'bicgstab'"):
        AIMOptions(solver="bicgstab", deflate=4)
    with pytest.raises(ValueError, match=r"\[model.aim\] deflate"):
        AIMOptions.from_mapping({"deflate": -2})


def test_flat_surface_has_no_vertical_projection():
    mesh = BEMMesh(HeightField(np.zeros((9, 9)), 0.4))
    proj = project(mesh, build_grid(mesh), "farfield", k=2 * np.pi / LAMBDA)
    assert np.abs(proj.weights[1]).max() == 0.0


def test_repeating_tables_are_the_fresh_tables_of_each_pair(cl_ctx, rng):
    """A tilted plane with dyadic heights (bit-identical element shapes): the tables cached per
    distinct pair geometry, over two calls sharing pairs, equal fresh tables per pair (to
    rounding: the same geometry at other positions); a cache bounded between one call's tables
    and two calls' keeps only the tables each call uses, and gives the same tables."""
    from wavebrdf.solver.bem3d.aim.near_tables import RepeatingTables
    from wavebrdf.solver.bem3d.elements import TABLE, ElementIntegrals

    i, j = np.meshgrid(np.arange(13), np.arange(13), indexing="ij")
    mesh = BEMMesh(HeightField((3 * i - j) / 256.0, 0.3), z_reference=0.0)
    assert RepeatingTables.worthwhile(mesh)
    ks = (2 * np.pi / 0.5, 2 * np.pi / 0.5 * (0.5 - 3.0j))
    repeating = RepeatingTables(ElementIntegrals(mesh, ctx=cl_ctx))
    columns = RepeatingTables(ElementIntegrals(mesh, ctx=cl_ctx))
    columns.n_shapes = 2**31  # the key no longer fits one int64: the column-wise comparison
    bounded = RepeatingTables(ElementIntegrals(mesh, ctx=cl_ctx))
    fresh = ElementIntegrals(mesh, ctx=cl_ctx)
    calls = []
    for _ in range(2):
        test = rng.integers(0, mesh.n_elements, 300)
        calls.append((test, np.clip(test + rng.integers(-30, 31, 300), 0, mesh.n_elements - 1)))
    calls.append(calls[0])  # the first call's pairs again, after the bounded cache has dropped some
    distinct = [set(bounded._distinct(t, s)[0]) for t, s in calls[:2]]
    union = len(distinct[0] | distinct[1])
    assert max(map(len, distinct)) < union
    row_bytes = np.dtype(complex).itemsize * 2 * TABLE
    bounded.max_bytes = row_bytes * (max(map(len, distinct)) + union) // 2  # holds one call's tables, not two
    for call, (test, source) in enumerate(calls):
        reference = fresh.tables(test, source, ks)
        for cache in (repeating, columns, bounded):
            store, index = cache.indexed_tables(test, source, ks)
            assert np.max(np.abs(store[index] - reference)) < 1e-13 * np.max(np.abs(reference))
            assert len(store) < 300 * (call + 1)  # computed once per distinct geometry
            assert sorted(cache._keys.values()) == list(range(len(store)))  # each cached geometry its own row
        if call == 1:  # the unbounded caches hold both calls' geometries, the bounded one the second's
            assert len(bounded._store) == len(distinct[1]) < len(repeating._store) == union


def test_a_swapped_element_pair_has_the_transposed_table(cl_ctx, rough_mesh):
    """Galerkin symmetry, computed both ways: the table of (B, A) is that of (A, B) with the test
    and source slots swapped (L_vec, K) and L_div unchanged, for regular and touching pairs of a
    rough mesh, glass and aluminium, to rounding (the singular rules map the two elements by other
    transforms; 5e-13 measured)."""
    from wavebrdf.solver.bem3d.aim.near_tables import TRANSPOSE
    from wavebrdf.solver.bem3d.elements import ElementIntegrals
    from wavebrdf.solver.bem3d.quadrature import CASE_REGULAR

    ne = rough_mesh.n_elements
    test, source = (a.ravel() for a in np.meshgrid(np.arange(ne), np.arange(ne), indexing="ij"))
    st = rough_mesh.element_st
    near = (np.abs(st[test] - st[source]).max(axis=1) <= 3) & (test != source)
    test, source = test[near], source[near]
    for index in (1.5, 0.49 - 4.86j):
        integrals = ElementIntegrals(rough_mesh, ctx=cl_ctx)
        ks = Media(LAMBDA, index).wavenumbers
        forward = integrals.tables(test, source, ks)
        backward = integrals.tables(source, test, ks)[:, :, TRANSPOSE]
        case, _, _ = integrals.classify(test, source)
        assert np.count_nonzero(case != CASE_REGULAR) > 100
        scale = np.abs(forward).max(axis=-1)
        assert np.max(np.abs(forward - backward).max(axis=-1) / scale) < 5e-12  # 5e-13 measured on PoCL
        assert np.max(np.abs(forward[..., 16] - backward[..., 16]) / scale) < 5e-12


def test_transposed_tables_over_strips_are_the_fresh_tables_of_each_pair(cl_ctx, rng):
    """Pairs asked for in strips of increasing test lines, each pair's other order in a later
    strip: every table equals the fresh table of that pair, each unordered pair is computed once,
    and the kept blocks go round their ring (and move when the store grows)."""
    from wavebrdf.solver.bem3d.aim.near_tables import TRANSPOSE, TransposedTables
    from wavebrdf.solver.bem3d.elements import ElementIntegrals

    mesh = BEMMesh(generate("gaussian", cells=14, size_um=14 * LAMBDA / 10, seed=3, rms_height_um=0.06,
                            correlation_um=0.2))
    ks = Media(LAMBDA, 0.49 - 4.86j).wavenumbers
    st = mesh.element_st
    transposed = TransposedTables(ElementIntegrals(mesh, ctx=cl_ctx))
    fresh = ElementIntegrals(mesh, ctx=cl_ctx)
    unordered = set()
    for y0 in range(mesh.cells):  # strips of one line of test elements, pairs within 2 cells
        test, source = (a.ravel() for a in np.meshgrid(np.flatnonzero(st[:, 1] == y0), np.arange(mesh.n_elements),
                                                       indexing="ij"))
        keep = np.abs(st[test] - st[source]).max(axis=1) <= 2
        order = rng.permutation(np.count_nonzero(keep))
        test, source = test[keep][order], source[keep][order]
        store, index = transposed.indexed_tables(test, source, ks)
        got = store[np.where(index < 0, -1 - index, index)]
        got[index < 0] = got[index < 0][:, :, TRANSPOSE]
        reference = fresh.tables(test, source, ks)
        assert np.max(np.abs(got - reference)) < 5e-12 * np.max(np.abs(reference))
        unordered |= set(zip(np.minimum(test, source).tolist(), np.maximum(test, source).tolist()))
    assert transposed.counts["computed"] == len(unordered)
    assert transposed.counts["requested"] > 1.7 * len(unordered)
    assert transposed.counts["wraps"] >= 2 and transposed.counts["growths"] >= 2, transposed.counts


def test_transposed_tables_stay_right_when_the_store_grows_under_kept_blocks(cl_ctx, rough_mesh):
    """Calls of growing size: the store grows while blocks kept by earlier calls are live (they
    move to the new store) and the same call reads pairs from them; every table is still its
    pair's own."""
    from wavebrdf.solver.bem3d.aim.near_tables import TRANSPOSE, TransposedTables
    from wavebrdf.solver.bem3d.elements import ElementIntegrals

    ks = Media(LAMBDA, 0.49 - 4.86j).wavenumbers
    st = rough_mesh.element_st
    transposed = TransposedTables(ElementIntegrals(rough_mesh, ctx=cl_ctx))
    fresh = ElementIntegrals(rough_mesh, ctx=cl_ctx)
    moved = 0
    for y, reach in ((0, 1), (1, 3), (2, 6)):  # each call asks for more pairs than the store holds
        test, source = (a.ravel() for a in np.meshgrid(np.flatnonzero(st[:, 1] == y), np.arange(rough_mesh.n_elements),
                                                       indexing="ij"))
        keep = np.abs(st[test] - st[source]).max(axis=1) <= reach
        test, source = test[keep], source[keep]
        before = [(block, block.start) for block in transposed._kept]
        keys = np.minimum(test, source) * rough_mesh.n_elements + np.maximum(test, source)
        store, index = transposed.indexed_tables(test, source, ks)
        # blocks that moved in this call and served some of its pairs
        moved += sum(any(block is kept for kept in transposed._kept) and block.start != start
                     and bool(np.isin(keys, block.keys).any()) for block, start in before)
        got = store[np.where(index < 0, -1 - index, index)]
        got[index < 0] = got[index < 0][:, :, TRANSPOSE]
        reference = fresh.tables(test, source, ks)
        assert np.max(np.abs(got - reference)) < 5e-12 * np.max(np.abs(reference))
    assert moved > 0  # a live block moved in a call that read tables from it


def test_kept_tables_beyond_the_device_buffer_are_refused_by_name(cl_ctx, rough_mesh):
    """A store whose kept tables alone exceed the device's largest buffer: a MemoryError that says
    so, not a split that cannot shrink them."""
    from types import SimpleNamespace

    from wavebrdf.solver.bem3d.aim.near_tables import TransposedTables
    from wavebrdf.solver.bem3d.elements import ElementIntegrals

    media = Media(LAMBDA, 0.49 - 4.86j)
    transposed = TransposedTables(ElementIntegrals(rough_mesh, ctx=cl_ctx))
    st = rough_mesh.element_st
    line0, line1 = np.flatnonzero(st[:, 1] == 0), np.flatnonzero(st[:, 1] == 1)
    transposed.indexed_tables(line0, line1, media.wavenumbers)  # pairs reaching line 1: kept for later calls
    assert transposed.store_rows(0)[1] > 0
    tiny = SimpleNamespace(info=SimpleNamespace(max_alloc_gib=1e-9))
    with pytest.raises(MemoryError, match="kept for later strips"):
        basis_pair_entries(tiny, rough_mesh, media, np.arange(4), np.arange(4) + 1, integrals=transposed)


def test_plane_wave_phases_of_repeating_and_scattered_positions(rng):
    """e^{jk·r} computed once per distinct position (lattice points) or per entry (scattered
    points) equals the direct exponential."""
    from wavebrdf.solver.bem3d.aim.projection import plane_wave_phases

    k = rng.standard_normal((40, 3)) * 12.0
    lattice = np.stack([rng.integers(0, 9, (500, 8)) * 0.0125, rng.integers(0, 7, (500, 8)) * 0.02,
                        np.full((500, 8), -0.03)], axis=-1)
    scattered = rng.uniform(-1, 1, (300, 8, 3))
    for r in (lattice, scattered):
        got = plane_wave_phases(r, k)
        assert got.shape == (r.shape[0], 8, 40)
        assert np.max(np.abs(got - np.exp(1j * np.einsum("bqc,lc->bql", r, k)))) < 1e-13


def test_device_plane_wave_moments_are_the_direct_sum(cl_ctx, rng):
    """The OpenCL moments Σ_q ψ_q e^{jk·r_q} equal the explicit sum of exponentials (double)."""
    from wavebrdf.solver.bem3d.aim.projection import plane_wave_moments_opencl

    k = rng.standard_normal((37, 3)) * 15.0
    r = rng.uniform(-0.1, 0.2, (301, 18, 3))
    psi = rng.standard_normal((3, 301, 18))
    expected = np.einsum("cbq,bql->cbl", psi, np.exp(1j * np.einsum("bqc,lc->bql", r, k)))
    got = plane_wave_moments_opencl(cl_ctx, r, psi, k)
    assert np.max(np.abs(got - expected)) < 1e-12 * np.max(np.abs(expected))


def test_far_field_projection_is_the_same_on_the_device(cl_ctx, rough_mesh):
    """Far-field-matched weights of a rough mesh: device and NumPy moments agree to rounding."""
    grid = build_grid(rough_mesh)
    k = 2 * np.pi / LAMBDA
    host = project(rough_mesh, grid, "farfield", k=k).weights
    device = project(rough_mesh, grid, "farfield", k=k, ctx=cl_ctx).weights
    assert np.max(np.abs(device - host)) < 1e-11 * np.max(np.abs(host))
