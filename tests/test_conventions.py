"""Dataset conventions (schema v3): every example config's dataset, made through the Python API
with overrides, is read by netCDF-C (netCDF4) without unnamed dimensions and with CF-style
attributes, and by xarray at the minimum versions pyproject allows (.venv/xarray-min, made by
tools/setup.sh), selecting by θ_i and by a swept value."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import h5py
import numpy as np
import pytest

import wavebrdf
from wavebrdf.jobs.store import StoreError, atomic_h5

ROOT = Path(__file__).resolve().parent.parent
MIN_PYTHON = ROOT / ".venv" / "xarray-min" / "bin" / "python"
# every config in configs/: overrides that make it run in seconds, with one swept key (its value
# index 1 is selected below) and the θ_i selected
EXAMPLES = {
    "default.toml": ({"output.resolution": 32, "surface.cells": 200,
                      "illumination.wavelengths_um": {"start": 0.45, "stop": 0.65, "count": 2},
                      "sweep": {"surface.seed": {"start": 1, "stop": 2, "count": 2}}}, 30.0, "surface.seed"),
    "stam_brushed.toml": ({"output.resolution": 32, "sweep": {"surface.rms_height_um": [0.04, 0.08]}}, 60.0,
                          "surface.rms_height_um"),
    "corner_cubes.toml": ({"output.resolution": 32, "surface.cells": 200, "sweep": {"surface.period_um": [2.0, 4.0]}},
                          40.0, "surface.period_um"),
    "heightfield_file.toml": ({"output.resolution": 32, "illumination.wavelengths_um": [0.5],
                               "sweep": {"material.name": ["silver", "gold"]}}, 45.0, "material.name"),
    "fiber_circle.toml": ({"model.name": "mie", "illumination.wavelengths_um": {"start": 0.4, "stop": 0.7, "count": 3},
                           "output.phi_r_bins": 36, "sweep": {"fiber.radius_um": [0.5, 1.0]}}, 30.0, "fiber.radius_um"),
    "fiber_ellipse.toml": ({"illumination.wavelengths_um": [0.5], "illumination.theta_i_deg": [0, 40],
                            "fiber.segments": 48, "output.phi_i_bins": 2, "output.phi_r_bins": 36,
                            "sweep": {"material.kappa": [0.0, 0.02]}}, 40.0, "material.kappa"),
    "render_ready.toml": ({"output.resolution": 32, "illumination.wavelengths_um": [0.45, 0.65],
                           "sweep": {"surface.seed": [1, 2]}}, 30.0, "surface.seed"),
    "polarization.toml": ({"output.resolution": 32, "surface.cells": 200, "illumination.wavelengths_um": [0.5],
                           "sweep": {"surface.seed": [1, 2]}}, 60.0, "surface.seed"),
}
MINUTES = {"bem_aim_aluminium.toml", "bem_aim_reference.toml", "bem_rough_aluminium.toml",
           "steering_bem.toml"}  # full-wave: minutes
CLUSTER = {"reference_subareas.toml"}  # days on a cluster: planned in tests/test_reference_inputs.py, not run


def test_every_example_config_is_covered():
    assert set(EXAMPLES) | MINUTES | CLUSTER == {p.name for p in (ROOT / "configs").glob("*.toml")}


@pytest.fixture(scope="module")
def examples(tmp_path_factory):
    folder = tmp_path_factory.mktemp("examples")
    made = {}
    for name, (overrides, theta, key) in EXAMPLES.items():
        out = folder / name.replace(".toml", ".h5")
        with wavebrdf.run(ROOT / "configs" / name, **{"study.output": str(out)}, **overrides) as ds:
            made[name] = (out, ds.kind, theta, key)
    return made


def test_minimum_xarray_selects_by_theta_and_by_a_swept_value(examples):
    assert MIN_PYTHON.is_file(), f"{MIN_PYTHON} is missing: run tools/setup.sh (it installs tools/xarray-min.txt)"
    items = [{"path": str(out), "kind": kind, "theta_i": theta, "sweep_key": key, "sweep_index": 1}
             for out, kind, theta, key in examples.values()]
    result = subprocess.run([str(MIN_PYTHON), str(ROOT / "tests" / "xarray_min_reader.py"), json.dumps(items)],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    report = json.loads(result.stdout.strip().splitlines()[-1])
    pins = {line.split("==")[0]: line.split("==")[1] for line in (ROOT / "tools" / "xarray-min.txt").read_text()
            .splitlines() if "==" in line}
    assert report["xarray"] == pins["xarray"] == "2024.1.0" and report["h5netcdf"] == pins["h5netcdf"]
    for checked in report["checked"]:
        assert {"/", "surface", "tasks"} <= set(checked["groups"]) or {"/", "fiber", "tasks"} <= set(checked["groups"])


def _walk(group, path="/"):
    yield path, group
    for name, sub in group.groups.items():
        yield from _walk(sub, f"{path}{name}/")


def test_netcdf_reads_named_dimensions_and_cf_attributes(examples):
    import netCDF4

    for name, (out, kind, _, key) in examples.items():
        with netCDF4.Dataset(out) as nc:
            assert nc.Conventions == "CF-1.8" and nc.format_version == 3
            assert "wavebrdf" in nc.history and name in nc.history
            seen = set()
            for where, group in _walk(nc):
                seen.add(where)
                for dim in group.dimensions:
                    assert not dim.startswith("phony_dim"), (name, where, dim)
                    assert dim[0].isalpha(), (name, where, dim)  # CF 2.3: names begin with a letter
                for var_name, var in group.variables.items():
                    assert var_name[0].isalpha(), (name, where, var_name)
                    attrs = var.ncattrs()
                    assert "long_name" in attrs, (name, where, var_name)
                    if var.dtype is not str:
                        assert "units" in attrs, (name, where, var_name)
            assert {"/tasks/", f"/{'fiber' if kind == 'fiber' else 'surface'}/"} <= seen
            assert nc["tasks"].dimensions.keys() == {"task"}
            unit = {"surface.seed": "1", "material.name": None, "material.kappa": "1"}.get(key, "um")
            assert getattr(nc[key], "units", None) == unit, (name, key)
            assert nc["wavelength_um"].units == "um" and nc["theta_i"].units == "degree"


def test_api_overrides_ranges_and_selection(examples):
    out = examples["default.toml"][0]
    with wavebrdf.open(out) as ds:
        assert np.allclose(ds.coords["wavelength_um"], np.linspace(0.45, 0.65, 2))
        assert list(ds.coords["surface.seed"]) == [1, 2] and ds.brdf.shape[-2:] == (32, 32)
        assert ds.config.startswith(f"# {ROOT / 'configs' / 'default.toml'} with overrides: ")
        assert ds.surface(1).shape == (201, 201)
        x = ds.to_xarray()
        albedo = x.albedo.sel(theta_i=40, phi_i=45).sel({"surface.seed": 2})
        assert np.allclose(albedo.values, ds.albedo[1, :, 2])
    # a config given as a dict, with a section merged from an override
    data = {"study": {"output": str(out.with_name("dict.h5"))},
            "surface": {"generator": "flat", "size_um": 4.0, "cells": 32},
            "material": {"n": 1.5}, "model": {"name": "kirchhoff"}, "output": {"resolution": 16},
            "illumination": {"wavelengths_um": [0.5], "directions_deg": {"theta": [0, 20], "phi": [0, 90]},
                             "waist_um": 0.7}}
    with wavebrdf.run(data, material={"n": 2.0}) as ds:
        assert [tuple(d) for d in zip(ds.coords["theta_i"], ds.coords["phi_i"])] == [(0, 0), (20, 0), (20, 90)]
        assert ds["ior_n"][0] == 2.0
        # flat dielectric at normal incidence: albedo = the Fresnel reflectance ((n − 1)/(n + 1))²
        assert ds.albedo[0, 0] == pytest.approx(((2.0 - 1) / (2.0 + 1)) ** 2, rel=0.05)


@pytest.mark.parametrize("umask", [0o022, 0o077])
def test_datasets_are_created_with_the_umask(tmp_path, umask):
    old = os.umask(umask)
    try:
        with atomic_h5(tmp_path / "x.h5") as h5:
            h5["a"] = np.arange(3)
    finally:
        os.umask(old)
    assert (tmp_path / "x.h5").stat().st_mode & 0o777 == 0o666 & ~umask


def test_previous_format_version_is_read_and_a_newer_one_refused(examples, tmp_path):
    source = examples["stam_brushed.toml"][0]
    for version, readable in ((1, True), (2, True), (4, False)):
        copy = tmp_path / f"v{version}.h5"
        shutil.copyfile(source, copy)
        with h5py.File(copy, "r+") as h5:
            h5.attrs["format_version"] = version
        if readable:
            with wavebrdf.open(copy) as ds:
                assert ds.brdf.shape[0] == 2
        else:
            with pytest.raises(StoreError, match="format version 4 .*reads format versions 1, 2, 3"):
                wavebrdf.open(copy)
