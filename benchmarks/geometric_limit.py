"""Geometric optics against the Kirchhoff lobe it is the limit of, on Gaussian-correlated glass
patches: the lobe error ``check_geometric_optics`` predicts from the roughness parameter g alone
(solver/validity.py ``geometric_limit_error``) beside the one measured between ``gs`` and
``kirchhoff`` on the same realization (uniform illumination of a periodic patch, as in
tests/approx/test_geometric.py: the unpolarized f·μ_o of both blurred by σ = 4 pixels of a 128²
grid, relative L2 where Kirchhoff is ≥ 10 % of its peak). The blur, the ray noise and the speckle
left after it set a floor of ≈ 0.06–0.08 on the measured column.

    nice .venv/bin/python benchmarks/geometric_limit.py    # ~20 s on 2 cores
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.ndimage import gaussian_filter

from wavebrdf.solver.farfield import HemisphereGrid, albedo
from wavebrdf.solver.models import SurfaceScene, get_model
from wavebrdf.solver.opencl import create_context
from wavebrdf.solver.surface import generate
from wavebrdf.solver.validity import geometric_optics_figures

WAVELENGTH_UM = 0.5
THETA_DEG = 20.0
CASES = ((1, 0.3), (1, 0.5), (2, 0.1), (2, 0.2), (2, 0.3), (4, 0.05), (4, 0.1), (8, 0.03))  # (T/λ, rms slope)


def blurred(result, grid):
    mu = np.where(grid.inside, grid.mu, 0.0)
    return gaussian_filter(np.nan_to_num(np.mean(result.brdf(), axis=0)) * mu, 4.0, mode="constant")


def main() -> None:
    ctx, grid = create_context(), HemisphereGrid(128)
    print(f"glass, λ {WAVELENGTH_UM} µm, θ_i {THETA_DEG:g}°, uniform illumination of a periodic patch\n")
    print("| T/λ | rms slope | patch (µm, cells) | g | e^−g | predicted (geometric_limit_error) "
          "| measured gs vs kirchhoff | albedo gs / kirchhoff |")
    print("|---|---|---|---|---|---|---|---|")
    for t_over, slope in CASES:
        correlation = t_over * WAVELENGTH_UM
        size = min(96.0, 80 * correlation)
        cells = int(np.ceil(size / min(0.15, correlation / 6)))
        surface = generate("gaussian", cells=cells, size_um=size, rms_height_um=slope * correlation / np.sqrt(2),
                           correlation_um=correlation, seed=5)
        scene = SurfaceScene(surface, WAVELENGTH_UM, complex(1.5), np.deg2rad(THETA_DEG), 0.3, 1e4, grid)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the uniform footprint reaches the patch edge; the check itself
            kirchhoff = get_model("kirchhoff").run(ctx, scene)
            rays = get_model("gs", {"rays": 1 << 21}).run(ctx, scene)
        ref, got = blurred(kirchhoff, grid), blurred(rays, grid)
        lobe = grid.inside & (ref > 0.1 * ref.max())
        measured = np.sqrt(np.sum((got - ref)[lobe] ** 2) / np.sum(ref[lobe] ** 2))
        figures = geometric_optics_figures(scene)
        ratio = albedo(rays.brdf(), grid).mean() / albedo(kirchhoff.brdf(), grid).mean()
        print(f"| {t_over} | {slope} | {size:g}, {cells} | {figures['roughness_g']:.3g} "
              f"| {figures['coherent_share']:.2g} | {figures['geometric_limit_error']:.3f} | {measured:.3f} "
              f"| {ratio:.3f} |", flush=True)


if __name__ == "__main__":
    main()
