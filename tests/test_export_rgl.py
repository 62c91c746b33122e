"""`wavebrdf export --format rgl` (jobs/export.py, wavebrdf/mitsuba/rgl.py): the RGL material file
read by Mitsuba's own readers, against the dataset it came from.

Independent references: Mitsuba's C++ tensor-file reader (``mi.TensorFile``) and its Python one
(``mitsuba.python.tensor_io``), its continuous marginal warp (``mi.MarginalContinuous2D0``) and
its built-in ``measured`` BSDF, which evaluates and samples the file; the datasets are the
textbook microfacet lobes of tests/test_mitsuba.py (Beckmann, Walter et al. 2007) and an
anisotropic Beckmann lobe written here (Heitz 2014, "Understanding the Masking-Shadowing Function
in Microfacet-Based BRDFs", eq. 85–87 with the anisotropic roughness of §5.3), stored with the
store's public writer; their stored albedo is the furnace's reference.
"""

from __future__ import annotations

import filecmp
import logging
import math

import h5py
import mitsuba as mi  # the `render` extra; missing = a failure, as every reference package
import numpy as np
import pytest
from scipy.special import erf

from test_mitsuba import beckmann_brdf, aluminium, pixel_directions, write_beckmann_dataset
from wavebrdf.jobs.cli import main
from wavebrdf.jobs.store import SurfaceDatasetWriter, atomic_h5
from wavebrdf.mitsuba.rgl import ContinuousWarp, write_tensor_file

logger = logging.getLogger(__name__)
THETAS_5 = [[float(t), 0.0] for t in range(0, 90, 5)]  # the render-ready incidences
WAVELENGTHS_UM = [0.45, 0.55, 0.65]


def export(*args) -> int:
    return main(["export", *map(str, args)])


def use(variant: str):
    import wavebrdf.mitsuba as wm

    mi.set_variant(variant)
    wm.register()
    return wm


@pytest.fixture(scope="module")
def iso(tmp_path_factory):
    """A Beckmann α = 0.2 aluminium dataset, θ_i every 5° to 85°, and its RGL files (spectral, rgb)."""
    folder = tmp_path_factory.mktemp("rgl_iso")
    path = write_beckmann_dataset(folder / "beckmann.h5", 0.2, resolution=96, wavelengths_um=WAVELENGTHS_UM,
                                  directions=THETAS_5)
    files = {}
    for channels in ("spectral", "rgb"):
        files[channels] = folder / f"beckmann_{channels}.bsdf"
        assert export(path, "-o", files[channels], "--channels", channels, "--isotropic", "--smooth-sigma", 0) == 0
    return path, files


@pytest.fixture
def llvm():
    from wavebrdf.mitsuba.scene import llvm_usable

    if not llvm_usable():
        pytest.skip("no libLLVM >= 17 for Mitsuba's llvm variants (see docs/mitsuba.md, Variants and speed)")


# -- the tensor file -------------------------------------------------------------------------------
def test_tensor_file_round_trips_through_mitsubas_readers(tmp_path):
    from mitsuba.python import tensor_io

    rng = np.random.default_rng(0)
    fields = {
        "description": np.frombuffer("λ = 550 nm, ünïcode".encode(), dtype=np.uint8),
        "jacobian": np.array([1], dtype=np.uint8),
        "grid": rng.random((2, 3, 5)).astype(np.float32),
        "wide": rng.random(7),  # float64
        "counts": np.arange(-3, 3, dtype=np.int32).reshape(2, 3),
        "empty": np.zeros(0, dtype=np.uint8),
        "odd": np.arange(3, dtype=np.uint16),  # 6 bytes: the next field is realigned
        "last": rng.random((4, 4)).astype(np.float32),
    }
    path = tmp_path / "t.bsdf"
    with open(path, "wb") as fh:
        write_tensor_file(fh, fields)
    read = tensor_io.read(str(path))  # Mitsuba's Python reader
    assert list(read) == list(fields)
    for name, value in fields.items():
        assert read[name].dtype == value.dtype and read[name].shape == value.shape, name
        np.testing.assert_array_equal(read[name], value)
    mi.set_variant("scalar_rgb")
    tf = mi.TensorFile(str(path))  # the C++ reader the measured plugin uses
    types = {np.float32: mi.Struct.Type.Float32, np.float64: mi.Struct.Type.Float64, np.uint8: mi.Struct.Type.UInt8,
             np.int32: mi.Struct.Type.Int32, np.uint16: mi.Struct.Type.UInt16}
    for name, value in fields.items():
        assert name in tf
        assert tf[name].dtype == types[value.dtype.type] and tf[name].offset % 8 == 0
    for name in ("grid", "last"):
        np.testing.assert_array_equal(np.array(tf[name].to(mi.TensorXf)), fields[name])
    assert "missing" not in tf


def test_warp_is_mitsubas_continuous_marginal_warp():
    """The map the exporter computes R at (sample space → u_m) is the one Mitsuba samples by."""
    mi.set_variant("scalar_rgb")
    rng = np.random.default_rng(1)
    for shape in ((5, 7), (33, 17)):
        density = (rng.random(shape) ** 3).astype(np.float32)
        density[:, -2:] = 0.0  # a zero band, as behind the terminator ⟨ω_i·m⟩ < 0
        density[1] = 0.0
        ours = ContinuousWarp(density)
        theirs = mi.MarginalContinuous2D0(density, normalize=True)
        points = np.concatenate([rng.random((300, 2)), [[0.0, 0.0], [1.0, 1.0], [0.5, 0.0], [0.0, 0.5]]])
        x, y, pdf = ours.sample(points[:, 0], points[:, 1])
        for k, (a, b) in enumerate(points):
            (mx, my), mpdf = theirs.sample(mi.Point2f(float(a), float(b)))
            # the corners: Mitsuba clips samples to [ε, 1 − ε], and next to a zero-density end
            # the inverse CDF goes as √ε there
            tolerance = 2e-5 if k < 300 else 1e-3
            assert abs(mx - x[k]) < tolerance and abs(my - y[k]) < tolerance, (shape, a, b)
            if k < 300:
                assert mpdf == pytest.approx(pdf[k], rel=1e-4, abs=1e-6)


# -- Mitsuba's measured BSDF reads the file -----------------------------------------------------------
def _direction(theta_deg, phi_deg):
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return mi.Vector3f(math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t))


def _random_directions(rng, n, theta_max_deg=90.0):
    """n directions uniform in solid angle up to θ_max, as an (n, 3) array."""
    cos_t = 1.0 - rng.random(n) * (1.0 - math.cos(math.radians(theta_max_deg)))
    phi = rng.random(n) * 2 * np.pi - np.pi
    sin_t = np.sqrt(1.0 - cos_t**2)
    return np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=-1)


def _eval_many(bsdf, wi, wo, wavelength_nm=None) -> np.ndarray:
    """eval (first channel) for pairs of directions, one call per pair (scalar variants)."""
    ctx = mi.BSDFContext()
    si = mi.SurfaceInteraction3f()
    if wavelength_nm is not None:
        si.wavelengths = mi.Spectrum(*([float(wavelength_nm)] * 4))
    out = np.empty(len(wo))
    for n, (a, b) in enumerate(zip(wi, wo)):
        si.wi = mi.Vector3f(*map(float, a))
        out[n] = np.array(bsdf.eval(ctx, si, mi.Vector3f(*map(float, b))))[0]
    return out


@pytest.mark.parametrize("variant", ["scalar_rgb", "scalar_spectral"])
def test_measured_loads_the_file_and_evaluates_the_tables(iso, variant):
    """Mitsuba's measured BSDF loads the file of its channel kind (and refuses the other); at a
    tabulated incidence its eval is the plugin's (the same tables) up to the sample-space
    interpolation."""
    from mitsuba.python import tensor_io

    path, files = iso
    spectral = "spectral" in variant
    use(variant)
    measured = mi.load_dict({"type": "measured", "filename": str(files["spectral" if spectral else "rgb"])})
    with pytest.raises(Exception, match="variant"):
        mi.load_dict({"type": "measured", "filename": str(files["rgb" if spectral else "spectral"])})
    plugin = mi.load_dict({"type": "wavebrdf", "filename": str(path), "isotropic": True, "smooth_sigma": 0.0})
    rng = np.random.default_rng(2)
    wo = _random_directions(rng, 1500, 85.0)
    wi = np.broadcast_to(np.array(_direction(40.0, 70.0)), wo.shape)
    wavelength = 550.0 if spectral else None
    a, b = _eval_many(measured, wi, wo, wavelength), _eval_many(plugin, wi, wo, wavelength)
    error = np.abs(a - b).sum() / b.sum()
    print(f"{variant}: eval at θ_i = 40° (tabulated), relative L1 measured vs wavebrdf plugin {error:.4f}")
    assert error < 0.01
    fields = tensor_io.read(str(files["spectral"]))
    np.testing.assert_allclose(fields["theta_i"], np.deg2rad(np.arange(0, 90, 5)), rtol=1e-6)
    assert fields["jacobian"].tolist() == [1] and fields["phi_i"].tolist() == [0.0]
    np.testing.assert_allclose(fields["wavelengths"], [450, 550, 650], rtol=1e-6)
    assert "beckmann.h5" in bytes(fields["description"]).decode() and "case 0" in bytes(fields["description"]).decode()


@pytest.mark.parametrize("variant", ["llvm_ad_rgb", "llvm_ad_spectral"])
def test_measured_loads_the_file_in_llvm_variants(llvm, iso, variant):
    import drjit as dr

    path, files = iso
    use(variant)
    kind = "spectral" if "spectral" in variant else "rgb"
    measured = mi.load_dict({"type": "measured", "filename": str(files[kind])})
    plugin = mi.load_dict({"type": "wavebrdf", "filename": str(path), "isotropic": True, "smooth_sigma": 0.0})
    rng = np.random.default_rng(3)
    n = 20000
    wi, wo = _random_directions(rng, n, 80.0), _random_directions(rng, n)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(*wi.T)
    if "spectral" in variant:
        si.wavelengths = mi.Spectrum(*([550.0] * 4))
    ctx = mi.BSDFContext()
    a = np.array(measured.eval(ctx, si, mi.Vector3f(*wo.T)))[0]
    b = np.array(plugin.eval(ctx, si, mi.Vector3f(*wo.T)))[0]
    ref = beckmann_brdf(wi, wo, 0.2, complex(aluminium([0.55])[0])) * wo[:, 2]
    if "rgb" in variant:  # compare shapes only: the R channel is no single wavelength's
        a, b, ref = a / a.sum(), b / b.sum(), ref / ref.sum()
    errors = [np.abs(x - ref).sum() / ref.sum() for x in (a, b)]
    print(f"{variant}: random incidences, relative L1 vs the analytic lobe: measured {errors[0]:.4f}, "
          f"wavebrdf plugin {errors[1]:.4f}")
    assert errors[0] < 0.03  # the format's own interpolation between the 5° nodes


# -- white furnace -------------------------------------------------------------------------------------
def test_white_furnace_matches_the_dataset_albedo(iso):
    """Albedo per θ_i and wavelength by Mitsuba's measured plugin (the mean BSDF sample weight of
    sample(): a white furnace) against the albedo stored in the dataset."""
    import h5py

    path, files = iso
    use("scalar_spectral")
    measured = mi.load_dict({"type": "measured", "filename": str(files["spectral"])})
    with h5py.File(path, "r") as h5:
        stored = h5["albedo"][()]  # (λ, incidence)
        thetas = h5["theta_i"][()]
    ctx = mi.BSDFContext()
    si = mi.SurfaceInteraction3f()
    si.wavelengths = mi.Spectrum(450.0, 550.0, 650.0, 550.0)
    rng = np.random.default_rng(4)
    worst = 0.0
    for k, theta in enumerate(thetas):
        si.wi = _direction(theta, 33.0)
        weights = []
        for a, b, c in rng.random((3000, 3)):
            _, weight = measured.sample(ctx, si, float(a), mi.Point2f(float(b), float(c)))
            weights.append(np.array(weight)[:3])
        weights = np.array(weights)
        albedo, error = weights.mean(axis=0), weights.std(axis=0) / math.sqrt(len(weights))
        deviation = albedo / stored[:, k] - 1.0
        print(f"θ_i = {theta:4.1f}°: measured {np.round(albedo, 4)} ± {np.round(error, 4)}, dataset "
              f"{np.round(stored[:, k], 4)}: {np.round(100 * deviation, 2)} %")
        assert np.all(np.abs(deviation) < 0.015 + 4 * error / stored[:, k])
        worst = max(worst, float(np.max(np.abs(deviation))))
    print(f"worst deviation {100 * worst:.2f} %")


# -- refusals and case selection ---------------------------------------------------------------------------
def test_sparse_incidences_are_refused_naming_the_config(tmp_path, capsys):
    sparse = write_beckmann_dataset(tmp_path / "sparse.h5", 0.3, resolution=32, wavelengths_um=[0.55],
                                    directions=[[0.0, 0.0], [30.0, 0.0], [60.0, 45.0]])
    out = tmp_path / "sparse.bsdf"
    assert export(sparse, "-o", out, "--isotropic") == 2
    message = capsys.readouterr().err
    assert "too sparse" in message and "a 30° gap between 60° and 90°" in message
    assert "wavebrdf run configs/render_ready.toml" in message
    assert "directions_deg = {theta = {start = 0, stop = 85, count = 18}, phi = 0}" in message
    assert export(sparse, "-o", out) == 2  # not declared isotropic: scattered directions
    message = capsys.readouterr().err
    assert "not a θ × φ grid" in message and "--isotropic" in message and "count = 12" in message
    one_phi = write_beckmann_dataset(tmp_path / "one_phi.h5", 0.3, resolution=32, wavelengths_um=[0.55],
                                     directions=THETAS_5)
    assert export(one_phi, "-o", out) == 2
    message = capsys.readouterr().err
    assert "at the one azimuth" in message and "--isotropic" in message
    assert not out.exists() and not list(tmp_path.glob(".sparse.bsdf*"))


def test_an_export_never_replaces_a_dataset(iso, tmp_path, capsys):
    """-o naming the dataset itself, or another wavebrdf dataset, is refused and both stay as they
    were; RGB and spectral exports get different default names."""
    path, _ = iso
    other = write_beckmann_dataset(tmp_path / "other.h5", 0.3, resolution=16, wavelengths_um=[0.55],
                                   directions=[[0.0, 0.0]])
    before = {p: p.read_bytes() for p in (path, other)}
    for target in (path, other):
        assert export(path, "-o", target, "--isotropic") == 2
        assert "is a wavebrdf dataset; an export never replaces one" in capsys.readouterr().err
    assert all(p.read_bytes() == data for p, data in before.items())
    copy = tmp_path / "beckmann.h5"
    copy.write_bytes(before[path])
    for channels in ("spectral", "rgb"):
        assert export(copy, "--channels", channels, "--isotropic", "--resolution", 8) == 0
    assert (tmp_path / "beckmann.bsdf").is_file() and (tmp_path / "beckmann_rgb.bsdf").is_file()


def test_an_export_replaces_only_its_own_formats_files(iso, tmp_path, capsys):
    """-o naming a user's file (a config, an HDF5 file that is not a dataset, a .bsdf that is not a
    tensor file) is refused and the file stays as it was; a previous export's .bsdf is replaced; a
    name without the format's suffix is refused, naming it."""
    path, _ = iso
    config, foreign, fake = tmp_path / "victim.toml", tmp_path / "meas.h5", tmp_path / "notes.bsdf"
    config.write_text("[study]\nname = 'x'\n")
    with h5py.File(foreign, "w") as h5:
        h5["data"] = np.arange(3)
    fake.write_text("my notes")
    before = {p: p.read_bytes() for p in (config, foreign, fake)}
    for target, said in ((config, "ends in .bsdf"), (foreign, "ends in .bsdf"), (fake, "is not a rgl file")):
        assert export(path, "-o", target, "--isotropic", "--resolution", 8) == 2
        assert said in capsys.readouterr().err
    assert all(p.read_bytes() == data for p, data in before.items())
    ours = tmp_path / "ours.bsdf"
    for _ in range(2):
        assert export(path, "-o", ours, "--isotropic", "--resolution", 8) == 0
    assert ours.read_bytes().startswith(b"tensor_file\x00")


def test_an_export_of_one_polarizations_brdf_says_so(tmp_path, capsys):
    """A study of the s-polarized BRDF exports that BRDF (the format has no polarization): the
    summary and the file's description say so; an unpolarized study's say nothing of it."""
    import wavebrdf

    for polarization in ("s", "unpolarized"):
        config = {"study": {"name": f"pol_{polarization}", "output": str(tmp_path / f"{polarization}.h5")},
                  "surface": {"generator": "gaussian", "size_um": 6.0, "cells": 64, "rms_height_um": 0.02,
                              "correlation_um": 0.8, "seed": 1},
                  "material": {"name": "aluminium"},
                  "illumination": {"wavelengths_um": [0.55], "waist_um": 1.2, "polarization": polarization,
                                   "directions_deg": [[float(t), 0.0] for t in range(0, 90, 10)]},
                  "model": {"name": "kirchhoff"}, "output": {"resolution": 32}}
        wavebrdf.run(config).close()
        out = tmp_path / f"{polarization}.bsdf"
        capsys.readouterr()
        assert export(tmp_path / f"{polarization}.h5", "-o", out, "--isotropic", "--resolution", 8) == 0
        said = capsys.readouterr().out
        description = out.read_bytes()  # the description field is stored as UTF-8 bytes
        if polarization == "s":
            assert "s-polarized" in said and b"s BRDF" in description, said
        else:
            assert "-polarized" not in said and b"unpolarized BRDF" in description, said
        assert main(["inspect", str(tmp_path / f"{polarization}.h5")]) == 0  # its albedo table says which
        assert f"albedo, {polarization} (rows:" in capsys.readouterr().out


def test_case_is_chosen_by_index_or_swept_value(tmp_path, capsys):
    path = write_beckmann_dataset(tmp_path / "sweep.h5", [0.2, 0.5], resolution=32, wavelengths_um=[0.55],
                                  directions=[[float(t), 0.0] for t in range(0, 90, 10)])
    assert export(path, "--isotropic", "--resolution", 16) == 2
    assert "2 sweep cases (model.alpha = 0.2, 0.5): choose one" in capsys.readouterr().err
    assert export(path, "--isotropic", "--resolution", 16, "--sweep", "model.alpha=0.3") == 2
    assert "not a swept value (values: 0.2, 0.5)" in capsys.readouterr().err
    assert export(path, "--isotropic", "--resolution", 16, "--case", 2) == 2
    assert "the dataset has 2 case(s)" in capsys.readouterr().err
    assert export(path, "--isotropic", "--resolution", 16, "--sweep", "model.alpha=0.5") == 0
    by_value = tmp_path / "sweep_case1.bsdf"  # the default name beside the dataset
    assert by_value.exists()
    by_index = tmp_path / "by_index.bsdf"
    assert export(path, "--isotropic", "--resolution", 16, "--case", 1, "-o", by_index) == 0
    assert filecmp.cmp(by_value, by_index, shallow=False)
    assert export(path, "--isotropic", "--resolution", 16, "--case", 0, "-o", tmp_path / "c0.bsdf") == 0
    assert not filecmp.cmp(by_value, tmp_path / "c0.bsdf", shallow=False)
    capsys.readouterr()
    assert main(["inspect", str(path)]) == 0  # the swept values as numbers, not reprs
    assert "sweep model.alpha: [0.2, 0.5]" in capsys.readouterr().out


# -- anisotropic data: a θ × φ grid ---------------------------------------------------------------------------
def anisotropic_beckmann(wi: np.ndarray, wo: np.ndarray, ax: float, ay: float, reflectance: float = 0.9):
    """f = F D G1(i) G1(o) / (4 cos θ_i cos θ_o) (1/sr) with the anisotropic Beckmann D and its
    Smith G1 (Heitz 2014): roughness α_x along x (the dataset's u), α_y along y; constant F."""
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    hz = np.clip(h[..., 2], 1e-12, 1.0)
    D = np.exp(-((h[..., 0] / ax) ** 2 + (h[..., 1] / ay) ** 2) / hz**2) / (np.pi * ax * ay * hz**4)

    def g1(v):
        cz = np.clip(v[..., 2], 1e-12, 1.0)
        s2 = np.clip(1.0 - cz**2, 1e-24, None)
        alpha = np.sqrt((v[..., 0] ** 2 * ax**2 + v[..., 1] ** 2 * ay**2) / s2)
        a = cz / np.maximum(alpha * np.sqrt(s2), 1e-12)
        return 2.0 / (1.0 + erf(a) + np.exp(-a * a) / (a * np.sqrt(np.pi)))

    f = reflectance * D * g1(wi) * g1(wo) / (4.0 * np.clip(wi[..., 2], 1e-12, 1) * np.clip(wo[..., 2], 1e-12, 1))
    return np.where((wi[..., 2] > 0) & (wo[..., 2] > 0), f, 0.0)


@pytest.fixture(scope="module", params=[0, 15])
def aniso(tmp_path_factory, request):
    """An anisotropic Beckmann dataset on θ_i = 0, 10, …, 80° × φ_i every 30° from ``request.param``
    (15°: no φ_i at ±180°, so the file's ±π nodes are blends) and its RGL file."""
    folder = tmp_path_factory.mktemp("rgl_aniso")
    path = folder / "aniso.h5"
    resolution = 64
    _, _, wo, inside = pixel_directions(resolution)
    directions = [[0.0, 0.0]] + [[float(t), float(p)] for t in range(10, 90, 10)
                                 for p in range(request.param, 360, 30)]
    with atomic_h5(path) as h5:
        writer = SurfaceDatasetWriter(h5, {}, [0.55], directions, resolution, "unpolarized", False)
        writer.create(config_text='[study]\nname = "aniso"\n[surface]\nfile = "analytic anisotropic Beckmann"\n',
                      study="aniso", software_version="test", device="numpy")
        writer.write_index((), np.array([1.0 + 0.0j]))
        for k, (t, p) in enumerate(np.deg2rad(directions)):
            wi = np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])
            f = np.where(inside, anisotropic_beckmann(np.broadcast_to(wi, wo.shape), wo, 0.15, 0.4), np.nan)
            albedo = float(np.nansum(f) * (2.0 / resolution) ** 2)
            writer.write_result((), 0, k, np.stack([f, f]), f, np.array([albedo, albedo]), albedo)
    out = folder / "aniso.bsdf"
    assert export(path, "-o", out, "--smooth-sigma", 0) == 0
    return path, out, request.param


def test_anisotropic_grid_keeps_its_orientation(aniso):
    """A θ × φ grid (not declared isotropic) becomes φ_i nodes from −π to π; the measured
    plugin then reproduces the anisotropic lobe (α_x ≠ α_y: a swapped axis or azimuth would
    not) at tabulated incidences and between them."""
    from mitsuba.python import tensor_io

    path, out, phase = aniso
    fields = tensor_io.read(str(out))
    nodes = np.arange(-180 + phase, 180, 30) if phase else np.arange(-180, 181, 30)
    expected = np.deg2rad(np.concatenate([[-180], nodes, [180]]) if phase else nodes)
    np.testing.assert_allclose(fields["phi_i"], expected, atol=1e-6)
    assert fields["spectra"].shape == (len(expected), 9, 1, 64, 64) and fields["spectra"].dtype == np.float32
    use("scalar_spectral")
    measured = mi.load_dict({"type": "measured", "filename": str(out)})
    rng = np.random.default_rng(5)
    wo = _random_directions(rng, 2000)
    tabulated = np.broadcast_to(np.array(_direction(40.0, 60.0 + phase)), wo.shape)
    between = _random_directions(rng, 2000, 80.0)
    for label, wi, bound in ((f"θ_i 40°, φ_i {60 + phase}° (tabulated)", tabulated, 0.02),
                             ("random incidences", between, 0.04)):
        value = _eval_many(measured, wi, wo, 550.0)
        reference = anisotropic_beckmann(wi, wo, 0.15, 0.4) * wo[:, 2]
        error = np.abs(value - reference).sum() / reference.sum()
        swapped = np.abs(value - anisotropic_beckmann(wi, wo, 0.4, 0.15) * wo[:, 2]).sum() / reference.sum()
        print(f"anisotropic, {label}: relative L1 vs the analytic lobe {error:.4f} (axes swapped: {swapped:.3f})")
        assert error < bound and swapped > 5 * bound


# -- renders ---------------------------------------------------------------------------------------------------
def relative_l1(image: np.ndarray, reference: np.ndarray) -> float:
    """Σ|I − R| / Σ R over the RGB of the pixels fully covered by the sphere in both."""
    mask = (reference[..., 3] > 0.999) & (image[..., 3] > 0.999)
    return float(np.abs(image[..., :3] - reference[..., :3])[mask].sum() / np.abs(reference[..., :3])[mask].sum())


def compare_renders(path, files, variant, resolution, spp):
    """(measured vs the wavebrdf plugin, the plugin at two seeds: the metric's noise floor)."""
    from wavebrdf.mitsuba import environment, scene_dict

    use(variant)
    env = environment(128)  # the example scene's sky and 2° sun

    def render(bsdf, seed):
        scene = mi.load_dict(scene_dict(bsdf, resolution=resolution, spp=spp, env=env, hide_emitters=True, seed=seed))
        return np.array(mi.render(scene))

    plugin = {"type": "wavebrdf", "filename": str(path), "isotropic": True, "smooth_sigma": 0.0}
    measured = {"type": "measured", "filename": str(files["spectral" if "spectral" in variant else "rgb"])}
    reference = render(plugin, 0)
    error, noise = relative_l1(render(measured, 0), reference), relative_l1(render(plugin, 1), reference)
    print(f"{variant} {resolution}² × {spp} spp: Σ|I − R|/ΣR measured vs wavebrdf plugin {error:.4f}, noise "
          f"floor (plugin, seeds 0 and 1) {noise:.4f}")
    return error, noise


@pytest.mark.parametrize("variant, resolution, spp", [
    ("scalar_rgb", 16, 256), pytest.param("scalar_spectral", 16, 256, marks=pytest.mark.slow)])  # CI: rgb (and llvm below)
def test_sphere_matches_the_plugin(iso, variant, resolution, spp):
    error, noise = compare_renders(*iso, variant, resolution, spp)
    assert noise < 0.05  # the metric resolves a few per cent
    assert error < 1.25 * noise


def test_sphere_matches_the_plugin_llvm(llvm, iso):
    error, noise = compare_renders(*iso, "llvm_ad_rgb", 64, 256)
    assert noise < 0.03
    assert error < 1.25 * noise


@pytest.mark.slow
@pytest.mark.parametrize("variant", ["llvm_ad_rgb", "llvm_ad_spectral"])
def test_sphere_matches_the_plugin_at_low_noise(llvm, iso, variant):
    error, noise = compare_renders(*iso, variant, 64, 2048)
    assert noise < 0.008
    assert error < 1.25 * noise


def test_a_non_reciprocal_models_export_says_it_reads_backwards(tmp_path, capsys):
    """A dataset of a model whose capabilities say it is not reciprocal (po) is exported with a note
    that a renderer looks it up with the camera-side direction as the incidence; a reciprocal
    model's (kirchhoff) without."""
    import wavebrdf

    notes = {}
    for model in ("po", "kirchhoff"):
        study = {"study": {"output": str(tmp_path / f"{model}.h5")},
                 "surface": {"generator": "gaussian", "size_um": 8.0, "cells": 64, "rms_height_um": 0.05,
                             "correlation_um": 0.8, "seed": 2},
                 "material": {"name": "aluminium"}, "model": {"name": model}, "output": {"resolution": 24},
                 "illumination": {"wavelengths_um": [0.5], "waist_um": 1.5,
                                  "directions_deg": {"theta": {"start": 0, "stop": 85, "count": 18}, "phi": 0}}}
        with wavebrdf.run(study):
            pass
        assert export(tmp_path / f"{model}.h5", "-o", tmp_path / f"{model}.bsdf", "--resolution", 8) == 0
        notes[model] = capsys.readouterr().out
    assert "note: po is not reciprocal" in notes["po"] and "camera-side" in notes["po"]
    assert "is not reciprocal" not in notes["kirchhoff"]  # (the 8² grid's albedo note may be there)


def test_an_rgb_export_of_data_outside_the_visible_says_its_colour_is_not_measured(tmp_path, capsys):
    """Near-infrared data (1.0 and 1.5 µm): the colour matching functions see the BRDF at 1.0 µm held
    flat over 380–780 nm (solver/spectrum.py), a grey; the summary says so, and the spectral export,
    which keeps the wavelengths, does not."""
    path = write_beckmann_dataset(tmp_path / "ir.h5", 0.3, resolution=32, wavelengths_um=[1.0, 1.5],
                                  directions=THETAS_5)
    notes = {}
    for channels in ("rgb", "spectral"):
        assert export(path, "-o", tmp_path / f"ir_{channels}.bsdf", "--channels", channels, "--isotropic") == 0
        notes[channels] = capsys.readouterr().out
    assert "no wavelength of the data (1–1.5 µm) lies in the visible" in notes["rgb"]
    assert "the BRDF at 1 µm carried flat across the visible, a grey" in notes["rgb"]
    assert "visible" not in notes["spectral"]


def test_a_file_that_loses_a_narrow_lobes_energy_says_so(iso, tmp_path, capsys):
    """A narrow Beckmann lobe (α = 0.03) near grazing is under-resolved by a 32² sample grid: the
    export's summary names the incidence and the file's albedo against its table's, and that figure
    is what Mitsuba's own sampling of the file measures (θ_i = 85°: −34 %), within 1.5 %; the broad
    render-ready lobe (α = 0.2) at the default grid says nothing of it."""
    import re

    from wavebrdf.mitsuba.tables import load_tables

    path = write_beckmann_dataset(tmp_path / "narrow.h5", 0.03, resolution=96, wavelengths_um=[0.55],
                                  directions=THETAS_5)
    out = tmp_path / "narrow.bsdf"
    capsys.readouterr()
    assert export(path, "-o", out, "--isotropic", "--smooth-sigma", 0, "--resolution", 32) == 0
    said = capsys.readouterr().out
    found = re.search(r"at θ_i = ([\d.]+)°, φ_i = [-\d.]+° the file's albedo \(estimated from its nodes\) is ([-+\d.]+)% "
                      r"off its table's", said)
    assert found, said
    theta, figure = float(found.group(1)), float(found.group(2)) / 100.0
    use("scalar_spectral")
    measured = mi.load_dict({"type": "measured", "filename": str(out)})
    si = mi.SurfaceInteraction3f()
    si.wi = _direction(theta, 0.0)
    si.wavelengths = mi.Spectrum(550.0, 550.0, 550.0, 550.0)
    rng = np.random.default_rng(7)
    weights = [float(np.array(measured.sample(mi.BSDFContext(), si, float(a), mi.Point2f(float(b), float(c)))[1])[0])
               for a, b, c in rng.random((6000, 3))]
    tables = load_tables(path, channels="spectral", smooth_sigma=0.0, isotropic=True)
    k = int(np.argmin(np.abs(np.rad2deg(tables.theta) - theta)))
    table = float(tables.albedo(k)[0])
    sampled = float(np.mean(weights)) / table - 1.0
    logger.info("θ_i %s°: the export's figure %+.4f, Mitsuba's sampling of the file %+.4f", theta, figure, sampled)
    assert figure < -0.1 and abs(figure - sampled) < 0.015
    assert export(iso[0], "-o", tmp_path / "broad.bsdf", "--isotropic", "--smooth-sigma", 0) == 0
    assert "file's albedo" not in capsys.readouterr().out
