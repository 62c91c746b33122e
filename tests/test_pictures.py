"""Pictures (``wavebrdf render``): which files, what their axes and scales say, the specular
marker and in-plane slice against the mirror direction, options and the cap on their number."""

from __future__ import annotations

import logging
import textwrap

import numpy as np
import pytest

import wavebrdf
from wavebrdf.jobs.cli import main
from wavebrdf.jobs.pictures import PictureOptions, pictures
from wavebrdf.jobs.pictures import surface as surface_pictures
from wavebrdf.jobs.pictures.surface import direction_values, in_plane, specular_uv
from wavebrdf.jobs.render import render_dataset

SURFACE = """
[study]
output = "{out}"
[surface]
generator = "gaussian"
size_um = 8.0
cells = 64
rms_height_um = 0.005
correlation_um = 1.0
[material]
name = "silver"
[illumination]
wavelengths_um = {{start = 0.45, stop = 0.65, count = 3}}
directions_deg = [[0, 0], [40, 30]]
waist_um = 1.5
[model]
name = "kirchhoff"
[output]
resolution = 64
"""
FIBER = """
[study]
output = "{out}"
[fiber]
shape = "circle"
radius_um = 0.3
[material]
n = 1.5
[illumination]
wavelengths_um = [0.5, 0.6]
theta_i_deg = [0, 30]
[model]
name = "mie"
[output]
phi_r_bins = 36
"""


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    folder = tmp_path_factory.mktemp("pictures")
    made = {}
    for name, text in (("surface", SURFACE), ("fiber", FIBER)):
        cfg = folder / f"{name}.toml"
        cfg.write_text(textwrap.dedent(text.format(out=folder / f"{name}.h5")))
        assert main(["run", str(cfg), "-q", "--no-render"]) == 0
        made[name] = folder / f"{name}.h5"
    return made


def test_every_kind_is_written_with_its_name(datasets, tmp_path):
    surface = render_dataset(datasets["surface"], tmp_path / "s")
    assert [p.name for p in surface] == [f"surface{s}.png" for s in (
        "_heights", "_albedo", "_inc0", "_slice_inc0", "_spectra_inc0", "_inc1", "_slice_inc1", "_spectra_inc1")]
    fiber = render_dataset(datasets["fiber"], tmp_path / "f")
    assert [p.name for p in fiber] == [f"fiber{s}.png" for s in (
        "_cross_sections", "_albedo", "_theta0", "_slice_theta0", "_theta1", "_slice_theta1")]
    assert all(p.stat().st_size > 5000 for p in [*surface, *fiber]) and surface.total == 8


def test_hemisphere_is_round_with_a_log_scale_in_units(datasets):
    with wavebrdf.open(datasets["surface"]) as ds:
        picture = [p for p in pictures(ds, PictureOptions(("maps",)), surface_pictures) if p.suffix == "_inc1"][0]
        fig = picture.draw()
    image, bar = fig.axes
    assert image.get_aspect() == 1.0 and image.get_xlim() == image.get_ylim()  # the horizon is a circle
    assert bar.get_yscale() == "log" and "1/sr" in bar.get_ylabel()
    marker = [line for line in image.get_lines() if line.get_label() == "specular"][0]
    # mirror direction of ω_i = (40°, 30°): (u, v) = −sin θ_i (cos φ_i, sin φ_i); the picture's x is v, y is u
    assert marker.get_xdata()[0] == pytest.approx(-np.sin(np.radians(40)) * np.sin(np.radians(30)))
    assert marker.get_ydata()[0] == pytest.approx(-np.sin(np.radians(40)) * np.cos(np.radians(30)))


def test_specular_marker_and_slice_peak_where_a_smooth_surface_reflects(datasets):
    with wavebrdf.open(datasets["surface"]) as ds:
        cube = np.asarray(ds.brdf[:, 1], dtype=float)  # (λ, u, v) at θ_i = 40°, φ_i = 30°
        u = ds.coords["u"]
    i, j = np.unravel_index(np.nanargmax(cube[1]), cube[1].shape)
    pixel = u[1] - u[0]
    su, sv = specular_uv(40.0, 30.0)
    assert abs(u[i] - su) <= pixel and abs(u[j] - sv) <= pixel
    theta_o, values = in_plane(cube, 30.0)
    assert abs(theta_o[np.nanargmax(values[1])] - 40.0) < 2.0  # the specular side is θ_o > 0


def test_direction_values_average_a_cone():
    cube = np.full((2, 64, 64), 3.0)
    assert np.allclose(direction_values(cube, 50.0, 120.0), 3.0)
    cube[1] = 7.0
    assert np.allclose(direction_values(cube, 0.0, 0.0), [3.0, 7.0])


def test_options_and_the_cap(datasets, tmp_path, caplog, capsys):
    chosen = render_dataset(datasets["surface"], tmp_path / "a", plots=["maps", "spectra"], incidences=[1],
                            directions=[(10, 0), (30, 200)])
    assert [p.name for p in chosen] == ["surface_inc1.png", "surface_spectra_inc1.png"]
    with caplog.at_level(logging.WARNING, logger="wavebrdf.render"):
        capped = render_dataset(datasets["fiber"], tmp_path / "b", max_images=2)
    assert len(capped) == 2 and capped.total == 6
    assert "wrote the first 2 of 6 pictures" in caplog.text and "--max-images" in caplog.text
    capsys.readouterr()
    for args, text in ((["--plots", "heights"], "--plots heights: fiber datasets have the pictures maps"),
                       (["--incidences", "5"], "--incidences 5: indices along theta_i are 0 to 1"),
                       (["--limits", "1", "0.5"], "--limits 1.0 0.5: need 0 < VMIN < VMAX")):
        assert main(["render", str(datasets["fiber"]), "--out", str(tmp_path / "c"), *args]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and text in err, err
    assert not (tmp_path / "c").exists()
    # a kind the surface dataset has no data for (intensity only): said in one line, no empty folder
    assert main(["render", str(datasets["surface"]), "--out", str(tmp_path / "d"), "--plots", "polarization"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "has none of these pictures" in err and "damaged" not in err, err
    assert not (tmp_path / "d").exists()
