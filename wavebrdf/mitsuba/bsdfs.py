"""The BSDFs ``"wavebrdf"`` and ``"wavebrdf_fiber"``: their registration with Mitsuba and the
tables they read, loaded once per (file, options, channel kind) and kept (:data:`_CACHE`;
:func:`clear_cache`)."""

from __future__ import annotations

import logging
import os
from pathlib import Path

from wavebrdf.mitsuba.fiber import make_fiber_plugin_class
from wavebrdf.mitsuba.fiber_tables import load_fiber_tables
from wavebrdf.mitsuba.plugin import make_plugin_class
from wavebrdf.mitsuba.tables import Tables, load_tables

__all__ = ["MITSUBA_REQUIREMENT", "clear_cache", "fiber_radius", "fiber_tables_for", "register", "require_mitsuba",
           "tables_for"]

MITSUBA_REQUIREMENT = "mitsuba>=3.6"  # the `render` extra's requirement (pyproject.toml)

logger = logging.getLogger("wavebrdf")
_CACHE: dict = {}
_NOTED: set = set()  # the cached tables whose polarization note was logged


def require_mitsuba():
    """The ``mitsuba`` module; ImportError saying how to install it when it is missing."""
    try:
        import mitsuba as mi
    except ImportError as exc:
        raise ImportError(f"wavebrdf.mitsuba needs Mitsuba 3 ({MITSUBA_REQUIREMENT}): pip install 'wavebrdf[render]' "
                          f"(or pip install '{MITSUBA_REQUIREMENT}'); {exc}") from None
    return mi


def _dataset_path(props, plugin: str, what: str) -> str:
    """The plugin's ``filename`` resolved as Mitsuba resolves its own plugins' files: against the
    folders of its file resolver, the scene file's folder first when the scene is an XML file."""
    if "filename" not in props:
        raise ValueError(f"[{plugin} plugin] filename: missing (a wavebrdf {what} dataset, .h5)")
    mi = require_mitsuba()
    resolver = mi.file_resolver() if hasattr(mi, "file_resolver") else mi.Thread.thread().file_resolver()
    return str(resolver.resolve(str(props["filename"])))


def tables_for(filename, *, channels: str, case: int = 0, smooth_sigma: float | None = None,
               isotropic: bool | None = None, polarized: bool = False) -> Tables:
    """The (cached) tables of a dataset for one channel kind ("rgb", "spectral", "mono"), with the
    Mueller ratio tables for polarized variants."""
    return _cached(filename, ("surface", channels, int(case), smooth_sigma, isotropic, polarized),
                   lambda path: load_tables(path, case=int(case), channels=channels, smooth_sigma=smooth_sigma,
                                            isotropic=isotropic, polarized=polarized))


def _cached(filename, options: tuple, load):
    """``load(path)``, cached per (resolved path, its mtime and size, ``options``)."""
    path = Path(filename).resolve()
    try:
        stamp = os.stat(path)
        stamp = (stamp.st_mtime_ns, stamp.st_size)
    except OSError:
        stamp = None  # the loader names the missing file
    key = (str(path), stamp) + options
    if key not in _CACHE:
        _CACHE[key] = load(path)
    return _CACHE[key]


def clear_cache() -> None:
    _CACHE.clear()
    _NOTED.clear()


def _load_from_props(props, channels: str, polarized: bool = False) -> Tables:
    path = _dataset_path(props, "wavebrdf", "surface")
    sigma = props.get("smooth_sigma", None)
    iso = props.get("isotropic", None)
    tables = tables_for(path, channels=channels, case=int(props.get("case", 0)),
                        smooth_sigma=None if sigma is None else float(sigma),
                        isotropic=None if iso is None else bool(iso), polarized=polarized)
    if tables.diagnostics.get("polarization_note") and id(tables) not in _NOTED:  # once per loaded tables
        _NOTED.add(id(tables))
        logger.warning("[wavebrdf plugin] filename = %r: %s", path, tables.diagnostics["polarization_note"])
    return tables


def fiber_tables_for(filename, *, channels: str, case: int = 0):
    """The (cached) tables of a fiber dataset for one channel kind ("rgb", "spectral", "mono")."""
    return _cached(filename, ("fiber", channels, int(case)),
                   lambda path: load_fiber_tables(path, case=int(case), channels=channels))


def _load_fiber_from_props(props, channels: str):
    path = _dataset_path(props, "wavebrdf_fiber", "fiber")
    variance = props.get("variance", None)
    tables = fiber_tables_for(path, channels=channels, case=int(props.get("case", 0)))
    return tables, None if variance is None else float(variance)


def fiber_radius(filename, geometric_radius: float, case: int = 0) -> float:
    """The radius to give a scene's cylinders/curves for fibers of ``geometric_radius`` (scene
    units): the bounding width C_b = max C_e of the dataset, scaled like the geometric width."""
    tables = fiber_tables_for(filename, channels="mono", case=case)
    return geometric_radius * tables.bounding_width_um / tables.geometric_width_um


def register() -> None:
    """Register BSDFs ``"wavebrdf"`` (surfaces) and ``"wavebrdf_fiber"`` (fibers) for the current
    Mitsuba variant (call after ``mi.set_variant``; again after switching variants)."""
    mi = require_mitsuba()
    cls = make_plugin_class(mi, _load_from_props)
    mi.register_bsdf("wavebrdf", lambda props: cls(props))
    fiber_cls = make_fiber_plugin_class(mi, _load_fiber_from_props)
    mi.register_bsdf("wavebrdf_fiber", lambda props: fiber_cls(props))
