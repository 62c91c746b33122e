"""Material indices and colour conversion against published values."""

from __future__ import annotations

import numpy as np
import pytest

from wavebrdf.solver.materials import Material, MaterialError
from wavebrdf.solver.spectrum import cmf_xyz, spectral_weights, srgb_encode, xyz_to_linear_srgb


def test_lorentz_drude_aluminium_matches_reference_table():
    """Rakić LD aluminium vs the reference simulator's aluminium table (independent source)."""
    table = Material.from_name("aluminium-bemsim")
    ld = Material.from_name("aluminium")
    lam = np.linspace(0.4, 0.688, 25)
    a, b = ld.index(lam), table.index(lam)
    assert np.all(np.abs(a.real - b.real) < 0.1) and np.all(np.abs(a.imag / b.imag - 1) < 0.03)


@pytest.mark.parametrize(
    "metal, lam, n, kappa",
    # Johnson & Christy 1972 spot values; LD fits agree to roughly 0.15 in n and 10 % in kappa
    [("silver", 0.5486, 0.059, 3.32), ("gold", 0.6199, 0.21, 3.27), ("copper", 0.6526, 0.21, 3.67)],
)
def test_noble_metals_near_published_values(metal, lam, n, kappa):
    value = Material.from_name(metal).index(lam)
    assert abs(value.real - n) < 0.15 and abs(-value.imag / kappa - 1) < 0.12


def test_loss_sign_and_range():
    for name in ("aluminium", "silver", "gold", "copper"):
        idx = Material.from_name(name).index(np.linspace(0.38, 0.78, 41))
        assert np.all(idx.imag < 0)  # n - j kappa with kappa > 0: loss under exp(+j w t)
    with pytest.raises(MaterialError, match="defined for"):
        Material.from_name("aluminium-bemsim").index(0.75)
    assert Material.from_name("glass").index(0.5) == 1.5


def test_cmf_fit_integrals():
    lam = np.linspace(360, 830, 4701)
    x, y, z = cmf_xyz(lam) * (lam[1] - lam[0])
    # the CIE 1931 tables integrate to 106.86 (x), 106.86 (y), 106.77 (z) nm
    assert np.sum(x) == pytest.approx(106.86, rel=0.01)
    assert np.sum(y) == pytest.approx(106.86, rel=0.01)
    assert np.sum(z) == pytest.approx(106.77, rel=0.01)


def test_flat_spectrum_renders_neutral_grey():
    w = spectral_weights([0.45, 0.55, 0.65])
    xyz = w @ np.ones(3)
    assert xyz[1] == pytest.approx(1.0, rel=1e-9)
    rgb = xyz_to_linear_srgb(xyz * 0.5)
    assert np.allclose(rgb, rgb.mean(), rtol=0.03)
    assert srgb_encode(np.array([0.0, 1.0]))[1] == pytest.approx(1.0)
