"""Registry adapter of the full-wave BEM: ``[model] name = "bem"``, ``method = "dense" | "aim"``.

* ``dense`` (bem3d/dense.py): the LU factorization of Z, the ground truth up to ~3·10⁴ unknowns;
* ``aim`` (bem3d/aim.py): the Adaptive Integral Method with a Krylov solve, 10⁵–10⁶ unknowns;
  options from the config table ``[model.aim]``; ``[model] precision = "single"`` selects its
  single-precision kernels and FFTs unless ``[model.aim] precision`` says otherwise.

The operator of one (surface, wavelength, material) serves every incident direction and both
polarizations (the LU factors, or the AIM near-field matrix, grid spectra and preconditioner), so
the last one is kept per process and reused while consecutive tasks share it (the planner orders
tasks case → wavelength → direction, and steered patches patch → basic direction, to make that
the common case).
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


def _operator_key(scene: SurfaceScene, method: str, aim: dict | None) -> tuple:
    z = np.ascontiguousarray(scene.surface.z)
    digest = hashlib.sha1(z.tobytes()).hexdigest()
    return (digest, scene.surface.size_um, scene.wavelength_um, complex(scene.index), scene.exterior_index,
            scene.z_reference, repr(sorted((scene.options.get("quadrature") or {}).items())), method,
            repr(sorted((aim or {}).items())))


def _aim_options(scene: SurfaceScene) -> dict:
    aim = dict(scene.options.get("aim") or {})
    if scene.precision == "single":
        aim.setdefault("precision", "single")
    return aim


class BEMModel(Model):
    """PMCHWT boundary elements on the height field (solver/bem3d)."""

    name = "bem"
    methods = ("dense", "aim")

    def _method(self, scene: SurfaceScene) -> str:
        method = scene.options.get("method") or self.methods[0]
        if method not in self.methods:
            raise ValueError(f"[model] method = {method!r}: the bem model offers {self.methods}")
        return method

    def _solver(self, ctx, scene: SurfaceScene):
        """The operator of this scene's surface, wavelength and material (built or reused)."""
        method = self._method(scene)
        aim = _aim_options(scene) if method == "aim" else None
        key = _operator_key(scene, method, aim)
        if _cache.get("key") != key:
            _cache.clear()  # free the previous operator before building the next one
            common = dict(exterior_index=scene.exterior_index, quadrature=scene.options.get("quadrature"),
                          z_reference=scene.z_reference)
            if method == "aim":
                from wavebrdf.solver.bem3d.aim import AIMBEM

                solver = AIMBEM(ctx, scene.surface, scene.wavelength_um, scene.index, aim=aim, **common)
            else:
                from wavebrdf.solver.bem3d.dense import DenseBEM

                solver = DenseBEM(ctx, scene.surface, scene.wavelength_um, scene.index, **common)
            _cache["solver"] = solver
            _cache["key"] = key
        return _cache["solver"]

    def farfield(self, ctx, scene: SurfaceScene) -> FarField:
        solver = self._solver(ctx, scene)
        return solver.farfield(scene.theta_i, scene.phi_i, scene.grid, waist_um=scene.waist_um, beam=scene.beam,
                               focus_um=scene.footprint_centre_um)

    def estimate(self, scene: SurfaceScene) -> Estimate:
        if self._method(scene) == "aim":
            from wavebrdf.solver.bem3d.aim import estimate_aim

            est = estimate_aim(scene.surface, scene.wavelength_um, scene.index, exterior_index=scene.exterior_index,
                               aim=_aim_options(scene), resolution=scene.grid.resolution, waist_um=scene.waist_um)
            return Estimate(est["bytes"], est["seconds"],
                            f"aim {est['unknowns']} unknowns, near {est['near_bytes'] / 2**30:.2f} GiB, "
                            f"FFT {'x'.join(map(str, est['fft']))}")
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
