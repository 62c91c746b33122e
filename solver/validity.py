"""Validity checks of the approximate rungs: situations where a rung's figure is known to be off
by more than its tolerance, said out loud (a :class:`ValidityWarning` through :func:`warnings.warn`,
which the batch layer stores in the dataset's diagnostics, and a figure in the result's
diagnostics). Found by the extremes suite (tests/extremes.py, docs/extremes.md).

* :func:`check_waist` — a footprint of waist w spreads over λ₁/(πw) in angle, across which the
  rungs' obliquity and Fresnel factors vary: the flat albedo is off by ≈ 0.3 (λ₁/(πw))²/μ_i²
  (measured on flat aluminium at 0°: +3.1% for w = 0.38 µm, +0.18% for w = 1.5 µm at λ = 0.4 µm,
  Kirchhoff and Stam alike; OHS −2.9%, PO +2.7% at w = 0.15 µm). GHS renormalizes it away; po,
  ws-v and wm lit by the beam reflect each plane wave at its own angle and are not checked, and lit
  by the footprint their warning names that option (:func:`beam_incidence_remedy`).
* :func:`check_evanescent_loss` — OHS keeps only the part of the reflected angular spectrum
  inside the unit disk (GHS renormalizes it): on rough patches the rest is simply missing.
* :func:`energy_excess_warning` — no model may return more power than falls on the surface
  (κ ≥ 0): the line a run's task table and ``compare``'s table carry when one does.
* :func:`check_lit_facets` — a tangent-plane rung (kirchhoff, po, ws-v, wm) whose albedo falls
  well below one reflection off each lit facet (:func:`~wavebrdf.solver.footprint.lit_facet_albedo`)
  has sent that power beyond the horizon: relief finer than λ₁ (a grating of period below λ,
  white-noise heights) scatters it into evanescent orders, which the full wave returns into the
  propagating ones (a 0.4 µm-period aluminium grating at λ 0.5 µm, 8 µm patch: kirchhoff 0.38, AIM BEM 0.856).
* :func:`check_geometric_optics` — the ray rungs (gs, gm) are the large-roughness limit of the
  Kirchhoff lobe: below it (roughness parameter g = (2k₁σ_h cos θ_i)² small) their lobe differs from
  the wave's by :func:`geometric_limit_error`, and on features narrower than λ₁ rays do not exist.
"""

from __future__ import annotations

import warnings

import numpy as np


__all__ = ["ENERGY_SLACK", "EVANESCENT_LOSS", "GO_LOBE_ERROR", "LIT_FACET_DEFICIT", "LIT_FACET_SLACK", "SPREAD_ERROR",
           "SPREAD_COEFFICIENT", "ValidityWarning", "beam_incidence_remedy", "beyond_horizon", "cells_fix",
           "check_evanescent_loss", "check_geometric_optics", "check_lit_facets", "check_waist",
           "energy_excess_warning", "geometric_limit_error", "geometric_optics_figures", "horizon_loss",
           "lattice_period_um", "point_sampled_error", "recorded_warnings", "roughness_parameter", "STEERED_FRESNEL",
           "steered_fresnel_warning", "under_auto", "waist_spread"]

EVANESCENT_LOSS = 0.01  # OHS: warn when this share of the reflected spectrum is dropped
SPREAD_COEFFICIENT = 0.3  # albedo error ≈ this × (λ₁/(πw))²/μ_i² (fitted on flat aluminium, see above)
SPREAD_ERROR = 0.005  # warn above this predicted relative albedo error (the rungs' flat tolerance)
ENERGY_SLACK = 1e-3  # an albedo above 1 by more than this is energy the model created
ASYMPTOTIC_G = 400.0  # geometric_limit_error takes its asymptote √6/(4g) beyond this roughness parameter
STEERED_FRESNEL = 0.05  # warn when a steered rung's kept reflectance is this far (relative) from the requested one's
GO_LOBE_ERROR = 0.05  # warn when geometric optics' lobe is predicted this far (relative L2) from Kirchhoff's (g < 13)
LIT_FACET_DEFICIT = 0.1  # warn when a tangent-plane rung's albedo is this share below its lit facets'
# (check_lit_facets; benchmarks/lit_facets.py: every warned run of the trade table is off by > 0.1)
LIT_FACET_SLACK = 0.005  # the most a lit-facet deficit exceeded the error measured against BEM (trade table, 316 runs)


class ValidityWarning(UserWarning):
    """An approximate rung is outside the range where its figure holds to its tolerance."""


def _append(diagnostics: dict, message: str) -> None:
    recorded = diagnostics.get("warnings")
    line = f"ValidityWarning: {message}"
    if isinstance(recorded, list):
        recorded.append(line)
    else:
        diagnostics["warnings"] = "; ".join(w for w in (recorded or "", line) if w)


def check_evanescent_loss(fraction: float, diagnostics: dict, theta_i: float) -> None:
    """Warn when OHS drops more than EVANESCENT_LOSS of the reflected angular spectrum."""
    if np.isfinite(fraction) and fraction > EVANESCENT_LOSS:
        message = (f"ohs: {fraction:.3g} of the reflected angular spectrum lies beyond the horizon at θ_i = "
                   f"{np.rad2deg(theta_i):.4g}° and is dropped: that share of R(θ_i) is missing from the albedo "
                   "(rough patch; ghs renormalizes it)")
        _append(diagnostics, message)
        warnings.warn(message, ValidityWarning, stacklevel=3)


def check_lit_facets(scene, result, model: str, lit: np.ndarray | None = None, masking: bool = False) -> None:
    """Record in ``result.diagnostics`` the lit facets' albedo
    (:func:`~wavebrdf.solver.footprint.lit_facet_albedo`; ``lit``: the rung's own shadowing mask),
    how far below it the result's unpolarized albedo falls (``lit_facet_deficit``, relative) and
    the point-sampling error the pixel check predicts for the scene's narrowest lobe
    (``lit_facet_sampling``); warn where :func:`horizon_loss` finds a loss above
    :data:`LIT_FACET_DEFICIT`. ``masking``: the rung also removes what relief masks on the way out
    (ws-v, wm), said in the warning. A BRDF with NaN/inf is the run's own failure: nothing recorded."""
    from wavebrdf.solver.farfield import albedo
    from wavebrdf.solver.footprint import lit_facet_albedo

    brdf = result.brdf()
    if not np.all(np.isfinite(brdf[:, result.grid.inside])):
        return
    diagnostics = result.diagnostics
    expected = lit_facet_albedo(scene, lit)
    got = float(np.mean(albedo(brdf, result.grid)))
    diagnostics["lit_facet_albedo"] = expected
    diagnostics["lit_facet_deficit"] = 1.0 - got / expected if expected > 0 else 0.0
    diagnostics["lit_facet_sampling"] = point_sampled_error(scene)
    loss = horizon_loss(diagnostics)
    if loss is None or not loss > LIT_FACET_DEFICIT:
        return
    footprint_lit = scene.waist_um is not None and diagnostics.get("incidence", "footprint") != "beam"
    spread = (_spread_error(scene.wavelength_um / scene.exterior_index, scene.theta_i, scene.waist_um)[1]
              if footprint_lit else 0.0)
    parts = ([f"the footprint's spread alone puts {spread:.2g} of the reflected lobe there (a larger waist removes "
              "that part)"] if spread > SPREAD_ERROR else []) + (["masking on the way out removes part of it too"]
                                                                   if masking else [])
    message = (f"{model}: albedo {got:.3g} at θ_i = {np.rad2deg(scene.theta_i):.4g}° is {100 * loss:.0f} % below "
               f"{expected:.3g}, what one reflection off each lit facet under the footprint returns (Fresnel at each "
               "facet): the tangent plane sends that power beyond the horizon — relief finer than λ₁ scatters it "
               "into evanescent orders, which the full wave returns into the propagating ones — or past grazing"
               f"{''.join(f'; {p}' for p in parts)}; outside the model's validity (bem models it)")
    _append(diagnostics, message)
    warnings.warn(message, ValidityWarning, stacklevel=3)


def horizon_loss(diagnostics: dict) -> float | None:
    """The share of the lit facets' albedo a tangent-plane run lost (``lit_facet_deficit``, from
    :func:`check_lit_facets`), where the pixels' point sampling does not explain it (its predicted
    error below half the deficit); None where the run recorded none or sampling may explain it."""
    deficit, sampling = diagnostics.get("lit_facet_deficit"), diagnostics.get("lit_facet_sampling", 0.0)
    if deficit is None or not np.isfinite(deficit) or not sampling < 0.5 * deficit:
        return None
    return float(deficit)


def energy_excess_warning(model: str, theta_i_deg: float, albedo_sp) -> str | None:
    """The EnergyWarning line (category first, as task tables store warnings) when the albedo (s,
    p) of ``model``'s BRDF at θ_i (degrees) exceeds 1 by more than :data:`ENERGY_SLACK` in either
    polarization (a NaN in one does not hide the other), else None."""
    finite = np.asarray(albedo_sp, dtype=float)[np.isfinite(albedo_sp)]
    excess = float(finite.max()) - 1.0 if finite.size else float("nan")
    if not excess > ENERGY_SLACK:
        return None
    return (f"EnergyWarning: albedo (s, p) = ({albedo_sp[0]:.4g}, {albedo_sp[1]:.4g}) > 1 at θ_i = "
            f"{theta_i_deg:g}°: {model} returns {excess:.3g} of the incident power that does not exist "
            "(outside the model's validity, e.g. no shadowing at grazing incidence; a rung with "
            "shadowing such as ws-v, or bem, models it)")


def beam_incidence_remedy(model: str, incidence: str = "footprint") -> str | None:
    """What removes the footprint's spread error from ``model`` (po, ws-v or wm) lit by ``incidence``,
    in check_waist's words; None lit by the beam (no spread error to remove)."""
    if incidence == "beam":
        return None
    return f'incidence = "beam" in [model.{model}] (each plane wave of the beam reflected at its own angle)'


def recorded_warnings(caught) -> str:
    """Warnings recorded by ``warnings.catch_warnings(record=True)`` as task tables store them:
    "Category: message", each once, sorted, joined by "; "."""
    return "; ".join(sorted({f"{w.category.__name__}: {w.message}" for w in caught}))


def beyond_horizon(theta_i: float, lobe_sigma: float, samples: int = 161) -> float:
    """Share of a Gaussian lobe of σ ``lobe_sigma`` (direction cosines, intensity) centred at the
    mirror direction of θ_i (radians) that lies beyond the horizon (outside the unit disk)."""
    centre = float(np.sin(theta_i))
    u = centre + np.linspace(-6.0, 6.0, samples) * lobe_sigma
    v = np.linspace(-6.0, 6.0, samples) * lobe_sigma
    weight = np.exp(-0.5 * ((u[:, None] - centre) ** 2 + v[None, :] ** 2) / lobe_sigma**2)
    return float(weight[u[:, None] ** 2 + v[None, :] ** 2 > 1.0].sum() / weight.sum())


def _spread_error(lambda1: float, theta_i: float, waist_um: float) -> tuple[float, float]:
    """(second-order spread term, share beyond the horizon) of :func:`waist_spread`."""
    mu_i = max(float(np.cos(theta_i)), 1e-12)
    second = SPREAD_COEFFICIENT * (lambda1 / (np.pi * waist_um)) ** 2 / mu_i**2
    return float(second), beyond_horizon(theta_i, lambda1 / (2 * np.pi * waist_um))


def _round_up(value: float, digits: int = 3) -> float:
    """``value`` rounded up to ``digits`` significant digits."""
    scale = 10.0 ** (np.floor(np.log10(value)) - digits + 1)
    return float(np.ceil(value / scale) * scale)


def waist_spread(scene, model: str, remedy: str = "ghs") -> tuple[float | None, str | None]:
    """The footprint's angular spread λ₁/(πw) makes the albedo err by ≈ :data:`SPREAD_COEFFICIENT`
    (λ₁/(πw))²/μ_i² (relative; obliquity and Fresnel vary across it, raising it) or, toward grazing,
    by up to the share of the reflected lobe (σ = λ₁/(2πw) in direction cosines) beyond the horizon,
    which the rung drops (:func:`beyond_horizon`), whichever is larger. Flat aluminium at λ 0.45 µm,
    kirchhoff against Fresnel: at 75° −23 / −17 / −11 / −7 % for w = 1 / 1.5 / 2 / 2.5 µm, that share
    0.33 / 0.24 / 0.18 / 0.12 (the second-order term alone 0.09 / 0.04 / 0.02 / 0.015); at 85°,
    w = 2.5 µm, −31 % against 0.46; at 60° and 45°, w = 1 µm, +2.4 and +1.4 % against 0.034 and
    0.012; at 30°, w = 0.5 µm, +3.6 % against 0.033 (po and stam alike, ±3 points). That predicted
    error (None for a plane wave) and, above
    :data:`SPREAD_ERROR`, the warning naming a waist that would do, or ``remedy``: what else removes
    the spread error for ``model``. Runs nothing (``plan`` foresees it: Model.foreseen_warnings)."""
    if scene.waist_um is None:
        return None, None
    lambda1 = scene.wavelength_um / scene.exterior_index
    second, beyond = _spread_error(lambda1, scene.theta_i, scene.waist_um)
    error = max(second, beyond)
    if not error > SPREAD_ERROR:
        return float(error), None

    def too_wide(waist: float) -> bool:
        return max(_spread_error(lambda1, scene.theta_i, waist)) > SPREAD_ERROR

    narrow, enough = scene.waist_um, 2.0 * scene.waist_um  # the error falls as the waist grows: bracket, bisect
    while too_wide(enough) and enough < 1e6:
        narrow, enough = enough, 2.0 * enough
    for _ in range(30):
        middle = np.sqrt(narrow * enough)
        narrow, enough = (middle, enough) if too_wide(middle) else (narrow, middle)
    enough = _round_up(1.02 * enough)  # printed to 3 digits, never below what suffices (the share is sampled)
    horizon = f"; {beyond:.2g} of the reflected lobe lies beyond the horizon" if beyond > second else ""
    return float(error), (
        f"{model}: the footprint of waist {scene.waist_um:g} µm spreads over λ₁/(πw) = "
        f"{lambda1 / (np.pi * scene.waist_um):.3g} rad at θ_i = {np.rad2deg(scene.theta_i):.4g}°, so the "
        f"albedo is off by {'up to ' if beyond > second else ''}about {error:.2g} (relative; obliquity and Fresnel "
        f"vary across the spread{horizon}): use a waist ≥ {enough:.3g} µm, or {remedy}")


def check_waist(scene, diagnostics: dict, model: str, remedy: str = "ghs") -> None:
    """Warn when the footprint's angular spread makes the albedo err by more than SPREAD_ERROR
    (:func:`waist_spread`; ``diagnostics["waist_spread_error"]``: the predicted relative error)."""
    error, message = waist_spread(scene, model, remedy)
    if error is None:
        return
    diagnostics["waist_spread_error"] = error
    if message:
        _append(diagnostics, message)
        warnings.warn(message, ValidityWarning, stacklevel=3)


# --- sampling validity (the Model seam runs it on every surface scene: solver/models.py) ----------

ALIAS_SIGMAS = 5.0  # a lobe reaches this many of its σ (intensity e^{−12.5}: Ω_K ∝ 1/μ_o lifts replica tails at the horizon)
PIXEL_ERROR = 0.005  # warn above this predicted relative albedo error of point-sampled lobes
STATISTICS_TOLERANCE = 0.1  # warn when a realization's expected statistic differs by more than this share

SAMPLING_FLAGS = ("lattice", "pixels", "realization")
"""What a model's figure depends on, each checked by :func:`check_sampling`:

* ``lattice`` — it sums e^{+jk s·x} over the surface nodes (the Kirchhoff family: kirchhoff, po,
  ohs, ghs, ws-v, wm), a sum periodic in s with period λ₁/d: the specular lobe at s = 0 repeats at
  s = m λ₁/d, i.e. at u_o = −u_i + m λ₁/d, inside the hemisphere unless λ₁/d exceeds
  1 + sin θ_i plus the lobe's reach (footprint spread, surface slopes);
* ``pixels`` — it point-samples its lobes at the pixel centres (the albedo is their Riemann sum);
* ``realization`` — it takes the height field: a random one is checked against its ensemble.
"""


class _SurfaceFigures:
    """rms height, rms slope and correlation length of a height field (µm), computed once per
    surface object (plan and run ask for the same surface many times)."""

    _cache: dict = {}

    @classmethod
    def of(cls, surface) -> dict:
        key = id(surface)
        hit = cls._cache.get(key)
        if hit is not None and hit[0] is surface:
            return hit[1]
        z = surface.z - surface.z.mean()
        flat = not np.ptp(z) > 0
        ensemble = surface.ensemble
        if ensemble is not None:
            correlation = min(ensemble.correlation_um)
        elif flat:
            correlation = float("nan")
        else:
            correlation = float(np.nanmin(surface.correlation_lengths()))
        figures = {"rms_height_um": float(np.sqrt(np.mean(z**2))), "flat": flat,
                   "rms_slope": 0.0 if flat else surface.rms_slope(), "correlation_um": correlation}
        if len(cls._cache) > 8:
            cls._cache.clear()
        cls._cache[key] = (surface, figures)
        return figures


def alias_free_spacing(scene, rms_slope: float = 0.0) -> float:
    """The largest surface spacing (µm) whose node sum keeps its specular lobe's replicas (at
    s = m λ₁/d) outside the hemisphere: λ₁/(1 + sin θ_i + 5σ_w + 5 (1 + μ_i) s/√2), with
    σ_w = λ₁/(2πw) the specular lobe's σ in direction cosines and s the rms slope (the diffuse
    lobe's reach along one axis, 0: the specular lobe only)."""
    lambda1 = scene.wavelength_um / scene.exterior_index
    reach = np.sin(scene.theta_i) + ALIAS_SIGMAS * lambda1 / (2 * np.pi * scene.waist_um)
    reach += ALIAS_SIGMAS * (1 + np.cos(scene.theta_i)) * rms_slope / np.sqrt(2.0)
    return lambda1 / (1.0 + reach)


def _where(scene) -> str:
    return (f"λ = {scene.wavelength_um:g} µm (λ₁ = {scene.wavelength_um / scene.exterior_index:g} µm), θ_i = "
            f"{np.rad2deg(scene.theta_i):.4g}°, waist {scene.waist_um:g} µm")


def cells_fix(surface, spacing_um: float) -> str:
    """The config fix that brings ``surface``'s spacing to ``spacing_um`` (µm) or below."""
    cells = int(np.ceil(surface.size_um / spacing_um * (1 - 1e-9)))  # a whole number of spacings is enough
    key = "surface.cells" if surface.parameters is not None else "a height file resampled to"
    return f"{key} ≥ {cells} (spacing ≤ {spacing_um:.4g} µm)"


def _check_lattice(model: str, scene, figures: dict) -> list[str]:
    """Refuse a spacing whose node sum repeats the specular lobe inside the hemisphere; warn when
    the diffuse lobe's tails (the rms slope) reach a replica."""
    surface = scene.surface
    d = surface.spacing_um
    limit = alias_free_spacing(scene)
    head = (f"{model}: surface spacing d = size_um/cells = {surface.size_um:g}/{surface.cells} = {d:.4g} µm at "
            f"{_where(scene)}")
    if d > limit:
        lambda1 = scene.wavelength_um / scene.exterior_index
        raise ValueError(f"{head}: the node sum repeats the specular lobe every λ₁/d in direction cosines, so a "
                         f"false lobe appears at u = −sin θ_i + λ₁/d = {lambda1 / d - np.sin(scene.theta_i):.3g} "
                         f"inside the hemisphere (alias-free below λ₁/(1 + sin θ_i + 5λ₁/(2πw)) = {limit:.4g} µm); "
                         f"use {cells_fix(surface, limit)}")
    rough = alias_free_spacing(scene, figures["rms_slope"])
    if figures["rms_slope"] > 0 and d > rough:
        return [f"{head}: the diffuse lobe of rms slope {figures['rms_slope']:.3g} reaches its replica at λ₁/d "
                f"(alias-free below {rough:.4g} µm = λ₁/(1 + sin θ_i + 5σ_w + 5(1 + μ_i)·slope/√2)), so part "
                f"of it folds back into the hemisphere; use {cells_fix(surface, rough)}"]
    return []


def point_sampling_error(sigma: float, pixel: float) -> float:
    """Relative error of the point-sampled integral of a 2-D Gaussian lobe of σ ``sigma`` on a
    lattice of pitch ``pixel`` (worst offset; Poisson summation): 4 exp(−2π²σ²/pixel²)."""
    return float(4.0 * np.exp(-2.0 * (np.pi * sigma / pixel) ** 2))


def lattice_period_um(surface) -> float | None:
    """The period (µm) of a generated periodic surface's lattice: its ``period_um``, or the square
    lattice of "hemispheres" (size/√count); None for a random or aperiodic surface."""
    recorded = surface.parameters or {}
    if surface.ensemble is not None:
        return None
    if recorded.get("period_um"):
        return float(recorded["period_um"])
    if recorded.get("generator") == "hemispheres" and recorded.get("placement", "square") == "square":
        return float(surface.size_um / np.sqrt(recorded["hemispheres"]))
    return None


def roughness_parameter(scene, rms_height_um: float) -> float:
    """g = (2k₁σ_h cos θ_i)² of heights of rms ``rms_height_um`` at the scene's λ₁ and θ_i: e^{−g} is
    the share of the reflected power a Gaussian-correlated surface keeps in the specular lobe."""
    k1 = 2 * np.pi * scene.exterior_index / scene.wavelength_um
    return float((2 * k1 * rms_height_um * np.cos(scene.theta_i)) ** 2)


def lobes(scene, figures: dict) -> list[tuple[str, float, float, bool]]:
    """The narrowest lobes of a scene: (name, share of the reflected power, σ in direction
    cosines, whether the footprint alone sets σ). The specular lobe: share e^{−g},
    g = (2kσ_h μ_i)², σ = λ₁/(2πw) (the footprint's spectrum); on a periodic surface
    (:func:`lattice_period_um`) the other diffraction orders, each as narrow, where one propagates
    (λ₁/Λ < 1 + sin θ_i): share 1 − e^{−g}; else the first diffuse term: share g e^{−g},
    σ = √(1/w² + 2/T²)/k (Stam's m = 1 term)."""
    if scene.waist_um is None:  # a plane wave: lobes of the patch's width, not point-sampled here
        return []
    k = 2 * np.pi * scene.exterior_index / scene.wavelength_um
    g = roughness_parameter(scene, figures["rms_height_um"])
    out = [("specular", float(np.exp(-g)), 1.0 / (k * scene.waist_um), True)]
    period = lattice_period_um(scene.surface)
    if g > 0 and period:
        if scene.wavelength_um / scene.exterior_index / period < 1.0 + np.sin(scene.theta_i):  # an order propagates
            orders = f"diffraction-order (period {period:.4g} µm)"
            out.append((orders, float(-np.expm1(-g)), 1.0 / (k * scene.waist_um), True))
        return out
    correlation = figures["correlation_um"]
    if g > 0 and np.isfinite(correlation):
        out.append(("diffuse (correlation length)", float(g * np.exp(-g)),
                    float(np.sqrt(1.0 / scene.waist_um**2 + 2.0 / correlation**2) / k), False))
    return out


def point_sampled_error(scene) -> float:
    """The largest albedo error (relative) the point sampling of the scene's lobes (:func:`lobes`)
    on its output pixels may make."""
    figures = _SurfaceFigures.of(scene.surface)
    pixel = 2.0 / scene.grid.resolution
    return max((share * point_sampling_error(sigma, pixel) for _, share, sigma, _ in lobes(scene, figures)),
               default=0.0)


def _check_pixels(model: str, scene, figures: dict) -> list[str]:
    """Warn when a lobe narrower than the output pixel is point-sampled beyond PIXEL_ERROR."""
    pixel = 2.0 / scene.grid.resolution
    out = []
    for name, share, sigma, footprint in lobes(scene, figures):
        error = share * point_sampling_error(sigma, pixel)
        if error > PIXEL_ERROR:
            # pitch at which share · 4 exp(−2π²σ²/p²) = PIXEL_ERROR / 2
            pitch = np.pi * sigma * np.sqrt(2.0 / np.log(8.0 * share / PIXEL_ERROR))
            resolution = int(np.ceil(2.0 / pitch))
            fix = f"use output.resolution ≥ {resolution}"
            if footprint:
                fix += f" or illumination.waist_um ≤ {scene.waist_um * pitch / pixel:.3g}"
            out.append(f"{model}: the {name} lobe (σ = {sigma:.3g} in direction cosines, {share:.3g} of the reflected "
                       f"power) is narrower than the output pixel (2/resolution = {pixel:.3g}, resolution "
                       f"{scene.grid.resolution}) at {_where(scene)} and is point-sampled: the albedo is off by up "
                       f"to {error:.2g} (relative); {fix}")
    return out


def _check_realization(model: str, scene) -> list[str]:
    """Warn when the expected statistics of a random realization on this grid differ from its
    ensemble's by more than STATISTICS_TOLERANCE (the spectrum is cut at the grid's Nyquist)."""
    surface = scene.surface
    ensemble = surface.ensemble
    if ensemble is None or ensemble.rms_height_um == 0:
        return []
    realized = ensemble.sampled_statistics(surface.cells, surface.size_um)
    wanted = ensemble.grid_statistics()
    worst = max(abs(realized[key] / wanted[key] - 1) for key in wanted)
    if worst <= STATISTICS_TOLERANCE:
        return []
    cells = ensemble.minimal_cells(surface.size_um, STATISTICS_TOLERANCE, start=surface.cells)
    names = {"correlation_x_um": "correlation length along x (µm)", "correlation_y_um": "along y (µm)",
             "rms_slope": "rms slope"}
    pairs = ", ".join(f"{names[key]} {realized[key]:.3g} vs {wanted[key]:.3g}" if np.isfinite(realized[key])
                      else f"{names[key]} beyond the patch (the autocorrelation stays above 1/e) vs {wanted[key]:.3g}"
                      for key in wanted)
    return [f"{model}: the realization on {surface.cells} cells of {surface.spacing_um:.4g} µm does not have the "
            f"requested statistics (expected on this grid vs the ensemble: {pairs}; tolerance "
            f"{STATISTICS_TOLERANCE:.0%}): " + (
                f"the grid cuts the spectrum at its Nyquist frequency; use surface.cells ≥ {cells}" if cells is not None
                else f"no finer grid reaches them on this {surface.size_um} µm patch (too few correlation lengths: "
                     "finite size); use a larger surface.size_um")]


def check_sampling(model: str, flags, scene) -> list[str]:
    """The sampling validity of ``scene`` for a model with ``flags`` (:data:`SAMPLING_FLAGS`):
    raises ValueError (naming the keys and the fix) where the figure would be wrong beyond repair,
    returns the warnings (messages naming the number and the fix) otherwise. Runs nothing."""
    flags = set(flags)
    unknown = flags - set(SAMPLING_FLAGS)
    if unknown:
        raise ValueError(f"unknown sampling flags {sorted(unknown)}; known: {SAMPLING_FLAGS}")
    if not flags:
        return []
    figures = _SurfaceFigures.of(scene.surface)
    out = []
    if "lattice" in flags:
        out += _check_lattice(model, scene, figures)
    if "pixels" in flags:
        out += _check_pixels(model, scene, figures)
    if "realization" in flags:
        out += _check_realization(model, scene)
    return out


def geometric_limit_error(g: float) -> float:
    """Relative L2 (over the whole lobe) between the Kirchhoff lobe of a surface of Gaussian-
    correlated heights with roughness parameter g = (2k₁σ_h cos θ_i)² and its geometric-optics limit.

    Beckmann's series writes the diffuse lobe in v = k₁(ω_o − ω_i)·T as Σ_{m≥1} p_m G_m with
    Poisson weights p_m = e^{−g} g^m/m! (the m = 0 term, e^{−g}, is the coherent specular lobe)
    and G_m(v) = exp(−|v|²/4m)/m; geometric optics puts all the reflected power into G_g, the
    distribution of the slopes. Each G_m carries 4π and ∫G_a G_b = 4π/(a + b), so the error is
    exact in closed form; it depends on g alone, not monotonically (0.14 at g ≈ 3.5, a local
    maximum; 0.05 at g = 13.06; √6/(4g) for large g). Infinite where the series carries nothing (a
    mirror: the rays' lobe is all of the error)."""
    if g > ASYMPTOTIC_G:  # the sum needs ~(24√g)² terms; the asymptote is within 0.2 % beyond
        return float(np.sqrt(6.0) / (4.0 * g))
    from scipy.stats import poisson

    m = np.arange(1, int(g + 12.0 * np.sqrt(g) + 20.0), dtype=float)
    p = poisson.pmf(m, g)
    beckmann = float(np.sum(np.outer(p, p) / np.add.outer(m, m)))
    if not beckmann > 0:
        return float("inf")
    cross = float(np.sum(p / (m + g)))
    return float(np.sqrt(max(beckmann - 2.0 * cross + 0.5 / g, 0.0) / beckmann))


def geometric_optics_figures(scene) -> dict:
    """What decides whether rays describe ``scene``: the roughness parameter g, the coherent
    specular share e^{−g} (of Gaussian heights), :func:`geometric_limit_error`, and the heights'
    correlation length (1/e) over λ₁ (NaN where they do not decorrelate within the patch). Empty
    for a flat surface (a mirror, which rays describe)."""
    figures = _SurfaceFigures.of(scene.surface)
    if figures["flat"]:
        return {}
    lambda1 = scene.wavelength_um / scene.exterior_index
    g = roughness_parameter(scene, figures["rms_height_um"])
    return {"roughness_g": g, "coherent_share": float(np.exp(-g)), "geometric_limit_error": geometric_limit_error(g),
            "correlation_over_wavelength": figures["correlation_um"] / lambda1}


GO_ADVICE = "use a wave rung (kirchhoff, ghs, po) or model = auto, which measures the rungs against the full wave"
GO_DIFFRACTION_ADVICE = "use bem or model = auto"


def under_auto(message: str) -> str:
    """A rung's warning as ``auto`` reports it: advice to use ``auto`` becomes what changes its
    choice (the ray rungs' :func:`check_geometric_optics`)."""
    took = "auto took this ray rung by its rule; a lower [model] tolerance, or "
    return message.replace(GO_ADVICE, took + "a wave rung (kirchhoff, ghs, po), avoids it").replace(
        GO_DIFFRACTION_ADVICE, took + "bem, avoids it")


def check_geometric_optics(model: str, scene) -> list[str]:
    """Warn where a ray rung's figure is outside geometric optics: a lobe predicted more than
    GO_LOBE_ERROR from the Kirchhoff lobe it is the limit of (:func:`geometric_limit_error`), or
    heights that decorrelate within less than λ₁ (relief that diffracts rather than reflects rays:
    on every such surface of the trade table gs and gm were 0.13–1.9 off the full wave,
    solver/data/trade.csv; a sinusoid's 1/e length is 0.19 of its period)."""
    figures = geometric_optics_figures(scene)
    if not figures:
        return []
    lambda1 = scene.wavelength_um / scene.exterior_index
    fix = GO_ADVICE
    out = []
    error, g = figures["geometric_limit_error"], figures["roughness_g"]
    if error > GO_LOBE_ERROR:
        spoken = f"≈ {error:.2g}" if error < 10 else "≫ 1"
        out.append(f"{model}: geometric optics is the large-roughness limit (g ≫ 1) of the Kirchhoff lobe, and at "
                   f"{_where(scene)} this surface has g = (2k₁σ_h cos θ_i)² = {g:.3g} (rms height "
                   f"{_SurfaceFigures.of(scene.surface)['rms_height_um']:.3g} µm): the wave keeps about e^−g = "
                   f"{figures['coherent_share']:.2g} of the reflected power in the coherent specular lobe and "
                   f"spreads the rest as Beckmann's series, whose lobe differs from the rays' by {spoken} "
                   f"(relative L2 for Gaussian-correlated heights; above {GO_LOBE_ERROR:g} wherever g < 13); {fix}")
    ratio = figures["correlation_over_wavelength"]
    if ratio < 1.0:
        out.append(f"{model}: the surface's heights decorrelate (to 1/e) within {ratio * lambda1:.3g} µm, less than "
                   f"λ₁ = {lambda1:.3g} µm, at {_where(scene)}: relief on a scale below the wavelength diffracts "
                   "rather than reflecting rays (on every such surface of the trade table, gs and gm were 0.13–1.9 "
                   "off the full wave, the worst of s, p and unpolarized; 0.07–1.6 unpolarized; docs/approx.md); "
                   + GO_DIFFRACTION_ADVICE)
    return out


def steered_fresnel_warning(model: str, kept: str, basic_scene, theta_i: float, phi_i: float,
                            polarizations: tuple[str, ...]) -> str | None:
    """The warning of a synthesis (jobs/steering.py) from a rung whose Fresnel factors follow the
    incident direction (``Model.steered_fresnel``: ``kept`` "incidence" or "half vector"), not each
    plane wave of the beam: steered from the basic direction ω_b to ω_i = (θ_i, φ_i) (radians) it
    keeps ω_b in them. On a flat patch of the material of ``basic_scene`` the angle they are taken
    at is θ_b, or at the half vector of ω_b and ω_i's mirror direction arccos √((1 + ω_b·ω_o)/2),
    which lies between θ_b and θ_i (so its figure is a lower bound for such a rung). The figure is
    the largest |ln(R(kept)/R(θ_i))| over ``polarizations`` (of "unpolarized", "s", "p": those the
    study stores); None below ln(1 + STEERED_FRESNEL)."""
    from wavebrdf.solver.farfield import direction
    from wavebrdf.solver.fresnel import fresnel_reflectance

    angle = float(basic_scene.theta_i)
    if kept == "half vector":  # ω_b and the mirror direction of ω_i, (θ_i, φ_i + π)
        cosine = (1.0 + direction(basic_scene.theta_i, basic_scene.phi_i) @ direction(theta_i, phi_i + np.pi)) / 2.0
        angle = float(np.arccos(np.sqrt(np.clip(cosine, 0.0, 1.0))))
    eta = complex(basic_scene.index) / basic_scene.exterior_index
    (rs_k, rp_k), (rs, rp) = (fresnel_reflectance(eta, np.cos(t)) for t in (angle, theta_i))
    pairs = {"unpolarized": (rs_k + rp_k, rs + rp), "s": (rs_k, rs), "p": (rp_k, rp)}
    tiny = np.finfo(float).tiny
    logs = {k: abs(float(np.log(max(pairs[k][0], tiny) / max(pairs[k][1], tiny)))) for k in polarizations}
    which = max(logs, key=logs.get)
    if not logs[which] > np.log1p(STEERED_FRESNEL):
        return None
    ratio = max(pairs[which][0], tiny) / max(pairs[which][1], tiny)
    amount = f"{ratio:.3g} times" if not 0.5 < ratio < 2.0 else f"{ratio - 1.0:+.0%} of"
    where = (f"θ_b = {np.rad2deg(basic_scene.theta_i):.3g}°" if kept == "incidence" else
             f"the half vector of ω_b and the mirror direction, {np.rad2deg(angle):.3g}° on a flat patch (the figure "
             "follows an angle between it and θ_b: this is the least it is off)")
    return (f"{model}: steered from its basic direction θ_b = {np.rad2deg(basic_scene.theta_i):.3g}° to θ_i = "
            f"{np.rad2deg(theta_i):.3g}°, it keeps the basic direction in its Fresnel factors (taken at the "
            f"{kept}, not per plane wave of the beam): at {where} a flat patch of this material reflects "
            f"({which}) {amount} what it reflects at θ_i; use a smaller [steering] hexagon_fill (more basic "
            "directions, smaller offsets), the full wave (bem), or po with incidence = \"beam\"")
