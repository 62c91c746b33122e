"""The one driver of the 3D BEM: an operator (dense LU or AIM) behind a single far-field template.

:class:`BEMSolver` builds, for one surface, wavelength and material, the media, the mesh, the
checks and the operator of the chosen ``method``, then serves any number of incident directions
and both polarizations:

    excitation (excitation.py)
    → with the flat continuation (aim/continuation.py, AIM ``edge = "flat"``): b − Z_SF c_F
    → operator.solve (dense.py: LU; aim/operator.py: Krylov)
    → operator.farfield (radiation): dense — direct quadrature sum and the hemisphere-quadrature
      radiated power (farfield.py); AIM — chirp-z transforms of grid point sources
      (aim/farfield.py), plus the continued currents beyond the patch in closed form when it is
      continued (``beyond``: FlatContinuation.radiation_beyond)
    → diagnostics.

An operator has ``mesh``, ``solve(b, diagnostics)`` → a result with ``x`` (P, 2N_b) that records
its figures (residual, iterations, times) into ``diagnostics``, ``farfield(mesh, x, grid, rule,
theta_i=, phi_i=, incident_power=, diagnostics=)`` → FarField (AIM adds ``beyond=``), and ``diagnostics()`` (set-up
figures). :func:`bem_farfield` is the one-shot entry point of both methods. Given a
:class:`~wavebrdf.solver.bem3d.warm_start.WarmStarts`, an AIM solve starts from the previous
wavelength's solution of the same surface and incidence (warm_start.py); given the
:class:`~wavebrdf.solver.bem3d.elements.StaticTables` of an earlier solve of the surface, its AIM
set-up skips the static singular tables (``[model.aim] reuse_setup``).
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from dataclasses import replace
from functools import partial
from typing import NamedTuple

import numpy as np

from wavebrdf.solver.beams import make_beam
from wavebrdf.solver.bem3d.aim.continuation import FlatContinuation, border_height, flux_beyond
from wavebrdf.solver.bem3d.aim.operator import AIMOperator
from wavebrdf.solver.bem3d.aim.options import AIM_QUADRATURE, AIMOptions
from wavebrdf.solver.bem3d.checks import (check_continuation_flux, check_material, check_resolution,
                                          check_surface_plasmons)
from wavebrdf.solver.bem3d.dense import DenseOperator
from wavebrdf.solver.bem3d.elements import StaticTables
from wavebrdf.solver.bem3d.excitation import BeamExcitation, SurfaceRule, beam_excitation, power_into_material
from wavebrdf.solver.bem3d.farfield import fields_from_integrals, radiated_fields
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import BEMMesh
from wavebrdf.solver.bem3d.quadrature import QuadratureOptions
from wavebrdf.solver.bem3d.warm_start import WarmStarts, surface_key
from wavebrdf.solver.farfield import FarField, HemisphereGrid
from wavebrdf.solver.resources import peak_memory_mb
from wavebrdf.solver.stages import StageClock
from wavebrdf.solver.surface import HeightField

__all__ = ["METHODS", "BEMSolver", "bem_farfield"]

METHODS = ("dense", "aim")


class Solution(NamedTuple):
    """One solve: the excitation, the patch's solution x (P, 2N_b), and when the patch is
    continued, the radiation integrals of the currents beyond it
    (``FlatContinuation.radiation_beyond`` for the solve's beam: (κx, κy, separable=) → (P, ..., 6))."""

    excitation: BeamExcitation
    x: np.ndarray
    beyond: Callable | None = None


class BEMSolver:
    """The PMCHWT operator of one surface, wavelength and material; far fields for any incidence.

    Parameters: ``ctx`` (ComputeContext; None runs the dense NumPy reference path on tiny meshes),
    ``surface`` (HeightField), ``wavelength_um``, ``index`` (n − jκ), ``method`` ("dense" | "aim"),
    ``exterior_index``, ``quadrature`` (QuadratureOptions or a mapping; default the dense default,
    or AIM_QUADRATURE for AIM), ``z_reference`` (height subtracted from the surface, default its
    mean, or the border's with the flat continuation), ``aim`` (AIMOptions or a mapping; method
    "aim" only), ``residual`` ("auto" | "copy" | "reassemble" | "none") and ``memory_limit_bytes``
    (default 85% of MemAvailable) of the dense path, ``progress`` (callable(stage, fraction)),
    ``warm_starts`` (a WarmStarts the AIM solves read their initial guess from and keep their
    solution in, when ``aim.warm_start``; None: every solve starts from zero), ``static_tables``
    (the StaticTables of an earlier AIM solve of this surface, used where they serve its geometry;
    with ``aim.reuse_setup`` the operator keeps its own as ``operator.static_tables``).
    """

    def __init__(self, ctx, surface: HeightField, wavelength_um: float, index: complex, *, method: str = "dense",
                 exterior_index: float = 1.0, quadrature=None, z_reference: float | None = None, aim=None,
                 residual: str = "auto", memory_limit_bytes: float | None = None, progress=None,
                 warm_starts: WarmStarts | None = None, static_tables: StaticTables | None = None):
        if method not in METHODS:
            raise ValueError(f"bem method must be one of {METHODS}, got {method!r}")
        if method == "aim" and ctx is None:
            raise ValueError("the AIM solver needs an OpenCL context (ctx)")
        if method == "dense" and aim:
            raise ValueError(f"aim options {aim!r} given for the bem method 'dense' (set method = 'aim')")
        self.ctx = ctx
        self.method = method
        self.media = Media(wavelength_um, index, exterior_index)
        self.aim = None
        if method == "aim":
            self.aim = aim if isinstance(aim, AIMOptions) else AIMOptions.from_mapping(aim)
        continued = self.aim is not None and self.aim.edge == "flat"
        if continued and z_reference is None:
            z_reference = border_height(surface)  # the continuation plane is z = 0
        self.mesh = BEMMesh(surface, z_reference)
        self.warm_starts = warm_starts if self.aim is not None and self.aim.warm_start else None
        self._warm_key = None if self.warm_starts is None else surface_key(
            self.mesh, float(exterior_index), self.aim.precision, id(ctx))
        if quadrature is None and method == "aim":
            quadrature = AIM_QUADRATURE
        if not isinstance(quadrature, QuadratureOptions):
            quadrature = QuadratureOptions.from_mapping(quadrature)
        self.quadrature = quadrature
        self.progress = progress or (lambda stage, fraction=None, **figures: None)
        self.diagnostics: dict = {"model": "bem", "method": method, "warnings": []}
        self.clock = StageClock()  # set-up stages here, per-direction stages added by farfield()
        self._set_up_warnings: list[tuple[type[Warning], str]] = []  # raised again by later solves
        self._solves = 0
        self._set_up_check(check_material, self.media, surface.size_um)
        self._set_up_check(check_resolution, self.media, surface)
        if method == "dense":
            self.operator = DenseOperator(ctx, self.mesh, self.media, quadrature, residual=residual,
                                          memory_limit_bytes=memory_limit_bytes, progress=self.progress)
        else:
            self.operator = AIMOperator(ctx, self.mesh, self.media, self.aim, quadrature=quadrature,
                                        progress=self.progress, clock=self.clock, static_tables=static_tables)
        setup = self.operator.diagnostics()
        self.continuation = None
        if continued:
            with self.clock("continuation set-up"):
                self.continuation = FlatContinuation(ctx, self.mesh, self.media, self.aim, quadrature=quadrature)
            setup["setup_s"] += self.continuation.setup_s
            if np.ptp(self.mesh.heights) > 0:
                self._set_up_check(check_surface_plasmons, self.media, surface.size_um)
        self.diagnostics.update(
            unknowns=self.mesh.n_unknowns, cells=self.mesh.cells, spacing_um=self.mesh.spacing_um, **setup,
            quadrature=self.quadrature.__dict__.copy(), device=None if ctx is None else ctx.describe(),
            index=complex(self.media.index),
        )

    def _set_up_check(self, check, *args) -> None:
        """Run a set-up check (solver/bem3d/checks.py: it warns and records in the diagnostics) and
        keep what it raised for :meth:`_warn_set_up_again`."""
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            check(*args, self.diagnostics)
        for w in caught:
            self._set_up_warnings.append((w.category, str(w.message)))
            warnings.warn(str(w.message), w.category, stacklevel=3)

    def _warn_set_up_again(self) -> None:
        """Raise the set-up's warnings again (recorded once): every solve after the first on this
        operator carries them too (a worker keeps the operator for the next task of the same
        surface and wavelength)."""
        self._solves += 1
        if self._solves > 1:
            for category, message in self._set_up_warnings:
                warnings.warn(message, category, stacklevel=3)

    # ------------------------------------------------------------------------------------------
    def farfield(self, theta_i: float, phi_i: float, grid: HemisphereGrid, *, waist_um: float | None,
                 beam: str = "exact", focus_um=(0.0, 0.0)) -> FarField:
        """Far field for incidence (θ_i, φ_i) (toward the light) with the named beam.

        Raises :class:`~wavebrdf.solver.krylov.KrylovNotConverged` (with ``diagnostics``) when an
        AIM solve misses its tolerance: such a result is never returned.
        """
        t0 = time.perf_counter()
        self._warn_set_up_again()
        diag = {k: v for k, v in self.diagnostics.items() if k != "warnings"}
        diag["warnings"] = list(self.diagnostics["warnings"])
        solution = self._solve(theta_i, phi_i, waist_um=waist_um, beam=beam, focus_um=focus_um, diagnostics=diag)
        t_solve = time.perf_counter()
        self.progress("far field", 0.0)
        inc, power = solution.excitation.beam, solution.excitation.incident_power
        extra = {}
        with self.clock("far field"):
            if solution.beyond is not None:
                k1 = float(self.media.wavenumbers[0].real)
                extra["beyond"] = np.moveaxis(solution.beyond(k1 * grid.u, k1 * grid.u, separable=True), -1, 1)
            # the dense operator's direct sum needs the surface rule; AIM radiates from grid sources
            rule = SurfaceRule.build(self.mesh, self.quadrature.farfield_order) if self.method == "dense" else None
            ff = self.operator.farfield(self.mesh, solution.x, grid, rule, theta_i=theta_i,
                                        phi_i=phi_i, incident_power=power, diagnostics=diag, **extra)
            into = power_into_material(self.mesh, solution.x, self.quadrature.farfield_order)  # through the patch only
        if not (np.all(np.isfinite(ff.E)) and np.all(np.isfinite(ff.H))):
            raise FloatingPointError(f"BEM far field ({self.method}) contains NaN/inf")
        ff.diagnostics.update(beam=beam, waist_um=waist_um, farfield_s=time.perf_counter() - t_solve,
                              total_direction_s=time.perf_counter() - t0, into_material_fraction=into / power,
                              peak_memory_bytes=peak_memory_mb() * 2**20, stages=self.clock.as_dict())
        if beam == "exact":
            ff.diagnostics["beam_reflectance"] = (inc.reflectance(self.media.index) if solution.beyond is None
                                                  else inc.continuous_reflectance(self.media.index))
            ff.diagnostics["beam_plane_waves"] = len(inc.plane_waves["kvec"])
        return ff

    def brdf_at(self, theta_i: float, phi_i: float, directions: np.ndarray, *, waist_um: float | None,
                beam: str = "exact", focus_um=(0.0, 0.0)) -> np.ndarray:
        """BRDF (sr⁻¹) per polarization (s, p) at arbitrary outgoing unit ``directions`` (M, 3), by
        the direct quadrature sum (plus the continued currents' closed form when the patch is
        continued)."""
        self._warn_set_up_again()
        solution = self._solve(theta_i, phi_i, waist_um=waist_um, beam=beam, focus_um=focus_um)
        directions = np.atleast_2d(np.asarray(directions, dtype=float))
        rule = SurfaceRule.build(self.mesh, self.quadrature.farfield_order)
        E, H = radiated_fields(self.ctx, self.mesh, self.media, solution.x, directions, rule)
        if solution.beyond is not None:
            k1 = float(self.media.wavenumbers[0].real)
            F = solution.beyond(k1 * directions[:, 0], k1 * directions[:, 1])
            E_beyond, H_beyond = fields_from_integrals(self.media, directions[None], F[..., :3], F[..., 3:])
            E, H = E + E_beyond, H + H_beyond
        intensity = np.linalg.norm(0.5 * np.real(np.cross(E, np.conj(H))), axis=-1)
        return intensity / (solution.excitation.incident_power[:, None] * directions[None, :, 2])

    # ------------------------------------------------------------------------------------------
    def _solve(self, theta_i: float, phi_i: float, *, waist_um: float | None, beam: str, focus_um,
               diagnostics: dict | None = None) -> Solution:
        """Excitation → (continuation: the fixed currents' field off the rhs) → operator.solve.
        ``diagnostics`` (if given) receives the footprint check and the solve's figures."""
        record = diagnostics if diagnostics is not None else {}
        margin = extent = None
        if self.continuation is not None:
            if beam != "exact":
                raise ValueError(f"aim.edge = 'flat' needs illumination.beam = 'exact' (the continued currents "
                                 f"come from its plane waves), got {beam!r}")
            footprint = make_beam(beam, self.media.wavelength_um, theta_i, phi_i, waist_um,
                                  exterior_index=self.media.exterior_index, focus_um=(*focus_um, 0.0),
                                  patch_size_um=self.mesh.surface.size_um)
            with self.clock("continuation reach"):
                margin = self.continuation.margin(footprint)
                extent = self.mesh.surface.size_um + 2 * margin * self.mesh.spacing_um
                check_continuation_flux(flux_beyond(footprint, extent), theta_i, extent, record)
        with self.clock("excitation"):
            excitation = beam_excitation(self.mesh, self.media, theta_i, phi_i, waist_um=waist_um, beam=beam,
                                         focus_um=focus_um, rhs_order=self.quadrature.rhs_order,
                                         diagnostics=diagnostics, extent_um=extent)
        b = excitation.rhs
        if margin is not None:  # the far field carries the whole plane's reflection: the beam's own power
            excitation = replace(excitation, incident_power=excitation.beam.continuous_power())
            t_fixed = time.perf_counter()
            with self.clock("continuation field"):
                fixed, field = self.continuation.fixed_currents(excitation.beam, margin)
            b = b - field
            record.update(edge="flat", continuation_cells=margin, continuation_s=time.perf_counter() - t_fixed,
                          extended_unknowns=fixed.shape[1])
        self.progress("solve", 0.0)
        incidence = (float(theta_i), float(phi_i), waist_um, beam, tuple(map(float, focus_um)))
        k1 = float(self.media.wavenumbers[0].real)
        guess = None if self.warm_starts is None else self.warm_starts.guess(
            self._warm_key, incidence, self.mesh, k1, theta_i, phi_i)
        if guess is not None:
            record["warm_start_from_um"] = guess[1]
        try:
            with self.clock("Krylov solve"):
                result = self.operator.solve(b, record, x0=None if guess is None else guess[0])
        except Exception as exc:  # keep the set-up diagnostics with the failure
            extra = getattr(exc, "diagnostics", None)
            if isinstance(extra, dict):
                extra.update({k: v for k, v in record.items() if k not in extra and k != "aim_options"})
            raise
        if self.warm_starts is not None:
            self.warm_starts.keep(self._warm_key, incidence, k1, self.media.wavelength_um, result.x)
        beyond = None
        if margin is not None:  # the continued currents radiate from the whole plane beyond the patch
            beyond = partial(self.continuation.radiation_beyond, excitation.beam)
            record["continuation_bytes"] = self.continuation.bytes()
        return Solution(excitation, result.x, beyond)


def bem_farfield(ctx, surface: HeightField, wavelength_um: float, index: complex, theta_i: float, phi_i: float,
                 waist_um: float | None, grid: HemisphereGrid, *, method: str = "dense", aim=None,
                 exterior_index: float = 1.0, beam: str = "exact", quadrature=None,
                 z_reference: float | None = None, focus_um=(0.0, 0.0), residual: str = "auto",
                 memory_limit_bytes: float | None = None, progress=None) -> FarField:
    """Full-wave BEM far field of ``surface`` (model "bem"); angles in radians, lengths in µm.

    ``method`` "dense" (LU) or "aim" (with ``aim``: AIMOptions or a mapping); the other arguments
    are those of :class:`BEMSolver` and :meth:`BEMSolver.farfield`. ``diagnostics`` of the result:
    unknowns, residual per polarization, set-up/solve/far-field times, peak memory, warnings, the
    fraction of incident power entering the material, and for the exact beam its flat-interface
    reflectance; dense adds the hemisphere-quadrature albedo, AIM the Krylov figures.
    """
    solver = BEMSolver(ctx, surface, wavelength_um, index, method=method, exterior_index=exterior_index,
                       quadrature=quadrature, z_reference=z_reference, aim=aim, residual=residual,
                       memory_limit_bytes=memory_limit_bytes, progress=progress)
    return solver.farfield(theta_i, phi_i, grid, waist_um=waist_um, beam=beam, focus_um=focus_um)
