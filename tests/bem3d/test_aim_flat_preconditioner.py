"""The flat interface's inverse as a preconditioner (solver/bem3d/aim/flat_circulant.py).

* its kernel is the damped flat operator: every entry of the dense PMCHWT matrix of a flat patch
  (assembled block by block, assembly.assemble_dense, with the same lossy exterior) at its
  lattice offset, cut at its radius, on a torus that does not wrap the patch onto itself;
* the preconditioner is the exact inverse of that kernel's block circulant on the torus (checked
  against a dense inverse of the circulant built entry by entry);
* on a rough aluminium patch it cuts GMRES's products at least 3×, and the flat patch's inner
  solve (flat_patch.py) 5× more, against the dense matrix;
* ``[model.aim] preconditioner = "flat"`` (and ``"flat-patch"``, flat_patch.py) end to end gives
  the BRDF of the near LU's solve.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from wavebrdf.solver.bem3d import BEMSolver, BEMWarning, estimate_aim
from wavebrdf.solver.bem3d.aim.flat_circulant import (DampedExterior, FlatCirculantPreconditioner, flat_kernel,
                                                      kernel_radius_cells, rooftops)
from wavebrdf.solver.bem3d.aim.flat_patch import FlatPatchPreconditioner
from wavebrdf.solver.bem3d.assembly import assemble_dense
from wavebrdf.solver.bem3d.excitation import beam_excitation
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import BEMMesh
from wavebrdf.solver.bem3d.quadrature import QuadratureOptions
from wavebrdf.solver.farfield import HemisphereGrid
from wavebrdf.solver.krylov import solve
from wavebrdf.solver.metrics import relative_l2
from wavebrdf.solver.surface import generate

AL_400 = 0.46582 - 4.7119j


def _fields(cells: int):
    """Per unknown of an N-cell mesh ([J_h | J_v | M̃_h | M̃_v]): its field (0–3) and lattice (x, y)."""
    field, x, y = [], [], []
    for magnetic in (0, 1):
        for o in (0, 1):
            xo, yo, _ = rooftops(cells, o)
            field.append(np.full(len(xo), 2 * magnetic + o))
            x.append(xo)
            y.append(yo)
    return np.concatenate(field), np.concatenate(x), np.concatenate(y)


def test_the_kernel_is_the_damped_flat_operator_at_every_offset(cl_ctx):
    """Every entry of the dense matrix of a flat 8-cell aluminium patch with a lossy exterior
    equals the kernel at the pair's lattice offset (translation invariance and the placement of
    the four fields)."""
    cells, d = 8, 0.03
    damped = DampedExterior(0.4, AL_400, damping=0.3)
    dense, _ = assemble_dense(cl_ctx, BEMMesh(generate("flat", cells=cells, size_um=cells * d)), damped)
    torus = (2 * cells, 2 * cells)
    K = flat_kernel(cl_ctx, damped, d, cells - 1, torus)
    field, x, y = _fields(cells)
    from_kernel = K[field[:, None], field[None, :], (x[:, None] - x[None, :]) % torus[0],
                    (y[:, None] - y[None, :]) % torus[1]]
    assert np.abs(from_kernel - dense).max() < 1e-6 * np.abs(dense).max()
    # the loss is what the exterior sees: the undamped patch differs
    plain, _ = assemble_dense(cl_ctx, BEMMesh(generate("flat", cells=cells, size_um=cells * d)), Media(0.4, AL_400))
    assert np.abs(plain - dense).max() > 1e-3 * np.abs(dense).max()


def test_the_kernel_is_cut_at_its_radius_and_the_torus_holds_the_patch_without_wrapping(cl_ctx):
    """With a radius R < N − 1: the preconditioner's torus is at least N + R per side; the kernel,
    looked up at the pair offsets of a 10-cell patch on that torus, is the damped flat patch's
    dense matrix wherever |Δx|, |Δy| ≤ R and zero beyond (no offset wraps onto a kept one)."""
    cells, d, R = 10, 0.03, 3
    media = Media(0.4, AL_400)
    mesh = BEMMesh(generate("flat", cells=cells, size_um=cells * d))
    pc = FlatCirculantPreconditioner(cl_ctx, mesh, media, damping=0.3, radius_cells=R)
    assert pc.radius_cells == R and min(pc.torus) >= cells + R
    damped = DampedExterior(0.4, AL_400, damping=0.3)
    dense, _ = assemble_dense(cl_ctx, mesh, damped)
    K = flat_kernel(cl_ctx, damped, d, R, pc.torus)
    field, x, y = _fields(cells)
    dx, dy = x[:, None] - x[None, :], y[:, None] - y[None, :]
    looked_up = K[field[:, None], field[None, :], dx % pc.torus[0], dy % pc.torus[1]]
    inside = (np.abs(dx) <= R) & (np.abs(dy) <= R)
    assert np.abs(looked_up[inside] - dense[inside]).max() < 1e-6 * np.abs(dense).max()
    assert np.all(looked_up[~inside] == 0) and np.any(dense[~inside] != 0)


def test_it_applies_the_inverse_of_the_kernels_block_circulant(cl_ctx):
    """M x is the patch's part of C⁻¹ (x placed in the torus), C the block circulant of the kernel
    built entry by entry over the whole torus and inverted densely."""
    cells, d = 6, 0.03
    media = Media(0.4, AL_400)
    mesh = BEMMesh(generate("gaussian", cells=cells, size_um=cells * d, rms_height_um=0.01, correlation_um=0.05))
    pc = FlatCirculantPreconditioner(cl_ctx, mesh, media, damping=0.3, radius_cells=3)
    Mx, My = pc.torus
    K = flat_kernel(cl_ctx, DampedExterior(0.4, AL_400, damping=0.3), d, 3, pc.torus)
    sx, sy = np.meshgrid(np.arange(Mx), np.arange(My), indexing="ij")
    sx, sy = sx.ravel(), sy.ravel()
    C = np.zeros((4, Mx * My, 4, Mx * My), dtype=complex)
    for i in range(4):
        for j in range(4):
            C[i, :, j, :] = K[i, j][(sx[:, None] - sx[None, :]) % Mx, (sy[:, None] - sy[None, :]) % My]
    C = C.reshape(4 * Mx * My, 4 * Mx * My)
    field, x, y = _fields(cells)
    site = field * Mx * My + x * My + y
    rng = np.random.default_rng(2)
    X = rng.standard_normal((2, mesh.n_unknowns)) + 1j * rng.standard_normal((2, mesh.n_unknowns))
    placed = np.zeros((2, 4 * Mx * My), dtype=complex)
    placed[:, site] = X
    expected = np.linalg.solve(C, placed.T).T[:, site]
    got = pc(X)
    assert got.dtype == X.dtype and got.shape == X.shape
    assert np.linalg.norm(got - expected) / np.linalg.norm(expected) < 1e-5  # complex64 transforms
    assert np.allclose(pc(X[0]), got[0])


def test_they_cut_gmres_products_on_rough_aluminium(cl_ctx):
    """A rough aluminium patch (24 cells at d = λ/10, rms slope ≈ 0.15) against its dense matrix:
    GMRES(30) takes at least 3× fewer products with the flat preconditioner than without, and
    FGMRES(30) with 16 inner steps on the flat patch (flat_patch.py) at least 5× fewer again; both
    reach the direct solution."""
    lam, cells, d = 0.4, 24, 0.04
    media = Media(lam, AL_400)
    mesh = BEMMesh(generate("gaussian", cells=cells, size_um=cells * d, seed=5, rms_height_um=0.03,
                            correlation_um=0.25))
    Z, _ = assemble_dense(cl_ctx, mesh, media)
    b = beam_excitation(mesh, media, 0.0, 0.0, waist_um=cells * d / 5, beam="exact", focus_um=(0.0, 0.0),
                        rhs_order=QuadratureOptions().rhs_order).rhs

    def matvec(X):
        return (Z @ np.atleast_2d(X).T).T

    pc = FlatCirculantPreconditioner(cl_ctx, mesh, media)
    assert pc.radius_cells == kernel_radius_cells(media, d, 0.3, cells)
    assert len(pc.inverse.pairs) == 8  # the inverse's J–M̃ blocks are zero, and not kept
    plain = solve(matvec, b, restart=30, max_iterations=2000)
    flat = solve(matvec, b, restart=30, max_iterations=2000, preconditioner=pc)
    inner_pc = FlatPatchPreconditioner(cl_ctx, mesh, media, steps=16)
    inner = solve(matvec, b, restart=30, max_iterations=2000, preconditioner=inner_pc)
    print("products: none", plain.iterations, "damped circulant", flat.iterations, "inner flat-patch solve",
          inner.iterations, "(inner T products", inner_pc.inner_products, ")")
    assert max(flat.iterations) * 3 <= min(plain.iterations)
    assert max(inner.iterations) * 5 <= min(flat.iterations)
    # 16 T products per outer Arnoldi step (the true-residual checks take a product but no inner solve)
    assert inner_pc.inner_products % 16 == 0 and 0 < inner_pc.inner_products <= 16 * int(inner.iterations.sum())
    x = np.linalg.solve(Z, b.T).T
    for result in (flat, inner):
        assert np.linalg.norm(result.x - x) / np.linalg.norm(x) < 1e-3


@pytest.mark.parametrize("name, kind, per_unknown", [
    pytest.param("flat", FlatCirculantPreconditioner, 600, marks=pytest.mark.slow),  # CI: the patch's, which contains it
    ("flat-patch", FlatPatchPreconditioner, 1000)])
def test_the_flat_options_end_to_end_give_the_near_lu_result(cl_ctx, name, kind, per_unknown):
    """``preconditioner = "flat"`` and ``"flat-patch"`` through BEMSolver: the BRDF of the
    LU-preconditioned solve within the Krylov tolerance's reach, the preconditioner's memory a few
    hundred bytes per unknown, as the planner's estimate has it; the inner solve's T products are
    reported."""
    surface = generate("gaussian", cells=32, size_um=1.6, seed=3, rms_height_um=0.03, correlation_um=0.3)
    grid = HemisphereGrid(32)
    ffs = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BEMWarning)
        for variant in ("near", name):
            solver = BEMSolver(cl_ctx, surface, 0.5, 1.5, method="aim", aim={"preconditioner": variant, "restart": 30})
            ffs[variant] = solver.farfield(0.2, 0.0, grid, waist_um=surface.size_um / 5)
        pc = solver.operator.preconditioner
        assert isinstance(pc, kind)
        assert pc.bytes() < per_unknown * solver.mesh.n_unknowns
        planned = estimate_aim(surface, 0.5, 1.5, aim={"preconditioner": name, "restart": 30})
        assert planned["preconditioner_bytes"] == pytest.approx(pc.bytes(), rel=0.01)
        assert (ffs[name].diagnostics.get("inner_products", 0) > 0) == (name == "flat-patch")
    assert np.all(relative_l2(ffs[name].brdf(), ffs["near"].brdf(), grid) < 1e-3)


@pytest.mark.parametrize("damping", [-0.1, float("nan")])
def test_a_negative_or_missing_damping_is_refused(damping):
    with pytest.raises(ValueError, match="flat_damping"):
        DampedExterior(0.5, 1.5, damping=damping)


def test_the_config_refuses_a_damping_of_zero_naming_the_key():
    from wavebrdf.solver.bem3d.aim import AIMOptions
    from wavebrdf.solver.options import OptionsError

    with pytest.raises(OptionsError, match=r"flat_damping.*0"):
        AIMOptions.from_mapping({"preconditioner": "flat", "flat_damping": 0})
