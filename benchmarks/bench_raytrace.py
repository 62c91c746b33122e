"""Geometric-optics ray tracer benchmark (solver/approx/raytrace.py): rays per second of the OpenCL
kernels against the NumPy twin of the same estimator (one run, same rays), and the ray count and
time for a target noise over the lobe.

    python benchmarks/bench_raytrace.py [--resolution 512] [--target 0.01] [--rays 1048576 4194304]
    wavebrdf bench raytrace

Scene: a "typical" rough metal, Gaussian surface (401² nodes, 24 µm, σ = 0.15 µm, T = 1 µm: rms
slope 0.3), aluminium, θ_i = 30°, footprint waist 4 µm, GM (max_depth 64). Noise of an estimate
with R rays: the relative L2 difference of two independent seeds' unpolarized BRDFs over the lobe
(pixels ≥ 10% of the peak of their mean), divided by √2. The rays for the target are extrapolated
from the measured noise (the fitted power of R), then checked with one pair of runs when
``--verify`` is given. Timings on a shared 2-core machine are noisy: compare the ratios of one
run; the CPU time (all threads) is printed beside the wall time.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
from timing import best_of

from wavebrdf.solver.approx.raytrace import trace_paths
from wavebrdf.solver.farfield import HemisphereGrid
from wavebrdf.solver.models import SurfaceScene
from wavebrdf.solver.opencl import create_context
from wavebrdf.solver.surface import generate

ALUMINIUM = 0.46582 - 4.7119j


def scene(surface, resolution: int, precision: str = "double") -> SurfaceScene:
    return SurfaceScene(surface, 0.5, ALUMINIUM, np.deg2rad(30.0), 0.3, 4.0, HemisphereGrid(resolution),
                        precision=precision)


def brdf(ctx, sc, rays: int, seed: int) -> tuple[np.ndarray, float, float]:
    """Unpolarized BRDF, wall and CPU seconds of one run (geometry not kept)."""
    t0, c0 = time.perf_counter(), time.process_time()
    trace = trace_paths(ctx, sc, rays=rays, max_depth=64, seed=seed, keep=False)
    return np.nanmean(trace.result().brdf(), axis=0), time.perf_counter() - t0, time.process_time() - c0


def noise(ctx, sc, rays: int) -> tuple[float, float, float]:
    """(noise over the lobe, wall s, CPU s per run) from seeds 1 and 2."""
    (f1, t1, c1), (f2, t2, c2) = brdf(ctx, sc, rays, 1), brdf(ctx, sc, rays, 2)
    mean = 0.5 * (np.nan_to_num(f1) + np.nan_to_num(f2))
    lobe = sc.grid.inside & (mean >= 0.1 * mean.max())
    rel = np.sqrt(np.sum((f1 - f2)[lobe] ** 2) / np.sum(mean[lobe] ** 2)) / np.sqrt(2)
    return float(rel), 0.5 * (t1 + t2), 0.5 * (c1 + c2)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, default=512)
    parser.add_argument("--target", type=float, default=0.01, help="relative noise over the lobe")
    parser.add_argument("--rays", type=int, nargs="+", default=[1 << 20, 1 << 22], help="rays of the noise fit")
    parser.add_argument("--speed-rays", type=int, default=1 << 20)
    parser.add_argument("--numpy-rays", type=int, default=1 << 14)
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--verify", action="store_true", help="run the extrapolated ray count once")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    ctx = create_context()
    surface = generate("gaussian", cells=400, size_um=24.0, rms_height_um=0.15, correlation_um=1.0, seed=3)
    stats = surface.statistics()
    print(f"device: {ctx.describe()}")
    print(f"surface 401² nodes, 24 µm, σ = 0.15 µm, T = 1 µm (rms slope {stats['rms_slope']:.3f}), aluminium, "
          f"θ_i = 30°, waist 4 µm, GM max_depth 64")

    # 1. rays per second: kernels vs the NumPy twin, same rays
    sc = scene(surface, args.resolution)
    trace_paths(ctx, sc, rays=4096, max_depth=64)  # kernel build
    rates = {}
    for label, c, precision, rays in (("OpenCL (double)", ctx, "double", args.speed_rays),
                                      ("OpenCL (single)", ctx, "single", args.speed_rays),
                                      ("NumPy twin", None, "double", args.numpy_rays)):
        s = scene(surface, args.resolution, precision)
        cpu0 = time.process_time()
        t, tr = best_of(args.repeat, lambda: trace_paths(c, s, rays=rays, max_depth=64, keep=False))
        cpu = (time.process_time() - cpu0) / max(1, args.repeat)
        rates[label] = rays / t
        d = tr.diagnostics
        print(f"{label:18s} {rays:10d} rays  best {t:8.3f} s (CPU {cpu:7.3f} s)  {rays / t:12.4g} rays/s  "
              f"trace {d['time_trace_s']:.3f} s, weights {d['time_weights_s']:.3f} s, mean bounces "
              f"{d['mean_bounces']:.3f}")
    print(f"speed-up OpenCL/NumPy: {rates['OpenCL (double)'] / rates['NumPy twin']:.1f}x (double), "
          f"{rates['OpenCL (single)'] / rates['NumPy twin']:.1f}x (single)")
    # the same rays agree
    a = trace_paths(ctx, sc, rays=args.numpy_rays, max_depth=64, seed=7).intensity()
    b = trace_paths(None, sc, rays=args.numpy_rays, max_depth=64, seed=7).intensity()
    print(f"OpenCL vs NumPy on the same {args.numpy_rays} rays: max |ΔI| / max I = {np.abs(a - b).max() / b.max():.2e}")

    # 2. noise over the lobe against rays, extrapolated to the target
    print(f"\nnoise over the lobe at {args.resolution}² (two seeds, /√2):")
    measured = []
    for rays in args.rays:
        rel, wall, cpu = noise(ctx, sc, rays)
        measured.append((rays, rel, wall))
        print(f"  {rays:11d} rays: noise {rel:.4f}, {wall:.2f} s per run (CPU {cpu:.2f} s)")
    r = np.array([m[0] for m in measured], float)
    e = np.array([m[1] for m in measured])
    power = -np.polyfit(np.log(r), np.log(e), 1)[0] if len(r) > 1 else 0.5
    needed = int(r[-1] * (e[-1] / args.target) ** (1 / power))
    seconds = measured[-1][2] * needed / r[-1]
    print(f"  noise ∝ R^-{power:.2f}: {args.target:.2%} needs ~{needed:.3g} rays, ~{seconds:.0f} s per run here")
    for res, target in ((256, 0.02),):
        s = scene(surface, res)
        rel, wall, _ = noise(ctx, s, args.rays[-1])
        need = int(args.rays[-1] * (rel / target) ** (1 / power))
        print(f"  at {res}²: noise {rel:.4f} with {args.rays[-1]} rays → {target:.0%} needs ~{need:.3g} rays")
    if args.verify:
        rel, wall, cpu = noise(ctx, sc, needed)
        print(f"  check: {needed} rays → noise {rel:.4f}, {wall:.1f} s per run (CPU {cpu:.1f} s)")


if __name__ == "__main__":
    main()
