"""Refit the AIM planner's set-up and product constants by measuring them again, and rewrite their
rows of solver/data/aim_cost.csv (value, command, commit, machine); the other rows stay as they are.

    .venv/bin/python tools/refit_aim_cost.py                       # the runs of record (~1 h, 6 GiB)
    .venv/bin/python tools/refit_aim_cost.py --cells 24 --flat-size 0.6 --resolution 64 --out /tmp/aim_cost.csv

Two runs of the full-wave solver, timed stage by stage (solver/stages.py):

* rough: benchmarks/bench_aim.py's sub-area (random bumps of 0.1 µm rms height, 1 µm
  correlation, d = 0.025 µm; ``--cells`` 480 is the 12 µm one), aluminium at λ = 0.4 µm, exact
  beam of waist L/4.8, normal incidence, ``--resolution`` pixels, the planner's settings of record
  (single precision, near_cells 7, no preconditioner, MINRES) unless ``--aim`` gives others;
* flat: the reference simulator's CPU case (flat glass, n = 1.5, λ = 0.5 µm, d = 0.025 µm) of
  side ``--flat-size`` (4 µm of record), waist side/2.5, default settings with the flat edge
  continuation (as ``bench_aim.py reference``), 256² pixels.

Fits: ``near_pair_s_rough``/``_flat`` = the near-field stage over the stored pairs;
``grid_setup_s_rough``/``_flat`` = projection + grid spectra + excitation over the unknowns;
``product_scale`` = the rough run's Krylov stage per operator call (over ``product_overhead``)
against the estimate's product time, times the scale in the file. ``--dry-run`` prints the
fits without writing. Small cases time kernel builds and Python overheads more than the
arithmetic: their figures test the tool, they are not constants to keep.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import subprocess
import sys
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REFIT = ("near_pair_s_rough", "near_pair_s_flat", "grid_setup_s_rough", "grid_setup_s_flat", "product_scale")
SETUP_STAGES = ("projection", "grid spectra", "excitation")
AL_400 = 0.46582 - 4.7119j  # aluminium at 0.4 µm, as benchmarks/bench_aim.py
RECORD_AIM = {"precision": "single", "near_cells": 7, "preconditioner": "none", "solver": "csym"}


def _git(*args: str) -> str:
    try:
        return subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return ""


def commit() -> str:
    """The code measured: HEAD's short hash, marked when tracked files differ from it."""
    head = _git("rev-parse", "--short", "HEAD").strip() or "unknown"
    return head + (" + uncommitted changes" if _git("status", "--porcelain", "--untracked-files=no").strip() else "")


def machine(ctx) -> str:
    """Cores, CPU model, memory and the OpenCL device of this machine."""
    model = platform.processor() or "unknown CPU"
    try:
        with open("/proc/cpuinfo") as fh:
            model = next(line.split(":", 1)[1].strip() for line in fh if line.startswith("model name"))
        with open("/proc/meminfo") as fh:
            total = next(int(line.split()[1]) for line in fh if line.startswith("MemTotal")) / 2**20
        memory = f"{total:.1f} GiB"
    except (OSError, StopIteration):
        memory = "memory unknown"
    return f"{os.cpu_count()}-core {model}, {memory}; {ctx.describe()}"


def measure(ctx, surface, wavelength_um: float, index: complex, waist_um: float, resolution: int, aim) -> dict:
    """One run's stage clocks and the estimate of the same run."""
    from wavebrdf.solver.bem3d import BEMSolver, BEMWarning, estimate_aim
    from wavebrdf.solver.farfield import HemisphereGrid

    estimate = estimate_aim(surface, wavelength_um, index, aim=aim, waist_um=waist_um, resolution=resolution)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BEMWarning)
        solver = BEMSolver(ctx, surface, wavelength_um, index, method="aim", aim=aim)
        ff = solver.farfield(0.0, 0.0, HemisphereGrid(resolution), waist_um=waist_um)
    iterations = ff.diagnostics["iterations"]
    return {"stages": ff.diagnostics["stages"], "estimate": estimate,
            "calls": max(iterations) if isinstance(iterations, (list, tuple)) else iterations}


def fits(rough: dict, flat: dict, cost: dict) -> dict[str, float]:
    """The refitted constants from the two runs (see the module docstring)."""
    out = {}
    for name, run in (("rough", rough), ("flat", flat)):
        stages, est = run["stages"], run["estimate"]
        out[f"near_pair_s_{name}"] = stages["near field"]["wall_s"] / est["near_nnz"]
        out[f"grid_setup_s_{name}"] = sum(stages[s]["wall_s"] for s in SETUP_STAGES) / est["unknowns"]
    per_call = rough["stages"]["Krylov solve"]["wall_s"] / max(rough["calls"], 1) / cost["product_overhead"]
    out["product_scale"] = cost["product_scale"] * per_call / rough["estimate"]["product_s"]
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cells", type=int, default=480, help="rough sub-area cells at d = 0.025 µm (480: 12 µm)")
    parser.add_argument("--flat-size", type=float, default=4.0, help="flat glass patch side (µm) at d = 0.025 µm")
    parser.add_argument("--resolution", type=int, default=1024, help="output pixels of the rough run")
    parser.add_argument("--aim", default=json.dumps(RECORD_AIM), help="AIM settings of the rough run (JSON)")
    parser.add_argument("--out", default=str(ROOT / "solver" / "data" / "aim_cost.csv"), help="the file written")
    parser.add_argument("--dry-run", action="store_true", help="print the fits, write nothing")
    args = parser.parse_args(argv)

    from wavebrdf.solver.fitted import fitted, fitted_rows, write_fitted
    from wavebrdf.solver.opencl import create_context
    from wavebrdf.solver.surface import generate

    ctx = create_context()
    rough_surface = generate("gaussian", cells=args.cells, size_um=args.cells * 0.025, seed=1, rms_height_um=0.1,
                             correlation_um=1.0)
    cells = round(args.flat_size / 0.025)
    flat_surface = generate("flat", cells=cells, size_um=cells * 0.025)
    rough = measure(ctx, rough_surface, 0.4, AL_400, rough_surface.size_um / 4.8, args.resolution,
                    json.loads(args.aim))
    flat = measure(ctx, flat_surface, 0.5, 1.5, flat_surface.size_um / 2.5, 256, {"edge": "flat"})
    values = fits(rough, flat, fitted("aim_cost"))
    command = "tools/refit_aim_cost.py " + " ".join(shlex.quote(a) for a in (argv if argv is not None else sys.argv[1:]))
    run = {"command": command.strip(), "commit": commit(), "machine": machine(ctx)}
    for name, value in values.items():
        print(f"{name} = {value:.3g}")
    if args.dry_run:
        return 0
    rows = fitted_rows("aim_cost")
    for row in rows:
        if row["name"] in values:
            row.update(value=f"{values[row['name']]:.3g}", **run)
    write_fitted(rows, args.out)
    print(f"wrote {args.out} ({', '.join(values)}: {run['command']}; {run['commit']}; {run['machine']})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
