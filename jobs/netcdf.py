"""CF-style metadata of wavebrdf datasets (schema v3), written by jobs/store.py.

Every variable and coordinate gets ``long_name``; numeric ones get ``units`` (UDUNITS spelling:
"um", "degree", "s", "1" for dimensionless numbers; strings carry none). Names that end in a unit
suffix (``_um``, ``_deg``, ``_s``, ``_mb``, ``_gb``, ``_rad``) get that unit — swept config keys
and task-table columns alike — and other numbers are dimensionless ("1"). The groups' arrays get
named dimensions (HDF5 dimension scales), so netCDF-4 readers (netCDF4, ``ncdump``, xarray's
h5netcdf engine at its strictest) see no ``phony_dim_*``.
"""

from __future__ import annotations

import h5py
import numpy as np

__all__ = [
    "CF_CONVENTIONS",
    "attach_scales",
    "coordinate",
    "describe_task_table",
    "history_line",
    "sweep_coordinate_attrs",
    "units_from_name",
]

CF_CONVENTIONS = "CF-1.8"
UNIT_SUFFIXES = (("_um", "um"), ("_deg", "degree"), ("_s", "s"), ("_mb", "MiB"), ("_gb", "GiB"), ("_rad", "rad"))
TASK_COLUMNS = {  # long names of the task table's common columns (others: the name with spaces)
    "id": "task id",
    "kind": "task kind (jobs/tasks.py KINDS)",
    "case": "flat sweep-case index (C order of the sweep axes)",
    "wavelength_index": "index along wavelength_um",
    "incidence_index": "index along incidence",
    "theta_index": "index along theta_i",
    "basic_index": "index of the simulated basic direction (steering)",
    "patch": "steering patch a x b",
    "status": "done or failed",
    "model": "model that ran the task",
    "wall_time_s": "wall-clock time of the task",
    "peak_memory_mb": "peak resident memory of the worker",
    "device": "OpenCL device",
    "warnings": "warnings raised by the task",
    "error": "why the task failed",
}


def units_from_name(name: str, dtype) -> str | None:
    """The unit of a numeric quantity named ``name`` (by its suffix; "1" without one); None for strings."""
    if np.dtype(dtype).kind not in "biuf":
        return None
    return next((unit for suffix, unit in UNIT_SUFFIXES if name.endswith(suffix)), "1")


def _with_units(attrs: dict, name: str, dtype) -> dict:
    unit = units_from_name(name, dtype)
    return {**attrs, "units": unit} if unit is not None else attrs


def sweep_coordinate_attrs(key: str, values) -> dict:
    """``long_name`` and ``units`` of the coordinate of swept config key ``key`` ("section.key")."""
    section, _, name = key.partition(".")
    return _with_units({"long_name": f"[{section}] {name} (swept config value)"}, name, np.asarray(values).dtype)


def history_line(created: str, software_version: str, source: str) -> str:
    """CF ``history``: one line "<UTC time> wavebrdf <version>: <what was done>"."""
    return f"{created} wavebrdf {software_version}: {source}"


def coordinate(group: h5py.Group, name: str, values, attrs: dict) -> h5py.Dataset:
    """A 1-D coordinate ``name`` in ``group``: numbers, or strings (variable-length UTF-8), made a
    dimension scale of that name."""
    values = np.asarray(values)
    if values.dtype.kind in "UO":
        ds = group.create_dataset(name, data=np.array(values, dtype=object), dtype=h5py.string_dtype())
    else:
        ds = group.create_dataset(name, data=values)
    ds.make_scale(name)
    ds.attrs.update(attrs)
    return ds


def attach_scales(var: h5py.Dataset, axes: list[tuple[str, np.ndarray, dict]]) -> None:
    """Give each axis of ``var`` a named dimension: (name, values, attrs) creates the coordinate
    ``name`` beside ``var`` (in its group) unless it exists, and attaches it."""
    group = var.parent
    for axis, (name, values, attrs) in enumerate(axes):
        if name not in group:
            coordinate(group, name, values, attrs)
        var.dims[axis].attach_scale(group[name])


def describe_task_table(group: h5py.Group) -> None:
    """The task table's dimension ``task`` (row number) and each column's long name and units."""
    columns = [name for name in group if name != "task"]
    if not columns:
        return
    rows = group[columns[0]].shape[0]
    for name in columns:
        column = group[name]
        column.attrs.update(_with_units({"long_name": TASK_COLUMNS.get(name, name.replace("_", " "))}, name,
                                        column.dtype))
        attach_scales(column, [("task", np.arange(rows), {"long_name": "row of the task table", "units": "1"})])
