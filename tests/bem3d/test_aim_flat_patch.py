"""The flat patch's operator solved by inner GMRES steps as the preconditioner of FGMRES
(solver/bem3d/aim/flat_patch.py).

* T X, by FFTs of the Toeplitz torus, is the dense PMCHWT matrix of the flat patch (assembled
  block by block, assembly.assemble_dense) times X, whatever the heights of the mesh it is built
  on (only its lattice is used);
* settings it cannot run with are refused by name.

Its products on a rough patch and end to end through BEMSolver: test_aim_flat_preconditioner.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from wavebrdf.solver.bem3d.aim import AIMOptions
from wavebrdf.solver.bem3d.aim.flat_patch import FlatPatchOperator
from wavebrdf.solver.bem3d.assembly import assemble_dense
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import BEMMesh
from wavebrdf.solver.options import OptionsError
from wavebrdf.solver.surface import generate

AL_400 = 0.46582 - 4.7119j


@pytest.mark.parametrize("index", [AL_400, 1.5])
def test_the_flat_patch_operator_is_the_dense_flat_matrix(cl_ctx, index):
    """T X = Z_flat X for random X (two right-hand sides) on a 9-cell patch, built from a rough
    mesh of the same lattice: every offset of the patch, no wrap on the torus."""
    cells, d = 9, 0.03
    media = Media(0.4, index)
    rough = BEMMesh(generate("gaussian", cells=cells, size_um=cells * d, rms_height_um=0.02, correlation_um=0.06))
    T = FlatPatchOperator(cl_ctx, rough, media)
    assert min(T.torus) >= 2 * cells - 1
    dense, _ = assemble_dense(cl_ctx, BEMMesh(generate("flat", cells=cells, size_um=cells * d)), media)
    rng = np.random.default_rng(4)
    X = rng.standard_normal((2, rough.n_unknowns)) + 1j * rng.standard_normal((2, rough.n_unknowns))
    expected = X @ dense.T
    got = T(X)
    assert len(T.spectrum.pairs) == 8  # the J–M̃ blocks of a flat lattice are zero, and not kept
    assert T.bytes() == T.spectrum.values.nbytes + T.placement.bytes()
    assert got.shape == X.shape
    assert np.linalg.norm(got - expected) / np.linalg.norm(expected) < 1e-5  # complex64 transforms


@pytest.mark.parametrize("settings, key", [
    ({"preconditioner": "flat-patch", "solver": "csym"}, "solver"),
    ({"preconditioner": "flat-patch", "deflate": 5}, "deflate"),
    ({"preconditioner": "flat-patch", "flat_inner_steps": 0}, "flat_inner_steps"),
])
def test_settings_the_inner_solve_cannot_run_with_are_refused_by_name(settings, key):
    with pytest.raises((ValueError, OptionsError), match=key):
        AIMOptions.from_mapping(settings)
