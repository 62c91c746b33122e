"""Registry adapter of the full-wave BEM: ``[model] name = "bem"``, ``method = "dense" | "aim"``.

* ``dense`` (bem3d/dense.py): the LU factorization of Z, the ground truth up to ~3·10⁴ unknowns;
* ``aim`` (bem3d/aim/): the Adaptive Integral Method with a Krylov solve, 10⁵–10⁶ unknowns;
  its settings are the table ``[model.aim]`` (:class:`~wavebrdf.solver.bem3d.aim.options.AIMOptions`);
  ``[model] precision = "single"`` selects its single-precision kernels and FFTs.

The operator of one (surface, wavelength, material) serves every incident direction and both
polarizations (the LU factors, or the AIM near-field matrix, grid spectra and preconditioner), so
a model instance keeps the last one and reuses it while consecutive scenes share it; its AIM
solves start from the previous wavelength's solution of the same surface and incidence
(bem3d/warm_start.py; ``[model.aim] warm_start``), and its AIM set-up at a new wavelength of the
same surface reuses the static singular tables of the last (``[model.aim] reuse_setup``; the
wavelength-independent part of the set-up, docs/aim.md). The planner orders tasks case → wavelength →
direction, and steered patches patch → wavelength → basic direction, and the scheduler keeps a
patch on one worker, to make both the common case.
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass, replace

import numpy as np

from wavebrdf.solver.beams import scene_beam, steering_fields
from wavebrdf.solver.bem3d.aim.options import AIMOptions
from wavebrdf.solver.bem3d.warm_start import WarmStarts
from wavebrdf.solver.farfield import FarField
from wavebrdf.solver.models import Capabilities, Estimate, Model, SurfaceScene
from wavebrdf.solver.options import OptionsError, option
from wavebrdf.solver.precision import Precision
from wavebrdf.solver.progress import silent

__all__ = ["BEMModel", "BEMOptions"]

logger = logging.getLogger(__name__)

LU_FLOPS_PER_SECOND = 1.5e10  # complex LU throughput measured on the 2-core machine (scipy/OpenBLAS)
ASSEMBLY_SECONDS_PER_ENTRY = 2e-7  # dense assembly on PoCL, per complex matrix entry


@dataclass(frozen=True)
class BEMOptions:
    """``[model]`` keys of the bem model (besides name and precision)."""

    method: str = option("dense", choices=("dense", "aim"),
                         doc="dense LU (small patches, the reference) or the Adaptive Integral Method")
    aim: AIMOptions = option(AIMOptions(), doc="[model.aim]: settings of method \"aim\" (docs/aim.md)")

    def __post_init__(self):
        if self.method != "aim" and self.aim != AIMOptions():
            raise ValueError('[model.aim] applies to name = "bem", method = "aim" only')


def _reporter(ctx):
    """The solver's progress callable: the context's reporter at the time of each call (the kept
    solver serves later tasks, each with its own reporter; solver/progress.py)."""
    return lambda stage, fraction=None, **figures: getattr(ctx, "progress", silent)(stage, fraction, **figures)


class BEMModel(Model):
    """PMCHWT boundary elements on the height field (solver/bem3d)."""

    name = "bem"
    summary = ("full-wave boundary elements (PMCHWT) on the height field, the reference: dense LU for small "
               "patches, the Adaptive Integral Method for 10^5-10^6 unknowns")
    Options = BEMOptions
    capabilities = Capabilities(takes="height_field", returns="fields", polarized=True, steerable=True,
                                reciprocal=True, conserves_energy=True, rung=9, vector_fields=True)
    run_warns_itself = True  # the solver raises its ResolutionWarnings (validity below)

    def __init__(self, options=None):
        super().__init__(options)
        self._kept: tuple | None = None  # (key, BEMSolver) of the last scene
        self._fits: dict = {}  # budget fits by scene geometry (aim/budget.py)
        self.warm_starts = WarmStarts()  # the last solutions of one surface, the next wavelength's guesses
        self._static: tuple | None = None  # (surface digest, StaticTables) of the last AIM set-up

    def aim_options(self, scene: SurfaceScene) -> AIMOptions:
        """[model.aim] with the scene's precision applied when it is single, fitted to the scene's
        memory budget (aim/budget.py: the planner's choice, which the run then uses): the AIM's
        one precision for this scene, resolved here."""
        return self.budget_fit(scene).options

    def budget_fit(self, scene: SurfaceScene):
        """The AIM settings for this scene's budget and their estimate (aim/budget.py BudgetFit;
        those of the smallest need when nothing fits, which the plan's memory check refuses)."""
        from wavebrdf.solver.bem3d.aim.budget import fit_to_budget

        aim = self.options.aim
        if scene.precision is Precision.SINGLE:
            aim = replace(aim, precision=Precision.SINGLE)
        # patches of one size whose height ranges agree within a cell and rms slopes within 0.01
        # share a fit (the estimate sees the heights only through the grid's extent and, for the
        # product count, the rms slope), so a steered study plans quickly
        surface = scene.surface
        ptp = float(np.ptp(surface.z))
        relief = (round(ptp / surface.spacing_um), ptp == 0.0)  # a flat patch's grid has one z plane
        slope = round(surface.rms_slope(), 2)
        key = (surface.cells, surface.size_um, relief, slope, scene.wavelength_um, complex(scene.index),
               scene.exterior_index, scene.waist_um, aim, scene.memory_budget_bytes, scene.grid.resolution)
        if key not in self._fits:
            budget = float("inf") if scene.memory_budget_bytes is None else scene.memory_budget_bytes
            self._fits[key] = fit_to_budget(scene.surface, scene.wavelength_um, scene.index, aim, budget,
                                            exterior_index=scene.exterior_index, waist_um=scene.waist_um,
                                            resolution=scene.grid.resolution)
            if self._fits[key].changed or not self._fits[key].fits:
                logger.info("%s", self._fits[key].summary())
        return self._fits[key]

    def _key(self, ctx, scene: SurfaceScene) -> tuple:
        z = np.ascontiguousarray(scene.surface.z)
        return (id(ctx), hashlib.sha1(z.tobytes()).hexdigest(), scene.surface.size_um, scene.wavelength_um,
                complex(scene.index), scene.exterior_index, scene.z_reference, self.options.method,
                self.aim_options(scene) if self.options.method == "aim" else None)

    def solver(self, ctx, scene: SurfaceScene):
        """The BEMSolver of this scene's surface, wavelength and material (built or reused)."""
        from wavebrdf.solver.bem3d.driver import BEMSolver

        key = self._key(ctx, scene)
        if self._kept is None or self._kept[0] != key:
            self._kept = None  # free the previous operator before building the next one
            aim = self.aim_options(scene) if self.options.method == "aim" else None
            surface = (*key[1:3], scene.z_reference)  # the heights the mesh gets: its tables' geometry
            if self._static is not None and (self._static[0] != surface or aim is None or not aim.reuse_setup):
                self._static = None  # another surface's tables go before this one's set-up
            solver = BEMSolver(ctx, scene.surface, scene.wavelength_um, scene.index, method=self.options.method,
                               exterior_index=scene.exterior_index, z_reference=scene.z_reference, aim=aim,
                               progress=_reporter(ctx), warm_starts=self.warm_starts,
                               static_tables=None if self._static is None else self._static[1])
            kept = getattr(solver.operator, "static_tables", None)
            self._static = None if kept is None else (surface, kept)
            self._kept = (key, solver)
        return self._kept[1]

    def release(self) -> None:
        self._kept = None
        self._static = None
        self.warm_starts.clear()

    def validity(self, scene) -> list[str]:
        """The mesh's resolution against λ₁ and the interior wavelength (solver/bem3d/checks.py), as
        ``wavebrdf plan`` shows it; the solve raises the same as ResolutionWarnings."""
        found = super().validity(scene)
        if isinstance(scene, SurfaceScene):
            from wavebrdf.solver.bem3d.checks import resolution_messages
            from wavebrdf.solver.bem3d.media import Media

            media = Media(scene.wavelength_um, scene.index, scene.exterior_index)
            found += [f"bem: {message}" for message in resolution_messages(media, scene.surface)]
        return found

    def foreseen_warnings(self, scene) -> list[str]:
        """:meth:`Model.foreseen_warnings` and the beam's own FootprintWarnings (the power outside
        the patch, the exact beam's spectrum cut: solver/bem3d/excitation.py ``foreseen_beam_warnings``);
        with the flat continuation, the flux beyond its reach is known only once the solve sizes
        it and is not foreseen."""
        found = super().foreseen_warnings(scene)
        if isinstance(scene, SurfaceScene):
            from wavebrdf.solver.bem3d.excitation import foreseen_beam_warnings

            continued = self.options.method == "aim" and self.options.aim.edge == "flat"
            focus = tuple(float(c) for c in scene.footprint_centre_um[:2])
            found += foreseen_beam_warnings(scene.beam, float(scene.wavelength_um), float(scene.theta_i),
                                            float(scene.phi_i), scene.waist_um, float(scene.exterior_index),
                                            focus, float(scene.surface.size_um), continued)
        return found

    def check(self, scene: SurfaceScene) -> None:
        """Refuse, before anything runs, what the flat edge continuation cannot do."""
        if self.options.method != "aim" or self.options.aim.edge != "flat":
            return
        if scene.beam != "exact":
            raise OptionsError(f'[model.aim] edge = "flat": needs illumination.beam = "exact" (the continued '
                               f'currents come from its plane waves), got "{scene.beam}"')
        from wavebrdf.solver.bem3d.aim.continuation import border_height, check_flat_border

        try:
            check_flat_border(scene.surface.z - border_height(scene.surface), scene.surface.spacing_um)
        except ValueError as exc:
            raise OptionsError(f"[model.aim] {exc}") from None

    def run(self, ctx, scene: SurfaceScene) -> FarField:
        return self.solver(ctx, scene).farfield(scene.theta_i, scene.phi_i, scene.grid, waist_um=scene.waist_um,
                                                beam=scene.beam, focus_um=scene.footprint_centre_um)

    def estimate(self, scene: SurfaceScene) -> Estimate:
        if self.options.method == "aim":
            from wavebrdf.solver.bem3d.aim.estimate import memory_breakdown

            fit = self.budget_fit(scene)
            est = fit.estimate
            chosen = "; " + ", ".join(f"{k} = {b!r}" for k, (a, b) in fit.changed.items()) if fit.changed else ""
            beyond = f" ({est['outside_fit']})" if est["outside_fit"] else ""
            return Estimate(est["bytes"], est["seconds"],
                            f"aim {est['unknowns']} unknowns, ~{est['iterations_guess']} products{beyond}{chosen}; "
                            f"{memory_breakdown(est)}", following_seconds=est["following_seconds"])
        from wavebrdf.solver.bem3d.dense import estimate_dense

        est = estimate_dense(scene.surface)
        n = est["unknowns"]
        seconds = est["lu_flops"] * 4 / LU_FLOPS_PER_SECOND + ASSEMBLY_SECONDS_PER_ENTRY * n * n
        return Estimate(est["bytes"], seconds, f"dense {n} unknowns, Z {est['matrix_bytes'] / 2**30:.2f} GiB")

    def incident_fields(self, scene: SurfaceScene, points):
        return steering_fields(scene_beam(scene), points)
