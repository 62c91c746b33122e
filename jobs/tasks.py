"""Task kinds: what each kind of task runs, estimates, saves in the parts folder and writes into
the dataset — one table, :data:`KINDS`, read by the plan, the scheduler and the store.

=========  ====================================  ===========================  ==================
kind       run                                   saved (``<output>.parts/``)  written (dataset)
=========  ====================================  ===========================  ==================
direct     the model on the whole surface        BRDF per polarization        brdf, albedo slot
patch      the model on one steering sub-area    its far field (global phase) task row only
synth      beam steering of the patch fields     BRDF per polarization        brdf, albedo slot
fiber      the fiber model, every φ_i at once    dC_s/dφ and cross sections   BCSDF slice
check      auto's spot check of a direct/patch   the full-wave far field      task row only
           task's scene (jobs/spot_checks.py)    (measured errors: row)
=========  ====================================  ===========================  ==================

Models are taken from a :class:`ModelPool`: one instance per model configuration and worker
process, so what a model keeps between scenes (an LU, an AIM operator, a fiber assembler) is
reused by the next task of the same worker and never shared across contexts or processes.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, replace
from typing import Any, Callable

import numpy as np

from wavebrdf.jobs.spot_checks import expectation_scene, twin_of
from wavebrdf.jobs.steering import estimate_synthesis, synthesize_task
from wavebrdf.solver.farfield import BRDFResult, FarField, albedo, combine_polarizations
from wavebrdf.solver.models import Estimate, Model, model_class
from wavebrdf.solver.polarimetry import jones
from wavebrdf.solver.resources import peak_memory_mb
from wavebrdf.solver.validity import energy_excess_warning, recorded_warnings

__all__ = ["KINDS", "ModelPool", "TaskKind", "execute_task", "plain"]


class ModelPool:
    """Model instances of one worker process, one per (name, options)."""

    def __init__(self):
        self._models: dict[tuple, Model] = {}

    def get(self, spec) -> Model:
        """The instance for a :class:`~wavebrdf.jobs.study.ModelSpec` (built on first use)."""
        key = (spec.name, spec.options)
        model = self._models.get(key)
        if model is None:
            for other in self._models.values():  # one model's kept operator at a time per worker
                other.release()
            model = self._models[key] = spec.build()
        return model


def plain(diagnostics: dict) -> dict:
    """Diagnostics with JSON-ready values (numbers, strings, lists of numbers; anything else as repr)."""
    def value(v):
        if isinstance(v, (bool, int, float, str)):
            return v
        if isinstance(v, (list, tuple)) and all(isinstance(x, (bool, int, float, str)) for x in v):
            return list(v)
        return repr(v)

    return {k: value(v) for k, v in diagnostics.items()}


@dataclass(frozen=True)
class TaskKind:
    """run(ctx, plan, task, pool, parts) → output; estimate(plan, task) → Estimate;
    save(plan, task, parts, output, extra) → diagnostics; write(writer, plan, task, parts) →
    diagnostics, or None when the kind has no slot in the dataset (its row only)."""

    run: Callable
    estimate: Callable[[Any, Any], Estimate]
    save: Callable
    write: Callable | None

    @property
    def writes_result(self) -> bool:
        return self.write is not None


# --- run ----------------------------------------------------------------------------------------


def _run_model(ctx, plan, task, pool, parts):
    """The task's model on the task's scene (surface or fiber); a task with spot checks gives its
    model their measurements (and the full-wave result of a check of this very scene). Where one of
    its checks failed, the task runs on the rule's choice (and its escalation check): the checks
    left would represent it at some wavelengths only."""
    model = pool.get(plan.model_spec(task))
    checks = [plan.tasks[i] for i in task.checks]
    if not checks or not all(parts.done(c) for c in checks):
        return model.run(ctx, plan.model_scene(task))
    twin = twin_of(plan, task)
    full_wave = None if twin is None or twin not in checks else (lambda: parts.load_farfield(twin))
    return model.run_checked(ctx, plan.model_scene(task), [_check_diagnostics(parts, c) for c in checks], full_wave)


_CHECKS: dict[tuple, dict] = {}  # (parts folder, fingerprint, check id, key) → diagnostics, read once per process


def _check_diagnostics(parts, check) -> dict:
    key = (str(parts.path), parts.plan.fingerprint, check.id, check.key)
    if key not in _CHECKS:
        if len(_CHECKS) > 4096:
            _CHECKS.clear()
        _CHECKS[key] = parts.load_diagnostics(check)
    return _CHECKS[key]


def _run_check(ctx, plan, task, pool, parts):
    """A spot check: the full wave and the cheaper rungs on the scene of the task it copies."""
    return pool.get(plan.model_spec(task)).spot_check(ctx, plan.model_scene(task))


def _run_patch(ctx, plan, task, pool, parts):
    """A sub-area's far field, its phase moved to the global origin (e^{+jk p·ω_o})."""
    ff = _run_model(ctx, plan, task, pool, parts)
    return ff.translated(plan.steering[task.case].layout.centre(task.patch))


def _estimate_model(plan, task) -> Estimate:
    """The model's estimate of the task's scene; a patch task after its sub-area's first
    wavelength takes the time of a solve that follows the previous one in its worker (the plan
    orders sub-area → wavelength and the scheduler keeps a sub-area on one worker)."""
    model = plan.model_spec(task).build()
    if task.checks:  # the rung its series is expected to take (jobs/spot_checks.py)
        estimate = model.estimate(plan.model_scene(task), like=expectation_scene(plan, task))
    else:
        estimate = model.estimate(plan.model_scene(task))
    if task.kind == "patch" and task.wavelength > 0 and estimate.following_seconds is not None:
        return replace(estimate, seconds=estimate.following_seconds)
    return estimate


def _estimate_check(plan, task) -> Estimate:
    return plan.model_spec(task).build().estimate_spot_check(plan.model_scene(task))


# --- save (parts folder) -----------------------------------------------------------------------


def _energy_check(plan, task, albedo_sp: np.ndarray, diagnostics: dict) -> None:
    """Record ``albedo_excess`` and, beyond :data:`~wavebrdf.solver.validity.ENERGY_SLACK`, a
    warning naming the model and the incidence (:func:`~wavebrdf.solver.validity.energy_excess_warning`)."""
    diagnostics["albedo_excess"] = max(0.0, float(np.nanmax(albedo_sp)) - 1.0)
    theta, _ = np.rad2deg(plan.direction_rad(task))
    message = energy_excess_warning(diagnostics.get("model", plan.model_spec(task).name), theta, albedo_sp)
    if message:
        diagnostics["warnings"] = "; ".join(w for w in (diagnostics.get("warnings", ""), message) if w)


def _save_brdf(plan, task, parts, result: BRDFResult, extra: dict) -> dict:
    """BRDF per polarization (float32) and its albedo; NaN/inf inside the disk is a failure."""
    brdf_sp = result.brdf()
    if not np.all(np.isfinite(brdf_sp[:, plan.grid.inside])):
        raise FloatingPointError(f"{task.label}: NaN/inf inside the unit disk")
    diagnostics = {**plain(result.diagnostics), **extra}
    albedo_sp = albedo(brdf_sp, plan.grid)
    _energy_check(plan, task, albedo_sp, diagnostics)
    parts.save_arrays(task, diagnostics, brdf_sp=brdf_sp.astype(np.float32), albedo_sp=albedo_sp,
                      **_polarimetry(plan, task, result, diagnostics))
    return diagnostics


def _polarimetry(plan, task, result: BRDFResult, diagnostics: dict) -> dict:
    """{"jones": (2, 2, res, res) complex64} where the study stores Jones or Mueller matrices."""
    stored = plan.config.cases[task.case].output_options.polarization
    if stored == "intensity":
        return {}
    model = diagnostics.get("model", plan.model_spec(task).name)
    if not isinstance(result, FarField) or not _vector_fields(model):
        raise ValueError(f"[output] polarization = \"{stored}\": {model} returned no vector far field at "
                         f"{task.label}; Jones and Mueller matrices need a vector-field model (bem, po)")
    return {"jones": jones(result).astype(np.complex64)}


def _vector_fields(name: str) -> bool:
    """Whether the model that ran (its registry name, e.g. the rung auto picked) returns vector fields."""
    try:
        return model_class(name).capabilities.vector_fields
    except (KeyError, ValueError):
        return False


def _save_farfield(plan, task, parts, ff, extra: dict) -> dict:
    ff.diagnostics.update(extra)
    diagnostics = plain(ff.diagnostics)
    parts.save_farfield(task, ff, diagnostics)
    return {**diagnostics, **extra}


def _save_fiber(plan, task, parts, result, extra: dict) -> dict:
    diagnostics = {**result.diagnostics, **extra}
    parts.save_arrays(task, diagnostics, **{k: np.asarray(v) for k, v in result.arrays().items()})
    return diagnostics


# --- write (dataset) ---------------------------------------------------------------------------


def _write_brdf(writer, plan, task, parts) -> dict:
    arrays, diagnostics = parts.load_arrays(task)
    brdf_sp = arrays["brdf_sp"]
    brdf = combine_polarizations(brdf_sp, plan.config.cases[task.case].illumination.polarization)
    writer.write_result(task.case_index, task.wavelength, task.incidence, brdf_sp, brdf, arrays["albedo_sp"],
                        float(albedo(brdf, plan.grid)), jones=arrays.get("jones"))
    return diagnostics


def _write_fiber(writer, plan, task, parts) -> dict:
    arrays, diagnostics = parts.load_arrays(task)
    writer.write_slice(task.case_index, task.wavelength, task.incidence, **arrays)
    return diagnostics


KINDS: dict[str, TaskKind] = {
    "direct": TaskKind(run=_run_model, estimate=_estimate_model, save=_save_brdf, write=_write_brdf),
    "patch": TaskKind(run=_run_patch, estimate=_estimate_model, save=_save_farfield, write=None),
    "synth": TaskKind(run=synthesize_task, estimate=estimate_synthesis, save=_save_brdf, write=_write_brdf),
    "fiber": TaskKind(run=_run_model, estimate=_estimate_model, save=_save_fiber, write=_write_fiber),
    "check": TaskKind(run=_run_check, estimate=_estimate_check, save=_save_farfield, write=None),
}


def execute_task(ctx, plan, task, parts, pool: ModelPool) -> dict:
    """Run ``task``, save its output in ``parts`` and return its diagnostics (the warnings it
    raised, wall time, peak memory and device included)."""
    kind = KINDS[task.kind]
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        output = kind.run(ctx, plan, task, pool, parts)
    extra = {
        "kind": task.kind,
        # the rung that ran: `auto` names its choice (and model_reason) in the result's diagnostics
        "model": getattr(output, "diagnostics", {}).get("model", plan.model_spec(task).name),
        "wall_time_s": time.perf_counter() - t0,
        "peak_memory_mb": peak_memory_mb(),
        "device": ctx.describe() if ctx is not None else "",
        "warnings": recorded_warnings(caught),
    }
    return kind.save(plan, task, parts, output, extra)
