"""The dense path: assemble Z, LU-factorize it once, solve both polarizations, far field.

:class:`DenseBEM` holds the factorized operator of one surface, wavelength and material; every
incident direction and both polarizations reuse it (only the right-hand sides change).
:func:`bem_farfield` is the one-shot entry point used by the model registry.

Memory: Z is (4N(N−1))² complex128. The dense path refuses, with the unknown count and the bytes
it would need, problems that do not fit (:class:`DenseTooLarge`); :func:`estimate_dense` gives
the same figures for planning. The residual ‖Zx − b‖/‖b‖ of each solve is computed with a copy
of Z when memory allows, otherwise by re-assembling Z block by block (``residual`` option).
"""

from __future__ import annotations

import logging
import time

import numpy as np
import scipy.linalg

from wavebrdf.solver.bem3d.assembly import assemble_dense, dense_blocks
from wavebrdf.solver.bem3d.checks import (
    RESIDUAL,
    SolverWarning,
    check_material,
    check_resolution,
    emit,
)
from wavebrdf.solver.bem3d.elements import ElementIntegrals
from wavebrdf.solver.bem3d.excitation import SurfaceRule, beam_excitation, power_into_material
from wavebrdf.solver.bem3d.farfield import farfield_on_grid, radiated_fields, radiated_power
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import BEMMesh
from wavebrdf.solver.bem3d.quadrature import QuadratureOptions
from wavebrdf.solver.farfield import FarField, HemisphereGrid
from wavebrdf.solver.resources import meminfo_bytes, peak_memory_mb
from wavebrdf.solver.surface import HeightField

logger = logging.getLogger(__name__)

__all__ = ["DenseBEM", "DenseTooLarge", "bem_farfield", "estimate_dense"]

WORKSPACE_BYTES = 512 * 2**20  # tables, points, buffers besides Z
MEMORY_FRACTION = 0.85  # of MemAvailable usable by default
RESIDUAL_MODES = ("auto", "copy", "reassemble", "none")


class DenseTooLarge(MemoryError):
    """The dense matrix does not fit; the message names the unknowns and the memory needed."""


def _cells(surface_or_cells) -> int:
    if isinstance(surface_or_cells, HeightField):
        return surface_or_cells.cells
    cells = int(surface_or_cells)
    if cells < 2:
        raise ValueError(f"cells must be >= 2, got {surface_or_cells!r}")
    return cells


def estimate_dense(surface_or_cells, *, residual: str = "auto", memory_limit_bytes: float | None = None) -> dict:
    """Unknowns, bytes and flops of the dense path for a surface (or its cell count N).

    Returns ``unknowns``, ``matrix_bytes`` (one Z), ``bytes`` (peak: Z, its copy for the residual
    when ``residual`` is "copy" or fits under "auto", and workspace), ``lu_flops`` (8n³/3 real),
    ``limit_bytes`` and ``fits``.
    """
    if residual not in RESIDUAL_MODES:
        raise ValueError(f"residual must be one of {RESIDUAL_MODES}, got {residual!r}")
    n = _cells(surface_or_cells)
    unknowns = 4 * n * (n - 1)
    matrix = 16.0 * unknowns**2
    limit = float(memory_limit_bytes) if memory_limit_bytes is not None else MEMORY_FRACTION * meminfo_bytes("MemAvailable")
    with_copy = 2 * matrix + WORKSPACE_BYTES
    copy = residual == "copy" or (residual == "auto" and with_copy <= limit)
    peak = (2 * matrix if copy else matrix) + WORKSPACE_BYTES
    return {
        "unknowns": unknowns,
        "matrix_bytes": matrix,
        "bytes": peak,
        "residual_copy": copy,
        "lu_flops": 8.0 / 3.0 * unknowns**3,
        "limit_bytes": limit,
        "fits": peak <= limit,
    }


def _gib(x: float) -> str:
    return f"{x / 2**30:.2f} GiB"


class DenseBEM:
    """Assembled and LU-factorized PMCHWT operator of one surface, wavelength and material.

    Parameters: ``ctx`` (ComputeContext, or None for the NumPy reference path on tiny meshes),
    ``surface`` (HeightField), ``wavelength_um``, ``index`` (n − jκ), ``exterior_index``,
    ``quadrature`` (QuadratureOptions or a mapping), ``z_reference`` (height subtracted from the
    surface, default its mean), ``residual`` ("auto" | "copy" | "reassemble" | "none"),
    ``memory_limit_bytes`` (default 85% of MemAvailable), ``progress`` (callable(stage, fraction)).
    """

    def __init__(self, ctx, surface: HeightField, wavelength_um: float, index: complex, *,
                 exterior_index: float = 1.0, quadrature=None, z_reference: float | None = None,
                 residual: str = "auto", memory_limit_bytes: float | None = None, progress=None,
                 exploit_symmetry: bool = True):
        self.ctx = ctx
        self.media = Media(wavelength_um, index, exterior_index)
        self.mesh = BEMMesh(surface, z_reference)
        if not isinstance(quadrature, QuadratureOptions):
            quadrature = QuadratureOptions.from_mapping(quadrature)
        self.options = quadrature
        self.progress = progress or (lambda stage, fraction: None)
        self.diagnostics: dict = {"model": "bem", "method": "dense", "warnings": []}
        est = estimate_dense(surface, residual=residual, memory_limit_bytes=memory_limit_bytes)
        if not est["fits"]:
            raise DenseTooLarge(
                f"dense BEM of a {surface.cells}x{surface.cells}-cell patch has {est['unknowns']} unknowns: "
                f"Z alone needs {_gib(est['matrix_bytes'])} (complex128, {est['unknowns']}² entries), "
                f"{_gib(est['bytes'])} in all, but only {_gib(est['limit_bytes'])} is usable here; "
                "use a smaller patch or a coarser mesh, or the AIM method"
            )
        check_material(self.media, surface.size_um, self.diagnostics)
        check_resolution(self.media, surface.spacing_um, self.diagnostics)
        self.residual_mode = "copy" if est["residual_copy"] else ("none" if residual == "none" else "reassemble")
        self.integrals = ElementIntegrals(self.mesh, self.options, ctx)
        self.progress("assembly", 0.0)
        Z, report = assemble_dense(ctx, self.mesh, self.media, self.integrals, exploit_symmetry=exploit_symmetry,
                                   ordering="blocked")
        self.unknown_order = report.unknown_order  # Z is held in the blocked ordering (assembly.py)
        if not np.all(np.isfinite(Z)):
            raise FloatingPointError("the assembled BEM matrix contains NaN/inf (check the geometry and index)")
        self.progress("factorization", 0.0)
        self.matrix = Z.copy() if self.residual_mode == "copy" else None
        t0 = time.perf_counter()
        self.lu = scipy.linalg.lu_factor(Z, overwrite_a=True, check_finite=False)
        self.diagnostics.update(
            unknowns=self.mesh.n_unknowns,
            cells=self.mesh.cells,
            spacing_um=self.mesh.spacing_um,
            matrix_bytes=est["matrix_bytes"],
            assembly_s=report.seconds,
            assembly_detail={"table_reuse": report.table_reuse, "blocks": report.blocks,
                             "element_pairs": report.element_pairs, **report.timings, **report.counts},
            factorization_s=time.perf_counter() - t0,
            quadrature=self.options.__dict__.copy(),
            device=None if ctx is None else ctx.describe(),
            index=complex(self.media.index),
        )
        self.progress("factorization", 1.0)

    # ------------------------------------------------------------------------------------------
    def solve(self, rhs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Solutions x (P, n) of Z x = b for right-hand sides ``rhs`` (P, n) and relative residuals."""
        rhs = np.atleast_2d(rhs)
        b = rhs[:, self.unknown_order]  # documented → blocked ordering
        xb = scipy.linalg.lu_solve(self.lu, b.T, check_finite=False).T
        x = np.empty_like(xb)
        x[:, self.unknown_order] = xb
        if self.residual_mode == "copy":
            r = xb @ self.matrix.T - b
        elif self.residual_mode == "reassemble":
            r = self._streamed_product(xb) - b
        else:
            return x, np.full(len(rhs), np.nan)
        return x, np.linalg.norm(r, axis=1) / np.linalg.norm(rhs, axis=1)

    def _streamed_product(self, x: np.ndarray) -> np.ndarray:
        """Z x in the blocked ordering by re-assembling Z in blocks (no stored matrix)."""
        nb = self.mesh.n_bases
        y = np.zeros_like(x)
        blocks = dense_blocks(self.ctx, self.mesh, self.media, self.integrals)
        off = next(blocks)[0].offsets
        for _, i, j, ee, mm, em in blocks:
            parts = [(slice(off[i], off[i + 1]), slice(off[j], off[j + 1]), ee, mm, em)]
            if i != j:
                parts.append((parts[0][1], parts[0][0], ee.T, mm.T, em.T))
            for r, c, e, m, k in parts:
                xj, xm = x[:, c], x[:, nb + c.start : nb + c.stop]
                y[:, r] += xj @ e.T + xm @ k.T
                y[:, nb + r.start : nb + r.stop] += xj @ k.T + xm @ m.T
        return y

    # ------------------------------------------------------------------------------------------
    def farfield(self, theta_i: float, phi_i: float, grid: HemisphereGrid, *, waist_um: float | None,
                 beam: str = "exact", focus_um=(0.0, 0.0)) -> FarField:
        """Far field for incidence (θ_i, φ_i) (toward the light) with the named beam."""
        t0 = time.perf_counter()
        diag = {k: v for k, v in self.diagnostics.items() if k != "warnings"}
        diag["warnings"] = list(self.diagnostics["warnings"])
        excitation = beam_excitation(self.mesh, self.media, theta_i, phi_i, waist_um=waist_um, beam=beam,
                                     focus_um=focus_um, rhs_order=self.options.rhs_order, diagnostics=diag)
        inc, power = excitation.beam, excitation.incident_power
        x, residual = self.solve(excitation.rhs)
        t_solve = time.perf_counter()
        if np.any(residual > RESIDUAL):
            emit(diag, SolverWarning, f"relative residual {residual} of the LU solve exceeds {RESIDUAL:g}")
        ff_rule = SurfaceRule.build(self.mesh, self.options.farfield_order)
        ff = farfield_on_grid(self.ctx, self.mesh, self.media, x, grid, ff_rule,
                              theta_i=theta_i, phi_i=phi_i, incident_power=power, diagnostics=diag)
        into = power_into_material(self.mesh, x, ff_rule)
        reflected = radiated_power(self.ctx, self.mesh, self.media, x, ff_rule)
        if not (np.all(np.isfinite(ff.E)) and np.all(np.isfinite(ff.H))):
            raise FloatingPointError("BEM far field contains NaN/inf")
        ff.diagnostics.update(
            beam=beam,
            waist_um=waist_um,
            residual=residual,
            solve_s=t_solve - t0,
            farfield_s=time.perf_counter() - t_solve,
            into_material_fraction=into / power,
            reflected_fraction=reflected / power,
            peak_memory_bytes=peak_memory_mb() * 2**20,
        )
        if beam == "exact":
            ff.diagnostics["beam_reflectance"] = inc.reflectance(self.media.index)
            ff.diagnostics["beam_plane_waves"] = len(inc.plane_waves["kvec"])
        return ff

    def brdf_at(self, theta_i: float, phi_i: float, directions: np.ndarray, *, waist_um: float | None,
                beam: str = "exact", focus_um=(0.0, 0.0)) -> np.ndarray:
        """BRDF (sr⁻¹) per polarization (s, p) at arbitrary outgoing unit ``directions`` (M, 3)."""
        inc, x, _ = self.solution(theta_i, phi_i, waist_um=waist_um, beam=beam, focus_um=focus_um)
        directions = np.atleast_2d(np.asarray(directions, dtype=float))
        rule = SurfaceRule.build(self.mesh, self.options.farfield_order)
        E, H = radiated_fields(self.ctx, self.mesh, self.media, x, directions, rule)
        intensity = np.linalg.norm(0.5 * np.real(np.cross(E, np.conj(H))), axis=-1)
        power = inc.incident_power(self.mesh.surface.size_um)
        return intensity / (power[:, None] * directions[None, :, 2])

    def solution(self, theta_i: float, phi_i: float, *, waist_um: float | None, beam: str = "exact",
                 focus_um=(0.0, 0.0)):
        """(beam, x (2, n), residual (2,)) without the far field (for custom post-processing)."""
        excitation = beam_excitation(self.mesh, self.media, theta_i, phi_i, waist_um=waist_um, beam=beam,
                                     focus_um=focus_um, rhs_order=self.options.rhs_order)
        inc = excitation.beam
        x, residual = self.solve(excitation.rhs)
        return inc, x, residual


def bem_farfield(ctx, surface: HeightField, wavelength_um: float, index: complex, theta_i: float, phi_i: float,
                 waist_um: float | None, grid: HemisphereGrid, *, exterior_index: float = 1.0, beam: str = "exact",
                 method: str = "dense", quadrature=None, z_reference: float | None = None,
                 focus_um=(0.0, 0.0), residual: str = "auto", memory_limit_bytes: float | None = None,
                 progress=None) -> FarField:
    """Full-wave BEM far field of ``surface`` (model "bem"); angles in radians, lengths in µm.

    ``method`` "dense" (the only one so far). ``diagnostics`` of the result: unknowns, residual
    per polarization, assembly/factorization/solve/far-field times, peak memory, warnings, the
    fraction of incident power entering the material, and for the exact beam its flat-interface
    reflectance.
    """
    if method != "dense":
        raise ValueError(f"bem method must be 'dense' (AIM is not available yet), got {method!r}")
    solver = DenseBEM(ctx, surface, wavelength_um, index, exterior_index=exterior_index, quadrature=quadrature,
                      z_reference=z_reference, residual=residual, memory_limit_bytes=memory_limit_bytes,
                      progress=progress)
    return solver.farfield(theta_i, phi_i, grid, waist_um=waist_um, beam=beam, focus_um=focus_um)
