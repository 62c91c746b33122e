"""The full fiber BCSDF S = M₀ · N_wave of a stored dataset (seed 004 §5.2; issue 20): energy
against an independent Mie code (treams, tests/references.py), the stored rendering tables
(C_e, φ_r CDFs, longitudinal variance, M₀ CDF) and the evaluator's symmetries."""

from __future__ import annotations

import tomllib
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.special import i0

import wavebrdf
from references import cylinder_widths_treams
from wavebrdf.jobs.cli import main
from wavebrdf.jobs.config import ConfigError, parse_config

ROOT = Path(__file__).resolve().parents[2]
DEG = np.pi / 180


def example_config(tmp_path, name, **changes) -> Path:
    """configs/fiber_circle.toml (a = 1 µm, m = 1.55) with ``changes`` {"section.key": value}."""
    data = tomllib.loads((ROOT / "configs" / "fiber_circle.toml").read_text())
    data["study"]["output"] = str(tmp_path / f"{name}.h5")
    for dotted, value in changes.items():
        section, key = dotted.split(".")
        data[section][key] = value
    lines = []
    for section, table in data.items():
        lines.append(f"[{section}]")
        lines += [f"{k} = {v!r}".replace("'", '"') for k, v in table.items()]
    path = tmp_path / f"{name}.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def run(path) -> Path:
    assert main(["run", str(path), "-q", "--no-render"]) == 0
    return Path(tomllib.loads(path.read_text())["study"]["output"])


@lru_cache(maxsize=None)
def treams_albedo(lam, radius, index, theta):
    ext, sca = cylinder_widths_treams(lam, radius, index, abs(theta))
    return sca.mean() / ext.mean(), ext.mean()


def sphere_integral(ds, theta_i, phi_i, lam, variance=None) -> float:
    """∫ S dω_r = ∫∫ S cosθ_r dθ_r dφ_r: Gauss–Legendre in θ_r (12 × 16 nodes), the periodic
    trapezoid rule in φ_r on 1440 points that include every interpolation node of N_wave (the
    360 bin centres, relative to φ_i for a circle), where it is exact for the linear interpolant."""
    x, w = np.polynomial.legendre.leggauss(16)
    edges = np.linspace(-np.pi / 2, np.pi / 2, 13)
    half = np.diff(edges)[:, None] / 2
    theta_r = ((edges[:-1] + edges[1:])[:, None] / 2 + half * x).ravel()
    w_theta = (half * w).ravel()
    phi_r = phi_i + np.arange(1440) * 2 * np.pi / 1440
    S = ds.bcsdf(theta_i, theta_r[:, None], phi_i, phi_r[None, :], lam, variance=variance)
    return float(np.sum(S * (np.cos(theta_r) * w_theta)[:, None]) * 2 * np.pi / 1440)


def interpolated_albedo(lam, theta, index, lams, thetas):
    """The treams albedo at the table nodes around (λ, |θ_i|), bilinearly interpolated: what an
    interpolated table can hold between its nodes (nodes: exactly the treams albedo)."""
    def nodes(grid, x):
        j = int(np.clip(np.searchsorted(grid, x, side="right") - 1, 0, len(grid) - 2))
        t = (np.clip(x, grid[0], grid[-1]) - grid[j]) / (grid[j + 1] - grid[j])
        return [(j, 1 - t), (j + 1, t)]

    return sum(wl * wt * treams_albedo(float(lams[l]), 1.0, index, float(thetas[t]))[0]
               for l, wl in nodes(lams, lam) for t, wt in nodes(thetas, abs(theta)) if wl * wt > 0)


@pytest.fixture(scope="module")
def circle_examples(tmp_path_factory):
    """The circular example through the Mie fast path ([model] name = "mie", as its comment
    says), 3 wavelengths; lossless as given and with κ = 0.05."""
    tmp = tmp_path_factory.mktemp("circle")
    lams = [0.40, 0.55, 0.70]
    lossless = run(example_config(tmp, "lossless", **{"model.name": "mie", "illumination.wavelengths_um": lams}))
    lossy = run(example_config(tmp, "lossy", **{"model.name": "mie", "illumination.wavelengths_um": lams,
                                                 "material.kappa": 0.05, "fiber.longitudinal_variance": 0.05}))
    return {"lossless": (lossless, 1.55), "lossy": (lossy, 1.55 - 0.05j)}


QUERIES = [  # (λ µm, θ_i, φ_i, variance): at table nodes, between them, negative θ_i, another v
    (0.55, 30 * DEG, 0.7, None), (0.70, 0.0, 0.0, None), (0.475, 45 * DEG, 2.0, None),
    (0.62, -20 * DEG, -1.0, None), (0.55, 60 * DEG, 0.3, 0.3),
]


@pytest.mark.parametrize("kind", ["lossless", "lossy"])
def test_energy_equals_mie_albedo(circle_examples, kind):
    """∫ S dω_r = C_sca/C_e (C_e = C_ext here: no clamp acts) within 1 %, treams as the reference:
    at table nodes its albedo there, between nodes the interpolation of its node albedos."""
    path, index = circle_examples[kind]
    ds = wavebrdf.open(path)
    lams, thetas = ds.h5["wavelength_um"][()], np.deg2rad(ds.h5["theta_i"][()])
    for lam, theta, phi, v in QUERIES:
        energy = sphere_integral(ds, theta, phi, lam, v)
        albedo = interpolated_albedo(lam, theta, index, lams, thetas)
        print(f"{kind} λ={lam} θ_i={np.degrees(theta):.0f}° φ_i={phi}: ∫S dω = {energy:.5f}, "
              f"treams {albedo:.5f}")
        assert energy == pytest.approx(albedo, rel=0.01)
    if kind == "lossy":
        assert albedo < 0.9  # the lossy case tests a real albedo, not only 1


def test_stored_rendering_tables(circle_examples):
    path, index = circle_examples["lossy"]
    ds = wavebrdf.open(path)
    h5 = ds.h5
    assert float(h5["longitudinal_variance"][()]) == 0.05
    lams, thetas = h5["wavelength_um"][()], np.deg2rad(h5["theta_i"][()])
    # C_e = C_ext (unpolarized) of the independent code; the clamp 6 C_g does not act
    for li, lam in enumerate(lams):
        for ti, th in enumerate(thetas):
            _, c_ext = treams_albedo(float(lam), 1.0, index, float(th))
            assert h5["C_eff"][li, ti, 0] == pytest.approx(c_ext, rel=1e-6)
    # φ_r CDFs: nondecreasing, 1 at the last bin, the running sum of N_wave
    cdf, n = h5["phi_r_cdf"][()], h5["bcsdf"][()].astype(np.float64)
    assert np.all(np.diff(cdf, axis=-1) >= 0) and np.allclose(cdf[..., -1], 1.0)
    np.testing.assert_allclose(cdf, np.cumsum(n, axis=-1) / n.sum(axis=-1, keepdims=True), atol=1e-6)
    # M₀ CDF over θ_r against quad of d'Eon's formula written here (direct form, fine for v = 0.05)
    v = 0.05
    theta_r = np.deg2rad(h5["theta_r"][()])

    def m0(ti, tr):
        return np.exp(-np.sin(ti) * np.sin(tr) / v) * i0(np.cos(ti) * np.cos(tr) / v) / (2 * v * np.sinh(1 / v))

    for ti, th in enumerate(thetas):
        for k in (60, 150, 200, 300):
            ref = quad(lambda t: m0(th, t) * np.cos(t), -np.pi / 2, theta_r[k], limit=200, epsabs=1e-10)[0]
            assert h5["m0_cdf"][ti, k] == pytest.approx(ref, abs=1e-6)


def test_bcsdf_symmetries_and_variance(circle_examples):
    ds = wavebrdf.open(circle_examples["lossy"][0])
    ti, tr, lam = 0.4, -0.3, 0.5
    phi_r = np.linspace(0, 2 * np.pi, 7)
    base = ds.bcsdf(ti, tr, 0.2, phi_r, lam)
    np.testing.assert_allclose(ds.bcsdf(-ti, -tr, 0.2, phi_r, lam), base, rtol=1e-12)  # z → -z
    np.testing.assert_allclose(ds.bcsdf(ti, tr, 1.2, phi_r + 1.0, lam), base, rtol=1e-9)  # circle: rotation
    assert ds.bcsdf(ti, -ti, 0.0, np.pi, lam) > ds.bcsdf(ti, 0.5, 0.0, np.pi, lam)  # peak on the cone
    wide = ds.bcsdf(ti, tr, 0.2, phi_r, lam, variance=0.5)
    assert not np.allclose(wide, base)
    assert ds.bcsdf(np.zeros((2, 3)), 0.0, 0.0, 0.0, lam).shape == (2, 3)
    with pytest.raises(ValueError, match="normal plane"):
        ds.bcsdf(2.0, 0.0, 0.0, 0.0, lam)


def test_longitudinal_variance_config_errors(tmp_path):
    for bad in (0.0, -1.0, "wide"):
        with pytest.raises(ConfigError, match="longitudinal_variance"):
            cfg = example_config(tmp_path, "bad", **{"fiber.longitudinal_variance": bad})
            parse_config(cfg.read_text(), cfg)


@pytest.mark.slow
def test_energy_bem_circular_example(tmp_path):
    """The circular example as committed (2.5D BEM, N = 300, 31 λ × 3 θ_i): energy against treams
    at every table node and between nodes."""
    ds = wavebrdf.open(run(example_config(tmp_path, "bem")))
    lams, thetas = ds.h5["wavelength_um"][()], np.deg2rad(ds.h5["theta_i"][()])
    worst = 0.0
    for lam in list(lams[::5]) + [0.405, 0.577, 0.695]:
        for th in list(thetas) + [15 * DEG, -45 * DEG]:
            energy = sphere_integral(ds, th, 0.0, lam)
            albedo = interpolated_albedo(lam, th, 1.55, lams, thetas)
            worst = max(worst, abs(energy / albedo - 1))
    print(f"BEM circular example: worst |∫S dω / albedo_treams - 1| = {worst:.2e}")
    assert worst < 0.01
