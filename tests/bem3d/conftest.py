"""Shared helpers of the 3D BEM tests: the independent references (tests/references.py) and small scenes."""

from __future__ import annotations

import numpy as np
import pytest

from references import ALUMINIUM_400NM, coulomb_squares, fresnel_reflectance

WAVELENGTH = 0.4


def fresnel_power(n1: float, n2: complex, cos_i: np.ndarray):
    """|r_s|², |r_p|² at incidence cosines ``cos_i`` (tests/references.py, independent of wavebrdf)."""
    return fresnel_reflectance(n1, n2, np.arccos(np.clip(np.asarray(cos_i, dtype=float), -1.0, 1.0)))


@pytest.fixture(scope="session")
def references():
    """The independent reference formulas above, for the test modules."""
    return {"fresnel_power": fresnel_power, "coulomb_squares": coulomb_squares, "al_400": ALUMINIUM_400NM,
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
