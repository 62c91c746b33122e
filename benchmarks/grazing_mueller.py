"""The full wave's flat-interface Mueller matrix toward grazing (issue 32; docs/dataset.md).

Runs the case of tests/test_polarimetry.py ``test_flat_mueller_equals_fresnel`` (bem, AIM with the
flat edge continuation, λ = 0.4 µm, the mirror direction read bilinearly from the output grid)
at angles, patches, meshes and output resolutions the test does not reach, and prints the worst
normalized Mueller element's distance from Fresnel's (tests/references.py, independent of the
code under test).

    .venv/bin/python benchmarks/grazing_mueller.py --size 4.8 --cells 144 192 --waist 1.2 \\
        --angles 80 --resolutions 256 --materials aluminium
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from references import ALUMINIUM_400NM, fresnel_coefficients, fresnel_mueller  # noqa: E402
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
    args = p.parse_args(argv)
    ctx = create_context()
    model = get_model("bem", {"method": "aim", "aim": {"edge": "flat"}})
    for material in args.materials:
        index = MATERIALS[material]
        for theta_deg in args.angles:
            theta = np.deg2rad(theta_deg)
            r_s, r_p = fresnel_coefficients(1.0, index, theta)
            reference = fresnel_mueller(r_s, r_p)
            for cells in args.cells:
                for resolution in args.resolutions:
                    cfg = dict(cells=cells, size_um=args.size, waist_um=args.waist, resolution=resolution)
                    t0 = time.perf_counter()
                    surface = generate("flat", cells=cells, size_um=args.size)
                    field = model.run(ctx, _scene(surface, cfg, index, theta, 0.0))
                    M = _at_mirror(mueller(jones(field)), field.grid, theta)
                    worst = float(np.max(np.abs(M / M[0, 0] - reference / reference[0, 0])))
                    print(f"{material} θ_i {theta_deg:g}°, patch {args.size:g} µm, "
                          f"d = λ/{0.4 * cells / args.size:.3g}, waist {args.waist:g} µm, output {resolution}²: "
                          f"worst normalized element off Fresnel by {worst:.2e} ({time.perf_counter() - t0:.0f} s)",
                          flush=True)


if __name__ == "__main__":
    main()
