"""HDF5 schema v1: independent readers (xarray/h5netcdf, h5py) see the documented layout."""

from __future__ import annotations

import textwrap

import h5py
import numpy as np
import pytest

import wavebrdf
from wavebrdf.jobs.cli import main
from wavebrdf.jobs.store import StoreError, atomic_h5

SWEEP_CONFIG = """
[study]
name = "sweep"
output = "{out}"

[surface]
generator = "gaussian"
size_um = 6.0
cells = 60
rms_height_um = 0.03
correlation_um = 1.0

[material]
name = "copper"

[illumination]
wavelengths_um = [0.45, 0.55, 0.65]
directions_deg = [[0, 0], [40, 30]]
waist_um = 1.0
polarization = "s"

[model]
name = "kirchhoff"

[output]
resolution = 48
per_polarization = true

[sweep]
"surface.rms_height_um" = [0.02, 0.05]
"surface.correlation_um" = [0.8, 1.2]
"""


@pytest.fixture(scope="module")
def sweep_dataset(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sweep")
    out = folder / "sweep.h5"
    cfg = folder / "sweep.toml"
    cfg.write_text(textwrap.dedent(SWEEP_CONFIG.format(out=out)))
    assert main(["run", str(cfg), "--quiet", "--no-render"]) == 0
    return out


def test_xarray_reads_every_swept_coordinate(sweep_dataset):
    import h5netcdf  # noqa: F401  (dev dependency: engine="h5netcdf" below; a missing one fails)
    import xarray as xr

    ds = xr.open_dataset(sweep_dataset, engine="h5netcdf")
    assert ds["brdf"].dims == ("surface.rms_height_um", "surface.correlation_um", "wavelength_um", "incidence", "u", "v")
    assert list(ds["surface.rms_height_um"].values) == [0.02, 0.05]
    assert list(ds["surface.correlation_um"].values) == [0.8, 1.2]
    assert np.allclose(ds["wavelength_um"].values, [0.45, 0.55, 0.65])
    assert list(ds["theta_i"].values) == [0.0, 40.0] and "theta_i" in ds.coords
    assert list(ds["polarization"].values) == ["s", "p"]
    assert ds["brdf_sp"].dims[-3:] == ("polarization", "u", "v")
    # the configured polarization ("s") is what `brdf` holds
    assert np.allclose(ds["brdf"].values, ds["brdf_sp"].sel(polarization="s").values, equal_nan=True)
    # albedo variable = sum of brdf * pixel area, NaN outside the disk
    res = ds.sizes["u"]
    summed = np.nansum(ds["brdf"].values.astype(float), axis=(-2, -1)) * (2.0 / res) ** 2
    assert np.allclose(summed, ds["albedo"].values, rtol=1e-5)
    U, V = np.meshgrid(ds["u"].values, ds["v"].values, indexing="ij")
    assert np.all(np.isnan(ds["brdf"].values[..., U**2 + V**2 > 1]))
    # rougher surfaces scatter more light away from the specular pixel
    peak = ds["brdf"].max(dim=("u", "v"))
    assert np.all(peak.isel({"surface.rms_height_um": 0}) > peak.isel({"surface.rms_height_um": 1}))


def test_reader_and_provenance(sweep_dataset):
    with wavebrdf.open(sweep_dataset) as ds:
        assert ds.attrs["format"] == "wavebrdf" and ds.attrs["format_version"] == 3
        assert ds.attrs["software_version"] == wavebrdf.__version__
        assert "[sweep]" in ds.config
        assert ds.sweep_keys == ["surface.rms_height_um", "surface.correlation_um"]
        assert ds.brdf.shape == (2, 2, 3, 2, 48, 48)
        assert len(ds.tasks["id"]) == 2 * 2 * 3 * 2 and set(ds.tasks["status"].astype(str)) == {"done"}
        assert ds.surface(3).shape == (61, 61)
        n, kappa = ds["ior_n"], ds["ior_kappa"]
        assert n.shape == (2, 2, 3) and np.all(kappa > 0)
    assert not sweep_dataset.with_name("sweep.h5.parts").exists()


def test_atomic_write_leaves_nothing_on_failure(tmp_path):
    target = tmp_path / "x.h5"
    with pytest.raises(RuntimeError):
        with atomic_h5(target) as h5:
            h5["a"] = np.arange(3)
            raise RuntimeError("simulated crash while writing")
    assert list(tmp_path.iterdir()) == []


def test_open_rejects_foreign_files(tmp_path):
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as h5:
        h5["x"] = 1
    with pytest.raises(StoreError, match="not a wavebrdf dataset") as refused:
        wavebrdf.open(other)
    assert "damaged" not in str(refused.value)  # a foreign file is not a damaged dataset
    with pytest.raises(StoreError, match="does not exist"):
        wavebrdf.open(tmp_path / "missing.h5")
