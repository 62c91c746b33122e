"""OHS all-incidence benchmark (approx.md §3.3 item 3): 32 incident directions on one surface,
wavelength, footprint and output grid, timed three ways in one run:

* ``ohs`` with ``transform = "all_incidence"``: one s-grid transform per (surface, λ, footprint),
  kept by the model instance, then a separable gridding + pixel assembly per direction;
* ``ohs`` with ``transform = "per_incidence"``: the exact chirp-z transform per direction;
* ``kirchhoff``: its exact per-direction Chebyshev/chirp-z transform (n_max + 1 orders).

    python benchmarks/bench_ohs.py [--cells 400] [--size 24] [--resolution 512] [--directions 32]

Reports the wall time of each (total over the directions, the s-grid build separately), the
ratios taken in this one run, and the largest all- vs per-incidence OHS difference (relative L2
over the lobe). Timings on a shared 2-core machine are noisy: compare ratios taken in one run.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from wavebrdf.solver.farfield import HemisphereGrid
from wavebrdf.solver.models import SurfaceScene, get_model
from wavebrdf.solver.opencl import create_context
from wavebrdf.solver.surface import generate


def directions(count: int, theta_max_deg: float) -> list[tuple[float, float]]:
    """``count`` directions spread over the cap θ ≤ θ_max (golden-angle spiral, equal projected area)."""
    golden = np.pi * (3 - np.sqrt(5))
    rho_max = np.sin(np.deg2rad(theta_max_deg))
    out = []
    for n in range(count):
        rho = rho_max * np.sqrt((n + 0.5) / count)
        out.append((float(np.arcsin(rho)), float((n * golden) % (2 * np.pi))))
    return out


def timed_run(ctx, model, scenes):
    t0 = time.perf_counter()
    results = [model.run(ctx, scene) for scene in scenes]
    return time.perf_counter() - t0, results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", type=int, default=400)
    parser.add_argument("--size", type=float, default=24.0, help="patch side, µm")
    parser.add_argument("--rms", type=float, default=0.1, help="rms height, µm")
    parser.add_argument("--correlation", type=float, default=1.0, help="correlation length, µm")
    parser.add_argument("--waist", type=float, default=4.0, help="footprint waist, µm")
    parser.add_argument("--wavelength", type=float, default=0.4, help="µm")
    parser.add_argument("--resolution", type=int, default=512)
    parser.add_argument("--directions", type=int, default=32)
    parser.add_argument("--theta-max", type=float, default=70.0, help="largest θ_i, degrees")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    ctx = create_context()
    surface = generate("gaussian", cells=args.cells, size_um=args.size, rms_height_um=args.rms,
                       correlation_um=args.correlation, seed=3)
    grid = HemisphereGrid(args.resolution)
    index = 0.46582 - 4.7119j
    scenes = [SurfaceScene(surface, args.wavelength, index, theta, phi, args.waist, grid)
              for theta, phi in directions(args.directions, args.theta_max)]
    ohs_all = get_model("ohs", {"transform": "all_incidence"})
    ohs_per = get_model("ohs", {"transform": "per_incidence"})
    kirchhoff = get_model("kirchhoff")
    warm = SurfaceScene(generate("flat", cells=16, size_um=4.0), args.wavelength, index, 0.1, 0.0, 0.7,
                        HemisphereGrid(16))
    for model in (ohs_all, ohs_per, kirchhoff):  # kernel builds out of the timings
        model.run(ctx, warm)
    ohs_all.release()

    t_all, res_all = timed_run(ctx, ohs_all, scenes)
    t_per, res_per = timed_run(ctx, ohs_per, scenes)
    t_kir, res_kir = timed_run(ctx, kirchhoff, scenes)
    build = res_all[0].diagnostics["sgrid_build_s"]
    worst = 0.0
    for a, b in zip(res_all, res_per):
        fa, fb = np.nan_to_num(a.brdf()), np.nan_to_num(b.brdf())
        lobe = fb > 1e-3 * fb.max()
        worst = max(worst, float(np.linalg.norm((fa - fb)[lobe]) / np.linalg.norm(fb[lobe])))
    n = len(scenes)
    d = res_all[0].diagnostics
    print(f"device: {ctx.describe()}")
    print(f"surface {args.cells + 1}² nodes, {args.size:g} µm, rms {args.rms:g} µm, λ {args.wavelength:g} µm, "
          f"waist {args.waist:g} µm, output {args.resolution}², {n} directions θ_i ≤ {args.theta_max:g}°")
    print(f"OHS s grid {d['sgrid_size']}² ({d['sgrid_mb']:.0f} MB); Kirchhoff "
          f"{res_kir[0].diagnostics['chebyshev_terms']} Chebyshev terms")
    print(f"{'path':34s} {'total (s)':>10s} {'per direction (s)':>18s}")
    print(f"{'OHS all incidences (incl. build)':34s} {t_all:10.3f} {(t_all - build) / n:18.4f}   build {build:.3f} s")
    print(f"{'OHS per incidence (chirp-z)':34s} {t_per:10.3f} {t_per / n:18.4f}")
    print(f"{'Kirchhoff per incidence':34s} {t_kir:10.3f} {t_kir / n:18.4f}")
    print(f"ratio Kirchhoff / OHS all-incidence: {t_kir / t_all:.1f}x; OHS per / all-incidence: {t_per / t_all:.2f}x")
    print(f"OHS all- vs per-incidence: largest relative L2 over the lobe {worst:.2e}")


if __name__ == "__main__":
    main()
