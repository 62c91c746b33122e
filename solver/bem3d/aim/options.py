"""Settings of the AIM solver: :class:`AIMOptions` (config table ``[model.aim]``) and the element
quadrature of its near field (:data:`AIM_QUADRATURE`)."""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np

from wavebrdf.solver.bem3d.aim.convolution import FFT_BACKENDS
from wavebrdf.solver.bem3d.aim.farfield import FARFIELD_STENCIL
from wavebrdf.solver.bem3d.aim.flat_circulant import FLAT_DAMPING
from wavebrdf.solver.bem3d.aim.flat_patch import FLAT_INNER_STEPS
from wavebrdf.solver.bem3d.aim.green import DECAY_TOLERANCE
from wavebrdf.solver.bem3d.aim.grid import GridOptions
from wavebrdf.solver.bem3d.aim.projection import PROJECTIONS
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.quadrature import QuadratureOptions
from wavebrdf.solver.krylov import KRYLOV_METHODS
from wavebrdf.solver.precision import PRECISIONS, Precision
from wavebrdf.solver.options import option, parse_options

__all__ = ["AIM_QUADRATURE", "EDGES", "FARFIELD_SOURCES", "PRECONDITIONERS", "AIMOptions"]

# Element integrals of the near field: looser than the dense default (1e-6, static order 8). The
# dense solver's own study (docs/bem3d.md, rough aluminium) measured a BRDF change of 2e-6 for
# these settings, far below the AIM error (~5e-4), at a third of the cost.
AIM_QUADRATURE = QuadratureOptions(tolerance=1e-4, static_order=5)

PRECONDITIONERS = ("near", "local", "flat", "flat-patch", "none")
EDGES = ("pinned", "flat")  # AIMOptions.edge
FARFIELD_SOURCES = ("operator", "matched")  # AIMOptions.farfield_sources


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
    deflate             GMRES-DR: harmonic Ritz vectors kept at each restart (0: plain GMRES(restart);
                        < restart; solver/krylov.py)
    warm_start          true: a solve starts from the previous wavelength's solution of the same
                        surface and incidence in this worker, phase-moved and least-squares
                        scaled (bem3d/warm_start.py); false: from zero (bitwise the same result
                        whatever the task order)
    reuse_setup         true: a worker keeps the wavelength-independent set-up of a patch (the
                        static singular tables of its touching element pairs, 2.3 KB per element)
                        for the patch's next wavelengths; false: each solve computes it again
                        (the planner turns it off where the budget is tight)
    preconditioner      "near" (sparse LU of the exact entries within preconditioner_cells) |
                        "local" (the inverses of local_tile_cells tiles of the entries within local_cells, each
                        extended by one cell: ~1.15 KB per unknown at 4 cells) | "flat" (the inverse
                        of the damped flat interface on the patch's lattice by 2-D FFTs, ~50 B per
                        unknown: flat_circulant.py; measured with restart = 30) | "flat-patch"
                        (flat_inner_steps GMRES steps on the flat patch's exact operator, by
                        FFTs, each preconditioned by that inverse; the outer solve is FGMRES:
                        solver "gmres", deflate 0; flat_patch.py) | "none"
    preconditioner_cells   radius of the preconditioner's pairs (cells)
    preconditioner_tile_cells   side of the preconditioner's LU tiles in cells (0: one LU)
    local_tile_cells    side of the "local" preconditioner's tiles in cells
    local_cells         radius of the "local" preconditioner's pairs (cells)
    flat_damping        ε > 0 of the "flat" preconditioner's exterior k₁(1 − jε) (and of
                        "flat-patch"'s inner one)
    flat_inner_steps    inner GMRES steps of the "flat-patch" preconditioner
    farfield_sources    "operator": the far field's point sources are the operator's own
                        exterior-medium projection (no second projection) | "matched": a grid
                        of their own, matched on the upper hemisphere (the options below)
    farfield_stencil, farfield_directions, farfield_regularization   the "matched" far-field
                        projection (upper hemisphere, its own grid with Δ = 1.6 d)
    edge                "pinned": the currents stop at the patch border (the beam must have
                        decayed there) | "flat": the surface goes on as the flat interface beyond
                        the border, with its closed-form currents (continuation.py; exact beam,
                        border in one plane)
    fit_memory          true: the planner may change precision, near_cells, preconditioner, its
                        tiles and the solver so that the solve fits the memory a task may use
                        ([run] memory_gb or the node, over the tasks at once; budget.py), and
                        says what it chose; false: keep them as given, refused if they do not fit
    fit_speed           true (with fit_memory): settings that fit still give way to ones the
                        planner predicts 25 % faster at the same precision (budget.py
                        SPEED_MARGIN); false: changed only to fit the memory
    """

    near_cells: float = option(6.0, low=0, low_open=True)
    spacing_cells: float = option(1.6, low=0, low_open=True)
    # |k|Δ: 1.35 left a +0.5–1.1% albedo bias on flat 20λ patches (docs/aim.md)
    max_k_spacing: float = option(0.8, low=0, low_open=True)
    z_spacing_ratio: float = option(4.0 / 3.0, low=0.5, high=4.0)
    stencil: tuple[int, int, int] = option((4, 4, 0), length=3, low=0)
    projection: str = option("farfield", choices=PROJECTIONS)
    directions: int = option(0, low=0)
    regularization: float = option(1e-4, low=0, low_open=True, high=1, high_open=True)
    interior_decay_tolerance: float = option(DECAY_TOLERANCE, low=0, low_open=True, high=1, high_open=True)
    precision: Precision = option(Precision.DOUBLE, choices=PRECISIONS, parse=Precision.of)
    near_storage: str = option("single", choices=("single", "double"))
    fft: str = option("auto", choices=FFT_BACKENDS)
    solver: str = option("gmres", choices=KRYLOV_METHODS)
    tolerance: float = option(1e-4, low=0, low_open=True, high=1, high_open=True)
    max_iterations: int = option(3000, low=1)
    restart: int = option(60, low=1)
    deflate: int = option(0, low=0)
    warm_start: bool = option(True)
    reuse_setup: bool = option(True)
    preconditioner: str = option("near", choices=PRECONDITIONERS)
    preconditioner_cells: float = option(2.3, low=0, low_open=True)
    preconditioner_tile_cells: int = option(0, low=0)
    local_tile_cells: int = option(4, low=1)
    # measured at 101 760 unknowns: products 122 / 111 / 118 at radius 2.3 / 3.5 / 5 (docs/aim.md)
    local_cells: float = option(3.5, low=0, low_open=True)
    flat_damping: float = option(FLAT_DAMPING, low=0, low_open=True, high=10)
    flat_inner_steps: int = option(FLAT_INNER_STEPS, low=1)
    farfield_sources: str = option("operator", choices=FARFIELD_SOURCES)
    farfield_stencil: tuple[int, int, int] = option(FARFIELD_STENCIL, length=3, low=0)
    farfield_directions: int = option(0, low=0)
    farfield_regularization: float = option(1e-5, low=0, low_open=True, high=1, high_open=True)
    edge: str = option("pinned", choices=EDGES)
    fit_memory: bool = option(True)
    fit_speed: bool = option(True)

    def __post_init__(self):
        if self.edge not in EDGES:
            raise ValueError(f"aim.edge must be one of {EDGES}, got {self.edge!r}")
        if self.projection not in PROJECTIONS:
            raise ValueError(f"aim.projection must be one of {PROJECTIONS}, got {self.projection!r}")
        if self.solver not in KRYLOV_METHODS:
            raise ValueError(f"aim.solver must be one of {KRYLOV_METHODS}, got {self.solver!r}")
        if self.preconditioner not in PRECONDITIONERS:
            raise ValueError(f"aim.preconditioner must be one of {PRECONDITIONERS}, got {self.preconditioner!r}")
        if self.deflate and (self.solver != "gmres" or self.deflate >= self.restart):
            raise ValueError(f"aim.deflate must be 0 or, with solver 'gmres', below restart = {self.restart}; "
                             f"got {self.deflate!r} with solver {self.solver!r}")
        if self.preconditioner == "flat-patch" and (self.solver != "gmres" or self.deflate):
            raise ValueError(f"aim.preconditioner 'flat-patch' is an inner solve: it needs solver 'gmres' with "
                             f"deflate = 0 (FGMRES); got solver {self.solver!r}, deflate {self.deflate!r}")
        if self.preconditioner != "none" and self.solver == "csym":
            raise ValueError(f"aim.solver 'csym' cannot use the {self.preconditioner!r} preconditioner; "
                             "set preconditioner = 'none'")
        tile = self.preconditioner_tile_cells
        if isinstance(tile, bool) or not isinstance(tile, numbers.Integral) or tile < 0:
            raise ValueError(f"aim.preconditioner_tile_cells must be an integer >= 0 (0: one LU), got {tile!r}")
        object.__setattr__(self, "preconditioner_tile_cells", int(tile))
        if self.precision not in PRECISIONS:
            raise ValueError(f"aim.precision must be one of {PRECISIONS}, got {self.precision!r}")
        object.__setattr__(self, "precision", Precision(self.precision))  # given as its word: typed once
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
        """Build from a config table (types, ranges and choices checked, unknown keys refused;
        :class:`~wavebrdf.solver.options.OptionsError` names the key and the value)."""
        return parse_options(cls, values, "model.aim")

    def grid_spacing_cells(self, media: Media, spacing_um: float, medium_indices) -> float:
        """Δx in cells: spacing_cells, reduced so that |k_i| Δ ≤ max_k_spacing for the grid media."""
        k_max = max(abs(media.wavenumbers[i].real) for i in medium_indices)
        return min(self.spacing_cells, self.max_k_spacing / (k_max * spacing_um))

    def grid_options(self, media: Media, spacing_um: float, medium_indices) -> GridOptions:
        dx = self.grid_spacing_cells(media, spacing_um, medium_indices)
        return GridOptions(dx, dx * self.z_spacing_ratio, self.stencil)
