"""The dense operator: assemble Z, LU-factorize it once, solve any right-hand sides.

:class:`DenseOperator` holds the factorized PMCHWT matrix of one mesh, wavelength and material;
every incident direction and both polarizations reuse it (only the right-hand sides change). The
driver (driver.py, ``method="dense"``) puts it behind the far-field template.

Memory: Z is (4N(N−1))² complex128. The dense path refuses, with the unknown count and the bytes
it would need, problems that do not fit (:class:`DenseTooLarge`); :func:`estimate_dense` gives
the same figures for planning. The residual ‖Zx − b‖/‖b‖ of each solve is computed with a copy
of Z when memory allows, otherwise by re-assembling Z block by block (``residual`` option).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from wavebrdf.solver.bem3d.assembly import assemble_dense, dense_blocks
from wavebrdf.solver.bem3d.checks import RESIDUAL, SolverWarning, emit
from wavebrdf.solver.bem3d.elements import ElementIntegrals
from wavebrdf.solver.bem3d.excitation import SurfaceRule
from wavebrdf.solver.bem3d.farfield import farfield_on_grid, radiated_power
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import BEMMesh
from wavebrdf.solver.bem3d.quadrature import QuadratureOptions
from wavebrdf.solver.resources import meminfo_bytes
from wavebrdf.solver.surface import HeightField

__all__ = ["RESIDUAL_MODES", "DenseOperator", "DenseSolve", "DenseTooLarge", "estimate_dense"]

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


@dataclass
class DenseSolve:
    """Solutions x (P, n) of Z x = b, relative residuals ‖Zx − b‖/‖b‖ (P,) (NaN without a residual)
    and the seconds of the solve (LU substitution and residual)."""

    x: np.ndarray
    residual: np.ndarray
    seconds: float

    def diagnostics(self) -> dict:
        return {"residual": self.residual, "solve_s": self.seconds}


class DenseOperator:
    """Assembled and LU-factorized PMCHWT operator of one mesh, wavelength and material.

    Parameters: ``ctx`` (ComputeContext, or None for the NumPy reference path on tiny meshes),
    ``mesh``, ``media``, ``quadrature`` (QuadratureOptions), ``residual`` ("auto" | "copy" |
    "reassemble" | "none"), ``memory_limit_bytes`` (default 85% of MemAvailable), ``progress``
    (callable(stage, fraction)). Raises :class:`DenseTooLarge` before assembling what does not fit.
    """

    def __init__(self, ctx, mesh: BEMMesh, media: Media, quadrature: QuadratureOptions | None = None, *,
                 residual: str = "auto", memory_limit_bytes: float | None = None, progress=None):
        est = estimate_dense(mesh.surface, residual=residual, memory_limit_bytes=memory_limit_bytes)
        if not est["fits"]:
            raise DenseTooLarge(
                f"dense BEM of a {mesh.cells}x{mesh.cells}-cell patch has {est['unknowns']} unknowns: "
                f"Z alone needs {_gib(est['matrix_bytes'])} (complex128, {est['unknowns']}² entries), "
                f"{_gib(est['bytes'])} in all, but only {_gib(est['limit_bytes'])} is usable here; "
                "use a smaller patch or a coarser mesh, or the AIM method"
            )
        progress = progress or (lambda stage, fraction: None)
        self.ctx, self.mesh, self.media = ctx, mesh, media
        self.residual_mode = "copy" if est["residual_copy"] else ("none" if residual == "none" else "reassemble")
        self.integrals = ElementIntegrals(mesh, quadrature or QuadratureOptions(), ctx)
        progress("assembly", 0.0)
        Z, report = assemble_dense(ctx, mesh, media, self.integrals, ordering="blocked")
        self.unknown_order = report.unknown_order  # Z is held in the blocked ordering (assembly.py)
        if not np.all(np.isfinite(Z)):
            raise FloatingPointError("the assembled BEM matrix contains NaN/inf (check the geometry and index)")
        progress("factorization", 0.0)
        self.matrix = Z.copy() if self.residual_mode == "copy" else None
        t0 = time.perf_counter()
        self.lu = scipy.linalg.lu_factor(Z, overwrite_a=True, check_finite=False)
        self._diagnostics = {
            "matrix_bytes": est["matrix_bytes"],
            "assembly_s": report.seconds,
            "assembly_detail": {"table_reuse": report.table_reuse, "blocks": report.blocks,
                                "element_pairs": report.element_pairs, **report.timings, **report.counts},
            "factorization_s": time.perf_counter() - t0,
        }
        progress("factorization", 1.0)

    def diagnostics(self) -> dict:
        """Set-up figures of the operator (for the run's diagnostics)."""
        return dict(self._diagnostics)

    def solve(self, rhs: np.ndarray, diagnostics: dict | None = None, x0: np.ndarray | None = None) -> DenseSolve:
        """Solve Z x = b for right-hand sides ``rhs`` (P, n); records the residual and the time into
        ``diagnostics`` (if given), with a SolverWarning when a residual exceeds RESIDUAL. ``x0``
        is not used (the LU solve is direct)."""
        t0 = time.perf_counter()
        rhs = np.atleast_2d(rhs)
        b = rhs[:, self.unknown_order]  # documented → blocked ordering
        xb = scipy.linalg.lu_solve(self.lu, b.T, check_finite=False).T
        x = np.empty_like(xb)
        x[:, self.unknown_order] = xb
        if self.residual_mode == "copy":
            residual = np.linalg.norm(xb @ self.matrix.T - b, axis=1) / np.linalg.norm(rhs, axis=1)
        elif self.residual_mode == "reassemble":
            residual = np.linalg.norm(self._streamed_product(xb) - b, axis=1) / np.linalg.norm(rhs, axis=1)
        else:
            residual = np.full(len(rhs), np.nan)
        result = DenseSolve(x, residual, time.perf_counter() - t0)
        if diagnostics is not None:
            if np.any(residual > RESIDUAL):
                emit(diagnostics, SolverWarning, f"relative residual {residual} of the LU solve exceeds {RESIDUAL:g}")
            diagnostics.update(result.diagnostics())
        return result

    def farfield(self, mesh: BEMMesh, x: np.ndarray, grid, rule: SurfaceRule, *, theta_i: float, phi_i: float,
                 incident_power: np.ndarray, diagnostics: dict):
        """The far field of the currents ``x`` on ``mesh`` by the direct quadrature sum over the
        output grid (farfield.py), with the hemisphere-quadrature radiated power as
        ``reflected_fraction`` (cheap at dense sizes)."""
        ff = farfield_on_grid(self.ctx, mesh, self.media, x, grid, rule, theta_i=theta_i, phi_i=phi_i,
                              incident_power=incident_power, diagnostics=diagnostics)
        ff.diagnostics["reflected_fraction"] = radiated_power(self.ctx, mesh, self.media, x, rule) / incident_power
        return ff

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
