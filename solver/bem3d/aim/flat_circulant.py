"""The flat interface's inverse as a preconditioner of the AIM Krylov solve (``preconditioner = "flat"``).

On a height field of moderate slope most of a solve's products go to long-range coupling along
the mean plane: the waves the flat interface guides (a metal's surface plasmon, grazing fields),
which the local inverses do not see (docs/aim.md: the count grows with L/λ and with how tightly
the plasmon is bound). The flat patch of the same lattice, media and wavelength carries the same
waves, and its operator is translation invariant: Z_flat x is a 2-D convolution of the four
rooftop fields [J_h | J_v | M̃_h | M̃_v] (mesh.py) with a 4 × 4 kernel K(Δx, Δy) of lattice
offsets. On a torus the convolution is block circulant and the 2-D FFT turns it into one 4 × 4
matrix K̂(ξ) per spatial frequency, so its inverse costs two FFTs:

    M x = R F⁻¹ K̂(ξ)⁻¹ F Rᵀ x        (Rᵀ: the patch's rooftops placed in the torus)

The kernel is the flat operator with an artificial loss in the exterior medium,
k₁ → k₁ (1 − jε) (``damping`` ε; the material keeps its index), as a shifted Laplacian damps
the Helmholtz operator. Undamped, the circulant's inverse resonates at the guided waves, which on
the finite patch leave through its border, and it preconditions worse than nothing; damped, the
kernel decays as e^{−ε k₁ r}, so it is needed within ``radius_cells`` only, and a torus of
N + radius cells per side holds the patch without wrapping it onto itself. Measured in
docs/aim.md ("A preconditioner from the flat interface").

Set-up: the entries of one rooftop of each orientation of a damped flat lattice with every
rooftop within the radius (assembly.basis_pair_entries), 16 FFTs and one 4 × 4 inverse per
torus point (a transient of 768 B per torus point while it is inverted). Memory: the 8 nonzero
blocks of the inverse in complex64 per torus point (the J–M̃ blocks of a flat lattice are zero)
and two indices per unknown. Each application: 8 FFTs of the torus per right-hand side, in
complex64 (it only steers the solve).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

import numpy as np
import scipy.fft

from wavebrdf.solver.bem3d.assembly import basis_pair_entries
from wavebrdf.solver.bem3d.elements import ElementIntegrals
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import BEMMesh, near_coords, near_first, near_row
from wavebrdf.solver.opencl import fft_workers
from wavebrdf.solver.surface import generate

logger = logging.getLogger(__name__)

__all__ = ["FLAT_DAMPING", "FLAT_KERNEL_DECAY", "SETUP_BYTES_PER_POINT", "BlockSpectrum", "DampedExterior",
           "FlatCirculantPreconditioner", "TorusPlacement", "flat_kernel", "kernel_radius_cells", "rooftops", "torus_side"]

FLAT_DAMPING = 0.3  # ε of k₁(1 − jε): products on rough aluminium, docs/aim.md
FLAT_KERNEL_DECAY = 1e-3  # the kernel is kept where e^{−ε k₁ r} is above this
MIN_RADIUS_CELLS = 4
KERNEL_CHUNK = 2**16  # target rooftops per call for the kernel's entries: bounds the element tables' memory
SETUP_BYTES_PER_POINT = 768  # complex128 at the set-up's peak: the spectrum, the 4 × 4 inverses and their workspace


@dataclass(frozen=True)
class DampedExterior(Media):
    """``Media`` with the exterior wavenumber k₁ (1 − j ``damping``): the kernel of a
    preconditioner only (no physical medium here is lossy above the surface)."""

    damping: float = 0.0

    def __post_init__(self):
        super().__post_init__()
        if not (math.isfinite(self.damping) and self.damping >= 0):
            raise ValueError(f"aim.flat_damping must be a number >= 0 (0: no loss), got {self.damping!r}")

    @property
    def indices(self) -> tuple[complex, complex]:
        return complex(self.exterior_index, -self.exterior_index * self.damping), self.index


def kernel_radius_cells(media: Media, spacing_um: float, damping: float, cells: int) -> int:
    """Lattice offsets (cells) within which the damped kernel is kept: e^{−ε k₁ r} ≥
    FLAT_KERNEL_DECAY, at least MIN_RADIUS_CELLS, at most the patch (N − 1)."""
    decay_per_um = damping * media.k0 * media.exterior_index
    radius = math.log(1.0 / FLAT_KERNEL_DECAY) / (decay_per_um * spacing_um) if decay_per_um > 0 else float(cells)
    return int(min(max(math.ceil(radius), MIN_RADIUS_CELLS), cells - 1))


def torus_side(cells: int, radius_cells: int) -> int:
    """Cells per side of the preconditioner's torus: at least N + R, so that no kernel offset
    within R wraps one patch site onto another (a fast FFT length)."""
    return scipy.fft.next_fast_len(cells + radius_cells)


def rooftops(cells: int, orientation: int):
    """(x, y) lattice coordinates and geometric indices of the rooftops of one orientation."""
    rows = np.arange(cells * (cells - 1))
    x, y = near_coords(orientation, cells, rows)
    return x, y, near_first(orientation, cells) + rows


def flat_kernel(ctx, media: Media, spacing_um: float, radius_cells: int, torus: tuple[int, int]) -> np.ndarray:
    """K (4, 4, Mx, My) complex128 of the flat interface of ``media`` on a lattice of spacing d:
    the PMCHWT entry of a target rooftop of field i ([J_h, J_v, M̃_h, M̃_v]) at lattice offset
    (Δx, Δy) from a source rooftop of field j, stored at (Δx mod Mx, Δy mod My), for |Δx|, |Δy| ≤
    ``radius_cells`` (zero beyond)."""
    R = int(radius_cells)
    cells = 2 * R + 2  # a source rooftop at (R, R) of either orientation sees every offset within R
    lattice = BEMMesh(generate("flat", cells=cells, size_um=cells * spacing_um))
    Mx, My = torus
    K = np.zeros((4, 4, Mx, My), dtype=np.complex128)
    targets = [rooftops(cells, o) for o in (0, 1)]
    integrals = ElementIntegrals(lattice, ctx=ctx)
    for oc in (0, 1):
        source = near_first(oc, cells) + int(near_row(oc, cells, R, R))
        for o in (0, 1):
            x, y, g = targets[o]
            dx, dy = x - R, y - R
            keep = (np.abs(dx) <= R) & (np.abs(dy) <= R)
            kept = np.flatnonzero(keep)
            for part in np.array_split(kept, -(-len(kept) // KERNEL_CHUNK)):  # bounded element tables
                ee, mm, em = basis_pair_entries(ctx, lattice, media, g[part], np.full(len(part), source), integrals)
                sites = (dx[part] % Mx, dy[part] % My)
                K[o, oc][sites] = ee
                K[o, 2 + oc][sites] = em
                K[2 + o, oc][sites] = em
                K[2 + o, 2 + oc][sites] = mm
    return K


class TorusPlacement:
    """The patch's rooftops placed in a torus of (Mx, My) lattice sites: the four fields [J_h, J_v,
    M̃_h, M̃_v] of a block of vectors (P, 2N_b) as (P, 4, Mx, My) complex64 (zero off the patch)
    and back. Two indices per unknown. The torus fields live in a buffer kept between calls (a
    solve's many products touch no fresh pages) until :meth:`release`."""

    def __init__(self, mesh: BEMMesh, torus: tuple[int, int]):
        self.torus = tuple(int(m) for m in torus)
        self._fields = None
        if min(self.torus) < mesh.cells:
            raise ValueError(f"a torus of {self.torus} sites cannot hold a patch of {mesh.cells} cells")
        n_b, My = mesh.n_bases, self.torus[1]
        self.fields = []  # (unknown positions, torus sites) per field
        for magnetic in (0, 1):
            for o in (0, 1):
                x, y, g = rooftops(mesh.cells, o)
                self.fields.append((magnetic * n_b + g, x * My + y))

    def bytes(self) -> int:
        return int(sum(u.nbytes + s.nbytes for u, s in self.fields))

    def release(self) -> None:
        """Free the kept torus fields."""
        self._fields = None

    def scatter(self, X: np.ndarray) -> np.ndarray:
        """(P, 4, Mx, My) complex64 of X (P, 2N_b), in the kept buffer (the next scatter overwrites it)."""
        P, (Mx, My) = len(X), self.torus
        if self._fields is None or len(self._fields) != P:
            self._fields = None
            self._fields = np.zeros((P, 4, Mx * My), dtype=np.complex64)
        else:
            self._fields.fill(0)
        fields = self._fields
        for f, (unknowns, sites) in enumerate(self.fields):
            fields[:, f, sites] = X[:, unknowns]
        return fields.reshape(P, 4, Mx, My)

    def gather(self, fields: np.ndarray, dtype) -> np.ndarray:
        """(P, 2N_b) of ``dtype`` (at least complex64) from the patch's sites of ``fields`` (P, 4, Mx, My)."""
        P = len(fields)
        fields = fields.reshape(P, 4, -1)
        Y = np.empty((P, sum(len(u) for u, _ in self.fields)), dtype=np.result_type(dtype, np.complex64))
        for f, (unknowns, sites) in enumerate(self.fields):
            Y[:, unknowns] = fields[:, f, sites]
        return Y


class BlockSpectrum:
    """The nonzero 4 × 4 field blocks of a block-circulant operator's spectrum (4, 4, Mx, My), kept
    in complex64: ``pairs`` [(i, j)] and ``values`` (len(pairs), Mx, My). On a flat lattice the
    J–M̃ coupling of coplanar rooftops vanishes (exactly, and so in the inverse): half the blocks.
    The product's work arrays are kept between calls until :meth:`release`."""

    def __init__(self, spectrum: np.ndarray):
        self._work = None
        self.pairs = [(i, j) for i in range(4) for j in range(4) if np.any(spectrum[i, j])]
        self.values = np.empty((len(self.pairs),) + spectrum.shape[2:], dtype=np.complex64)
        for k, (i, j) in enumerate(self.pairs):
            self.values[k] = spectrum[i, j]

    @property
    def nbytes(self) -> int:
        return int(self.values.nbytes)

    def release(self) -> None:
        """Free the kept work arrays."""
        self._work = None

    def convolve(self, fields: np.ndarray) -> np.ndarray:
        """The block-circulant product on the torus, F⁻¹ (spectrum(ξ) F fields), for ``fields`` (P,
        4, Mx, My) complex64 (overwritten); the result may live in a work array the next call reuses
        (read it before the next call; never pass it back in)."""
        spectra = scipy.fft.fft2(fields, axes=(2, 3), workers=fft_workers(), overwrite_x=True)
        if self._work is None or self._work[0].shape != spectra.shape:
            self._work = None
            self._work = (np.empty_like(spectra), np.empty_like(spectra[:, 0]))
        out, scratch = self._work
        written = set()
        for (i, j), block in zip(self.pairs, self.values):
            if i in written:
                np.multiply(block, spectra[:, j], out=scratch)
                out[:, i] += scratch
            else:
                np.multiply(block, spectra[:, j], out=out[:, i])
                written.add(i)
        for i in set(range(out.shape[1])) - written:
            out[:, i] = 0
        return scipy.fft.ifft2(out, axes=(2, 3), workers=fft_workers(), overwrite_x=True)


class FlatCirculantPreconditioner:
    """M ≈ Z⁻¹ from the damped flat interface on the patch's lattice (module docstring).

    ``mesh``, ``media``: the solve's (only the lattice, the spacing and the media are used, not
    the heights). ``ctx``: OpenCL context for the kernel's entries (None: NumPy, tiny meshes)."""

    def __init__(self, ctx, mesh: BEMMesh, media: Media, *, damping: float = FLAT_DAMPING,
                 radius_cells: int | None = None):
        t0 = time.perf_counter()
        N, d = mesh.cells, mesh.spacing_um
        self.damping = float(damping)
        damped = DampedExterior(media.wavelength_um, media.index, media.exterior_index, damping=self.damping)
        R = kernel_radius_cells(media, d, self.damping, N) if radius_cells is None else int(radius_cells)
        if not 1 <= R < N:
            raise ValueError(f"aim flat preconditioner: radius_cells must be in [1, {N - 1}], got {R!r}")
        self.radius_cells = R
        self.torus = (torus_side(N, R),) * 2
        spectrum = scipy.fft.fft2(flat_kernel(ctx, damped, d, R, self.torus), axes=(2, 3), workers=fft_workers(),
                                  overwrite_x=True)  # (4, 4, Mx, My)
        inverse = np.linalg.inv(np.moveaxis(spectrum, (0, 1), (2, 3)))  # (Mx, My, 4, 4)
        del spectrum
        self.inverse = BlockSpectrum(np.moveaxis(inverse, (2, 3), (0, 1)))
        del inverse
        # stored entries (8 blocks per torus point), as the other preconditioners count theirs: fill 1
        self.nnz = self.factor_nnz = self.inverse.values.size
        self.placement = TorusPlacement(mesh, self.torus)
        self.seconds = time.perf_counter() - t0
        self.apply_s = 0.0
        logger.info("flat preconditioner: damping %g, kernel radius %d cells, torus %s, %.1f MB, %.1f s",
                    self.damping, R, self.torus, self.bytes() / 2**20, self.seconds)

    def bytes(self) -> int:
        return int(self.inverse.nbytes + self.placement.bytes())

    def __call__(self, X: np.ndarray) -> np.ndarray:
        """M X for X (P, 2N_b) or (2N_b,), complex, in X's precision."""
        t0 = time.perf_counter()
        single = np.ndim(X) == 1
        X = np.atleast_2d(X)
        Y = self.placement.gather(self.inverse.convolve(self.placement.scatter(X)), X.dtype)
        self.apply_s += time.perf_counter() - t0
        return Y[0] if single else Y

    def release(self) -> None:
        """Free the work arrays kept between applications."""
        self.placement.release()
        self.inverse.release()
