"""The Adaptive Integral Method: Z x = (B + C) x without the dense matrix (bem3d.md §6–§9).

* B (aim_base.py): far interactions through grid point sources, FFT convolution on the AIM grid
  (aim_grid.py), projections Λ (projection.py), sampled kernels (aim_green.py);
* C (nearfield.py): exact minus grid entries of near pairs, diagonal (offset) storage on the rooftop lattice;
* a Krylov solve (solver/krylov.py) for both polarizations at once, right-preconditioned by the
  sparse LU of the exact near entries within ``preconditioner_cells`` (:class:`NearPreconditioner`);
  without a preconditioner, on the rescaled system S Z S y = S b with S = diag(I, jI)
  (complex-symmetric like Z, but with its spectrum in the right half-plane, which roughly halves
  the GMRES iterations). Both measured in docs/aim.md;
* the far field from grid point sources with chirp-z transforms (fft_farfield.py).

Public entry points: :func:`aim_farfield` (the signature of ``bem_farfield`` plus AIM options),
:class:`AIMBEM` (operator kept for several incident directions), :func:`estimate_aim` (memory
and time before a run), :class:`AIMOptions`.
"""

from __future__ import annotations

import logging
import math
import numbers
import time
from dataclasses import asdict, dataclass, field

import numpy as np
import scipy.sparse.linalg

from wavebrdf.solver.bem3d.aim_base import PACKED_BATCHES, BaseOperator, GridGroup, batch_chunks
from wavebrdf.solver.bem3d.aim_grid import GridOptions, build_grid
from wavebrdf.solver.bem3d.aim_green import DECAY_TOLERANCE, grid_media, interior_decay, kernel_spectra
from wavebrdf.solver.beams import make_beam
from wavebrdf.solver.bem3d.checks import check_material, check_resolution, check_surface_plasmons
from wavebrdf.solver.bem3d.continuation import FLUX_LEFT, FlatContinuation, border_height
from wavebrdf.solver.bem3d.elements import ElementIntegrals
from wavebrdf.solver.bem3d.excitation import SurfaceRule, beam_excitation, power_into_material
from wavebrdf.solver.bem3d.fft_farfield import FARFIELD_STENCIL, GridFarField
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import BEMMesh
from wavebrdf.solver.bem3d.nearfield import NearPattern, assemble_near, near_coords, near_first
from wavebrdf.solver.bem3d.projection import PROJECTIONS, project
from wavebrdf.solver.bem3d.quadrature import QuadratureOptions
from wavebrdf.solver.farfield import FarField, HemisphereGrid
from wavebrdf.solver.krylov import KRYLOV_METHODS, solve
from wavebrdf.solver.resources import peak_memory_mb, release_free_memory
from wavebrdf.solver.surface import HeightField

logger = logging.getLogger(__name__)

__all__ = ["AIM_QUADRATURE", "AIMBEM", "AIMOperator", "AIMOptions", "NearPreconditioner", "aim_farfield",
           "estimate_aim"]

# Element integrals of the near field: looser than the dense default (1e-6, static order 8). The
# dense solver's own study (docs/bem3d.md, rough aluminium) measured a BRDF change of 2e-6 for
# these settings, far below the AIM error (~5e-4), at a third of the cost.
AIM_QUADRATURE = QuadratureOptions(tolerance=1e-4, static_order=5)
PROJECTION_ORDER = 3  # Gauss order per element of the projection integrals (order 4: same AIM error)

PRECONDITIONERS = ("near", "none")
EDGES = ("pinned", "flat")  # AIMOptions.edge
PRECONDITIONER_OVERLAP = 3  # cells added on every side of a preconditioner tile
# resident bytes per factor entry of a complex64 SuperLU factorization: 8 + 4 of value and index,
# and SuperLU's supernodal storage (measured: 14.7 GiB for 7.8·10⁸ entries at 6.4·10⁵ unknowns)
SUPERLU_BYTES = 20.0


@dataclass(frozen=True)
class AIMOptions:
    """Settings of the AIM solver (config table ``[model.aim]``; defaults measured, docs/aim.md).

    near_cells          near-pair radius in cells d (rooftop centres, x-y distance)
    spacing_cells       largest grid spacing Δx = Δy in cells
    max_k_spacing       upper bound on |k_i| Δ of every grid medium (shrinks Δ for dense media)
    z_spacing_ratio     Δz / Δx
    stencil             stencil points (s_x, s_y, s_z); s_z = 0: 1 on flat patches, else 3
    projection          "farfield" (plane-wave matching, one Λ per grid medium) | "moments"
    directions          matching directions (0: 3S on the sphere)
    regularization      Tikhonov weight relative to σ_max of the matching matrix
    interior_decay_tolerance   the interior of a lossy material leaves the grid when
                        max(1, |n₂/n₁|²)·e^{−|Im k₂| r_near} ≤ this
    precision           "double" | "single": kernels and FFTs (near entries are computed in double)
    near_storage        "single" | "double": storage of the near-field correction
    fft                 "auto" | "host" | "vkfft"
    solver              "gmres" | "csym" | "bicgstab"
    tolerance           ‖r‖/‖b‖ of the Krylov solve (checked on the true residual)
    max_iterations      operator products per polarization
    restart             GMRES restart length
    preconditioner      "near" (sparse LU of the exact entries within preconditioner_cells) | "none"
    preconditioner_cells   radius of the preconditioner's pairs (cells)
    preconditioner_tile_cells   side of the preconditioner's LU tiles in cells (0: one LU)
    farfield_stencil, farfield_directions, farfield_regularization   far-field projection
                        (upper hemisphere, its own grid with Δ = 1.6 d)
    edge                "pinned": the currents stop at the patch border (the beam must have
                        decayed there) | "flat": the surface goes on as the flat interface beyond
                        the border, with its closed-form currents (continuation.py; exact beam,
                        border in one plane)
    """

    near_cells: float = 6.0
    spacing_cells: float = 1.6
    max_k_spacing: float = 0.8  # |k|Δ: 1.35 left a +0.5–1.1% albedo bias on flat 20λ patches (docs/aim.md)
    z_spacing_ratio: float = 4.0 / 3.0
    stencil: tuple[int, int, int] = (4, 4, 0)
    projection: str = "farfield"
    directions: int = 0
    regularization: float = 1e-4
    interior_decay_tolerance: float = DECAY_TOLERANCE
    precision: str = "double"
    near_storage: str = "single"
    fft: str = "auto"
    solver: str = "gmres"
    tolerance: float = 1e-4
    max_iterations: int = 3000
    restart: int = 60
    preconditioner: str = "near"
    preconditioner_cells: float = 2.3
    preconditioner_tile_cells: int = 0
    farfield_stencil: tuple[int, int, int] = FARFIELD_STENCIL
    farfield_directions: int = 0
    farfield_regularization: float = 1e-5
    edge: str = "pinned"

    def __post_init__(self):
        if self.edge not in EDGES:
            raise ValueError(f"aim.edge must be one of {EDGES}, got {self.edge!r}")
        if self.projection not in PROJECTIONS:
            raise ValueError(f"aim.projection must be one of {PROJECTIONS}, got {self.projection!r}")
        if self.solver not in KRYLOV_METHODS:
            raise ValueError(f"aim.solver must be one of {KRYLOV_METHODS}, got {self.solver!r}")
        if self.preconditioner not in PRECONDITIONERS:
            raise ValueError(f"aim.preconditioner must be one of {PRECONDITIONERS}, got {self.preconditioner!r}")
        if self.preconditioner == "near" and self.solver == "csym":
            raise ValueError("aim.solver 'csym' cannot use the near preconditioner; set preconditioner = 'none'")
        tile = self.preconditioner_tile_cells
        if isinstance(tile, bool) or not isinstance(tile, numbers.Integral) or tile < 0:
            raise ValueError(f"aim.preconditioner_tile_cells must be an integer >= 0 (0: one LU), got {tile!r}")
        object.__setattr__(self, "preconditioner_tile_cells", int(tile))
        if self.precision not in ("double", "single"):
            raise ValueError(f"aim.precision must be 'double' or 'single', got {self.precision!r}")
        if not (np.isfinite(self.max_k_spacing) and self.max_k_spacing > 0):
            raise ValueError(f"aim.max_k_spacing must be > 0, got {self.max_k_spacing!r}")
        if not (0.5 <= self.z_spacing_ratio <= 4.0):
            raise ValueError(f"aim.z_spacing_ratio must be in [0.5, 4], got {self.z_spacing_ratio!r}")
        if not (0 < self.regularization < 1) or not (0 < self.farfield_regularization < 1):
            raise ValueError("aim.regularization and aim.farfield_regularization must be in (0, 1)")
        object.__setattr__(self, "stencil", tuple(int(s) for s in self.stencil))
        object.__setattr__(self, "farfield_stencil", tuple(int(s) for s in self.farfield_stencil))
        GridOptions(stencil=self.farfield_stencil)  # validates
        GridOptions(self.spacing_cells, self.spacing_cells * self.z_spacing_ratio, self.stencil)  # validates

    @classmethod
    def from_mapping(cls, values: dict | None) -> "AIMOptions":
        """Build from a config table; unknown keys are an error naming them."""
        values = dict(values or {})
        unknown = sorted(set(values) - set(cls.__dataclass_fields__))
        if unknown:
            raise ValueError(f"unknown aim option(s) {unknown}; known: {sorted(cls.__dataclass_fields__)}")
        return cls(**values)

    def grid_spacing_cells(self, media: Media, spacing_um: float, medium_indices) -> float:
        """Δx in cells: spacing_cells, reduced so that |k_i| Δ ≤ max_k_spacing for the grid media."""
        k_max = max(abs(media.wavenumbers[i].real) for i in medium_indices)
        return min(self.spacing_cells, self.max_k_spacing / (k_max * spacing_um))

    def grid_options(self, media: Media, spacing_um: float, medium_indices) -> GridOptions:
        dx = self.grid_spacing_cells(media, spacing_um, medium_indices)
        return GridOptions(dx, dx * self.z_spacing_ratio, self.stencil)


def _symmetric_scaling(n_b: int, dtype) -> np.ndarray:
    """S = diag(I, jI): S Z S keeps Z's symmetry and moves its spectrum into Re λ > 0."""
    s = np.ones(2 * n_b, dtype=dtype)
    s[n_b:] = 1j
    return s


class NearPreconditioner:
    """M(X) ≈ Z⁻¹X from the exact entries A_near of the pairs within the preconditioner radius.

    The sparse LU (SuperLU, minimum-degree ordering of A + Aᵀ) of S A_near S, S = diag(I, jI),
    with diagonal pivots only: S keeps Z complex-symmetric and gives its diagonal blocks the same
    sign, so the diagonal is dominant enough. Kept in complex64: it only steers the iteration.
    M = S (S A S)⁻¹ S.

    ``tile_cells`` > 0 splits the patch into square tiles of about that many cells and factors
    each tile's block, extended by ``overlap_cells`` on every side, on its own (restricted
    additive Schwarz: each tile's solve writes only the unknowns of its own tile). The fill of
    one LU grows with its size (8.9 at 2·10⁴ unknowns, 13.1 at 1.6·10⁵, 16.6 at 6.4·10⁵), so
    tiles keep the memory and time linear in the patch size; measured at 1.6·10⁵ unknowns they
    saved 17–24% of the LU memory for 2.6× the GMRES products (docs/aim.md). 0: one LU of the
    whole patch (the default).

    Measured (docs/aim.md, radius 2.3 cells, ~67 entries per row): fill 8–12 × nnz(A_near) at
    1.6·10⁴–4·10⁴ unknowns, 1.4 s and 9 s, ‖M A x − x‖/‖x‖ = 9e-5 (complex64). Partial pivoting
    (threshold 0.1) pivoted off the diagonal for aluminium at d = λ/8 (fill 29–37, 10× slower);
    SuperLU's incomplete LU was no cheaper and far less accurate (error 0.07 at drop 1e-3; with
    its fill capped at 4 and drop 1e-2, 155: GMRES then stalled).
    """

    def __init__(self, near, tile_cells: int = 0, overlap_cells: int = PRECONDITIONER_OVERLAP):
        t0 = time.perf_counter()
        n_b = near.n_bases
        self.scale = _symmetric_scaling(n_b, np.complex64)
        S = scipy.sparse.diags(self.scale)
        A = (S @ near.exact_sparse(np.complex64) @ S).tocsc()
        self.nnz = A.nnz
        self.tiles = []  # (unknowns of the extended tile, positions of its own unknowns in them, own unknowns, LU)
        self.factor_nnz = 0
        for extended, own in preconditioner_tiles(near.pattern, tile_cells, overlap_cells):
            block = A if len(extended) == A.shape[0] else A[extended][:, extended].tocsc()
            lu = scipy.sparse.linalg.splu(block, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0)
            self.factor_nnz += lu.L.nnz + lu.U.nnz
            self.tiles.append((extended, np.searchsorted(extended, own), own, lu))  # both sorted, own ⊂ extended
        del A
        release_free_memory()
        self.seconds = time.perf_counter() - t0
        self.apply_s = 0.0
        logger.info("near preconditioner: LU of %d entries in %d tile(s), fill %.1f, %.1f s", self.nnz,
                    len(self.tiles), self.factor_nnz / self.nnz, self.seconds)

    def bytes(self) -> int:
        return int(self.factor_nnz * SUPERLU_BYTES)

    def __call__(self, X: np.ndarray) -> np.ndarray:
        t0 = time.perf_counter()
        X = np.atleast_2d(X)
        Xs = np.ascontiguousarray((self.scale * X).T, dtype=np.complex64)  # (n, P)
        if len(self.tiles) == 1:
            Y = self.tiles[0][3].solve(Xs)
        else:
            Y = np.empty_like(Xs)
            for extended, positions, own, lu in self.tiles:
                Y[own] = lu.solve(np.ascontiguousarray(Xs[extended]))[positions]
        Y = self.scale * Y.T
        self.apply_s += time.perf_counter() - t0
        return Y.astype(X.dtype, copy=False)


def tiles_per_axis(cells: int, tile_cells: int) -> int:
    """Preconditioner tiles along each axis of an N-cell patch: 1 (one LU) unless 0 < T < N."""
    return max(1, round(cells / tile_cells)) if 0 < tile_cells < cells else 1


def preconditioner_tiles(pattern: NearPattern, tile_cells: int, overlap_cells: int):
    """(extended, own) unknown indices (sorted) of each preconditioner tile; one tile if tile_cells ≤ 0.

    Rooftops belong to the tile holding their centre (horizontal (x + 1, y + ½), vertical
    (x + ½, y + 1) in cells); the extended tile adds the rooftops within ``overlap_cells``.
    Unknowns are [J | M̃]: rooftop b gives b and b + N_b.
    """
    N, n_b = pattern.cells, 2 * pattern.rows
    per_axis = tiles_per_axis(N, tile_cells)
    if per_axis == 1:
        everything = np.arange(2 * n_b)
        yield everything, everything
        return
    x = np.empty(n_b)
    y = np.empty(n_b)
    for o in (0, 1):
        first = near_first(o, N)
        cx, cy = near_coords(o, N, np.arange(pattern.rows))
        x[first:first + pattern.rows] = cx + (1.0 if o == 0 else 0.5)
        y[first:first + pattern.rows] = cy + (0.5 if o == 0 else 1.0)
    edges = np.linspace(0.0, N, per_axis + 1)
    edges[-1] = np.inf
    for x0, x1 in zip(edges[:-1], edges[1:]):
        for y0, y1 in zip(edges[:-1], edges[1:]):
            own = np.flatnonzero((x >= x0) & (x < x1) & (y >= y0) & (y < y1))
            ext = np.flatnonzero((x >= x0 - overlap_cells) & (x < x1 + overlap_cells)
                                 & (y >= y0 - overlap_cells) & (y < y1 + overlap_cells))
            yield np.concatenate([ext, ext + n_b]), np.concatenate([own, own + n_b])


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
    def build(cls, ctx, mesh: BEMMesh, media: Media, options: AIMOptions) -> "GridPart":
        t0 = time.perf_counter()
        on_grid = grid_media(media, options.near_cells * mesh.spacing_um, options.interior_decay_tolerance)
        grid = build_grid(mesh, options.grid_options(media, mesh.spacing_um, on_grid))
        cdtype = np.complex128 if options.precision == "double" else np.complex64
        if options.projection == "moments":
            groups = [(project(mesh, grid, "moments", order=PROJECTION_ORDER), on_grid)]
        else:
            groups = [(project(mesh, grid, "farfield", k=media.wavenumbers[i].real, order=PROJECTION_ORDER,
                               directions=options.directions or None, regularization=options.regularization), (i,))
                      for i in on_grid]
        t1 = time.perf_counter()
        spectra = kernel_spectra(grid, media, on_grid, dtype=cdtype)
        base = BaseOperator(ctx, mesh, [GridGroup.build(p, spectra, media, m, cdtype) for p, m in groups],
                            precision=options.precision, fft=options.fft)
        return cls(on_grid, grid, groups, base, t1 - t0)


class AIMOperator:
    """Z x ≈ (B + C) x for one mesh, wavelength and material (see the module docstring)."""

    def __init__(self, ctx, mesh: BEMMesh, media: Media, options: AIMOptions | None = None, *,
                 quadrature: QuadratureOptions | None = None, integrals: ElementIntegrals | None = None,
                 progress=None):
        t0 = time.perf_counter()
        self.ctx = ctx
        self.mesh = mesh
        self.media = media
        self.options = options = options or AIMOptions()
        self.precision = options.precision
        self.dtype = np.complex128 if options.precision == "double" else np.complex64
        grid_part = GridPart.build(ctx, mesh, media, options)
        self.grid_media, self.grid, self.base = grid_part.media, grid_part.grid, grid_part.base
        groups = grid_part.groups
        t1, t2 = t0 + grid_part.projection_s, time.perf_counter()
        self.pattern = NearPattern.build(mesh.cells, options.near_cells)
        self.integrals = integrals or ElementIntegrals(mesh, quadrature or AIM_QUADRATURE, ctx)
        precondition = options.preconditioner == "near"
        self.near = assemble_near(ctx, mesh, media, self.pattern, groups, integrals=self.integrals,
                                  storage=options.near_storage, progress=progress,
                                  exact_cells=options.preconditioner_cells if precondition else None)
        if ctx is not None:
            self.near.upload(ctx)
        t3 = time.perf_counter()
        self.preconditioner = NearPreconditioner(self.near, options.preconditioner_tile_cells) if precondition else None
        self.setup = {
            "projection_s": t1 - t0, "spectra_s": t2 - t1, "near_s": t3 - t2,
            "near_detail": dict(self.near.timings), "grid": self.grid.describe(),
            "grid_media": list(self.grid_media),
            "interior_decay": interior_decay(media, options.near_cells * mesh.spacing_um),
            "preconditioner_s": 0.0 if self.preconditioner is None else self.preconditioner.seconds,
            "preconditioner_fill": 0.0 if self.preconditioner is None else
            self.preconditioner.factor_nnz / self.preconditioner.nnz,
        }
        logger.info("AIM operator: %s; near %d offsets, %.1f MB; set-up %.1f s", self.grid.describe(),
                    len(self.pattern.same) * 2 + len(self.pattern.cross), self.near.bytes() / 2**20, t3 - t0)

    @property
    def unknowns(self) -> int:
        return self.mesh.n_unknowns

    def matvec(self, x: np.ndarray) -> np.ndarray:
        """Z x for x (P, 2N_b) or (2N_b,) on the device."""
        import pyopencl as cl

        single = np.ndim(x) == 1
        x = np.ascontiguousarray(np.atleast_2d(x), dtype=self.dtype)
        if len(x) not in PACKED_BATCHES:
            return np.concatenate([self.matvec(x[c]) for c in batch_chunks(len(x))])
        ctx = self.ctx
        mf = cl.mem_flags
        y = np.zeros_like(x)
        x_buf = cl.Buffer(ctx.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=x)
        y_buf = cl.Buffer(ctx.context, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=y)
        t0 = time.perf_counter()
        self.near.apply(ctx, x_buf, y_buf, len(x), self.precision == "double")
        ctx.queue.finish()
        self.base.timings["near_s"] = self.base.timings.get("near_s", 0.0) + time.perf_counter() - t0
        self.base.apply(x, y_buf)
        cl.enqueue_copy(ctx.queue, y, y_buf)
        ctx.queue.finish()
        return y[0] if single else y

    def matvec_numpy(self, x: np.ndarray) -> np.ndarray:
        """NumPy reference of :meth:`matvec`."""
        return self.near.apply_numpy(x) + self.base.apply_numpy(x)

    def solve(self, rhs: np.ndarray, x0: np.ndarray | None = None):
        """Krylov solve of Z x = b for right-hand sides (P, 2N_b); returns a KrylovResult (x unscaled)."""
        o = self.options
        apply = self.matvec if self.ctx is not None else self.matvec_numpy
        if self.preconditioner is not None:
            return solve(apply, rhs, method=o.solver, tol=o.tolerance, max_iterations=o.max_iterations,
                         restart=o.restart, preconditioner=self.preconditioner)
        s = _symmetric_scaling(self.mesh.n_bases, self.dtype)
        result = solve(lambda Y: s * apply(s * Y), s * rhs, method=o.solver, tol=o.tolerance,
                       max_iterations=o.max_iterations, restart=o.restart,
                       x0=None if x0 is None else x0 / s)
        result.x = s * result.x
        return result

    def bytes(self) -> int:
        extra = 0 if self.preconditioner is None else self.preconditioner.bytes()
        return self.near.bytes() + self.base.bytes() + extra


class AIMBEM:
    """AIM operator of one surface, wavelength and material; far fields for any incidence.

    The parameters are those of ``DenseBEM`` (bem3d/dense.py) plus ``aim`` (AIMOptions or a
    mapping).
    """

    def __init__(self, ctx, surface: HeightField, wavelength_um: float, index: complex, *,
                 exterior_index: float = 1.0, quadrature=None, z_reference: float | None = None,
                 aim=None, progress=None):
        if ctx is None:
            raise ValueError("the AIM solver needs an OpenCL context (ctx)")
        self.ctx = ctx
        self.media = Media(wavelength_um, index, exterior_index)
        self.options = aim if isinstance(aim, AIMOptions) else AIMOptions.from_mapping(aim)
        if self.options.edge == "flat" and z_reference is None:
            z_reference = border_height(surface)  # the continuation plane is z = 0
        self.mesh = BEMMesh(surface, z_reference)
        if quadrature is None:
            quadrature = AIM_QUADRATURE
        elif not isinstance(quadrature, QuadratureOptions):
            quadrature = QuadratureOptions.from_mapping(quadrature)
        self.quadrature = quadrature
        self.progress = progress or (lambda stage, fraction: None)
        self.diagnostics: dict = {"model": "bem", "method": "aim", "warnings": []}
        check_material(self.media, surface.size_um, self.diagnostics)
        check_resolution(self.media, surface.spacing_um, self.diagnostics)
        t0 = time.perf_counter()
        self.operator = AIMOperator(ctx, self.mesh, self.media, self.options, quadrature=quadrature,
                                    progress=self.progress)
        self.continuation = None
        if self.options.edge == "flat":
            self.continuation = FlatContinuation(ctx, self.mesh, self.media, self.options, quadrature=quadrature)
            if np.ptp(self.mesh.heights) > 0:
                check_surface_plasmons(self.media, surface.size_um, self.diagnostics)
        self.diagnostics.update(
            unknowns=self.mesh.n_unknowns, cells=self.mesh.cells, spacing_um=self.mesh.spacing_um,
            setup_s=time.perf_counter() - t0, aim_setup=self.operator.setup,
            near_bytes=self.operator.near.bytes(), near_bytes_per_unknown=self.operator.near.bytes() / self.mesh.n_unknowns,
            operator_bytes=self.operator.bytes(), aim_options=asdict(self.options),
            quadrature=self.quadrature.__dict__.copy(), device=ctx.describe(), index=complex(self.media.index),
        )
        self._farfields: dict = {}

    def _grid_farfield(self, grid: HemisphereGrid, mesh: BEMMesh | None = None) -> GridFarField:
        """The far-field transform of ``mesh`` (default the patch's) onto ``grid``, kept (one
        extended mesh at a time: its size follows the beam)."""
        mesh = mesh or self.mesh
        key = (grid.resolution, mesh.cells)
        if key not in self._farfields:
            if mesh is not self.mesh:
                self._farfields = {k: v for k, v in self._farfields.items() if k[1] == self.mesh.cells}
            o = self.options
            self._farfields[key] = GridFarField(
                mesh, self.media, grid, grid_options=GridOptions(stencil=o.farfield_stencil),
                directions=o.farfield_directions or None, regularization=o.farfield_regularization)
        return self._farfields[key]

    def farfield(self, theta_i: float, phi_i: float, grid: HemisphereGrid, *, waist_um: float | None,
                 beam: str = "exact", focus_um=(0.0, 0.0)) -> FarField:
        """Far field for incidence (θ_i, φ_i) (toward the light) with the named beam."""
        t0 = time.perf_counter()
        diag = {k: v for k, v in self.diagnostics.items() if k != "warnings"}
        diag["warnings"] = list(self.diagnostics["warnings"])
        margin = None
        if self.continuation is not None:
            if beam != "exact":
                raise ValueError(f"aim.edge = 'flat' needs illumination.beam = 'exact' (the continued currents "
                                 f"come from its plane waves), got {beam!r}")
            footprint = make_beam(beam, self.media.wavelength_um, theta_i, phi_i, waist_um,
                                  exterior_index=self.media.exterior_index, focus_um=(*focus_um, 0.0),
                                  patch_size_um=self.mesh.surface.size_um)
            margin = self.continuation.margin(footprint)
        extent = None if margin is None else self.mesh.surface.size_um + 2 * margin * self.mesh.spacing_um
        excitation = beam_excitation(self.mesh, self.media, theta_i, phi_i, waist_um=waist_um, beam=beam,
                                     focus_um=focus_um, rhs_order=self.quadrature.rhs_order, diagnostics=diag,
                                     extent_um=extent)
        inc, power, b = excitation.beam, excitation.incident_power, excitation.rhs
        if margin is not None:
            t_fixed = time.perf_counter()
            fixed, field = self.continuation.fixed_currents(inc, margin)
            b = b - field
            diag.update(edge="flat", continuation_cells=margin, continuation_s=time.perf_counter() - t_fixed,
                        extended_unknowns=fixed.shape[1])
        self.progress("solve", 0.0)
        try:
            result = self.operator.solve(b)
        except Exception as exc:  # keep the set-up diagnostics with the failure
            extra = getattr(exc, "diagnostics", None)
            if isinstance(extra, dict):
                extra.update({k: v for k, v in diag.items() if k not in extra and k != "aim_options"})
            raise
        t_solve = time.perf_counter()
        self.progress("far field", 0.0)
        mesh, x = self.mesh, result.x
        if margin is not None:  # the far field of the patch's and the continued currents
            mesh, x = self.continuation.extended_solution(margin, fixed, result.x)
            diag["continuation_bytes"] = self.continuation.bytes()
        ff = self._grid_farfield(grid, mesh).farfield(x, theta_i=theta_i, phi_i=phi_i, incident_power=power,
                                                      diagnostics=diag)
        ff_rule = SurfaceRule.build(self.mesh, self.quadrature.farfield_order)
        into = power_into_material(self.mesh, result.x, ff_rule)  # through the patch only
        if not (np.all(np.isfinite(ff.E)) and np.all(np.isfinite(ff.H))):
            raise FloatingPointError("AIM far field contains NaN/inf")
        ff.diagnostics.update(
            beam=beam, waist_um=waist_um, **result.diagnostics(),
            matvec_timings=dict(self.operator.base.timings),
            farfield_s=time.perf_counter() - t_solve, total_direction_s=time.perf_counter() - t0,
            into_material_fraction=into / power,
            peak_memory_bytes=peak_memory_mb() * 2**20,
        )
        if beam == "exact":
            ff.diagnostics["beam_reflectance"] = inc.reflectance(self.media.index)
        return ff


def aim_farfield(ctx, surface: HeightField, wavelength_um: float, index: complex, theta_i: float, phi_i: float,
                 waist_um: float | None, grid: HemisphereGrid, *, exterior_index: float = 1.0, beam: str = "exact",
                 method: str = "aim", quadrature=None, z_reference: float | None = None, focus_um=(0.0, 0.0),
                 aim=None, progress=None, **ignored) -> FarField:
    """Full-wave BEM far field of ``surface`` by AIM (model "bem", method "aim").

    Same arguments as ``bem_farfield``; ``aim``: AIMOptions or a mapping of them. Raises
    :class:`~wavebrdf.solver.krylov.KrylovNotConverged` (with ``diagnostics``) when the solve
    misses its tolerance: such a result is never returned.
    """
    if method != "aim":
        raise ValueError(f"aim_farfield serves method 'aim', got {method!r}")
    unused = sorted(k for k in ignored if k not in ("residual", "memory_limit_bytes"))
    if unused:
        raise TypeError(f"aim_farfield got unexpected argument(s) {unused}")
    solver = AIMBEM(ctx, surface, wavelength_um, index, exterior_index=exterior_index, quadrature=quadrature,
                    z_reference=z_reference, aim=aim, progress=progress)
    return solver.farfield(theta_i, phi_i, grid, waist_um=waist_um, beam=beam, focus_um=focus_um)


# ---------------------------------------------------------------------------------------------
# Planning


def _continuation_cost(mesh: BEMMesh, options: AIMOptions, waist_um: float | None, near_entry: int, cplx: int,
                       stencil_points: int) -> tuple[float, float, float]:
    """(bytes, set-up seconds, far-field bytes) of the flat continuation (continuation.py): the ring
    operator's near storage and set-up, the extended mesh's grid weights, and the far field of the
    extended mesh (which replaces the patch's)."""
    n, d, L = mesh.cells, mesh.spacing_um, mesh.surface.size_um
    ring = n + 2 * (math.ceil(options.near_cells) + 2)
    waist = waist_um or L / 2.5
    reach = waist * math.sqrt(0.5 * math.log(1.0 / FLUX_LEFT))
    extended = max(ring + 4, math.ceil(2 * reach / d))
    ring_pairs = NearPattern.build(ring, options.near_cells).stored_entries()
    ring_elements = ring**2 * math.pi * (options.near_cells + 1.5) ** 2
    extended_bases = 2 * extended * (extended - 1)
    weights = 2 * cplx * 3 * stencil_points * extended_bases
    farfield = 4300 * 2 * extended_bases
    return ring_pairs * near_entry + weights, 2e-5 * ring_elements + 3e-6 * ring_pairs, farfield


def _preconditioner_cost(cells: int, unknowns: int, options: AIMOptions) -> tuple[float, float]:
    """(peak bytes, seconds) of the near LU: SUPERLU_BYTES per factor entry of every tile, plus
    SuperLU's working memory while one tile is factored (0.06 × its factors). Fill 2.2 ln n − 12.6
    per LU of n unknowns fits 5.6 … 16.6 measured at 4·10³ … 6.4·10⁵ unknowns; time
    1.1e-9 nnz^1.5 per LU fits 42 s and 346–384 s at 1.2·10⁷ and 4.7·10⁷ entries (docs/aim.md)."""
    near_nnz = 4 * NearPattern.build(cells, options.preconditioner_cells).nnz()  # (J, M) × (J, M) blocks
    per_axis = tiles_per_axis(cells, options.preconditioner_tile_cells)
    side = cells if per_axis == 1 else cells / per_axis + 2 * PRECONDITIONER_OVERLAP
    share = (side / cells) ** 2  # of the unknowns and near entries in one (extended) tile
    fill = max(4.0, 2.2 * math.log(max(unknowns * share, 2.0)) - 12.6)
    one_tile = SUPERLU_BYTES * near_nnz * share * fill
    seconds = per_axis**2 * 1.1e-9 * (near_nnz * share) ** 1.5
    return one_tile * per_axis**2 + 0.06 * one_tile, seconds


def estimate_aim(surface: HeightField, wavelength_um: float, index: complex, *, exterior_index: float = 1.0,
                 aim=None, resolution: int = 256, directions: int = 1, waist_um: float | None = None) -> dict:
    """Memory and time of an AIM run before it starts (for ``wavebrdf plan``).

    Returns ``unknowns``, ``near_nnz`` (stored near pairs), ``bytes`` (peak estimate) with its
    parts, ``seconds`` (set-up + ``directions`` × both polarizations) and the grid sizes. The
    time model uses throughputs measured on the 2-core development machine (docs/aim.md) and an
    iteration count growing like the square root of the patch size in wavelengths. With
    ``edge = "flat"`` it adds the continuation (``continuation_bytes``): the ring operator and the
    extended mesh, whose size follows from ``waist_um`` (default L/2.5, a border at 1.25 w).
    """
    options = aim if isinstance(aim, AIMOptions) else AIMOptions.from_mapping(aim)
    media = Media(wavelength_um, index, exterior_index)
    mesh = BEMMesh(surface)
    d = mesh.spacing_um
    gm = grid_media(media, options.near_cells * d, options.interior_decay_tolerance)
    grid = build_grid(mesh, options.grid_options(media, d, gm))
    pattern = NearPattern.build(mesh.cells, options.near_cells)
    n = mesh.n_unknowns
    groups = len(gm) if options.projection == "farfield" else 1
    real = 8 if options.precision == "double" else 4
    cplx = 2 * real
    near_entry = 24 if options.near_storage == "single" else 48
    near_bytes = pattern.stored_entries() * near_entry
    spectra = cplx * grid.padded_points * (len(gm) + 3) * groups
    weights = 2 * cplx * 3 * grid.stencil_size * mesh.n_bases * groups  # by basis and by grid point (aim.cl)
    work = cplx * grid.padded_points * 8 * 2 * 2  # 8 components, 2 right-hand sides, FFT temporaries
    krylov = cplx * n * 2 * (options.restart + 3 if options.solver == "gmres" else 6)
    preconditioner = preconditioner_s = 0.0
    if options.preconditioner == "near":
        preconditioner, preconditioner_s = _preconditioner_cost(mesh.cells, n, options)
    stored_pairs = int(pattern.stored_entries())
    element_pairs = mesh.n_elements * math.pi * (options.near_cells + 1.5) ** 2
    assembly_temp = 600_000 * 1100 * 2  # element tables + staging of one strip
    farfield = 4300 * n  # far-field projection and sums (measured 2.7 GiB at 6.4·10⁵ unknowns)
    continuation = continuation_s = 0.0
    if options.edge == "flat":
        continuation, continuation_s, farfield = _continuation_cost(mesh, options, waist_um, near_entry, cplx,
                                                                     grid.stencil_size * groups)
    total = (near_bytes + spectra + weights + work + krylov + preconditioner + assembly_temp + farfield
             + continuation + 300 * 2**20)
    # time model (seconds), constants from benchmarks/bench_aim.py on the 2-core machine
    fft_points = grid.padded_points * 16 * groups
    matvec_s = 2.5e-8 * fft_points * math.log2(max(grid.padded_points, 2)) / 20 + 4e-9 * stored_pairs * 2
    size_waves = surface.size_um * exterior_index / wavelength_um
    if options.preconditioner == "near":  # measured 7–43 products (docs/aim.md): a generous bound
        iterations = 20 + 6 * math.sqrt(size_waves)
    else:
        iterations = 60 + 25 * math.sqrt(size_waves) * (1 + abs(media.index) / 4)
    setup_s = 2e-5 * element_pairs + 3e-6 * stored_pairs + preconditioner_s + continuation_s
    seconds = setup_s + directions * iterations * matvec_s * 1.1
    return {
        "unknowns": n,
        "near_nnz": stored_pairs,
        "bytes": int(total),
        "near_bytes": int(near_bytes),
        "spectra_bytes": int(spectra),
        "work_bytes": int(work + krylov),
        "preconditioner_bytes": int(preconditioner),
        "continuation_bytes": int(continuation),
        "seconds": float(seconds),
        "iterations_guess": int(iterations),
        "grid": grid.shape,
        "fft": grid.padded,
        "grid_media": gm,
    }
