"""Registry adapter of the full-wave BEM: ``[model] name = "bem"`` (``method = "dense"``).

The LU factorization of one (surface, wavelength, material) serves every incident direction and
both polarizations, so the last factorized operator is kept per process and reused while
consecutive tasks share it (the planner orders tasks case → wavelength → direction, and steered
patches patch → basic direction, to make that the common case).
"""

from __future__ import annotations

import hashlib

import numpy as np

from wavebrdf.solver.beams import make_beam
from wavebrdf.solver.farfield import FarField
from wavebrdf.solver.models import Estimate, Model, SurfaceScene

__all__ = ["BEMModel"]

LU_FLOPS_PER_SECOND = 1.5e10  # complex LU throughput measured on the 2-core machine (scipy/OpenBLAS)
ASSEMBLY_SECONDS_PER_ENTRY = 2e-7  # dense assembly on PoCL, per complex matrix entry

_cache: dict = {}


def _operator_key(scene: SurfaceScene) -> tuple:
    z = np.ascontiguousarray(scene.surface.z)
    digest = hashlib.sha1(z.tobytes()).hexdigest()
    return (digest, scene.surface.size_um, scene.wavelength_um, complex(scene.index), scene.exterior_index,
            scene.z_reference, repr(sorted(scene.options.get("quadrature", {}).items())))


class BEMModel(Model):
    """PMCHWT boundary elements on the height field (solver/bem3d)."""

    name = "bem"
    methods = ("dense",)

    def _dense(self, ctx, scene: SurfaceScene):
        from wavebrdf.solver.bem3d.dense import DenseBEM

        key = _operator_key(scene)
        if _cache.get("key") != key:
            _cache.clear()  # free the previous operator before building the next one
            _cache["solver"] = DenseBEM(ctx, scene.surface, scene.wavelength_um, scene.index,
                                        exterior_index=scene.exterior_index,
                                        quadrature=scene.options.get("quadrature"), z_reference=scene.z_reference)
            _cache["key"] = key
        return _cache["solver"]

    def farfield(self, ctx, scene: SurfaceScene) -> FarField:
        method = scene.options.get("method") or self.methods[0]
        if method not in self.methods:
            raise ValueError(f"[model] method = {method!r}: the bem model offers {self.methods}")
        solver = self._dense(ctx, scene)
        return solver.farfield(scene.theta_i, scene.phi_i, scene.grid, waist_um=scene.waist_um, beam=scene.beam,
                               focus_um=scene.footprint_centre_um)

    def estimate(self, scene: SurfaceScene) -> Estimate:
        from wavebrdf.solver.bem3d.dense import estimate_dense

        est = estimate_dense(scene.surface)
        n = est["unknowns"]
        seconds = est["lu_flops"] * 4 / LU_FLOPS_PER_SECOND + ASSEMBLY_SECONDS_PER_ENTRY * n * n
        return Estimate(est["bytes"], seconds, f"dense {n} unknowns, Z {est['matrix_bytes'] / 2**30:.2f} GiB")

    def incident_fields(self, scene: SurfaceScene, points):
        beam = make_beam(scene.beam, scene.wavelength_um, scene.theta_i, scene.phi_i, scene.waist_um,
                         exterior_index=scene.exterior_index,
                         focus_um=(scene.footprint_centre_um[0], scene.footprint_centre_um[1], 0.0),
                         patch_size_um=scene.surface.size_um)
        E, H = beam.fields(np.asarray(points, dtype=float))
        # beams return (2, ..., 3); the steering code wants (2, 3, ...)
        return np.moveaxis(E, -1, 1), np.moveaxis(H, -1, 1)
