"""2.5D boundary element solver for fibers of arbitrary cross section (fiber.md §1–6).

Per (λ, θ_i): assemble the 4N×4N PMCHWT matrix on the OpenCL device
(:class:`~wavebrdf.solver.fiber.assembly.FiberAssembler`), factor it once on the host
(``scipy.linalg.lu_factor``, complex128), and solve both polarizations and all φ_i as one
block of right-hand sides; then far field and cross sections (:mod:`.farfield`).

Units and conventions: µm, vacuum wavelength, e^{+jωt}, index m = n - jκ, θ_i from the plane
normal to the axis (radians), φ in radians; cross sections per unit length in µm, normalised by
S₀ cosθ_i (fiber.md §6: C = 2a·Q_BH/cosθ_i for a circle). Polarization axis: 0 = "parallel"
(BH case I), 1 = "perpendicular" (BH case II).
"""

from __future__ import annotations

import logging
import time
import warnings
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from wavebrdf.solver.fiber.assembly import (
    BEMQuadrature,
    FiberAssembler,
    fiber_assemble_reference,
    fiber_pair_moments_reference,
)
from wavebrdf.solver.fiber.farfield import (
    absorption_cross_section,
    dcs_dphi,
    extinction_cross_section,
    far_field_pattern,
    sample_scattering,
)
from wavebrdf.solver.fiber.incidence import FiberMedia, fiber_media, rhs_vectors
from wavebrdf.solver.fiber.results import ScatteringResult
from wavebrdf.solver.fiber.shapes import CrossSection, recommended_segments

logger = logging.getLogger(__name__)

__all__ = ["FiberBEM", "FiberMeshWarning", "FiberSolution", "mesh_messages", "solve_fiber"]

MIN_ELEMENTS_PER_WAVELENGTH = 9.5  # fiber.md §4 asks for about 10 per interior wavelength
POWER_BALANCE_WARNING = 1e-2  # |C_ext - C_sca - C_abs|/C_ext above this: mesh too coarse


class FiberMeshWarning(UserWarning):
    """The cross section's mesh is too coarse (elements per wavelength, power balance): said as a
    warning, so that the batch layer keeps it in the dataset's diagnostics (it was only logged)."""


@dataclass
class FiberSolution:
    """The solved system of one (λ, θ_i): solution block and what is needed to post-process it."""

    shape: CrossSection
    media: FiberMedia
    phi_i: np.ndarray
    rhs: np.ndarray  # (4N, 2P), columns (polarization, φ_i)
    x: np.ndarray  # (4N, 2P)
    quadrature: BEMQuadrature
    timings: dict

    def pattern(self, phi_r) -> np.ndarray:
        """U(φ_r) of every column in the transverse basis (φ̂, p̂ × φ̂), shape (R, 2, 2P)."""
        return far_field_pattern(self.shape, self.media, self.x, phi_r, self.quadrature.farfield_points)

    def scattering(self, phi_r=None, bins: int = 360) -> ScatteringResult:
        """dC_s/dφ at point samples ``phi_r`` or, if None, box-averaged over ``bins`` bins, and
        the cross sections (C_sca integrated on the band-limit-resolving grid)."""
        t0 = time.perf_counter()
        npol, nphi = 2, self.phi_i.size
        phi_out, values, c_sca = sample_scattering(
            lambda phi: dcs_dphi(self.media, self.pattern(phi)), self.shape.r_max,
            self.media.wavelength_um, phi_r, bins)
        c_ext = extinction_cross_section(self.media, self.rhs, self.x)
        c_abs = absorption_cross_section(self.shape, self.media, self.x)
        timings = dict(self.timings, farfield_s=time.perf_counter() - t0)
        balance = np.max(np.abs(c_ext - c_sca - c_abs) / np.abs(c_ext))
        if balance > POWER_BALANCE_WARNING:  # the runtime error estimate of fiber.md §6
            warnings.warn(f"fiber BEM power balance error {balance:.1e} at λ = {self.media.wavelength_um:.4g} µm, "
                          f"θ_i = {np.rad2deg(self.media.theta_i):.4g}°: refine the mesh", FiberMeshWarning,
                          stacklevel=2)
        return ScatteringResult(
            wavelength_um=self.media.wavelength_um,
            index=self.media.index,
            theta_i=self.media.theta_i,
            phi_i=self.phi_i,
            phi_r=phi_out,
            dCs_dphi=values.T.reshape(npol, nphi, -1),
            C_ext=c_ext.reshape(npol, nphi),
            C_sca=c_sca.reshape(npol, nphi),
            C_abs=c_abs.reshape(npol, nphi),
            binned=phi_r is None,
            timings=timings,
        )


class FiberBEM:
    """2.5D PMCHWT solver for one cross section on one OpenCL context.

    ``solve`` assembles on the device (``reference=True``: the NumPy/scipy twin instead),
    factors once per (λ, θ_i) and solves 2·len(φ_i) right-hand sides as a block.
    """

    def __init__(self, ctx, shape: CrossSection, quadrature: BEMQuadrature | None = None):
        self.ctx = ctx
        self.shape = shape
        self.quadrature = quadrature or BEMQuadrature()
        self._assembler = None

    @property
    def assembler(self) -> FiberAssembler:
        if self._assembler is None:
            self._assembler = FiberAssembler(self.ctx, self.shape, self.quadrature)
        return self._assembler

    def matrix(self, media: FiberMedia, reference: bool = False) -> np.ndarray:
        """The system matrix (4N×4N complex128) on the device or by the NumPy reference."""
        if reference:
            mom_i, mom_k = fiber_pair_moments_reference(self.shape, media, self.quadrature)
            return fiber_assemble_reference(self.shape, mom_i, mom_k, media)
        return self.assembler.matrix(media)

    def solve(self, wavelength_um: float, index: complex, theta_i: float, phi_i,
              reference: bool = False) -> FiberSolution:
        """Solve for incidence (θ_i, each φ_i) and both polarizations (angles in radians)."""
        media = fiber_media(wavelength_um, index, theta_i)
        phi = np.atleast_1d(np.asarray(phi_i, dtype=float))
        self._check_resolution(media)
        t0 = time.perf_counter()
        z = self.matrix(media, reference=reference)
        t1 = time.perf_counter()
        lu = scipy.linalg.lu_factor(z, overwrite_a=True, check_finite=True)
        t2 = time.perf_counter()
        rhs = rhs_vectors(self.shape, media, phi, self.quadrature.rhs_points)
        x = scipy.linalg.lu_solve(lu, rhs)
        t3 = time.perf_counter()
        timings = {"assembly_s": t1 - t0, "factorization_s": t2 - t1, "solve_s": t3 - t2}
        logger.debug("fiber BEM N=%d λ=%.4g θ=%.4g: %s", self.shape.segments, wavelength_um, theta_i, timings)
        return FiberSolution(self.shape, media, phi, rhs, x, self.quadrature, timings)

    @property
    def r_max(self) -> float:
        return self.shape.r_max

    def width(self, phi) -> np.ndarray:
        """Geometric width C_g (µm) for incidence azimuths ``phi``."""
        return self.shape.width(phi)

    def scattering(self, wavelength_um: float, index: complex, theta_i: float, phi_i=0.0,
                   phi_r=None, bins: int = 360) -> ScatteringResult:
        """Solve and post-process: dC_s/dφ (point samples at ``phi_r`` or ``bins`` box averages)
        and cross sections, both polarizations (the interface shared with :class:`MieFiber`)."""
        return self.solve(wavelength_um, index, theta_i, phi_i).scattering(phi_r, bins)

    def _check_resolution(self, media: FiberMedia) -> None:
        """Warn (FiberMeshWarning) below MIN_ELEMENTS_PER_WAVELENGTH (:func:`mesh_messages`)."""
        for message in mesh_messages(self.shape, media.wavelength_um, media.index):
            warnings.warn(message, FiberMeshWarning, stacklevel=3)


def mesh_messages(shape: CrossSection, wavelength_um: float, index: complex) -> list[str]:
    """What the solve says of a cross section's mesh below about 10 elements per interior
    wavelength λ/|m| (λ in µm; fiber.md §4), with the element count that would do; ``wavebrdf
    plan`` shows it (FiberBEMModel.validity)."""
    interior_wavelength = wavelength_um / abs(index)
    longest = float(shape.lengths.max())
    per_wavelength = interior_wavelength / longest
    if per_wavelength >= MIN_ELEMENTS_PER_WAVELENGTH:
        return []
    elements = len(shape.lengths)
    # 10 per λ/|m| over the perimeter, or the longest element shrunk to λ/(10|m|) where it is longer
    needed = max(recommended_segments(shape, wavelength_um, index, per_wavelength=10.0),
                 int(np.ceil(elements * 10.0 / per_wavelength)))
    return [f"fiber mesh is coarse: {per_wavelength:.1f} elements per interior wavelength (λ/|m| = "
            f"{interior_wavelength:.3g} µm, longest element {longest:.3g} µm); use at least 10: [fiber] segments ≥ "
            f"{needed} (this mesh has {elements} elements)"]


def solve_fiber(ctx, shape: CrossSection, wavelength_um: float, index: complex, theta_i: float,
                phi_i=0.0, phi_r=None, bins: int = 360,
                quadrature: BEMQuadrature | None = None) -> ScatteringResult:
    """One-call fiber BEM: dC_s/dφ and cross sections for (λ, θ_i, φ_i), both polarizations."""
    return FiberBEM(ctx, shape, quadrature).scattering(wavelength_um, index, theta_i, phi_i, phi_r, bins)
