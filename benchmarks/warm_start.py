"""Warm starts and set-up reuse across a sub-area's wavelengths (docs/aim.md quotes its output).

One sub-area of the reference simulator's family (random bumps of 0.1 µm rms height, correlation
1 µm, d = 0.025 µm, aluminium from its wvl.txt rows, exact beam of waist L/4.8) solved at
consecutive wavelengths twice: cold (every solve from zero and every set-up whole,
``[model.aim] warm_start = false``, ``reuse_setup = false``) and warm (each solve from the
previous wavelength's solution, bem3d/warm_start.py, and each set-up with the static singular
tables of the first, elements.py ``StaticTables``: a study's defaults). Prints per wavelength
the products per polarization, the initial residual of the guess, the static tables' seconds,
the set-up, Krylov and total wall and CPU seconds, the warm result's BRDF relative L2 and albedo
change against the cold one, and the CPU ratios cold/warm of the wavelengths after the first
and of the whole sweep.

    # the acceptance case: one ≥ 10⁵-unknown sub-area (192 cells, 4.8 µm, 146 688 unknowns),
    # settings fitted to 8 GiB, 3 wavelengths (tens of minutes on the 2-core machine)
    .venv/bin/python benchmarks/warm_start.py --cells 192 --memory-gb 8
    # the reference's 12 µm sub-area (481² heights, 919 680 unknowns): hours
    .venv/bin/python benchmarks/warm_start.py --cells 480 --memory-gb 8 --resolution 1024
    # the small check docs/aim.md quotes (≤ 2·10⁴ unknowns, a minute or two)
    .venv/bin/python benchmarks/warm_start.py --cells 64

Other agents may share the cores: compare the ratios of one run, not absolute times.
"""

from __future__ import annotations

import argparse
import json
import os
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from wavebrdf.solver.bem3d import BEMSolver, BEMWarning
from wavebrdf.solver.bem3d.aim import AIMOptions
from wavebrdf.solver.bem3d.aim.budget import fit_to_budget, given_options
from wavebrdf.solver.bem3d.warm_start import WarmStarts
from wavebrdf.solver.farfield import HemisphereGrid, albedo
from wavebrdf.solver.metrics import relative_l2
from wavebrdf.solver.opencl import create_context
from wavebrdf.solver.surface import generate

ALUMINIUM = Path(__file__).resolve().parents[1] / "solver" / "data" / "aluminium_bemsim.csv"


def load() -> str:
    one, five, _ = os.getloadavg()
    return f"load average {one:.2f} (1 min), {five:.2f} (5 min) on {os.cpu_count()} CPUs"


def cpu_s() -> float:
    t = os.times()
    return t.user + t.system


def pair(values, spec: str) -> str:
    """Per-polarization figures as "a / b"."""
    return " / ".join(format(float(v), spec) for v in values)


def sweep(ctx, surface, rows, aim: AIMOptions, waist: float, theta: float, phi: float, grid, warm: WarmStarts | None):
    """One solve per (λ, index) row in order, each set-up given the static tables the previous one
    kept (with ``aim.reuse_setup``); per row (BRDF (2, R, R), figures)."""
    out = []
    static = None
    for lam, index in rows:
        t0, c0 = time.perf_counter(), cpu_s()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", BEMWarning)
            solver = BEMSolver(ctx, surface, lam, index, method="aim", aim=aim, warm_starts=warm,
                               static_tables=static)
            setup_wall, setup_cpu = time.perf_counter() - t0, cpu_s() - c0
            static = solver.operator.static_tables
            ff = solver.farfield(theta, phi, grid, waist_um=waist)
        d = ff.diagnostics
        out.append((ff.brdf(), {
            "wavelength_um": lam, "products": d["iterations"], "initial_residual": d.get("initial_residual"),
            "static_s": d["aim_setup"]["near_detail"]["element_static_s"],
            "setup_s": setup_wall, "setup_cpu_s": setup_cpu, "krylov_s": d["solve_s"],
            "wall_s": time.perf_counter() - t0, "cpu_s": cpu_s() - c0, "unknowns": d["unknowns"]}))
        del solver
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cells", type=int, default=64, help="cells per side at d = 0.025 µm")
    parser.add_argument("--wavelengths", type=int, nargs="+", default=[0, 1, 2],
                        help="rows of the reference's aluminium table (0.4 + 0.012 k µm)")
    parser.add_argument("--theta", type=float, default=0.0, help="incidence θ_i (degrees)")
    parser.add_argument("--phi", type=float, default=0.0, help="incidence φ_i (degrees)")
    parser.add_argument("--resolution", type=int, default=256)
    parser.add_argument("--memory-gb", type=float, default=0.0, help="fit the AIM settings to this budget")
    parser.add_argument("--aim", default="{}", help='AIM options as JSON, e.g. \'{"preconditioner": "none"}\'')
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()

    print(load())
    ctx = create_context()
    table = np.loadtxt(ALUMINIUM, delimiter=",", comments="#")
    rows = [(float(table[k, 0]), complex(table[k, 1], -table[k, 2])) for k in args.wavelengths]
    d = 0.025
    surface = generate("gaussian", cells=args.cells, size_um=args.cells * d, seed=args.seed, rms_height_um=0.1,
                       correlation_um=1.0)
    waist = surface.size_um / 4.8
    aim = given_options(json.loads(args.aim))
    if args.memory_gb:
        fit = fit_to_budget(surface, rows[0][0], rows[0][1], aim, args.memory_gb * 2**30, waist_um=waist,
                            resolution=args.resolution)
        print("planner:", fit.summary(), flush=True)
        aim = fit.options
    print(f"surface: {surface.cells} cells, {surface.size_um:g} µm; wavelengths {[r[0] for r in rows]} µm; "
          f"θ_i {args.theta:g}°, φ_i {args.phi:g}°; settings {json.dumps(aim.__dict__, default=str)}", flush=True)
    grid = HemisphereGrid(args.resolution)
    theta, phi = np.deg2rad(args.theta), np.deg2rad(args.phi)
    cold = sweep(ctx, surface, rows, replace(aim, warm_start=False, reuse_setup=False), waist, theta, phi, grid, None)
    warm = sweep(ctx, surface, rows, replace(aim, warm_start=True, reuse_setup=True), waist, theta, phi, grid,
                 WarmStarts())
    print(f"unknowns {cold[0][1]['unknowns']}")
    header = (f"{'λ µm':>7} {'run':>5} {'products':>12} {'initial r':>16} {'static s':>9} {'set-up s':>9} "
              f"{'Krylov s':>9} {'wall s':>8} {'CPU s':>8} {'BRDF L2 vs cold':>18} {'Δalbedo':>18}")
    print(header)
    for (b_cold, f_cold), (b_warm, f_warm) in zip(cold, warm):
        l2 = relative_l2(b_warm, b_cold, grid)
        dalb = albedo(b_warm, grid) - albedo(b_cold, grid)
        for name, f, extra in (("cold", f_cold, ""), ("warm", f_warm, f" {pair(l2, '.1e'):>18} {pair(dalb, '+.1e'):>18}")):
            r = "-" if f["initial_residual"] is None else pair(f["initial_residual"], ".3f")
            print(f"{f['wavelength_um']:>7.3f} {name:>5} {str(f['products']):>12} {r:>16} {f['static_s']:>9.1f} "
                  f"{f['setup_s']:>9.1f} {f['krylov_s']:>9.1f} {f['wall_s']:>8.1f} {f['cpu_s']:>8.1f}{extra}")
    steps_cold = sum(sum(f["products"]) for _, f in cold[1:])
    steps_warm = sum(sum(f["products"]) for _, f in warm[1:])
    cpu_cold, cpu_warm = sum(f["cpu_s"] for _, f in cold), sum(f["cpu_s"] for _, f in warm)
    later_cold, later_warm = sum(f["cpu_s"] for _, f in cold[1:]), sum(f["cpu_s"] for _, f in warm[1:])
    print(f"after the first wavelength: products cold {steps_cold}, warm {steps_warm} "
          f"({steps_warm / max(steps_cold, 1):.2f}x), CPU cold {later_cold:.1f} s, warm {later_warm:.1f} s "
          f"(ratio cold/warm {later_cold / max(later_warm, 1e-9):.2f}); whole sweep CPU cold {cpu_cold:.1f} s, "
          f"warm {cpu_warm:.1f} s (ratio {cpu_cold / max(cpu_warm, 1e-9):.2f}; the cold run's first solve also "
          f"builds the kernels); {load()}")


if __name__ == "__main__":
    main()
