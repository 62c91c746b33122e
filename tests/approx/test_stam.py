"""The ``stam`` rung (Stam 1999; approx.md §3.3 "Analytic special cases"): the expected Kirchhoff
BRDF of a Gaussian ensemble, checked against

* the mean of many ``kirchhoff`` realizations drawn from the same ensemble (the issue's bar:
  ≤ 5% relative L2 over the lobe, isotropic and rotated anisotropic);
* independent formulas written here or in tests/references.py: a flat ensemble reflects the
  Fresnel reflectance, the coherent part is attenuated by e^{−g}, the geometric-optics limit is
  the Beckmann microfacet BRDF |r|² D(ω_h)/(4μ_iμ_o);
* its own two forms where they overlap (series vs geometric optics), exact symmetries, the
  config/CLI path, and the GS rung in the geometric limit.
"""

from __future__ import annotations

import logging
import textwrap

import h5py
import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from references import ALUMINIUM_400NM, fresnel_reflectance
from wavebrdf.jobs.cli import main
from wavebrdf.solver.approx.stam import GO_THRESHOLD, stam_brdf
from wavebrdf.solver.farfield import HemisphereGrid, albedo
from wavebrdf.solver.models import SurfaceScene, get_model, model_names
from wavebrdf.solver.surface import GaussianEnsemble, HeightField, generate

logger = logging.getLogger(__name__)

DEG = np.pi / 180


def relative_l2(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    """‖a − b‖/‖b‖ over ``mask`` (pixels of equal projected solid angle)."""
    return float(np.linalg.norm((a - b)[mask]) / np.linalg.norm(b[mask]))


def blurred(brdf_sp: np.ndarray, sigma_px: float) -> np.ndarray:
    """The same Gaussian blur (σ in pixels) of each polarization's image, zero outside the disk."""
    return np.stack([gaussian_filter(np.nan_to_num(f), sigma_px, mode="constant") for f in brdf_sp])


# ============================================================================================
# 1. The bar: stam = the mean of kirchhoff realizations


def shifted(tile: np.ndarray, shift: tuple[int, int], size_um: float) -> HeightField:
    """The periodic realization whose N×N ``tile`` is translated by ``shift`` cells (equivalent
    to moving the footprint over the periodic surface)."""
    n = tile.shape[0]
    z = np.empty((n + 1, n + 1))
    z[:n, :n] = np.roll(tile, shift, axis=(0, 1))
    z[n] = z[0]
    z[:, n] = z[:, 0]
    return HeightField(z, size_um)


def kirchhoff_ensemble_mean(ctx, params: dict, seeds, shifts: int, *, cells: int, size_um: float,
                            wavelength_um: float, index, theta_i: float, phi_i: float, waist_um: float,
                            grid: HemisphereGrid) -> np.ndarray:
    """Mean kirchhoff BRDF (2, res, res) over the realizations ``seeds`` of the "gaussian" generator,
    each seen through shifts × shifts footprint positions (the tile translated by size/shifts)."""
    model = get_model("kirchhoff")
    total = np.zeros((2, grid.resolution, grid.resolution))
    count = 0
    step = cells // shifts
    for seed in seeds:
        tile = generate("gaussian", cells=cells, size_um=size_um, seed=seed, **params).z[:-1, :-1]
        for i in range(shifts):
            for j in range(shifts):
                scene = SurfaceScene(shifted(tile, (i * step, j * step), size_um), wavelength_um, complex(index),
                                     theta_i, phi_i, waist_um, grid)
                total += model.run(ctx, scene).brdf()
                count += 1
    return total / count


# λ = 0.5 µm, footprint w = 3 µm on a 16 µm periodic patch (5.3 w: no edge warning), 96 cells
# (d = λ/3, T/d ≥ 4), 64² pixels (speckle λ/(πw) = 0.053 ≥ the pixel 0.031); g at specular 4.7.
ENSEMBLE_CASES = {
    "isotropic": dict(params=dict(rms_height_um=0.1, correlation_um=1.0), theta_deg=30.0, phi_deg=0.0,
                      seeds=16, shifts=4, tolerance=0.05),
    "anisotropic": dict(params=dict(rms_height_um=0.1, correlation_um=[2.0, 0.7], angle_deg=30.0), theta_deg=30.0,
                        phi_deg=20.0, seeds=32, shifts=4, tolerance=0.05),
}
# slow: more looks, a tighter bar, a rougher surface (λ = 0.35 µm, g = 26 at specular: ~90 series
# terms; 128 cells for d < λ/(1 + |u_i| + 2 s_max)) and a brushed-like ensemble at 50° with a 20%
# coherent lobe. The patch must be many correlation lengths wide: a realization is scaled to the
# exact rms on the patch after its mean (the PSD's k = 0 share ε ≈ πT_xT_y/L²) is removed, so its
# small-scale variance exceeds the ensemble's by ε (measured: T = 2 µm on 16 µm, ε = 5%, gave a 5%
# systematic difference with 1024 looks; the cases here keep ε ≤ 2%).
ENSEMBLE_CASES_SLOW = {
    "isotropic-rough": dict(params=dict(rms_height_um=0.15, correlation_um=1.2), theta_deg=20.0, phi_deg=0.0,
                            seeds=32, shifts=4, tolerance=0.03, wavelength_um=0.35, cells=128),
    "brushed-50deg": dict(params=dict(rms_height_um=0.08, correlation_um=[3.0, 0.6], angle_deg=60.0),
                          theta_deg=50.0, phi_deg=-30.0, seeds=64, shifts=4, tolerance=0.03),
}
BLUR_PX = 2.0


def _ensemble_case(cl_ctx, name, case):
    """stam vs the mean of kirchhoff realizations, both blurred by the same Gaussian of 2 pixels."""
    lam, cells, size, waist = case.get("wavelength_um", 0.5), case.get("cells", 96), 16.0, 3.0
    tx, ty = np.broadcast_to(case["params"]["correlation_um"], (2,))
    assert np.pi * tx * ty / size**2 <= 0.025  # the realizations' exact-rms scaling (see above) stays small
    grid = HemisphereGrid(64)
    theta, phi = case["theta_deg"] * DEG, case["phi_deg"] * DEG
    index = 1.5
    ensemble = generate("gaussian", cells=cells, size_um=size, seed=0, **case["params"]).ensemble
    expected, coherent, diagnostics = stam_brdf(ensemble, lam, index, theta, phi, grid, waist)
    mean = kirchhoff_ensemble_mean(cl_ctx, case["params"], range(1, case["seeds"] + 1), case["shifts"],
                                   cells=cells, size_um=size, wavelength_um=lam, index=index, theta_i=theta,
                                   phi_i=phi, waist_um=waist, grid=grid)
    looks = case["seeds"] * case["shifts"] ** 2
    lobe = grid.inside & (expected[0] > 0.01 * np.nanmax(expected[0]))
    raw = [relative_l2(mean[p], expected[p], lobe) for p in range(2)]
    a, b = blurred(mean, BLUR_PX), blurred(expected, BLUR_PX)
    smooth = [relative_l2(a[p], b[p], lobe) for p in range(2)]
    albedo_stam, albedo_mean = albedo(expected, grid), albedo(mean, grid)
    logger.info("%s: %d looks, stam %s; relative L2 over the lobe (%d px): raw %s, blurred (%g px) %s; "
                "albedo stam %s vs kirchhoff mean %s", name, looks, diagnostics, lobe.sum(),
                np.round(raw, 4), BLUR_PX, np.round(smooth, 4), albedo_stam, albedo_mean)
    assert max(smooth) <= case["tolerance"], f"{name}: stam vs kirchhoff mean off by {smooth} (blurred)"
    assert np.all(np.abs(albedo_mean / albedo_stam - 1) < 0.01), (albedo_mean, albedo_stam)


@pytest.mark.parametrize("name", list(ENSEMBLE_CASES))
def test_stam_equals_mean_of_kirchhoff_realizations(cl_ctx, name):
    """Speckle averaged fairly: every realization (different seed, same ensemble) is seen through
    4 × 4 footprint positions (the periodic tile translated by L/4 = 4 µm ≈ 1.3 w, so successive
    looks' speckle is ~17% correlated), 256 (isotropic) / 512 (anisotropic) looks in all; the
    mean and the stam BRDF then get the same Gaussian blur of 2 pixels (0.06 in u, a quarter of the
    lobe's width) before the relative L2 over the lobe (stam > 1% of its peak) is taken. The
    albedos (no blur needed) agree within 1%."""
    _ensemble_case(cl_ctx, name, ENSEMBLE_CASES[name])


@pytest.mark.slow
@pytest.mark.parametrize("name", list(ENSEMBLE_CASES_SLOW))
def test_stam_equals_mean_of_kirchhoff_realizations_slow(cl_ctx, name):
    """As the CI case with 512–1024 looks, a 3% bar, rougher and more oblique scenes."""
    _ensemble_case(cl_ctx, name, ENSEMBLE_CASES_SLOW[name])


# ============================================================================================
# 2. Analytic references


@pytest.mark.parametrize("index", [1.5, ALUMINIUM_400NM], ids=["glass", "aluminium"])
def test_flat_ensemble_reflects_fresnel(index):
    """σ = 0: only the coherent lobe (the footprint's spectrum), whose albedo is |r_s|², |r_p|². The
    waist (30 µm: lobe σ_u = λ/(2πw) = 1.4 pixels of the 1024² grid) lets the pixel sum integrate it;
    its angular spread, and so the departure from plane-wave Fresnel (the conformance suite's
    θ = 80° case), is 0.15% at 70°."""
    grid = HemisphereGrid(1024)
    flat = GaussianEnsemble(0.0, (1.0, 1.0))
    for theta_deg in (0.0, 30.0, 70.0):  # (not near Brewster, where |r_p|² varies across the lobe)
        brdf, coherent, diag = stam_brdf(flat, 0.5, index, theta_deg * DEG, 40 * DEG, grid, 30.0)
        measured = albedo(brdf, grid)
        expected = np.array(fresnel_reflectance(1.0, index, theta_deg * DEG))
        logger.info("flat %s θ=%g°: albedo %s vs Fresnel %s (%s)", index, theta_deg, measured, expected, diag)
        assert np.all(np.abs(measured / expected - 1) < 5e-3)
        assert diag["coherent_fraction"] == pytest.approx(1.0)
        assert np.array_equal(np.nan_to_num(brdf), np.nan_to_num(coherent))


def test_coherent_part_is_attenuated_by_exp_minus_g():
    """The m = 0 term's albedo is e^{−g}|r|² with g = (2kσ cos θ_i)² (Stam's ⟨p⟩ = e^{−g/2})."""
    grid = HemisphereGrid(512)
    lam, index = 0.5, ALUMINIUM_400NM
    k = 2 * np.pi / lam
    for sigma in (0.01, 0.03, 0.06):
        for theta_deg in (0.0, 45.0):
            theta = theta_deg * DEG
            ensemble = GaussianEnsemble(sigma, (1.5, 0.8), 20.0)
            brdf, coherent, diag = stam_brdf(ensemble, lam, index, theta, 0.0, grid, 15.0)
            g = (2 * k * sigma * np.cos(theta)) ** 2
            expected = np.exp(-g) * np.array(fresnel_reflectance(1.0, index, theta))
            measured = albedo(coherent, grid)
            logger.info("σ=%g θ=%g°: g %.4g, coherent albedo %s vs e^-g |r|² %s; coherent fraction %.4g",
                        sigma, theta_deg, g, measured, expected, diag["coherent_fraction"])
            assert diag["g_specular"] == pytest.approx(g, rel=1e-12)
            assert np.all(np.abs(measured / expected - 1) < 5e-3)


def beckmann_brdf(grid: HemisphereGrid, index, theta_i, phi_i, sigma, correlation, angle_deg):
    """|r(θ_h)|² D(ω_h) / (4 μ_i μ_o), D the anisotropic Beckmann distribution of slopes with
    α = 2σ/T along the rotated axes: D = exp(−p_x'²/α_x² − p_y'²/α_y²)/(π α_x α_y cos⁴θ_h), where
    p = −(h_x, h_y)/h_z are the facet slopes of the half vector h (written from the textbook
    microfacet model, not from wavebrdf)."""
    U, V = grid.uv
    mu_o = grid.mu
    w_i = np.array([np.sin(theta_i) * np.cos(phi_i), np.sin(theta_i) * np.sin(phi_i), np.cos(theta_i)])
    h = np.stack([U + w_i[0], V + w_i[1], mu_o + w_i[2]])
    h /= np.linalg.norm(h, axis=0)
    px, py = -h[0] / h[2], -h[1] / h[2]
    a = np.deg2rad(angle_deg)
    pxr, pyr = np.cos(a) * px + np.sin(a) * py, -np.sin(a) * px + np.cos(a) * py
    ax, ay = 2 * sigma / correlation[0], 2 * sigma / correlation[1]
    D = np.exp(-(pxr / ax) ** 2 - (pyr / ay) ** 2) / (np.pi * ax * ay * h[2] ** 4)
    cos_h = h[0] * w_i[0] + h[1] * w_i[1] + h[2] * w_i[2]
    rs, rp = fresnel_reflectance(1.0, index, np.arccos(np.clip(cos_h, -1, 1)))
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.stack([rs, rp]) * D / (4 * np.cos(theta_i) * mu_o)
    return np.where(grid.inside, f, np.nan)


def test_geometric_limit_is_beckmann():
    """g ≫ 1 (σ = 1 µm at λ = 0.5: g ≈ 600 at specular, the GO form nearly everywhere), a wide footprint
    (100 µm: its spectrum is negligible): f = |r|² D_Beckmann(ω_h)/(4μ_iμ_o) within 1% over the lobe."""
    grid = HemisphereGrid(256)
    sigma, corr, angle = 1.0, (12.0, 7.0), 25.0
    for theta_deg, phi_deg in ((0.0, 0.0), (40.0, 70.0)):
        theta, phi = theta_deg * DEG, phi_deg * DEG
        brdf, _, diag = stam_brdf(GaussianEnsemble(sigma, corr, angle), 0.5, ALUMINIUM_400NM, theta, phi, grid, 100.0)
        reference = beckmann_brdf(grid, ALUMINIUM_400NM, theta, phi, sigma, corr, angle)
        lobe = grid.inside & (reference[0] > 0.01 * np.nanmax(reference[0]))
        err = [relative_l2(brdf[p], reference[p], lobe) for p in range(2)]
        logger.info("θ=%g°: stam (%s) vs Beckmann: relative L2 %s; albedo %s vs %s", theta_deg, diag["form"], err,
                    albedo(brdf, grid), albedo(reference, grid))
        assert diag["go_pixel_fraction"] > 0.9  # (grazing outputs, where μ_i + μ_o is small, sum the series)
        assert max(err) < 0.01


@pytest.mark.parametrize("g_specular", [60.0, 100.0, 160.0])
def test_series_and_geometric_forms_agree_where_they_overlap(g_specular):
    """Both forms on the same pixels near the switch (g = 100): the series (go_threshold = ∞) and the
    corrected GO form (go_threshold = 0) within 0.5% relative L2 over the lobe, so the default mix
    is seamless; the plain GO form (m → g, no Poisson-spread factor) is off by O(1/g), 0.5–5%."""
    from wavebrdf.solver.approx import stam as stam_module

    grid = HemisphereGrid(128)
    lam, theta = 0.5, 25 * DEG
    k = 2 * np.pi / lam
    sigma = np.sqrt(g_specular) / (2 * k * np.cos(theta))
    ensemble = GaussianEnsemble(sigma, (2.0, 1.2), 30.0)
    args = (ensemble, lam, 1.5, theta, 10 * DEG, grid, 8.0)
    series, _, d_series = stam_brdf(*args, go_threshold=np.inf)
    go, _, d_go = stam_brdf(*args, go_threshold=0.0)
    mixed, _, d_mixed = stam_brdf(*args)
    lobe = grid.inside & (series[0] > 0.01 * np.nanmax(series[0]))
    err_go = relative_l2(go[0], series[0], lobe)
    err_mixed = relative_l2(mixed[0], series[0], lobe)
    plain = stam_module._GaussianTerms.geometric
    try:  # the plain m → g form, for the record
        stam_module._GaussianTerms.geometric = lambda self, g, corrected=True: plain(self, g, corrected=False)
        uncorrected, _, _ = stam_brdf(*args, go_threshold=0.0)
    finally:
        stam_module._GaussianTerms.geometric = plain
    err_plain = relative_l2(uncorrected[0], series[0], lobe)
    logger.info("g_s = %g: %d series terms; GO vs series %.2e, mixed (%s, %.0f%% GO) vs series %.2e, plain GO %.3g",
                g_specular, d_series["terms"], err_go, d_mixed["form"], 100 * d_mixed["go_pixel_fraction"],
                err_mixed, err_plain)
    assert d_series["form"] == "series" and d_go["form"] == "GO"
    assert err_go < 5e-3 and err_mixed < 5e-3
    assert 5e-3 * (100 / g_specular) < err_plain < 0.05 * (100 / g_specular) + 0.01
    assert GO_THRESHOLD == 100.0


# ============================================================================================
# 3. Symmetries, precision, diagnostics


def test_rotation_by_90_degrees_transposes_the_image():
    """Ensemble and incidence both turned by 90° about ẑ: u ↔ v on the pixel grid (exact)."""
    grid = HemisphereGrid(96)
    a, _, _ = stam_brdf(GaussianEnsemble(0.12, (1.5, 0.5), 0.0), 0.5, 1.5, 35 * DEG, 0.0, grid, 5.0)
    b, _, _ = stam_brdf(GaussianEnsemble(0.12, (1.5, 0.5), 90.0), 0.5, 1.5, 35 * DEG, 90 * DEG, grid, 5.0)
    b_back = b[:, ::-1, :].transpose(0, 2, 1)  # rotate the image back by −90°: (u, v) → (v, −u)
    scale = np.nanmax(a)
    assert np.nanmax(np.abs(a - b_back)) < 1e-10 * scale


def test_single_precision_follows_double():
    grid = HemisphereGrid(128)
    args = (GaussianEnsemble(0.15, (1.0, 0.6), 15.0), 0.5, ALUMINIUM_400NM, 40 * DEG, 0.3, grid, 6.0)
    double, _, _ = stam_brdf(*args)
    single, _, _ = stam_brdf(*args, dtype=np.float32)
    lobe = grid.inside & (double[0] > 1e-3 * np.nanmax(double[0]))
    assert relative_l2(single[0], double[0], lobe) < 1e-4


def test_albedo_excess_is_reported_not_hidden(cl_ctx):
    """Kirchhoff without shadowing gains energy at grazing incidence on steep surfaces (approx.md
    §3.3 hazard 2); the model reports the excess albedo over 1 instead of renormalizing."""
    grid = HemisphereGrid(128)
    surface = generate("gaussian", cells=64, size_um=8.0, seed=1, rms_height_um=0.4, correlation_um=0.8)
    scene = SurfaceScene(surface, 0.5, -1e6j + 1.0, 80 * DEG, 0.0, 3.0, grid)  # a near-perfect conductor
    result = get_model("stam").run(cl_ctx, scene)
    a = albedo(result.brdf(), grid)
    logger.info("PEC-like, slopes %.2f, 80°: albedo %s, diagnostics %s", surface.ensemble.slope_rms[0], a,
                result.diagnostics)
    assert a.max() > 1.05
    assert result.diagnostics["albedo_excess"] == pytest.approx(a.max() - 1, rel=1e-9)
    for key in ("g_specular", "terms", "form", "coherent_fraction", "go_pixel_fraction"):
        assert key in result.diagnostics


# ============================================================================================
# 4. The model seam: refusals, config and CLI


def test_surfaces_without_an_ensemble_are_refused(cl_ctx):
    grid = HemisphereGrid(32)
    model = get_model("stam")
    cases = {
        "surface.file": HeightField(np.zeros((9, 9)), 2.0),
        'surface.generator = "sinusoid"': generate("sinusoid", cells=16, size_um=4.0, amplitude_um=0.1,
                                                   period_um=1.0),
        'surface.generator = "flat"': generate("flat", cells=16, size_um=4.0),
    }
    for where, surface in cases.items():
        scene = SurfaceScene(surface, 0.5, 1.5, 0.2, 0.0, 1.0, grid)
        for call in (model.check, lambda s: model.run(cl_ctx, s)):
            with pytest.raises(ValueError, match="stam") as info:
                call(scene)
            assert where in str(info.value) and "gaussian" in str(info.value)


STAM_STUDY = """
[study]
name = "stam-study"
output = "{out}"

[surface]
generator = "{generator}"
size_um = 8.0
cells = 32
{surface}

[material]
n = 1.5

[illumination]
wavelengths_um = [0.5]
directions_deg = [[0, 0], [40, 30]]
waist_um = 1.5

[model]
name = "stam"

[output]
resolution = 48
per_polarization = true
"""


def test_stam_study_runs_end_to_end(tmp_path, capsys):
    """config → plan → scheduler → store with the "statistics" model; the stored BRDF is the model's
    own (stam_brdf of the same ensemble), and a deterministic surface is refused at load."""
    surface = 'rms_height_um = 0.08\ncorrelation_um = [1.2, 0.6]\nangle_deg = 35.0\nseed = 4'
    cfg = tmp_path / "stam.toml"
    cfg.write_text(textwrap.dedent(STAM_STUDY.format(out=tmp_path / "stam.h5", generator="gaussian",
                                                     surface=surface)))
    assert main(["run", str(cfg), "-q", "--no-render"]) == 0, capsys.readouterr().err
    capsys.readouterr()
    grid = HemisphereGrid(48)
    ensemble = GaussianEnsemble(0.08, (1.2, 0.6), 35.0)
    with h5py.File(tmp_path / "stam.h5", "r") as h5:
        assert set(h5["tasks/status"][()].astype(str)) == {"done"}
        forms = set(h5["tasks/form"][()].astype(str))
        stored = h5["brdf_sp"][()][0]  # (incidence, pol, u, v)
        attrs = dict(h5["surface/height_0"].attrs)
    assert forms == {"series"}
    assert attrs["ensemble_correlation_um"].tolist() == [1.2, 0.6] and attrs["ensemble_angle_deg"] == 35.0
    for i, (theta, phi) in enumerate(((0.0, 0.0), (40.0, 30.0))):
        expected, _, _ = stam_brdf(ensemble, 0.5, 1.5, theta * DEG, phi * DEG, grid, 1.5)
        inside = grid.inside
        assert np.allclose(stored[i][:, inside], expected[:, inside], rtol=1e-6)  # float32 storage
    bad = tmp_path / "stam-sinusoid.toml"
    bad.write_text(textwrap.dedent(STAM_STUDY.format(out=tmp_path / "bad.h5", generator="sinusoid",
                                                     surface="amplitude_um = 0.1\nperiod_um = 2.0")))
    assert main(["plan", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "stam" in err and 'surface.generator = "sinusoid"' in err, err
    steered = tmp_path / "stam-steering.toml"
    steered.write_text(cfg.read_text() + "\n[steering]\npatches = [2, 2]\npatch_size_um = 4.0\n")
    assert main(["plan", str(steered)]) == 2
    assert "cannot be steered" in capsys.readouterr().err


# ============================================================================================
# 5. Against the geometric-optics rung GS in its own limit


@pytest.mark.skipif("gs" not in model_names(), reason="the GS rung is not registered")
def test_stam_matches_gs_in_the_geometric_limit(cl_ctx):
    """kσ = 6 ≥ 5 (g ≈ 110 at specular: no coherent lobe, mostly the GO form), total rms slope
    2σ/T = 0.24 ≤ 0.3 (little shadowing), θ_i = 30°, aluminium: stam (the ensemble expectation)
    and the mean of GS over 4 realizations of the same ensemble (2^20 rays each; a 12 µm footprint
    covers ~150 correlation areas, which sets GS's own realization noise) within 10% relative L2
    over the lobe after the same 2-pixel blur; albedos within 2%. GO does not depend on λ except
    through the index, so λ = 0.125 µm puts a fine-scale surface in the geometric limit."""
    lam, grid = 0.125, HemisphereGrid(64)
    params = dict(rms_height_um=0.12, correlation_um=1.0)
    gs = get_model("gs", {"rays": 1 << 20})
    mean = np.zeros((2, 64, 64))
    for seed in range(4):
        surface = generate("gaussian", cells=384, size_um=64.0, seed=seed, **params)
        scene = SurfaceScene(surface, lam, ALUMINIUM_400NM, 30 * DEG, 0.0, 12.0, grid)
        mean += gs.run(cl_ctx, scene).brdf() / 4
    ensemble = surface.ensemble
    assert 2 * np.pi / lam * ensemble.rms_height_um >= 5 and np.hypot(*ensemble.slope_rms) <= 0.3
    stam = get_model("stam").run(cl_ctx, scene)
    a = stam.brdf()
    lobe = grid.inside & (a[0] > 0.01 * np.nanmax(a[0]))
    A, B = blurred(a, BLUR_PX), blurred(mean, BLUR_PX)
    err = [relative_l2(B[p], A[p], lobe) for p in range(2)]
    logger.info("stam (%s, g_s %.1f) vs GS mean: relative L2 %s (raw %s); albedo %s vs %s", stam.diagnostics["form"],
                stam.diagnostics["g_specular"], np.round(err, 4),
                np.round([relative_l2(mean[p], a[p], lobe) for p in range(2)], 4), albedo(a, grid), albedo(mean, grid))
    assert max(err) < 0.10
    assert np.all(np.abs(albedo(mean, grid) / albedo(a, grid) - 1) < 0.02)
