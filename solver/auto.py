"""``[model] name = "auto"``: the cheapest rung expected to meet a tolerance, per scene.

Modelling only what a scene requires, in three steps (docs/auto.md):

1. **Measure the scene** (:func:`measure_scene`): rms height/λ, rms and max slope, correlation
   length/λ and waist/λ from the height field; the shadowed fraction at θ_i and the share of the
   reflected energy that leaves after two or more reflections, from a short geometric-optics pilot
   (:data:`PILOT_RAYS` paths of the NumPy tracer — the same numbers in ``plan`` and ``run``); the
   material's index contrast and polarization contrast (the least R_p/R_s over the incidences the
   light meets), the share of the spectrum near grazing.
2. **Predict each rung's error** (:class:`Rule`), the relative L2 over the lobe of the
   speckle-averaged BRDF against the full-wave reference, the worst of s, p and unpolarized
   (:func:`table_error`: ``rel_l2_smooth``, ``_s`` and ``_p`` of ``wavebrdf compare``), by a
   per-rung least-squares fit of log₁₀(error) on the features, over the trade table of record
   (``solver/data/trade.csv``, written by ``benchmarks/trade.py``; docs/trade.md), shifted up by
   the rung's margin: the largest residual over the table's rows and over each scene config's rows
   under the fit without that config.
   A single-scattering rung is never predicted below the multiple-scattering share it omits.
   Rungs the table does not cover are not predicted (not chosen).
3. **Choose and check**: the cheapest rung (by its own :meth:`Model.estimate`) whose predicted
   error is within ``tolerance``; none: the full-wave BEM (AIM) where it fits 80 % of the node's RAM,
   else the approximation predicted best, said so. At run time an escalation check runs
   the next rung up (the cheapest rung predicted more accurate, BEM excepted) and the chosen one
   on a coarse grid of sentinel directions and escalates while they differ by more than the
   tolerance.

In a study of many tasks the rule only chooses what to measure: the batch layer (jobs/spot_checks.py)
adds **spot checks**, tasks chosen by :func:`select_spot_checks` to span the study (extremes of λ
and θ_i, the steepest sub-areas) within a stated share of the all-full-wave cost (at both ends of
the spectrum, checks as oblique and as steep as every task there whose full wave fits, whatever
the share), each running the full wave and every cheaper candidate rung on its scene
(:meth:`AutoModel.spot_check`). Every other
task then runs the cheapest rung whose *measured* error on the checks that represent it, times a
margin, is within the tolerance (:meth:`AutoModel.run_checked`); one rung per (case, direction or
sub-area) across wavelengths unless ``mix_wavelengths``.

The choice and its reason are the result's diagnostics ``model`` and ``model_reason`` (the
dataset's task table); ``estimate`` is the chosen rung's plus the pilot and the check, and its
detail names the choice, the predicted error and the cost of the full-wave run avoided. When no
rung can meet the tolerance within the task's memory budget, or a one-task study relies on the rule
above the tolerances its bounds were measured at (:data:`VALIDATED_TOLERANCE`), a
:class:`ToleranceWarning` says so (run log, task table, ``plan``, ``inspect``).
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import hashlib
import json
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from wavebrdf.solver.metrics import worst_speckle_error
from wavebrdf.solver.models import (Capabilities, Estimate, Model, ModelsWith, SurfaceScene, get_model, model_class,
                                    model_names, rungs)
from wavebrdf.solver.options import option
from wavebrdf.solver.precision import Precision
from wavebrdf.solver.validity import LIT_FACET_SLACK, horizon_loss, recorded_warnings, under_auto

__all__ = ["AutoModel", "CheckUnit", "Choice", "Rule", "SceneFeatures", "ToleranceWarning", "check_slope", "choose",
           "measure_scene", "polarization_contrast", "select_spot_checks", "table_error", "TRADE_TABLE"]

TRADE_TABLE = Path(__file__).parent / "data" / "trade.csv"
ERROR_COLUMNS = {"unpolarized": "rel_l2_smooth", "s": "rel_l2_smooth_s", "p": "rel_l2_smooth_p"}  # speckle_errors' keys →
# the trade table's columns: the tolerance bounds all three
PILOT_RAYS = 1 << 14
PILOT_SECONDS = 0.5  # the pilot and the scene statistics, measured 0.3–2 s on the trade suite (2 cores)
SENTINEL_RESOLUTION = 32
REFERENCE = "bem"
# rungs whose paths end after one reflection: they miss the energy of longer paths
SINGLE_SCATTERING = ModelsWith("single_scattering")
PLANE_WAVE_WAIST = 100.0  # waist/λ a plane wave (waist None) counts as in the rule
GRAZING_FLOOR = 1e-3  # grazing shares below it count as it: nothing grazes, the other regressors decide
POLARIZATION_FLOOR = 1e-3  # R_p/R_s below it counts as it (at Brewster's angle R_p is 0)
ERROR_CEILING = 0.3  # the rule bounds errors up to this (a rung measured worse need only be predicted ≥ it)
CENSORED_STEPS = 50  # Newton steps of the censored least squares at most (the trade table's 360 fits: ≤ 7)
MIN_ROWS_PER_REGRESSOR = 4  # table rows a rung needs per regressor to be fitted (with 3.4, stam's 34 rows, its fit
# without the smooth random aluminium config predicted 0.039 at λ 0.7 µm, θ_i 0°, measured 0.084: tests/test_auto.py)
MATERIAL_SLACK = 1.5  # a material is like the table's within this factor of their |Re ε| (gold at λ 0.6 µm, Re ε −8.0
# against aluminium's −22…−60: the tangent-plane rungs measured 0.56–0.63 on steep hemispheres at waist 4.2 λ where the
# rule fitted on aluminium and glass bounds them at 0.30–0.36, aluminium's measuring 0.26–0.29 there; benchmarks/
# auto_at_scale.py single --material gold --wavelength 0.6, and without --material)
VALIDATED_TOLERANCE = 0.05  # the one-task rule's picks were measured within on scenes off its table up to this (the
# table's 25 configs left out of the fit in turn, benchmarks/trade.py; the second suite of tests/test_auto.py); above
# it they missed on a config left out: at 0.1 ghs on smooth glass at 30° (0.107), at 0.2 and 0.25 ohs on the shallow
# grating at waist 5 λ, θ_i 30°, whose order +1 leaves at grazing (0.441; docs/trade.md): a pick above it is said,
# not relied on silently
CHECKED_RUNG_SHARE = 0.25  # a spot check measures the candidate rungs estimated at most this share of the full wave


class ToleranceWarning(UserWarning):
    """``auto``'s figure may miss its tolerance: no rung can meet it within the task's memory budget,
    or a one-task study relies on the rule above :data:`VALIDATED_TOLERANCE`."""


@dataclass(frozen=True)
class SceneFeatures:
    """What ``auto`` measures of one scene (dimensionless; angles in degrees)."""

    theta_i_deg: float
    height_over_wavelength: float
    rms_slope: float
    max_slope: float
    correlation_over_wavelength: float
    waist_over_wavelength: float
    shadowed: float
    multi_bounce: float
    index_contrast: float  # |n₂| / n₁ of the material below the surface
    polarization_contrast: float  # the least R_p/R_s over the incidences the light meets (:func:`polarization_contrast`)
    grazing_share: float  # of the phase-screen spectrum near grazing (:func:`grazing_share`)
    permittivity: float  # real part of (n₂/n₁)²: below 0 a metal, above a dielectric (not a regressor: Rule.uncovered)

    REGRESSORS = ("1", "log10 σ/λ", "rms slope", "sin²θ_i", "multi-bounce", "shadowed", "log10 w/λ",
                  "log10 |n₂|/n₁", "log10 Rp/Rs", "log10 grazing share")

    def regressors(self) -> np.ndarray:
        """The rule's regressors: 1, log₁₀(σ/λ) (floored at 10⁻⁴), rms slope, sin²θ_i,
        multiple-bounce share, shadowed fraction, log₁₀(waist/λ) (a plane wave counts as
        :data:`PLANE_WAVE_WAIST` wavelengths), log₁₀ of the index contrast, log₁₀ of the
        polarization contrast (floored at :data:`POLARIZATION_FLOOR`), log₁₀ of the grazing share
        (floored at :data:`GRAZING_FLOOR`)."""
        return np.array([1.0, np.log10(max(self.height_over_wavelength, 1e-4)), self.rms_slope,
                         np.sin(np.radians(self.theta_i_deg)) ** 2, self.multi_bounce, self.shadowed,
                         np.log10(min(self.waist_over_wavelength, PLANE_WAVE_WAIST)),
                         np.log10(max(self.index_contrast, 1.0)),
                         np.log10(max(self.polarization_contrast, POLARIZATION_FLOOR)),
                         np.log10(max(self.grazing_share, GRAZING_FLOOR))])

    def describe(self) -> str:
        return (f"σ/λ {self.height_over_wavelength:.3g}, rms slope {self.rms_slope:.3g}, max slope "
                f"{self.max_slope:.3g}, θ_i {self.theta_i_deg:.0f}°, shadowed {self.shadowed:.3g}, "
                f"multi-bounce {self.multi_bounce:.3g}, waist {self.waist_over_wavelength:.3g} λ, "
                f"|n₂|/n₁ {self.index_contrast:.3g}, R_p/R_s ≥ {self.polarization_contrast:.3g}, grazing share "
                f"{self.grazing_share:.3g}")


FEATURES = tuple(f.name for f in dataclasses.fields(SceneFeatures))
OPTIONAL_REGRESSORS = ("log10 grazing share",)  # a rung's fit takes them where they bound left-out scenes better


def measure_scene(scene: SurfaceScene) -> SceneFeatures:
    """:class:`SceneFeatures` of ``scene``: height-field statistics and a geometric-optics pilot
    (NumPy tracer, :data:`PILOT_RAYS` paths up to 16 reflections, weighted by the scene's own
    material's Fresnel coefficients)."""
    from wavebrdf.solver.approx.raytrace import trace_paths

    stats = scene.surface.statistics()
    lam = scene.wavelength_um / scene.exterior_index
    correlation = np.nanmin([stats["correlation_length_x_um"], stats["correlation_length_y_um"], np.inf])
    double = scene if scene.precision.fp64 else dataclasses.replace(scene, precision=Precision.DOUBLE)
    trace = trace_paths(None, double, rays=PILOT_RAYS, max_depth=16, keep=False)  # the NumPy twin is double
    escaped = trace.escaped_by_depth.mean(axis=0)
    multi = float(escaped[2:].sum() / escaped.sum()) if escaped.sum() > 0 else 0.0
    return SceneFeatures(
        theta_i_deg=float(np.degrees(scene.theta_i)),
        height_over_wavelength=stats["rms_height_um"] / lam,
        rms_slope=stats["rms_slope"],
        max_slope=stats["max_slope"],
        correlation_over_wavelength=float(correlation / lam),
        waist_over_wavelength=float((scene.waist_um or np.inf) / lam),
        shadowed=float(trace.shadowed_fraction),
        multi_bounce=multi,
        index_contrast=float(abs(complex(scene.index)) / scene.exterior_index),
        polarization_contrast=polarization_contrast(scene, stats["rms_slope"]),
        grazing_share=grazing_share(scene),
        permittivity=float(((complex(scene.index) / scene.exterior_index) ** 2).real),
    )


def polarization_contrast(scene: SurfaceScene, rms_slope: float) -> float:
    """The least ratio R_p/R_s of the material's flat-interface power reflectances
    (solver/fresnel.py) over the incidences the scene's light meets: θ_i ± the footprint's angular
    spread λ/(πw) (a plane wave: none) widened by the rms slope's angle, within [0°, 89°]. Near a
    dielectric's Brewster angle it falls toward 0: the p-polarized BRDF is small there, and every
    rung's relative error in p large."""
    from wavebrdf.solver.fresnel import fresnel_reflectance

    lam = scene.wavelength_um / scene.exterior_index
    spread = (lam / (np.pi * scene.waist_um) if scene.waist_um else 0.0) + np.arctan(rms_slope)
    theta = np.linspace(max(scene.theta_i - spread, 0.0), min(scene.theta_i + spread, np.radians(89.0)), 181)
    r_s, r_p = fresnel_reflectance(complex(scene.index) / scene.exterior_index, np.cos(theta))
    ratio = np.divide(r_p, r_s, out=np.ones_like(r_s), where=r_s > 0)  # index-matched: nothing reflects, no contrast
    return float(np.min(ratio))


GRAZING_BAND = (np.sin(np.radians(70.0)), 1.06)  # |k∥|/k: within 20° of grazing, and just evanescent
GRAZING_BINS_PER_K = 50  # spectral bins per k the phase screen is zero-padded to (the band is 6 wide)


def grazing_share(scene: SurfaceScene) -> float:
    """Share of the scene's tangent-plane spectrum in the grazing band: the patch's phase screen
    exp(2jk cosθ_i h) under the beam's footprint (a Gaussian of the waist, elongated by 1/cosθ_i
    along the plane of incidence; a plane wave: of a third of the patch), zero-padded to
    :data:`GRAZING_BINS_PER_K` bins per k, Fourier transformed and shifted by the incident k∥; the
    power with |k∥| in :data:`GRAZING_BAND` (k of the exterior medium) over the power with |k∥| up
    to its top. Light scattered there is where the
    tangent-plane rungs miss what the full wave has: Rayleigh anomalies of periodic surfaces,
    shadowing and multiple scattering at grazing exit, coupling to evanescent orders."""
    surface = scene.surface
    n = surface.z.shape[0]
    x = (np.arange(n) - (n - 1) / 2) * surface.spacing_um
    x, y = np.meshgrid(x, x, indexing="ij")
    k = 2 * np.pi * scene.exterior_index / scene.wavelength_um
    cos_i = np.cos(scene.theta_i)
    along = x * np.cos(scene.phi_i) + y * np.sin(scene.phi_i)
    across = -x * np.sin(scene.phi_i) + y * np.cos(scene.phi_i)
    waist = scene.waist_um or surface.size_um / 3
    footprint = -((along * cos_i) ** 2 + across ** 2) / waist ** 2
    screen = np.exp(footprint + 2j * k * cos_i * (surface.z - surface.z.mean()))
    size = max(n, int(np.ceil(GRAZING_BINS_PER_K * 2 * np.pi / (k * surface.spacing_um))))
    power = np.abs(np.fft.fft2(screen, s=(size, size))) ** 2
    frequencies = 2 * np.pi * np.fft.fftfreq(size, surface.spacing_um)
    kx = frequencies[:, None] + k * np.sin(scene.theta_i) * np.cos(scene.phi_i)
    ky = frequencies[None, :] + k * np.sin(scene.theta_i) * np.sin(scene.phi_i)
    s = np.hypot(kx, ky) / k
    low, high = GRAZING_BAND
    total = power[s <= high].sum()
    return float(power[(s >= low) & (s <= high)].sum() / total) if total > 0 else 0.0


@dataclass(frozen=True)
class Rule:
    """Per rung: coefficients of log₁₀(error) on :meth:`SceneFeatures.regressors` and the margin
    added to every prediction; ``rows`` the number of table rows fitted; ``low``/``high`` the range
    of each regressor over them (outside it a prediction is the larger of the extrapolated one and
    the one at the nearest fitted point: never below either).

    The margin makes every row's prediction at least its measured error, or at least
    :data:`ERROR_CEILING` where that was measured above it (tolerances are below the ceiling, so
    such a rung is not chosen either way). It is the larger of two residuals (a jackknife margin):
    the largest over the table's rows under the whole fit, and the largest of each scene config's
    rows under the fit without that config — what a bound needs on scenes unlike any the fit has
    seen. With a single config there is nothing to leave out and the first alone is the margin.
    The regressor set is the one whose left-out residual is smaller, and that residual is the
    margin, so the choice itself is not left out. Rows the multiple-scattering floor of a
    single-scattering rung already covers impose nothing. How the rule bounds scenes it has not
    seen is measured by refitting it, margin included, without each config in turn
    (tests/test_auto.py, benchmarks/trade.py, docs/trade.md)."""

    coefficients: dict[str, np.ndarray]
    margin: dict[str, float]
    rows: dict[str, int]
    low: dict[str, np.ndarray]
    high: dict[str, np.ndarray]
    permittivity_ranges: dict[str, tuple[float, float]]  # "metal"/"dielectric" → the table's least and largest |Re ε|

    def uncovered(self, features: SceneFeatures) -> str | None:
        """Why the table has no material like the scene's (None: it has): its permittivity's real
        part must have the sign of a class the table measured (metal below 0, dielectric above) and
        a magnitude within that class's range widened by :data:`MATERIAL_SLACK` either way."""
        kind = "metal" if features.permittivity < 0 else "dielectric"
        if kind not in self.permittivity_ranges:
            return f"the trade table has no {kind} (Re ε {features.permittivity:.3g})"
        low, high = self.permittivity_ranges[kind]
        size = abs(features.permittivity)
        if size < low / MATERIAL_SLACK or size > high * MATERIAL_SLACK:
            return (f"Re ε {features.permittivity:.3g} is outside the trade table's {kind}s (|Re ε| {low:.3g}–{high:.3g}, "
                    f"×{MATERIAL_SLACK:g} either way)")
        return None

    @classmethod
    def fit(cls, table: list[dict], ridge: float = 1e-3) -> "Rule":
        """Least squares (with a small ridge; rows measured at or beyond :data:`ERROR_CEILING`
        censored there) of log₁₀(:func:`table_error`) per rung over the
        table's rows (dicts with the :data:`FEATURES` and ``model``; the reference's rows
        skipped); a rung with fewer than :data:`MIN_ROWS_PER_REGRESSOR` rows per regressor is not
        fitted (not predicted, not chosen). The :data:`OPTIONAL_REGRESSORS` enter a rung's fit only
        where they lower its margin measured on scenes left out: each scene config (the rows'
        ``config``, else their ``scene``) fitted without and predicted, the largest residual; the
        margin is the larger of that and the in-sample one."""
        coefficients, margin, rows, low, high = {}, {}, {}, {}, {}
        optional = np.isin(SceneFeatures.REGRESSORS, OPTIONAL_REGRESSORS)
        for name in sorted({r["model"] for r in table} - {REFERENCE}):
            mine = [r for r in table if r["model"] == name and np.isfinite(table_error(r))]
            if len(mine) < MIN_ROWS_PER_REGRESSOR * len(SceneFeatures.REGRESSORS):
                continue
            x = np.array([_features(r).regressors() for r in mine])
            measured = np.array([table_error(r) for r in mine])
            censored = measured >= ERROR_CEILING  # fitted and bounded at the ceiling: predicted at least it
            y = np.log10(np.clip(measured, 1e-6, ERROR_CEILING))
            bound = y.copy()  # what each row's prediction must reach
            if name in SINGLE_SCATTERING:  # where the multi-bounce floor reaches it, the fit need not
                floor = np.log10(np.maximum([_float(r["multi_bounce"]) for r in mine], 1e-12))
                bound = np.where(floor >= bound, -np.inf, bound)
            groups = np.array([r.get("config") or r.get("scene") for r in mine])
            used = ~optional
            left_out = _left_out_margin(x[:, used], y, censored, bound, groups, ridge)
            if optional.any():
                with_optional = _left_out_margin(x, y, censored, bound, groups, ridge)
                if with_optional < left_out:
                    used, left_out = np.ones_like(optional), with_optional
            w = np.zeros(len(optional))
            w[used] = _least_squares(x[:, used], y, censored, ridge)
            coefficients[name], rows[name] = w, len(mine)
            margin[name] = float(max(0.0, np.max(bound - x @ w), left_out))
            low[name], high[name] = x.min(axis=0), x.max(axis=0)
        permittivity = np.array([_float(r["permittivity"]) for r in table])
        ranges = {kind: (float(np.abs(values).min()), float(np.abs(values).max()))
                  for kind, values in (("metal", permittivity[permittivity < 0]),
                                       ("dielectric", permittivity[permittivity > 0])) if values.size}
        return cls(coefficients, margin, rows, low, high, ranges)

    def predict(self, name: str, features: SceneFeatures, central: bool = False) -> float:
        """Predicted error of rung ``name`` (NaN when the table does not cover it): the bound (fit
        plus margin) an unmeasured choice relies on, or with ``central`` the fit itself — what a
        measurement of the rung is expected to find."""
        if name == REFERENCE:
            return 0.0
        if name not in self.coefficients:
            return float("nan")
        x = features.regressors()
        nearest = np.clip(x, self.low[name], self.high[name])
        log_error = max(x @ self.coefficients[name], nearest @ self.coefficients[name])
        error = 10.0 ** (log_error + (0.0 if central else self.margin[name]))
        if name in SINGLE_SCATTERING:
            error = max(error, features.multi_bounce)
        return float(min(error, 10.0))


def _least_squares(x: np.ndarray, y: np.ndarray, censored: np.ndarray, ridge: float) -> np.ndarray:
    """Ridge least squares of ``y`` on ``x`` where the ``censored`` rows (measured at or beyond the
    ceiling, ``y`` the ceiling) cost only where predicted below their ``y``. The cost is convex and
    continuously differentiable: Newton steps, each the least squares on the rows that cost at the
    current fit and halved until the cost does not rise, end at a fit whose own costing rows are
    those it was solved on (the minimum), or where a step no longer lowers the cost (a censored
    row predicted at its ``y`` to rounding); past :data:`CENSORED_STEPS` the last fit, with a
    warning."""
    regularized = ridge * np.eye(x.shape[1])

    def costing(w: np.ndarray) -> np.ndarray:
        return ~censored | (x @ w < y)

    def cost(w: np.ndarray) -> float:
        residual = np.where(costing(w), y - x @ w, 0.0)
        return float(residual @ residual + ridge * w @ w)

    def solve(rows: np.ndarray) -> np.ndarray:
        return np.linalg.solve(x[rows].T @ x[rows] + regularized, x[rows].T @ y[rows])

    w = solve(np.ones(len(y), dtype=bool))
    for _ in range(CENSORED_STEPS):
        rows = costing(w)
        newton = solve(rows)
        if np.array_equal(costing(newton), rows):
            return newton
        step, now = 1.0, cost(w)
        while cost(w + step * (newton - w)) > now and step > 1e-6:
            step /= 2
        following = w + step * (newton - w)
        if cost(following) >= now:
            return w
        w = following
    warnings.warn(f"the rule's censored least squares did not settle in {CENSORED_STEPS} Newton steps; its last "
                  "fit is used", RuntimeWarning, stacklevel=2)
    return w


def _left_out_margin(x: np.ndarray, y: np.ndarray, censored: np.ndarray, bound: np.ndarray, groups: np.ndarray,
                     ridge: float) -> float:
    """The largest residual (``bound`` − prediction) of each group's rows under the fit without
    that group; −∞ with fewer than two groups (nothing to leave out)."""
    worst, names = -np.inf, np.unique(groups)
    for group in names if len(names) > 1 else ():
        out = groups == group
        fit = _least_squares(x[~out], y[~out], censored[~out], ridge)
        worst = max(worst, float(np.max(bound[out] - x[out] @ fit)))
    return worst


def _float(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")


def table_error(row: dict) -> float:
    """A trade-table row's error as ``auto``'s tolerance reads it: the worst of its speckle-averaged
    relative L2 errors unpolarized, for s and for p (:data:`ERROR_COLUMNS`;
    :func:`~wavebrdf.solver.metrics.worst_speckle_error`); NaN where one is missing."""
    return worst_speckle_error({key: _float(row.get(column)) for key, column in ERROR_COLUMNS.items()})


def _features(row: dict) -> SceneFeatures:
    return SceneFeatures(**{k: _float(row[k]) for k in FEATURES})


def read_table(path: Path = TRADE_TABLE) -> list[dict]:
    """The trade table's rows; a table without the columns the rule needs is refused, naming them."""
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    missing = sorted({"model", *ERROR_COLUMNS.values(), *FEATURES} - set(rows[0] if rows else ()))
    if missing:
        raise ValueError(f"{path}: the trade table lacks column(s) {', '.join(missing)}; regenerate it with "
                         "benchmarks/trade.py")
    return rows


@functools.lru_cache(maxsize=1)
def default_rule() -> Rule:
    """The rule fitted to the committed trade table (:data:`TRADE_TABLE`), on first use."""
    rule = Rule.fit(read_table())
    if not rule.coefficients:
        raise ValueError(f"{TRADE_TABLE}: no rung has enough rows to fit auto's rule; regenerate it with "
                         "benchmarks/trade.py")
    return rule


@dataclass(frozen=True)
class Choice:
    """The rung chosen for a scene, its predicted error, every candidate's (predicted error,
    estimated seconds), the full-wave estimate avoided, and the reason in words."""

    model: str
    predicted_error: float
    candidates: dict[str, tuple[float, float]]
    avoided: Estimate | None
    reason: str
    within: bool = True  # false: no rung (the full wave included) can meet the tolerance within the budget
    unlike: str = ""  # why the trade table has no material like the scene's (then no prediction is relied on)
    unvalidated: bool = False  # a cheap rung picked by the rule's bound above VALIDATED_TOLERANCE


def candidate_models(scene: SurfaceScene) -> list[str]:
    """Registered surface rungs that can take ``scene`` (statistics rungs only with an ensemble;
    steerable rungs only where the scene must give coherent fields, vector-field rungs only where it
    must give Jones matrices)."""
    names = list(rungs("height_field"))
    if scene.surface.ensemble is not None:
        names += list(model_names("statistics"))
    if scene.coherent:
        names = [n for n in names if model_class(n).capabilities.steerable]
    if scene.polarimetric:
        names = [n for n in names if model_class(n).capabilities.vector_fields]
    usable = []
    for name in names:
        try:
            get_model(name).check(scene)
        except ValueError:
            continue
        usable.append(name)
    return usable


def memory_budget_bytes(scene: SurfaceScene | None = None) -> float:
    """Memory the full-wave fallback may use: the task's budget (``scene.memory_budget_bytes``: [run]
    memory_gb or the node's over the tasks at once, which AIM fits its settings to), else 80% of this
    machine's RAM (the same on every call, so ``plan`` and ``run`` agree on machines of one size)."""
    from wavebrdf.solver.resources import meminfo_bytes

    if scene is not None and scene.memory_budget_bytes is not None:
        return float(scene.memory_budget_bytes)
    return 0.8 * meminfo_bytes("MemTotal")


def budgeted(scene: SurfaceScene) -> SurfaceScene:
    """``scene`` with the memory budget the full wave fits its settings to (:func:`memory_budget_bytes`)."""
    if scene.memory_budget_bytes is not None:
        return scene
    return dataclasses.replace(scene, memory_budget_bytes=memory_budget_bytes())


def reference_model():
    """The full-wave rung ``auto`` falls back to (AIM: it fits the budgets the planner checks)."""
    return get_model(REFERENCE, {"method": "aim"})


def choose(scene: SurfaceScene, tolerance: float, rule: Rule | None = None,
           features: SceneFeatures | None = None, central: bool = False) -> Choice:
    """The cheapest candidate predicted within ``tolerance``; none (or the table has no material like
    the scene's, :meth:`Rule.uncovered`): the full-wave reference with the
    settings fitted to the task's memory budget, or, where the full-wave model cannot take the scene
    (its ValueError) or would not fit :func:`memory_budget_bytes`, the approximation predicted best —
    said so in the reason (``Choice.within`` false). ``central``: by the rule's fit without its
    margin (what spot checks are expected to measure; :meth:`Rule.predict`)."""
    rule = rule or default_rule()
    features = features or measure_scene(scene)
    scene = budgeted(scene)
    budget = memory_budget_bytes(scene)
    candidates, full_wave = {}, None
    for name in candidate_models(scene):
        try:
            estimate = (reference_model() if name == REFERENCE else get_model(name)).estimate(scene)
        except ValueError:  # e.g. AIM's grid limits: not a candidate for this scene
            continue
        if name == REFERENCE:
            if estimate.memory_bytes > budget:  # it could not run within the task's budget: not a candidate
                continue
            full_wave = estimate
        candidates[name] = (rule.predict(name, features, central), estimate.seconds)
    unlike = rule.uncovered(features)  # the fit has not seen such a material: no prediction is relied on
    fitting = [] if unlike else sorted((seconds, name) for name, (error, seconds) in candidates.items()
                                       if name != REFERENCE and np.isfinite(error) and error <= tolerance)
    avoided = "" if full_wave is None else (
        f"; avoided {REFERENCE} ≈ {full_wave.seconds:.3g} s, {full_wave.memory_bytes / 2**30:.2f} GiB")
    if fitting:
        seconds, name = fitting[0]
        error = candidates[name][0]
        how = "expected to measure" if central else "predicted"
        reason = (f"{name}: the cheapest rung {how} within tolerance {tolerance:g} ({how} {error:.3g}; "
                  f"{features.describe()}){avoided}")
        unvalidated = not central and tolerance > VALIDATED_TOLERANCE
        if unvalidated:
            reason += (f"; UNVALIDATED: the rule's bounds held on scenes off its table up to tolerance "
                       f"{VALIDATED_TOLERANCE:g} only (above it they missed on a grating and on smooth glass left out)")
        return Choice(name, error, candidates, full_wave, reason, unvalidated=unvalidated)
    best = min(((e, n) for n, (e, _) in candidates.items() if n != REFERENCE and np.isfinite(e)), default=None)
    closest = f"; best approximation {best[1]} predicted {best[0]:.3g}" if best else ""
    none = (f"no rung's prediction is relied on: {unlike}" if unlike
            else f"no rung predicted within tolerance {tolerance:g}")
    if full_wave is not None:
        reason = f"{REFERENCE}: {none}{closest} ({features.describe()})"
        return Choice(REFERENCE, 0.0, candidates, None, reason, unlike=unlike or "")
    if best is None:
        raise ValueError(f"[model] name = \"auto\": no rung of the trade table can take this scene and {REFERENCE} "
                         f"cannot run it within {budget / 2**30:.1f} GiB; choose a model")
    reason = (f"{best[1]}: {none} and {REFERENCE} cannot take this "
              f"scene or exceeds the task's {budget / 2**30:.1f} GiB; the best approximation, predicted "
              f"{best[0]:.3g}{' (not relied on)' if unlike else ''} ({features.describe()})")
    return Choice(best[1], float("nan") if unlike else best[0], candidates, None, reason, within=False,
                  unlike=unlike or "")


def next_rung_up(choice: Choice, name: str) -> str | None:
    """The cheapest rung predicted more accurate than ``name`` (the reference excepted)."""
    error, seconds = choice.candidates[name]
    better = sorted((s, n) for n, (e, s) in choice.candidates.items()
                    if n not in (name, REFERENCE) and np.isfinite(e) and e < error)
    return better[0][1] if better else None


@dataclass(frozen=True)
class AutoOptions:
    tolerance: float = option(0.05, low=1e-4, high=ERROR_CEILING, high_open=True,
                              doc="relative L2 over the lobe (speckle-averaged; the worst of s, p and unpolarized) the "
                                  f"chosen rung must meet (the rule bounds errors below {ERROR_CEILING:g})")
    check: bool = option(True, doc="escalation check where no spot check represents a task: compare with the "
                                   "next rung up on sentinel directions")
    spot_check_share: float = option(0.1, low=0.0, high=1.0,
                                     doc="share of the all-full-wave estimate a study of several tasks spends on "
                                         "spot checks (full wave and candidate rungs on sampled tasks; the hardest "
                                         "task at each end of the spectrum, and any less oblique but steeper one, is "
                                         "checked whatever the share; 0: the rule alone)")
    margin: float = option(1.25, low=1.0, high=10.0,
                           doc="a rung is taken where its worst measured error times this is within the tolerance")
    mix_wavelengths: bool = option(False, doc="let a direction's (or sub-area's) rung change across wavelengths, each "
                                              "wavelength represented by the nearest checked one")


@dataclass(frozen=True)
class CheckUnit:
    """One task ``auto`` decides, as the spot-check selection sees it (θ_i in radians, λ in µm).
    ``series``: the tasks that share one rung across wavelengths (case and direction or sub-area)."""

    task: int
    series: tuple
    wavelength_um: float
    theta_i: float
    slope: float  # :func:`check_slope`
    full_wave_seconds: float
    full_wave_fits: bool


def check_slope(surface, theta_i: float, phi_i: float) -> float:
    """How steep a task's sub-area is as the spot-check selection ranks it (dimensionless): its rms
    slope, or at oblique incidence √2 × its rms slope along the plane of incidence where that is
    larger. An isotropic surface's in-plane rms slope is its rms slope / √2, so there the two agree;
    an anisotropic one lit across its grooves is harder than its rms slope says (shadowing and the
    spread of local incidence angles grow with the in-plane slope: a brushed aluminium patch at θ_i
    40°, docs/auto.md, measured kirchhoff 0.047 lit along its grooves and 0.135 across)."""
    total = surface.rms_slope()
    if theta_i <= 0.0:
        return total
    return max(total, np.sqrt(2.0) * surface.rms_slope_along(phi_i))


def select_spot_checks(units: list[CheckUnit], share: float, mix_wavelengths: bool = False
                       ) -> tuple[list[CheckUnit], dict[int, tuple[int, ...]]]:
    """The units to spot-check and, per unit, the indices (into that list) of the checks that
    represent it.

    Only units whose full wave fits are candidates ("the shortest λ" is the shortest of theirs).
    Candidates, hardest first: the hardest unit of the study (largest θ_i, then steepest), then θ_i
    largest, smallest, median × λ shortest, longest, each the steepest unit there (steepest by
    :func:`check_slope`: the sub-area's rms slope, or its slope in the plane of incidence, so that
    of several azimuths the one across an anisotropic surface's grooves counts), then the
    median-slope sub-area at (largest θ_i, shortest λ). At the shortest and at the longest λ the
    hardest unit (largest θ_i there, then the steepest) — and, where a less oblique one is steeper
    (by more than :data:`SLOPE_TIE`), the hardest of those, and so on, until every unit at that λ
    has a check as oblique and as steep as itself — are taken whatever the share (when ``share`` > 0
    and there are two units or more) and come first; the others follow in that order while all the
    checks' full-wave estimates add up to at most ``share`` of the all-full-wave estimate of the
    units where it fits.

    A unit is represented, at each checked λ, by the checks there at the nearest θ_i at or above its
    own and, among those, the nearest slope at or above its own (within :data:`SLOPE_TIE`; the
    tangent-plane rungs' errors grow with both) — or, with ``mix_wavelengths``, at the nearest
    checked λ only;
    a unit no check covers so (its own full wave does not fit, or it occurs at a middle λ only) by
    every check no other covers, the worst of them. Along λ an error may grow either way (with λ/ℓ
    where a rung's curvature limit binds, with h/λ where its phase does), so both ends of the
    spectrum are measured."""
    eligible = [u for u in units if u.full_wave_fits and np.isfinite(u.full_wave_seconds)]
    if len(units) < 2 or share <= 0 or not eligible:
        return [], {}
    lams = sorted({u.wavelength_um for u in eligible})
    thetas = sorted({u.theta_i for u in eligible})
    wanted = [(t, l) for t in (thetas[-1], thetas[0], thetas[len(thetas) // 2]) for l in (lams[0], lams[-1])]
    picked: list[CheckUnit] = [max(eligible, key=lambda u: (u.theta_i, u.slope, -u.wavelength_um, -u.task))]
    for theta, lam in wanted:
        at = [u for u in eligible if u.theta_i == theta and u.wavelength_um == lam]
        if at and (steepest := max(at, key=lambda u: (u.slope, -u.task))) not in picked:
            picked.append(steepest)
    hardest = sorted((u for u in eligible if u.theta_i == thetas[-1] and u.wavelength_um == lams[0]),
                     key=lambda u: (u.slope, u.task))
    if len({u.slope for u in hardest}) > 2 and hardest[len(hardest) // 2] not in picked:
        picked.append(hardest[len(hardest) // 2])
    always = [u for lam in sorted({lams[0], lams[-1]})
              for u in _staircase([u for u in eligible if u.wavelength_um == lam])]
    order = always + [u for u in picked if u not in always]
    budget = share * sum(u.full_wave_seconds for u in eligible)
    checks, spent = list(always), sum(u.full_wave_seconds for u in always)
    for unit in order[len(always):]:
        if spent + unit.full_wave_seconds <= budget:
            checks.append(unit)
            spent += unit.full_wave_seconds
    return checks, {u.task: _representatives(u, checks, mix_wavelengths) for u in units}


ROUNDING = 1e-12  # θ_i (rad), slopes and λ (µm) this close are equal
SLOPE_TIE = 0.05  # slopes within 5 % count as equal: an isotropic surface's in-plane slope moves by a few % with
#                   the azimuth by realization, which would otherwise force a check per azimuth


def _covers(check: CheckUnit, unit: CheckUnit) -> bool:
    """``check`` is as oblique and as steep as ``unit`` (θ_i to rounding, slopes within :data:`SLOPE_TIE`)."""
    return check.theta_i >= unit.theta_i - ROUNDING and check.slope * (1.0 + SLOPE_TIE) >= unit.slope


def _staircase(units: list[CheckUnit]) -> list[CheckUnit]:
    """Units that together cover every one of ``units``: the hardest (largest θ_i, then steepest),
    then the hardest of those it does not cover (less oblique, steeper), and so on."""
    out = []
    while units:
        top = max(units, key=lambda u: (u.theta_i, u.slope, -u.task))
        out.append(top)
        units = [u for u in units if not _covers(top, u)]
    return out


def _representatives(unit: CheckUnit, checks: list[CheckUnit], mix_wavelengths: bool) -> tuple[int, ...]:
    """Indices of the checks that represent ``unit`` (select_spot_checks): at every checked λ (with
    ``mix_wavelengths`` only the nearest checked λ), of the checks there that cover it, the nearest
    θ_i, then the nearest slope; none covers it (its own full wave does not fit, or it occurs only
    at a middle λ): every check no other one covers strictly, the most oblique to the steepest,
    whose worst measured error then stands for it (with ``mix_wavelengths`` those at the nearest
    checked λ). Without ``mix_wavelengths`` they do not depend on the unit's λ: one rung per series."""
    covering = [i for i, c in enumerate(checks) if _covers(c, unit)]
    if not covering:
        pool = [i for i, c in enumerate(checks) if not any(_covers(o, c) and not _covers(c, o) for o in checks)]
        return tuple(_nearest(pool, checks, (lambda c: abs(c.wavelength_um - unit.wavelength_um),)
                              if mix_wavelengths else ()))
    if mix_wavelengths:
        covering = _nearest(covering, checks, (lambda c: abs(c.wavelength_um - unit.wavelength_um),))
    out = []
    for lam in sorted({round(checks[i].wavelength_um, 9) for i in covering}):
        at = [i for i in covering if round(checks[i].wavelength_um, 9) == lam]
        out += _nearest(at, checks, (lambda c: c.theta_i, lambda c: c.slope))
    return tuple(sorted(out))


def _nearest(pool: list[int], checks: list[CheckUnit], keys) -> list[int]:
    """The indices of ``pool`` nearest by each key in turn (ties within :data:`ROUNDING` kept)."""
    for key in keys:
        nearest = min(key(checks[i]) for i in pool)
        pool = [i for i in pool if key(checks[i]) <= nearest + ROUNDING]
    return pool


class AutoModel(Model):
    """``[model] name = "auto"``: chooses a rung per scene (module docstring) and runs it. Steered
    sub-areas (``scene.coherent``) choose among steerable rungs, so it returns coherent fields
    there; elsewhere it returns what the chosen rung returns."""

    name = "auto"
    summary = ("the cheapest rung expected (one task) or measured on spot checks (a study of many) to meet "
               "[model] tolerance, chosen per task and run; the full wave where none is")
    capabilities = Capabilities(takes="height_field", returns="fields", polarized=True, steerable=True,
                                reciprocal=False, conserves_energy=False, spot_checks=True, picks_rung=True,
                                vector_fields=True)
    Options = AutoOptions
    run_warns_itself = True  # the rung that runs raises its own validity warnings (after any escalation)

    def __init__(self, options=None):
        super().__init__(options)
        self._rungs: dict[str, Model] = {}  # instances kept between scenes (an AIM operator, traced paths)

    def rung(self, name: str) -> Model:
        if name not in self._rungs:
            self._rungs[name] = reference_model() if name == REFERENCE else get_model(name)
        return self._rungs[name]

    def release(self) -> None:
        for model in self._rungs.values():
            model.release()
        self._rungs.clear()

    def choice(self, scene: SurfaceScene, checked: bool = False) -> Choice:
        """The rule's choice for ``scene`` (measured once per scene and tolerance in this process);
        ``checked``: for a task spot checks decide, the rung they are expected to measure within
        the tolerance (the rule's fit without its margin, times :attr:`AutoOptions.margin`) — what
        ``plan`` expects, while the run takes what the checks measure."""
        z = np.ascontiguousarray(scene.surface.z)
        key = (hashlib.sha1(z.tobytes()).hexdigest(), z.shape, scene.surface.size_um, scene.wavelength_um,
               complex(scene.index), scene.theta_i, scene.phi_i, scene.waist_um, scene.grid.resolution,
               scene.exterior_index, scene.memory_budget_bytes, scene.coherent, scene.polarimetric, scene.precision,
               scene.beam,
               scene.z_reference, scene.footprint_centre_um, repr(scene.surface.ensemble), self.options.tolerance,
               checked and self.options.margin)
        if key not in _CHOICES:
            if len(_CHOICES) > 4096:
                _CHOICES.clear()
            _CHOICES[key] = (choose(scene, self.options.tolerance / self.options.margin, central=True) if checked
                             else choose(scene, self.options.tolerance))
        return _CHOICES[key]

    def validity(self, scene, like: SurfaceScene | None = None) -> list[str]:
        """The sampling validity of the rung the rule expects for ``scene`` (or, given, for ``like``:
        the scene of a task spot checks decide, whose expected rung stands for it) — what ``plan``
        shows; spot checks and the escalation check may run others, each through its own validity."""
        if not isinstance(scene, SurfaceScene):
            return []
        return [under_auto(m) for m in
                self.rung(self.choice(like or scene, checked=like is not None).model).validity(scene)]

    def foreseen_warnings(self, scene, like: SurfaceScene | None = None) -> list[str]:
        """As :meth:`validity`: those of the rung the rule expects (for ``like``, given)."""
        if not isinstance(scene, SurfaceScene):
            return []
        return [under_auto(m) for m in
                self.rung(self.choice(like or scene, checked=like is not None).model).foreseen_warnings(scene)]

    def incident_fields(self, scene: SurfaceScene, points):
        """The full-wave reference's beam (a steered synthesis of mixed rungs divides each rung's
        sub-areas by the power of that rung's own summed beams: jobs/steering.py)."""
        return self.rung(REFERENCE).incident_fields(scene, points)

    def estimate(self, scene: SurfaceScene, like: SurfaceScene | None = None) -> Estimate:
        """The chosen rung's estimate, plus the pilot and the escalation check's coarse runs; with
        ``like`` (a task spot checks decide), the rung they are expected to measure within the
        tolerance for that scene (the first of its direction or sub-area: a series takes one rung)
        estimated on ``scene``, alone (the checks replace pilot and escalation)."""
        from wavebrdf.solver.farfield import HemisphereGrid

        if like is not None:
            choice = self.choice(like, checked=True)
            chosen = self.rung(choice.model).estimate(budgeted(scene))
            full = self.full_wave_estimate(scene)  # what runs where the checks measure no rung within tolerance
            reach = [chosen] + ([full] if full is not None and full.memory_bytes <= memory_budget_bytes(scene) else [])
            fit = (f"no prediction relied on: {choice.unlike}" if choice.unlike
                   else f"rule's fit {choice.predicted_error:.2g}")
            return dataclasses.replace(_largest_of(reach), detail=f"auto → {choice.model} (expected from the spot "
                                       f"checks; {fit}): {chosen.detail}")
        choice = self.choice(scene)
        chosen = self.rung(choice.model).estimate(budgeted(scene))
        extra = PILOT_SECONDS
        up = next_rung_up(choice, choice.model) if self.options.check and choice.model != REFERENCE else None
        if up is not None:
            coarse = dataclasses.replace(scene, grid=HemisphereGrid(SENTINEL_RESOLUTION))
            extra += self.rung(choice.model).estimate(coarse).seconds + self.rung(up).estimate(coarse).seconds
        # escalation may run any rung predicted more accurate: the memory to plan for is the largest
        reachable = [n for n, (e, _) in choice.candidates.items()
                     if n != REFERENCE and np.isfinite(e) and e < choice.candidates.get(choice.model, (0.0,))[0]]
        others = [self.rung(n).estimate(scene) for n in (reachable if self.options.check else [])]
        following = None if chosen.following_seconds is None else chosen.following_seconds + extra
        chosen = dataclasses.replace(_largest_of([chosen] + others), seconds=chosen.seconds + extra,
                                     following_seconds=following, detail=chosen.detail)
        avoided = "" if choice.avoided is None else (
            f"; avoids {REFERENCE} ≈ {choice.avoided.seconds:.3g} s, {choice.avoided.memory_bytes / 2**30:.2f} GiB")
        missed = "" if choice.within else f"; cannot meet tolerance {self.options.tolerance:g} within the budget"
        predicted = (f"no prediction relied on: {choice.unlike}" if choice.unlike
                     else f"predicted error {choice.predicted_error:.2g}")
        detail = (f"auto → {choice.model} ({predicted}{avoided}{missed}): "
                  f"{chosen.detail}")
        return dataclasses.replace(chosen, detail=detail)

    def plan_spot_checks(self, units: list[CheckUnit]) -> tuple[list[CheckUnit], dict[int, tuple[int, ...]]]:
        """:func:`select_spot_checks` with these options."""
        return select_spot_checks(units, self.options.spot_check_share, self.options.mix_wavelengths)

    def check_unit(self, task: int, series: tuple, scene: SurfaceScene) -> CheckUnit:
        """What :func:`select_spot_checks` needs of one task's scene."""
        full = self.full_wave_estimate(scene)
        fits = full is not None and full.memory_bytes <= memory_budget_bytes(scene)
        return CheckUnit(task, series, scene.wavelength_um, scene.theta_i,
                         check_slope(scene.surface, scene.theta_i, scene.phi_i),
                         full.seconds if full is not None else float("inf"), fits)

    def full_wave_estimate(self, scene: SurfaceScene) -> Estimate | None:
        """The full wave's estimate with the settings fitted to the task's budget (None: it cannot take
        the scene)."""
        try:
            return self.rung(REFERENCE).estimate(budgeted(scene))
        except ValueError:
            return None

    def checked_rungs(self, scene: SurfaceScene) -> list[str]:
        """The candidate rungs a spot check of ``scene`` measures: every approximation estimated at
        most :data:`CHECKED_RUNG_SHARE` of the full wave's time and within the task's memory budget,
        cheapest first."""
        choice = self.choice(scene)
        full = choice.avoided.seconds if choice.avoided is not None else choice.candidates.get(REFERENCE, (0, np.inf))[1]
        budget = memory_budget_bytes(scene)
        return [n for n, (_, seconds) in sorted(choice.candidates.items(), key=lambda kv: kv[1][1])
                if n != REFERENCE and seconds <= CHECKED_RUNG_SHARE * full
                and self.rung(n).estimate(scene).memory_bytes <= budget]

    def estimate_spot_check(self, scene: SurfaceScene) -> Estimate:
        """A spot check: the full wave and every checked rung on ``scene``."""
        full = self.full_wave_estimate(scene)
        if full is None:
            raise ValueError(f"{REFERENCE} cannot take this scene: no spot check of it")
        names = self.checked_rungs(scene)
        rungs = [self.rung(n).estimate(scene) for n in names]
        return dataclasses.replace(_largest_of([full] + rungs), seconds=full.seconds + sum(e.seconds for e in rungs),
                                   detail=f"spot check: {REFERENCE} + {', '.join(names) or 'no rung'}; {full.detail}")

    def spot_check(self, ctx, scene: SurfaceScene):
        """The full wave on ``scene`` (settings fitted to its budget) and every checked rung measured
        against it: relative L2 over the lobe per polarization and unpolarized, speckle-averaged
        (the footprint's spread λ₁/(πw)) and raw. Returns the full-wave result; its diagnostics
        ``spot_check`` hold the measured errors (JSON: rung → figures; ``error`` is the largest
        speckle-averaged one of s, p and unpolarized, the figure the choice uses; ``predicted`` the
        rule's bound beside it, left out for a material the rule relies on no prediction for)."""
        from wavebrdf.solver.metrics import speckle_errors, speckle_sigma_u

        scene = budgeted(scene)
        reference = self.rung(REFERENCE).run(ctx, scene)
        reference_sp = reference.brdf()
        self.rung(REFERENCE).release()  # the rungs run after it, not beside it
        sigma = speckle_sigma_u(scene.wavelength_um, scene.waist_um, scene.grid, scene.exterior_index)
        choice = self.choice(scene)
        measured = {}
        for name in self.checked_rungs(scene):
            started = time.process_time()
            try:
                with warnings.catch_warnings(record=True) as caught:  # the rung's warnings are not the result's
                    warnings.simplefilter("always")
                    result = self.rung(name).run(ctx, scene)
                # each rung's own power: a steered synthesis divides each rung's sub-areas by that of its own beams
                errors = speckle_errors(result.brdf(), reference_sp, scene.grid, sigma)
            except Exception as exc:  # noqa: BLE001 - a rung that fails here is not measured, not chosen
                measured[name] = {"error": None, "failure": f"{type(exc).__name__}: {exc}"[:300],
                                  "seconds": choice.candidates[name][1]}
                continue
            finally:
                self.rung(name).release()
            worst = worst_speckle_error(errors)
            measured[name] = {"error": worst if np.isfinite(worst) else None, **_finite(errors),
                              **({} if choice.unlike else _finite({"predicted": choice.candidates[name][0]})),
                              "seconds": choice.candidates[name][1],
                              "cpu_s": time.process_time() - started, "warnings": len(caught)}
        where = (f"λ {scene.wavelength_um:g} µm, θ_i {np.degrees(scene.theta_i):.3g}°, rms slope "
                 f"{scene.surface.rms_slope():.3g}")
        summary = ", ".join(f"{n} {m['error']:.3g}" if m["error"] is not None else f"{n} failed"
                            for n, m in measured.items())
        reference.diagnostics.update(model=REFERENCE, model_predicted_error=0.0, spot_check=json.dumps(measured),
                                     spot_check_where=where,
                                     model_reason=f"spot check at {where}: {REFERENCE}, and measured against it "
                                                  f"{summary or 'no rung'}")
        return reference

    def run_checked(self, ctx, scene: SurfaceScene, checks: list[dict], full_wave=None):
        """``scene`` with the cheapest rung whose worst measured error over ``checks`` (the
        diagnostics of the spot checks that represent it), times the margin, is within the
        tolerance; none: the full wave (``full_wave()``, when given, returns a check's result of this
        very scene instead of solving it again); where the full wave cannot run within the task's
        budget, the rung measured best, with a :class:`ToleranceWarning`."""
        scene = budgeted(scene)
        tolerance, margin = self.options.tolerance, self.options.margin
        measured = [json.loads(c["spot_check"]) for c in checks]
        where = "; ".join(c.get("spot_check_where", "?") for c in checks)
        rows = []
        for name in sorted(set(candidate_models(scene)) - {REFERENCE}):
            errors = [m[name]["error"] for m in measured if name in m]
            if len(errors) == len(measured) and None not in errors:
                rows.append((sum(m[name]["seconds"] for m in measured), name, max(errors)))
        within = sorted(r for r in rows if r[2] * margin <= tolerance)
        best = min(rows, key=lambda r: r[2], default=None)
        closest = f"; best measured {best[1]} {best[2]:.3g}" if best else ""
        if within:
            _, name, error = within[0]
            reason = (f"{name}: the cheapest rung measured within tolerance {tolerance:g} (worst {error:.3g} × margin "
                      f"{margin:g} over {len(checks)} spot check(s): {where})")
            outside: list = []
            name, result, reason = self._run_measured(ctx, scene, name, reason, outside)
            if outside:
                result.diagnostics["escalation_check_warnings"] = under_auto(recorded_warnings(outside))
            error = error if name != REFERENCE else 0.0
        elif (full := self.full_wave_estimate(scene)) is not None and full.memory_bytes <= memory_budget_bytes(scene):
            name, error = REFERENCE, 0.0
            reason = (f"{REFERENCE}: no rung measured within tolerance {tolerance:g} (margin {margin:g}) over "
                      f"{len(checks)} spot check(s) ({where}){closest}")
            result = full_wave() if full_wave is not None else self._only(REFERENCE).run(ctx, scene)
            result.diagnostics.pop("spot_check", None)
        elif best is not None:
            _, name, error = best
            reason = (f"{name}: no rung measured within tolerance {tolerance:g} over {len(checks)} spot check(s) "
                      f"({where}) and {REFERENCE} exceeds the task's {memory_budget_bytes(scene) / 2**30:.1f} GiB; "
                      f"the rung measured best ({error:.3g})")
            _warn_tolerance(reason)
            result = self._only(name).run(ctx, scene)
        else:
            return self.run(ctx, scene)
        result.diagnostics.update(model=name, model_reason=reason, model_measured_error=error, spot_checks=where)
        return result

    def _run_measured(self, ctx, scene: SurfaceScene, name: str, reason: str, set_aside: list,
                      warned: bool = False):
        """Run rung ``name``; where its own run measures it outside the tolerance — its albedo more
        than the tolerance plus :data:`~wavebrdf.solver.validity.LIT_FACET_SLACK` below one
        reflection off its lit facets, pixel sampling not explaining it (solver/validity.py
        ``horizon_loss``: on the trade table's 316 runs the measured error was never below that
        share by more than the slack) — run the full wave instead when it fits the task's budget
        (the rung's warnings then go to ``set_aside``), else warn that the tolerance is missed
        (unless ``warned``: a ToleranceWarning was given already). Returns (rung run, result, reason)."""
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            result = self._only(name).run(ctx, scene)
        loss = horizon_loss(result.diagnostics) if name != REFERENCE else None
        if loss is not None and loss > self.options.tolerance + LIT_FACET_SLACK:
            outside = (f"; {name}'s albedo measured {100 * loss:.0f} % below its lit facets' (its error is at least "
                       f"about that, beyond tolerance {self.options.tolerance:g})")
            full = self.full_wave_estimate(scene)
            if full is not None and full.memory_bytes <= memory_budget_bytes(scene):
                set_aside.extend(caught)
                reason += outside + f": escalated to {REFERENCE}"
                return REFERENCE, self._only(REFERENCE).run(ctx, scene), reason
            reason += outside + f" and {REFERENCE} cannot run within the task's budget"
            if not warned:
                _warn_tolerance(reason)
        for w in caught:  # the rung's own warnings, now the task's (in auto's words)
            text = under_auto(str(w.message))
            warnings.warn(w.message if text == str(w.message) else w.category(text), stacklevel=2)
        return name, result, reason

    def _only(self, name: str) -> Model:
        """Rung ``name``, the others released first (one rung's kept operator in memory at a time)."""
        for other, model in self._rungs.items():
            if other != name:
                model.release()
        return self.rung(name)

    def run(self, ctx, scene: SurfaceScene):
        from wavebrdf.solver.farfield import HemisphereGrid
        from wavebrdf.solver.metrics import speckle_errors, speckle_sigma_u

        scene = budgeted(scene)
        choice = self.choice(scene)
        name, reason = choice.model, choice.reason
        if not choice.within:
            _warn_tolerance(reason)
        elif choice.unvalidated:
            warnings.warn(f"auto relies on its rule beyond the tolerances it was validated at: {reason}",
                          ToleranceWarning, stacklevel=2)
        check_caught: list = []
        if self.options.check and name != REFERENCE:
            coarse = dataclasses.replace(scene, grid=HemisphereGrid(SENTINEL_RESOLUTION))
            sigma = speckle_sigma_u(scene.wavelength_um, scene.waist_um, coarse.grid, scene.exterior_index)
            coarse_brdf = {}

            def sentinel(n: str) -> np.ndarray:
                if n not in coarse_brdf:  # what the check's runs warn of is theirs (its coarse grid), not the task's
                    with warnings.catch_warnings(record=True) as caught:
                        warnings.simplefilter("always")
                        coarse_brdf[n] = self.rung(n).run(ctx, coarse).brdf()
                    check_caught.extend(caught)
                return coarse_brdf[n]

            if next_rung_up(choice, name) is None:
                reason += f"; no approximate rung predicted more accurate than {name}: nothing to check against"
            while (up := next_rung_up(choice, name)) is not None:
                differ = worst_speckle_error(speckle_errors(sentinel(name), sentinel(up), coarse.grid, sigma))
                if differ <= self.options.tolerance:
                    reason += f"; checked against {up} on {SENTINEL_RESOLUTION}² sentinel directions: differ {differ:.3g}"
                    break
                reason += f"; escalated to {up} ({name} and {up} differ by {differ:.3g} > {self.options.tolerance:g})"
                name = up
        name, result, reason = self._run_measured(ctx, scene, name, reason, check_caught, warned=not choice.within)
        if check_caught:
            result.diagnostics["escalation_check_warnings"] = under_auto(recorded_warnings(check_caught))
        result.diagnostics.update(model=name, model_reason=reason,
                                  model_predicted_error=(float("nan") if choice.unlike and name != REFERENCE
                                                         else choice.candidates.get(name, (0.0,))[0]))
        return result


def _finite(figures: dict) -> dict:
    """``figures`` with NaN and inf as None (JSON has neither)."""
    return {k: (float(v) if np.isfinite(v) else None) for k, v in figures.items()}


def _largest_of(estimates: list[Estimate]) -> Estimate:
    """An estimate whose memory and device figures are the largest of ``estimates`` (rungs run one
    after another in one task); time and detail those of the first."""
    def most(values):
        known = [v for v in values if v is not None]
        return max(known) if known else None

    return dataclasses.replace(estimates[0], memory_bytes=max(e.memory_bytes for e in estimates),
                               device_bytes=most(e.device_bytes for e in estimates),
                               largest_buffer_bytes=most(e.largest_buffer_bytes for e in estimates))


def _warn_tolerance(reason: str) -> None:
    warnings.warn(f"auto cannot meet its tolerance within the task's memory budget: {reason}", ToleranceWarning,
                  stacklevel=3)


_CHOICES: dict[tuple, Choice] = {}  # (the heights' digest, the scene's other inputs, tolerance) → Choice


def plan_summary(choices: list[Choice], chosen_seconds: list[float]) -> str:
    """One paragraph for ``wavebrdf plan``: rungs chosen, the estimated time of the chosen rungs and
    of the full-wave runs they avoid."""
    counts = {}
    for c in choices:
        counts[c.model] = counts.get(c.model, 0) + 1
    avoided = sum(c.avoided.seconds for c in choices if c.avoided is not None)
    spent = sum(s for c, s in zip(choices, chosen_seconds) if c.avoided is not None)
    picked = ", ".join(f"{n} ×{k}" for n, k in sorted(counts.items(), key=lambda kv: -kv[1]))
    text = f"auto: {picked}"
    if avoided:
        text += (f"; the approximate rungs ≈ {spent:.3g} s where {REFERENCE} would take ≈ {avoided:.3g} s "
                 f"({avoided / max(spent, 1e-9):.3g}× avoided)")
    worst = max((c.predicted_error for c in choices if np.isfinite(c.predicted_error)), default=0.0)
    text += f"; worst predicted error {worst:.2g}"
    unlike = [c for c in choices if c.unlike]
    if unlike:
        text += (f"\n{len(unlike)} of {len(choices)} task(s) of a material the trade table has not measured: no "
                 f"rung's prediction is relied on there ({unlike[0].unlike})")
    missed = sum(not c.within for c in choices)
    if missed:
        text += (f"\nWARNING: {missed} of {len(choices)} task(s) cannot meet the tolerance within the task's memory "
                 f"budget (no rung predicted within it, or none relied on, and {REFERENCE} does not fit): "
                 f"{next(c.reason for c in choices if not c.within)}")
    return text
