"""Benchmarks and convergence studies of the dense 3D BEM (docs/bem3d.md quotes their output).

    .venv/bin/python benchmarks/bench_bem3d.py assembly      # PoCL vs NumPy on the same pairs
    .venv/bin/python benchmarks/bench_bem3d.py quadrature    # error vs order tables
    .venv/bin/python benchmarks/bench_bem3d.py tolerance     # BRDF change, default vs tight quadrature
    .venv/bin/python benchmarks/bench_bem3d.py beams         # paraxial vs exact beam, flat patch
    .venv/bin/python benchmarks/bench_bem3d.py convergence   # d = λ/8, λ/12, λ/16 on a rough patch
    .venv/bin/python benchmarks/bench_bem3d.py flat --cells 48   # flat-patch albedo vs exact reflectance
    .venv/bin/python benchmarks/bench_bem3d.py solve [--cells N]   # dense solve of the largest patch

Timings on a shared 2-core machine are noisy: compare ratios measured within one run.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from wavebrdf.solver.bem3d import BEMSolver, BEMWarning, QuadratureOptions, estimate_dense
from wavebrdf.solver.bem3d import elements as el
from wavebrdf.solver.bem3d.assembly import basis_pair_entries
from wavebrdf.solver.bem3d.elements import ElementIntegrals
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import BEMMesh
from wavebrdf.solver.bem3d.quadrature import pair_case, singular_orders, singular_rule
from wavebrdf.solver.farfield import HemisphereGrid, albedo
from wavebrdf.solver.opencl import create_context
from wavebrdf.solver.surface import HeightField, generate

LAMBDA = 0.4
AL = 0.46582 - 4.7119j


def smooth_random_surface(cells: int, size_um: float, rms_height: float, correlation: float, seed: int = 7):
    """A band-limited random surface defined by fixed Fourier modes, sampled at any resolution
    (the same continuous geometry for every mesh size, for convergence studies). The rms height
    and the mean are set on a fine reference grid, independent of ``cells``."""
    rng = np.random.default_rng(seed)
    n_modes = 60
    k = rng.normal(0.0, np.sqrt(2.0) / correlation, (n_modes, 2))
    phase = rng.uniform(0, 2 * np.pi, n_modes)

    def heights(n):
        x = -0.5 * size_um + size_um / n * np.arange(n + 1)
        X, Y = np.meshgrid(x, x, indexing="ij")
        return np.sum(np.cos(k[:, 0, None, None] * X + k[:, 1, None, None] * Y + phase[:, None, None]), axis=0)

    fine = heights(256)
    mean, rms = fine.mean(), (fine - fine.mean()).std()
    return HeightField((heights(cells) - mean) * (rms_height / rms), size_um)


def lobe_mask(brdf, level=1e-3):
    """Pixels inside the disk where ``brdf`` exceeds ``level`` times its peak."""
    return np.isfinite(brdf) & (np.nan_to_num(brdf) > level * np.nanmax(brdf))


def lobe_difference(f, g, weight_mask):
    """Relative L2 difference of two BRDF images over the pixels of ``weight_mask``."""
    return float(np.linalg.norm((f - g)[weight_mask]) / np.linalg.norm(g[weight_mask]))


# ---------------------------------------------------------------------------------------------


def bench_assembly(ctx, cells: int = 20, rows: int = 24):
    """Time per unknown pair: the OpenCL path vs the NumPy twins on the same basis pairs."""
    surface = generate("gaussian", cells=cells, size_um=cells * LAMBDA / 8, seed=5,
                       rms_height_um=0.04, correlation_um=0.4)
    mesh = BEMMesh(surface)
    media = Media(LAMBDA, AL)
    nb = mesh.n_bases
    rng = np.random.default_rng(0)
    sel = np.sort(rng.choice(nb, rows, replace=False))
    r = np.repeat(sel, nb)
    c = np.tile(np.arange(nb), rows)
    pairs = 4 * len(r)  # each rooftop pair gives 4 unknown pairs (J-J, J-M̃, M̃-J, M̃-M̃)
    print(f"assembly benchmark: rough Al patch {cells}x{cells} cells (d = λ/8), {rows} rooftop rows x "
          f"{nb} columns = {pairs} unknown pairs, {ctx.describe()}")
    basis_pair_entries(ctx, mesh, media, r[:8], c[:8])  # build kernels (not timed)
    ocl = ElementIntegrals(mesh, ctx=ctx)
    t0 = time.perf_counter()
    a = basis_pair_entries(ctx, mesh, media, r, c, integrals=ocl)
    t_ocl = time.perf_counter() - t0
    ref = ElementIntegrals(mesh, ctx=None)
    t0 = time.perf_counter()
    b = basis_pair_entries(None, mesh, media, r, c, integrals=ref)
    t_np = time.perf_counter() - t0
    diff = max(np.abs(x - y).max() / np.abs(y).max() for x, y in zip(a, b))
    print(f"  OpenCL : {t_ocl:8.2f} s  {t_ocl / pairs * 1e6:8.3f} µs per unknown pair  {ocl.timings}")
    print(f"  NumPy  : {t_np:8.2f} s  {t_np / pairs * 1e6:8.3f} µs per unknown pair  {ref.timings}")
    print(f"  ratio NumPy/OpenCL = {t_np / t_ocl:.1f}x   max relative difference {diff:.2e}")
    print(f"  element pairs {ocl.counts}")


def bench_quadrature(ctx):
    """Relative error vs Gauss order of the singular transforms (reference: order 20)."""
    d = LAMBDA / 8
    meshes = {
        "flat": BEMMesh(HeightField(np.zeros((5, 5)), 4 * d)),
        "curved": BEMMesh(HeightField(np.random.default_rng(3).uniform(-d, d, (5, 5)), 4 * d)),
    }
    k0 = 2 * np.pi / LAMBDA
    ks = (k0, k0 * AL)
    orders = [2, 3, 4, 5, 6, 7, 8, 10, 12]
    cases = {"self": (0, 0), "edge": (1, 0), "vertex": (1, 1)}
    print("singular transforms, relative error vs order (d = λ/8; curved: corner heights ±d, slopes up to ~2)")
    print("  parts: static 1/R, ∇(1/R) | remainder G−G₀, exterior k₁ | remainder, aluminium k₂ (each vs its own size)")
    header = "  " + f"{'geometry':8s} {'pair':7s} {'part':9s}" + "".join(f"{n:>9d}" for n in orders)
    print(header)
    for gname, mesh in meshes.items():
        for cname, (ds, dt) in cases.items():
            test = np.array([mesh.cells + 1])
            source = test + ds * mesh.cells + dt
            case, ct, cs = pair_case(np.array([ds]), np.array([dt]))

            def table(kind, order):
                return el.singular_pairs_opencl(ctx, mesh.geometry, mesh.half, test, source, ct, cs,
                                                singular_rule(int(case[0]), order), ks, kind)

            for part, kind, medium in (("static", el.KIND_STATIC, None), ("ext", el.KIND_REMAINDER, 0),
                                       ("Al int", el.KIND_REMAINDER, 1)):
                ref = table(kind, 20)
                ref = ref[0] if medium is None else ref[0, medium]
                errs = []
                for n in orders:
                    got = table(kind, n)
                    got = got[0] if medium is None else got[0, medium]
                    errs.append(np.abs(got - ref).max() / np.abs(ref).max())
                print("  " + f"{gname:8s} {cname:7s} {part:9s}" + "".join(f"{e:9.1e}" for e in errs))
    opts = QuadratureOptions()
    glass = (k0, 1.5 * k0)

    def orders(mesh, wavenumbers):  # (a priori, measured) per medium (docs/bem3d.md, "Singular remainder orders")
        return (singular_orders(opts, mesh.half_length.max(), wavenumbers),
                el.ElementIntegrals(mesh, opts, ctx).remainder_orders(wavenumbers))

    print(f"  defaults: static_order = {opts.static_order}, tolerance = {opts.tolerance:g} -> remainder orders "
          f"(a priori, measured) per medium {orders(meshes['curved'], ks)} for Al (curved), "
          f"{orders(meshes['flat'], glass)} for n = 1.5 (flat)")


def _solver(ctx, surface, index, quadrature=None):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BEMWarning)
        return BEMSolver(ctx, surface, LAMBDA, index, quadrature=quadrature)


def _flat_solvers(ctx, cells: int):
    """(surface, index, solver) of a flat λ/8 patch for glass and aluminium."""
    surface = generate("flat", cells=cells, size_um=cells * LAMBDA / 8)
    for index in (1.5, AL):
        yield surface, index, _solver(ctx, surface, index)


def bench_tolerance(ctx, cells: int = 24):
    """BRDF change when the quadrature is tightened from the defaults (justifies the defaults)."""
    surface = smooth_random_surface(cells, cells * LAMBDA / 8, LAMBDA / 10, 0.3)
    grid = HemisphereGrid(96)
    theta = np.deg2rad(20.0)
    stats = surface.statistics()
    print(f"quadrature tolerance study: rough Al patch {cells}x{cells} (d = λ/8, rms height "
          f"{stats['rms_height_um']:.3f} µm, rms slope {stats['rms_slope']:.2f}, max slope {stats['max_slope']:.2f}), "
          "θ_i = 20°, exact beam")
    results = {}
    for label, q in (("tol 1e-4", {"tolerance": 1e-4, "static_order": 5}), ("default", None),
                     ("tol 1e-9", {"tolerance": 1e-9, "static_order": 10})):
        t0 = time.perf_counter()
        solver = _solver(ctx, surface, AL, q)
        ff = solver.farfield(theta, 0.0, grid, waist_um=surface.size_um / 5)
        results[label] = (ff.brdf(), albedo(ff.brdf(), grid), time.perf_counter() - t0)
    ref = results["tol 1e-9"][0]
    mask = lobe_mask(ref[0])
    for label, (brdf, alb, secs) in results.items():
        print(f"  {label:9s} albedo {alb}  rel. L2 BRDF change vs tol 1e-9: "
              f"{lobe_difference(brdf[0], ref[0], mask):.2e} (s), {lobe_difference(brdf[1], ref[1], mask):.2e} (p)"
              f"  time {secs:.1f} s")


def bench_beams(ctx, cells: int = 32):
    """Paraxial vs exact beam on a flat patch (albedo and BRDF)."""
    grid = HemisphereGrid(96)
    print(f"paraxial vs exact beam: flat {cells * LAMBDA / 8:g} µm patch ({cells} cells, d = λ/8), waist L/5")
    for surface, index, solver in _flat_solvers(ctx, cells):
        for theta in (0.0, 45.0, 70.0):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", BEMWarning)
                ex = solver.farfield(np.deg2rad(theta), 0.0, grid, waist_um=surface.size_um / 5, beam="exact")
                pa = solver.farfield(np.deg2rad(theta), 0.0, grid, waist_um=surface.size_um / 5, beam="paraxial")
            a_ex, a_pa = albedo(ex.brdf(), grid), albedo(pa.brdf(), grid)
            mask = lobe_mask(ex.brdf()[0])
            print(f"  n = {index}, θ = {theta:4.0f}°: exact albedo {a_ex} (beam reflectance "
                  f"{ex.diagnostics['beam_reflectance']}); paraxial albedo {a_pa}; BRDF rel. L2 difference "
                  f"{lobe_difference(pa.brdf()[0], ex.brdf()[0], mask):.3f} (s)")


def bench_flat(ctx, cells: int = 48):
    """Flat patch (d = λ/8, waist L/5): albedo vs the exact beam's reflectance at 0° and 45°."""
    grid = HemisphereGrid(128)
    print(f"flat patch {cells / 8:g}λ ({cells} cells, d = λ/8), waist L/5 = {cells / 40:.2f}λ: "
          "albedo / exact beam reflectance − 1 (s, p)")
    for surface, index, solver in _flat_solvers(ctx, cells):
        for theta in (0.0, 45.0):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", BEMWarning)
                ff = solver.farfield(np.deg2rad(theta), 0.0, grid, waist_um=surface.size_um / 5)
            ref = ff.diagnostics["beam_reflectance"]
            print(f"  n = {index}, θ = {theta:4.0f}°: grid {albedo(ff.brdf(), grid) / ref - 1}, hemisphere "
                  f"{ff.diagnostics['reflected_fraction'] / ref - 1}, reflectance {ref}, incident power outside "
                  f"the patch {ff.diagnostics['incident_outside_fraction']:.1e}")


def bench_convergence(ctx, size_wavelengths: float = 4.0, divisions=(8, 12, 16)):
    """BRDF of one rough Al patch at d = λ/8, λ/12, λ/16; observed order of convergence."""
    size = size_wavelengths * LAMBDA
    grid = HemisphereGrid(96)
    theta = np.deg2rad(30.0)
    brdfs, albedos = [], []
    stats = smooth_random_surface(128, size, LAMBDA / 10, 0.4).statistics()
    print(f"convergence in d: rough Al patch {size:g} µm (rms height {stats['rms_height_um']:.3f} µm, rms slope "
          f"{stats['rms_slope']:.2f}, max slope {stats['max_slope']:.2f}), θ_i = 30°, exact beam, waist L/5")
    for div in divisions:
        cells = int(round(size_wavelengths * div))
        surface = smooth_random_surface(cells, size, LAMBDA / 10, 0.4)
        t0 = time.perf_counter()
        solver = _solver(ctx, surface, AL)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", BEMWarning)
            ff = solver.farfield(theta, 0.0, grid, waist_um=size / 5)
        brdfs.append(0.5 * (ff.brdf()[0] + ff.brdf()[1]))
        albedos.append(albedo(ff.brdf(), grid))
        print(f"  d = λ/{div:<3d} ({cells} cells, {solver.mesh.n_unknowns} unknowns): albedo {albedos[-1]}, "
              f"assembly {solver.diagnostics['assembly_s']:.1f} s, LU {solver.diagnostics['factorization_s']:.1f} s, "
              f"total {time.perf_counter() - t0:.1f} s")
        del solver
    ref = brdfs[-1]
    mask = lobe_mask(ref)
    diffs = [lobe_difference(brdfs[i], brdfs[i + 1], mask) for i in range(len(brdfs) - 1)]
    for i, dd in enumerate(diffs):
        print(f"  BRDF change λ/{divisions[i]} → λ/{divisions[i + 1]}: rel. L2 {dd:.3e}; albedo change "
              f"{np.abs(albedos[i] - albedos[i + 1]).max():.2e}")
    if len(diffs) == 2:
        h = 1.0 / np.array(divisions, dtype=float)
        ratio = diffs[0] / diffs[1]
        # solve (h0^p − h1^p)/(h1^p − h2^p) = ratio for p
        ps = np.linspace(0.2, 6, 2000)
        model = (h[0] ** ps - h[1] ** ps) / (h[1] ** ps - h[2] ** ps)
        p = ps[np.argmin(np.abs(model - ratio))]
        print(f"  observed order of convergence p ≈ {p:.2f} (from the two successive changes)")


def bench_solve(ctx, cells: int | None = None):
    """Dense solve time for the largest patch that fits (or ``cells``)."""
    n_fit = 4
    while estimate_dense(n_fit + 1)["fits"]:
        n_fit += 1
    est = estimate_dense(n_fit)
    print(f"largest patch that fits here: {n_fit}x{n_fit} cells, {est['unknowns']} unknowns, "
          f"{est['bytes'] / 2**30:.1f} GiB (limit {est['limit_bytes'] / 2**30:.1f} GiB), "
          f"LU {est['lu_flops'] / 1e12:.1f} Tflop")
    cells = cells or n_fit
    surface = smooth_random_surface(cells, cells * LAMBDA / 8, LAMBDA / 10, 0.4)
    t0 = time.perf_counter()
    solver = _solver(ctx, surface, AL)
    grid = HemisphereGrid(128)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BEMWarning)
        ff = solver.farfield(np.deg2rad(30.0), 0.0, grid, waist_um=surface.size_um / 5)
    dg = ff.diagnostics
    n = solver.mesh.n_unknowns
    print(f"  ran {cells}x{cells} cells ({n} unknowns, Z {dg['matrix_bytes'] / 2**30:.2f} GiB): assembly "
          f"{dg['assembly_s']:.1f} s, LU {dg['factorization_s']:.1f} s "
          f"({8 / 3 * n**3 / dg['factorization_s'] / 1e9:.1f} Gflop/s), solve+residual {dg['solve_s']:.1f} s, "
          f"far field {dg['farfield_s']:.1f} s, residual {dg['residual']}, peak RSS "
          f"{dg['peak_memory_bytes'] / 2**30:.1f} GiB, total {time.perf_counter() - t0:.1f} s")
    if cells != n_fit:
        scale = (est["unknowns"] / n) ** 3
        print(f"  extrapolated LU time of the largest ({n_fit} cells): {dg['factorization_s'] * scale / 60:.0f} min")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sections", nargs="*", default=["assembly", "quadrature", "tolerance", "beams", "convergence"],
                        choices=["assembly", "quadrature", "tolerance", "beams", "convergence", "flat", "solve"])
    parser.add_argument("--cells", type=int, default=None, help="cells per side for 'solve' and 'flat'")
    args = parser.parse_args(argv)
    ctx = create_context()
    for section in args.sections:
        t0 = time.perf_counter()
        if section == "solve":
            bench_solve(ctx, args.cells)
        elif section == "flat":
            bench_flat(ctx, args.cells or 48)
        else:
            globals()[f"bench_{section}"](ctx)
        print(f"[{section}: {time.perf_counter() - t0:.0f} s]\n", flush=True)


if __name__ == "__main__":
    main()
