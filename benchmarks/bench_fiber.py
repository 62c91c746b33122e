"""Fiber BEM benchmark (issue 6): time per (λ, θ_i) for N = 300 segments, split into assembly
(OpenCL kernels, and the NumPy/scipy reference in the same run), LU factorization, block solve
and far field; plus the Mie fast path for the same circle.

    python benchmarks/bench_fiber.py [--segments 300] [--repeat 3] [--phi-i 90]

Case: circle a = 1 µm, λ = 0.4 µm (the [P] validation case) at θ_i = 0 (m = 1.55) and at
θ_i = 60° (m = 1.55 - 0.05j, complex interior Hankel arguments). Best of ``--repeat`` for the
OpenCL path, one run of the reference (it is the slow one). On a shared 2-core machine absolute
times are noisy: compare the ratios taken within one run.
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np
from timing import best_of
import scipy.linalg

from wavebrdf.solver.fiber import FiberBEM, MieFiber, circle, fiber_media
from wavebrdf.solver.opencl import create_context

CASES = [("lossless, theta_i = 0", 1.55, 0.0), ("lossy, theta_i = 60 deg", 1.55 - 0.05j, np.radians(60.0))]



def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--segments", type=int, default=300)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--phi-i", type=int, default=90, help="incidence azimuths solved per (λ, θ_i)")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    ctx = create_context()
    shape = circle(1.0, args.segments)
    bem = FiberBEM(ctx, shape)
    lam = 0.4
    phi_i = 2 * np.pi * np.arange(args.phi_i) / args.phi_i
    print(f"device: {ctx.describe()}")
    print(f"circle a = 1 um, lambda = {lam} um, N = {args.segments} (matrix {4 * args.segments}^2), "
          f"{args.phi_i} phi_i x 2 polarizations = {2 * args.phi_i} right-hand sides, 360 phi_r bins")
    header = (f"{'case':26s} {'asm OpenCL':>10s} {'asm NumPy':>10s} {'NumPy/CL':>9s} {'LU':>7s} "
              f"{'solve':>7s} {'farfield':>9s} {'total CL':>9s} {'|dZ|/|Z|':>9s}")
    print(header)
    print("-" * len(header))
    for label, m, theta in CASES:
        media = fiber_media(lam, m, theta)
        bem.matrix(media)  # warm-up: kernel builds
        t_cl, z_cl = best_of(args.repeat, lambda: bem.matrix(media))
        t_np, z_np = best_of(1, lambda: bem.matrix(media, reference=True))
        t_lu, _ = best_of(args.repeat, lambda: scipy.linalg.lu_factor(z_cl))
        sol = bem.solve(lam, m, theta, phi_i)
        t_ff, _ = best_of(1, lambda: sol.scattering(bins=360))
        t_solve = sol.timings["solve_s"]
        total = t_cl + t_lu + t_solve + t_ff
        diff = np.abs(z_cl - z_np).max() / np.abs(z_np).max()
        print(f"{label:26s} {t_cl:10.3f} {t_np:10.3f} {t_np / t_cl:8.1f}x {t_lu:7.3f} {t_solve:7.3f} "
              f"{t_ff:9.3f} {total:9.3f} {diff:9.1e}")
    mie = MieFiber(1.0)
    for label, m, theta in CASES:
        t_mie, _ = best_of(args.repeat, lambda: mie.scattering(lam, m, theta, phi_i, bins=360))
        print(f"Mie fast path, {label}: {t_mie:.4f} s for the same outputs")
    print("times in seconds per (lambda, theta_i); 'asm' = moments + matrix assembly incl. read-back")


if __name__ == "__main__":
    main()
