"""Mitsuba 3 plugins for wavebrdf datasets (optional extra ``render``: ``pip install wavebrdf[render]``).

>>> import mitsuba as mi, wavebrdf.mitsuba
>>> mi.set_variant("scalar_rgb")            # or llvm_ad_rgb, scalar_spectral, llvm_ad_spectral, *_mono
>>> wavebrdf.mitsuba.register()             # BSDF "wavebrdf" for the current variant
>>> mi.load_dict({"type": "sphere", "bsdf": {"type": "wavebrdf", "filename": "out/default.h5"}})

Plugin properties: ``filename`` (a surface dataset; a relative path is resolved by Mitsuba's file
resolver, against an XML scene's folder first), ``case`` (flat sweep-case index, default 0),
``smooth_sigma`` (speckle blur, u units; default λ/(2π·waist) from the dataset's config, 0 = none),
``isotropic`` (use rotation invariance in φ; default: as the config declares it),
``interpolation`` ("shift": Harvey–Shack alignment of the lobes over incidence, default; "blend").
:func:`render_scene` renders a sphere or a tilted plate of the material under a procedural sky
(docs/mitsuba.md). Tables are loaded once per (file, options, channel kind) and kept
(:func:`clear_cache`; wavebrdf/mitsuba/bsdfs.py).
"""

from __future__ import annotations

from wavebrdf.mitsuba.bsdfs import clear_cache, fiber_radius, fiber_tables_for, register, tables_for
from wavebrdf.mitsuba.scene import environment, render_scene, scene_dict

__all__ = ["clear_cache", "environment", "fiber_radius", "fiber_tables_for", "register", "render_scene", "scene_dict",
           "tables_for"]
