"""The full wave's flat-interface Mueller matrix toward grazing (issue 32; docs/dataset.md).

Runs the case of tests/test_polarimetry.py ``test_flat_mueller_equals_fresnel`` (bem, AIM with the
flat edge continuation, λ = 0.4 µm, the mirror direction read bilinearly from the output grid)
at angles, patches, meshes and output resolutions the test does not reach, and prints the worst
normalized Mueller element's distance from Fresnel's (tests/references.py, independent of the
code under test).

    .venv/bin/python benchmarks/grazing_mueller.py --size 2.4 --cells 48 72 --waist 6 \\
        --angles 80 --resolutions 1024 --materials aluminium glass
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from references import ALUMINIUM_400NM, fresnel_coefficients, fresnel_mueller, gaussian_beam_power_ratio  # noqa: E402
from test_polarimetry import _at_mirror, _scene  # noqa: E402

from wavebrdf.solver.models import get_model  # noqa: E402
from wavebrdf.solver.opencl import create_context  # noqa: E402
from wavebrdf.solver.polarimetry import jones, mueller  # noqa: E402
from wavebrdf.solver.surface import generate  # noqa: E402

MATERIALS = {"glass": 1.5, "aluminium": ALUMINIUM_400NM}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=float, default=4.8, help="patch side (µm)")
    p.add_argument("--cells", type=int, nargs="+", default=[144], help="cells per side (d = size / cells)")
    p.add_argument("--waist", type=float, default=1.2, help="beam waist (µm)")
    p.add_argument("--angles", type=float, nargs="+", default=[70.0, 80.0], help="θ_i (degrees)")
    p.add_argument("--resolutions", type=int, nargs="+", default=[256], help="output grid sides")
    p.add_argument("--materials", nargs="+", default=list(MATERIALS), choices=list(MATERIALS))
    p.add_argument("--margin-scales", type=float, nargs="*", default=[],
                   help="also solve with the continuation's extended mesh scaled by these factors (cells beyond the "
                        "patch) and print how the mirror-direction Mueller matrix and M00 move with it")
    args = p.parse_args(argv)
    ctx = create_context()
    if args.margin_scales:
        for material in args.materials:
            for theta_deg in args.angles:
                for cells in args.cells:
                    window_dependence(ctx, MATERIALS[material], np.deg2rad(theta_deg), cells, args, material)
    model = get_model("bem", {"method": "aim", "aim": {"edge": "flat"}})
    for material in args.materials:
        index = MATERIALS[material]
        for theta_deg in args.angles:
            theta = np.deg2rad(theta_deg)
            r_s, r_p = fresnel_coefficients(1.0, index, theta)
            plane = fresnel_mueller(r_s, r_p)
            ratio = gaussian_beam_power_ratio(0.4, args.waist, theta)
            reference = fresnel_mueller(r_s, r_p / np.sqrt(ratio))
            for cells in args.cells:
                for resolution in args.resolutions:
                    cfg = dict(cells=cells, size_um=args.size, waist_um=args.waist, resolution=resolution)
                    t0 = time.perf_counter()
                    surface = generate("flat", cells=cells, size_um=args.size)
                    field = model.run(ctx, _scene(surface, cfg, index, theta, 0.0))
                    M = _at_mirror(mueller(jones(field)), field.grid, theta)
                    worst = float(np.max(np.abs(M / M[0, 0] - reference / reference[0, 0])))
                    worst_plane = float(np.max(np.abs(M / M[0, 0] - plane / plane[0, 0])))
                    print(f"{material} θ_i {theta_deg:g}°, patch {args.size:g} µm, "
                          f"d = λ/{0.4 * cells / args.size:.3g}, waist {args.waist:g} µm, output {resolution}²: "
                          f"worst normalized element off Fresnel by {worst:.2e} with the beam's P_p/P_s = "
                          f"{ratio:.5f}, {worst_plane:.2e} without ({time.perf_counter() - t0:.0f} s)",
                          flush=True)


def window_dependence(ctx, index, theta, cells, args, material):
    """The mirror-direction normalized Mueller matrix and M00 for continuations of the default
    extent and of ``args.margin_scales`` times its cells beyond the patch (with the beam's share of
    spectrum beyond the light cone, ExactGaussianBeam.evanescent_fraction)."""
    from wavebrdf.solver.bem3d.driver import BEMSolver
    from wavebrdf.solver.farfield import HemisphereGrid

    runs = []
    for scale in [1.0, *args.margin_scales]:
        solver = BEMSolver(ctx, generate("flat", cells=cells, size_um=args.size), 0.4, index, method="aim",
                           aim={"edge": "flat"})
        default = solver.continuation.margin
        solver.continuation.margin = lambda beam, scale=scale, default=default: int(round(scale * default(beam)))
        field = solver.farfield(theta, 0.0, HemisphereGrid(args.resolutions[0]), waist_um=args.waist)
        M = _at_mirror(mueller(jones(field)), field.grid, theta)
        runs.append((scale, field.diagnostics["continuation_cells"], M[0, 0], M / M[0, 0]))
        print(f"{material} θ_i {np.rad2deg(theta):g}°, d = λ/{0.4 * cells / args.size:.3g}, waist {args.waist:g} µm: "
              f"continuation {runs[-1][1]} cells, M00 at the mirror {M[0, 0]:.6g} (relative to the default "
              f"{M[0, 0] / runs[0][2] - 1:+.2%}), normalized elements moved by up to "
              f"{np.max(np.abs(M / M[0, 0] - runs[0][3])):.2e}; beam spectrum beyond the light cone "
              f"{field.diagnostics.get('beam_evanescent_fraction', float('nan')):.3g}", flush=True)


if __name__ == "__main__":
    main()
