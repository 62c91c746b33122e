"""Registry adapters of the fiber models: ``[model] name = "fiber-bem"`` (2.5D boundary elements,
any cross section) and ``"mie"`` (Bohren–Huffman series, circles only).

One :class:`~wavebrdf.solver.models.FiberScene` is one (λ, θ_i): every φ_i and both
polarizations are solved at once (one LU per (λ, θ_i) for the BEM). φ_i is either explicit point
samples or box-averaged bins (fiber.md §14.8, :func:`~wavebrdf.solver.fiber.bcsdf.bcsdf_slices`).
"""

from __future__ import annotations

import hashlib
import time

import numpy as np

from wavebrdf.solver.models import Capabilities, Estimate, FiberResult, FiberScene, Model

__all__ = ["FiberBEMModel", "MieModel"]

FIBER_CAPABILITIES = Capabilities(takes="cross_section", returns="fiber_table", polarized=True, steerable=False,
                                  reciprocal=False, conserves_energy=True)


class _FiberModel(Model):
    """What both fiber models share: φ_i sampling, checks and diagnostics around ``solver()``."""

    capabilities = FIBER_CAPABILITIES

    def solver(self, ctx, scene: FiberScene):  # pragma: no cover - abstract
        """An object with ``scattering(λ, m, θ_i, φ_i, bins=)`` and ``r_max`` (FiberBEM / MieFiber)."""
        raise NotImplementedError

    def run(self, ctx, scene: FiberScene) -> FiberResult:
        from wavebrdf.solver.fiber.bcsdf import bcsdf_slices

        t0 = time.perf_counter()
        solver = self.solver(ctx, scene)
        if scene.phi_i is not None:
            res = solver.scattering(scene.wavelength_um, scene.index, scene.theta_i, np.asarray(scene.phi_i),
                                    bins=scene.phi_r_bins)
        else:
            res = next(bcsdf_slices(solver, [scene.wavelength_um], [scene.index], [scene.theta_i],
                                    scene.phi_i_bins, scene.phi_r_bins))
        result = FiberResult(res.dCs_dphi, res.C_ext, res.C_sca, res.C_abs)
        if not all(np.all(np.isfinite(a)) for a in result.arrays().values()):
            raise FloatingPointError("NaN/inf in the fiber solution")
        result.diagnostics = {
            "model": self.name, "wall_time_s": time.perf_counter() - t0,
            "power_balance_error": float(result.power_balance_error.max()),
            "device": ctx.describe() if ctx is not None else "",
            **{f"time_{k}": float(v) for k, v in res.timings.items()},
        }
        return result

    @staticmethod
    def _table_entries(scene: FiberScene) -> int:
        phi_i = len(scene.phi_i) if scene.phi_i is not None else scene.phi_i_bins
        return phi_i * 8 * scene.phi_r_bins


class FiberBEMModel(_FiberModel):
    """2.5D PMCHWT boundary elements (solver/fiber/bem.py); the assembler of one cross section is
    kept for the next scene on the same context."""

    name = "fiber-bem"
    summary = "full-wave 2.5D boundary elements for a fiber of any cross section at oblique incidence (BCSDF tables)"
    run_warns_itself = True  # the solver raises its FiberMeshWarning (validity below)

    def __init__(self, options=None):
        super().__init__(options)
        self._kept: tuple | None = None  # (key, FiberBEM)

    def solver(self, ctx, scene: FiberScene):
        from wavebrdf.solver.fiber.bem import FiberBEM

        nodes = np.ascontiguousarray(scene.cross_section.nodes)
        key = (id(ctx), hashlib.sha1(nodes.tobytes()).hexdigest())
        if self._kept is None or self._kept[0] != key:
            self._kept = (key, FiberBEM(ctx, scene.cross_section))
        return self._kept[1]

    def release(self) -> None:
        self._kept = None

    def validity(self, scene) -> list[str]:
        """The mesh against the interior wavelength (solver/fiber/bem.py ``mesh_messages``), as
        ``wavebrdf plan`` shows it; the solve raises the same as a FiberMeshWarning."""
        found = super().validity(scene)
        if isinstance(scene, FiberScene) and scene.meshed:
            from wavebrdf.solver.fiber.bem import mesh_messages

            found += [f"{self.name}: {m}" for m in mesh_messages(scene.cross_section, scene.wavelength_um, scene.index)]
        return found

    def check(self, scene: FiberScene) -> None:
        """Boundary elements need a mesh: ``[fiber] segments`` for the smooth shapes."""
        if not scene.meshed:
            raise ValueError(f"[fiber] segments: required by the {self.name} model for shape = \"{scene.shape}\" "
                             "(e.g. 300 for a 1 µm radius at 0.4 µm: >= 10 elements per interior wavelength)")

    def estimate(self, scene: FiberScene) -> Estimate:
        """A dense 4N×4N complex LU per (λ, θ_i)."""
        n = 4 * scene.cross_section.segments
        memory = 3 * 16.0 * n * n + 100e6
        seconds = 8.0 / 3.0 * n**3 * 4 / 2e10 + 4e-7 * n * n + 0.1
        return Estimate(memory, seconds, f"dense {n}x{n} complex LU")


class MieModel(_FiberModel):
    """The Mie series of a circular cylinder (solver/fiber/mie.py); needs ``scene.radius_um``."""

    name = "mie"
    summary = "Mie series of a circular fiber (Bohren-Huffman): exact for circles, fast"

    def check(self, scene: FiberScene) -> None:
        """The series is that of a circular cylinder."""
        if scene.radius_um is None:
            raise ValueError(f"[model] name = \"{self.name}\": the Mie series solves circular fibers only, not fiber.shape = "
                             f"{scene.shape!r}; use \"fiber-bem\"")

    def solver(self, ctx, scene: FiberScene):
        from wavebrdf.solver.fiber.mie import MieFiber

        if scene.radius_um is None:
            raise ValueError("the Mie series solves circular fibers only (give fiber.radius_um)")
        return MieFiber(scene.radius_um)

    def estimate(self, scene: FiberScene) -> Estimate:
        return Estimate(50e6 + 16.0 * self._table_entries(scene), 0.05, "Mie series")
