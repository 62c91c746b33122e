"""``[model] name = "auto"``: the cheapest rung expected to meet a tolerance, per scene.

Modelling only what a scene requires, in three steps (docs/auto.md):

1. **Measure the scene** (:func:`measure_scene`): rms height/λ, rms and max slope, correlation
   length/λ and waist/λ from the height field; the shadowed fraction at θ_i and the share of the
   reflected energy that leaves after two or more reflections, from a short geometric-optics pilot
   (:data:`PILOT_RAYS` paths of the NumPy tracer — the same numbers in ``plan`` and ``run``).
2. **Predict each rung's error** (:class:`Rule`), the relative L2 over the lobe of the
   speckle-averaged BRDF against the full-wave reference (``rel_l2_smooth`` of ``wavebrdf
   compare``), by a per-rung least-squares fit of log₁₀(error) on the features, over the trade table
   of record (``solver/data/trade.csv``, written by ``benchmarks/trade.py``; docs/trade.md), shifted
   up by the largest residual of the fit (on the table no prediction is below what was measured).
   A single-scattering rung is never predicted below the multiple-scattering share it omits.
   Rungs the table does not cover are not predicted (not chosen).
3. **Choose and check**: the cheapest rung (by its own :meth:`Model.estimate`) whose predicted
   error is within ``tolerance``; none: the full-wave BEM (AIM) where it fits 80 % of the node's RAM,
   else the approximation predicted best, said so. At run time an escalation check runs
   the next rung up (the cheapest rung predicted more accurate, BEM excepted) and the chosen one
   on a coarse grid of sentinel directions and escalates while they differ by more than the
   tolerance.

The choice and its reason are the result's diagnostics ``model`` and ``model_reason`` (the
dataset's task table); ``estimate`` is the chosen rung's plus the pilot and the check, and its
detail names the choice, the predicted error and the cost of the full-wave run avoided.
"""

from __future__ import annotations

import csv
import dataclasses
import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from wavebrdf.solver.models import Capabilities, Estimate, Model, SurfaceScene, get_model, model_names
from wavebrdf.solver.options import option

__all__ = ["AutoModel", "Choice", "Rule", "SceneFeatures", "choose", "measure_scene", "TRADE_TABLE"]

TRADE_TABLE = Path(__file__).parent / "data" / "trade.csv"
ERROR_COLUMN = "rel_l2_smooth"
PILOT_RAYS = 1 << 14
PILOT_SECONDS = 0.5  # the pilot and the scene statistics, measured 0.3–2 s on the trade suite (2 cores)
SENTINEL_RESOLUTION = 32
REFERENCE = "bem"
# rungs whose paths end after one reflection: they miss the energy of longer paths
SINGLE_SCATTERING = frozenset({"gs", "ohs", "ghs", "kirchhoff", "po", "stam", "ws-v"})


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

    REGRESSORS = ("1", "log10 σ/λ", "rms slope", "sin²θ_i", "multi-bounce", "shadowed")

    def regressors(self) -> np.ndarray:
        """The rule's regressors: 1, log₁₀(σ/λ) (floored at 10⁻⁴), rms slope, sin²θ_i,
        multiple-bounce share, shadowed fraction."""
        return np.array([1.0, np.log10(max(self.height_over_wavelength, 1e-4)), self.rms_slope,
                         np.sin(np.radians(self.theta_i_deg)) ** 2, self.multi_bounce, self.shadowed])

    def describe(self) -> str:
        return (f"σ/λ {self.height_over_wavelength:.3g}, rms slope {self.rms_slope:.3g}, max slope "
                f"{self.max_slope:.3g}, θ_i {self.theta_i_deg:.0f}°, shadowed {self.shadowed:.3g}, "
                f"multi-bounce {self.multi_bounce:.3g}")


FEATURES = tuple(f.name for f in dataclasses.fields(SceneFeatures))


def measure_scene(scene: SurfaceScene) -> SceneFeatures:
    """:class:`SceneFeatures` of ``scene``: height-field statistics and a geometric-optics pilot
    (NumPy tracer, :data:`PILOT_RAYS` paths up to 16 reflections, weighted by the scene's own
    material's Fresnel coefficients)."""
    from wavebrdf.solver.approx.raytrace import trace_paths

    stats = scene.surface.statistics()
    lam = scene.wavelength_um / scene.exterior_index
    correlation = np.nanmin([stats["correlation_length_x_um"], stats["correlation_length_y_um"], np.inf])
    double = scene if scene.precision == "double" else dataclasses.replace(scene, precision="double")
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
    )


@dataclass(frozen=True)
class Rule:
    """Per rung: coefficients of log₁₀(error) on :meth:`SceneFeatures.regressors` and the margin
    (largest residual) added to every prediction; ``rows`` the number of table rows fitted."""

    coefficients: dict[str, np.ndarray]
    margin: dict[str, float]
    rows: dict[str, int]

    @classmethod
    def fit(cls, table: list[dict], ridge: float = 1e-3) -> "Rule":
        """Least squares (with a small ridge) of log₁₀(:data:`ERROR_COLUMN`) per rung over the
        table's rows (dicts with the :data:`FEATURES` and ``model``; the reference's rows skipped)."""
        coefficients, margin, rows = {}, {}, {}
        for name in sorted({r["model"] for r in table} - {REFERENCE}):
            mine = [r for r in table if r["model"] == name and np.isfinite(_float(r.get(ERROR_COLUMN)))]
            if len(mine) < 2 * len(SceneFeatures.REGRESSORS):  # too few rows to fit and bound the residual
                continue
            x = np.array([_features(r).regressors() for r in mine])
            y = np.log10(np.maximum([_float(r[ERROR_COLUMN]) for r in mine], 1e-6))
            a = x.T @ x + ridge * np.eye(x.shape[1])
            w = np.linalg.solve(a, x.T @ y)
            coefficients[name], margin[name], rows[name] = w, float(max(0.0, np.max(y - x @ w))), len(mine)
        return cls(coefficients, margin, rows)

    def predict(self, name: str, features: SceneFeatures) -> float:
        """Predicted error of rung ``name`` (NaN when the table does not cover it)."""
        if name == REFERENCE:
            return 0.0
        if name not in self.coefficients:
            return float("nan")
        error = 10.0 ** (features.regressors() @ self.coefficients[name] + self.margin[name])
        if name in SINGLE_SCATTERING:
            error = max(error, features.multi_bounce)
        return float(min(error, 10.0))


def _float(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")


def _features(row: dict) -> SceneFeatures:
    return SceneFeatures(**{k: _float(row[k]) for k in FEATURES})


def read_table(path: Path = TRADE_TABLE) -> list[dict]:
    """The trade table's rows; a table without the columns the rule needs is refused, naming them."""
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    missing = sorted({"model", ERROR_COLUMN, *FEATURES} - set(rows[0] if rows else ()))
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


def candidate_models(scene: SurfaceScene) -> list[str]:
    """Registered surface rungs that can take ``scene`` (statistics rungs only with an ensemble)."""
    names = [n for n in model_names("height_field") if n != "auto"]
    if scene.surface.ensemble is not None:
        names += list(model_names("statistics"))
    usable = []
    for name in names:
        try:
            get_model(name).check(scene)
        except ValueError:
            continue
        usable.append(name)
    return usable


def memory_budget_bytes() -> float:
    """Memory the full-wave fallback may use: 80% of this machine's RAM (the same on every call, so
    ``plan`` and ``run`` agree when they run on machines of the same size; ``plan``'s own budget
    check then applies to the choice)."""
    from wavebrdf.solver.resources import meminfo_bytes

    return 0.8 * meminfo_bytes("MemTotal")


def reference_model():
    """The full-wave rung ``auto`` falls back to (AIM: it fits the budgets the planner checks)."""
    return get_model(REFERENCE, {"method": "aim"})


def choose(scene: SurfaceScene, tolerance: float, rule: Rule | None = None,
           features: SceneFeatures | None = None) -> Choice:
    """The cheapest candidate predicted within ``tolerance``; none: the full-wave reference, or,
    where the full-wave model cannot take the scene (its ValueError) or would not fit
    :func:`memory_budget_bytes`, the approximation predicted best — said so in the reason."""
    rule = rule or default_rule()
    features = features or measure_scene(scene)
    candidates = {}
    for name in candidate_models(scene):
        try:
            estimate = (reference_model() if name == REFERENCE else get_model(name)).estimate(scene)
        except ValueError:  # e.g. AIM's grid limits: not a candidate for this scene
            continue
        candidates[name] = (rule.predict(name, features), estimate.seconds)
    full_wave = None
    if REFERENCE in candidates:
        full_wave = reference_model().estimate(scene)
        if full_wave.memory_bytes > memory_budget_bytes():  # it could not run here: not a candidate
            candidates.pop(REFERENCE)
            full_wave = None
    fitting = sorted((seconds, name) for name, (error, seconds) in candidates.items()
                     if name != REFERENCE and np.isfinite(error) and error <= tolerance)
    avoided = "" if full_wave is None else (
        f"; avoided {REFERENCE} ≈ {full_wave.seconds:.3g} s, {full_wave.memory_bytes / 2**30:.2f} GiB")
    if fitting:
        seconds, name = fitting[0]
        error = candidates[name][0]
        reason = (f"{name}: the cheapest rung predicted within tolerance {tolerance:g} (predicted {error:.3g}; "
                  f"{features.describe()}){avoided}")
        return Choice(name, error, candidates, full_wave, reason)
    best = min(((e, n) for n, (e, _) in candidates.items() if n != REFERENCE and np.isfinite(e)), default=None)
    closest = f"; best approximation {best[1]} predicted {best[0]:.3g}" if best else ""
    if full_wave is not None:
        reason = f"{REFERENCE}: no rung predicted within tolerance {tolerance:g}{closest} ({features.describe()})"
        return Choice(REFERENCE, 0.0, candidates, None, reason)
    if best is None:
        raise ValueError(f"[model] name = \"auto\": no rung of the trade table can take this scene and {REFERENCE} "
                         f"cannot run it within {memory_budget_bytes() / 2**30:.1f} GiB; choose a model")
    reason = (f"{best[1]}: no rung predicted within tolerance {tolerance:g} and {REFERENCE} cannot take this "
              f"scene or exceeds {memory_budget_bytes() / 2**30:.1f} GiB; the best approximation, predicted "
              f"{best[0]:.3g} ({features.describe()})")
    return Choice(best[1], best[0], candidates, None, reason)


def next_rung_up(choice: Choice, name: str) -> str | None:
    """The cheapest rung predicted more accurate than ``name`` (the reference excepted)."""
    error, seconds = choice.candidates[name]
    better = sorted((s, n) for n, (e, s) in choice.candidates.items()
                    if n not in (name, REFERENCE) and np.isfinite(e) and e < error)
    return better[0][1] if better else None


@dataclass(frozen=True)
class AutoOptions:
    tolerance: float = option(0.05, low=1e-4, high=10.0,
                              doc="relative L2 over the lobe (speckle-averaged) the chosen rung must meet")
    check: bool = option(True, doc="escalation check: compare with the next rung up on sentinel directions")


class AutoModel(Model):
    """``[model] name = "auto"``: chooses a rung per scene (module docstring) and runs it."""

    name = "auto"
    capabilities = Capabilities(takes="height_field", returns="intensity", polarized=True, steerable=False,
                                reciprocal=False, conserves_energy=False)
    Options = AutoOptions

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

    def choice(self, scene: SurfaceScene) -> Choice:
        """The choice for ``scene`` (measured once per scene and tolerance in this process)."""
        key = (id(scene.surface), scene.wavelength_um, complex(scene.index), scene.theta_i, scene.phi_i,
               scene.waist_um, scene.grid.resolution, scene.exterior_index, self.options.tolerance)
        kept = _CHOICES.get(key)
        if kept is None or kept[0] is not scene.surface:
            if len(_CHOICES) > 256:
                _CHOICES.clear()
            kept = _CHOICES[key] = (scene.surface, choose(scene, self.options.tolerance))
        return kept[1]

    def estimate(self, scene: SurfaceScene) -> Estimate:
        """The chosen rung's estimate, plus the pilot and the escalation check's coarse runs."""
        from wavebrdf.solver.farfield import HemisphereGrid

        choice = self.choice(scene)
        chosen = self.rung(choice.model).estimate(scene)
        extra = PILOT_SECONDS
        up = next_rung_up(choice, choice.model) if self.options.check and choice.model != REFERENCE else None
        if up is not None:
            coarse = dataclasses.replace(scene, grid=HemisphereGrid(SENTINEL_RESOLUTION))
            extra += self.rung(choice.model).estimate(coarse).seconds + self.rung(up).estimate(coarse).seconds
        # escalation may run any rung predicted more accurate: the memory to plan for is the largest
        reachable = [n for n, (e, _) in choice.candidates.items()
                     if n != REFERENCE and np.isfinite(e) and e < choice.candidates.get(choice.model, (0.0,))[0]]
        memory = max([chosen.memory_bytes] + [self.rung(n).estimate(scene).memory_bytes
                                              for n in (reachable if self.options.check else [])])
        chosen = dataclasses.replace(chosen, seconds=chosen.seconds + extra, memory_bytes=memory)
        avoided = "" if choice.avoided is None else (
            f"; avoids {REFERENCE} ≈ {choice.avoided.seconds:.3g} s, {choice.avoided.memory_bytes / 2**30:.2f} GiB")
        detail = (f"auto → {choice.model} (predicted error {choice.predicted_error:.2g}{avoided}): "
                  f"{chosen.detail}")
        return dataclasses.replace(chosen, detail=detail)

    def run(self, ctx, scene: SurfaceScene):
        from wavebrdf.solver.farfield import HemisphereGrid
        from wavebrdf.solver.metrics import blur, relative_l2

        choice = self.choice(scene)
        name, reason = choice.model, choice.reason
        if self.options.check and name != REFERENCE:
            coarse = dataclasses.replace(scene, grid=HemisphereGrid(SENTINEL_RESOLUTION))
            lam = scene.wavelength_um / scene.exterior_index  # the footprint's angular spread λ₁/(πw)
            sigma = max(2.0 / SENTINEL_RESOLUTION, lam / (np.pi * (scene.waist_um or np.inf)))
            coarse_brdf = {}

            def sentinel(n: str) -> np.ndarray:
                if n not in coarse_brdf:
                    coarse_brdf[n] = blur(_unpolarized(self.rung(n).run(ctx, coarse).brdf()), coarse.grid, sigma)
                return coarse_brdf[n]

            if next_rung_up(choice, name) is None:
                reason += f"; no approximate rung predicted more accurate than {name}: nothing to check against"
            while (up := next_rung_up(choice, name)) is not None:
                differ = float(relative_l2(sentinel(name), sentinel(up), coarse.grid))
                if differ <= self.options.tolerance:
                    reason += f"; checked against {up} on {SENTINEL_RESOLUTION}² sentinel directions: differ {differ:.3g}"
                    break
                reason += f"; escalated to {up} ({name} and {up} differ by {differ:.3g} > {self.options.tolerance:g})"
                name = up
        result = self.rung(name).run(ctx, scene)
        result.diagnostics.update(model=name, model_reason=reason,
                                  model_predicted_error=choice.candidates.get(name, (0.0,))[0])
        return result


def _unpolarized(brdf_sp: np.ndarray) -> np.ndarray:
    return 0.5 * (brdf_sp[0] + brdf_sp[1])


_CHOICES: dict[tuple, tuple] = {}  # key → (surface kept alive, Choice)


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
    worst = max((c.predicted_error for c in choices), default=0.0)
    return text + f"; worst predicted error {worst:.2g}"
