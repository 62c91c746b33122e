"""Hankel evaluator H0^(2), H1^(2) (fiber.md §8, T9): OpenCL kernel and NumPy mirror against
scipy's AMOS (exponentially scaled ``hankel2e``, which stays finite where ``hankel2`` fails)."""

from __future__ import annotations

import logging

import numpy as np
import pytest
import scipy.special as sp

from wavebrdf.kernels import KERNEL_DIR
from wavebrdf.solver.fiber.hankel import (
    HEADER_NAME,
    LAGUERRE_FINE_MAX,
    LAGUERRE_MID_MAX,
    SERIES_MAX,
    bessel01_series,
    hankel2_01,
    hankel2_01_cl,
    hankel2_01_scipy,
    laguerre_header_text,
)
from wavebrdf.solver.precision import Precision

logger = logging.getLogger(__name__)

T9_TOL = 1e-10  # acceptance bar for series/quadrature evaluators
MAX_ABS_IM = 650.0  # beyond, |H^(2)| ~ e^{-|Im z|} leaves the normal double range


def _t9_arguments(rng, n=1_000_000):
    """Half real log-uniform in [1e-6, 3000], half on rays arg z in [-45°, -1°] (fiber.md T9)."""
    r = np.exp(rng.uniform(np.log(1e-6), np.log(3000.0), n))
    psi = np.where(np.arange(n) < n // 2, 0.0, np.radians(rng.uniform(1.0, 45.0, n)))
    z = r * np.exp(-1j * psi)
    return z[np.abs(z.imag) < MAX_ABS_IM]


def _max_rel(got, want):
    return float(np.max(np.abs(got - want) / np.abs(want)))


@pytest.fixture(scope="module")
def t9_reference(rng_module):
    z = _t9_arguments(rng_module)
    return z, hankel2_01_scipy(z)


@pytest.fixture(scope="module")
def rng_module():
    return np.random.default_rng(20260601)


def test_t9_opencl_matches_amos_on_a_million_arguments(cl_ctx, t9_reference):
    z, (ref0, ref1) = t9_reference
    h0, h1 = hankel2_01_cl(cl_ctx, z)
    err = max(_max_rel(h0, ref0), _max_rel(h1, ref1))
    logger.info("T9 OpenCL: %d arguments, max relative error %.2e", z.size, err)
    assert z.size > 900_000
    assert err < T9_TOL


def test_t9_numpy_mirror_matches_amos(t9_reference):
    z, (ref0, ref1) = t9_reference
    sub = slice(0, None, 5)  # the mirror is the slow path; 2e5 arguments suffice
    h0, h1 = hankel2_01(z[sub])
    assert max(_max_rel(h0, ref0[sub]), _max_rel(h1, ref1[sub])) < T9_TOL


@pytest.mark.parametrize("angle_deg", [0.0, -1.0, -30.0, -45.0, -80.0])
def test_switch_points_and_small_arguments(cl_ctx, angle_deg):
    """Both sides of the switch points, tiny |z| (H1 ~ 2j/(πz)), complex ln branch."""
    radii = np.concatenate([
        SERIES_MAX * (1.0 + np.array([-1e-12, -1e-9, 0.0, 1e-9])),
        LAGUERRE_FINE_MAX * (1.0 + np.array([-1e-12, -1e-9, 0.0, 1e-9])),
        LAGUERRE_MID_MAX * (1.0 + np.array([-1e-12, -1e-9, 0.0, 1e-9])),
        np.geomspace(1e-9, 1e-3, 13),
        [3.0, 20.0],
    ])
    z = radii * np.exp(1j * np.radians(angle_deg))
    ref0, ref1 = hankel2_01_scipy(z)
    for h0, h1 in (hankel2_01_cl(cl_ctx, z), hankel2_01(z)):
        assert _max_rel(h0, ref0) < T9_TOL
        assert _max_rel(h1, ref1) < T9_TOL
    # the small-argument forms fiber.md §4 relies on
    tiny = z[(radii < 1e-6)]
    h0, h1 = hankel2_01_cl(cl_ctx, tiny)
    lead0 = 1.0 - 2j / np.pi * (np.log(tiny / 2) + np.euler_gamma)
    assert _max_rel(h0, lead0) < 1e-10
    assert _max_rel(h1, 2j / (np.pi * tiny)) < 1e-10


def test_series_parts_match_scipy_bessel():
    """J0 - 1, J1 and the log-free parts of Y0, Y1 used by the singularity subtraction."""
    z = np.array([1e-4, 0.3, 1.0, 2.4]) * np.exp(-1j * np.radians([0.0, 10.0, 40.0, 70.0]))
    j0m1, j1, y0r, y1r = bessel01_series(z)
    log_half = np.log(z / 2)
    np.testing.assert_allclose(1.0 + j0m1, sp.jv(0, z), rtol=1e-14)
    np.testing.assert_allclose(j0m1[1:], sp.jv(0, z[1:]) - 1.0, rtol=1e-12)
    np.testing.assert_allclose(j1, sp.jv(1, z), rtol=1e-14)
    np.testing.assert_allclose(y0r, sp.yv(0, z) - 2 / np.pi * log_half * sp.jv(0, z), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(y1r, sp.yv(1, z) - 2 / np.pi * log_half * sp.jv(1, z) + 2 / (np.pi * z),
                               rtol=1e-9, atol=1e-12)  # reference cancels 2/(πz) ~ 6e3 at z = 1e-4


def test_single_precision_build_agrees_to_float_accuracy(cl_ctx, rng):
    z = np.exp(rng.uniform(np.log(1e-3), np.log(300.0), 20_000)) * np.exp(-1j * np.radians(rng.uniform(0, 30, 20_000)))
    z = z[np.abs(z.imag) < 30]
    h0, h1 = hankel2_01_cl(cl_ctx, z, precision=Precision.SINGLE)
    ref0, ref1 = hankel2_01_scipy(z)
    assert h0.dtype == np.complex64
    assert _max_rel(h0, ref0) < 1e-3 and _max_rel(h1, ref1) < 1e-3


def test_laguerre_header_is_current():
    """kernels/hankel_laguerre.h is generated from the Python constants; regenerate with
    ``python -m wavebrdf.solver.fiber.hankel`` after changing them."""
    assert (KERNEL_DIR / HEADER_NAME).read_text() == laguerre_header_text()
