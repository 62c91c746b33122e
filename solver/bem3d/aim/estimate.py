"""Memory and time of an AIM run before it starts (for ``wavebrdf plan``): :func:`estimate_aim`.

The figures are cost models fitted to runs on the 2-core development machine (docs/aim.md);
each helper names what it counts.
"""

from __future__ import annotations

import math

from wavebrdf.solver.bem3d.aim.continuation import FLUX_LEFT
from wavebrdf.solver.bem3d.aim.green import grid_media
from wavebrdf.solver.bem3d.aim.grid import build_grid
from wavebrdf.solver.bem3d.aim.nearfield import NearPattern
from wavebrdf.solver.bem3d.aim.options import AIMOptions
from wavebrdf.solver.bem3d.aim.preconditioner import PRECONDITIONER_OVERLAP, SUPERLU_BYTES, tiles_per_axis
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import BEMMesh
from wavebrdf.solver.surface import HeightField

__all__ = ["estimate_aim"]


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
                 aim=None, directions: int = 1, waist_um: float | None = None) -> dict:
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
