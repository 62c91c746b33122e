"""HDF5 dataset schema v3: writer (atomic), reader (:func:`open_dataset`, ``wavebrdf.open``).

Two layouts, told apart by the root attribute ``kind``: "surface" (BRDFs of height fields,
below) and "fiber" (BCSDF tables: ``bcsdf``, ``dCs_dphi``, ``C_ext``/``C_sca``/``C_abs`` over
wavelength, θ_i, polarization, φ_i, φ_r; see docs/dataset.md). Surface layout (every coordinate
is a 1-D dataset registered as an HDF5 dimension scale, so
``xarray.open_dataset(path, engine="h5netcdf")`` reads it with no custom code)::

    /                         attrs: format="wavebrdf", format_version=3, software_version,
                              config (TOML text), created (UTC ISO 8601), device, study, conventions,
                              Conventions="CF-1.8", history (CF-style: every variable and
                              coordinate has long_name, numeric ones units; see jobs/netcdf.py)
    <sweep key>               one coordinate per swept config key, e.g. "surface.rms_height_um"
    wavelength_um             vacuum wavelengths (µm)
    incidence                 0..n-1; with coordinates theta_i, phi_i (degrees) along it
    polarization              "s", "p"
    u, v                      projected-hemisphere pixel centres (direction cosines x, y)
    brdf       [sweep..., wavelength_um, incidence, u, v]  float32, 1/sr, NaN outside the disk,
                              for the configured polarization (attribute "polarization")
    albedo     [sweep..., wavelength_um, incidence]        Σ brdf Δu Δv
    albedo_sp  [sweep..., wavelength_um, incidence, polarization]
    brdf_sp    [sweep..., wavelength_um, incidence, polarization, u, v]  (output.per_polarization)
    jones      [sweep..., wavelength_um, incidence, polarization_out, polarization, u, v, complex]
                              float32, 1/sr^0.5 ([output] polarization = "jones"; solver/polarimetry.py)
    mueller    [sweep..., wavelength_um, incidence, stokes_out, stokes_in, u, v]  float32, 1/sr
                              ([output] polarization = "mueller")
    ior_n, ior_kappa [sweep..., wavelength_um]          material index n − jκ
    surface/height_<case>     height matrix (µm) of each sweep case [x_<case>, y_<case>] (node
                              positions, µm, dimension scales in surface/); attrs size_um, spacing_um, stats
    tasks/                    one row per task [task]: case, wavelength/incidence index, model, status,
                              wall_time_s, peak_memory_mb, device, message (diagnostics)

Version 2 added the CF-style attributes and the dimension scales of the groups (no
``phony_dim_*``); version 3 (this writer) names the per-case variables of the groups with a letter
first, as CF asks (``surface/height_<case>``, ``fiber/polygon_<case>``; ``surface/<case>``,
``fiber/<case>`` before). Readers accept versions 1 to 3 (``READ_VERSIONS``; :meth:`Dataset.case_variable`
finds either name).

Writing is atomic: the file is assembled under a temporary name in the target folder (with the
mode any new file gets from the umask) and renamed into place only when complete, so a crash
never leaves a half-written dataset, and a write that fails (disk full, I/O error, file too large)
leaves the previous file as it was and raises a one-line
:class:`~wavebrdf.jobs.parts.StorageError` naming the path. Reading (:class:`Dataset`) checks
the format, its version and the variables of its layout before anything is read. This
module owns every HDF5 write: :func:`write_dataset` assembles a run's dataset (surface or fiber
layout) from its parts folder, each task's slot written by its kind (jobs/tasks.py ``KINDS``),
and :func:`write_comparison` the file of ``wavebrdf compare`` (read back by :func:`read_comparison`).
"""

from __future__ import annotations

import io
import json
import os
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path
from typing import NamedTuple

import h5py
import numpy as np

from wavebrdf._version import __version__
from wavebrdf.jobs.input_files import input_file_problem
from wavebrdf.jobs.netcdf import (CF_CONVENTIONS, attach_scales, coordinate, describe_task_table, history_line,
                                  sweep_coordinate_attrs, units_from_name)
from wavebrdf.jobs.parts import StorageError, fsync_folder, storage_error, temporary_path
from wavebrdf.solver import polarimetry as polarimetry_module

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "Dataset",
    "FiberDatasetWriter",
    "LAYOUTS",
    "StoreError",
    "SurfaceDatasetWriter",
    "atomic_h5",
    "not_a_dataset",
    "open_dataset",
    "read_comparison",
    "write_comparison",
    "write_dataset",
    "is_comparison",
]

FORMAT = "wavebrdf"
FORMAT_VERSION = 3
READ_VERSIONS = (1, 2, 3)  # v2 = v1 + CF attributes, group dimensions; v3 = v2 with letter-first case variables
CONVENTIONS = (
    "lengths in micrometres; vacuum wavelength; time dependence exp(+j omega t); index n - j kappa; "
    "theta_i/phi_i in degrees toward the light; u (rows) = x direction cosine, v (columns) = y; "
    "BRDF f = |0.5 Re(E x H*)| / (Phi_i cos theta_o) in 1/sr; unpolarized = mean of s and p"
)
STRING = h5py.string_dtype()


class StoreError(RuntimeError):
    """The file is not a readable wavebrdf dataset."""


def not_a_dataset(path: Path) -> str | None:
    """Why the existing file ``path`` is not a wavebrdf dataset ("is not an HDF5 file", "is an
    HDF5 file without wavebrdf's format attribute", ...); None for a dataset wavebrdf wrote (any
    format version, readable or damaged: its ``format`` attribute says so)."""
    path = Path(path)
    if path.is_dir():
        return "is a folder"
    if not path.is_file():
        return "is not a regular file"
    try:
        if path.stat().st_size == 0:
            return "is an empty file"
        if not h5py.is_hdf5(path):
            return "is not an HDF5 file"
        with h5py.File(path, "r") as h5:
            found = h5.attrs.get("format")
    except (OSError, ValueError, KeyError) as exc:
        return f"cannot be read as HDF5 ({type(exc).__name__}: {' '.join(str(exc).split())[:80]})"
    found = found.decode() if isinstance(found, bytes) else found
    if found != FORMAT:
        shown = "" if found is None else f" (format = {found!r})"
        return f"is an HDF5 file without wavebrdf's format attribute{shown}"
    return None


class Layout(NamedTuple):
    """The variables a dataset of one kind (root attribute ``kind``) must hold: the main variable,
    its trailing dimensions and their letters, {other variable: its dimensions as letters, "*" =
    the sweep dimensions, a digit = that size} (polarization holds strings, the rest numbers); the
    coordinates a reader lists after the sweep keys, the xarray index ``to_xarray`` sets, and the
    per-case variable (group, name prefix): ``<group>/<prefix>_<flat case index>``."""

    main: str
    trailing: tuple[str, ...]
    letters: str
    others: dict
    coordinates: tuple[str, ...]
    xarray_index: dict
    per_case: tuple[str, str]

    def case_variable(self, case) -> str:
        """The path of case ``case``'s variable (format version 3)."""
        group, prefix = self.per_case
        return f"{group}/{prefix}_{case}"


LAYOUTS = {
    "surface": Layout("brdf", ("wavelength_um", "incidence", "u", "v"), "LIUV",
                      {"albedo": "*LI", "albedo_sp": "*LI2", "theta_i": "I", "phi_i": "I", "polarization": "2"},
                      ("wavelength_um", "incidence", "theta_i", "phi_i", "polarization", "u", "v"),
                      {"incidence": ["theta_i", "phi_i"]}, ("surface", "height")),
    "fiber": Layout("bcsdf", ("wavelength_um", "theta_i", "phi_i", "phi_r"), "LTPR",
                    {"dCs_dphi": "*LT2PR", "C_ext": "*LT2P", "C_sca": "*LT2P", "C_abs": "*LT2P", "polarization": "2"},
                    ("wavelength_um", "theta_i", "phi_i", "phi_r", "polarization"), {}, ("fiber", "polygon")),
}


class _GuardedFile(io.RawIOBase):
    """The file HDF5 writes through (h5py's file-object driver; unbuffered ``pwrite``/``pread``).

    The first failed write (disk full, I/O error, file too large) is recorded; that write and
    every later one are kept in memory instead (``shadow``) and reads see them, so the HDF5
    library finishes and closes the doomed file consistently, without the error cascade that
    crashed it after a failed write. :func:`atomic_h5` then raises the recorded error and removes
    the file; :func:`write_dataset` stops writing data as soon as ``error`` is set, so the shadow
    holds little more than the closing metadata."""

    def __init__(self, fd: int):
        super().__init__()
        self.fd = fd
        self.pos = 0
        self.error: OSError | None = None
        self.shadow: list[tuple[int, bytes]] = []  # (offset, data) written after the failure

    def readable(self) -> bool:
        return True

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def _size(self) -> int:
        return max([os.fstat(self.fd).st_size] + [offset + len(data) for offset, data in self.shadow])

    def seek(self, offset: int, whence: int = 0) -> int:
        if whence == 1:
            offset += self.pos
        elif whence == 2:
            offset += self._size()
        self.pos = offset
        return self.pos

    def tell(self) -> int:
        return self.pos

    def readinto(self, buffer) -> int:
        """Bytes at the position (zeros past the end), the shadowed writes laid over them."""
        view = memoryview(buffer).cast("B")
        data = os.pread(self.fd, len(view), self.pos)
        view[: len(data)] = data
        view[len(data):] = bytes(len(view) - len(data))
        for offset, written in self.shadow:
            lo, hi = max(offset, self.pos), min(offset + len(written), self.pos + len(view))
            if lo < hi:
                view[lo - self.pos: hi - self.pos] = written[lo - offset: hi - offset]
        self.pos += len(view)
        return len(view)

    def write(self, data) -> int:
        view = memoryview(data).cast("B")
        if self.error is None:
            try:
                done = 0
                while done < len(view):
                    done += os.pwrite(self.fd, view[done:], self.pos + done)
            except OSError as exc:
                self.error = exc
        if self.error is not None:
            self.shadow.append((self.pos, bytes(view)))
        self.pos += len(view)
        return len(view)

    def truncate(self, size: int | None = None) -> int:
        size = self.pos if size is None else size
        if self.error is None:
            try:
                os.ftruncate(self.fd, size)
            except OSError as exc:
                self.error = exc
        return size

    def sync(self) -> None:
        """fsync (a failure is recorded like a failed write)."""
        if self.error is None:
            try:
                os.fsync(self.fd)
            except OSError as exc:
                self.error = exc

    def close(self) -> None:
        if not self.closed:
            super().close()
            os.close(self.fd)


@contextmanager
def _guarded_h5(path: Path):
    """(h5py file, its :class:`_GuardedFile`) written atomically (see :func:`atomic_h5`)."""
    path = Path(path)
    tmp = temporary_path(path)
    try:
        fd = os.open(tmp, os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o666)  # mode from the umask
    except OSError as exc:
        raise storage_error(path, exc) from None
    guard = _GuardedFile(fd)
    try:
        with h5py.File(guard, "w", track_order=True) as h5:
            yield h5, guard
        guard.sync()
        guard.close()
        if guard.error is not None:
            raise guard.error
        os.replace(tmp, path)
        fsync_folder(path.parent)
    except BaseException as exc:
        guard.close()
        try:
            os.remove(tmp)
        except OSError:
            pass
        if guard.error is not None or isinstance(exc, OSError):
            raise storage_error(path, guard.error or exc) from None
        raise


@contextmanager
def atomic_h5(path: Path):
    """An HDF5 file written atomically: assembled under ``.<name>.<pid>.<thread>.tmp`` next to
    ``path`` and renamed to ``path`` when complete. On failure the temporary file is removed and
    ``path`` is left as it was; a failed write raises :class:`~wavebrdf.jobs.parts.StorageError`
    naming ``path``. The folder must exist (nothing is created but the file)."""
    with _guarded_h5(path) as (h5, _):
        yield h5


COMPARISON_FORMAT = 1  # ``wavebrdf_compare`` attribute of a comparison file


def write_comparison(path: Path, columns, rows: list[dict], brdfs: list[tuple[str, str, np.ndarray, dict]],
                     grid_resolution: int, text_columns=()) -> None:
    """A comparison's file, atomically: ``table/<column>`` (one entry per row: strings in the
    ``text_columns``, elsewhere floats where every value is a number or missing — a failed row's
    NaN —, else strings) and ``brdf/<i>`` per (scene, model, BRDF (2, n, n) in 1/sr s/p,
    diagnostics) stored as float32 with the scene, model and diagnostics (JSON) as attributes."""
    with atomic_h5(path) as h5:
        h5.attrs["wavebrdf_compare"] = COMPARISON_FORMAT
        table = h5.create_group("table")
        for key in columns:
            values = [r.get(key) for r in rows]
            if key not in text_columns and all(v is None or isinstance(v, (int, float)) for v in values):
                table.create_dataset(key, data=np.array([np.nan if v is None else v for v in values], dtype=float))
            else:
                table.create_dataset(key, data=np.array(["" if v is None else str(v) for v in values], dtype=STRING))
        group = h5.create_group("brdf")
        group.attrs["grid_resolution"] = grid_resolution
        for i, (scene, model, brdf, diagnostics) in enumerate(brdfs):
            ds = group.create_dataset(f"{i:04d}", data=np.asarray(brdf, dtype=np.float32), compression="gzip")
            ds.attrs.update({"model": model, "scene": scene, "diagnostics": json.dumps(diagnostics, default=repr)})


def is_comparison(path: Path) -> bool:
    """Whether ``path`` is a file of ``wavebrdf compare`` (:func:`write_comparison`); False for
    anything else, a study's dataset or no HDF5 file at all included."""
    try:
        with h5py.File(path, "r") as h5:
            return "wavebrdf_compare" in h5.attrs
    except OSError:
        return False


def read_comparison(path: Path) -> tuple[dict[str, list], dict[tuple[str, str], np.ndarray]]:
    """(the table, column → values; (scene, model) → BRDF (2, n, n) in 1/sr) of a file written by
    :func:`write_comparison`."""
    path = Path(path)
    try:
        h5 = h5py.File(path, "r")
    except OSError as exc:
        raise StoreError(f"{path}: cannot be read as a comparison file ({exc})") from None
    with h5:
        if "wavebrdf_compare" not in h5.attrs:
            raise StoreError(f"{path}: not a comparison file (no 'wavebrdf_compare' attribute)")
        table = {k: [v.decode() if isinstance(v, bytes) else v for v in h5["table"][k][()]] for k in h5["table"]}
        brdfs = {(ds.attrs["scene"], ds.attrs["model"]): ds[()].astype(float) for ds in h5["brdf"].values()}
    return table, brdfs


def _coordinate(h5: h5py.File, name: str, values, attrs: dict | None = None) -> h5py.Dataset:
    return coordinate(h5, name, values, attrs or {})


def _attach(var: h5py.Dataset, dims: list[str], h5: h5py.File) -> None:
    for axis, dim in enumerate(dims):
        var.dims[axis].attach_scale(h5[dim])


class _Writer:
    """What every layout shares: root attributes, sweep and wavelength coordinates, the material
    index per case, the task table. Subclasses add their own coordinates and variables."""

    kind = ""

    def __init__(self, h5: h5py.File, sweep_axes: dict, wavelengths_um: np.ndarray):
        self.h5 = h5
        self.sweep_axes = sweep_axes  # {"section.key": values}
        self.wavelengths_um = np.asarray(wavelengths_um, dtype=float)

    @property
    def sweep(self) -> list[str]:
        return list(self.sweep_axes)

    @property
    def lead(self) -> list[int]:
        return [len(v) for v in self.sweep_axes.values()]

    def create(self, *, config_text: str, study: str, software_version: str, device: str,
               source: str = "wavebrdf run") -> None:
        """Root attributes (``source``: what made the file, for CF ``history``), coordinates, layout."""
        h5 = self.h5
        created = datetime.now(timezone.utc).isoformat(timespec="seconds")
        h5.attrs.update(
            {
                "format": FORMAT,
                "format_version": FORMAT_VERSION,
                "kind": self.kind,
                "software_version": software_version,
                "config": config_text,
                "created": created,
                "device": device,
                "study": study,
                "conventions": CONVENTIONS,
                "Conventions": CF_CONVENTIONS,
                "history": history_line(created, software_version, source),
            }
        )
        for key, values in self.sweep_axes.items():
            _coordinate(h5, key, list(values), sweep_coordinate_attrs(key, list(values)))
        _coordinate(h5, "wavelength_um", self.wavelengths_um, {"units": "um", "long_name": "vacuum wavelength"})
        self.create_layout()
        for name, long_name in (("ior_n", "real part n of the index n - j kappa"),
                                ("ior_kappa", "extinction coefficient kappa (>= 0 is loss)")):
            self._variable(name, self.sweep + ["wavelength_um"], self.lead + [len(self.wavelengths_um)], np.float64,
                           {"long_name": long_name, "units": "1"})

    def create_layout(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def write_index(self, case_index: tuple[int, ...], index: np.ndarray) -> None:
        self.h5["ior_n"][tuple(case_index)] = np.real(index)
        self.h5["ior_kappa"][tuple(case_index)] = -np.imag(index)

    def _variable(self, name, dims, shape, dtype, attrs, chunks=None):
        fill = np.nan
        kwargs = {"chunks": chunks, "compression": "gzip", "compression_opts": 4, "shuffle": True} if chunks else {}
        ds = self.h5.create_dataset(name, shape=tuple(shape), dtype=dtype, fillvalue=fill, **kwargs)
        ds.attrs.update({"_FillValue": np.array(fill, dtype=dtype), "long_name": name.replace("_", " "),
                         "units": units_from_name(name, dtype), **attrs})  # CF: NaN = not computed
        _attach(ds, dims, self.h5)
        return ds

    def write_tasks(self, rows: list[dict]) -> None:
        """The task table (diagnostics + completion status), one entry per task.

        Numeric columns become int64/float64 (NaN where a row lacks the value), others strings.
        """
        grp = self.h5.create_group("tasks")
        keys = list(dict.fromkeys(k for r in rows for k in r))
        for key in keys:
            values = [r.get(key) for r in rows]
            present = [v for v in values if v is not None and v != ""]
            numeric = present and all(isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
                                      for v in present)
            if numeric and len(present) == len(values) and all(isinstance(v, (int, np.integer)) for v in present):
                grp.create_dataset(key, data=np.asarray(values, dtype=np.int64))
            elif numeric:
                grp.create_dataset(key, data=np.array([np.nan if v in (None, "") else v for v in values], dtype=float))
            else:
                data = ["" if v is None else v if isinstance(v, str) else json.dumps(v) for v in values]
                grp.create_dataset(key, data=np.array(data, dtype=object), dtype=STRING)
        describe_task_table(grp)


class SurfaceDatasetWriter(_Writer):
    """BRDF layout: brdf[sweep..., wavelength_um, incidence, u, v] and friends."""

    kind = "surface"

    def __init__(self, h5, sweep_axes, wavelengths_um, directions_deg, resolution: int, polarization: str,
                 per_polarization: bool, polarimetry: str = "intensity"):
        super().__init__(h5, sweep_axes, wavelengths_um)
        self.directions_deg = np.asarray(directions_deg, dtype=float)  # (n, 2): theta, phi
        self.resolution = resolution
        self.polarization = polarization
        self.per_polarization = per_polarization
        if polarimetry not in polarimetry_module.POLARIMETRY:
            raise ValueError(f"polarimetry must be one of {polarimetry_module.POLARIMETRY}, got {polarimetry!r}")
        self.polarimetry = polarimetry  # [output] polarization: what is stored beyond intensities

    def create_layout(self) -> None:
        h5 = self.h5
        n_inc = len(self.directions_deg)
        _coordinate(h5, "incidence", np.arange(n_inc), {"long_name": "incident direction index", "units": "1"})
        _coordinate(h5, "polarization", np.array(["s", "p"], dtype=object),
                    {"long_name": "polarization of the incident field (s: E perpendicular to the plane of incidence)"})
        u = 2.0 * (np.arange(self.resolution) + 0.5) / self.resolution - 1.0
        _coordinate(h5, "u", u, {"long_name": "x direction cosine of the outgoing direction", "units": "1"})
        _coordinate(h5, "v", u, {"long_name": "y direction cosine of the outgoing direction", "units": "1"})
        for name, column, long_name in (("theta_i", 0, "incident polar angle"), ("phi_i", 1, "incident azimuth")):
            ds = h5.create_dataset(name, data=self.directions_deg[:, column])
            ds.attrs.update({"units": "degree", "long_name": f"{long_name} (toward the light)"})
            _attach(ds, ["incidence"], h5)
        sweep, lead = self.sweep, self.lead
        n_wl = len(self.wavelengths_um)
        res = self.resolution
        coords = "theta_i phi_i"
        self._variable(
            "brdf", sweep + ["wavelength_um", "incidence", "u", "v"], lead + [n_wl, n_inc, res, res],
            np.float32, {"units": "1/sr", "polarization": self.polarization, "coordinates": coords,
                         "long_name": f"BRDF ({self.polarization}), NaN outside the unit disk"},
            chunks=tuple([1] * (len(lead) + 2) + [res, res]),
        )
        self._variable(
            "albedo", sweep + ["wavelength_um", "incidence"], lead + [n_wl, n_inc], np.float64,
            {"units": "1", "polarization": self.polarization, "coordinates": coords,
             "long_name": "sum of brdf * pixel area over the unit disk"},
        )
        self._variable(
            "albedo_sp", sweep + ["wavelength_um", "incidence", "polarization"], lead + [n_wl, n_inc, 2],
            np.float64, {"units": "1", "coordinates": coords, "long_name": "albedo of each polarization"},
        )
        if self.per_polarization:
            self._variable(
                "brdf_sp", sweep + ["wavelength_um", "incidence", "polarization", "u", "v"],
                lead + [n_wl, n_inc, 2, res, res], np.float32, {"units": "1/sr", "coordinates": coords,
                                                                "long_name": "BRDF of each polarization"},
                chunks=tuple([1] * (len(lead) + 3) + [res, res]),
            )
        if self.polarimetry != "intensity":
            self._polarimetry_layout(coords)
        h5.create_group("surface")

    def _polarimetry_layout(self, coords: str) -> None:
        """``jones`` or ``mueller`` per pixel, in the s/p frames of solver/polarimetry.py."""
        h5, sweep, lead, res = self.h5, self.sweep, self.lead, self.resolution
        n_wl, n_inc = len(self.wavelengths_um), len(self.directions_deg)
        frames = ("s/p frames of solver/polarimetry.py and docs/dataset.md: s = (-sin phi, cos phi, 0) of each "
                  "direction, p = k x s (k the propagation direction)")
        if self.polarimetry == "jones":
            _coordinate(h5, "polarization_out", np.array(["s", "p"], dtype=object),
                        {"long_name": "polarization of the scattered field (s: E perpendicular to the plane of exitance)"})
            _coordinate(h5, "complex", np.array(["real", "imaginary"], dtype=object),
                        {"long_name": "part of the complex amplitude"})
            self._variable(
                "jones", sweep + ["wavelength_um", "incidence", "polarization_out", "polarization", "u", "v", "complex"],
                lead + [n_wl, n_inc, 2, 2, res, res, 2], np.float32,
                {"units": "sr-0.5", "coordinates": coords, "frames": frames,
                 "long_name": "Jones matrix J[out, in]: sum over out of |J|^2 is the BRDF of polarization in"},
                chunks=tuple([1] * (len(lead) + 2) + [2, 2, res, res, 2]))
            return
        _coordinate(h5, "stokes_out", np.array(polarimetry_module.STOKES, dtype=object), {"long_name": "Stokes component of the scattered light"})
        _coordinate(h5, "stokes_in", np.array(polarimetry_module.STOKES, dtype=object), {"long_name": "Stokes component of the incident light"})
        self._variable(
            "mueller", sweep + ["wavelength_um", "incidence", "stokes_out", "stokes_in", "u", "v"],
            lead + [n_wl, n_inc, 4, 4, res, res], np.float32,
            {"units": "1/sr", "coordinates": coords, "frames": frames,
             "stokes": "S = (|E_s|^2 + |E_p|^2, |E_s|^2 - |E_p|^2, 2 Re(E_s E_p*), -2 Im(E_s E_p*)), e^{+j omega t}",
             "long_name": "Mueller matrix M[out, in]; M[0, 0] is the unpolarized BRDF"},
            chunks=tuple([1] * (len(lead) + 2) + [4, 4, res, res]))

    def write_case(self, case_index: tuple[int, ...], case_id: str, heights: np.ndarray, size_um: float,
                   stats: dict, index: np.ndarray, parameters: dict | None = None, ensemble=None) -> None:
        """Per-case data: surface heights with their measured statistics, the generator's
        parameters (``generator``, ``generator_<key>``) and ensemble (``ensemble_<key>``) when it
        has them, and the material index at every wavelength."""
        ds = self.h5.create_dataset(LAYOUTS["surface"].case_variable(case_id), data=heights, compression="gzip",
                                    shuffle=True)
        spacing = size_um / (heights.shape[0] - 1)
        ds.attrs.update({"size_um": size_um, "spacing_um": spacing, "units": "um", "long_name": "surface height",
                         "case_index": list(case_index), **stats})
        attach_scales(ds, [(f"{axis}_{case_id}", spacing * np.arange(n), {
            "units": "um", "long_name": f"{axis} of the height nodes of case {case_id}"})
            for axis, n in zip("xy", heights.shape)])
        if parameters:
            ds.attrs.update({k if k == "generator" else f"generator_{k}": v for k, v in parameters.items()})
        if ensemble is not None:
            ds.attrs.update(ensemble.attributes())
        self.write_index(case_index, index)

    def write_steering(self, case_index: tuple[int, ...], steering) -> None:
        """Basic direction of every requested direction (degrees) and the patch layout."""
        sweep = list(self.sweep_axes)
        if "theta_basic" not in self.h5:
            lead = [len(v) for v in self.sweep_axes.values()]
            n_inc = len(self.directions_deg)
            for name, long_name in (("theta_basic", "polar angle"), ("phi_basic", "azimuth")):
                self._variable(name, sweep + ["incidence"], lead + [n_inc], np.float64,
                               {"units": "degree", "long_name": f"{long_name} of the simulated basic direction"})
            layout = steering.layout
            self.h5.attrs.update({"steering_patches": list(layout.counts),
                                  "steering_patch_size_um": layout.patch_size_um,
                                  "steering_shift_um": layout.shift_um,
                                  "steering_hexagon_radius": steering.tiling.radius})
        basics = np.rad2deg(steering.basics_rad[steering.basic_of])
        self.h5["theta_basic"][tuple(case_index)] = basics[:, 0]
        self.h5["phi_basic"][tuple(case_index)] = basics[:, 1]

    def write_result(self, case_index: tuple[int, ...], wl: int, inc: int, brdf_sp: np.ndarray,
                     brdf: np.ndarray, albedo_sp: np.ndarray, albedo: float, jones: np.ndarray | None = None) -> None:
        """One task's slices; ``jones`` (2, 2, res, res) complex where the study stores polarimetry."""
        where = tuple(case_index) + (wl, inc)
        self.h5["brdf"][where] = brdf.astype(np.float32)
        self.h5["albedo"][where] = albedo
        self.h5["albedo_sp"][where] = albedo_sp
        if self.per_polarization:
            self.h5["brdf_sp"][where] = brdf_sp.astype(np.float32)
        if self.polarimetry == "intensity":
            return
        if jones is None:
            raise ValueError(f"[output] polarization = \"{self.polarimetry}\": the task at {where} carries no Jones "
                             "matrix (its model returned intensities only)")
        outside = ~np.isfinite(brdf)
        if self.polarimetry == "jones":
            pair = np.stack([jones.real, jones.imag], axis=-1).astype(np.float32)
            pair[:, :, outside] = np.nan
            self.h5["jones"][where] = pair
        else:
            matrix = polarimetry_module.mueller(jones).astype(np.float32)
            matrix[:, :, outside] = np.nan
            self.h5["mueller"][where] = matrix



class FiberDatasetWriter(_Writer):
    """BCSDF layout of fiber studies (see docs/dataset.md, "Fiber datasets")."""

    kind = "fiber"

    def __init__(self, h5, sweep_axes, wavelengths_um, theta_i_deg, phi_i_deg, phi_r_deg, phi_i_binned: bool):
        super().__init__(h5, sweep_axes, wavelengths_um)
        self.theta_i_deg = np.asarray(theta_i_deg, dtype=float)
        self.phi_i_deg = np.asarray(phi_i_deg, dtype=float)
        self.phi_r_deg = np.asarray(phi_r_deg, dtype=float)
        self.phi_i_binned = phi_i_binned

    def create_layout(self) -> None:
        h5 = self.h5
        _coordinate(h5, "theta_i", self.theta_i_deg,
                    {"units": "degree", "long_name": "incident angle from the plane normal to the fiber axis"})
        _coordinate(h5, "phi_i", self.phi_i_deg, {
            "units": "degree", "long_name": "incident azimuth around the axis",
            "sampling": f"bin centres, bins of {360 / len(self.phi_i_deg):g} degrees (box averages)"
            if self.phi_i_binned else "point samples"})
        _coordinate(h5, "phi_r", self.phi_r_deg, {
            "units": "degree", "long_name": "outgoing azimuth around the axis",
            "sampling": f"bin centres, bins of {360 / len(self.phi_r_deg):g} degrees (box averages)"})
        _coordinate(h5, "polarization", np.array(["parallel", "perpendicular"], dtype=object),
                    {"long_name": "parallel: incident E in the plane of the axis and the incident direction "
                                  "(Bohren-Huffman case I); perpendicular: case II"})
        sweep, lead = self.sweep, self.lead
        L, T, P, R = len(self.wavelengths_um), len(self.theta_i_deg), len(self.phi_i_deg), len(self.phi_r_deg)
        base = sweep + ["wavelength_um", "theta_i"]
        self._variable("bcsdf", base + ["phi_i", "phi_r"], lead + [L, T, P, R], np.float32, {
            "units": "1/rad", "long_name": "azimuthal scattering function N_wave = (dC_s/dphi)/C_ext, unpolarized "
            "(the BCSDF is S = M0(theta_i, theta_r) * N_wave with d'Eon's longitudinal M0)"},
            chunks=tuple([1] * (len(lead) + 2) + [P, R]))
        self._variable("dCs_dphi", base + ["polarization", "phi_i", "phi_r"], lead + [L, T, 2, P, R], np.float32,
                       {"units": "um/rad", "long_name": "differential scattering width per unit length"},
                       chunks=tuple([1] * (len(lead) + 3) + [P, R]))
        for name, long_name in (("C_ext", "extinction"), ("C_sca", "scattering"), ("C_abs", "absorption")):
            self._variable(name, base + ["polarization", "phi_i"], lead + [L, T, 2, P], np.float64, {
                "units": "um", "long_name": f"{long_name} cross section per unit length, normalised by S0 cos(theta_i)"})
        self._variable("power_balance_error", base + ["polarization", "phi_i"], lead + [L, T, 2, P], np.float64,
                       {"long_name": "|C_ext - C_sca - C_abs| / C_ext"})
        self._variable("C_geom", sweep + ["phi_i"], lead + [P], np.float64,
                       {"units": "um", "long_name": "geometric width of the cross section seen from phi_i"})
        self._create_rendering_tables(base, [L, T, P, R])
        h5.create_group("fiber")

    def _create_rendering_tables(self, base: list[str], LTPR: list[int]) -> None:
        """C_e, the φ_r CDFs, the longitudinal variance and M0's θ_r CDF (docs/dataset.md)."""
        from wavebrdf.solver.fiber.evaluator import M0_CDF_EDGES_DEG

        sweep, lead = self.sweep, self.lead
        L, T, P, R = LTPR
        _coordinate(self.h5, "theta_r", M0_CDF_EDGES_DEG, {
            "units": "degree", "long_name": "outgoing angle from the plane normal to the fiber axis (CDF nodes)"})
        self._variable("C_eff", base + ["phi_i"], lead + [L, T, P], np.float64, {
            "units": "um", "long_name": "effective width C_e for renderers: unpolarized C_ext clamped to 6 C_geom"})
        self._variable("phi_r_cdf", base + ["phi_i", "phi_r"], lead + [L, T, P, R], np.float32, {
            "units": "1", "long_name": "CDF of bcsdf over the phi_r bins at each bin's upper edge "
            "(sampling table per wavelength, theta_i, phi_i)"}, chunks=tuple([1] * (len(lead) + 2) + [P, R]))
        self._variable("longitudinal_variance", sweep, lead, np.float64, {
            "units": "rad2", "long_name": "d'Eon's longitudinal variance v of M0 (default; renderers may override)"})
        self._variable("m0_cdf", sweep + ["theta_i", "theta_r"], lead + [T, len(M0_CDF_EDGES_DEG)], np.float64, {
            "units": "1", "long_name": "CDF over theta_r of M0(theta_i, theta_r; longitudinal_variance) cos(theta_r)"})

    def write_case(self, case_index: tuple[int, ...], case_id: str, nodes: np.ndarray, width: np.ndarray,
                   index: np.ndarray, longitudinal_variance: float = 0.02) -> None:
        ds = self.h5.create_dataset(LAYOUTS["fiber"].case_variable(case_id), data=nodes)
        ds.attrs.update({"units": "um", "long_name": "cross-section polygon nodes (x, y), counter-clockwise",
                         "case_index": list(case_index)})
        attach_scales(ds, [(f"node_{case_id}", np.arange(len(nodes)), {"units": "1", "long_name": "node index"}),
                           ("xy", np.array(["x", "y"]), {"long_name": "coordinate of the node"})])
        self.h5["C_geom"][tuple(case_index)] = width
        self.write_index(case_index, index)
        from wavebrdf.solver.fiber.bcsdf import longitudinal_cdf
        from wavebrdf.solver.fiber.evaluator import M0_CDF_EDGES_DEG

        self.h5["longitudinal_variance"][tuple(case_index)] = longitudinal_variance
        self.h5["m0_cdf"][tuple(case_index)] = longitudinal_cdf(np.deg2rad(self.theta_i_deg),
                                                                longitudinal_variance, np.deg2rad(M0_CDF_EDGES_DEG))

    def write_slice(self, case_index, wl: int, theta: int, *, dCs_dphi, C_ext, C_sca, C_abs) -> None:
        where = tuple(case_index) + (wl, theta)
        self.h5["dCs_dphi"][where] = dCs_dphi.astype(np.float32)
        self.h5["C_ext"][where], self.h5["C_sca"][where], self.h5["C_abs"][where] = C_ext, C_sca, C_abs
        from wavebrdf.solver.fiber.results import power_balance_error  # the fiber package imports scipy

        self.h5["power_balance_error"][where] = power_balance_error(C_ext, C_sca, C_abs)
        self.h5["bcsdf"][where] = (dCs_dphi.mean(axis=0) / C_ext.mean(axis=0)[:, None]).astype(np.float32)
        from wavebrdf.solver.fiber.bcsdf import effective_width
        from wavebrdf.solver.fiber.evaluator import azimuthal_cdf

        self.h5["C_eff"][where] = effective_width(C_ext.mean(axis=0), self.h5["C_geom"][tuple(case_index)])
        self.h5["phi_r_cdf"][where] = azimuthal_cdf(self.h5["bcsdf"][where]).astype(np.float32)


def write_dataset(plan, parts, device: str, run_info: dict | None = None) -> Path:
    """Assemble the HDF5 dataset of ``plan`` from its finished ``parts`` (one writer, atomic rename).

    Tasks without a finished part get ``status = "failed"`` and keep NaN in their slot.
    """
    from wavebrdf.jobs.tasks import KINDS

    output = Path(plan.config.output)
    kind = plan.study.kind  # the layout, the per-case data and the task rows of the study's kind
    with _guarded_h5(output) as (h5, guard):
        writer = kind.writer(h5, plan)
        source = f"wavebrdf run {plan.config.path or '(config given as a dict)'}"
        writer.create(config_text=plan.config.text, study=plan.study.name, software_version=__version__,
                      device=device, source=source)
        h5.attrs["fingerprint"] = plan.fingerprint  # a re-run of the same plan is "up to date" (jobs/finished.py)
        for case, case_index in plan.config.case_indices():
            kind.write_case(writer, plan, case, case_index)
        rows = []
        for task in plan.tasks:
            if guard.error is not None:  # the disk is full: stop; the file is removed
                break
            ran = (run_info or {}).get(task.id) or (parts.run_info(task) if parts.done(task) else {})
            row = {**kind.task_row(task), **ran}
            failure = parts.failure(task)
            if failure is not None or not parts.done(task):
                rows.append({**row, "status": "failed", **(failure or {"error": "not run"})})
                continue
            write = KINDS[task.kind].write
            diagnostics = parts.load_diagnostics(task) if write is None else write(writer, plan, task, parts)
            rows.append({**row, "status": "done", **diagnostics})
        if guard.error is None:
            writer.write_tasks(rows)
    return output


class Dataset:
    """Read access to a wavebrdf HDF5 dataset (``wavebrdf.open(path)``).

    Arrays are read on access: ``ds.brdf`` (numpy, float32), ``ds.albedo``, ``ds.coords``
    (dict of coordinate arrays), ``ds.config`` (TOML text), ``ds.tasks`` (task table dict).
    ``ds.to_xarray()`` returns the same file as an ``xarray.Dataset``.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        problem = input_file_problem(self.path)
        if problem is not None:
            raise StoreError(f"{str(self.path)!r} {problem}")
        try:
            self._h5 = h5py.File(self.path, "r")
        except OSError as exc:
            raise StoreError(f"{str(self.path)!r} is not a readable HDF5 file: {exc}") from None
        try:
            with self.reading():
                self._validate()
        except StoreError:
            self._h5.close()
            raise

    def _fail(self, problem: str) -> StoreError:
        return StoreError(f"{str(self.path)!r} {problem}")

    def _validate(self) -> None:
        """Format, version and the variables of the layout, before anything else is read."""
        attrs = self._h5.attrs
        if attrs.get("format") != FORMAT:
            if "wavebrdf_compare" in attrs:
                raise self._fail("is a file of `wavebrdf compare`, not a study's dataset: `wavebrdf inspect` prints "
                                 "its table (wavebrdf.jobs.store.read_comparison reads its BRDFs)")
            raise self._fail("is not a wavebrdf dataset (no format=\"wavebrdf\" attribute)")
        version = attrs.get("format_version")
        if not isinstance(version, (int, np.integer)) or isinstance(version, (bool, np.bool_)):
            raise self._fail(f"has no valid format_version attribute (found {version!r})")
        if version not in READ_VERSIONS:
            newer = "by a newer wavebrdf; update wavebrdf to read it" if version > FORMAT_VERSION else "unsupported"
            raise self._fail(f"is in format version {version} ({newer}); this wavebrdf reads format versions "
                             f"{', '.join(map(str, READ_VERSIONS))}")
        if self.kind not in LAYOUTS:
            raise self._fail(f"has an unknown kind {self.kind!r} (known: {', '.join(LAYOUTS)})")
        layout = LAYOUTS[self.kind]
        main, trailing, letters, others = layout.main, layout.trailing, layout.letters, layout.others
        for name in (main, *others, *trailing):
            if not isinstance(self._h5.get(name), h5py.Dataset):
                raise self._fail(f"is not a complete wavebrdf dataset: variable {name!r} is missing")
        dims, shape = self._dims(main), self._h5[main].shape
        if len(dims) < len(trailing) or tuple(dims[-len(trailing):]) != trailing:
            raise self._fail(f"is damaged: variable {main!r} has dimensions {dims}, expected [..., "
                             f"{', '.join(trailing)}]")
        for dim, n in zip(dims, shape):
            coordinate = self._h5.get(dim)
            if not isinstance(coordinate, h5py.Dataset) or coordinate.shape != (n,):
                raise self._fail(f"is damaged: variable {main!r} has {n} {dim!r} values but its coordinate "
                                 f"has shape {getattr(coordinate, 'shape', None)}")
            if dim in trailing and coordinate.dtype.kind not in "fiu":
                raise self._fail(f"is damaged: coordinate {dim!r} holds {coordinate.dtype}, not numbers")
        lead = shape[: len(shape) - len(trailing)]
        size = dict(zip(letters, shape[len(lead):]))
        for name, spec in {main: "*" + letters, **others}.items():
            expected = tuple(n for c in spec for n in (lead if c == "*" else [int(c)] if c.isdigit() else [size[c]]))
            found = self._h5[name]
            numeric = found.dtype.kind in "fiu"
            if found.shape != expected or numeric == (name == "polarization"):
                raise self._fail(f"is damaged: variable {name!r} is {found.dtype} {found.shape}, expected "
                                 f"{'strings' if name == 'polarization' else 'numbers'} {expected}")

    @contextmanager
    def reading(self):
        """Turn what a damaged file raises while it is read into a one-line :class:`StoreError`."""
        try:
            yield self
        except (StorageError, StoreError, BrokenPipeError):  # a reader that stopped reading is not a damaged
            raise  # file, and a file found not to be a dataset says so itself
        except (KeyError, ValueError, IndexError, TypeError, OSError, RuntimeError) as exc:  # h5py: stale scales
            text = " ".join(str(exc).split())[:200]
            raise self._fail(f"is damaged or incomplete ({type(exc).__name__}: {text})") from None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        self._h5.close()

    @property
    def h5(self) -> h5py.File:
        return self._h5

    @property
    def attrs(self) -> dict:
        return {k: (v.decode() if isinstance(v, bytes) else v) for k, v in self._h5.attrs.items()}

    @property
    def config(self) -> str:
        return self.attrs.get("config", "")

    @property
    def kind(self) -> str:
        """ "surface" (BRDF layout) or "fiber" (BCSDF layout)."""
        return self.attrs.get("kind", "surface")

    @property
    def main_variable(self) -> str:
        return LAYOUTS[self.kind].main

    @property
    def sweep_shape(self) -> tuple[int, ...]:
        """The lengths of the sweep axes (() without a sweep); flat case indices are C order over them."""
        return tuple(self._h5[self.main_variable].shape[: len(self.sweep_keys)])

    @property
    def sweep_keys(self) -> list[str]:
        dims = self._dims(self.main_variable)
        return dims[: dims.index("wavelength_um")]

    def _dims(self, name: str) -> list[str]:
        return [d.label or self._scale_name(d) for d in self._h5[name].dims]

    @staticmethod
    def _scale_name(dim) -> str:
        return dim[0].name.lstrip("/") if len(dim) else ""

    @property
    def coords(self) -> dict[str, np.ndarray]:
        out = {}
        for name in self.sweep_keys + list(LAYOUTS[self.kind].coordinates):
            data = self._h5[name][()]
            if data.dtype.kind == "O":
                data = np.array([x.decode() if isinstance(x, bytes) else x for x in data])
            out[name] = data
        return out

    def __getitem__(self, name: str) -> np.ndarray:
        return self._h5[name][()]

    def bcsdf(self, theta_i, theta_r, phi_i, phi_r, wavelength_um, variance=None, case: int = 0) -> np.ndarray:
        """Fiber datasets: the full BCSDF S = M0(θ_i, θ_r; v) · N_wave(λ, θ_i, φ_i, φ_r) in 1/sr,
        vectorized (arrays broadcast). Angles in radians (θ from the plane normal to the axis, ω_i
        toward the light), λ in µm, ``variance`` v (rad²; default: the stored
        ``longitudinal_variance``), ``case`` a flat sweep index. ∫ S dω_r = C_sca/C_ext.
        See :mod:`wavebrdf.solver.fiber.evaluator`."""
        from wavebrdf.solver.fiber.evaluator import FiberBCSDF

        cache = self.__dict__.setdefault("_bcsdf_cache", {})
        if case not in cache:
            cache[case] = FiberBCSDF.from_dataset(self, case)
        return cache[case](theta_i, theta_r, phi_i, phi_r, wavelength_um, variance)

    @property
    def brdf(self) -> np.ndarray:
        return self["brdf"]

    @property
    def brdf_polarization(self) -> str:
        """The polarization the surface dataset's ``brdf`` is of ("unpolarized", "s" or "p"; "" when
        unrecorded)."""
        label = self._h5["brdf"].attrs.get("polarization", "") if "brdf" in self._h5 else ""
        return label.decode() if isinstance(label, bytes) else str(label)

    @property
    def polarimetry(self) -> str:
        """What the surface dataset stores beyond intensities: "jones", "mueller" or "intensity"."""
        return next((name for name in ("jones", "mueller") if name in self._h5), "intensity")

    def jones(self, where: tuple = ()) -> np.ndarray:
        """Complex Jones matrices [sweep..., wavelength_um, incidence, out, in, u, v] (1/√sr; NaN
        outside the disk), frames of solver/polarimetry.py; a dataset stored with
        ``[output] polarization = "jones"``. ``where``: an index into the leading axes (sweep…,
        wavelength, incidence), read alone (e.g. ``(0, 2)``: sweep case 0, wavelength 2)."""
        if "jones" not in self._h5:
            raise self._fail(f"stores no Jones matrices (polarimetry: {self.polarimetry}); run the study with "
                             "[output] polarization = \"jones\"")
        pair = self._h5["jones"][tuple(where)]
        return pair[..., 0] + 1j * pair[..., 1].astype(np.complex64)

    def mueller(self, where: tuple = ()) -> np.ndarray:
        """Mueller matrices [sweep..., wavelength_um, incidence, 4, 4, u, v] (1/sr; NaN outside the
        disk), stored (``polarization = "mueller"``) or derived from the Jones matrices; ``where``
        as in :meth:`jones`. Averages of them (over pixels, realizations, wavelengths) are
        incoherent averages."""
        if "mueller" in self._h5:
            return self._h5["mueller"][tuple(where)]
        J = np.moveaxis(self.jones(where), (-4, -3), (0, 1))  # out, in first
        return np.moveaxis(polarimetry_module.mueller(J).astype(np.float32), (0, 1), (-4, -3))

    @property
    def albedo(self) -> np.ndarray:
        return self["albedo"]

    @property
    def tasks(self) -> dict[str, np.ndarray]:
        grp = self._h5.get("tasks")
        return {} if grp is None else {k: grp[k][()] for k in grp}

    def case_variable(self, case: int = 0) -> h5py.Dataset | None:
        """The per-case variable of flat sweep case ``case`` (surface heights, fiber cross section),
        by its name in format version 3 or, in older files, the bare case number; None if absent."""
        layout = LAYOUTS[self.kind]
        for name in (layout.case_variable(case), f"{layout.per_case[0]}/{case}"):
            found = self._h5.get(name)
            if isinstance(found, h5py.Dataset):
                return found
        return None

    def surface(self, case: int = 0) -> np.ndarray:
        """The height matrix (µm) of flat sweep case ``case``."""
        found = self.case_variable(case)
        if found is None:
            raise self._fail(f"has no surface heights of case {case}")
        return found[()]

    def to_xarray(self):
        """The file as an ``xarray.Dataset`` (h5netcdf engine); for surfaces ``incidence`` is
        indexed by (theta_i, phi_i), so ``.sel(theta_i=30)`` or ``.sel(theta_i=60, phi_i=45)``
        selects directions (``.isel(incidence=k)`` still works)."""
        import xarray as xr

        ds = xr.open_dataset(self.path, engine="h5netcdf")
        index = LAYOUTS[self.kind].xarray_index
        return ds.set_index(**index) if index else ds

    def __repr__(self) -> str:
        name = self.main_variable
        shape = dict(zip(self._dims(name), self._h5[name].shape))
        return f"<wavebrdf.Dataset {self.path.name} study={self.attrs.get('study')!r} {name}{shape}>"


def open_dataset(path: str | Path) -> Dataset:
    """Open a wavebrdf dataset for reading."""
    return Dataset(path)
