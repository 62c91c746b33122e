"""The "wavebrdf" Mitsuba 3 BSDF plugin against Mitsuba's own rough conductor and against its tables.

The analytic lobe is written here from the textbook (Walter, Marschner, Li & Torrance, "Microfacet
Models for Refraction through Rough Surfaces", EGSR 2007: Beckmann D eq. 25, exact Smith G1
eq. 27, f = F D G / (4 |i·n| |o·n|) eq. 20), with the conductor Fresnel reflectance of
tests/references.py, never taken from wavebrdf or Mitsuba, and stored with the store's public
writer (jobs/store.py: atomic_h5 + SurfaceDatasetWriter).
"""

from __future__ import annotations

import math

import mitsuba as mi  # the `render` extra; missing = a failure, as every reference package
import numpy as np
import pytest
from scipy.special import erf

from references import fresnel_reflectance
from wavebrdf.jobs.store import SurfaceDatasetWriter, atomic_h5
from wavebrdf.solver.materials import Material

WAVELENGTHS_UM = np.linspace(0.36, 0.83, 9)  # covers Mitsuba's spectral range 360–830 nm
THETAS_DEG = np.concatenate([np.arange(0.0, 88.0, 4.0), [88.0, 89.5]])
RGB_WAVELENGTHS_UM = (0.61, 0.55, 0.465)  # R, G, B stand-ins for Mitsuba's RGB eta/k


def aluminium(wavelength_um):
    """n − jκ of aluminium (wavebrdf's Rakić table: data, shared by both sides)."""
    return Material.from_name("aluminium").index(np.asarray(wavelength_um, dtype=float))


def beckmann_geometry(wi: np.ndarray, wo: np.ndarray, alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """D G / (4 |i·n| |o·n|) (Walter et al. 2007, Beckmann D, exact Smith G1) and the angle
    between ω_i and the half vector (the Fresnel angle). wi, wo: (..., 3) unit vectors, z = normal;
    0 below the horizon."""
    ci, co = wi[..., 2], wo[..., 2]
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    ch = np.clip(h[..., 2], 1e-12, 1.0)
    tan2 = (1.0 - ch**2) / ch**2
    D = np.exp(-tan2 / alpha**2) / (np.pi * alpha**2 * ch**4)

    def g1(v):
        cv = np.clip(v[..., 2], 1e-12, 1.0)
        tan_v = np.sqrt(np.clip(1.0 - cv**2, 0.0, None)) / cv
        a = 1.0 / np.maximum(alpha * tan_v, 1e-12)
        g = 2.0 / (1.0 + erf(a) + np.exp(-a * a) / (a * np.sqrt(np.pi)))
        return np.where(np.sum(v * h, axis=-1) / cv > 0, g, 0.0)

    dg = D * g1(wi) * g1(wo) / (4.0 * np.maximum(ci, 1e-12) * np.maximum(co, 1e-12))
    cos_d = np.clip(np.sum(wi * h, axis=-1), 0.0, 1.0)
    return np.where((ci > 0) & (co > 0), dg, 0.0), np.arccos(cos_d)


def beckmann_brdf(wi: np.ndarray, wo: np.ndarray, alpha: float, index: complex) -> np.ndarray:
    """The rough conductor f = F D G / (4 |i·n| |o·n|) (1/sr) with the unpolarized Fresnel
    reflectance of the index n − jκ."""
    dg, theta_d = beckmann_geometry(wi, wo, alpha)
    rs, rp = fresnel_reflectance(1.0, index, theta_d)
    return 0.5 * (rs + rp) * dg


def pixel_directions(resolution: int):
    """(U, V, ω_o (res, res, 3), inside-the-disk mask) of the dataset's projected-hemisphere grid."""
    u = 2.0 * (np.arange(resolution) + 0.5) / resolution - 1.0
    U, V = np.meshgrid(u, u, indexing="ij")
    wo = np.stack([U, V, np.sqrt(np.clip(1.0 - U**2 - V**2, 0.0, None))], axis=-1)
    return U, V, wo, U**2 + V**2 < 1.0


def write_beckmann_dataset(path, alpha, *, resolution: int = 128, wavelengths_um=WAVELENGTHS_UM,
                           directions=None):
    """The Beckmann lobe tabulated on the dataset grid (NaN outside the disk), written with the
    store's public writer. ``directions``: [[θ, φ], ...] in degrees (default THETAS_DEG at φ = 0);
    ``alpha``: one roughness, or a list of them written as the sweep axis "model.alpha"."""
    _, _, wo, inside = pixel_directions(resolution)
    directions = np.array([[t, 0.0] for t in THETAS_DEG] if directions is None else directions, dtype=float)
    alphas = list(np.atleast_1d(alpha))
    sweep = {"model.alpha": alphas} if np.ndim(alpha) else {}
    config = f'[study]\nname = "beckmann"\n[surface]\nfile = "analytic Beckmann alpha = {alpha}"\n'
    theta, phi = np.deg2rad(directions).T
    wi = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)
    wi = np.broadcast_to(wi[:, None, None, :], (len(wi),) + wo.shape)
    index = aluminium(wavelengths_um)
    with atomic_h5(path) as h5:
        writer = SurfaceDatasetWriter(h5, sweep, wavelengths_um, directions, resolution, "unpolarized", False)
        writer.create(config_text=config, study="beckmann", software_version="test", device="numpy")
        for case, a in enumerate(alphas):
            where = (case,) if sweep else ()
            writer.write_index(where, index)
            dg, theta_d = beckmann_geometry(wi, np.broadcast_to(wo, wi.shape), a)
            for wl, n in enumerate(index):
                rs, rp = fresnel_reflectance(1.0, n, theta_d)
                for inc, f in enumerate(np.where(inside, 0.5 * (rs + rp) * dg, np.nan)):
                    albedo = float(np.nansum(f) * (2.0 / resolution) ** 2)
                    writer.write_result(where, wl, inc, np.stack([f, f]), f, np.array([albedo, albedo]), albedo)
    return path


# -- helpers -------------------------------------------------------------------------------------
COMPARE_ENV = dict(elevation_deg=35.0, azimuth_deg=-120.0, radius_deg=20.0, radiance=6.0)


@pytest.fixture(scope="module")
def beckmann(tmp_path_factory):
    folder = tmp_path_factory.mktemp("beckmann")
    return {alpha: write_beckmann_dataset(folder / f"beckmann_{alpha}.h5", alpha) for alpha in (0.2, 0.5)}


def use(variant: str):
    import wavebrdf.mitsuba as wm

    mi.set_variant(variant)
    wm.register()
    return wm


def roughconductor(alpha: float, spectral: bool) -> dict:
    """Mitsuba's rough conductor with aluminium's index (wavebrdf n − jκ → Mitsuba eta + i k:
    eta = n, k = κ), spectrally on the dataset's wavelengths, or one (eta, k) per RGB channel."""
    if spectral:
        n = aluminium(WAVELENGTHS_UM)
        wl = ", ".join(f"{x * 1000:g}" for x in WAVELENGTHS_UM)
        eta = {"type": "irregular", "wavelengths": wl, "values": ", ".join(f"{x:.6f}" for x in n.real)}
        k = {"type": "irregular", "wavelengths": wl, "values": ", ".join(f"{-x:.6f}" for x in n.imag)}
    else:
        n = aluminium(RGB_WAVELENGTHS_UM)
        eta = {"type": "rgb", "value": [float(x) for x in n.real]}
        k = {"type": "rgb", "value": [float(-x) for x in n.imag]}
    return {"type": "roughconductor", "distribution": "beckmann", "alpha": alpha, "eta": eta, "k": k}


def render(bsdf: dict, *, resolution: int, spp: int, env, seed: int = 0) -> np.ndarray:
    from wavebrdf.mitsuba import scene_dict

    scene = mi.load_dict(scene_dict(bsdf, resolution=resolution, spp=spp, env=env, hide_emitters=True, seed=seed))
    return np.array(mi.render(scene))


def relative_l1(image: np.ndarray, reference: np.ndarray) -> float:
    """Σ|I − R| / Σ|R| over the RGB of the pixels fully covered by the object (alpha = 1)."""
    mask = (reference[..., 3] > 0.999) & (image[..., 3] > 0.999)
    return float(np.abs(image[..., :3] - reference[..., :3])[mask].sum() / np.abs(reference[..., :3])[mask].sum())


def compare_with_roughconductor(path, alpha, variant, *, resolution, spp, env, reference_spp=4096):
    """(plugin at ``spp`` vs Mitsuba at ``reference_spp``, Mitsuba at ``spp`` vs the same: the
    metric's noise floor at ``spp``)."""
    wm = use(variant)
    spectral = "spectral" in variant
    plugin = {"type": "wavebrdf", "filename": str(path), "isotropic": True, "smooth_sigma": 0.0}
    reference = render(roughconductor(alpha, spectral), resolution=resolution, spp=reference_spp, env=env, seed=7)
    image = render(plugin, resolution=resolution, spp=spp, env=env)
    noisy = render(roughconductor(alpha, spectral), resolution=resolution, spp=spp, env=env)
    error, noise = relative_l1(image, reference), relative_l1(noisy, reference)
    print(f"{variant} alpha={alpha} {resolution}x{resolution}: relative L1 plugin ({spp} spp) vs roughconductor "
          f"({reference_spp} spp) {error:.4f}; roughconductor at {spp} spp vs the same {noise:.4f}")
    wm.clear_cache()
    return error, noise


# -- (a) the plugin renders what Mitsuba's own rough conductor renders ---------------------------
@pytest.mark.parametrize("variant", ["scalar_rgb", "scalar_spectral"])
@pytest.mark.parametrize("alpha", [0.2, 0.5])
def test_sphere_matches_roughconductor(beckmann, alpha, variant):
    from wavebrdf.mitsuba import environment

    env = environment(64, sun=COMPARE_ENV)
    error, noise = compare_with_roughconductor(beckmann[alpha], alpha, variant, resolution=10, spp=256, env=env)
    assert noise < 0.02  # the metric resolves the 3 % bar
    assert error <= 0.03


@pytest.mark.slow
@pytest.mark.parametrize("variant", ["scalar_rgb", "scalar_spectral"])
@pytest.mark.parametrize("alpha", [0.2, 0.5])
def test_sphere_matches_roughconductor_sunlit(beckmann, alpha, variant):
    """Larger image, a 2° sun (the example scene's sky): highlights resolve the lobe shape."""
    from wavebrdf.mitsuba import environment

    error, noise = compare_with_roughconductor(beckmann[alpha], alpha, variant, resolution=32, spp=576,
                                               env=environment(256))
    assert noise < 0.015
    assert error <= 0.03


# -- (b) sample() draws from pdf() ----------------------------------------------------------------
def chi_square_p_value(bsdf, wi, *, samples: int = 6000, bins: int = 16, sub: int = 5, seed: int = 1):
    """Goodness of fit of sample() against pdf() for incidence ``wi``: sampled ω_o binned on a
    bins × bins (u, v) grid, expected counts = samples × ∫ pdf/cos θ_o du dv per cell (midpoint
    rule on sub × sub points), plus one cell for invalid samples (1 − ∫ pdf); cells with fewer
    than 5 expected merged. Returns (p, number of cells)."""
    ctx = mi.BSDFContext()
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(*map(float, wi))
    rng = np.random.default_rng(seed)
    xi = rng.random((samples, 3))
    observed = np.zeros(bins * bins + 1)
    for n, (a, b, c) in enumerate(xi):
        bs, weight = bsdf.sample(ctx, si, float(a), mi.Point2f(float(b), float(c)))
        if bs.pdf <= 0:
            observed[-1] += 1
            continue
        i = min(int((bs.wo.x + 1) / 2 * bins), bins - 1)
        j = min(int((bs.wo.y + 1) / 2 * bins), bins - 1)
        observed[i * bins + j] += 1
        if n < 100:  # the sample weight is eval / pdf
            assert bs.pdf == pytest.approx(bsdf.pdf(ctx, si, bs.wo), rel=1e-6)
            assert np.allclose(np.array(weight), np.array(bsdf.eval(ctx, si, bs.wo)) / bs.pdf, rtol=1e-5)
    h = 2.0 / (bins * sub)
    centres = -1.0 + h * (np.arange(bins * sub) + 0.5)
    density = np.zeros((bins * sub, bins * sub))
    for i, x in enumerate(centres):
        for j, y in enumerate(centres):
            r2 = x * x + y * y
            if r2 < 1.0:
                z = math.sqrt(1.0 - r2)
                density[i, j] = bsdf.pdf(ctx, si, mi.Vector3f(float(x), float(y), z)) / z
    cells = density.reshape(bins, sub, bins, sub).sum(axis=(1, 3)) * h * h
    assert 0.5 < cells.sum() <= 1.0 + 1e-3  # the valid fraction (shifted lobes may leave the disk)
    return merged_chi_square(observed, cells.ravel(), samples)


def merged_chi_square(observed, cells, samples):
    """(p, number of cells) of Pearson's test: ``observed`` counts per cell plus a last one for
    invalid/other samples, ``cells`` the probabilities of the cells (the last gets 1 − Σ);
    cells under 5 expected merged into one."""
    from scipy.stats import chisquare

    expected = np.append(cells, max(1.0 - cells.sum(), 0.0)) * samples
    keep = expected >= 5
    obs = np.append(observed[keep], observed[~keep].sum())
    exp = np.append(expected[keep], expected[~keep].sum())
    if exp[-1] == 0:
        obs, exp = obs[:-1], exp[:-1]
    exp *= obs.sum() / exp.sum()
    return chisquare(obs, exp).pvalue, len(obs)


def _direction(theta_deg, phi_deg):
    t, p = np.deg2rad(theta_deg), np.deg2rad(phi_deg)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


@pytest.fixture(scope="module")
def schemes(tmp_path_factory, beckmann):
    """One dataset per incidence scheme: isotropic (θ-linear, rotated), a θ × φ grid, scattered."""
    folder = tmp_path_factory.mktemp("schemes")
    grid = [[0.0, 0.0]] + [[t, p] for t in (20.0, 40.0, 60.0) for p in (0.0, 90.0, 180.0, 270.0)]
    small = dict(resolution=64, wavelengths_um=[0.55])
    return {"isotropic": (beckmann[0.2], True),
            "grid": (write_beckmann_dataset(folder / "grid.h5", 0.3, directions=grid, **small), False),
            "nearest": (write_beckmann_dataset(folder / "scattered.h5", 0.3,
                                               directions=[[0.0, 0.0], [30.0, 0.0], [60.0, 45.0]], **small), False)}


@pytest.mark.parametrize("scheme, direction", [
    ("isotropic", (10.0, 30.0)), ("isotropic", (47.0, 200.0)), ("isotropic", (75.0, -60.0)),
    ("grid", (30.0, 45.0)), ("nearest", (50.0, 30.0)),
])
def test_sample_matches_pdf_chi_square(schemes, scheme, direction):
    use("scalar_rgb")
    path, isotropic = schemes[scheme]
    bsdf = mi.load_dict({"type": "wavebrdf", "filename": str(path), "isotropic": isotropic, "smooth_sigma": 0.0})
    assert bsdf.tables.scheme == scheme
    p, cells = chi_square_p_value(bsdf, _direction(*direction))
    print(f"chi-square {scheme} θ,φ = {direction}: p = {p:.3f} over {cells} cells")
    assert cells > 20
    assert p > 0.01


# -- (c) at a tabulated incidence, eval is the table at the pixel centres ------------------------
@pytest.mark.parametrize("isotropic, theta_deg", [(True, 40.0), (True, 88.0), (False, 0.0), (False, 40.0)])
def test_eval_equals_table_at_pixel_centres(beckmann, isotropic, theta_deg):
    """Spectral variant at four of the dataset's wavelengths: with wi the tabulated incidence,
    eval(wi, wo) / cos θ_wo is the stored f(wi → wo) at every pixel centre wo."""
    import h5py

    use("scalar_spectral")
    path = beckmann[0.2]
    bsdf = mi.load_dict({"type": "wavebrdf", "filename": str(path), "isotropic": isotropic, "smooth_sigma": 0.0})
    with h5py.File(path, "r") as h5:
        inc = int(np.flatnonzero(np.isclose(h5["theta_i"][()], theta_deg))[0])
        channels = [0, 3, 5, 8]
        table = h5["brdf"][channels, inc]  # (4, res, res)
        u = h5["u"][()]
    ctx = mi.BSDFContext()
    si = mi.SurfaceInteraction3f()
    si.wavelengths = mi.Spectrum(*[float(WAVELENGTHS_UM[c] * 1000) for c in channels])
    si.wi = mi.Vector3f(*map(float, _direction(theta_deg, 0.0)))
    rng = np.random.default_rng(3)
    checked = 0
    for i, j in rng.integers(0, len(u), size=(400, 2)):
        if u[i] ** 2 + u[j] ** 2 >= 0.98:
            continue
        mu = math.sqrt(1.0 - u[i] ** 2 - u[j] ** 2)
        value = np.array(bsdf.eval(ctx, si, mi.Vector3f(float(u[i]), float(u[j]), mu))) / mu
        np.testing.assert_allclose(value, table[:, i, j], rtol=2e-5, atol=1e-6 * np.nanmax(table))
        checked += 1
    assert checked > 200


def test_zero_below_the_horizon_and_on_back_faces(beckmann):
    use("scalar_rgb")
    bsdf = mi.load_dict({"type": "wavebrdf", "filename": str(beckmann[0.5]), "isotropic": True})
    ctx = mi.BSDFContext()
    si = mi.SurfaceInteraction3f()
    up, down = mi.Vector3f(0.3, 0.1, float(np.sqrt(0.9))), mi.Vector3f(0.3, 0.1, -float(np.sqrt(0.9)))
    for wi, wo in ((up, down), (down, up), (down, down)):
        si.wi = wi
        assert np.all(np.array(bsdf.eval(ctx, si, wo)) == 0.0)
        assert bsdf.pdf(ctx, si, wo) == 0.0
    si.wi = down
    bs, weight = bsdf.sample(ctx, si, 0.5, mi.Point2f(0.5, 0.5))
    assert bs.pdf == 0.0 and np.all(np.array(weight) == 0.0)


def test_bad_properties_name_the_field(beckmann, tmp_path):
    use("scalar_rgb")
    with pytest.raises(Exception, match="filename: missing"):
        mi.load_dict({"type": "wavebrdf"})
    with pytest.raises(Exception, match=r"case = 3: the dataset has 1 sweep case"):
        mi.load_dict({"type": "wavebrdf", "filename": str(beckmann[0.5]), "case": 3})
    with pytest.raises(Exception, match=r"smooth_sigma = -1"):
        mi.load_dict({"type": "wavebrdf", "filename": str(beckmann[0.5]), "smooth_sigma": -1.0})
    with pytest.raises(Exception, match=r"interpolation = 'cubic'"):
        mi.load_dict({"type": "wavebrdf", "filename": str(beckmann[0.5]), "interpolation": "cubic"})
    with pytest.raises(Exception, match="does not exist"):
        mi.load_dict({"type": "wavebrdf", "filename": str(tmp_path / "missing.h5")})


# -- (d) a real dataset: a small variant of the default study, rendered as a sphere and a plate ---
def small_default_config(folder) -> str:
    """configs/default.toml with 200 cells (same patch, coarser) and 128² output pixels."""
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parent.parent / "configs" / "default.toml").read_text()
    text, cells = re.subn(r"(?m)^cells\s*=\s*\d+", "cells = 200", text)
    text, res = re.subn(r"(?m)^resolution\s*=\s*\d+", "resolution = 128", text)
    assert cells == res == 1, "configs/default.toml changed shape: update small_default_config"
    path = folder / "small.toml"
    path.write_text(text)
    return str(path)


def test_real_dataset_white_furnace(tmp_path):
    """Under a uniform sky of radiance 1, the pixel facing the camera shows ∫ f cos θ dω over
    the light directions = the albedo stored at θ_i = 0 (luminance of the RGB conversion)."""
    import time

    from wavebrdf.jobs.cli import main
    from wavebrdf.solver.spectrum import spectral_weights

    out = tmp_path / "small.h5"
    assert main(["run", small_default_config(tmp_path), "--output", str(out), "--quiet", "--no-render"]) == 0
    wm = use("scalar_rgb")
    start = time.perf_counter()
    result = wm.render_scene(out, "sphere", out=tmp_path / "furnace.png", spp=64, resolution=15,
                             variant="scalar_rgb", env=np.ones((16, 32, 3), np.float32))
    image = result["image"]
    assert result["path"].is_file() and np.all(np.isfinite(image))
    centre = image[7, 7, :3]  # the camera looks at the sphere's centre: normal ≈ view direction
    luminance = float(np.array([0.2126729, 0.7151522, 0.0721750]) @ centre)
    with wavebrdf_open(out) as ds:
        albedo = float(spectral_weights(ds.coords["wavelength_um"])[1] @ ds.albedo[:, 0])
    print(f"white furnace: centre pixel luminance {luminance:.4f}, stored albedo (Y) {albedo:.4f}; "
          f"render {time.perf_counter() - start:.1f} s")
    assert luminance == pytest.approx(albedo, rel=0.03)
    plate = wm.render_scene(out, "plate", out=tmp_path / "plate.png", spp=4, resolution=12, variant="scalar_rgb")
    assert (plate["image"][..., 3] > 0.999).sum() > 20


def wavebrdf_open(path):
    import wavebrdf

    return wavebrdf.open(path)


def test_sweep_case_selects_its_tables(tmp_path):
    """``case`` picks one sweep case (flat C-order index): here two lobes of different α."""
    alphas = [0.2, 0.5]
    path = write_beckmann_dataset(tmp_path / "sweep.h5", alphas, resolution=32, wavelengths_um=[0.55],
                                  directions=[[0.0, 0.0], [40.0, 0.0]])
    _, _, wo, _ = pixel_directions(32)
    use("scalar_spectral")
    ctx, si = mi.BSDFContext(), mi.SurfaceInteraction3f()
    si.wavelengths = mi.Spectrum(550.0, 550.0, 550.0, 550.0)
    si.wi = mi.Vector3f(*map(float, _direction(40.0, 0.0)))
    probe = wo[10, 17]
    for case, alpha in enumerate(alphas):
        bsdf = mi.load_dict({"type": "wavebrdf", "filename": str(path), "case": case, "smooth_sigma": 0.0})
        expected = beckmann_brdf(_direction(40.0, 0.0), probe, alpha, aluminium([0.55])[0])
        value = np.array(bsdf.eval(ctx, si, mi.Vector3f(*map(float, probe))))[0] / probe[2]
        assert value == pytest.approx(expected, rel=1e-5)


@pytest.fixture(scope="module")
def llvm():
    from wavebrdf.mitsuba.scene import llvm_usable

    if not llvm_usable():
        pytest.skip("no libLLVM >= 17 for Mitsuba's llvm variants (the JIT backend of the plugin is "
                    "also exercised by cuda variants on GPUs)")


@pytest.mark.parametrize("variant, scheme", [("llvm_ad_rgb", "isotropic"), ("llvm_ad_spectral", "isotropic"),
                                             ("llvm_ad_rgb", "grid"), ("llvm_ad_rgb", "nearest")])
def test_jit_variant_matches_scalar(llvm, schemes, variant, scheme):
    """The Dr.Jit backend (vectorized, traced) computes what the scalar backend computes."""
    import drjit as dr

    path, isotropic = str(schemes[scheme][0]), schemes[scheme][1]
    rng = np.random.default_rng(11)
    count = 64
    wi = np.array([_direction(t, p) for t, p in zip(rng.uniform(0, 85, count), rng.uniform(0, 360, count))])
    wo = np.array([_direction(t, p) for t, p in zip(rng.uniform(0, 85, count), rng.uniform(0, 360, count))])
    wo[::4] = wi[::4] * [-1, -1, 1]  # specular probes
    xi = rng.random((count, 3))
    lam = rng.uniform(360, 830, (count, 4))
    scalar = variant.replace("llvm_ad", "scalar")
    results = {}
    for name in (scalar, variant):
        use(name)
        bsdf = mi.load_dict({"type": "wavebrdf", "filename": path, "isotropic": isotropic, "smooth_sigma": 0.0})
        ctx = mi.BSDFContext()
        if name == variant:
            si = dr.zeros(mi.SurfaceInteraction3f, count)
            si.wi = mi.Vector3f(*[mi.Float(c) for c in wi.T])
            if "spectral" in name:
                si.wavelengths = mi.Spectrum(*[mi.Float(c) for c in lam.T])
            out = mi.Vector3f(*[mi.Float(c) for c in wo.T])
            bs, weight = bsdf.sample(ctx, si, mi.Float(xi[:, 0]), mi.Point2f(mi.Float(xi[:, 1]), mi.Float(xi[:, 2])))
            results[name] = (np.array(bsdf.eval(ctx, si, out)).T, np.array(bsdf.pdf(ctx, si, out)),
                             np.array(bs.wo).T, np.array(bs.pdf), np.array(weight).T)
            continue
        rows = []
        for n in range(count):
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(*map(float, wi[n]))
            if "spectral" in name:
                si.wavelengths = mi.Spectrum(*map(float, lam[n]))
            out = mi.Vector3f(*map(float, wo[n]))
            bs, weight = bsdf.sample(ctx, si, float(xi[n, 0]), mi.Point2f(float(xi[n, 1]), float(xi[n, 2])))
            rows.append((np.array(bsdf.eval(ctx, si, out)), bsdf.pdf(ctx, si, out), np.array(bs.wo), bs.pdf,
                         np.array(weight)))
        results[name] = tuple(np.array(col) for col in zip(*rows))
    valid = results[scalar][3] > 0  # invalid samples (outside the disk): only pdf = weight = 0 is defined
    for n, (a, b) in enumerate(zip(results[scalar], results[variant])):
        b = b.reshape(a.shape)
        if n == 2:
            a, b = a[valid], b[valid]
        np.testing.assert_allclose(b, a, rtol=2e-3, atol=1e-4 * max(1.0, np.abs(a).max()))


@pytest.mark.parametrize("theta_deg", [60.0, 72.0, 80.0])
def test_the_lookup_next_to_the_rim_keeps_a_broad_lobes_albedo(llvm, beckmann, theta_deg):
    """The plugin's BRDF integrated over the disk (eval / cos θ_o on 512² directions, the dataset's
    own wavelengths) is the stored albedo Σ f Δu Δv: a query between the last pixel centre inside
    the disk and the rim reads the ring of pixels beyond it, which holds the nearest value inside,
    not 0 (which lost 0.6 % of a Beckmann α = 0.5 lobe at 60°; the rest, −0.2 %, is the bilinear
    lookup's trapezoid against the midpoint sum over a lobe squeezed toward the rim)."""
    import drjit as dr
    import h5py

    from benchmarks.white_furnace import albedo as furnace_albedo

    use("llvm_ad_spectral")
    path = beckmann[0.5]
    bsdf = mi.load_dict({"type": "wavebrdf", "filename": str(path), "isotropic": True, "smooth_sigma": 0.0})
    with h5py.File(path, "r") as h5:
        inc = int(np.flatnonzero(np.isclose(h5["theta_i"][()], theta_deg))[0])
        stored = h5["albedo"][:, inc]
    albedo = furnace_albedo(bsdf, theta_deg, WAVELENGTHS_UM, mi, dr)
    deviation = albedo / stored - 1.0
    print(f"θ_i {theta_deg}°: plugin's albedo / stored − 1 = {np.round(100 * deviation, 3)} %")
    assert np.all(np.abs(deviation) < 0.0035)


def test_speckle_blur_keeps_each_tables_albedo_at_the_rim():
    """The speckle blur (tables._smooth) of a table whose lobe sits at the rim of the disk (a
    grazing specular) keeps its albedo Σ f Δu Δv over the disk: the values filled in outside the
    disk do not leak in. A lobe well inside is blurred as a plain Gaussian filter blurs it."""
    from scipy.ndimage import gaussian_filter

    from wavebrdf.mitsuba.tables import _fill_outside, _pixel_centres, _smooth

    res, sigma_u = 64, 0.05
    c = _pixel_centres(res)
    u, v = np.meshgrid(c, c, indexing="ij")
    inside = u**2 + v**2 < 1.0
    rim = np.exp(-((u - 0.93) ** 2 + v**2) / (2 * 0.04**2))
    centre = np.exp(-((u - 0.1) ** 2 + v**2) / (2 * 0.04**2))
    cube = np.where(inside, np.stack([rim, centre]), np.nan)[:, None]  # (tables, wavelengths, res, res)
    filled, _ = _fill_outside(cube, "test")
    out = _smooth(filled, np.array([sigma_u]))
    for k in range(2):
        assert np.isclose(out[k, 0][inside].sum(), cube[k, 0][inside].sum(), rtol=1e-12), k
    bright = _smooth(np.where(inside, cube, 1e3), np.array([sigma_u]))  # another fill outside
    np.testing.assert_array_equal(bright[..., inside], out[..., inside])
    plain = gaussian_filter(centre, sigma_u * res / 2.0)
    np.testing.assert_allclose(out[1, 0][inside], plain[inside], rtol=0, atol=1e-6 * centre.max())


def test_each_sweep_case_is_blurred_as_its_own_waist_says(tmp_path):
    """A swept waist sets each case's speckle blur λ/(2π w), not the base config's."""
    import wavebrdf
    from wavebrdf.mitsuba.tables import load_tables

    study = {"study": {"output": str(tmp_path / "sweep.h5")},
             "surface": {"generator": "gaussian", "size_um": 8.0, "cells": 64, "rms_height_um": 0.02,
                         "correlation_um": 1.0, "seed": 3},
             "material": {"name": "aluminium"}, "model": {"name": "kirchhoff"}, "output": {"resolution": 16},
             "illumination": {"wavelengths_um": [0.5], "directions_deg": [[0, 0], [20, 0]], "waist_um": 1.0},
             "sweep": {"illumination.waist_um": [1.0, 1.5]}}
    with wavebrdf.run(study) as ds:
        path = ds.path
    for case, waist in enumerate((1.0, 1.5)):
        tables = load_tables(path, case=case, channels="mono")
        assert np.isclose(tables.diagnostics["smooth_sigma_u"][0], 0.5 / (2 * np.pi * waist), rtol=1e-12), case


def test_colour_tables_of_data_outside_the_visible_say_so(tmp_path, caplog):
    """rgb or mono tables of near-infrared data are the BRDF at 1.0 µm held flat over the visible
    (a grey): the tables' diagnostics and the log say so; spectral tables carry no such note."""
    from wavebrdf.mitsuba.tables import load_tables

    path = write_beckmann_dataset(tmp_path / "ir.h5", 0.3, resolution=32, wavelengths_um=[1.0, 1.5])
    for channels in ("rgb", "mono"):
        caplog.clear()
        note = load_tables(path, channels=channels).diagnostics["channels_note"]
        assert "no wavelength of the data (1–1.5 µm) lies in the visible" in note and "a grey" in note
        assert note in caplog.text
    assert load_tables(path, channels="spectral").diagnostics["channels_note"] == ""


def test_tables_of_one_polarizations_brdf_say_so(tmp_path, caplog):
    """An [illumination] polarization = "s" study stores R_s-like lobes, which the unpolarized
    variants would render as the unpolarized BRDF (flat glass at 60°: 0.177 against 0.089): the
    tables' diagnostics and the plugin's log say so; an unpolarized study's tables carry no such note."""
    import warnings

    import wavebrdf
    from wavebrdf.mitsuba.tables import load_tables

    def study(polarization):
        config = {"study": {"name": f"flat_{polarization}", "output": str(tmp_path / f"flat_{polarization}.h5")},
                  "surface": {"generator": "flat", "size_um": 8.0, "cells": 40}, "material": {"n": 1.5},
                  "illumination": {"wavelengths_um": [0.55], "directions_deg": [[60, 0]], "waist_um": 2.0,
                                   "polarization": polarization},
                  "model": {"name": "kirchhoff"}, "output": {"resolution": 32}}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            wavebrdf.run(config).close()
        return tmp_path / f"flat_{polarization}.h5"

    path = study("s")
    note = load_tables(path, channels="mono").diagnostics["polarization_note"]
    assert "s-polarized" in note and "renders as the unpolarized BRDF" in note
    mi.set_variant("scalar_rgb")
    from wavebrdf.mitsuba.bsdfs import register

    register()
    caplog.clear()
    mi.load_dict({"type": "wavebrdf", "filename": str(path)})  # the plugin logs it
    assert note in caplog.text
    assert "polarization_note" not in load_tables(study("unpolarized"), channels="mono").diagnostics
