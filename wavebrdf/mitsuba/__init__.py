"""Mitsuba 3 plugins for wavebrdf datasets (optional extra ``render``: ``pip install wavebrdf[render]``).

>>> import mitsuba as mi, wavebrdf.mitsuba
>>> mi.set_variant("scalar_rgb")            # or llvm_ad_rgb, scalar_spectral, llvm_ad_spectral, *_mono
>>> wavebrdf.mitsuba.register()             # BSDF "wavebrdf" for the current variant
>>> mi.load_dict({"type": "sphere", "bsdf": {"type": "wavebrdf", "filename": "out/default.h5"}})

Plugin properties: ``filename`` (a surface dataset), ``case`` (flat sweep-case index, default 0),
``smooth_sigma`` (speckle blur, u units; default λ/(2π·waist) from the dataset's config, 0 = none),
``isotropic`` (use rotation invariance in φ; default: as the config declares it),
``interpolation`` ("shift": Harvey–Shack alignment of the lobes over incidence, default; "blend").
:func:`render_scene` renders a sphere or a tilted plate of the material under a procedural sky
(docs/mitsuba.md). Tables are loaded once per (file, options, channel kind) and kept
(:data:`_CACHE`; :func:`clear_cache`).
"""

from __future__ import annotations

import os
from pathlib import Path

from wavebrdf.mitsuba.tables import Tables, load_tables

__all__ = ["clear_cache", "environment", "fiber_radius", "fiber_tables_for", "register", "render_scene", "scene_dict",
           "tables_for"]

_CACHE: dict = {}


def _mitsuba():
    try:
        import mitsuba as mi
    except ImportError as exc:  # pragma: no cover - depends on the installation
        raise ImportError("wavebrdf.mitsuba needs Mitsuba 3: pip install 'wavebrdf[render]' "
                          f"(or pip install 'mitsuba>=3.5'): {exc}") from None
    return mi


def tables_for(filename, *, channels: str, case: int = 0, smooth_sigma: float | None = None,
               isotropic: bool | None = None) -> Tables:
    """The (cached) tables of a dataset for one channel kind ("rgb", "spectral", "mono")."""
    return _cached(filename, ("surface", channels, int(case), smooth_sigma, isotropic),
                   lambda path: load_tables(path, case=int(case), channels=channels, smooth_sigma=smooth_sigma,
                                            isotropic=isotropic))


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


def _load_from_props(props, channels: str) -> Tables:
    if "filename" not in props:
        raise ValueError("[wavebrdf plugin] filename: missing (a wavebrdf surface dataset, .h5)")
    sigma = props.get("smooth_sigma", None)
    iso = props.get("isotropic", None)
    return tables_for(str(props["filename"]), channels=channels, case=int(props.get("case", 0)),
                      smooth_sigma=None if sigma is None else float(sigma),
                      isotropic=None if iso is None else bool(iso))


def fiber_tables_for(filename, *, channels: str, case: int = 0):
    """The (cached) tables of a fiber dataset for one channel kind ("rgb", "spectral", "mono")."""
    from wavebrdf.mitsuba.fiber_tables import load_fiber_tables

    return _cached(filename, ("fiber", channels, int(case)),
                   lambda path: load_fiber_tables(path, case=int(case), channels=channels))


def _load_fiber_from_props(props, channels: str):
    if "filename" not in props:
        raise ValueError("[wavebrdf_fiber plugin] filename: missing (a wavebrdf fiber dataset, .h5)")
    variance = props.get("variance", None)
    tables = fiber_tables_for(str(props["filename"]), channels=channels, case=int(props.get("case", 0)))
    return tables, None if variance is None else float(variance)


def fiber_radius(filename, geometric_radius: float, case: int = 0) -> float:
    """The radius to give a scene's cylinders/curves for fibers of ``geometric_radius`` (scene
    units): the bounding width C_b = max C_e of the dataset, scaled like the geometric width."""
    tables = fiber_tables_for(filename, channels="mono", case=case)
    return geometric_radius * tables.bounding_width_um / tables.geometric_width_um


def register() -> None:
    """Register BSDFs ``"wavebrdf"`` (surfaces) and ``"wavebrdf_fiber"`` (fibers) for the current
    Mitsuba variant (call after ``mi.set_variant``; again after switching variants)."""
    mi = _mitsuba()
    from wavebrdf.mitsuba.fiber import make_fiber_plugin_class
    from wavebrdf.mitsuba.plugin import make_plugin_class

    cls = make_plugin_class(mi, _load_from_props)
    mi.register_bsdf("wavebrdf", lambda props: cls(props))
    fiber_cls = make_fiber_plugin_class(mi, _load_fiber_from_props)
    mi.register_bsdf("wavebrdf_fiber", lambda props: fiber_cls(props))


from wavebrdf.mitsuba.scene import environment, render_scene, scene_dict  # noqa: E402
