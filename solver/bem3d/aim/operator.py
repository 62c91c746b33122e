"""The AIM operator: Z x = (B + C) x without the dense matrix, and its Krylov solve (bem3d.md §6–§7).

* B, the grid part (:class:`GridPart`): far interactions through grid point sources (grid.py),
  projections Λ (projection.py), sampled kernels (green.py), FFT convolution (convolution.py);
* C (nearfield.py, assembled by near_assembly.py): exact minus grid entries of near pairs,
  diagonal (offset) storage on the rooftop lattice;
* a Krylov solve (solver/krylov.py) for both polarizations at once, right-preconditioned by the
  sparse LU of the exact near entries within ``preconditioner_cells``, by the local inverses
  of small tiles of them (preconditioner.py) or by the inverse of the damped flat interface on
  the patch's lattice (flat_circulant.py), or by a few GMRES steps on the flat patch's operator
  (flat_patch.py; the outer solve is then FGMRES);
  without a preconditioner, on the rescaled system S Z S y = S b with S = diag(I, jI)
  (complex-symmetric like Z, but with its spectrum in the right half-plane, which roughly halves
  the GMRES iterations). Both measured in docs/aim.md.

The driver (bem3d/driver.py) puts it behind the same far-field template as the dense LU.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass

import numpy as np

from wavebrdf.solver.bem3d.aim.convolution import PACKED_BATCHES, BaseOperator, GridGroup, batch_chunks
from wavebrdf.solver.bem3d.aim.farfield import GridFarField
from wavebrdf.solver.bem3d.aim.flat_circulant import FlatCirculantPreconditioner
from wavebrdf.solver.bem3d.aim.flat_patch import FlatPatchPreconditioner
from wavebrdf.solver.bem3d.aim.green import grid_media, interior_decay, kernel_spectra
from wavebrdf.solver.bem3d.aim.grid import GridOptions, build_grid
from wavebrdf.solver.bem3d.aim.near_assembly import assemble_near
from wavebrdf.solver.bem3d.aim.nearfield import NearPattern
from wavebrdf.solver.bem3d.aim.options import AIM_QUADRATURE, AIMOptions
from wavebrdf.solver.bem3d.aim.preconditioner import (LocalInversePreconditioner, NearPreconditioner,
                                                       symmetric_scaling)
from wavebrdf.solver.bem3d.aim.projection import project
from wavebrdf.solver.bem3d.elements import ElementIntegrals, StaticTables
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import BEMMesh
from wavebrdf.solver.bem3d.quadrature import QuadratureOptions
from wavebrdf.solver.krylov import KrylovResult, solve
from wavebrdf.solver.progress import silent
from wavebrdf.solver.stages import StageClock

logger = logging.getLogger(__name__)

__all__ = ["PROJECTION_ORDER", "AIMOperator", "GridPart"]

PROJECTION_ORDER = 3  # Gauss order per element of the projection integrals (order 4: same AIM error)


@dataclass
class GridPart:
    """The grid part B of an AIM operator: the media on the grid, the grid, the projections
    (each with the media it serves) and the BaseOperator that applies B."""

    media: tuple
    grid: object
    groups: list
    base: BaseOperator
    projection_s: float

    @classmethod
    def build(cls, ctx, mesh: BEMMesh, media: Media, options: AIMOptions, clock: StageClock | None = None) -> "GridPart":
        """Grid, projections (stored in the operator's precision: the kernels read them so) and
        kernel spectra; ``clock`` records the stages "projection" and "grid spectra"."""
        clock = clock or StageClock()
        t0 = time.perf_counter()
        with clock("projection"):
            on_grid = grid_media(media, options.near_cells * mesh.spacing_um, options.interior_decay_tolerance)
            grid = build_grid(mesh, options.grid_options(media, mesh.spacing_um, on_grid))
            real, cdtype = options.precision.real, options.precision.complex
            if options.projection == "moments":
                groups = [(project(mesh, grid, "moments", order=PROJECTION_ORDER, dtype=real), on_grid)]
            else:
                groups = [(project(mesh, grid, "farfield", k=media.wavenumbers[i].real, order=PROJECTION_ORDER,
                                   directions=options.directions or None, regularization=options.regularization,
                                   dtype=real, ctx=ctx), (i,))
                          for i in on_grid]
        t1 = time.perf_counter()
        with clock("grid spectra"):
            spectra = kernel_spectra(grid, media, on_grid, dtype=cdtype)
            base = BaseOperator(ctx, mesh, [GridGroup.build(p, spectra, media, m, cdtype) for p, m in groups],
                                precision=options.precision, fft=options.fft)
        return cls(on_grid, grid, groups, base, t1 - t0)

    def exterior_projection(self, media: Media):
        """The projection of the exterior medium's group when it is far-field matched at k₁ alone
        (it then reproduces every rooftop's radiation integral: the far field's point sources),
        else None."""
        for projection, group_media in self.groups:
            if (0 in group_media and projection.method == "farfield"
                    and projection.wavenumber == (float(media.wavenumbers[0].real),)):
                return projection
        return None


class AIMOperator:
    """Z x ≈ (B + C) x for one mesh, wavelength and material (see the module docstring)."""

    def __init__(self, ctx, mesh: BEMMesh, media: Media, options: AIMOptions | None = None, *,
                 quadrature: QuadratureOptions | None = None, progress=None, clock: StageClock | None = None,
                 static_tables: StaticTables | None = None):
        """``static_tables``: those of an earlier solve of this patch, used where they serve its
        geometry; with ``options.reuse_setup`` the ones this operator used are kept as
        ``self.static_tables`` (for the patch's next wavelength), else freed after the set-up."""
        t0 = time.perf_counter()
        self.clock = clock = clock or StageClock()
        self.ctx = ctx
        self.mesh = mesh
        self.media = media
        self.options = options = options or AIMOptions()
        self.precision = options.precision
        self.dtype = options.precision.complex
        self.progress = progress or silent
        self.progress("projection", None)
        self.grid_part = grid_part = GridPart.build(ctx, mesh, media, options, clock)
        self.grid_media, self.grid, self.base = grid_part.media, grid_part.grid, grid_part.base
        groups = grid_part.groups
        t1, t2 = t0 + grid_part.projection_s, time.perf_counter()
        precondition = options.preconditioner != "none"
        with clock("near field"):
            self.pattern = NearPattern.build(mesh.cells, options.near_cells)
            integrals = ElementIntegrals(mesh, quadrature or AIM_QUADRATURE, ctx, static=static_tables)
            static_reused = integrals.static is not None
            self.near = assemble_near(ctx, mesh, media, self.pattern, groups, integrals=integrals,
                                      storage=options.near_storage, progress=progress,
                                      exact_cells=self._exact_cells(options))
            # kept for the next wavelength, or freed before the preconditioner and the solve
            self.static_tables = integrals.static if options.reuse_setup else None
            del integrals
            if ctx is not None:
                self.near.upload(ctx)
        t3 = time.perf_counter()
        self.preconditioner = None
        if precondition:
            self.progress("preconditioner", None)
            with clock("preconditioner"):
                if options.preconditioner == "near":
                    self.preconditioner = NearPreconditioner(self.near, options.preconditioner_tile_cells)
                elif options.preconditioner == "flat":
                    self.preconditioner = FlatCirculantPreconditioner(ctx, mesh, media, damping=options.flat_damping)
                elif options.preconditioner == "flat-patch":
                    self.preconditioner = FlatPatchPreconditioner(ctx, mesh, media, steps=options.flat_inner_steps,
                                                                  damping=options.flat_damping)
                else:
                    self.preconditioner = LocalInversePreconditioner(self.near, options.local_tile_cells)
                    self.near.exact = self.near.exact_offsets = None  # in the local inverses now: memory
        self.setup = {
            "projection_s": t1 - t0, "spectra_s": t2 - t1, "near_s": t3 - t2,
            "near_detail": dict(self.near.timings), "grid": self.grid.describe(),
            "grid_media": list(self.grid_media),
            "interior_decay": interior_decay(media, options.near_cells * mesh.spacing_um),
            "preconditioner_s": 0.0 if self.preconditioner is None else self.preconditioner.seconds,
            "preconditioner_fill": 0.0 if self.preconditioner is None else
            self.preconditioner.factor_nnz / self.preconditioner.nnz,
            "static_tables_reused": static_reused,
        }
        self.setup_s = time.perf_counter() - t0
        self._grid_farfields: dict = {}
        logger.info("AIM operator: %s; near %d offsets, %.1f MB; set-up %.1f s", self.grid.describe(),
                    len(self.pattern.same) * 2 + len(self.pattern.cross), self.near.bytes() / 2**20, self.setup_s)

    @staticmethod
    def _exact_cells(options: AIMOptions) -> float | None:
        """Radius (cells) of the exact near entries the preconditioner is built from (None: none)."""
        return {"near": options.preconditioner_cells, "local": options.local_cells}.get(options.preconditioner)

    def matvec(self, x: np.ndarray) -> np.ndarray:
        """Z x for x (P, 2N_b) or (2N_b,) on the device."""
        import pyopencl as cl

        single = np.ndim(x) == 1
        x = np.ascontiguousarray(np.atleast_2d(x), dtype=self.dtype)
        if len(x) not in PACKED_BATCHES:
            return np.concatenate([self.matvec(x[c]) for c in batch_chunks(len(x))])
        ctx = self.ctx
        y = np.zeros_like(x)
        x_buf = ctx.to_device(x)
        y_buf = ctx.to_device(y, writable=True)
        t0 = time.perf_counter()
        self.near.apply(ctx, x_buf, y_buf, len(x), self.precision)
        ctx.queue.finish()
        self.base.timings["near_s"] = self.base.timings.get("near_s", 0.0) + time.perf_counter() - t0
        self.base.apply(x, y_buf)
        cl.enqueue_copy(ctx.queue, y, y_buf)
        ctx.queue.finish()
        return y[0] if single else y

    def matvec_numpy(self, x: np.ndarray) -> np.ndarray:
        """NumPy reference of :meth:`matvec`."""
        return self.near.apply_numpy(x) + self.base.apply_numpy(x)

    def solve(self, rhs: np.ndarray, diagnostics: dict | None = None, x0: np.ndarray | None = None) -> KrylovResult:
        """Krylov solve of Z x = b for right-hand sides (P, 2N_b), from the initial guess ``x0``
        (P, 2N_b; least-squares scaled, solver/krylov.py) or zero; returns a KrylovResult (x
        unscaled) and records its figures and the matvec timings so far into ``diagnostics`` (if
        given). Raises KrylovNotConverged (with ``diagnostics``) when the tolerance is missed."""
        o = self.options
        apply = self.matvec if self.ctx is not None else self.matvec_numpy
        pc = self.preconditioner
        before = (getattr(pc, "apply_s", 0.0), getattr(pc, "inner_products", 0))  # this solve's share below
        try:
            if self.preconditioner is not None:
                result = solve(apply, rhs, method=o.solver, tol=o.tolerance, max_iterations=o.max_iterations,
                               restart=o.restart, deflate=o.deflate, x0=x0, preconditioner=self.preconditioner,
                               progress=self.progress)
            else:
                s = symmetric_scaling(self.mesh.n_bases, self.dtype)  # entries 1 and j: S⁻¹ = S̄
                result = solve(lambda Y: s * apply(s * Y), s * rhs, method=o.solver, tol=o.tolerance,
                               max_iterations=o.max_iterations, restart=o.restart, deflate=o.deflate,
                               x0=None if x0 is None else np.conj(s) * x0, progress=self.progress)
                result.x = s * result.x
        finally:
            self.base.release_work()  # the products' arrays: the far field and the next set-up need the memory
            if hasattr(pc, "release"):  # and the preconditioner's work arrays (flat, flat-patch)
                pc.release()
        if diagnostics is not None:
            diagnostics.update(result.diagnostics(), matvec_timings=dict(self.base.timings))
            if pc is not None:
                diagnostics["preconditioner_apply_s"] = pc.apply_s - before[0]
            if hasattr(pc, "inner_products"):  # "flat-patch": this solve's inner products with T
                diagnostics["inner_products"] = pc.inner_products - before[1]
        return result

    def farfield(self, mesh: BEMMesh, x: np.ndarray, grid, rule=None, *, theta_i: float, phi_i: float,
                 incident_power: np.ndarray, diagnostics: dict, beyond: np.ndarray | None = None):
        """The far field of the currents ``x`` on the operator's ``mesh`` from grid point sources by
        chirp-z transforms (farfield.py), plus the radiation integrals ``beyond`` (P, 6, res, res)
        of currents off the mesh (a flat continuation's); ``rule`` is not used (the dense
        operator's direct sum needs it)."""
        if mesh is not self.mesh:
            raise ValueError("the AIM far field radiates the operator's own mesh")
        return self._grid_farfield(grid).farfield(x, theta_i=theta_i, phi_i=phi_i, incident_power=incident_power,
                                                  diagnostics=diagnostics, beyond=beyond)

    def _grid_farfield(self, grid) -> GridFarField:
        """The far-field transform of the mesh onto ``grid``, kept per output resolution. With
        ``farfield_sources = "operator"`` the point sources are the operator's own exterior-medium
        projection (no second projection is built or held); with "matched", or when the operator's
        projection is not far-field matched at k₁, a grid of its own matched on the upper hemisphere."""
        if grid.resolution not in self._grid_farfields:
            o = self.options
            projection = None
            if o.farfield_sources == "operator" and self.grid_part is not None:
                projection = self.grid_part.exterior_projection(self.media)
            self._grid_farfields[grid.resolution] = GridFarField(
                self.mesh, self.media, grid, projection=projection, grid_options=GridOptions(stencil=o.farfield_stencil),
                directions=o.farfield_directions or None, regularization=o.farfield_regularization)
        return self._grid_farfields[grid.resolution]

    def diagnostics(self) -> dict:
        """Set-up figures of the operator (for the run's diagnostics)."""
        return {"setup_s": self.setup_s, "aim_setup": self.setup, "near_bytes": self.near.bytes(),
                "near_bytes_per_unknown": self.near.bytes() / self.mesh.n_unknowns,
                "operator_bytes": self.bytes(), "aim_options": asdict(self.options)}

    def bytes(self) -> int:
        extra = 0 if self.preconditioner is None else self.preconditioner.bytes()
        kept = 0 if self.static_tables is None else self.static_tables.bytes()
        return self.near.bytes() + self.base.bytes() + extra + kept
