"""Memory and time of an AIM run before it starts (for ``wavebrdf plan``): :func:`estimate_aim`.

The figures are cost models whose constants are fitted to measured runs: they are the rows of
``solver/data/aim_cost.csv`` (:data:`COST`), each with its meaning, unit and the run it came from
(command, commit, machine); ``tools/refit_aim_cost.py`` measures the set-up and product constants
again and rewrites their rows (docs/aim.md, "Refitting the planner"). Each helper names what it
counts.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from wavebrdf.solver.bem3d.aim.continuation import FLUX_LEFT
from wavebrdf.solver.bem3d.aim.flat_circulant import SETUP_BYTES_PER_POINT, kernel_radius_cells, torus_side
from wavebrdf.solver.bem3d.aim.flat_patch import TOEPLITZ_SETUP_BYTES_PER_POINT, toeplitz_torus_side
from wavebrdf.solver.bem3d.aim.green import grid_media
from wavebrdf.solver.bem3d.aim.grid import build_grid
from wavebrdf.solver.bem3d.aim.near_tables import REPEATING_STORE_BYTES, RepeatingTables
from wavebrdf.solver.bem3d.aim.nearfield import NearPattern
from wavebrdf.solver.bem3d.aim.options import AIMOptions
from wavebrdf.solver.bem3d.aim.preconditioner import (LOCAL_OVERLAP, PRECONDITIONER_OVERLAP, SUPERLU_BYTES,
                                                       local_inverse_entries, tiles_per_axis)
from wavebrdf.solver.bem3d.elements import STATIC_BYTES_PER_ELEMENT
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import BEMMesh
from wavebrdf.solver.fitted import fitted
from wavebrdf.solver.surface import HeightField

__all__ = ["COST", "estimate_aim", "memory_breakdown", "metallic", "plasmon_binding"]

COST = fitted("aim_cost")  # the cost model's fitted constants (solver/data/aim_cost.csv)


def _continuation_cost(mesh: BEMMesh, options: AIMOptions, waist_um: float | None, near_entry: int, cplx: int,
                       stencil_points: int, grid_media: int = 1) -> tuple[float, float]:
    """(bytes, set-up seconds) of the flat continuation (continuation.py): the ring operator's near
    storage and set-up and the extended mesh's grid weights (the closed form of its far field:
    BEYOND_PIXEL_BYTES per output pixel), on the solve's ``grid_media``."""
    n, d, L = mesh.cells, mesh.spacing_um, mesh.surface.size_um
    ring = n + 2 * (math.ceil(options.near_cells) + 2)
    waist = waist_um or L / 2.5
    reach = waist * math.sqrt(0.5 * math.log(1.0 / FLUX_LEFT))
    extended = max(ring + 4, math.ceil(2 * reach / d))
    ring_pairs = NearPattern.build(ring, options.near_cells).stored_entries()
    extended_bases = 2 * extended * (extended - 1)
    weights = 2 * cplx * 3 * stencil_points * extended_bases
    seconds = (_near_assembly_s(ring_pairs, True, grid_media)
               + _grid_setup_s(2 * extended_bases, True, grid_media))
    return ring_pairs * near_entry + weights, seconds


# Set-up time: the near-field assembly per stored pair and the projection, kernel spectra and
# excitation per unknown, on rough and on flat patches (whose element tables repeat)
NEAR_PAIR_S = {"rough": COST["near_pair_s_rough"], "flat": COST["near_pair_s_flat"]}
GRID_SETUP_S = {"rough": COST["grid_setup_s_rough"], "flat": COST["grid_setup_s_flat"]}


def _near_assembly_s(stored_pairs: float, flat: bool, grid_media: int = 1) -> float:
    """The near field's assembly; its grid subtraction (``near_grid_share`` of it with one grid
    medium) repeats per medium on the grid."""
    share = COST["near_grid_share"] * (grid_media - 1)
    return NEAR_PAIR_S["flat" if flat else "rough"] * stored_pairs * (1.0 + share)


def _grid_setup_s(unknowns: float, flat: bool, grid_media: int = 1) -> float:
    """Projection, kernel spectra and excitation; ``grid_setup_medium_share`` of them repeats per
    medium on the grid."""
    share = COST["grid_setup_medium_share"] * (grid_media - 1)
    return GRID_SETUP_S["flat" if flat else "rough"] * unknowns * (1.0 + share)


_GRIDS: dict = {}  # AIM grids of recent estimates by (cells, size, relief in cells, grid options)


def _grid(mesh: BEMMesh, grid_options):
    """The AIM grid of ``mesh`` (patches of one size whose relief agrees within a cell share it:
    a steered study's estimates then build a few grids, not one per patch)."""
    surface = mesh.surface
    ptp = float(np.ptp(surface.z))
    key = (surface.cells, surface.size_um, round(ptp / surface.spacing_um), ptp == 0.0, grid_options)
    if key not in _GRIDS:
        if len(_GRIDS) >= 16:
            _GRIDS.pop(next(iter(_GRIDS)))
        _GRIDS[key] = build_grid(mesh, grid_options)
    return _GRIDS[key]


@functools.lru_cache(maxsize=64)
def _near_nnz(cells: int, radius_cells: float) -> int:
    """Near pairs (both orientations) within ``radius_cells`` on an N-cell patch."""
    return int(NearPattern.build(cells, radius_cells).nnz())


def _preconditioner_cost(cells: int, unknowns: int, options: AIMOptions, flat: bool = False) -> tuple[float, float]:
    """(peak bytes, seconds) of the near LU: SUPERLU_BYTES per factor entry of every tile, plus
    SuperLU's working memory while one tile is factored (``lu_working_share`` × its factors);
    fill ``lu_fill_slope`` ln n + ``lu_fill_offset`` per LU of n unknowns (at least
    ``lu_fill_min``), time ``lu_time_s`` nnz^1.5 per LU (:data:`COST`)."""
    # (J, M) × (J, M) blocks; on a flat patch the J–M coupling of coplanar rooftops is zero, so
    # only the two diagonal blocks hold entries (measured: 577 592 entries at 16 128 unknowns)
    near_nnz = (2 if flat else 4) * _near_nnz(cells, options.preconditioner_cells)
    per_axis = tiles_per_axis(cells, options.preconditioner_tile_cells)
    side = cells if per_axis == 1 else cells / per_axis + 2 * PRECONDITIONER_OVERLAP
    share = (side / cells) ** 2  # of the unknowns and near entries in one (extended) tile
    fill = max(COST["lu_fill_min"],
               COST["lu_fill_slope"] * math.log(max(unknowns * share, 2.0)) + COST["lu_fill_offset"])
    one_tile = SUPERLU_BYTES * near_nnz * share * fill
    seconds = per_axis**2 * COST["lu_time_s"] * (near_nnz * share) ** 1.5
    return one_tile * per_axis**2 + COST["lu_working_share"] * one_tile, seconds


def _local_inverse_cost(cells: int, unknowns: int, options: AIMOptions) -> tuple[float, float, float]:
    """(bytes, set-up seconds, entries) of the local-inverse preconditioner: complex64 rows of
    ``local_inverse_entries`` per unknown; one inverse of m × m per tile (m its extended
    unknowns), ``local_inverse_s`` × m³ each (:data:`COST`)."""
    entries = local_inverse_entries(cells, options.local_tile_cells) * unknowns
    per_axis = tiles_per_axis(cells, options.local_tile_cells)
    m = 4.0 * (cells / per_axis + 2 * LOCAL_OVERLAP) ** 2
    return 8.0 * entries, per_axis**2 * COST["local_inverse_s"] * m**3, entries


def _flat_cost(media: Media, cells: int, spacing_um: float, unknowns: int, options: AIMOptions) -> tuple[float, float, int]:
    """(bytes, set-up seconds, torus points) of the flat-interface preconditioner: its inverse's 8
    nonzero blocks in complex64 per point of its torus and two indices per unknown
    (flat_circulant.py); its set-up
    ``flat_setup_s`` per torus point (:data:`COST`)."""
    points = torus_side(cells, kernel_radius_cells(media, spacing_um, options.flat_damping, cells)) ** 2
    return 8 * 8.0 * points + 16.0 * unknowns, COST["flat_setup_s"] * points, points


def _flat_patch_cost(media: Media, cells: int, spacing_um: float, unknowns: int,
                     options: AIMOptions) -> tuple[float, float, int, int]:
    """(bytes, set-up seconds, Toeplitz torus points, circulant torus points) of the flat patch's
    inner solve (flat_patch.py): the damped circulant (:func:`_flat_cost`) and T's 8 nonzero blocks
    in complex64 per point of its torus with two indices per unknown; T's set-up
    ``flat_patch_setup_s`` per point of its torus (:data:`COST`)."""
    circulant, circulant_s, circulant_points = _flat_cost(media, cells, spacing_um, unknowns, options)
    points = toeplitz_torus_side(cells) ** 2
    return (circulant + 8 * 8.0 * points + 16.0 * unknowns, circulant_s + COST["flat_patch_setup_s"] * points,
            points, circulant_points)


# Products of a warm-started solve over a cold one, by preconditioner (docs/aim.md, warm starts);
# not measured with the flat interface's circulant alone: no gain counted
WARM_PRODUCTS = {"local": COST["warm_products_local"], "near": COST["warm_products_near"],
                 "none": COST["warm_products_none"], "flat": 1.0, "flat-patch": COST["warm_products_flat_patch"]}

# Memory the stages need besides their arrays (what each is: solver/data/aim_cost.csv)
RUNTIME_BYTES = COST["runtime_bytes"]  # interpreter, NumPy/SciPy, OpenCL runtime and built kernels
ASSEMBLY_BYTES = COST["assembly_bytes"]  # near-field assembly above what it keeps
BLOCK_BYTES = COST["block_bytes"]  # the beam's fields and surface power over element blocks (excitation.py)
EXCITATION_BYTES_PER_UNKNOWN = COST["excitation_bytes_per_unknown"]
FARFIELD_PIXEL_BYTES = 16 * 2 * 36  # per output pixel: F (6), E, H (3 + 3) per polarization, CZT planes
# per output pixel, a flat continuation's closed form (radiation_beyond): three arrays of 6 components
# per polarization (whole plane, patch rooftops, difference) and the spectral densities behind them
BEYOND_PIXEL_BYTES = 16 * 2 * 6 * 7


def estimate_aim(surface: HeightField, wavelength_um: float, index: complex, *, exterior_index: float = 1.0,
                 aim=None, directions: int = 1, waist_um: float | None = None, resolution: int = 512,
                 cache: dict | None = None) -> dict:
    """Memory and time of an AIM run before it starts (for ``wavebrdf plan``).

    Returns ``unknowns``, ``near_nnz`` (stored near pairs), ``bytes`` (the peak: what is held
    at a stage, ``held`` by part, plus that stage's transient, ``transient``; the set-up's
    transients come before the preconditioner; :func:`memory_breakdown` prints them), ``seconds``
    (set-up + ``directions`` × both polarizations, with ``setup_s`` and ``product_s``),
    ``following_seconds`` (the same solve right after its patch's previous wavelength in one worker:
    without the static tables with ``reuse_setup``, ``warm_products_*`` of the products with
    ``warm_start``),
    ``iterations_guess`` (products per polarization), ``outside_fit`` (what of the surface lies
    beyond the product count's fitted range, "" if nothing) and the grid sizes. With ``edge = "flat"`` it
    adds the continuation: the ring operator and the extended mesh, whose size follows from
    ``waist_um`` (default L/2.5, a border at 1.25 w). ``resolution``: the output image side.
    ``cache``: a dict kept between estimates of the same surface (its mesh and rms slope; the grids are cached
    by geometry, ``_grid``).
    """
    options = aim if isinstance(aim, AIMOptions) else AIMOptions.from_mapping(aim)
    media = Media(wavelength_um, index, exterior_index)
    cache = {} if cache is None else cache
    mesh = cache.get("mesh") or cache.setdefault("mesh", BEMMesh(surface))
    d = mesh.spacing_um
    gm = grid_media(media, options.near_cells * d, options.interior_decay_tolerance)
    grid_options = options.grid_options(media, d, gm)
    grid = _grid(mesh, grid_options)
    pattern = NearPattern.build(mesh.cells, options.near_cells)
    n, n_b = mesh.n_unknowns, mesh.n_bases
    flat = bool(np.ptp(mesh.heights) == 0)
    if "repeating" not in cache:
        cache["repeating"] = RepeatingTables.worthwhile(mesh)
    # the static tables kept for the patch's next wavelength (elements.py); a patch whose element
    # pairs repeat (flat, tilted, 1-D periodic) fills a few rows only, at next to no cost
    keeps_tables = options.reuse_setup and not cache["repeating"]
    farfield_matching = options.projection == "farfield"
    groups = len(gm) if farfield_matching else 1
    real = options.precision.real.itemsize
    cplx = 2 * real
    weight = cplx if farfield_matching else real
    near_entry = 24 if options.near_storage == "single" else 48
    stored_pairs = int(pattern.stored_entries())
    S, padded = grid.stencil_size, grid.padded_points
    compact = grid.points
    P = 2  # polarizations side by side
    held = {
        "runtime": RUNTIME_BYTES,
        "near field": stored_pairs * near_entry,
        # per group: G of its media and the 3 precombined gradient spectra
        "grid spectra": cplx * padded * (len(gm) + 3 * groups),
        # weights by basis and by grid point (aim.cl), inverse map, origins
        "projections": groups * 2 * 3 * S * n_b * weight + 4 * (compact + n_b * S) + 12 * n_b,
        "preconditioner": 0.0,
        "static tables": STATIC_BYTES_PER_ELEMENT * mesh.n_elements if keeps_tables else 0.0,  # from the near field on
    }
    preconditioner_s = local_entries = torus_points = toeplitz_points = 0.0
    if options.preconditioner == "near":
        held["preconditioner"], preconditioner_s = _preconditioner_cost(mesh.cells, n, options, flat=flat)
    elif options.preconditioner == "local":
        held["preconditioner"], preconditioner_s, local_entries = _local_inverse_cost(mesh.cells, n, options)
    elif options.preconditioner == "flat":
        held["preconditioner"], preconditioner_s, torus_points = _flat_cost(media, mesh.cells, d, n, options)
    elif options.preconditioner == "flat-patch":
        held["preconditioner"], preconditioner_s, toeplitz_points, torus_points = _flat_patch_cost(
            media, mesh.cells, d, n, options)
    # Krylov vectors are complex128 (solver/krylov.py works in the rhs dtype: complex for the driver);
    # FGMRES keeps the preconditioned vectors too
    stored = 2 * options.restart + 4 if options.preconditioner == "flat-patch" else options.restart + 4
    krylov = 16 * n * P * (stored if options.solver == "gmres" else 8)
    krylov += 16 * n * (options.deflate + 1) if options.deflate else 0  # GMRES-DR's restart: V Q, one rhs at a time
    nx, ny, nz = grid.shape
    px = grid.padded[0]
    slab = 3 * 64 * 2**20
    transient = {
        # the kernels' spectra in complex128 while sampled and transformed, one medium at a time
        # (the near-field assembly also copies the projections in double for its grid subtraction)
        "set-up": max(16 * padded * 6 + cplx * padded * (len(gm) + 3 * groups),
                      ASSEMBLY_BYTES + groups * 3 * S * n_b * 16
                      + (REPEATING_STORE_BYTES if cache["repeating"] and not flat else 0)),
        "excitation": BLOCK_BYTES + EXCITATION_BYTES_PER_UNKNOWN * n,
        # host FFTs in slabs: the kept array A (8P, p_x, n_y, n_z), the kept slab and scipy.fft's
        # work arrays for the strided transforms (bounded by the compact-grid term)
        "products": krylov + cplx * 8 * P * (px * ny * nz + compact) + slab + 2 * 16 * n * P,
        "far field": P * 6 * compact * max(cplx, 8) + FARFIELD_PIXEL_BYTES * resolution**2 + BLOCK_BYTES,
    }
    if options.preconditioner == "flat":  # the set-up's complex128 peak, before what it keeps exists
        transient["preconditioner"] = SETUP_BYTES_PER_POINT * torus_points
    elif options.preconditioner == "flat-patch":  # the circulant's peak, then T's on its flat lattice of 2N cells
        transient["preconditioner"] = max(SETUP_BYTES_PER_POINT * torus_points,
                                          TOEPLITZ_SETUP_BYTES_PER_POINT * toeplitz_points
                                          + COST["flat_lattice_bytes_per_cell"] * 4 * mesh.cells**2)
        # each application, in complex64: the inner GMRES basis (steps + 1 vectors) and about 8 more
        # (the right-hand side, iterate, Arnoldi and Gram–Schmidt temporaries, the circulant's output;
        # the complex128 result counts as 2), and the torus fields, spectra and product of T
        transient["products"] += 8.0 * P * ((options.flat_inner_steps + 9) * n + 3 * 4 * toeplitz_points)
    continuation = continuation_s = 0.0
    if options.edge == "flat":
        continuation, continuation_s = _continuation_cost(mesh, options, waist_um, near_entry, cplx, S * groups,
                                                          len(gm))
        held["continuation"] = continuation
        transient["far field"] += BEYOND_PIXEL_BYTES * resolution**2
    # the set-up's transients come before the preconditioner and the continuation exist
    before_preconditioner = sum(v for k, v in held.items() if k not in ("preconditioner", "continuation"))
    total = max(before_preconditioner + transient["set-up"],
                sum(held.values()) + max(v for k, v in transient.items() if k != "set-up"))
    # time of one product of both polarizations: the FFTs of every grid group and the near SpMV,
    # scaled to measured Krylov stages; single precision; the near LU's triangular solves
    fft_points = padded * 16 * groups
    product_s = COST["product_scale"] * (COST["product_fft_s"] * fft_points * math.log2(max(padded, 2))
                                         + COST["product_near_s"] * stored_pairs * 2)
    if not options.precision.fp64:
        product_s *= COST["product_single_ratio"]
    if options.preconditioner == "near":
        product_s += 2.0 * held["preconditioner"] / SUPERLU_BYTES * COST["lu_solve_s"]
    inner_steps = options.flat_inner_steps if options.preconditioner == "flat-patch" else 1
    product_s += 2.0 * local_entries * COST["local_apply_s"] + 2.0 * inner_steps * (
        torus_points * COST["flat_apply_s"] + toeplitz_points * COST["flat_patch_apply_s"])
    size_waves = surface.size_um * exterior_index / wavelength_um
    exterior_wavelength = wavelength_um / exterior_index
    key = ("rms_slope_below", exterior_wavelength)  # the surface's, for every candidate of one fit
    if key not in cache:
        cache[key] = surface.rms_slope_below(exterior_wavelength)
    iterations = _products(options, size_waves, complex(media.index) / exterior_index, cache[key])
    beyond = options.preconditioner != "near" and cache[key] > COST["products_fine_slope_max"]
    outside_fit = (f"rms slope finer than λ {cache[key]:.2f} beyond the product count's fitted "
                   f"{COST['products_fine_slope_max']:.2f}: the count is held there and likely low" if beyond else "")
    setup_s = (_near_assembly_s(stored_pairs, flat, len(gm)) + _grid_setup_s(n, flat, len(gm)) + preconditioner_s
               + continuation_s)
    krylov_s = directions * iterations * product_s * COST["product_overhead"]
    seconds = setup_s + krylov_s
    # the same solve right after its patch's previous wavelength in one worker: the static tables
    # kept and the solves warm-started
    kept_s = COST["static_table_s"] * mesh.n_elements if keeps_tables else 0.0
    warm = WARM_PRODUCTS[options.preconditioner] if options.warm_start else 1.0
    following_seconds = setup_s - kept_s + warm * krylov_s
    return {
        "unknowns": n,
        "near_nnz": stored_pairs,
        "bytes": int(total),
        "held": {k: int(v) for k, v in held.items()},
        "transient": {k: int(v) for k, v in transient.items()},
        "near_bytes": int(held["near field"]),
        "spectra_bytes": int(held["grid spectra"]),
        "preconditioner_bytes": int(held["preconditioner"]),
        "continuation_bytes": int(continuation),
        "seconds": float(seconds),
        "following_seconds": float(following_seconds),
        "setup_s": float(setup_s),
        "product_s": float(product_s),
        "iterations_guess": int(iterations),
        "outside_fit": outside_fit,
        "grid": grid.shape,
        "fft": grid.padded,
        "grid_media": gm,
    }


def metallic(index: complex) -> bool:
    """Whether a material of relative ``index`` (n − jκ) counts as a metal in the product count: Re ε < 0."""
    return (complex(index) ** 2).real < 0.0


def plasmon_binding(index: complex) -> float | None:
    """b = ln(Re n_spp − 1): how tightly a flat interface of relative ``index`` (n − jκ) binds its
    surface plasmon, n_spp = √(ε/(1 + ε)), ε = n² (the plasmon's wavenumber over the exterior
    one); None where Re ε ≥ −1 (a dielectric: no bound plasmon)."""
    eps = complex(index) ** 2
    if eps.real >= -1.0:
        return None
    excess = (eps / (1.0 + eps)) ** 0.5
    return math.log(max(excess.real - 1.0, 1e-12))


def _products(options: AIMOptions, size_waves: float, index: complex, fine_slope: float,
              cost: dict = COST) -> float:
    """Operator products per polarization to the tolerance (``cost``: :data:`COST`): with the whole
    near LU a + b √(L/λ), ``products_tiled_ratio`` × that on tiles. Without a preconditioner (MINRES)
    the count follows the roughness as much as the size:

        c (L/λ)^β (s + s₀)^γ × { e^{α b} (s + s₀)^δ   a metal, Re ε < 0 (b = plasmon_binding)
                                { g                     a dielectric, Re ε ≥ 0

    with s the rms slope of the relief finer than λ (``HeightField.rms_slope_below``: roughness at
    and below λ couples nearby elements) and ``index`` relative to the exterior; a more tightly
    bound plasmon takes more products (gold more than aluminium, aluminium at 0.4 µm more than at
    0.55 µm: docs/aim.md). With the flat interface's inverse, ``products_flat_ratio`` × that
    (measured on one patch). With the local inverses (GMRES), ``products_local_ratio``
    (L/10λ)^``products_local_size_exp`` × that. c, β, γ, δ, α, g, the local ratio and its exponent
    are fitted by tools/refit_product_counts.py to solver/data/aim_products.csv; s₀
    (``products_slope_offset``) was chosen there by leave-one-out. Beyond the fitted ranges of s
    and b (``products_fine_slope_max``, ``products_plasmon_binding_min``/``_max``) the count is the
    one at the nearest fitted value; a metal whose plasmon is not bound (−1 ≤ Re ε < 0) takes the
    most tightly bound one's. Not held: L/λ (the local rows' growth with it rests on one row at
    L/λ = 30) and a dielectric's index (only n = 1.5 was measured: any dielectric gets glass's
    count)."""
    size_waves = max(size_waves, 1.0)
    if options.preconditioner == "near":
        whole = cost["products_lu_base"] + cost["products_lu_per_sqrt_size"] * math.sqrt(size_waves)
        return whole * (1.0 if options.preconditioner_tile_cells == 0 else cost["products_tiled_ratio"])
    ratio = 1.0
    if options.preconditioner == "local":  # the local inverses leave the long-range part, which grows with L/λ
        ratio = cost["products_local_ratio"] * (size_waves / 10.0) ** cost["products_local_size_exp"]
    elif options.preconditioner == "flat":  # one measured patch (L = 10 λ): not fitted, not chosen by the planner
        ratio = cost["products_flat_ratio"]
    elif options.preconditioner == "flat-patch":
        return _flat_patch_products(index, fine_slope, cost)
    roughness = min(fine_slope, cost["products_fine_slope_max"]) + cost["products_slope_offset"]
    count = (cost["products_minres"] * size_waves ** cost["products_minres_size_exp"]
             * roughness ** cost["products_minres_slope_exp"])
    if not metallic(index):
        return ratio * count * cost["products_dielectric_ratio"]
    metal = math.exp(cost["products_plasmon_exp"] * _held_binding(index, cost)) \
        * roughness ** cost["products_metal_slope_exp"]
    return ratio * count * metal


def _held_binding(index: complex, cost: dict) -> float:
    """A metal's plasmon binding b held within the fitted range; −1 ≤ Re ε < 0 (near the plasmon
    resonance, no bound plasmon) takes the most tightly bound fitted one's."""
    binding = plasmon_binding(index)
    binding = cost["products_plasmon_binding_max"] if binding is None else binding
    return min(max(binding, cost["products_plasmon_binding_min"]), cost["products_plasmon_binding_max"])


def _flat_patch_products(index: complex, fine_slope: float, cost: dict = COST) -> float:
    """FGMRES products per polarization with the flat patch's inner solve (``flat_inner_steps`` =
    16, restart 30): a (s + s₀)^η × (a metal: e^{α_f b}, b = plasmon_binding held within the fitted
    range; a dielectric: g_f), s the rms slope finer than λ held at ``products_fine_slope_max``. The
    size does not enter: the flat patch carries the coupling along the plane that makes the other
    counts grow with L/λ (10 products at L = 10, 16 and 30 λ on the sub-area family, docs/aim.md).
    a, η, α_f, g_f: tools/refit_product_counts.py on the ``flat-patch`` rows of
    solver/data/aim_products.csv."""
    roughness = min(fine_slope, cost["products_fine_slope_max"]) + cost["products_slope_offset"]
    count = cost["products_flat_patch"] * roughness ** cost["products_flat_patch_slope_exp"]
    if not metallic(index):
        return count * cost["products_flat_patch_dielectric_ratio"]
    return count * math.exp(cost["products_flat_patch_plasmon_exp"] * _held_binding(index, cost))


def memory_breakdown(estimate: dict) -> str:
    """One line: the held parts and the largest transient of an :func:`estimate_aim` (GiB)."""
    gib = 2**30
    held = ", ".join(f"{k} {v / gib:.2f}" for k, v in estimate["held"].items() if v)
    transients = ", ".join(f"{k} {v / gib:.2f}" for k, v in estimate["transient"].items())
    return f"held {held}; transient {transients} GiB"
