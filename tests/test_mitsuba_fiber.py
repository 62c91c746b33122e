"""The "wavebrdf_fiber" Mitsuba 3 BSDF (issue 20): sample() against pdf() (chi-square), eval against
the dataset's own BCSDF evaluator and stored effective widths, the Null (pass-through) component,
and the example fiber scene."""

from __future__ import annotations

import math
import textwrap

import mitsuba as mi  # the `render` extra; missing = a failure, as every reference package
import numpy as np
import pytest

import wavebrdf
from test_mitsuba import merged_chi_square
from wavebrdf.jobs.cli import main
from wavebrdf.solver.validity import ValidityWarning

FIBER = """
[study]
name = "{name}"
output = "{out}"

[fiber]
{fiber}
longitudinal_variance = 0.05

[material]
n = 1.55
kappa = 0.05

[illumination]
wavelengths_um = {lams}
theta_i_deg = {thetas}

[model]
name = "{model}"

[output]
phi_r_bins = 36
{extra}
"""


def make_dataset(folder, name, fiber, model, lams, thetas, extra=""):
    cfg = folder / f"{name}.toml"
    cfg.write_text(textwrap.dedent(FIBER.format(name=name, out=folder / f"{name}.h5", fiber=fiber, model=model,
                                                lams=lams, thetas=thetas, extra=extra)))
    assert main(["run", str(cfg), "-q", "--no-render"]) == 0
    return folder / f"{name}.h5"


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fibers")
    circle = make_dataset(folder, "circle", 'shape = "circle"\nradius_um = 0.5', "mie", [0.45, 0.55, 0.65],
                          [0, 30, 60])
    ellipse = make_dataset(folder, "ellipse", 'shape = "ellipse"\nsemi_axes_um = [0.4, 0.25]\nsegments = 48',
                           "fiber-bem", [0.5, 0.6], [0, 40], extra="phi_i_bins = 8")
    return {"circle": circle, "ellipse": ellipse}


def use(variant):
    import wavebrdf.mitsuba as wm

    mi.set_variant(variant)
    wm.register()
    return wm


def interaction(theta_deg, psi_deg, u=0.0):
    """An interaction whose wi makes θ (from the normal plane = local xz) and azimuth ψ (from n
    toward s; |ψ| < 90°: front face) in the fiber frame of the plugin (axis = local y); uv = (u, 0.5)."""
    t, p = np.radians(theta_deg), np.radians(psi_deg)
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(float(np.cos(t) * np.sin(p)), float(np.sin(t)), float(np.cos(t) * np.cos(p)))
    si.uv = mi.Point2f(float(u), 0.5)
    return si


def chi_square_p_value(bsdf, si, *, offset, bins_phi, samples=4000, bins_y=12, sub=8, seed=1):
    """Goodness of fit of sample() against pdf() over the sphere of ω_o, binned in (sinθ_o, φ_o):
    φ cells aligned with the table's φ_r bins (edges ``offset`` + (k - ½)·2π/bins_phi, where the
    plugin's φ density is constant), expected counts = samples × Σ pdf Δ(sinθ) Δφ (midpoint rule
    in sinθ on ``sub`` points per cell), plus one cell for Null samples (1 - ∫ pdf dω)."""
    ctx = mi.BSDFContext()
    rng = np.random.default_rng(seed)
    dphi = 2 * np.pi / bins_phi
    observed = np.zeros(bins_y * bins_phi + 1)
    for n, (a, b, c) in enumerate(rng.random((samples, 3))):
        bs, weight = bsdf.sample(ctx, si, float(a), mi.Point2f(float(b), float(c)))
        if bs.sampled_type == +mi.BSDFFlags.Null:
            assert np.allclose(np.array(bs.wo), -np.array(si.wi), atol=1e-6)
            observed[-1] += 1
            continue
        y = min(max(bs.wo.y, -1.0), 1.0)
        phi = math.atan2(bs.wo.x, bs.wo.z)
        i = min(int((y + 1) / 2 * bins_y), bins_y - 1)
        j = int(math.floor((phi - offset) / dphi + 0.5)) % bins_phi
        observed[i * bins_phi + j] += 1
        if n < 50:  # the sample weight is eval / pdf
            assert bs.pdf == pytest.approx(bsdf.pdf(ctx, si, bs.wo), rel=1e-5)
            assert np.allclose(np.array(weight), np.array(bsdf.eval(ctx, si, bs.wo)) / bs.pdf, rtol=1e-5)
    h = 2.0 / (bins_y * sub)
    ys = -1.0 + h * (np.arange(bins_y * sub) + 0.5)
    cells = np.zeros((bins_y, bins_phi))
    for k, y in enumerate(ys):
        c = math.sqrt(1 - y * y)
        for j in range(bins_phi):
            phi = offset + j * dphi
            wo = mi.Vector3f(float(c * math.sin(phi)), float(y), float(c * math.cos(phi)))
            cells[k // sub, j] += bsdf.pdf(ctx, si, wo) * h * dphi
    assert 0.3 < cells.sum() <= 1.0 + 1e-3
    return merged_chi_square(observed, cells.ravel(), samples)


@pytest.mark.parametrize("name, variant, theta, psi, u", [
    ("circle", "scalar_rgb", 10.0, 20.0, 0.0),     # between θ_i nodes
    ("circle", "scalar_rgb", -45.0, -70.0, 0.0),  # negative θ_i (z-mirror), between nodes
    ("circle", "scalar_spectral", 60.0, 0.0, 0.0),  # at a node, hero-wavelength CDFs
    ("ellipse", "scalar_rgb", 25.0, 60.0, 0.3),  # φ_i = 2π·0.3 + 60° between bins, absolute φ_r bins
])
def test_sample_matches_pdf_chi_square(datasets, name, variant, theta, psi, u):
    use(variant)
    bsdf = mi.load_dict({"type": "wavebrdf_fiber", "filename": str(datasets[name])})
    si = interaction(theta, psi, u)
    if "spectral" in variant:
        si.wavelengths = mi.Spectrum([500.0, 560.0, 610.0, 640.0])
    circle = name == "circle"
    # φ_o = 2π u + ψ_o: the φ_r bins sit at φ_o = k·10° (+ φ_i for a circle); in ψ_o, shifted by -2πu
    offset = (np.radians(psi) if circle else 0.0) - (0.0 if circle else 2 * np.pi * u)
    p, cells = chi_square_p_value(bsdf, si, offset=offset, bins_phi=36)
    print(f"chi-square {name} {variant} θ,ψ = {theta}, {psi}: p = {p:.3f} over {cells} cells")
    assert cells > 30
    assert p > 0.01


@pytest.mark.parametrize("name", ["circle", "ellipse"])
def test_eval_is_hit_times_dataset_bcsdf(datasets, name):
    """Spectral variant at tabulated incidences (λ, θ_i, φ_i nodes; any ψ_i, u, ω_o): eval(wi, wo)
    = (C_e/C_b)(λ, wi) · S(wi → wo), with S from ``wavebrdf.open(...).bcsdf`` and C_e read from the
    file: the plugin's fiber frame (axis = local y, φ = 2π u + atan2(x, z)), its θ_r/φ_r
    dependence and its M₀ are those of the evaluator. (Between incidence nodes the plugin
    interpolates the product (C_e/C_b)·N_wave, which differs from the product of interpolants.)"""
    use("scalar_spectral")
    path = datasets[name]
    ds = wavebrdf.open(path)
    lams = ds.h5["wavelength_um"][()]
    c_eff = ds.h5["C_eff"][()]
    bsdf = mi.load_dict({"type": "wavebrdf_fiber", "filename": str(path)})
    ctx = mi.BSDFContext()
    rng = np.random.default_rng(4)
    for _ in range(6):
        theta_i = rng.choice([-1, 1]) * rng.choice(ds.h5["theta_i"][()])
        psi_i = rng.uniform(-85, 85)
        phi_node = rng.choice(ds.h5["phi_i"][()])  # a φ_i bin centre (a circle: any)
        u = ((phi_node - psi_i) / 360.0) % 1.0
        si = interaction(theta_i, psi_i, u)
        si.wavelengths = mi.Spectrum([lams[0] * 1000, lams[-1] * 1000, lams[0] * 1000, lams[-1] * 1000])
        alpha = 2 * np.pi * u
        for _ in range(4):
            t, p = np.radians(rng.uniform(-80, 80)), rng.uniform(-np.pi, np.pi)
            wo = mi.Vector3f(float(np.cos(t) * np.sin(p)), float(np.sin(t)), float(np.cos(t) * np.cos(p)))
            value = np.array(bsdf.eval(ctx, si, wo))
            for k, li in enumerate([0, len(lams) - 1]):
                s = ds.bcsdf(np.radians(theta_i), t, alpha + np.radians(psi_i), alpha + p, lams[li])
                c_e = _interp_c_eff(ds, c_eff[li], np.radians(theta_i), alpha + np.radians(psi_i))
                assert value[k] == pytest.approx(c_e / c_eff.max() * s, rel=2e-4)


def _interp_c_eff(ds, c_eff_l, theta, phi):
    """C_e of one wavelength at (|θ_i|, φ_i): linear in θ_i (clamped), φ_i periodic between the
    stored bin centres (one φ_i: constant)."""
    thetas = np.radians(ds.h5["theta_i"][()])
    P = c_eff_l.shape[1]
    x = np.clip(abs(theta), thetas[0], thetas[-1])
    per_t = np.array([np.interp(phi % (2 * np.pi), np.arange(P + 1) * 2 * np.pi / P,
                                np.append(c_eff_l[t], c_eff_l[t][0])) for t in range(len(thetas))])
    return float(np.interp(x, thetas, per_t))


def test_null_component_and_back_faces(datasets):
    use("scalar_rgb")
    bsdf = mi.load_dict({"type": "wavebrdf_fiber", "filename": str(datasets["circle"]), "variance": 0.2})
    assert "v = 0.2" in str(bsdf)
    ctx = mi.BSDFContext()
    si = interaction(20.0, 30.0)
    bs, weight = bsdf.sample(ctx, si, 0.0, mi.Point2f(0.5, 0.5))  # sample1 = 0: the Null branch
    assert bs.sampled_type == +mi.BSDFFlags.Null and np.allclose(np.array(bs.wo), -np.array(si.wi))
    miss = np.array(bsdf.eval_null_transmission(si))
    assert np.all((miss > 0) & (miss < 1))
    assert np.allclose(np.array(weight) * bs.pdf, miss, rtol=1e-5)  # weight = miss / P_null
    back = interaction(20.0, 30.0)
    back.wi = -back.wi
    assert np.allclose(np.array(bsdf.eval_null_transmission(back)), 1.0)
    assert np.allclose(np.array(bsdf.eval(ctx, back, mi.Vector3f(0, 0, 1))), 0.0)
    assert bsdf.pdf(ctx, back, mi.Vector3f(0, 0, 1)) == 0.0
    bs, weight = bsdf.sample(ctx, back, 0.9, mi.Point2f(0.5, 0.5))
    assert bs.sampled_type == +mi.BSDFFlags.Null and np.allclose(np.array(weight), 1.0)
    with pytest.raises(Exception, match="filename"):
        mi.load_dict({"type": "wavebrdf_fiber"})


def test_fiber_scene_renders_and_cli_checks_kinds(datasets, tmp_path, capsys):
    from wavebrdf.mitsuba import render_scene

    result = render_scene(datasets["circle"], "fibers", tmp_path / "wisp.png", spp=4, resolution=24,
                          variant="scalar_rgb")
    assert result["path"].is_file() and result["image"].shape == (24, 24, 4)
    assert np.isfinite(result["image"]).all() and result["image"][..., 3].max() > 0.5  # fibers cover pixels
    assert main(["render", str(datasets["circle"]), "--scene", "sphere"]) == 2
    assert "fiber datasets render with --scene fibers" in capsys.readouterr().err


@pytest.mark.parametrize("variant, name", [("llvm_ad_rgb", "circle"), ("llvm_ad_spectral", "circle"),
                                           ("llvm_ad_rgb", "ellipse")])
def test_jit_variant_matches_scalar(datasets, variant, name):
    """The Dr.Jit backend (vectorized, traced) computes what the scalar backend computes: eval, pdf,
    null transmission, sampled directions, pdfs and weights (front and back faces)."""
    import drjit as dr

    from wavebrdf.mitsuba.scene import llvm_usable

    if not llvm_usable():
        pytest.skip("no libLLVM >= 17 for Mitsuba's llvm variants (the JIT backend of the plugin is "
                    "also exercised by cuda variants on GPUs)")
    rng = np.random.default_rng(12)
    count = 48

    def directions(n, psi_max):
        t, p = np.radians(rng.uniform(-80, 80, n)), np.radians(rng.uniform(-psi_max, psi_max, n))
        return np.column_stack([np.cos(t) * np.sin(p), np.sin(t), np.cos(t) * np.cos(p)])

    wi, wo = directions(count, 85), directions(count, 180)
    wi[::8] *= -1  # back faces
    uv = rng.random(count)
    xi = rng.random((count, 3))
    lam = rng.uniform(400, 700, (count, 4))
    scalar = variant.replace("llvm_ad", "scalar")
    results = {}
    for mode in (scalar, variant):
        use(mode)
        bsdf = mi.load_dict({"type": "wavebrdf_fiber", "filename": str(datasets[name])})
        ctx = mi.BSDFContext()
        if mode == variant:
            si = dr.zeros(mi.SurfaceInteraction3f, count)
            si.wi = mi.Vector3f(*[mi.Float(c) for c in wi.T])
            si.uv = mi.Point2f(mi.Float(uv), mi.Float(np.full(count, 0.5)))
            if "spectral" in mode:
                si.wavelengths = mi.Spectrum(*[mi.Float(c) for c in lam.T])
            out = mi.Vector3f(*[mi.Float(c) for c in wo.T])
            bs, weight = bsdf.sample(ctx, si, mi.Float(xi[:, 0]), mi.Point2f(mi.Float(xi[:, 1]), mi.Float(xi[:, 2])))
            results[mode] = (np.array(bsdf.eval(ctx, si, out)).T, np.array(bsdf.pdf(ctx, si, out)),
                             np.array(bsdf.eval_null_transmission(si)).T, np.array(bs.wo).T, np.array(bs.pdf),
                             np.array(weight).T)
            continue
        rows = []
        for n in range(count):
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(*map(float, wi[n]))
            si.uv = mi.Point2f(float(uv[n]), 0.5)
            if "spectral" in mode:
                si.wavelengths = mi.Spectrum(*map(float, lam[n]))
            out = mi.Vector3f(*map(float, wo[n]))
            bs, weight = bsdf.sample(ctx, si, float(xi[n, 0]), mi.Point2f(float(xi[n, 1]), float(xi[n, 2])))
            rows.append((np.array(bsdf.eval(ctx, si, out)), bsdf.pdf(ctx, si, out),
                         np.array(bsdf.eval_null_transmission(si)), np.array(bs.wo), bs.pdf, np.array(weight)))
        results[mode] = tuple(np.array(col) for col in zip(*rows))
    for a, b in zip(results[scalar], results[variant]):
        b = b.reshape(a.shape)
        np.testing.assert_allclose(b, a, rtol=2e-3, atol=1e-4 * max(1.0, np.abs(a).max()))


def test_a_table_of_one_phi_i_is_read_at_its_own_azimuth(datasets, tmp_path):
    """A circle computed at one explicit φ_i = 30° holds φ_r for that incidence (forward peak at
    210°): read at any φ_i it is the circle's table turned by φ_i − 30°, so ``bcsdf`` and the plugin
    equal the φ_i = 0 circle's everywhere (they read it as if stored for φ_i = 0, 30° off: 5 %
    at the forward peak). A non-circular cross section computed at one φ_i says it is read as if
    rotation invariant."""
    import warnings

    turned = make_dataset(tmp_path, "circle30", 'shape = "circle"\nradius_um = 0.5', "mie", [0.45, 0.55, 0.65],
                          "[0, 30, 60]\nphi_i_deg = [30]")  # the template's theta_i_deg line, then φ_i
    plain, turned = wavebrdf.open(datasets["circle"]), wavebrdf.open(turned)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ValidityWarning)  # a circle at one φ_i is rotation invariant: no warning
        turned.bcsdf(0.0, 0.0, 0.0, 0.0, 0.55)
    phi_r = np.deg2rad(turned.h5["phi_r"][()])
    assert np.isclose(np.rad2deg(phi_r[np.argmax(turned.h5["bcsdf"][0, 0, 0])]), 210.0, atol=5.0)
    rng = np.random.default_rng(3)
    for _ in range(20):
        theta_i, theta_r = np.radians(rng.uniform(-60, 60, 2))
        phi_i, phi_r_query = rng.uniform(-np.pi, np.pi, 2)
        a = turned.bcsdf(theta_i, theta_r, phi_i, phi_r_query, 0.55)
        b = plain.bcsdf(theta_i, theta_r, phi_i, phi_r_query, 0.55)
        assert float(a) == pytest.approx(float(b), rel=1e-6)
    use("scalar_spectral")
    bsdfs = [mi.load_dict({"type": "wavebrdf_fiber", "filename": str(p)}) for p in (datasets["circle"], turned.path)]
    ctx = mi.BSDFContext()
    for psi_i, u in ((10.0, 0.1), (-40.0, 0.7)):
        si = interaction(30.0, psi_i, u)
        si.wavelengths = mi.Spectrum([550.0] * 4)
        for t, p in ((0.2, 0.5), (-0.4, 2.8), (0.1, -1.2)):
            wo = mi.Vector3f(float(np.cos(t) * np.sin(p)), float(np.sin(t)), float(np.cos(t) * np.cos(p)))
            values = [float(np.array(b.eval(ctx, si, wo))[0]) for b in bsdfs]
            assert values[1] == pytest.approx(values[0], rel=1e-5)
    use("scalar_rgb")  # and samples what it evaluates (the φ_r bins sit at φ_i + k·10° in ψ_o)
    si = interaction(10.0, 20.0, 0.0)
    p, cells = chi_square_p_value(mi.load_dict({"type": "wavebrdf_fiber", "filename": str(turned.path)}), si,
                                  offset=np.radians(20.0), bins_phi=36)
    assert cells > 30 and p > 0.01
    ellipse = make_dataset(tmp_path, "ellipse1", 'shape = "ellipse"\nsemi_axes_um = [0.4, 0.25]\nsegments = 48',
                           "fiber-bem", [0.55], "[0]\nphi_i_deg = [20]")
    with pytest.warns(ValidityWarning, match=r"one φ_i \(20°\) of a cross section that is not a circle"):
        wavebrdf.open(ellipse).bcsdf(0.0, 0.0, 0.3, 1.0, 0.55)
