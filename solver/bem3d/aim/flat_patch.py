"""The flat patch's operator solved by a few inner GMRES steps, as the preconditioner of a
flexible GMRES on the AIM operator (``preconditioner = "flat-patch"``).

The damped circulant (flat_circulant.py) is the inverse of the flat interface on a torus; it
misses the patch's border and, damped, the guided waves' reach. The flat *patch* of the solve's
lattice, media and wavelength has the operator T, block Toeplitz: T x is the 2-D convolution of
the four rooftop fields [J_h, J_v, M̃_h, M̃_v] with the undamped 4 × 4 kernel at every lattice
offset of the patch (|Δx|, |Δy| ≤ N − 1), so on a torus of ≥ 2N − 1 sites per side it is exact by
2-D FFTs (no offset wraps). T⁻¹ carries what slows the AIM solve of a gently rough surface: the
coupling along the mean plane (a metal's surface plasmon), border included. The preconditioner

    M r = C u_k,    u_k: ``steps`` GMRES steps on (T C) u = r from zero     (C: the damped circulant)

is not a fixed linear map (GMRES's iterate depends on r nonlinearly), so the outer solve is FGMRES
(solver/krylov.py). Measured in docs/aim.md ("The flat patch's inverse by an inner solve").

Set-up: T's kernel (flat_circulant.flat_kernel at radius N − 1: the entries of one rooftop of each
orientation of a flat lattice of 2N cells with every other rooftop, ~16 N² pair entries) and its
16 FFTs, plus the damped circulant. Memory: 8 complex64 per point of T's torus (the J–M̃ blocks of
a flat lattice are zero) and the circulant's; per application, ``steps`` GMRES vectors of the
patch per right-hand side and the torus fields. Everything in complex64: it only steers the solve.
"""

from __future__ import annotations

import logging
import time

import numpy as np
import scipy.fft

from wavebrdf.solver.bem3d.aim.flat_circulant import (FLAT_DAMPING, BlockSpectrum, FlatCirculantPreconditioner,
                                                      TorusPlacement, flat_kernel)
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import BEMMesh
from wavebrdf.solver.krylov import gmres_steps
from wavebrdf.solver.opencl import fft_workers

logger = logging.getLogger(__name__)

__all__ = ["FLAT_INNER_STEPS", "TOEPLITZ_SETUP_BYTES_PER_POINT", "FlatPatchOperator", "FlatPatchPreconditioner", "toeplitz_torus_side"]

FLAT_INNER_STEPS = 16  # inner steps: 10 AIM products at 101 760 and 261 120 unknowns (docs/aim.md)
# T's set-up peak per point of its torus: the kernel in complex128 (256 B), its spectrum (256 B) and
# the 8 nonzero blocks kept in complex64 (64 B)
TOEPLITZ_SETUP_BYTES_PER_POINT = 576


def toeplitz_torus_side(cells: int) -> int:
    """Sites per side of the torus on which the flat patch's block-Toeplitz operator is an exact
    circular convolution: every offset within the patch, ±(N − 1), on its own site (≥ 2N − 1)."""
    return scipy.fft.next_fast_len(2 * cells - 1)


class FlatPatchOperator:
    """T X for X (P, 2N_b): the PMCHWT operator of the flat patch of ``mesh``'s lattice (its
    heights ignored), ``media`` and wavelength, by 2-D FFTs of its torus, in complex64."""

    def __init__(self, ctx, mesh: BEMMesh, media: Media):
        N = mesh.cells
        side = toeplitz_torus_side(N)
        self.torus = (side, side)
        kernel = flat_kernel(ctx, media, mesh.spacing_um, N - 1, self.torus)
        self.spectrum = BlockSpectrum(scipy.fft.fft2(kernel, axes=(2, 3), workers=fft_workers(), overwrite_x=True))
        del kernel
        self.placement = TorusPlacement(mesh, self.torus)
        self.products = 0

    def bytes(self) -> int:
        return int(self.spectrum.nbytes + self.placement.bytes())

    def release(self) -> None:
        """Free the work arrays kept between products."""
        self.placement.release()
        self.spectrum.release()

    def __call__(self, X: np.ndarray) -> np.ndarray:
        X = np.atleast_2d(X)
        self.products += len(X)
        return self.placement.gather(self.spectrum.convolve(self.placement.scatter(X)), X.dtype)


class FlatPatchPreconditioner:
    """M ≈ Z⁻¹: ``steps`` GMRES steps on the flat patch's operator, preconditioned by the damped
    circulant (module docstring). ``flexible``: the outer solve must be FGMRES.

    ``mesh``, ``media``: the solve's (only the lattice, spacing and media are used). ``ctx``:
    OpenCL context for the kernels' entries (None: NumPy, tiny meshes)."""

    flexible = True

    def __init__(self, ctx, mesh: BEMMesh, media: Media, *, steps: int = FLAT_INNER_STEPS,
                 damping: float = FLAT_DAMPING):
        if isinstance(steps, bool) or int(steps) != steps or steps < 1:
            raise ValueError(f"aim.flat_inner_steps must be an integer >= 1, got {steps!r}")
        t0 = time.perf_counter()
        self.steps = int(steps)
        self.circulant = FlatCirculantPreconditioner(ctx, mesh, media, damping=damping)
        self.operator = FlatPatchOperator(ctx, mesh, media)
        # stored entries, counted as the other preconditioners count theirs (fill 1)
        self.nnz = self.factor_nnz = self.circulant.nnz + self.operator.spectrum.values.size
        self.seconds = time.perf_counter() - t0
        self.apply_s = 0.0
        logger.info("flat-patch preconditioner: %d inner steps, Toeplitz torus %s, circulant torus %s, %.1f MB, %.1f s",
                    self.steps, self.operator.torus, self.circulant.torus, self.bytes() / 2**20, self.seconds)

    def release(self) -> None:
        """Free the work arrays of T and the circulant."""
        self.operator.release()
        self.circulant.release()

    @property
    def inner_products(self) -> int:
        """Products with T so far, per right-hand side summed."""
        return self.operator.products

    def bytes(self) -> int:
        return int(self.circulant.bytes() + self.operator.bytes())

    def __call__(self, X: np.ndarray) -> np.ndarray:
        """M X for X (P, 2N_b) or (2N_b,), in X's precision (the inner steps in complex64)."""
        t0 = time.perf_counter()
        single = np.ndim(X) == 1
        X = np.atleast_2d(X)
        try:
            Y = gmres_steps(self.operator, X.astype(np.complex64), self.steps, preconditioner=self.circulant)
        finally:
            self.release()  # the inner steps' work arrays: held within one application only
        self.apply_s += time.perf_counter() - t0
        Y = Y.astype(np.result_type(X, np.complex64), copy=False)
        return Y[0] if single else Y
