"""Conformance suite of the Model seam (solver/models.py): every registered model, by name.

Each case is parametrized over ``model_names()``, so a model registered later is covered without
editing this file; only scene sizes that a model needs differ, in :data:`SETTINGS` (a generic
default plus overrides keyed by model name). References are independent of the models' code:
tests/references.py (textbook Fresnel formulas), energy identities, and exact swaps of directions.

Cases (VALIDATION.md items 1, 3, 4, 5):

* capabilities and options: class attributes present and valid, default options parse, unknown
  option keys refused naming the key, ``estimate()`` positive and finite;
* surface models: flat albedo = Fresnel reflectance (unpolarized and per polarization) for glass
  and aluminium at several angles, lobe peak at the mirror direction;
* reciprocity (models claiming it): f(ω_i, ω_o) = f(ω_o, ω_i), directions on pixel centres;
* no gain for κ ≥ 0 (surfaces: albedo ≤ 1; fibers: C_abs ≥ 0, C_ext = C_sca + C_abs, ...);
* ``estimate()`` within a stated factor of the measured peak memory and CPU time (subprocess);
* capability flags enforced by the real config/plan/CLI layer, and an intensity-only test model
  (Lambertian) run end to end into a dataset.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import subprocess
import sys
import textwrap
import time
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest

from references import ALUMINIUM_400NM, beam_fresnel_reflectance, fresnel_reflectance
from wavebrdf.jobs.cli import main
from wavebrdf.solver import models
from wavebrdf.solver.farfield import HemisphereGrid, IntensityResult, albedo
from wavebrdf.solver.models import (
    Capabilities,
    Estimate,
    FiberResult,
    FiberScene,
    Model,
    ModelsWith,
    SurfaceScene,
    get_model,
    model_class,
    model_names,
    rung_order,
    rungs,
)
from wavebrdf.solver.options import OptionsError, option, parse_options
from wavebrdf.solver.surface import HeightField, generate

logger = logging.getLogger(__name__)

INPUTS = ("height_field", "cross_section", "statistics")  # Capabilities.takes (the seam's contract)
OUTPUTS = ("fields", "intensity", "fiber_table")  # Capabilities.returns
LAMBDA = 0.4  # µm, surfaces (aluminium constants are those at 0.4 µm)
GLASS = 1.5
DEG = np.pi / 180

# --------------------------------------------------------------------------------------------
# Per-model scene settings: a generic default (cheap approximate wave models) and overrides.
#
# flat:   flat patch for the Fresnel case. "reference" is "fresnel" (plane-wave Fresnel at θ_i) or
#         "exact_beam" (the same Fresnel formulas applied to each plane wave of the scene's exact
#         Gaussian beam — for models that illuminate with that beam on patches too small for its
#         angular spread λ/(πw) to be negligible; the plane-wave figure is logged as well).
# rough:  gently rough patch for reciprocity; gain: the same for the no-gain case.
# tolerance: the model's bar (VALIDATION.md item 1: 0.5% approximate wave models, 1% BEM).
# estimate: the scene whose memory/time estimate is compared with a measured run.
DEFAULT = {
    "tolerance": 0.005,
    "flat": dict(cells=810, size_um=162.0, waist_um=30.0, resolution=1024, angles_deg=(0.0, 40.0, 70.0, 80.0),
                 beam="exact", reference="fresnel", options=None),
    "rough": dict(cells=160, size_um=10.0, rms_height_um=0.12, correlation_um=1.0, seed=9, waist_um=1.8,
                  resolution=64, beam="exact", options=None),
    "gain": dict(cells=160, size_um=10.0, rms_height_um=0.12, correlation_um=1.0, seed=9, waist_um=1.8,
                 resolution=64, beam="exact", options=None),
    "estimate": dict(kind="surface", generator="gaussian", cells=400, size_um=24.0, rms_height_um=0.2,
                     correlation_um=1.0, waist_um=4.0, resolution=512, options=None),
    "fiber": dict(segments_per_wavelength=12.0),
}
OVERRIDES = {
    # CI: dense LU of a 1.5 µm patch (24 × 24 cells, d = λ/6.4, 2208 unknowns; the LU serves every
    # direction of a material), waist L/5 (margin 2.5 w). Its beam spreads over λ/(πw) ≈ 0.42 rad,
    # hence the exact-beam reference. The 1% bar holds at 0° and 20°; at 40° (glass, −1.4% in s) and
    # 70° (−4 … +22%) this patch is too small and too coarse (VALIDATION.md asks d ≤ λ/12): the
    # footprint leaks past the border (0.3% and 4.9% of Φ_i, FootprintWarning). Oblique incidence
    # is the slow case "flat_slow": AIM at d = λ/12 with the patch continued as the flat interface
    # beyond its border (aim.edge = "flat"), so no footprint is cut.
    "bem": {
        "tolerance": 0.01,
        "flat": dict(cells=24, size_um=1.5, waist_um=0.3, resolution=64, angles_deg=(0.0, 20.0),
                     beam="exact", reference="exact_beam", options={"method": "dense"}),
        "flat_slow": dict(cells=72, size_um=2.4, waist_um=0.6, resolution=128, angles_deg=(40.0, 70.0),
                          beam="exact", reference="exact_beam",
                          options={"method": "aim", "aim": {"edge": "flat"}}),
        # plane waves: the discrete PMCHWT scattering amplitudes are reciprocal (a finite beam is
        # not, tests/bem3d/test_bem3d_reciprocity.py); rough aluminium-like patch of 2λ
        "rough": dict(cells=16, size_um=0.8, rms_height_um=0.04, correlation_um=0.2, seed=11, waist_um=None,
                      resolution=32, beam="plane", options={"method": "dense"}),
        "gain": dict(cells=12, size_um=0.6, rms_height_um=0.02, correlation_um=0.2, seed=11, waist_um=0.12,
                     resolution=48, beam="exact", options={"method": "dense"}),
        "estimate": dict(kind="surface", generator="gaussian", cells=16, size_um=0.8, rms_height_um=0.03,
                         correlation_um=0.2, waist_um=0.16, resolution=32, options={"method": "dense"}),
    },
}
# GHS: albedo = R(θ_i) by Krywonos' renormalization on any patch, so a small flat patch suffices
# (OHS takes DEFAULT: its Ω = μ_o/μ_i curves across the lobe at 80°, −0.26% at w = 30 µm).
OVERRIDES["ghs"] = {
    "flat": dict(cells=400, size_um=64.0, waist_um=12.0, resolution=512, angles_deg=(0.0, 40.0, 70.0, 80.0),
                 beam="exact", reference="fresnel", options=None),
    "estimate": dict(kind="surface", generator="gaussian", cells=400, size_um=24.0, rms_height_um=0.1,
                     correlation_um=1.0, waist_um=4.0, resolution=512, options=None),
}
# PO: the footprint plane wave is not a Maxwell beam, so a flat patch reflects |r|²(1 + O((λ/w)²/μ_i⁴))
# (+1.1% s, +1.7% p at 80° for w = 30 µm; 0.1%/0.35% at 70°): 0°–70° in CI, 80° with w = 64 µm slow.
# Flat patches transform 8 of the 12 current components (J_z = M_z = 0), one order.
OVERRIDES["po"] = {
    "flat": dict(cells=810, size_um=162.0, waist_um=30.0, resolution=768, angles_deg=(0.0, 40.0, 70.0),
                 beam="exact", reference="fresnel", options=None),
    "flat_slow": dict(cells=1700, size_um=340.0, waist_um=64.0, resolution=1536, angles_deg=(80.0,),
                      beam="exact", reference="fresnel", options=None),
    "estimate": dict(kind="surface", generator="gaussian", cells=120, size_um=8.0, rms_height_um=0.05,
                     correlation_um=1.0, waist_um=1.4, resolution=128, options=None),
}
# GS/GM (ray rungs, 1% bar): a flat patch reflects every ray at θ_i, so a small patch and few rays
# suffice; fewer rays than the default for the other cases (CI time). Not reciprocal per pixel (the
# claim is False): see solver/approx/geometric.py.
OVERRIDES["gs"] = OVERRIDES["gm"] = {
    "tolerance": 0.01,
    "flat": dict(cells=16, size_um=4.0, waist_um=1.0, resolution=64, angles_deg=(0.0, 40.0, 70.0, 80.0),
                 beam="exact", reference="fresnel", options={"rays": 4096}),
    "gain": dict(DEFAULT["gain"], options={"rays": 1 << 16}),
    "estimate": dict(DEFAULT["estimate"], options={"rays": 1 << 20}),
}
# WS-V/WM (Falster): the per-facet obliquity (μ_o/μ_i for |r| = 1) curves across the footprint's
# angular spread at grazing incidence (+1.3% at 80° for w = 30 µm, +0.3% for w = 60 µm at 2048²),
# like PO: 0°–70° in CI, 80° with w = 60 µm slow. WM's depth ≥ 2 part is empty on a plane.
OVERRIDES["ws-v"] = {
    "flat": dict(DEFAULT["flat"], angles_deg=(0.0, 40.0, 70.0)),
    "flat_slow": dict(cells=1620, size_um=324.0, waist_um=60.0, resolution=2048, angles_deg=(80.0,),
                      beam="exact", reference="fresnel", options=None),
    "estimate": dict(DEFAULT["estimate"], cells=160, size_um=10.0, waist_um=1.8, resolution=128),
}
OVERRIDES["wm"] = {
    "flat": dict(OVERRIDES["ws-v"]["flat"], options={"rays": 4096}),
    "flat_slow": dict(OVERRIDES["ws-v"]["flat_slow"], options={"rays": 4096}),
    "gain": dict(DEFAULT["gain"], options={"rays": 1 << 16}),
    "rough": dict(DEFAULT["rough"], options={"rays": 1 << 16}),
    "estimate": dict(OVERRIDES["ws-v"]["estimate"], options={"rays": 1 << 20}),
}
# auto runs the rung it chooses (plus its pilot and escalation check): the flat Fresnel bar at 0° and
# 40° in CI (1%: a ray rung may be chosen), 70° and 80° as slow. Its rough scenes are gentle (σ = λ/40)
# so that it chooses an approximate rung: on the default rough patch (σ = 0.3λ) it would choose a
# 10⁵-unknown BEM, whose own conformance is tested above on small patches.
OVERRIDES["auto"] = {
    "tolerance": 0.01,
    "flat": dict(DEFAULT["flat"], angles_deg=(0.0, 40.0)),
    "flat_slow": dict(DEFAULT["flat"], angles_deg=(70.0, 80.0)),
    "gain": dict(DEFAULT["gain"], rms_height_um=0.01),
    "rough": dict(DEFAULT["rough"], rms_height_um=0.01),
    "estimate": dict(DEFAULT["estimate"], cells=160, size_um=10.0, rms_height_um=0.01, waist_um=1.8,
                     resolution=128),
}
ESTIMATE_FIBER = dict(kind="fiber", radius_um=0.5, wavelength_um=0.5, index=[1.55, -0.1], theta_i_deg=40.0,
                      phi_i=[0.0, 0.5, 1.0], phi_r_bins=360, options=None)

MEMORY_FACTOR = 4.0  # estimate within [measured / 4, measured * 4]
TIME_FACTOR = 20.0  # a sanity check on the cost model, not a speed assertion
MEMORY_FLOOR_BYTES = 32 * 2**20  # measured increments below this are noise (allocator, page cache)
TIME_FLOOR_S = 0.05  # measured run times below this are interpreter overhead and timer noise


def settings(name: str, case: str):
    """The model's settings for ``case`` (its override, else the generic default)."""
    overrides = OVERRIDES.get(name, {})
    return overrides[case] if case in overrides else DEFAULT[case]


def tolerance(name: str) -> float:
    return OVERRIDES.get(name, {}).get("tolerance", DEFAULT["tolerance"])


# --------------------------------------------------------------------------------------------
# Parametrization over the registry (an import failure of one model fails its tests, not collection)


def _capabilities_or_none(name: str):
    try:
        return model_class(name).capabilities
    except Exception:  # noqa: BLE001 - reported by the test itself (model_class raises again there)
        return None


def _names(predicate=lambda caps: True) -> list:
    """Registered names whose capabilities satisfy ``predicate`` (unimportable models included,
    so that their tests fail loudly)."""
    out = []
    for name in model_names():
        caps = _capabilities_or_none(name)
        if caps is None or predicate(caps):
            out.append(name)
    return out


SURFACE_INPUTS = ("height_field", "statistics")  # a height field, or the Gaussian ensemble it is drawn from
ALL = _names()
SURFACE = _names(lambda c: c.takes in SURFACE_INPUTS)
FIBER = _names(lambda c: c.takes == "cross_section")
RECIPROCAL = _names(lambda c: c.takes in SURFACE_INPUTS and c.reciprocal)


def _surface_class(name):
    cls = model_class(name)
    assert cls.capabilities.takes in SURFACE_INPUTS, f"{name}: not a surface model"
    return cls


# --------------------------------------------------------------------------------------------
# Scenes


def _surface(cfg: dict, takes: str = "height_field") -> HeightField:
    """The scene's patch; models taking statistics get a flat one as the σ = 0 Gaussian ensemble."""
    if cfg.get("rms_height_um") is None and takes == "height_field":
        return generate("flat", cells=cfg["cells"], size_um=cfg["size_um"])
    return generate("gaussian", cells=cfg["cells"], size_um=cfg["size_um"], seed=cfg.get("seed", 0),
                    rms_height_um=cfg.get("rms_height_um") or 0.0, correlation_um=cfg.get("correlation_um", 1.0))


def surface_scene(surface, cfg, index, theta, phi, grid) -> SurfaceScene:
    return SurfaceScene(surface=surface, wavelength_um=LAMBDA, index=complex(index), theta_i=float(theta),
                        phi_i=float(phi), waist_um=cfg["waist_um"], grid=grid, beam=cfg["beam"])


def _run(model, ctx, scene):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # footprint/resolution warnings of small patches: figures are asserted
        return model.run(ctx, scene)


def fiber_scene(index, theta_deg, radius=0.5, wavelength=0.5, phi_i=(0.0, 1.0), phi_r_bins=72,
                per_wavelength=12.0) -> FiberScene:
    from wavebrdf.solver.fiber import circle

    interior = wavelength / abs(complex(index))
    segments = max(16, int(math.ceil(per_wavelength * 2 * np.pi * radius / interior)))
    return FiberScene(cross_section=circle(radius, segments), wavelength_um=wavelength, index=complex(index),
                      theta_i=theta_deg * DEG, phi_i=tuple(phi_i), phi_i_bins=len(phi_i), phi_r_bins=phi_r_bins,
                      radius_um=radius)


def standard_scene(name: str):
    """A small valid scene of the model's kind (for estimate/check sanity)."""
    caps = model_class(name).capabilities
    if caps.takes == "cross_section":
        return fiber_scene(1.55, 30.0)
    if caps.takes in SURFACE_INPUTS:
        cfg = settings(name, "rough")
        return surface_scene(_surface(cfg), cfg, GLASS, 20 * DEG, 0.0, HemisphereGrid(cfg["resolution"]))
    pytest.fail(f"{name}: no standard scene for models taking {caps.takes!r} (add one to tests/test_models.py)")


# ============================================================================================
# 1. Capabilities and options


@pytest.mark.parametrize("name", ALL)
def test_capabilities_and_options(name):
    cls = model_class(name)
    assert issubclass(cls, Model)
    assert cls.name == name, f"class {cls.__name__}.name = {cls.name!r}, registered as {name!r}"
    caps = cls.capabilities
    assert isinstance(caps, Capabilities)
    assert caps.takes in INPUTS and caps.returns in OUTPUTS
    for flag in ("polarized", "steerable", "reciprocal", "conserves_energy", "spot_checks", "single_scattering",
                 "picks_rung", "vector_fields"):
        assert isinstance(getattr(caps, flag), bool), flag
    assert caps.rung is None or (isinstance(caps.rung, int) and caps.rung >= 0), caps.rung
    if caps.takes == "cross_section" or caps.picks_rung:  # the ladder is the surface rungs'
        assert caps.rung is None and not caps.single_scattering
    if caps.takes == "cross_section":
        assert caps.returns == "fiber_table" and not caps.steerable
    else:
        assert caps.returns in ("fields", "intensity")
    if caps.steerable:  # steering needs the model's own incident beam
        assert caps.returns == "fields" and cls.incident_fields is not Model.incident_fields
    # Options: a frozen dataclass whose defaults parse; unknown keys refused, naming the key
    assert dataclasses.is_dataclass(cls.Options) and cls.Options.__dataclass_params__.frozen
    defaults = parse_options(cls.Options, {}, f"model.{name}")
    assert defaults == cls.Options()
    model = get_model(name)
    assert model.options == cls.Options() and model.name == name
    with pytest.raises(OptionsError, match="no_such_option_xyz"):
        get_model(name, {"no_such_option_xyz": 1})
    # estimate() and check() on a small valid scene
    scene = standard_scene(name)
    est = model.estimate(scene)
    assert isinstance(est, Estimate)
    logger.info("%s: estimate %s", name, est)
    assert math.isfinite(est.memory_bytes) and est.memory_bytes > 0
    assert math.isfinite(est.seconds) and est.seconds > 0
    assert model.check(scene) is None


def test_the_ladder_is_read_from_the_capabilities():
    """compare's order and reference and auto's single-scattering floor come from the models'
    capabilities: the rungs in order, each place once, and which rungs end after one reflection."""
    ranked = sorted((n for n in model_names() if model_class(n).capabilities.rung is not None), key=rung_order)
    assert ranked == ["gs", "gm", "ohs", "ghs", "kirchhoff", "stam", "ws-v", "wm", "po", "bem"]
    assert len({model_class(n).capabilities.rung for n in ranked}) == len(ranked)
    assert set(ModelsWith("single_scattering")) == {"gs", "ohs", "ghs", "kirchhoff", "po", "stam", "ws-v"}
    assert "gm" not in ModelsWith("single_scattering") and "no-such-model" not in ModelsWith("single_scattering")
    assert "auto" not in rungs() and set(rungs()) == set(model_names()) - {"auto"}


# ============================================================================================
# 2. Surface models: flat interface = Fresnel (VALIDATION.md item 1)

FLAT_CASES = [(name, mat, angle, "flat") for name in SURFACE for mat in ("glass", "aluminium")
              for angle in (settings(name, "flat")["angles_deg"] if _capabilities_or_none(name) else (0.0,))]
FLAT_CASES += [pytest.param(name, mat, angle, "flat_slow", marks=pytest.mark.slow)
               for name in SURFACE if "flat_slow" in OVERRIDES.get(name, {}) for mat in ("glass", "aluminium")
               for angle in OVERRIDES[name]["flat_slow"]["angles_deg"]]


# logged beside the flat-surface figures when a model reports them (hemisphere-quadrature albedo,
# power into the material, its own beam reflectance): they locate a miss (grid, solver, beam)
DIAGNOSTICS = ("reflected_fraction", "into_material_fraction", "beam_reflectance", "incident_outside_fraction")


@pytest.fixture(scope="module")
def flat_models():
    """One instance per model, so that an operator built for one angle serves the next."""
    return {}


@pytest.mark.parametrize("name,material,theta_deg,scene", FLAT_CASES)
def test_flat_albedo_equals_fresnel(cl_ctx, flat_models, name, material, theta_deg, scene):
    _surface_class(name)
    cfg = settings(name, scene)
    key = (name, material, scene)
    if key not in flat_models:
        flat_models.clear()  # keep one operator alive at a time
        flat_models[key] = get_model(name, cfg["options"])
    model = flat_models[key]
    index = GLASS if material == "glass" else ALUMINIUM_400NM
    theta, phi = theta_deg * DEG, 25 * DEG
    grid = HemisphereGrid(cfg["resolution"])
    scene = surface_scene(_surface(cfg, model_class(name).capabilities.takes), cfg, index, theta, phi, grid)
    t0 = time.perf_counter()
    result = _run(model, cl_ctx, scene)
    brdf = result.brdf()
    measured = albedo(brdf, grid)  # (s, p)
    plane = np.array(fresnel_reflectance(1.0, index, theta))
    if cfg["reference"] == "exact_beam":
        from wavebrdf.solver.beams import make_beam  # the scene's incident field, not its reflection

        waves = make_beam("exact", LAMBDA, theta, phi, cfg["waist_um"], patch_size_um=cfg["size_um"]).plane_waves
        expected = beam_fresnel_reflectance(waves["kvec"], waves["E"], 1.0, index)
    else:
        expected = plane
    rel = measured / expected - 1
    rel_unpol = measured.mean() / expected.mean() - 1
    tol = tolerance(name)
    logger.info("%s %s θ=%g°: albedo s,p %s vs %s reference %s: rel %s, unpolarized %.3g "
                "(vs plane-wave Fresnel %s: rel %s) [%.1f s]; model's own diagnostics: %s", name, material,
                theta_deg, measured, cfg["reference"], expected, rel, rel_unpol, plane, measured / plane - 1,
                time.perf_counter() - t0, {k: result.diagnostics[k] for k in DIAGNOSTICS if k in result.diagnostics})
    assert abs(rel_unpol) < tol, f"{name} {material} {theta_deg}°: unpolarized albedo off by {rel_unpol:.4g}"
    assert np.all(np.abs(rel) < tol), f"{name} {material} {theta_deg}°: s,p albedo off by {rel}"
    # the lobe peaks at the mirror direction u_o = −u_i: radiant intensity f·μ_o, within one pixel
    # plus the beam's own angular half-width 1/(k w)
    intensity = np.nan_to_num(brdf.mean(axis=0)) * grid.mu
    peak = np.unravel_index(np.argmax(intensity), intensity.shape)
    mirror = -np.sin(theta) * np.array([np.cos(phi), np.sin(phi)])
    allowed = 2.0 / grid.resolution + 1.0 / (2 * np.pi / LAMBDA * cfg["waist_um"])
    offset = np.abs(grid.u[list(peak)] - mirror)
    logger.info("%s: peak at %s, mirror %s (allowed %.3g)", name, grid.u[list(peak)], mirror, allowed)
    assert np.all(offset <= allowed), f"{name} {material} {theta_deg}°: peak {offset} from the mirror direction"


# ============================================================================================
# 3. Reciprocity (VALIDATION.md item 3)

RECIPROCITY_PAIRS_DEG = [((15.0, 0.0), (35.0, 160.0)), ((30.0, 60.0), (50.0, 220.0)), ((45.0, 200.0), (20.0, 10.0))]


def _pixel(grid: HemisphereGrid, theta_deg: float, phi_deg: float) -> tuple[int, int]:
    """The pixel whose centre is nearest to the direction (θ, φ)."""
    u = np.sin(theta_deg * DEG) * np.array([np.cos(phi_deg * DEG), np.sin(phi_deg * DEG)])
    i, j = (int(np.argmin(np.abs(grid.u - c))) for c in u)
    assert grid.inside[i, j]
    return i, j


def _pixel_direction(grid: HemisphereGrid, pixel) -> tuple[float, float]:
    u, v = grid.u[pixel[0]], grid.u[pixel[1]]
    return float(np.arcsin(np.hypot(u, v))), float(np.arctan2(v, u))


@pytest.mark.parametrize("name", RECIPROCAL)
def test_reciprocity_on_a_gently_rough_surface(cl_ctx, name):
    """Unpolarized f(ω_i → ω_o) = f(ω_o → ω_i) within 2%, ω_i and ω_o on pixel centres."""
    _surface_class(name)
    cfg = settings(name, "rough")
    model = get_model(name, cfg["options"])
    grid = HemisphereGrid(cfg["resolution"])
    surface = _surface(cfg)
    worst = 0.0
    for a_deg, b_deg in RECIPROCITY_PAIRS_DEG:
        a, b = _pixel(grid, *a_deg), _pixel(grid, *b_deg)
        values = []
        for src, dst in ((a, b), (b, a)):
            theta, phi = _pixel_direction(grid, src)
            result = _run(model, cl_ctx, surface_scene(surface, cfg, ALUMINIUM_400NM, theta, phi, grid))
            values.append(result.brdf()[:, dst[0], dst[1]])
        f_io, f_oi = (float(np.mean(v)) for v in values)
        rel = f_io / f_oi - 1
        worst = max(worst, abs(rel))
        logger.info("%s: pixels %s ↔ %s: f(i,o) = %.6g, f(o,i) = %.6g (s,p %s / %s), rel %.3g",
                    name, a, b, f_io, f_oi, values[0], values[1], rel)
        assert f_io > 0 and f_oi > 0
    assert worst < 0.02, f"{name}: reciprocity off by {worst:.4g}"


# ============================================================================================
# 4. No gain for κ ≥ 0 (VALIDATION.md item 4)

# n − jκ for κ ∈ {0, 0.1, 5}: a dielectric, a weak absorber, a strong metal (n = 0.5, R ≈ 0.93)
GAIN_INDICES = {"kappa0": GLASS, "kappa0.1": GLASS - 0.1j, "kappa5": 0.5 - 5j}


# auto on the lossless dielectric runs the full wave (a minute here): CI keeps auto's two lossy cases
NO_GAIN_CASES = [pytest.param(name, kappa, marks=pytest.mark.slow) if (name, kappa) == ("auto", "kappa0")
                 else (name, kappa) for kappa in GAIN_INDICES for name in SURFACE]


@pytest.mark.parametrize("name, kappa", NO_GAIN_CASES)
def test_surface_no_gain(cl_ctx, name, kappa):
    cls = _surface_class(name)
    cfg = settings(name, "gain")
    model = get_model(name, cfg["options"])
    grid = HemisphereGrid(cfg["resolution"])
    surface = _surface(cfg)
    index = GAIN_INDICES[kappa]
    angles = (30.0, 70.0) if cls.capabilities.conserves_energy else (30.0,)
    for theta_deg in angles:
        result = _run(model, cl_ctx, surface_scene(surface, cfg, index, theta_deg * DEG, 0.4, grid))
        brdf = result.brdf()
        assert np.all(np.isfinite(brdf[:, grid.inside])) and np.all(brdf[:, grid.inside] >= 0)
        a = albedo(brdf, grid)
        logger.info("%s n = %s θ = %g°: albedo s,p %s (bound 1 + %g)", name, index, theta_deg, a, tolerance(name))
        assert np.all(a <= 1 + tolerance(name)), f"{name} n = {index} θ = {theta_deg}°: albedo {a} > 1"


FIBER_INDICES = {"lossless": 1.55, "lossy": 1.55 - 0.1j}


@pytest.mark.parametrize("material", list(FIBER_INDICES))
@pytest.mark.parametrize("name", FIBER)
def test_fiber_energy(cl_ctx, name, material):
    """Circle a = 0.5 µm, λ = 0.5 µm, θ_i 0° and 40°: C_abs ≥ 0, C_ext = C_sca + C_abs within
    1e-3, C_sca/C_ext ≤ 1, ∫ dC_s/dφ dφ = C_sca; lossless: C_abs ≈ 0 (< 1e-3 C_ext)."""
    cls = model_class(name)
    assert cls.capabilities.takes == "cross_section"
    model = get_model(name)
    index = FIBER_INDICES[material]
    for theta_deg in (0.0, 40.0):
        scene = fiber_scene(index, theta_deg, per_wavelength=DEFAULT["fiber"]["segments_per_wavelength"])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = model.run(cl_ctx, scene)
        assert isinstance(result, FiberResult)
        P, R = len(scene.phi_i), scene.phi_r_bins
        assert result.dCs_dphi.shape == (2, P, R)
        for arr in (result.C_ext, result.C_sca, result.C_abs):
            assert arr.shape == (2, P) and np.all(np.isfinite(arr))
        ext, sca, ab = result.C_ext, result.C_sca, result.C_abs
        balance = np.abs(ext - sca - ab) / ext
        integral = result.dCs_dphi.sum(axis=-1) * (2 * np.pi / R)
        logger.info("%s m = %s θ = %g° (N = %d): C_ext %s C_sca %s C_abs %s, balance %.3g, C_abs/C_ext %.3g, "
                    "∫dCs/dφ vs C_sca %.3g", name, index, theta_deg, len(scene.cross_section.nodes), ext[:, 0],
                    sca[:, 0], ab[:, 0], balance.max(), (ab / ext).max(), np.abs(integral / sca - 1).max())
        assert np.all(ext > 0) and np.all(sca > 0)
        assert np.all(ab >= -1e-12 * ext), f"{name}: gain, C_abs = {ab}"
        assert np.all(balance < 1e-3), f"{name}: C_ext − C_sca − C_abs = {balance.max():.3g} C_ext"
        assert np.all(sca / ext <= 1 + 1e-3)
        assert np.all(result.dCs_dphi >= 0)
        assert np.allclose(integral, sca, rtol=1e-3)
        if np.imag(index) == 0:
            assert np.all(np.abs(ab) / ext < 1e-3), f"{name}: lossless C_abs/C_ext = {(np.abs(ab) / ext).max():.3g}"
        else:
            assert np.all(ab / ext > 0.1)


# ============================================================================================
# 5. estimate() against the measured cost (subprocess: peak RSS over the post-import baseline)

MEASURE = r"""
import json, resource, sys, time, warnings
import numpy as np
spec = json.loads(sys.argv[1])
from wavebrdf.solver.models import FiberScene, SurfaceScene, get_model, model_class
from wavebrdf.solver.farfield import HemisphereGrid
from wavebrdf.solver.opencl import create_context
from wavebrdf.solver.surface import generate
from wavebrdf.solver.fiber import circle
import pyopencl, scipy.fft, scipy.linalg, scipy.special
model_class(spec["name"])  # the model's own modules
def peak_bytes():
    # VmHWM: this process's peak RSS (ru_maxrss would carry the parent's peak across fork + exec)
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmHWM:"):
                return float(line.split()[1]) * 1024.0
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024.0
baseline = peak_bytes()
warnings.simplefilter("ignore")
ctx = create_context()
if spec["kind"] == "surface":
    if spec["generator"] == "flat":
        surface = generate("flat", cells=spec["cells"], size_um=spec["size_um"])
    else:
        surface = generate("gaussian", cells=spec["cells"], size_um=spec["size_um"], seed=3,
                           rms_height_um=spec["rms_height_um"], correlation_um=spec["correlation_um"])
    scene = SurfaceScene(surface, 0.4, complex(1.2, -6.0), 0.5, 0.3, spec["waist_um"],
                         HemisphereGrid(spec["resolution"]))
else:
    from math import ceil, pi
    index = complex(*spec["index"])
    segments = int(ceil(12 * 2 * pi * spec["radius_um"] / (spec["wavelength_um"] / abs(index))))
    scene = FiberScene(circle(spec["radius_um"], segments), spec["wavelength_um"], index,
                       np.deg2rad(spec["theta_i_deg"]), tuple(spec["phi_i"]), len(spec["phi_i"]),
                       spec["phi_r_bins"], radius_um=spec["radius_um"])
model = get_model(spec["name"], spec["options"])
estimate = model.estimate(scene)
t0, cpu0 = time.perf_counter(), time.process_time()
model.run(ctx, scene)  # first run: kernel builds come from the disk cache (POCL_CACHE_DIR)
seconds, cpu_seconds = time.perf_counter() - t0, time.process_time() - cpu0
print(json.dumps({"baseline": baseline, "peak": peak_bytes(), "seconds": seconds, "cpu_seconds": cpu_seconds,
                  "estimate_bytes": estimate.memory_bytes, "estimate_seconds": estimate.seconds,
                  "detail": estimate.detail}))
"""


@pytest.mark.parametrize("name", ALL)
def test_estimate_within_factor_of_measured(name, tmp_path):
    """One scene per model in a fresh interpreter: Estimate.memory_bytes within 4× of the measured
    peak RSS (VmHWM) over the baseline after importing the same modules (context creation and the
    run are counted), Estimate.seconds within 20× of the run's wall time on an idle machine,
    bounded by its CPU time, which other processes' load does not change: an idle run with c cores
    takes between cpu/c and cpu seconds (floors: 32 MB, 0.05 s)."""
    caps = model_class(name).capabilities
    if caps.takes == "cross_section":
        spec = dict(ESTIMATE_FIBER)
    elif caps.takes in SURFACE_INPUTS:
        spec = dict(settings(name, "estimate"))
    else:
        pytest.fail(f"{name}: no estimate scene for models taking {caps.takes!r} (add one to tests/test_models.py)")
    spec["name"] = name
    script = tmp_path / "measure.py"
    script.write_text(MEASURE)
    proc = subprocess.run([sys.executable, str(script), json.dumps(spec)], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    m = json.loads(proc.stdout.strip().splitlines()[-1])
    used = m["peak"] - m["baseline"]
    logger.info("%s: estimate %.1f MB, %.3g s (%s); measured %.1f MB over the %.1f MB baseline, %.3g s",
                name, m["estimate_bytes"] / 2**20, m["estimate_seconds"], m["detail"], used / 2**20,
                m["baseline"] / 2**20, m["seconds"])
    print(f"{name}: estimate {m['estimate_bytes'] / 2**20:.1f} MB / {m['estimate_seconds']:.3g} s; measured "
          f"{used / 2**20:.1f} MB / {m['seconds']:.3g} s wall, {m['cpu_seconds']:.3g} s CPU")
    measured_bytes = max(used, MEMORY_FLOOR_BYTES)
    assert measured_bytes / MEMORY_FACTOR <= m["estimate_bytes"] <= measured_bytes * MEMORY_FACTOR, \
        f"{name}: memory estimate {m['estimate_bytes'] / 2**20:.1f} MB vs measured {used / 2**20:.1f} MB"
    cpu_seconds = max(m["cpu_seconds"], TIME_FLOOR_S)
    cores = len(os.sched_getaffinity(0))
    assert cpu_seconds / cores / TIME_FACTOR <= m["estimate_seconds"] <= cpu_seconds * TIME_FACTOR, \
        (f"{name}: time estimate {m['estimate_seconds']:.3g} s vs {m['cpu_seconds']:.3g} CPU s measured "
         f"({cores} cores; wall {m['seconds']:.3g} s)")


# ============================================================================================
# 6. Capabilities enforced by the real config/plan/CLI layer; an intensity-only model end to end


@dataclasses.dataclass(frozen=True)
class LambertianOptions:
    albedo: float = option(0.6, low=0.0, high=1.0, doc="diffuse reflectance ρ")


class LambertianTestModel(Model):
    """A Lambertian surface (test model): radiant intensity ρ Φ_i μ_o / π per polarization, so
    f = ρ/π and the albedo is ρ. Intensity-only: cannot be steered."""

    name = "lambertian-test"
    Options = LambertianOptions
    capabilities = Capabilities(takes="height_field", returns="intensity", polarized=False, steerable=False,
                                reciprocal=True, conserves_energy=True)

    def run(self, ctx, scene: SurfaceScene) -> IntensityResult:
        grid = scene.grid
        power = np.cos(scene.theta_i) * scene.surface.size_um**2  # any positive normalisation
        intensity = self.options.albedo * power * grid.mu / np.pi * grid.inside
        return IntensityResult(grid=grid, wavelength_um=scene.wavelength_um, theta_i=scene.theta_i,
                               phi_i=scene.phi_i, radiant_intensity=np.stack([intensity, intensity]),
                               incident_power=np.array([power, power]), diagnostics={"model": self.name})

    def estimate(self, scene) -> Estimate:
        return Estimate(1e6 + 64.0 * scene.grid.resolution**2, 1e-3, "Lambertian")


@pytest.fixture
def lambertian():
    models.register(LambertianTestModel.name, f"{__name__}:LambertianTestModel")
    yield LambertianTestModel.name
    models._REGISTRY.pop(LambertianTestModel.name, None)


SURFACE_STUDY = """
[study]
name = "{name}"
output = "{out}"

[surface]
generator = "gaussian"
size_um = 4.0
cells = 40
rms_height_um = 0.05
correlation_um = 0.8
seed = 2

[material]
n = 1.5

[illumination]
wavelengths_um = [0.5, 0.6]
directions_deg = [[0, 0], [35, 20]]
waist_um = 0.7

[model]
name = "{model}"
{model_extra}

[output]
resolution = {resolution}
{extra}
"""

FIBER_STUDY = """
[study]
name = "{name}"
output = "{out}"

[fiber]
shape = "circle"
radius_um = 0.3
segments = 48

[material]
n = 1.55

[illumination]
wavelengths_um = [0.5]
theta_i_deg = [0]

[model]
name = "{model}"

[output]
phi_r_bins = 36
"""

STEERING = """
[steering]
patches = [2, 2]
patch_size_um = 2.0
"""


def write_study(folder: Path, name: str, model: str, *, fiber=False, model_extra="", extra="",
                resolution=64) -> Path:
    template = FIBER_STUDY if fiber else SURFACE_STUDY
    path = folder / f"{name}.toml"
    path.write_text(textwrap.dedent(template.format(name=name, out=folder / f"{name}.h5", model=model,
                                                    model_extra=model_extra, extra=extra,
                                                    resolution=resolution)))
    return path


def refused(capsys, argv, *patterns) -> str:
    """main(argv) returns 2 and prints one line ``wavebrdf: error: ...`` containing ``patterns``."""
    code = main(argv)
    err = capsys.readouterr().err.strip()
    assert code == 2, (code, err)
    assert len(err.splitlines()) == 1 and err.startswith("wavebrdf: error: "), err
    for pattern in patterns:
        assert pattern in err, err
    return err


def test_steering_refused_for_non_steerable_models(tmp_path, capsys, lambertian):
    """Every non-steerable surface model (today: the intensity-only test model) is refused at plan."""
    names = [n for n in model_names() if _capabilities_or_none(n) is not None
             and model_class(n).capabilities.takes == "height_field" and not model_class(n).capabilities.steerable]
    assert lambertian in names
    for name in names:
        cfg = write_study(tmp_path, f"steer-{name}", name, extra=STEERING)
        err = refused(capsys, ["plan", str(cfg)], "[steering]", repr(name), "cannot be steered")
        logger.info("%s: %s", name, err)
        assert not (tmp_path / f"steer-{name}.h5").exists()
    # the same study with a steerable model plans (the refusal is the capability, not the study)
    steerable = [n for n in SURFACE if _capabilities_or_none(n) and model_class(n).capabilities.steerable]
    assert steerable
    assert main(["plan", str(write_study(tmp_path, "steer-ok", steerable[0], extra=STEERING))]) == 0
    capsys.readouterr()


@pytest.mark.parametrize("name", FIBER)
def test_fiber_model_refused_in_a_surface_study(tmp_path, capsys, name):
    cfg = write_study(tmp_path, "surface-with-fiber-model", name)
    refused(capsys, ["plan", str(cfg)], "[model] name", f'"{name}"', "surface study")
    refused(capsys, ["run", str(cfg), "-q", "--no-render"], "surface study")
    assert not (tmp_path / "surface-with-fiber-model.h5").exists()


@pytest.mark.parametrize("name", SURFACE)
def test_surface_model_refused_in_a_fiber_study(tmp_path, capsys, name):
    cfg = write_study(tmp_path, "fiber-with-surface-model", name, fiber=True)
    refused(capsys, ["plan", str(cfg)], "[model] name", f'"{name}"', "fiber study")
    refused(capsys, ["run", str(cfg), "-q", "--no-render"], "fiber study")
    assert not (tmp_path / "fiber-with-surface-model.h5").exists()


def test_intensity_only_model_runs_end_to_end(tmp_path, capsys, lambertian):
    """The Lambertian test model through config → plan → scheduler → store: albedo = ρ within the
    grid's pixel error (the disk's pixel area against π), for every wavelength and direction."""
    rho = 0.37
    resolution = 64
    cfg = write_study(tmp_path, "lambert", lambertian, model_extra=f"albedo = {rho}", resolution=resolution)
    code = main(["run", str(cfg), "-q", "--no-render"])
    assert code == 0, capsys.readouterr().err
    capsys.readouterr()
    grid = HemisphereGrid(resolution)
    disk = grid.inside.sum() * grid.pixel_area / np.pi  # Σ Δu Δv over the disk / π
    with h5py.File(tmp_path / "lambert.h5", "r") as h5:
        stored = h5["albedo"][()]
        brdf = h5["brdf"][()]
        status = set(h5["tasks/status"][()].astype(str))
    logger.info("Lambertian ρ = %g: stored albedo %s, disk pixel area / π = %.6f", rho, stored.ravel(), disk)
    assert status == {"done"} and stored.size == 4
    assert np.allclose(stored, rho * disk, rtol=1e-6)
    assert np.all(np.abs(stored / rho - 1) <= abs(disk - 1) + 1e-6)
    assert abs(disk - 1) < 4.0 / resolution  # the pixel error itself is small
    inside = np.isfinite(brdf)
    assert np.allclose(brdf[inside], rho / np.pi, rtol=1e-6)
    # an unknown key of the model's own Options is refused by the config layer, naming it
    bad = write_study(tmp_path, "lambert-bad", lambertian, model_extra="albedoo = 0.3")
    refused(capsys, ["plan", str(bad)], "albedoo")
    bad = write_study(tmp_path, "lambert-range", lambertian, model_extra="albedo = 1.5")
    refused(capsys, ["plan", str(bad)], "albedo", "1.5")
    # a model that does not resolve polarization cannot be asked for s, p or per-polarization images
    bad = write_study(tmp_path, "lambert-pol", lambertian, extra="per_polarization = true")
    refused(capsys, ["plan", str(bad)], "does not resolve polarization", repr(lambertian))
