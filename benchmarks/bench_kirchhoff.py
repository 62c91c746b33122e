"""Kirchhoff benchmark (issue 2): a 401×401 height field (12.5 µm, λ = 0.4 µm, normal incidence,
waist 2.5 µm) at 1024² output, OpenCL path vs the NumPy reference path in the same run.

    python benchmarks/bench_kirchhoff.py [--repeat 3] [--resolution 1024]
    wavebrdf bench kirchhoff

Reports the best-of-N wall time of each path and their ratio, the stage split of the OpenCL path,
and the agreement of the two results. Timings on a shared 2-core machine are noisy: compare
ratios taken in one run.
"""

from __future__ import annotations

import argparse
import os
import warnings

import numpy as np
from timing import best_of

from wavebrdf.solver.approx.kirchhoff import kirchhoff_farfield, kirchhoff_farfield_numpy
from wavebrdf.solver.farfield import HemisphereGrid
from wavebrdf.solver.opencl import create_context
from wavebrdf.solver.precision import Precision
from wavebrdf.solver.surface import generate



def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--resolution", type=int, default=1024)
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    ctx = create_context()
    # rough aluminium like the reference simulator's "test" surface (rms 0.088 µm, T ≈ 1.8 µm)
    surface = generate("gaussian", cells=400, size_um=12.5, rms_height_um=0.0877, correlation_um=1.8, seed=3)
    grid = HemisphereGrid(args.resolution)
    run_args = (surface, 0.4, 0.46582 - 4.7119j, 0.0, 0.0, grid)
    kirchhoff_farfield(ctx, *run_args, waist_um=2.5)  # warm-up: kernel build
    t_cl, ff_cl = best_of(args.repeat, lambda: kirchhoff_farfield(ctx, *run_args, waist_um=2.5))
    t_np, ff_np = best_of(max(1, args.repeat - 1), lambda: kirchhoff_farfield_numpy(*run_args, waist_um=2.5))
    t_sp, ff_sp = best_of(args.repeat, lambda: kirchhoff_farfield(ctx, *run_args, waist_um=2.5, precision=Precision.SINGLE))
    err = np.abs(ff_cl.E - ff_np.E).max() / np.abs(ff_np.E).max()
    b_d, b_s = ff_cl.brdf(), ff_sp.brdf()
    err_single = np.sqrt(np.nansum((b_s - b_d) ** 2) / np.nansum(b_d**2))
    d = ff_cl.diagnostics
    print(f"device: {ctx.describe()}; FFT workers: {os.environ.get('WAVEBRDF_FFT_WORKERS', os.cpu_count())}")
    print(f"surface 401x401 nodes, 12.5 um, lambda 0.4 um, waist 2.5 um, output {args.resolution}^2, "
          f"{d['chebyshev_terms']} Chebyshev terms")
    print(f"{'path':28s} {'best time (s)':>14s}")
    print(f"{'OpenCL (double)':28s} {t_cl:14.3f}   fields {d['time_fields_s']:.3f} / transforms "
          f"{d['time_transform_s']:.3f} / assembly {d['time_assembly_s']:.3f}")
    print(f"{'OpenCL (single)':28s} {t_sp:14.3f}   BRDF relative L2 vs double {err_single:.2e}")
    print(f"{'NumPy reference':28s} {t_np:14.3f}")
    print(f"speed-up OpenCL/NumPy: {t_np / t_cl:.2f}x (double), {t_np / t_sp:.2f}x (single); "
          f"max |E_cl - E_np| / max |E_np| = {err:.2e}")


if __name__ == "__main__":
    main()
