"""Fiber studies in the batch layer: one task per (case, λ, θ_i) → a BCSDF slice.

A fiber task solves every incidence azimuth φ_i and both polarizations at once (one LU per
(λ, θ_i) for the BEM, block right-hand sides; the Mie series for circles) and stores dC_s/dφ
(φ_r bin averages), C_ext, C_sca, C_abs. φ_i is either the list ``[illumination] phi_i_deg``
(point samples) or ``[output] phi_i_bins`` box-averaged bins over [0, 360°) (default: 1 bin at
φ_i = 0 for circles, which are rotation invariant, 72 otherwise), sampled as fiber.md §14.8
prescribes. The dataset layout is documented in docs/dataset.md ("Fiber datasets").
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from wavebrdf.jobs.plan import Plan, Task
from wavebrdf.solver.models import Estimate
from wavebrdf.solver.resources import peak_memory_mb

__all__ = ["estimate_fiber_task", "fiber_model", "phi_i_axis_deg", "run_fiber_task", "write_fiber_dataset"]

DEFAULT_PHI_I_BINS = 72


def phi_i_bins(plan: Plan) -> int:
    """Number of φ_i bins of the table (ignored when explicit φ_i samples are given)."""
    study = plan.study
    if study.output_options.phi_i_bins is not None:
        return study.output_options.phi_i_bins
    return 1 if study.fiber.shape == "circle" else DEFAULT_PHI_I_BINS


def phi_i_axis_deg(plan: Plan) -> np.ndarray:
    """The dataset's φ_i coordinate (degrees): explicit samples or bin centres."""
    explicit = plan.study.illumination.phi_i_deg
    if explicit is not None:
        return np.array(explicit, dtype=float)
    n = phi_i_bins(plan)
    return np.zeros(1) if n == 1 else 360.0 * np.arange(n) / n


def fiber_model(plan: Plan, case: int, ctx):
    """The solver of ``case`` (built once per process): Mie for "mie", else the 2.5D BEM."""
    key = ("fiber-model", case)
    if key not in plan._surfaces:
        from wavebrdf.solver import fiber

        study = plan.config.cases[case]
        if study.model.name == "mie":
            plan._surfaces[key] = fiber.MieFiber(study.fiber.radius_um)
        else:
            plan._surfaces[key] = fiber.FiberBEM(ctx, plan.cross_section(case))
    return plan._surfaces[key]


def run_fiber_task(ctx, plan: Plan, task: Task, parts) -> dict:
    """Solve one (case, λ, θ_i) and save its slice in ``parts``; return its diagnostics."""
    from wavebrdf.solver.fiber import bcsdf_slices

    t0 = time.perf_counter()
    study = plan.config.cases[task.case]
    model = fiber_model(plan, task.case, ctx)
    lam = study.illumination.wavelengths_um[task.wavelength]
    index = complex(plan.index(task.case)[task.wavelength])
    theta, _ = plan.direction_rad(task)
    n_phi_r = study.output_options.phi_r_bins
    if study.illumination.phi_i_deg is not None:
        res = model.scattering(lam, index, theta, np.deg2rad(study.illumination.phi_i_deg), bins=n_phi_r)
        arrays = {"dCs_dphi": res.dCs_dphi, "C_ext": res.C_ext, "C_sca": res.C_sca, "C_abs": res.C_abs}
        timings = res.timings
    else:
        sl = next(bcsdf_slices(model, [lam], [index], [theta], phi_i_bins(plan), n_phi_r))
        arrays = {"dCs_dphi": sl.dCs_dphi, "C_ext": sl.C_ext, "C_sca": sl.C_sca, "C_abs": sl.C_abs}
        timings = sl.timings
    balance = np.abs(arrays["C_ext"] - arrays["C_sca"] - arrays["C_abs"]) / np.abs(arrays["C_ext"])
    if not all(np.all(np.isfinite(a)) for a in arrays.values()):
        raise FloatingPointError(f"{task.label}: NaN/inf in the fiber solution")
    diagnostics = {
        "kind": task.kind, "model": study.model.name, "wall_time_s": time.perf_counter() - t0,
        "power_balance_error": float(balance.max()), "device": ctx.describe() if ctx is not None else "",
        **{f"time_{k}": float(v) for k, v in timings.items()},
    }
    diagnostics["peak_memory_mb"] = peak_memory_mb()
    parts.save_arrays(task, diagnostics, **{k: np.asarray(v) for k, v in arrays.items()})
    return diagnostics


def estimate_fiber_task(plan: Plan, task: Task) -> Estimate:
    """Memory/time of one fiber solve: a dense 4N×4N complex LU (BEM) or a Mie series."""
    study = plan.config.cases[task.case]
    n_phi = len(phi_i_axis_deg(plan)) * 8 * study.output_options.phi_r_bins
    if study.model.name == "mie":
        return Estimate(50e6 + 16.0 * n_phi, 0.05, "Mie series")
    n = 4 * plan.cross_section(task.case).segments
    memory = 3 * 16.0 * n * n + 100e6
    seconds = 8.0 / 3.0 * n**3 * 4 / 2e10 + 4e-7 * n * n + 0.1
    return Estimate(memory, seconds, f"dense {n}x{n} complex LU")


def write_fiber_dataset(plan: Plan, parts, device: str, run_info: dict | None = None) -> Path:
    """Assemble the fiber HDF5 dataset from the finished parts (one writer, atomic rename)."""
    from wavebrdf import __version__
    from wavebrdf.jobs.store import FiberDatasetWriter, atomic_h5

    study = plan.study
    output = Path(plan.config.output)
    with atomic_h5(output) as h5:
        writer = FiberDatasetWriter(
            h5, plan.config.sweep_axes, plan.wavelengths_um, np.array(study.illumination.theta_i_deg),
            phi_i_axis_deg(plan), 360.0 * np.arange(study.output_options.phi_r_bins) / study.output_options.phi_r_bins,
            phi_i_binned=study.illumination.phi_i_deg is None and phi_i_bins(plan) > 1,
        )
        writer.create(config_text=plan.config.text, study=study.name, software_version=__version__, device=device)
        shape = plan.config.case_shape
        for case, case_index in enumerate(np.ndindex(*shape) if shape else [()]):
            section = plan.cross_section(case)
            width = section.width(np.deg2rad(phi_i_axis_deg(plan)))
            writer.write_case(tuple(case_index), str(case), section.nodes, width, plan.index(case))
        rows = []
        for task in plan.tasks:
            row = {"id": task.id, "kind": task.kind, "case": task.case, "wavelength_index": task.wavelength,
                   "theta_index": task.incidence, **(run_info or {}).get(task.id, {})}
            failure = parts.failure(task)
            if failure is not None or not parts.done(task):
                rows.append({**row, "status": "failed", **(failure or {"error": "not run"})})
                continue
            arrays, diagnostics = parts.load_arrays(task)
            writer.write_slice(task.case_index, task.wavelength, task.incidence, **arrays)
            rows.append({**row, "status": "done", **diagnostics})
        writer.write_tasks(rows)
    return output
