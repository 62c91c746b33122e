"""Far field from AIM grid point sources with chirp-z transforms vs the direct quadrature sum.

Bar (issue 4): relative error < 1e-3 over the hemisphere (every pixel of the projected disk),
for random currents (the hardest case: no smoothness) on a rough patch and on a flat one, with
the far field's own hemisphere-matched sources ("matched") and with the operator's own
exterior-medium projection ("operator", the default since issue 18), in both precisions.
"""

from __future__ import annotations

import numpy as np
import pytest

from wavebrdf.solver.bem3d.aim.farfield import GridFarField
from wavebrdf.solver.bem3d.aim.operator import GridPart
from wavebrdf.solver.bem3d.aim.options import AIMOptions
from wavebrdf.solver.bem3d.excitation import SurfaceRule
from wavebrdf.solver.bem3d.farfield import radiated_fields
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import BEMMesh
from wavebrdf.solver.farfield import HemisphereGrid
from wavebrdf.solver.surface import generate


@pytest.mark.parametrize("sources, precision", [("matched", "double"), ("operator", "double"),
                                               ("operator", "single")])
@pytest.mark.parametrize("generator, params, index, lam", [
    ("gaussian", {"rms_height_um": 0.08, "correlation_um": 0.3}, 1.5, 0.5),
    ("flat", {}, 1.5, 0.5),
    ("gaussian", {"rms_height_um": 0.08, "correlation_um": 0.3}, 0.46582 - 4.7119j, 0.4),
])
def test_grid_far_field_matches_direct_sum(cl_ctx, rng, generator, params, index, lam, sources, precision):
    d, cells = lam / 10, 24
    mesh = BEMMesh(generate(generator, cells=cells, size_um=cells * d, seed=2, **params))
    media = Media(lam, index)
    out = HemisphereGrid(96)
    x = rng.standard_normal((2, mesh.n_unknowns)) + 1j * rng.standard_normal((2, mesh.n_unknowns))
    projection = None
    if sources == "operator":
        projection = GridPart.build(cl_ctx, mesh, media, AIMOptions(precision=precision)).exterior_projection(media)
        assert projection is not None
    E, H = GridFarField(mesh, media, out, projection=projection).fields(x)
    dirs = out.directions[out.inside]
    E0, H0 = radiated_fields(cl_ctx, mesh, media, x, dirs, SurfaceRule.build(mesh, 4))
    E1 = np.moveaxis(E, 1, -1)[:, out.inside]
    H1 = np.moveaxis(H, 1, -1)[:, out.inside]
    err_e = np.linalg.norm(E1 - E0) / np.linalg.norm(E0)
    err_h = np.linalg.norm(H1 - H0) / np.linalg.norm(H0)
    worst = np.max(np.linalg.norm(E1 - E0, axis=-1)) / np.max(np.linalg.norm(E0, axis=-1))
    print(f"{generator} {index} {sources} {precision}: relative L2 error E {err_e:.2e}, H {err_h:.2e}, worst pixel / peak {worst:.2e}")
    assert err_e < 1e-3 and err_h < 1e-3 and worst < 1e-3
    assert np.all(E[:, :, ~out.inside] == 0)
