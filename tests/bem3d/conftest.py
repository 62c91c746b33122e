"""Shared helpers of the 3D BEM tests: independent reference formulas and small scenes."""

from __future__ import annotations

import numpy as np
import pytest

AL_400 = 0.46582 - 4.7119j  # aluminium at 0.4 µm (reference simulator's examples)
WAVELENGTH = 0.4


def fresnel_power(n1: float, n2: complex, cos_i: np.ndarray):
    """|r_s|², |r_p|² from Snell + the textbook Fresnel formulas (written here, independent of
    wavebrdf.solver.fresnel), e^{+jωt}: the transmitted cosine is chosen with Im(n₂ cosθ₂) ≤ 0."""
    cos_i = np.asarray(cos_i, dtype=float)
    sin_i = np.sqrt(np.clip(1 - cos_i**2, 0, None))
    cos_t = np.sqrt(1 - (n1 * sin_i / n2) ** 2 + 0j)
    cos_t = np.where(np.imag(n2 * cos_t) > 0, -cos_t, cos_t)
    rs = (n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t)
    rp = (n2 * cos_i - n1 * cos_t) / (n2 * cos_i + n1 * cos_t)
    return np.abs(rs) ** 2, np.abs(rp) ** 2


def coulomb_squares(a: tuple, b: tuple) -> float:
    """∫_A ∫_B dA dA'/|r − r'| for coplanar axis-aligned rectangles A, B = ((x0, x1), (y0, y1)).

    Closed form: Σ ± F(x_i − x'_k, y_j − y'_l) with ∂²_X∂²_Y F = 1/√(X² + Y²),
    F = X²Y/2 asinh(Y/X) + XY²/2 asinh(X/Y) − r³/6 (even in X and Y).
    """

    def F(X, Y):
        X, Y = abs(X), abs(Y)
        r = np.hypot(X, Y)
        t1 = 0.5 * X * X * Y * np.arcsinh(Y / X) if X > 0 else 0.0
        t2 = 0.5 * X * Y * Y * np.arcsinh(X / Y) if Y > 0 else 0.0
        return t1 + t2 - r**3 / 6.0

    total = 0.0
    for i, xa in enumerate(a[0]):
        for k, xb in enumerate(b[0]):
            for j, ya in enumerate(a[1]):
                for m, yb in enumerate(b[1]):
                    sign = (-(-1) ** (i + k)) * (-(-1) ** (j + m))
                    total += sign * F(xa - xb, ya - yb)
    return total


@pytest.fixture(scope="session")
def references():
    """The independent reference formulas above, for the test modules."""
    return {"fresnel_power": fresnel_power, "coulomb_squares": coulomb_squares, "al_400": AL_400,
            "wavelength": WAVELENGTH}


def rough_heights(cells: int, spacing: float, amplitude: float, seed: int) -> np.ndarray:
    """Random corner heights uniform in ±amplitude (strongly curved, twisted elements)."""
    return np.random.default_rng(seed).uniform(-amplitude, amplitude, (cells + 1, cells + 1)) * spacing


@pytest.fixture(scope="session")
def curved_mesh():
    """A 6×6-cell patch at d = λ/8 with corner heights uniform in ±d (slopes up to ~2)."""
    from wavebrdf.solver.bem3d.mesh import BEMMesh
    from wavebrdf.solver.surface import HeightField

    d = WAVELENGTH / 8
    return BEMMesh(HeightField(rough_heights(6, d, 1.0, seed=3), 6 * d))


@pytest.fixture(scope="session")
def flat_mesh():
    from wavebrdf.solver.bem3d.mesh import BEMMesh
    from wavebrdf.solver.surface import HeightField

    d = WAVELENGTH / 8
    return BEMMesh(HeightField(np.zeros((7, 7)), 6 * d))
