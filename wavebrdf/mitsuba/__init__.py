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

__all__ = ["clear_cache", "environment", "register", "render_scene", "scene_dict", "tables_for"]

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
    path = Path(filename).resolve()
    try:
        stamp = os.stat(path)
        stamp = (stamp.st_mtime_ns, stamp.st_size)
    except OSError:
        stamp = None  # load_tables names the missing file
    key = (str(path), stamp, channels, int(case), smooth_sigma, isotropic)
    if key not in _CACHE:
        _CACHE[key] = load_tables(path, case=int(case), channels=channels, smooth_sigma=smooth_sigma,
                                  isotropic=isotropic)
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


def register() -> None:
    """Register BSDF ``"wavebrdf"`` for the current Mitsuba variant (call after ``mi.set_variant``;
    again after switching variants)."""
    mi = _mitsuba()
    from wavebrdf.mitsuba.plugin import make_plugin_class

    cls = make_plugin_class(mi, _load_from_props)
    mi.register_bsdf("wavebrdf", lambda props: cls(props))


from wavebrdf.mitsuba.scene import environment, render_scene, scene_dict  # noqa: E402
