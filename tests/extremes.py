"""The extremes case library (VALIDATION.md "Numerical stability at the extremes"; issue 17 item 3).

Cases are defined once here and used by tests/test_extremes.py (a CI subset, the full grid marked
slow) and by ``benchmarks/extremes.py`` (the case × model table in docs/extremes.md). Every case
runs on every registered model it applies to (``model_names()``), so a model registered later is
covered by the same cases. Per-model scene sizes come from the conformance suite
(tests/test_models.py ``settings``: "flat" for the Fresnel family, "gain" for rough patches).

Each (case, model) ends in one verdict:

* ``ok``       the value is within the case's tolerance of an independent reference
               (tests/references.py: Fresnel, the Rayleigh limit of a cylinder, treams' T-matrix;
               or a bound such as albedo ≤ 1);
* ``warned``   outside the tolerance, but the run said so loudly: a Python warning (what the batch
               layer stores in the dataset's diagnostics), or the dataset's EnergyWarning
               (jobs/tasks.py ``_energy_check``: albedo > 1 + ENERGY_SLACK);
* ``refused``  a clear ValueError (the config layer's ``check()`` or the run), never a number;
* ``n/a``      the model does not take this kind of scene (a fiber case for a surface model);
* ``skipped``  beyond MAX_BYTES/MAX_SECONDS by the model's own estimate (not run on 2 cores);
* ``FAIL``     a silent wrong number (or NaN): what the suite forbids.

Single vs double precision: :func:`run_case` with ``precision="single"`` runs the same scene in
float32 kernels/FFTs; the generator reports |single − double| / |double| of the case's value.
"""

from __future__ import annotations

import math
import time
import traceback
import warnings
from dataclasses import dataclass, field

import numpy as np

from references import (
    ALUMINIUM_400NM,
    beam_fresnel_reflectance,
    cylinder_rayleigh_widths,
    cylinder_widths_treams,
    fresnel_reflectance,
)
from test_models import LAMBDA, settings, tolerance
from wavebrdf.solver.farfield import HemisphereGrid, albedo
from wavebrdf.solver.models import FiberScene, SurfaceScene, get_model, model_class, model_names
from wavebrdf.solver.surface import HeightField, generate

__all__ = ["CASES", "Case", "Outcome", "run_case", "applicable"]

DEG = np.pi / 180
FIBER_LAMBDA = 0.5  # µm
ROUGH_TOLERANCE = 0.10  # rough aluminium: albedo within 10% of R(θ_i) when no closed form exists
MAX_BYTES = 1.5 * 2**30  # cases beyond these estimates are "skipped" (see _too_costly)
MAX_SECONDS = 300.0
PEC_INDEX = 1.0 - 1000.0j
PARADOX_X = 1000.0  # x from which C_ext is compared with 2·(2a) (treams returns NaN at x = 1000)
PARADOX_TOLERANCE = 0.02  # the approach to 2 is ~x^(-2/3) = 1% at x = 1000
T6 = ((20.138, math.nan), (18.845, math.nan))  # fiber.md T6 (C_ext, C_sca) case I, a = 0.3 µm, 89.9°  # κ = 1e3: a near-perfect conductor (R ≥ 0.996 at any angle)


@dataclass(frozen=True)
class Case:
    """One extreme: ``group`` (the VALIDATION.md item), ``kind`` surface|fiber, ``params`` of the
    scene, ``checks`` (what it checks, for the docs); ``ci``: part of the CI subset."""

    id: str
    group: str
    kind: str
    checks: str
    params: dict
    ci: bool = False


@dataclass
class Outcome:
    """What one (case, model[, precision]) gave."""

    case: str
    model: str
    precision: str = "double"
    verdict: str = "n/a"
    value: float = math.nan
    reference: float | str = math.nan
    error: float = math.nan
    tolerance: float = math.nan
    warnings: list = field(default_factory=list)
    refused: str = ""
    seconds: float = 0.0
    note: str = ""


# ------------------------------------------------------------------------------------------------
# The cases


def _cases() -> list[Case]:
    out = []
    alu = ALUMINIUM_400NM
    for theta in (80.0, 85.0, 88.0, 89.0, 89.9):
        out.append(Case(f"grazing-{theta:g}", "grazing", "surface",
                        "gently rough aluminium (rms slope 0.17) at grazing θ_i: albedo ≤ 1 (energy bound), "
                        "finite; an excess must be warned (EnergyWarning), a cut footprint too",
                        dict(surface="rough", index=alu, theta=theta), ci=theta in (89.0,)))
    for kappa in (0.0, 1e-8, 1e-4, 1.0, 10.0, 1e3):
        out.append(Case(f"kappa-{kappa:g}", "kappa", "surface",
                        "flat n = 1.5 − jκ at θ_i = 30°: albedo = Fresnel R(30°) (continuous in κ, "
                        "→ 1 never above for κ → ∞)",
                        dict(surface="flat", index=1.5 - 1j * kappa, theta=30.0), ci=kappa in (1e-8, 1e3)))
    out.append(Case("n-1.0001", "kappa", "surface",
                    "flat n = 1.0001 at θ_i = 0°: albedo = Fresnel 2.5e-9 within 1% (no cancellation)",
                    dict(surface="flat", index=1.0001, theta=0.0, tolerance=0.01), ci=True))
    for theta in (0.0, 50.0):
        out.append(Case(f"pec-rough-{theta:g}", "kappa", "surface",
                        "gently rough κ = 1e3 (PEC limit): albedo ≤ 1, and ≥ 0.9",
                        dict(surface="rough", index=PEC_INDEX, theta=theta, bound=(0.9, 1.0)), ci=theta == 0.0))
    out.append(Case("heights-1e-5", "geometry", "surface",
                    "rms height 1e-5 λ on the flat scene (aluminium, 30°): albedo = Fresnel (no cancellation noise)",
                    dict(surface="tiny", index=alu, theta=30.0), ci=True))
    out.append(Case("heights-3lambda", "geometry", "surface",
                    "Gaussian heights with a 3λ peak-to-valley (aluminium, 30°): albedo ≤ 1 and within 10% of R(30°)",
                    dict(surface="tall", index=alu, theta=30.0, rough_tolerance=ROUGH_TOLERANCE)))
    out.append(Case("slopes-60", "geometry", "surface",
                    "sinusoid of 60° maximum slope (PEC κ = 1e3, 20°): albedo ≤ 1 (shadowing and "
                    "multiple scattering models lose or move light, never create it)",
                    dict(surface="slopes60", index=PEC_INDEX, theta=20.0, bound=(0.0, 1.0))))
    out.append(Case("step", "geometry", "surface",
                    "a near-vertical step (λ/2 high over one cell, 73°; aluminium, 30°): albedo ≤ 1, finite",
                    dict(surface="step", index=alu, theta=30.0, bound=(0.0, 1.0))))
    for per in (3, 6, 12, 24, 40):
        out.append(Case(f"lambda-d-{per}", "sampling", "surface",
                        f"λ/d = {per} (gently rough aluminium rms 0.01λ, 30°): albedo within the model's "
                        "flat tolerance + 1% of Fresnel, or a resolution warning",
                        dict(surface="sampled", per_wavelength=per, index=alu, theta=30.0), ci=per == 3))
    for patch in (2, 5, 20, 60):
        out.append(Case(f"patch-{patch}lambda", "scale", "surface",
                        f"flat aluminium patch of {patch}λ (waist = patch/5.3, 0°): albedo = Fresnel "
                        "(exact-beam Fresnel for beams that spread), or a footprint/beam warning",
                        dict(surface="patch", patch_wavelengths=patch, index=alu, theta=0.0), ci=patch == 2))
    for x in (0.01, 0.1, 1.0, 10.0, 100.0, 1000.0):
        out.append(Case(f"fiber-x-{x:g}", "fiber", "fiber",
                        f"circular fiber, size parameter x = {x:g}, m = 1.55 − 0.01j, normal incidence: "
                        + ("C_ext, C_sca vs the Rayleigh closed form within 1%" if x <= 0.01 else
                           "C_ext vs the extinction paradox 2·(2a) within 2% (treams fails here)" if x >= 1000 else
                           "C_ext, C_sca vs treams' T-matrix within 1%"),
                        dict(x=x, index=1.55 - 0.01j, theta=0.0), ci=x in (0.01,)))
    for theta in (89.5, 89.9):
        out.append(Case(f"fiber-theta-{theta:g}", "fiber", "fiber",
                        f"a = 0.3 µm fiber (x = 3.8), m = 1.55 − 0.02j at θ_i = {theta:g}° from the normal plane: "
                        + ("C_ext, C_sca (case I) vs fiber.md T6 (20.138, 18.845 µm)" if theta == 89.9
                           else "C_ext, C_sca vs treams") + " within 1%",
                        dict(x=2 * math.pi * 0.3 / FIBER_LAMBDA, index=1.55 - 0.02j, theta=theta,
                             table=T6 if theta == 89.9 else None), ci=theta == 89.9))
    for label, m in (("absorbing", 1.55 - 1.0j), ("lossless", 1.55 - 1e-8j)):
        out.append(Case(f"fiber-{label}", "fiber", "fiber",
                        f"x = 3 fiber, m = {m}: C_ext, C_sca vs treams within 1%; C_abs ≥ 0",
                        dict(x=3.0, index=m, theta=30.0)))
    out.append(Case("fiber-cusp", "fiber", "fiber",
                    "near-cusp cross section (two circles overlapping at a 10° notch), m = 1.55: power "
                    "balance C_ext = C_sca + C_abs and C_abs ≈ 0 within 1% (lossless)",
                    dict(shape="cusp", index=1.55, theta=20.0), ci=True))
    return out


CASES: list[Case] = _cases()
CASE_BY_ID = {c.id: c for c in CASES}


# ------------------------------------------------------------------------------------------------
# Scenes


def _takes(name: str) -> str:
    return model_class(name).capabilities.takes


def applicable(case: Case, name: str) -> bool:
    """Whether the model takes this kind of scene (surface models surfaces, fiber models fibers)."""
    takes = _takes(name)
    return (case.kind == "fiber") == (takes == "cross_section")


def _gaussian(cells, size_um, rms, corr, seed=9) -> HeightField:
    return generate("gaussian", cells=cells, size_um=size_um, seed=seed, rms_height_um=rms, correlation_um=corr)


def _surface_scene(case: Case, name: str, precision: str):
    """(model options, scene, reference kind, tolerance) of a surface case for model ``name``."""
    p = case.params
    kind = p["surface"]
    flat = settings(name, "flat")
    rough = settings(name, "gain")
    tol = p.get("tolerance", tolerance(name))
    if kind in ("flat", "tiny", "patch"):
        cfg = dict(flat)
        if kind == "patch":
            size = p["patch_wavelengths"] * LAMBDA
            cells = max(int(round(flat["cells"] * size / flat["size_um"])), 8)
            cfg.update(size_um=size, cells=cells, waist_um=size / 5.3, resolution=max(flat["resolution"], 64))
        if kind == "tiny":
            surface = _gaussian(cfg["cells"], cfg["size_um"], 1e-5 * LAMBDA, cfg["size_um"] / 20)
        elif _takes(name) == "statistics":  # the σ = 0 Gaussian ensemble
            surface = _gaussian(cfg["cells"], cfg["size_um"], 0.0, 1.0)
        else:
            surface = generate("flat", cells=cfg["cells"], size_um=cfg["size_um"])
        reference = cfg["reference"]
    else:
        cfg = dict(rough)
        cells, size = cfg["cells"], cfg["size_um"]
        if kind == "rough":  # rms slope √2 σ/ℓ ≈ 0.17
            surface = _gaussian(cells, size, cfg["rms_height_um"], cfg["correlation_um"])
        elif kind == "tall":  # p-v ≈ 3λ: σ = 3λ/6, ℓ = patch/3
            surface = _gaussian(cells, size, 0.5 * LAMBDA, size / 3)
        elif kind == "slopes60":  # 2πa/Λ = tan 60°, Λ = patch/4
            period = size / 4
            surface = generate("sinusoid", cells=cells, size_um=size, amplitude_um=math.tan(math.pi / 3) * period
                               / (2 * math.pi), period_um=period)
        elif kind == "step":
            z = np.zeros((cells + 1, cells + 1))
            z[cells // 2 + 1:, :] = 0.5 * LAMBDA
            surface = HeightField(z - z.mean(), size)
        elif kind == "sampled":  # the same Gaussian statistics sampled at d = λ/per on a fixed patch
            size = max(size, 8 * LAMBDA) if rough["cells"] > 60 else size
            cells = max(int(round(size / (LAMBDA / p["per_wavelength"]))), 4)
            surface = _gaussian(cells, size, 0.01 * LAMBDA, cfg["correlation_um"])
            cfg.update(cells=cells, size_um=size)
            tol = tolerance(name) + 0.01
        else:
            raise ValueError(f"unknown surface kind {kind!r}")
        reference = "fresnel" if kind == "sampled" else "bound"
    scene = SurfaceScene(surface=surface, wavelength_um=LAMBDA, index=complex(p["index"]), theta_i=p["theta"] * DEG,
                         phi_i=25 * DEG, waist_um=cfg["waist_um"], grid=HemisphereGrid(cfg["resolution"]),
                         beam=cfg["beam"], precision=precision)
    return cfg["options"], scene, reference, tol, cfg


def _surface_reference(case: Case, scene: SurfaceScene, reference: str, cfg: dict):
    """(reference value, description) for the unpolarized albedo of a surface case."""
    p = case.params
    if reference == "exact_beam":
        from wavebrdf.solver.beams import make_beam  # the scene's incident field, not its reflection

        waves = make_beam("exact", LAMBDA, scene.theta_i, scene.phi_i, scene.waist_um,
                          patch_size_um=scene.surface.size_um).plane_waves
        return float(np.mean(beam_fresnel_reflectance(waves["kvec"], waves["E"], 1.0, scene.index))), "beam Fresnel"
    fresnel = float(np.mean(fresnel_reflectance(1.0, scene.index, scene.theta_i)))
    if reference == "fresnel":
        return fresnel, "Fresnel"
    if "bound" in p:
        return p["bound"], f"[{p['bound'][0]:g}, {p['bound'][1]:g}]"
    if "rough_tolerance" in p:
        lo = fresnel * (1 - p["rough_tolerance"])
        return (lo, 1.0), f"[{lo:.3g}, 1]"
    return (0.0, 1.0), "≤ 1"


def _fiber_scene(case: Case, name: str, precision: str) -> tuple[FiberScene, float]:
    from wavebrdf.solver.fiber import circle

    p = case.params
    index = complex(p["index"])
    if p.get("shape") == "cusp":
        section, radius = cusp_section(0.4, 10.0, 12.0 * 2 * math.pi * 0.4 / (FIBER_LAMBDA / abs(index))), None
    else:
        radius = p["x"] * FIBER_LAMBDA / (2 * math.pi)
        per = FIBER_LAMBDA / abs(index)
        segments = max(16, int(math.ceil(12.0 * 2 * math.pi * radius / per)))
        section = circle(radius, segments)
    scene = FiberScene(cross_section=section, wavelength_um=FIBER_LAMBDA, index=index, theta_i=p["theta"] * DEG,
                       phi_i=(0.0,), phi_i_bins=1, phi_r_bins=72, radius_um=radius, precision=precision)
    return scene, radius


def cusp_section(radius_um: float, notch_deg: float, segments: float):
    """Two equal circles whose union has two notches of interior angle ``notch_deg`` (a near cusp):
    centres ±c on x with c = r cos(notch/2), so the boundaries meet at that angle."""
    from wavebrdf.solver.fiber.shapes import polygon

    half = 0.5 * notch_deg * DEG  # the boundaries cross at angle π − 2·(π/2 − half) = 2·half
    c = radius_um * math.sin(half)
    crossing = math.acos(-c / radius_um)  # polar angle (about each centre) of the crossing points
    count = max(int(segments) // 2, 24)
    t = np.linspace(-crossing, crossing, count, endpoint=False)
    right = np.stack([c + radius_um * np.cos(t), radius_um * np.sin(t)], axis=1)
    left = -right
    return polygon(np.concatenate([right, left]))


# ------------------------------------------------------------------------------------------------
# Running one case


def _energy_warning(model: str, theta_rad: float, albedo_sp) -> str:
    """The dataset's EnergyWarning for this albedo (what jobs/tasks.py ``_energy_check`` stores), or ""."""
    from wavebrdf.solver.validity import energy_excess_warning

    return energy_excess_warning(model, float(np.rad2deg(theta_rad)), np.asarray(albedo_sp)) or ""


def _run_surface(ctx, case: Case, name: str, precision: str, out: Outcome, models: dict):
    options, scene, reference, tol, cfg = _surface_scene(case, name, precision)
    out.tolerance = tol
    model = models.get((name, repr(options))) or get_model(name, options)
    models.clear()
    models[(name, repr(options))] = model
    ref, out.note = _surface_reference(case, scene, reference, cfg)
    model.check(scene)
    if _too_costly(model, scene, out):
        return None
    result, caught = _caught(model.run, ctx, scene)
    out.warnings += caught + _diagnostic_warnings(result.diagnostics, caught)
    brdf = result.brdf()
    a = albedo(brdf, scene.grid)
    energy = _energy_warning(name, scene.theta_i, a)
    if energy:
        out.warnings.append(energy)
    finite = bool(np.all(np.isfinite(brdf[:, scene.grid.inside])))
    out.value = float(np.mean(a)) if finite else math.nan
    if isinstance(ref, tuple):  # a bound holds per polarization
        lo, hi = ref
        out.value = float(np.max(a)) if finite else math.nan
        out.reference = out.note
        out.error = max(lo - out.value, out.value - hi, 0.0) if finite else math.nan
        within = finite and out.value <= hi + tol and out.value >= lo - tol
    else:
        out.reference = ref
        out.error = out.value / ref - 1 if finite else math.nan
        within = finite and abs(out.error) <= tol
    return within


def _run_fiber(ctx, case: Case, name: str, precision: str, out: Outcome, models: dict):
    scene, radius = _fiber_scene(case, name, precision)
    p = case.params
    out.tolerance = 0.01
    model = get_model(name)
    model.check(scene)
    if _too_costly(model, scene, out):
        return None
    result, caught = _caught(model.run, ctx, scene)
    out.warnings += caught + _diagnostic_warnings(result.diagnostics, caught)
    ext, sca, ab = (np.asarray(a)[:, 0] for a in (result.C_ext, result.C_sca, result.C_abs))
    finite = all(np.all(np.isfinite(a)) for a in (ext, sca, ab))
    out.value = float(np.mean(ext)) if finite else math.nan
    if p.get("shape") == "cusp":
        balance = float(np.max(np.abs(ext - sca - ab) / ext))
        out.reference, out.note = "C_ext = C_sca, C_abs = 0", "power balance"
        out.error = max(balance, float(np.max(np.abs(ab) / ext))) if finite else math.nan
        return finite and out.error <= out.tolerance
    theta = p["theta"] * DEG
    if p.get("table"):
        ref_ext, ref_sca = (np.array(v) for v in p["table"])
        out.note = "fiber.md T6"
        out.value = float(ext[0]) if finite else math.nan  # the table gives case I
    elif p["x"] <= 0.01:
        ref_ext, ref_sca = cylinder_rayleigh_widths(FIBER_LAMBDA, radius, scene.index)
        out.note = "Rayleigh limit"
    elif p["x"] >= PARADOX_X:  # treams' series fails (NaN) here: the extinction paradox, C_ext → 2·(2a)
        ref_ext, ref_sca = np.full(2, 4.0 * radius), np.full(2, math.nan)
        out.note, out.tolerance = "extinction paradox 2·2a", PARADOX_TOLERANCE
    else:
        try:
            ref_ext, ref_sca = cylinder_widths_treams(FIBER_LAMBDA, radius, scene.index, theta)
        except ValueError as exc:  # the reference's failure is not the model's refusal
            raise RuntimeError(f"reference: {exc}") from None
        out.note = "treams T-matrix"
    out.reference = float(np.nanmean(ref_ext))
    errors = np.concatenate([ext / ref_ext - 1, sca / ref_sca - 1]) if finite else np.array([math.nan])
    errors = errors[np.isfinite(errors)] if finite else errors
    out.error = float(errors[np.argmax(np.abs(errors))])
    return bool(finite and np.all(np.abs(errors) <= out.tolerance) and np.all(ab >= -1e-12 * ext))


def _too_costly(model, scene, out: Outcome) -> bool:
    """Cases beyond MAX_BYTES / MAX_SECONDS by the model's own estimate are not run here (2-core
    machine): verdict "skipped", with the estimate (the plan refuses what does not fit a node)."""
    est = model.estimate(scene)
    if est.memory_bytes > MAX_BYTES or est.seconds > MAX_SECONDS:
        out.verdict = "skipped"
        out.note = f"estimate {est.memory_bytes / 2**30:.2g} GiB, {est.seconds:.3g} s ({est.detail})"
        return True
    return False


def _caught(func, *args):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = func(*args)
    messages = sorted({f"{w.category.__name__}: {w.message}" for w in caught
                       if not issubclass(w.category, (DeprecationWarning, ResourceWarning))
                       and "CompilerWarning" not in w.category.__name__})
    return result, messages


def _diagnostic_warnings(diagnostics: dict, caught: list) -> list:
    """Warnings a model recorded in its diagnostics without raising them (kept in the dataset)."""
    recorded = diagnostics.get("warnings") or []
    if isinstance(recorded, str):
        recorded = [w for w in recorded.split("; ") if w]
    return [w for w in recorded if w not in caught]


def run_case(ctx, case: Case, name: str, precision: str = "double", models: dict | None = None) -> Outcome:
    """Run ``case`` on model ``name`` and return its :class:`Outcome` (never raises for the model's
    own refusals; other exceptions are a FAIL with the traceback's last line)."""
    out = Outcome(case.id, name, precision)
    if not applicable(case, name):
        return out
    t0 = time.perf_counter()
    models = {} if models is None else models
    try:
        run = _run_fiber if case.kind == "fiber" else _run_surface
        within = run(ctx, case, name, precision, out, models)
        if within is None:  # skipped
            out.seconds = time.perf_counter() - t0
            return out
    except ValueError as exc:  # OptionsError, SurfaceError, ShapeError are ValueErrors
        out.verdict, out.refused = "refused", f"{type(exc).__name__}: {exc}"
        out.seconds = time.perf_counter() - t0
        return out
    except Exception as exc:  # noqa: BLE001 - a crash is a failure of the case, reported
        out.verdict = "FAIL"
        out.refused = f"crash: {type(exc).__name__}: {exc}"
        out.note = traceback.format_exc().strip().splitlines()[-1]
        out.seconds = time.perf_counter() - t0
        return out
    out.seconds = time.perf_counter() - t0
    if within:
        out.verdict = "ok"
    elif out.warnings:
        out.verdict = "warned"
    else:
        out.verdict = "FAIL"
    return out


def models_for(case: Case) -> list[str]:
    """The registered models this case applies to (every one, by capability)."""
    names = []
    for name in model_names():
        try:
            ok = applicable(case, name)
        except Exception:  # noqa: BLE001 - an unimportable model fails its case loudly in run_case
            ok = True
        if ok:
            names.append(name)
    return names
