"""Fiber studies through configs, the batch layer, HDF5 and render (issue 6, deliverable 6)."""

from __future__ import annotations

import textwrap

import numpy as np
import pytest

import wavebrdf
from wavebrdf.jobs.cli import main
from wavebrdf.jobs.config import ConfigError, parse_config
from wavebrdf.solver.fiber import mie_cylinder

FIBER = """
[study]
name = "{name}"
output = "{out}"

[fiber]
{fiber}

[material]
n = 1.55
kappa = 0.05

[illumination]
wavelengths_um = [0.45, 0.5, 0.55]
theta_i_deg = [0, 30]
{extra_illumination}

[model]
name = "{model}"

[output]
phi_r_bins = 72
{extra_output}
"""


def write(tmp_path, name, fiber, model, extra_illumination="", extra_output=""):
    path = tmp_path / f"{name}.toml"
    path.write_text(textwrap.dedent(FIBER.format(name=name, out=tmp_path / f"{name}.h5", fiber=fiber, model=model,
                                                 extra_illumination=extra_illumination,
                                                 extra_output=extra_output)))
    return path


def test_circle_study_matches_mie_and_is_xarray_readable(tmp_path):
    cfg = write(tmp_path, "circle", 'shape = "circle"\nradius_um = 0.3\nsegments = 64', "fiber-bem")
    assert main(["run", str(cfg), "-q"]) == 0
    out = tmp_path / "circle.h5"
    import h5netcdf  # noqa: F401  (dev dependency: engine="h5netcdf" below; a missing one fails)
    import xarray as xr

    ds = xr.open_dataset(out, engine="h5netcdf")
    assert ds["bcsdf"].dims == ("wavelength_um", "theta_i", "phi_i", "phi_r")
    assert ds["C_ext"].dims == ("wavelength_um", "theta_i", "polarization", "phi_i")
    assert list(ds["polarization"].values) == ["parallel", "perpendicular"]
    assert list(ds["theta_i"].values) == [0.0, 30.0] and ds.sizes["phi_r"] == 72
    for li, lam in enumerate([0.45, 0.5, 0.55]):
        for ti, theta in enumerate([0.0, 30.0]):
            mie = mie_cylinder(lam, 0.3, 1.55 - 0.05j, np.deg2rad(theta))
            bem = ds["C_ext"].values[li, ti, :, 0]
            assert np.allclose(bem, mie.C_ext, rtol=2e-3), (lam, theta, bem, mie.C_ext)
    # Σ N_wave Δφ = C_sca / C_ext (the albedo of the azimuthal lobe)
    albedo = ds["bcsdf"].sum("phi_r").values * (2 * np.pi / 72)
    expected = (ds["C_sca"].mean("polarization") / ds["C_ext"].mean("polarization")).values
    assert np.allclose(albedo, expected, rtol=1e-5)
    assert np.all(ds["power_balance_error"].values < 1e-3)
    assert len(list((tmp_path / "circle_png").glob("circle_theta?.png"))) == 2  # + slices, albedo, cross sections
    with wavebrdf.open(out) as d:
        assert d.kind == "fiber" and d.coords["phi_r"].size == 72 and d["fiber/polygon_0"].shape == (64, 2)


def test_ellipse_with_phi_i_bins_and_explicit_samples(tmp_path):
    ellipse = 'shape = "ellipse"\nsemi_axes_um = [0.4, 0.25]\nsegments = 80'
    binned = write(tmp_path, "binned", ellipse, "fiber-bem", extra_output="phi_i_bins = 8")
    explicit = write(tmp_path, "explicit", ellipse, "fiber-bem", extra_illumination="phi_i_deg = [0, 90]")
    assert main(["run", str(binned), "-q", "--no-render"]) == 0
    assert main(["run", str(explicit), "-q", "--no-render"]) == 0
    with wavebrdf.open(tmp_path / "binned.h5") as a, wavebrdf.open(tmp_path / "explicit.h5") as b:
        assert a["bcsdf"].shape == (3, 2, 8, 72) and b["bcsdf"].shape == (3, 2, 2, 72)
        assert list(b.coords["phi_i"]) == [0.0, 90.0]
        # the ellipse looks different from φ_i = 0 and 90°: widths 0.8 and 0.5 µm
        assert np.allclose(b["C_geom"], [0.5, 0.8], rtol=1e-2)  # seen from +x: 2b; from +y: 2a
        assert not np.allclose(b["C_ext"][..., 0], b["C_ext"][..., 1], rtol=1e-2)


def test_mie_model_fast_path(tmp_path):
    cfg = write(tmp_path, "mie", 'shape = "circle"\nradius_um = 1.0', "mie")
    assert main(["run", str(cfg), "-q", "--no-render"]) == 0
    with wavebrdf.open(tmp_path / "mie.h5") as d:
        mie = mie_cylinder(0.5, 1.0, 1.55 - 0.05j, 0.0)
        assert np.allclose(d["C_sca"][1, 0, :, 0], mie.C_sca, rtol=1e-10)


@pytest.mark.parametrize(
    "fiber, model, extra, pattern",
    [
        ('shape = "ellipse"\nsemi_axes_um = [0.4, 0.25]\nsegments = 64', "mie", "", "Mie series solves circular"),
        ('shape = "circle"\nsegments = 64', "fiber-bem", "", "radius_um: required"),
        ('shape = "circle"\nradius_um = 1.0\nsemi_axes_um = [1, 2]\nsegments = 64', "fiber-bem", "", "not used"),
        ('shape = "circle"\nradius_um = 1.0', "fiber-bem", "", "segments: required by the fiber-bem"),
        ('shape = "circle"\nradius_um = 1.0\nsegments = 64', "kirchhoff", "", "fiber study needs one of"),
        ('shape = "circle"\nradius_um = 1.0\nsegments = 64', "mie", "waist_um = 1.0", "not used in a fiber study"),
        ('shape = "polygon"\npoints_file = "nope.txt"', "fiber-bem", "", "does not exist"),
    ],
)
def test_bad_fiber_configs(tmp_path, fiber, model, extra, pattern):
    cfg = write(tmp_path, "bad", fiber, model, extra_illumination=extra)
    with pytest.raises(ConfigError, match=pattern):
        parse_config(cfg.read_text(), cfg)


def test_theta_i_must_avoid_grazing(tmp_path):
    cfg = write(tmp_path, "grazing", 'shape = "circle"\nradius_um = 1.0', "mie")
    text = cfg.read_text().replace("theta_i_deg = [0, 30]", "theta_i_deg = [0, 90]")
    with pytest.raises(ConfigError, match=r"\(-90, 90\)"):
        parse_config(text, cfg)
