"""Shallow sinusoidal aluminium grating: AIM diffraction efficiencies vs RCWA (VALIDATION.md item 2).

h(x) = a cos(2πx/Λ), Λ = 2.5λ (orders m = 0, ±1, ±2 propagate at normal incidence, none grazing),
2πa/λ = 0.94 ("shallow", ≤ 1), λ = 0.4 µm, aluminium n = 0.46582 − 4.7119j. BEM: a 10Λ patch at
d = λ/8, exact Gaussian beam of waist 3Λ at normal incidence; the power of order m is the BRDF
integrated (Σ f Δu Δv) over the disk of radius λ/(2Λ) around u = mλ/Λ. Reference: the RCWA code
grcwa (PyPI), staircase profile, run inside the test at two truncations (harmonics, layers) that
must agree within 1% absolute before the comparison. Bar: 2% absolute per order, both polarizations.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from wavebrdf.solver.bem3d import BEMWarning, bem_farfield
from wavebrdf.solver.farfield import HemisphereGrid
from wavebrdf.solver.surface import generate

LAMBDA = 0.4
AL_400 = 0.46582 - 4.7119j
PERIOD = 2.5 * LAMBDA
AMPLITUDE = 0.94 * LAMBDA / (2 * np.pi)
ORDERS = (-2, -1, 0, 1, 2)


def rcwa_efficiencies(harmonics: int, layers: int, samples: int = 400) -> np.ndarray:
    """Reflected power per order (rows s, p; columns ORDERS) by grcwa at normal incidence.

    grcwa uses e^{−iωt}: the metal permittivity is conj(n)². Its "s" excitation has H along x,
    i.e. E along the grooves (y), as the BEM's s polarization (E ⟂ plane of incidence at φ = 0).
    """
    import grcwa  # independent reference (dev dependency): a missing one fails, never skips

    grcwa.set_backend("numpy")
    eps = np.conj(AL_400) ** 2
    x = (np.arange(samples) + 0.5) / samples * PERIOD
    h = AMPLITUDE * np.cos(2 * np.pi * x / PERIOD)
    dz = 2 * AMPLITUDE / layers
    z_mid = AMPLITUDE - (np.arange(layers) + 0.5) * dz
    ny = 4  # the grating is uniform along y; the lattice is 1-D in practice (tiny y period)
    out = np.zeros((2, len(ORDERS)))
    for row, (p_amp, s_amp) in enumerate(((0.0, 1.0), (1.0, 0.0))):
        obj = grcwa.obj(harmonics, [PERIOD, 0.0], [0.0, 0.01 * PERIOD], 1.0 / LAMBDA, 0.0, 0.0, verbose=0)
        obj.Add_LayerUniform(0.1, 1.0)
        for _ in z_mid:
            obj.Add_LayerGrid(dz, samples, ny)
        obj.Add_LayerUniform(0.1, eps)
        obj.Init_Setup(Gmethod=0)
        assert np.all(obj.G[:, 1] == 0), "y harmonics would enter the truncation"
        grids = [np.repeat(np.where(h > z, eps, 1.0)[:, None], ny, axis=1).ravel() for z in z_mid]
        obj.GridLayer_geteps(np.concatenate(grids))
        obj.MakeExcitationPlanewave(p_amp, 0.0, s_amp, 0.0, order=0)
        reflected, _ = obj.RT_Solve(normalize=1, byorder=1)
        for col, m in enumerate(ORDERS):
            out[row, col] = np.sum(np.real(reflected[obj.G[:, 0] == m]))
    return out


def test_rcwa_reference_reproduces_fresnel_on_a_flat_interface():
    """The reference itself: amplitude 0 gives |r|² of aluminium (independent formula)."""
    import grcwa

    obj = grcwa.obj(21, [PERIOD, 0.0], [0.0, 0.01 * PERIOD], 1.0 / LAMBDA, 0.0, 0.0, verbose=0)
    obj.Add_LayerUniform(0.1, 1.0)
    obj.Add_LayerUniform(0.1, np.conj(AL_400) ** 2)
    obj.Init_Setup(Gmethod=0)
    obj.MakeExcitationPlanewave(0.0, 0.0, 1.0, 0.0, order=0)
    R, _ = obj.RT_Solve(normalize=1)
    assert abs(R - abs((1 - AL_400) / (1 + AL_400)) ** 2) < 1e-10


@pytest.mark.slow
def test_grating_orders_match_rcwa():
    coarse = rcwa_efficiencies(81, 60)
    fine = rcwa_efficiencies(121, 80)
    print("RCWA s, p per order", ORDERS, "\n", np.round(fine, 4), "\nchange with truncation",
          np.round(fine - coarse, 4))
    assert np.all(np.abs(fine - coarse) < 0.01), "RCWA not converged in harmonics/layers"

    from wavebrdf.solver.opencl import create_context

    ctx = create_context()
    cells = int(round(10 * PERIOD / (LAMBDA / 8)))
    surface = generate("sinusoid", cells=cells, size_um=10 * PERIOD, amplitude_um=AMPLITUDE, period_um=PERIOD)
    grid = HemisphereGrid(256)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BEMWarning)
        ff = bem_farfield(ctx, surface, LAMBDA, AL_400, 0.0, 0.0, 3 * PERIOD, grid, method="aim")
    brdf = np.nan_to_num(ff.brdf())
    U, V = grid.uv
    bem = np.zeros((2, len(ORDERS)))
    for col, m in enumerate(ORDERS):
        lobe = (U - m * LAMBDA / PERIOD) ** 2 + V**2 < (0.5 * LAMBDA / PERIOD) ** 2
        bem[:, col] = np.sum(brdf[:, lobe], axis=1) * grid.pixel_area
    print("AIM s, p per order\n", np.round(bem, 4), "\ndifference to RCWA", np.round(bem - fine, 4),
          "\niterations", ff.diagnostics["iterations"], "unknowns", ff.diagnostics["unknowns"])
    assert np.all(np.abs(bem - fine) < 0.02)
