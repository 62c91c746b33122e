"""Geometric-optics rungs ``gs`` (single scattering, approx.md §3.1) and ``gm`` (multiple
scattering, §3.2): ray tracing of the bilinear height field (solver/approx/raytrace.py,
kernels/raytrace.cl) → IntensityResult per incident polarization s|p.

Both illuminate with the footprint of every rung (|W|² = exp(−2|x − c|²/w²) on the reference
plane, ``scene.waist_um``, ``scene.footprint_centre_um``) as equal-power rays along −ω_i, apply
Fresnel (n − jκ) and the facet Mueller matrix at each reflection, and deposit escaping rays in the
projected-disk pixel of their direction (f = P/(Φ_i A_p)). ``gs`` keeps the first reflection when
the reflected ray escapes and reports the rest as ``masked_energy_fraction``; ``gm`` follows paths
up to ``max_depth`` reflections and reports ``truncated_energy_fraction``. Both report the power
into the material, the footprint-weighted shadowed fraction and the energy per bounce order.
Rays are the large-roughness limit of the wave: both say where a scene is outside it (the
roughness parameter g and the lobe error it implies, features narrower than λ₁: solver/validity.py
``check_geometric_optics``; the figures in the diagnostics, the warning in ``plan`` and the run).

GO depends on the wavelength only through the index: the traced geometry is kept per (surface,
incidence, footprint, grid, border, rays, seed, depth, precision) in the model instance (the
batch layer keeps one instance per worker), so the next wavelength or material only reweights it
(diagnostics ``geometry_reused``; ``traces`` counts the traces of the instance).
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from dataclasses import dataclass, replace

import numpy as np

from wavebrdf.solver.approx.raytrace import BATCH_RAYS, BORDERS, RAY_BYTES, RECORD_BYTES, trace_paths
from wavebrdf.solver.farfield import IntensityResult
from wavebrdf.solver.models import Capabilities, Estimate, Model, SurfaceScene
from wavebrdf.solver.options import OptionsError, option
from wavebrdf.solver.validity import check_geometric_optics, geometric_optics_figures

__all__ = ["GMModel", "GMOptions", "GSModel", "GSOptions"]

RAYS_DEFAULT = 1 << 22


@dataclass(frozen=True)
class GSOptions:
    rays: int = option(RAYS_DEFAULT, low=1, high=2**32 - 1,
                       doc="equal-power rays per scene (default 2^22: ~1% relative noise over the lobe of a 256² "
                           "output, 1.5% at 512², for a rough metal of rms slope 0.3 at θ_i = 30°; noise falls as "
                           "rays^-0.65, benchmarks/bench_raytrace.py)")
    border: str = option("periodic", choices=BORDERS,
                         doc="surface beyond the patch: periodic continuation (generated surfaces) or the edge "
                             "heights extended outward")
    seed: int = option(0, low=0, high=2**63 - 1, doc="seed of the ray-origin lattice (independent estimates)")
    keep_mb: float = option(1024.0, low=0.0,
                            doc="memory for traced geometry kept for further wavelengths/materials (least recently "
                                "used dropped first; a study with more incident directions than fit re-traces)")


@dataclass(frozen=True)
class GMOptions(GSOptions):
    max_depth: int = option(64, low=1, high=255, doc="reflections per path before it is truncated (reported)")


class GSModel(Model):
    """``[model] name = "gs"``: geometric optics, single scattering with exact shadowing/masking."""

    name = "gs"
    summary = "geometric optics by ray tracing the height field: single scattering with exact shadowing and masking"
    Options = GSOptions
    sampling = frozenset({"realization"})  # rays: the spacing need not resolve λ, the slopes must be the ensemble's
    # Reciprocal only in expectation, not claimed: per realization the estimate averages f over the
    # output pixel at an exact ω_i, and a surface's own slope histogram has structure below a pixel;
    # on the conformance "rough" scene the pairs differ by 2–5% per pixel at 1–4M rays under a plane
    # wave, 15–60% with its 1.8 µm footprint (the footprint weights a path by where it enters)
    capabilities = Capabilities(takes="height_field", returns="intensity", polarized=True, steerable=False,
                                reciprocal=False, conserves_energy=True, rung=0, single_scattering=True)
    _lost_key = "masked_energy_fraction"  # diagnostics name of the energy still hitting after max_depth

    def __init__(self, options=None):
        super().__init__(options)
        self._kept: OrderedDict = OrderedDict()
        self.traces = 0  # geometry traces by this instance (reweighted runs do not count)

    @property
    def max_depth(self) -> int:
        return 1

    def check(self, scene: SurfaceScene) -> None:
        table = f"model.{self.name}"
        if not 0.0 <= scene.theta_i < 0.5 * np.pi:
            raise OptionsError(f"[{table}] illumination.directions_deg: θ_i = {np.rad2deg(scene.theta_i):g}°: "
                               "must be in [0°, 90°)")
        if np.imag(scene.index) > 0:
            raise OptionsError(f"[{table}] material index = {scene.index!r}: must be n - jκ with κ >= 0")
        if scene.waist_um is not None and not (np.isfinite(scene.waist_um) and scene.waist_um > 0):
            raise OptionsError(f"[{table}] illumination.waist_um = {scene.waist_um!r}: must be > 0 "
                               "(the ray origins follow the footprint)")

    def validity(self, scene) -> list[str]:
        """The sampling checks and whether rays describe the scene at all
        (:func:`~wavebrdf.solver.validity.check_geometric_optics`)."""
        found = super().validity(scene)
        return found + check_geometric_optics(self.name, scene) if isinstance(scene, SurfaceScene) else found

    def _key(self, ctx, scene: SurfaceScene) -> tuple:
        z = np.ascontiguousarray(scene.surface.z)
        return (id(ctx), hashlib.blake2b(z.tobytes(), digest_size=16).hexdigest(), z.shape, scene.surface.size_um,
                scene.theta_i, scene.phi_i, scene.waist_um, tuple(scene.footprint_centre_um), scene.z_reference,
                scene.grid.resolution, scene.precision, self.options.border, self.options.rays, self.options.seed,
                self.max_depth)

    def run(self, ctx, scene: SurfaceScene) -> IntensityResult:
        self.check(scene)
        key = self._key(ctx, scene)
        geometry = self._kept.pop(key, None)
        budget = int(self.options.keep_mb * 2**20)
        trace = trace_paths(ctx, scene, rays=self.options.rays, max_depth=self.max_depth, border=self.options.border,
                            seed=self.options.seed, geometry=geometry, keep=budget > 0, keep_bytes=budget)
        if geometry is None:
            self.traces += 1
            geometry = trace.geometry
        if geometry is not None:
            self._kept[key] = geometry
            while self._kept and sum(g.nbytes for g in self._kept.values()) > budget:
                self._kept.popitem(last=False)
        diagnostics = dict(trace.diagnostics)
        lost = diagnostics.pop("truncated_energy_fraction")
        diagnostics[self._lost_key] = lost
        diagnostics.update(model=self.name, traces=self.traces, **geometric_optics_figures(scene))
        result = trace.result()
        result.diagnostics = diagnostics
        return result

    def release(self) -> None:
        self._kept.clear()

    def estimate(self, scene: SurfaceScene) -> Estimate:
        rays = self.options.rays
        surface = scene.surface
        n = surface.cells
        res = scene.grid.resolution
        stats = surface.statistics()
        d = surface.spacing_um
        # cells crossed per segment: down from z_max to the surface and back up, at the incidence
        # angle (the lobe leaves near the mirror direction), plus the cell of the hit
        rise = 0.5 * stats["peak_to_valley_um"] / d
        cells = 2.0 + rise * min(np.tan(scene.theta_i), 50.0)
        bounces = 1.0 if self.max_depth == 1 else 1.0 + min(1.0, stats["rms_slope"] ** 2)
        steps = rays * cells * (1.0 + bounces)
        # measured on PoCL (2 cores, shared): ~0.3 µs per ray (origin, reflection, records, weights,
        # binning) + ~50 ns per cell crossed, plus set-up (surface, pixel table, shadowing rays)
        seconds = 0.3 + 5e-8 * steps + 3e-7 * rays + 1e-7 * n * n
        real = scene.precision.real
        kept = rays * RAY_BYTES + rays * bounces * RECORD_BYTES[real]
        if kept > self.options.keep_mb * 2**20:
            kept = 0.0
        batch = min(rays, BATCH_RAYS)
        records = batch * (1.25 * bounces) * RECORD_BYTES[real]  # one batch's record buffers
        memory = 120e6 + kept + batch * 60.0 + 16.0 * (n + 1) ** 2 + 64.0 * res * res
        device = (kept * 0.9 + records + batch * (9 + 2 * real.itemsize) + real.itemsize * (n + 1) ** 2
                  + 4.0 * res * res)
        # the record buffers of a batch: 1.25 × the records per ray, and for the first batch of a
        # multiple-scattering trace (its depth not yet measured) 1.625 per ray (raytrace.trace_paths)
        per_ray = max(1.25 * bounces, 1.625 if self.max_depth > 1 else 1.0)
        largest = max(batch * per_ray * 3 * real.itemsize + 64 * 3 * real.itemsize, real.itemsize * (n + 1) ** 2,
                      4.0 * res * res)
        return Estimate(memory, seconds, f"{rays} rays, ~{cells:.0f} cells per segment, {bounces:.2f} bounces",
                        device_bytes=device, largest_buffer_bytes=largest)


class GMModel(GSModel):
    """``[model] name = "gm"``: geometric optics, multiple scattering (paths up to ``max_depth``)."""

    name = "gm"
    summary = "geometric optics by ray tracing the height field: multiple scattering (paths up to max_depth bounces)"
    Options = GMOptions
    capabilities = replace(GSModel.capabilities, rung=1, single_scattering=False)
    _lost_key = "truncated_energy_fraction"

    @property
    def max_depth(self) -> int:
        return self.options.max_depth
