"""AIM matrix-vector product against the dense PMCHWT matrix (VALIDATION.md item 7).

Bar: relative error ‖(Z_AIM − Z)x‖/‖Zx‖ < 1e-3 for random vectors, with the default options, at
three patch sizes for a dielectric (n = 1.5, d = λ/10) and for aluminium (d = λ/12.8), rough
surfaces (several z planes). The dense matrix uses the same quadrature, so the difference is the
AIM approximation alone (both use the AIM's element quadrature, AIM_QUADRATURE). The OpenCL
product must also equal its NumPy twin.
"""

from __future__ import annotations

import numpy as np
import pytest

from wavebrdf.solver.bem3d.aim import AIM_QUADRATURE, AIMOperator, AIMOptions
from wavebrdf.solver.bem3d.assembly import assemble_dense
from wavebrdf.solver.bem3d.elements import ElementIntegrals
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import BEMMesh
from wavebrdf.solver.surface import generate

DIELECTRIC = (0.5, 1.5, 10.0)  # λ (µm), index, λ/d
ALUMINIUM = (0.4, 0.46582 - 4.7119j, 12.8)


def _matvec_error(ctx, cells, case, rng, options=None):
    lam, index, per_wavelength = case
    d = lam / per_wavelength
    surface = generate("gaussian", cells=cells, size_um=cells * d, seed=cells, rms_height_um=0.1 * lam,
                       correlation_um=0.8 * lam)
    mesh = BEMMesh(surface)
    media = Media(lam, index)
    Z, _ = assemble_dense(ctx, mesh, media, ElementIntegrals(mesh, AIM_QUADRATURE, ctx))
    op = AIMOperator(ctx, mesh, media, options or AIMOptions(preconditioner="none"))
    x = rng.standard_normal((2, mesh.n_unknowns)) + 1j * rng.standard_normal((2, mesh.n_unknowns))
    ref = x @ Z.T
    y = op.matvec(x)
    err = np.linalg.norm(y - ref) / np.linalg.norm(ref)
    print(f"N = {cells} ({mesh.n_unknowns} unknowns), n = {index}: AIM vs dense {err:.2e}, {op.grid.describe()}, "
          f"z planes {op.grid.shape[2]}, grid media {op.grid_media}")
    return err, op, x, y


@pytest.mark.parametrize("cells", [16, 20, 24])
def test_aim_matvec_matches_dense_dielectric(cl_ctx, rng, cells):
    err, op, x, y = _matvec_error(cl_ctx, cells, DIELECTRIC, rng)
    assert err < 1e-3
    twin = op.matvec_numpy(x)
    assert np.linalg.norm(y - twin) / np.linalg.norm(twin) < 1e-6  # complex64 near storage
    if cells == 16:  # three right-hand sides: the kernels take 1, 2 or 4, so the product splits (2 + 1)
        y3 = op.matvec(np.vstack([x, x[:1]]))
        assert np.allclose(y3, np.vstack([y, y[:1]]), rtol=1e-12, atol=0)


@pytest.mark.parametrize("cells", [16, 24])
def test_aim_matvec_matches_dense_aluminium(cl_ctx, rng, cells):
    err, op, _, _ = _matvec_error(cl_ctx, cells, ALUMINIUM, rng)
    assert err < 1e-3


@pytest.mark.slow
@pytest.mark.parametrize("cells", [32, 40, 48])
def test_aim_matvec_matches_dense_larger(cl_ctx, rng, cells):
    for case in (DIELECTRIC, ALUMINIUM):
        err, _, _, _ = _matvec_error(cl_ctx, cells, case, rng)
        assert err < 1e-3


def test_single_precision_costs_little_accuracy(cl_ctx, rng):
    """precision = "single" (float kernels, complex64 FFTs): AIM error stays below 1e-3."""
    err, _, _, _ = _matvec_error(cl_ctx, 16, DIELECTRIC, rng, AIMOptions(preconditioner="none", precision="single"))
    assert err < 1e-3
