"""Benchmarks of the AIM solver (docs/aim.md quotes their output).

    .venv/bin/python benchmarks/bench_aim.py matvec            # matvec / FFT time, near memory, 3 sizes
    .venv/bin/python benchmarks/bench_aim.py solve             # solve time at 3 patch sizes vs N log N
    .venv/bin/python benchmarks/bench_aim.py solvers           # iterations and time per Krylov method
    .venv/bin/python benchmarks/bench_aim.py precision         # single vs double: time and accuracy
    .venv/bin/python benchmarks/bench_aim.py fft               # host scipy.fft vs VkFFT on this device
    .venv/bin/python benchmarks/bench_aim.py accuracy          # matvec error vs near radius / spacing / projection
    .venv/bin/python benchmarks/bench_aim.py reference         # the reference simulator's 4 µm flat case
    .venv/bin/python benchmarks/bench_aim.py truncation        # dense vs AIM on that geometry at d = λ/8
    .venv/bin/python benchmarks/bench_aim.py continuation      # a bump: continued vs pinned patches, glass and Al
    .venv/bin/python benchmarks/bench_aim.py scale             # 12.5 µm aluminium, d = λ/12.8 (~6.4e5 unknowns)
    .venv/bin/python benchmarks/bench_aim.py subarea           # the reference's 12 µm sub-area (919 680 unknowns),
                                                               # settings fitted to --memory-gb; --cells for smaller
    .venv/bin/python benchmarks/bench_aim.py products          # unpreconditioned MINRES products vs the planner's
                                                               # estimate on small surfaces of varied roughness
    .venv/bin/python benchmarks/bench_aim.py flat-patch        # the flat patch's inner solve alone at 480 cells:
                                                               # set-up, memory, one application

Every run prints the machine load (other agents share the 2 cores): compare ratios measured in
one run, not absolute times. CPU seconds and peak memory come from getrusage.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import shlex
import sys
import time
import warnings

import numpy as np

from wavebrdf.kernels import load_source
from wavebrdf.solver.bem3d import BEMSolver, BEMWarning, estimate_aim
from wavebrdf.solver.bem3d.aim import AIM_QUADRATURE, AIMOperator, AIMOptions
from wavebrdf.solver.bem3d.aim.convolution import forward_pruned, inverse_pruned
from wavebrdf.solver.bem3d.aim.grid import build_grid
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import BEMMesh
from wavebrdf.solver.farfield import HemisphereGrid, albedo
from wavebrdf.solver.opencl import create_context
from wavebrdf.solver.resources import peak_memory_mb, resident_memory_mb
from wavebrdf.solver.stages import format_stages
from wavebrdf.solver.surface import HeightField, generate

AL_400 = 0.46582 - 4.7119j
KERNELS = ("aim.cl", "aim_near.cl", "sparse.cl", "bem_elements.cl", "bem_assembly.cl", "bem_farfield.cl")


def freeze_kernel_sources():
    """Read every kernel source now: long runs are then immune to edits of kernels/ on disk."""
    for name in KERNELS:
        load_source(name)


def load() -> str:
    one, five, _ = os.getloadavg()
    return f"load average {one:.2f} (1 min), {five:.2f} (5 min) on {os.cpu_count()} CPUs"


def usage() -> dict:
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return {"cpu_s": ru.ru_utime + ru.ru_stime, "peak_memory_gb": peak_memory_mb() / 1024,
            "resident_gb": resident_memory_mb() / 1024}


def aluminium_patch(cells: int, lam: float = 0.4, per_wavelength: float = 12.8, seed: int = 1):
    """Rough aluminium test surface like the reference's 'test' set (rms 0.088 µm, T = 1.8 µm)."""
    d = lam / per_wavelength
    return generate("gaussian", cells=cells, size_um=cells * d, seed=seed, rms_height_um=0.088,
                    correlation_um=1.8)


def best_matvec(op: AIMOperator, x: np.ndarray, repeat: int = 3):
    """(best total time, the base timings of that call, median over the calls of matvec / FFT time)."""
    best, timings, ratios = math.inf, None, []
    for _ in range(repeat):
        op.base.timings = {k: 0.0 for k in op.base.timings}
        t0 = time.perf_counter()
        op.matvec(x)
        dt = time.perf_counter() - t0
        ratios.append(dt / op.base.timings["fft_s"])
        if dt < best:
            best, timings = dt, dict(op.base.timings)
    return best, timings, float(np.median(ratios))


def cmd_matvec(args, ctx):
    rng = np.random.default_rng(0)
    print(load())
    for cells in args.sizes:
        surface = aluminium_patch(cells)
        mesh = BEMMesh(surface)
        media = Media(0.4, AL_400)
        op = AIMOperator(ctx, mesh, media, AIMOptions(precision=args.precision, preconditioner="none"))
        x = rng.standard_normal((2, mesh.n_unknowns)) + 1j * rng.standard_normal((2, mesh.n_unknowns))
        total, t, median = best_matvec(op, x.astype(op.dtype), repeat=args.repeat)
        print(f"N = {cells}: {mesh.n_unknowns} unknowns, {op.grid.describe()}; near {op.near.bytes() / mesh.n_unknowns:.0f} "
              f"B/unknown; matvec (2 RHS) {total:.3f} s: FFT {t['fft_s']:.3f}, scatter {t['scatter_s']:.3f}, "
              f"Fourier {t['fourier_s']:.3f}, gather {t['gather_s']:.3f}, near {t['near_s']:.3f}; "
              f"matvec / FFT = {total / t['fft_s']:.2f} (median of {args.repeat} products {median:.2f})", flush=True)
    print(load())


def cmd_solve(args, ctx):
    """Solve time at 3 sizes (aluminium, normal incidence) against N log N growth."""
    print(load())
    rows = []
    for cells in args.sizes:
        surface = aluminium_patch(cells)
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", BEMWarning)
            solver = BEMSolver(ctx, surface, 0.4, AL_400, method="aim", aim={"precision": args.precision})
            setup = time.perf_counter() - t0
            ff = solver.farfield(0.0, 0.0, HemisphereGrid(128), waist_um=surface.size_um / 5)
        n = solver.mesh.n_unknowns
        d = ff.diagnostics
        rows.append((n, setup, d["solve_s"], d["iterations"]))
        print(f"N = {cells}: {n} unknowns, set-up {setup:.1f} s, solve {d['solve_s']:.1f} s "
              f"({d['iterations']} products), per product {d['solve_s'] / max(d['iterations']):.3f} s", flush=True)
    n0, _, s0, i0 = rows[0]
    for n, setup, s, its in rows[1:]:
        nlogn = n * math.log(n) / (n0 * math.log(n0))
        per = (s / max(its)) / (s0 / max(i0))
        print(f"{n} vs {n0} unknowns: N log N ratio {nlogn:.2f}; solve-time ratio {s / s0:.2f}; "
              f"time per product ratio {per:.2f}; iterations {its} vs {i0}")
    print(load())


def cmd_solvers(args, ctx):
    """Iterations and time of each Krylov method (with and without the near preconditioner)."""
    print(load())
    for lam, index, per in ((0.5, 1.5, 10.0), (0.4, AL_400, 12.8)):
        d = lam / per
        surface = generate("gaussian", cells=args.cells, size_um=args.cells * d, seed=3, rms_height_um=0.1 * lam,
                           correlation_um=0.8 * lam)
        base = BEMSolver(ctx, surface, lam, index, method="aim", aim={"preconditioner": "none"})
        pre = BEMSolver(ctx, surface, lam, index, method="aim")
        for label, solver, method in (("gmres", base, "gmres"), ("csym", base, "csym"), ("bicgstab", base, "bicgstab"),
                                      ("gmres + near LU", pre, "gmres"), ("bicgstab + near LU", pre, "bicgstab")):
            solver.operator.options = AIMOptions(**{**solver.operator.options.__dict__, "solver": method})
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", BEMWarning)
                    ff = solver.farfield(0.2, 0.0, HemisphereGrid(32), waist_um=surface.size_um / 5)
                print(f"n = {index}, N = {args.cells}: {label:20s} products {ff.diagnostics['iterations']}, "
                      f"solve {ff.diagnostics['solve_s']:.2f} s", flush=True)
            except Exception as exc:  # a method that fails is a result here
                print(f"n = {index}: {label}: {type(exc).__name__}: {str(exc)[:100]}", flush=True)
    print(load())


def cmd_precision(args, ctx):
    """Single vs double precision: matvec time ratio and BRDF difference."""
    print(load())
    surface = aluminium_patch(args.cells)
    out = {}
    for precision in ("double", "single"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", BEMWarning)
            solver = BEMSolver(ctx, surface, 0.4, AL_400, method="aim", aim={"precision": precision})
            x = np.random.default_rng(0).standard_normal((2, solver.mesh.n_unknowns)).astype(solver.operator.dtype)
            mv, _, _ = best_matvec(solver.operator, x)
            ff = solver.farfield(0.0, 0.0, HemisphereGrid(128), waist_um=surface.size_um / 5)
        out[precision] = (mv, ff.brdf(), ff.diagnostics["solve_s"], ff.diagnostics["iterations"])
    bd, bs = out["double"][1], out["single"][1]
    lobe = np.isfinite(bd) & (bd > 1e-3 * np.nanmax(bd))
    err = np.linalg.norm((bs - bd)[lobe]) / np.linalg.norm(bd[lobe])
    print(f"N = {args.cells}: matvec single/double time ratio {out['single'][0] / out['double'][0]:.2f}; "
          f"solve time ratio {out['single'][2] / out['double'][2]:.2f} (iterations {out['single'][3]} vs "
          f"{out['double'][3]}); BRDF rel. L2 over the lobe single vs double {err:.2e}")
    print(load())


def cmd_fft(args, ctx):
    """Host scipy.fft (pruned) vs VkFFT (full padded) for the AIM FFTs of one product."""
    import pyopencl.array as cla
    from pyvkfft.opencl import VkFFTApp

    print(load())
    for cells in args.sizes:
        mesh = BEMMesh(aluminium_patch(cells))
        grid = build_grid(mesh, AIMOptions().grid_options(Media(0.4, AL_400), mesh.spacing_um, (0,)))
        for dtype in (np.complex128, np.complex64):
            q = (np.random.default_rng(0).standard_normal((16,) + grid.shape)).astype(dtype)
            Q = cla.zeros(ctx.queue, (16,) + grid.padded, dtype)
            app = VkFFTApp(Q.shape, dtype, ctx.queue, ndim=3, inplace=True, norm=1)
            host, device = math.inf, math.inf
            for _ in range(args.repeat):  # alternate to share the load fairly
                t0 = time.perf_counter()
                inverse_pruned(forward_pruned(q, grid.padded), grid.shape)
                host = min(host, time.perf_counter() - t0)
                t0 = time.perf_counter()
                app.fft(Q)
                app.ifft(Q)
                ctx.queue.finish()
                device = min(device, time.perf_counter() - t0)
            print(f"N = {cells}, FFT {grid.padded}, {np.dtype(dtype).name}, 16 transforms each way: host "
                  f"(pruned scipy) {host:.3f} s, VkFFT on {ctx.info.name} {device:.3f} s, ratio VkFFT/host "
                  f"{device / host:.2f}", flush=True)
    print(load())


def cmd_accuracy(args, ctx):
    """Matvec error vs the dense matrix as a function of the near radius (and grid spacing)."""
    from wavebrdf.solver.bem3d.assembly import assemble_dense
    from wavebrdf.solver.bem3d.elements import ElementIntegrals

    print(load())
    rng = np.random.default_rng(0)
    for lam, index, per in ((0.5, 1.5, 10.0), (0.4, AL_400, 12.8)):
        d = lam / per
        surface = generate("gaussian", cells=args.cells, size_um=args.cells * d, seed=args.cells,
                           rms_height_um=0.1 * lam, correlation_um=0.8 * lam)
        mesh = BEMMesh(surface)
        media = Media(lam, index)
        Z, _ = assemble_dense(ctx, mesh, media, ElementIntegrals(mesh, AIM_QUADRATURE, ctx))
        x = rng.standard_normal((2, mesh.n_unknowns)) + 1j * rng.standard_normal((2, mesh.n_unknowns))
        ref = x @ Z.T
        for options in args.variants:
            opts = AIMOptions(preconditioner="none", **json.loads(options))
            op = AIMOperator(ctx, mesh, media, opts)
            err = np.linalg.norm(op.matvec(x) - ref) / np.linalg.norm(ref)
            print(f"n = {index}, N = {args.cells}: {options:50s} error {err:.2e}, near "
                  f"{op.near.bytes() / mesh.n_unknowns:.0f} B/unknown, {op.grid.describe()}", flush=True)
    print(load())


def _single_run(ctx, surface, lam, index, waist, resolution, aim, estimate: dict | None = None):
    """One AIM solve at normal incidence, its estimate (``estimate``, or made here), stages and
    figures printed; returns the far field."""
    t0 = time.perf_counter()
    cpu0 = usage()["cpu_s"]
    from wavebrdf.solver.bem3d.aim.estimate import memory_breakdown

    if estimate is None:
        estimate = estimate_aim(surface, lam, index, aim=aim, waist_um=waist, resolution=resolution)
    print("estimate:", {k: v for k, v in estimate.items()}, flush=True)
    print(f"estimate: {estimate['bytes'] / 2**30:.2f} GiB ({memory_breakdown(estimate)}), {estimate['seconds']:.0f} s "
          f"(set-up {estimate['setup_s']:.0f} s, {estimate['iterations_guess']} products x {estimate['product_s']:.2f} s)",
          flush=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BEMWarning)
        solver = BEMSolver(ctx, surface, lam, index, method="aim", aim=aim)
        print("set-up:", json.dumps(solver.diagnostics["aim_setup"], default=str), flush=True)
        print("after set-up:", usage(), load(), flush=True)
        grid = HemisphereGrid(resolution)
        ff = solver.farfield(0.0, 0.0, grid, waist_um=waist)
    wall = time.perf_counter() - t0
    measured = albedo(ff.brdf(), grid)
    expected = ff.diagnostics["beam_reflectance"]
    d = ff.diagnostics
    print(f"unknowns {d['unknowns']}, iterations {d['iterations']}, residual {d['residual']}, solve {d['solve_s']:.1f} s, "
          f"far field {d['farfield_s']:.1f} s, near {d['near_bytes_per_unknown']:.0f} B/unknown, "
          f"matvec timings {d['matvec_timings']}")
    print(f"albedo {measured}, exact-beam reflectance {expected}, relative error {measured / expected - 1}, "
          f"unpolarized {measured.mean() / expected.mean() - 1:+.4f}")
    print("stages:\n" + format_stages(d["stages"]))
    print(f"wall {wall:.1f} s, CPU {usage()['cpu_s'] - cpu0:.1f} s, peak memory {usage()['peak_memory_gb']:.2f} GB; {load()}")
    return ff


PLANNER_SURFACES = {  # name → (λ µm, material, generator and parameters): none is in solver/data/aim_products.csv
    "rough-al-500": (0.5, "aluminium", dict(generator="gaussian", rms_height_um=0.09, correlation_um=1.2, seed=51)),
    "rough-al-700": (0.7, "aluminium", dict(generator="gaussian", rms_height_um=0.12, correlation_um=0.5, seed=52)),
    "brushed-glass-600": (0.6, "glass", dict(generator="brushed", rms_height_um=0.1, correlation_um=[2.0, 0.5],
                                             angle_deg=20.0, seed=53)),
    "rough-gold-600": (0.6, "gold", dict(generator="gaussian", rms_height_um=0.08, correlation_um=0.8, seed=54)),
    # round 4, chosen before the plasmon-binding model (commit after e3850b0) ran on them
    "rough-al-600": (0.6, "aluminium", dict(generator="gaussian", rms_height_um=0.05, correlation_um=0.6, seed=61)),
    "sinusoid-glass-550": (0.55, "glass", dict(generator="sinusoid", amplitude_um=0.06, period_um=0.7)),
    "brushed-gold-650": (0.65, "gold", dict(generator="brushed", rms_height_um=0.06, correlation_um=[1.5, 0.3],
                                            angle_deg=40.0, seed=63)),
    # round 5, chosen before the refit that adds round 4's rows ran on them
    "rough-copper-650": (0.65, "copper", dict(generator="gaussian", rms_height_um=0.07, correlation_um=0.8, seed=71)),
    "brushed-al-450-60deg": (0.45, "aluminium", dict(generator="brushed", rms_height_um=0.06,
                                                     correlation_um=[1.2, 0.4], angle_deg=60.0, seed=72)),
    "rough-glass-500": (0.5, "glass", dict(generator="gaussian", rms_height_um=0.08, correlation_um=0.6, seed=73)),
    # round 6, chosen before it ran on the fit of rounds 1–4 (round 5 still a check)
    "rough-silver-550": (0.55, "silver", dict(generator="gaussian", rms_height_um=0.06, correlation_um=0.7, seed=81)),
    "sinusoid-al-500-30deg": (0.5, "aluminium", dict(generator="sinusoid", amplitude_um=0.05, period_um=0.9,
                                                     angle_deg=30.0)),
    "brushed-glass-450-70deg": (0.45, "glass", dict(generator="brushed", rms_height_um=0.07, correlation_um=[1.0, 0.3],
                                                    angle_deg=70.0, seed=83)),
}


def cmd_planner(args, ctx):
    """The planner's product count against the measured one on surfaces outside its fit
    (PLANNER_SURFACES) at ``--cells`` and d = λ/16, exact beam of waist L/4.8, normal incidence,
    with ``--aim`` (default: the planner's choice at the 12 µm sub-area). Prints the table and
    each run as a row of solver/data/aim_products.csv (to add it to the fit once it has served
    as a check: tools/refit_product_counts.py)."""
    from wavebrdf.solver.bem3d.aim.flat_patch import FLAT_INNER_STEPS
    from wavebrdf.solver.materials import Material

    print(load())
    aim = json.loads(args.aim)
    run_as = AIMOptions.from_mapping(aim)  # the data file's kinds: MINRES alone, local inverses or the flat patch with (F)GMRES(30)
    kind = {("none", "csym"): "minres", ("local", "gmres"): "local",
            ("flat-patch", "gmres"): "flat-patch"}.get((run_as.preconditioner, run_as.solver))
    if kind in ("local", "flat-patch") and run_as.restart != 30 or \
            kind == "flat-patch" and run_as.flat_inner_steps != FLAT_INNER_STEPS:
        kind = None
    rows, records = [], []
    command = (".venv/bin/python benchmarks/bench_aim.py " + shlex.join(sys.argv[1:])).replace('"', '""')  # a CSV field
    for name in args.surfaces:
        lam, material, params = PLANNER_SURFACES[name]
        params = dict(params)
        generator = params.pop("generator")
        size = round(args.cells * lam / 16, 6)
        surface = generate(generator, cells=args.cells, size_um=size, **params)
        index = complex(Material.from_name(material).index(lam))
        print(f"{name}: {material} at {lam} µm (n = {index:.4g}), L = {size:g} µm, {surface.statistics()}", flush=True)
        waist = surface.size_um / 4.8
        planned = estimate_aim(surface, lam, index, aim=aim, waist_um=waist, resolution=args.resolution)
        ff = _single_run(ctx, surface, lam, index, waist, args.resolution, aim, planned)
        measured = ff.diagnostics["iterations"]
        rows.append((name, material, lam, surface.rms_slope_below(lam), planned["iterations_guess"], measured))
        spec = json.dumps({"generator": generator, "cells": args.cells, "size_um": size, **params}).replace('"', '""')
        records.append(f'"{name}: {material}, {generator}",{kind},check,{lam},{index.real:.6g}{index.imag:+.6g}j,"{spec}",'
                       f"{measured[0]},{measured[1]},\"{command}\",<commit>")
    print("| surface | material, λ | rms slope finer than λ | planned products | measured (s / p) | planner error (s / p) |")
    for name, material, lam, slope, planned, measured in rows:
        errors = " / ".join(f"{planned / m - 1:+.0%}" for m in measured)
        print(f"| {name} | {material}, {lam} µm | {slope:.3f} | {planned} | {' / '.join(str(m) for m in measured)} | "
              f"{errors} |")
    if kind is not None:  # <commit>: the commit of the code that ran
        print("rows of solver/data/aim_products.csv:\n" + "\n".join(records))


def cmd_reference(args, ctx):
    """The reference simulator's CPU case: 4 µm flat dielectric, n = 1.5, λ = 0.5, d = 0.025,
    waist 1.6 µm, normal incidence, 256² output (it took 5169 CPU-s, 4.8 GB, albedo error 1.35%).
    ``--size`` enlarges the patch at the same d (truncation study), ``--aim`` adds AIM options,
    ``--edge pinned`` stops the currents at the border instead of continuing the flat interface."""
    print(load())
    surface = generate("flat", cells=round(args.size / 0.025), size_um=args.size)
    _single_run(ctx, surface, 0.5, 1.5, args.waist, 256,
                {"precision": args.precision, "edge": args.edge, **json.loads(args.aim)})


def cmd_truncation(args, ctx):
    """Dense LU vs AIM on the reference geometry (4 µm flat glass, waist 1.6 µm) at d = λ/8: how
    much of the albedo error belongs to the truncated patch rather than to AIM; and AIM with the
    patch continued as the flat interface (aim.edge = "flat")."""
    print(load())
    surface = generate("flat", cells=64, size_um=4.0)
    grid = HemisphereGrid(256)
    brdf = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BEMWarning)
        runs = {
            "AIM": lambda: BEMSolver(ctx, surface, 0.5, 1.5, method="aim"),
            "dense": lambda: BEMSolver(ctx, surface, 0.5, 1.5),
            "AIM, flat continuation": lambda: BEMSolver(ctx, surface, 0.5, 1.5, method="aim",
                                                        aim={"edge": "flat"}),
        }
        for name, make in runs.items():
            t0 = time.perf_counter()
            ff = make().farfield(0.0, 0.0, grid, waist_um=args.waist)
            measured, expected = albedo(ff.brdf(), grid), ff.diagnostics["beam_reflectance"]
            brdf[name] = ff.brdf()
            print(f"{name}: {ff.diagnostics['unknowns']} unknowns, albedo {measured}, exact beam {expected}, "
                  f"relative error {measured / expected - 1}, {time.perf_counter() - t0:.0f} s", flush=True)
    ref = brdf["dense"]
    lobe = np.isfinite(ref) & (ref > 1e-3 * np.nanmax(ref))
    print(f"AIM vs dense BRDF rel. L2 over the lobe {np.linalg.norm((brdf['AIM'] - ref)[lobe]) / np.linalg.norm(ref[lobe]):.1e}")
    print(load())


def cmd_continuation(args, ctx):
    """A bump (0.1 µm high, radius 0.3 µm) on a flat interface, λ = 0.5 µm, waist 0.8 µm: continued
    patches (aim.edge = "flat", border at 1.25 w and 1.9 w) and pinned ones (1.25 w, 2.5 w, 3.1 w),
    BRDF over the lobe of every pair; on glass and on aluminium (surface plasmons)."""
    print(load())
    lam, d, waist = 0.5, 0.5 / args.per_wavelength, 0.8
    grid = HemisphereGrid(96)
    runs = (("pinned 4 µm", 4.0, "pinned"), ("pinned 5 µm", 5.0, "pinned"), ("continued 2 µm", 2.0, "flat"),
            ("continued 3 µm", 3.0, "flat"), ("pinned 2 µm", 2.0, "pinned"))
    for index in (1.5, AL_400):
        brdf = {}
        for name, size, edge in runs:
            n = round(size / d)
            x = np.linspace(-size / 2, size / 2, n + 1)
            X, Y = np.meshgrid(x, x, indexing="ij")
            surface = HeightField(0.1 * np.exp(-(X**2 + Y**2) / 0.3**2), size)
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", BEMWarning)
                solver = BEMSolver(ctx, surface, lam, index, method="aim", z_reference=0.0, aim={"edge": edge})
                ff = solver.farfield(args.theta, 0.0, grid, waist_um=waist)
            brdf[name] = ff.brdf()
            print(f"n = {index}, {name}: {ff.diagnostics['unknowns']} unknowns, albedo {albedo(ff.brdf(), grid)}, "
                  f"products {ff.diagnostics['iterations']}, {time.perf_counter() - t0:.0f} s", flush=True)
        names = list(brdf)
        for i, a in enumerate(names):
            lobe = np.isfinite(brdf[a]) & (brdf[a] > 1e-3 * np.nanmax(brdf[a]))
            for b in names[i + 1 :]:
                err = np.linalg.norm((brdf[b] - brdf[a])[lobe]) / np.linalg.norm(brdf[a][lobe])
                print(f"n = {index}: {b} vs {a}: BRDF rel. L2 over the lobe {err:.2e}")
    print(load())


def subarea_surface(cells: int, d: float = 0.025, seed: int = 1) -> HeightField:
    """The reference simulator's sub-area at ``cells`` (480: its 12 µm, 481² heights): random
    bumps of 0.1 µm rms height (Gaussian correlation 1 µm) at d = 0.025 µm."""
    return generate("gaussian", cells=cells, size_um=cells * d, seed=seed, rms_height_um=0.1, correlation_um=1.0)


def cmd_subarea(args, ctx):
    """The reference simulator's flagship sub-area (12 µm, 481² heights, 919 680 unknowns) or a
    smaller one at the same d (``--cells``): aluminium at λ = 0.4 µm, exact beam of waist
    L/4.8 (2.5 µm at 12 µm), normal incidence, 1024² output; AIM settings chosen by the planner
    for ``--memory-gb`` (solver/bem3d/aim/budget.py); those ``--aim`` gives are changed only
    where they do not fit it (``fit_speed`` false).
    Prints the plan's memory and time, then the measured stage breakdown."""
    from wavebrdf.solver.bem3d.aim.budget import fit_to_budget, given_options

    print(load())
    surface = subarea_surface(args.cells)
    waist = surface.size_um / 4.8
    print(f"surface: {surface.cells} cells, {surface.size_um:g} µm, {surface.statistics()}")
    aim = given_options(json.loads(args.aim))
    if args.memory_gb:
        fit = fit_to_budget(surface, 0.4, AL_400, aim, args.memory_gb * 2**30, waist_um=waist,
                            resolution=args.resolution)
        print("planner:", fit.summary(), flush=True)
        aim = fit.options
    ff = _single_run(ctx, surface, 0.4, AL_400, waist, args.resolution, aim)
    d = ff.diagnostics
    print(f"memory per unknown {peak_memory_mb() * 2**20 / d['unknowns']:.0f} B; system CPU share "
          f"{resource.getrusage(resource.RUSAGE_SELF).ru_stime / max(usage()['cpu_s'], 1e-9):.3f}")
    if args.save:
        np.save(args.save, ff.brdf())
    if args.compare:
        from wavebrdf.solver.metrics import relative_l2

        ref = np.load(args.compare)
        grid = HemisphereGrid(args.resolution)
        mine = ff.brdf()
        print(f"vs {args.compare}: BRDF relative L2 (s, p) {relative_l2(mine, ref, grid)}, albedo "
              f"{albedo(mine, grid)} vs {albedo(ref, grid)}")


# (label, wavelength µm, index, surface): the planner's unpreconditioned settings on small
# patches at d = λ/16 (the aluminium patch: λ/12.8) whose roughness and correlation differ
PRODUCT_CASES = (
    ("Al, rms 0.1 µm, T 1 µm (sub-area family)", 0.4, AL_400, lambda: subarea_surface(96)),
    ("Al, rms 0.088 µm, T 1.8 µm", 0.4, AL_400,
     lambda: generate("gaussian", cells=96, size_um=2.4, seed=1, rms_height_um=0.088, correlation_um=1.8)),
    ("Al, rms 0.2 µm, T 1 µm", 0.4, AL_400,
     lambda: generate("gaussian", cells=96, size_um=2.4, seed=1, rms_height_um=0.2, correlation_um=1.0)),
    ("Al, flat", 0.4, AL_400, lambda: generate("flat", cells=96, size_um=2.4)),
    ("Al, scale-run family at d = λ/12.8", 0.4, AL_400, lambda: aluminium_patch(96)),
    ("glass, the sub-area family scaled to λ = 0.5", 0.5, 1.5,
     lambda: generate("gaussian", cells=96, size_um=3.0, seed=1, rms_height_um=0.125, correlation_um=1.25)),
    ("Al, rms 0.1 µm, T 1 µm, 1.6 µm", 0.4, AL_400,
     lambda: generate("gaussian", cells=64, size_um=1.6, seed=2, rms_height_um=0.1, correlation_um=1.0)),
    ("Al, rms 0.05 µm, T 0.5 µm, 1.6 µm", 0.4, AL_400,
     lambda: generate("gaussian", cells=64, size_um=1.6, seed=2, rms_height_um=0.05, correlation_um=0.5)),
    ("glass, rms 0.06 µm, T 0.5 µm, 1.5 µm", 0.5, 1.5,
     lambda: generate("gaussian", cells=48, size_um=1.5, seed=2, rms_height_um=0.06, correlation_um=0.5)),
)


def cmd_products(args, ctx):
    """MINRES products without a preconditioner (single precision, the interior off the grid
    where the radius allows: the planner's choice at scale) against ``estimate_aim``'s count, on
    the small patches of PRODUCT_CASES; exact beam of waist L/4.8 at normal incidence."""
    from wavebrdf.solver.bem3d.aim.budget import interior_leaves_grid_cells

    print(load())
    for label, lam, index, make in PRODUCT_CASES[slice(*args.cases)]:
        surface = make()
        aim = AIMOptions(precision="single", preconditioner="none", solver="csym")
        off = interior_leaves_grid_cells(aim, Media(lam, index), surface.spacing_um)
        aim = AIMOptions(precision="single", preconditioner="none", solver="csym",
                         near_cells=aim.near_cells if off is None else off)
        waist = surface.size_um / 4.8
        guess = estimate_aim(surface, lam, index, aim=aim, waist_um=waist)["iterations_guess"]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", BEMWarning)
            solver = BEMSolver(ctx, surface, lam, index, method="aim", aim=aim)
            measured = solver.farfield(0.0, 0.0, HemisphereGrid(64), waist_um=waist).diagnostics["iterations"]
        print(f"{label}: L/λ {surface.size_um / lam:.1f}, rms slope {surface.statistics()['rms_slope']:.3f}, "
              f"near_cells {aim.near_cells:g}: products {measured}, estimate {guess} "
              f"({guess / np.mean(measured) - 1:+.0%})", flush=True)


PRECONDITIONER_CASES = {  # label → (wavelength µm, index, surface of N cells): rough metal and dielectric
    "aluminium": (0.4, AL_400, subarea_surface),
    "glass": (0.5, 1.5, lambda cells: generate("gaussian", cells=cells, size_um=cells * 0.03125, seed=1,
                                               rms_height_um=0.125, correlation_um=1.25)),
}
PRECONDITIONER_VARIANTS = {  # label → AIM options over single precision
    "none (MINRES)": {"preconditioner": "none", "solver": "csym"},
    "local inverses, 4-cell tiles (GMRES(30))": {"preconditioner": "local", "restart": 30},
    "near LU, whole patch (GMRES(60))": {"preconditioner": "near"},
    "flat interface, damped (GMRES(30))": {"preconditioner": "flat", "restart": 30},
    "flat patch, 16 inner steps (FGMRES(30))": {"preconditioner": "flat-patch", "restart": 30},
}


def cmd_preconditioners(args, ctx):
    """Each preconditioner on the same patches (``--cells``: 160 is 101 760 unknowns): the sub-area
    family in aluminium at 0.4 µm and scaled to glass at 0.5 µm (d = λ/16), exact beam of waist
    L/4.8, normal incidence, single precision. Per variant: products, the preconditioner's set-up
    and bytes per unknown, solve and total time of a fresh solver, and the BRDF against the first."""
    from wavebrdf.solver.metrics import relative_l2

    print(load())
    grid = HemisphereGrid(args.resolution)
    for case in args.cases:
        lam, index, make = PRECONDITIONER_CASES[case]
        surface = make(args.cells)
        waist = surface.size_um / 4.8
        first = None
        for label in args.variants:
            aim = AIMOptions.from_mapping({"precision": "single", "warm_start": False,
                                           **PRECONDITIONER_VARIANTS[label]})
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", BEMWarning)
                solver = BEMSolver(ctx, surface, lam, index, method="aim", aim=aim)
                ff = solver.farfield(0.0, 0.0, grid, waist_um=waist)
            total = time.perf_counter() - t0
            pc = solver.operator.preconditioner
            n = solver.mesh.n_unknowns
            brdf = ff.brdf()
            first = brdf if first is None else first
            print(f"{case}, N = {args.cells} ({n} unknowns, L/λ {surface.size_um / lam:.1f}, rms slope "
                  f"{surface.statistics()['rms_slope']:.3f}): {label}: products {ff.diagnostics['iterations']}, "
                  f"preconditioner {0 if pc is None else pc.seconds:.1f} s and "
                  f"{0 if pc is None else pc.bytes() / n:.0f} B per unknown (applied {0 if pc is None else pc.apply_s:.1f} s), "
                  f"solve {ff.diagnostics['solve_s']:.1f} s, total {total:.1f} s, process peak so far {peak_memory_mb() / 1024:.2f} GiB; "
                  f"BRDF vs the first variant {relative_l2(brdf, first, grid)}", flush=True)
            del solver, ff
    print(load())


def cmd_flat_patch(args, ctx):
    """The flat-patch preconditioner alone at ``--cells`` (aluminium at 0.4 µm, d = 0.025 µm: the
    12 µm sub-area's lattice at 480): its set-up time and peak memory, then one application (16
    inner steps, both polarizations) and the products of T and of the damped circulant alone,
    fastest of ``--repeat`` (the planner's ``flat_patch_*`` and ``flat_apply_s`` rows)."""
    from wavebrdf.solver.bem3d.aim.flat_patch import FlatPatchPreconditioner

    print(load())
    mesh = BEMMesh(generate("flat", cells=args.cells, size_um=args.cells * 0.025))
    before = resident_memory_mb()
    t0 = time.perf_counter()
    pc = FlatPatchPreconditioner(ctx, mesh, Media(0.4, AL_400))
    setup = time.perf_counter() - t0
    print(f"{args.cells} cells ({mesh.n_unknowns} unknowns): set-up {setup:.1f} s (T on a {pc.operator.torus} torus, "
          f"the circulant on {pc.circulant.torus}); resident before {before:.0f} MB, process peak {peak_memory_mb():.0f} "
          f"MB; kept {pc.bytes() / 2**20:.0f} MB ({pc.bytes() / mesh.n_unknowns:.0f} B per unknown)")
    X = np.random.default_rng(1).standard_normal((2, mesh.n_unknowns)).astype(np.complex64)

    def fastest(f):
        times = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            f()
            times.append(time.perf_counter() - t0)
        return min(times)

    whole, T, C = fastest(lambda: pc(X)), fastest(lambda: pc.operator(X)), fastest(lambda: pc.circulant(X))
    steps = pc.steps
    print(f"both polarizations: one application ({steps} inner steps) {whole:.3f} s; T alone {T:.3f} s, the circulant "
          f"alone {C:.3f} s; the inner GMRES's own work {(whole - steps * (T + C)) / steps:.3f} s per step")
    points = pc.operator.torus[0] * pc.operator.torus[1]
    print(f"per polarization: (application / {steps} − circulant) per Toeplitz torus point "
          f"{(whole / steps - C) / 2 / points:.3g} s; circulant per its torus point "
          f"{C / 2 / (pc.circulant.torus[0] * pc.circulant.torus[1]):.3g} s")
    print(load())


def cmd_scale(args, ctx):
    """12.5 µm aluminium patch at λ = 0.4 µm, d = λ/12.8 = 0.03125 µm (N = 400, 638 400 unknowns),
    exact beam of waist L/5, normal incidence; single precision and storage unless ``--aim`` says more."""
    print(load())
    surface = aluminium_patch(args.cells)
    print(f"surface: {surface.cells} cells, {surface.size_um:g} µm, {surface.statistics()}")
    _single_run(ctx, surface, 0.4, AL_400, args.waist or surface.size_um / 5, args.resolution,
                {"precision": args.precision, "near_storage": "single", **json.loads(args.aim)})
    print(f"system CPU share {resource.getrusage(resource.RUSAGE_SELF).ru_stime / max(usage()['cpu_s'], 1e-9):.3f}")


def main():
    freeze_kernel_sources()
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("matvec")
    p.add_argument("--sizes", type=int, nargs="+", default=[96, 160, 256])
    p.add_argument("--precision", default="double")
    p.add_argument("--repeat", type=int, default=7, help="products per size; the fastest is reported")
    p = sub.add_parser("solve")
    p.add_argument("--sizes", type=int, nargs="+", default=[64, 128, 192])
    p.add_argument("--precision", default="single")
    p = sub.add_parser("solvers")
    p.add_argument("--cells", type=int, default=32)
    p = sub.add_parser("precision")
    p.add_argument("--cells", type=int, default=96)
    p = sub.add_parser("fft")
    p.add_argument("--sizes", type=int, nargs="+", default=[128, 400])
    p.add_argument("--repeat", type=int, default=5)
    p = sub.add_parser("accuracy")
    p.add_argument("--cells", type=int, default=24)
    p.add_argument("--variants", nargs="+", default=[
        '{"near_cells": 4}', '{"near_cells": 5}', '{"near_cells": 6}', '{"near_cells": 7}', '{"near_cells": 8}',
        '{"near_cells": 6, "spacing_cells": 1.6, "max_k_spacing": 9}', '{"near_cells": 6, "projection": "moments"}',
        '{"near_cells": 6, "near_storage": "double"}'])
    p = sub.add_parser("reference")
    p.add_argument("--waist", type=float, default=1.6)
    p.add_argument("--size", type=float, default=4.0, help="patch side (µm) at d = 0.025 µm")
    p.add_argument("--precision", default="double")
    p.add_argument("--aim", default="{}", help='AIM options as JSON, e.g. \'{"near_cells": 8}\'')
    p.add_argument("--edge", default="flat", choices=("flat", "pinned"),
                   help="patch border: continued as the flat interface, or currents pinned to zero")
    p = sub.add_parser("truncation")
    p.add_argument("--waist", type=float, default=1.6)
    p = sub.add_parser("continuation")
    p.add_argument("--theta", type=float, default=0.4, help="incidence (rad)")
    p.add_argument("--per-wavelength", type=float, default=10.0, help="cells per wavelength")
    p = sub.add_parser("subarea")
    p.add_argument("--cells", type=int, default=480)
    p.add_argument("--memory-gb", type=float, default=8.0, help="budget the planner fits (0: use --aim as given)")
    p.add_argument("--resolution", type=int, default=1024)
    p.add_argument("--aim", default="{}", help="AIM options as JSON")
    p.add_argument("--save", default=None, help="write the BRDF (.npy)")
    p.add_argument("--compare", default=None, help="a saved BRDF (.npy) to compare with (relative L2, albedo)")
    p = sub.add_parser("planner")
    p.add_argument("--cells", type=int, default=160)
    p.add_argument("--surfaces", nargs="+", default=list(PLANNER_SURFACES), choices=list(PLANNER_SURFACES))
    p.add_argument("--resolution", type=int, default=128)
    p.add_argument("--aim", default='{"precision": "single", "near_cells": 7, "preconditioner": "local", "restart": 30}',
                   help="AIM options as JSON")
    p = sub.add_parser("products")
    p.add_argument("--cases", type=int, nargs=2, default=[0, len(PRODUCT_CASES)], help="a slice of PRODUCT_CASES")
    p = sub.add_parser("preconditioners")
    p.add_argument("--cells", type=int, default=160)
    p.add_argument("--cases", nargs="+", default=list(PRECONDITIONER_CASES), choices=list(PRECONDITIONER_CASES))
    p.add_argument("--variants", nargs="+", default=list(PRECONDITIONER_VARIANTS), choices=list(PRECONDITIONER_VARIANTS))
    p.add_argument("--resolution", type=int, default=128)
    p = sub.add_parser("flat-patch")
    p.add_argument("--cells", type=int, default=480)
    p.add_argument("--repeat", type=int, default=3)
    p = sub.add_parser("scale")
    p.add_argument("--cells", type=int, default=400)
    p.add_argument("--waist", type=float, default=None)
    p.add_argument("--precision", default="single")
    p.add_argument("--resolution", type=int, default=256)
    p.add_argument("--aim", default="{}", help='more AIM options as JSON, e.g. \'{"preconditioner": "none", '
                   '"solver": "csym"}\' (the issue-18 run)')
    args = parser.parse_args()
    ctx = create_context()
    print(f"device: {ctx.describe()}")
    globals()[f"cmd_{args.command.replace('-', '_')}"](args, ctx)
    print("usage:", usage())


if __name__ == "__main__":
    main()
