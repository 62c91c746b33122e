"""Reads wavebrdf datasets with plain xarray (no wavebrdf import): run by tests/test_conventions.py
under .venv/xarray-min (xarray and h5netcdf at the minimum versions pyproject allows).

Input (argv[1]): JSON list of {"path", "kind", "theta_i", "sweep_key", "sweep_index"}. For each
dataset: open the root and every group with engine="h5netcdf" at its default strictness (a
dimension without a name is an error there), select by θ_i and by the swept value, and compare
with the same slice read by h5py. Prints one JSON line: {"xarray": version, "h5netcdf": version,
"checked": [...], "groups": {...}}; exits non-zero on the first failure.
"""

from __future__ import annotations

import json
import sys

import h5netcdf
import h5py
import numpy as np
import xarray as xr


def groups(path: str) -> list[str]:
    found = []
    with h5py.File(path, "r") as h5:
        h5.visititems(lambda name, obj: found.append(name) if isinstance(obj, h5py.Group) else None)
    return found


def check(item: dict) -> dict:
    path, kind, theta = item["path"], item["kind"], item["theta_i"]
    key, index = item["sweep_key"], item["sweep_index"]
    opened = {}
    for group in [None, *groups(path)]:
        ds = xr.open_dataset(path, engine="h5netcdf", group=group)
        opened[group or "/"] = sorted(ds.sizes)
        ds.close()
    ds = xr.open_dataset(path, engine="h5netcdf")
    main = "bcsdf" if kind == "fiber" else "brdf"
    with h5py.File(path, "r") as h5:
        thetas = h5["theta_i"][()]
        raw = h5[main][()]
        sweep_values = h5[key][()]
    value = sweep_values[index]
    value = value.decode() if isinstance(value, bytes) else value.item()
    k = int(np.flatnonzero(thetas == theta)[0])
    by_sweep = ds[main].sel({key: value}).values
    assert np.array_equal(by_sweep, raw[index], equal_nan=True), "selection by the swept value"
    if kind == "fiber":
        by_theta = ds[main].sel(theta_i=theta).values
    else:
        by_theta = ds.set_index(incidence=["theta_i", "phi_i"])[main].sel(theta_i=theta).values
    expected = np.take(raw, np.flatnonzero(thetas == theta), axis=2)  # sweep, wavelength, incidence/theta_i, ...
    if kind == "fiber" or len(np.flatnonzero(thetas == theta)) == 1:
        expected = expected[:, :, 0]
        by_theta = by_theta.reshape(expected.shape)
    assert np.array_equal(by_theta, expected, equal_nan=True), f"selection by theta_i = {theta} (index {k})"
    ds.close()
    return {"path": path, "groups": opened}


def main() -> int:
    items = json.loads(sys.argv[1])
    checked = [check(item) for item in items]
    print(json.dumps({"xarray": xr.__version__, "h5netcdf": h5netcdf.__version__, "checked": checked}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
