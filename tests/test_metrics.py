"""The BRDF error metrics (solver/metrics.py) on slices whose metrics are known in closed form."""

from __future__ import annotations

import numpy as np
import pytest

from wavebrdf.solver.farfield import HemisphereGrid
from wavebrdf.solver.metrics import (
    angular_distance_deg,
    blur,
    cone_fraction,
    lobe_mask,
    log_error,
    misplaced_energy,
    peak_direction,
    relative_l2,
)

GRID = HemisphereGrid(256)


def lambertian(rho=0.8):
    return np.where(GRID.inside, rho / np.pi, np.nan)


def gaussian_lobe(u0, width=0.05, total=0.9):
    """A lobe of radiance ∝ exp(−|u − u0|²/(2 width²)) whose ∫ f d²u is ``total``."""
    U, V = GRID.uv
    g = np.exp(-((U - u0[0]) ** 2 + (V - u0[1]) ** 2) / (2 * width**2)) * GRID.inside
    g *= total / (g.sum() * GRID.pixel_area)
    return np.where(GRID.inside, g, np.nan)


def test_misplaced_energy_of_disjoint_and_scaled_slices():
    a, b = gaussian_lobe((0.3, 0.0), total=0.9), gaussian_lobe((-0.5, 0.2), total=0.6)
    assert misplaced_energy(a, b, GRID) == pytest.approx(0.5 * (0.9 + 0.6), rel=1e-6)  # no overlap
    assert misplaced_energy(a, 0.5 * a, GRID) == pytest.approx(0.5 * 0.45, rel=1e-9)
    assert misplaced_energy(a, a, GRID) == 0.0


def test_relative_l2_of_a_scaled_slice_and_the_lobe_mask():
    b = gaussian_lobe((0.2, 0.1))
    assert relative_l2(1.1 * b, b, GRID) == pytest.approx(0.1, rel=1e-12)
    both = np.stack([b, 2 * b])
    assert np.allclose(relative_l2(0.9 * both, both, GRID), 0.1)
    mask = lobe_mask(b, GRID)
    # radiance f μ_o ≥ 1e-3 peak: roughly the disk of radius width·√(2 ln 1000) ≈ 0.186 around the peak
    area = mask.sum() * GRID.pixel_area
    assert area == pytest.approx(np.pi * (0.05 * np.sqrt(2 * np.log(1e3))) ** 2, rel=0.1)


def test_cone_fraction_of_a_lambertian_slice_is_sin_squared():
    for half in (10.0, 30.0, 60.0):
        expected = np.sin(np.deg2rad(half)) ** 2  # projected area of the cone / π
        assert cone_fraction(lambertian(), GRID, 0.0, 0.0, half) == pytest.approx(expected, rel=0.02)


def test_peak_direction_and_angles():
    u0 = np.array([0.31, -0.17])
    found = peak_direction(gaussian_lobe(u0, width=0.03), GRID)
    assert np.allclose(found, u0, atol=0.3 * 2 / GRID.resolution)  # a third of a pixel
    assert angular_distance_deg([0.0, 0.0], [np.sin(0.3), 0.0]) == pytest.approx(np.rad2deg(0.3))
    assert angular_distance_deg([0.5, 0.0], [-0.5, 0.0]) == pytest.approx(60.0)


def test_log_error_of_a_constant_factor():
    b = gaussian_lobe((0.0, 0.0), width=0.2)
    assert log_error(10 * b, b, GRID, floor=1e-30) == pytest.approx(1.0, abs=1e-9)


def test_blur_keeps_a_constant_and_the_energy_of_an_interior_lobe():
    f = lambertian()
    assert np.allclose(blur(f, GRID, 0.02)[GRID.inside], 0.8 / np.pi)
    lobe = gaussian_lobe((0.1, 0.0), width=0.02)
    blurred = blur(lobe, GRID, 0.02)
    assert np.nansum(blurred) * GRID.pixel_area == pytest.approx(0.9, rel=1e-6)
    assert np.isnan(blurred[0, 0])


def test_shapes_are_checked():
    with pytest.raises(ValueError, match="does not match"):
        relative_l2(np.zeros((4, 4)), np.zeros((4, 4)), GRID)
    with pytest.raises(ValueError, match="no lobe"):
        lobe_mask(np.zeros((256, 256)), GRID)
