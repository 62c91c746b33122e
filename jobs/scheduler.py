"""Execution: run a plan's tasks, keep every finished task on disk, assemble the dataset.

Each finished task is saved atomically as ``<output>.parts/task-<id>.npz`` (written under a
temporary name, then renamed), so a run that dies loses at most the tasks in flight. The final
HDF5 file is assembled from the parts by one writer and renamed into place
(:func:`wavebrdf.jobs.store.atomic_h5`); then the parts folder is removed. Re-running the same
command completes only the missing tasks; a changed config is refused (the parts folder records
the plan's fingerprint).
"""

from __future__ import annotations

import json
import logging
import os
import resource
import shutil
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from wavebrdf import __version__
from wavebrdf.jobs.plan import Plan, Task
from wavebrdf.jobs.store import DatasetWriter, atomic_h5
from wavebrdf.solver.farfield import albedo, combine_polarizations
from wavebrdf.solver.models import get_model

logger = logging.getLogger(__name__)

__all__ = ["PartsFolder", "ResumeError", "TaskResult", "execute_task", "run_plan"]


class ResumeError(RuntimeError):
    """Existing partial results belong to a different configuration."""


@dataclass
class TaskResult:
    brdf_sp: np.ndarray  # (2, res, res) float32, s and p
    albedo_sp: np.ndarray  # (2,)
    diagnostics: dict

    def brdf(self, polarization: str) -> np.ndarray:
        return combine_polarizations(self.brdf_sp, polarization)


def peak_memory_mb() -> float:
    """Peak resident memory of this process (MB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def execute_task(ctx, plan: Plan, task: Task) -> TaskResult:
    """Simulate one task and reduce its FarField to BRDFs (both polarizations)."""
    scene = plan.scene(task)
    model = get_model(plan.model_name(task))
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ff = model.farfield(ctx, scene)
    brdf_sp = ff.brdf()
    if not np.all(np.isfinite(brdf_sp[:, plan.grid.inside])):
        raise FloatingPointError(f"{task.label}: the model returned NaN/inf inside the disk")
    diag = {
        key: (value if isinstance(value, (int, float, str, bool)) else repr(value))
        for key, value in ff.diagnostics.items()
    }
    messages = sorted({f"{w.category.__name__}: {w.message}" for w in caught})
    for message in messages:
        logger.warning("%s: %s", task.label, message)
    diag.update(
        model=model.name,
        wall_time_s=time.perf_counter() - t0,
        peak_memory_mb=peak_memory_mb(),
        device=ctx.describe(),
        warnings="; ".join(messages),
    )
    return TaskResult(brdf_sp.astype(np.float32), albedo(brdf_sp, plan.grid), diag)


class PartsFolder:
    """Finished task results next to the output file, for resume."""

    def __init__(self, plan: Plan):
        self.plan = plan
        output = Path(plan.config.output)
        self.path = output.with_name(output.name + ".parts")
        self.manifest = self.path / "manifest.json"

    def open(self) -> None:
        """Create the folder, or check that an existing one belongs to this plan."""
        expected = {"fingerprint": self.plan.fingerprint, "tasks": len(self.plan.tasks)}
        if self.manifest.exists():
            found = json.loads(self.manifest.read_text())
            if {k: found.get(k) for k in expected} != expected:
                raise ResumeError(
                    f"{self.path} holds partial results of a different configuration "
                    f"(fingerprint {found.get('fingerprint')} vs {expected['fingerprint']}); "
                    "delete that folder to start over, or restore the original config to resume"
                )
            return
        self.path.mkdir(parents=True, exist_ok=True)
        _atomic_write_bytes(self.manifest, json.dumps({**expected, "software_version": __version__}).encode())

    def _file(self, task: Task) -> Path:
        return self.path / f"task-{task.id:06d}.npz"

    def done(self, task: Task) -> bool:
        return self._file(task).exists()

    def save(self, task: Task, result: TaskResult) -> None:
        target = self._file(task)
        tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
        with open(tmp, "wb") as fh:
            np.savez(fh, brdf_sp=result.brdf_sp, albedo_sp=result.albedo_sp,
                     diagnostics=np.array(json.dumps(result.diagnostics)))
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)

    def load(self, task: Task) -> TaskResult:
        with np.load(self._file(task)) as data:
            return TaskResult(data["brdf_sp"], data["albedo_sp"], json.loads(str(data["diagnostics"])))

    def remove(self) -> None:
        shutil.rmtree(self.path, ignore_errors=True)


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def _progress(total: int, initial: int, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, unit="task", disable=not enabled, file=sys.stderr,
                dynamic_ncols=True, desc="simulating")


def run_plan(plan: Plan, ctx, *, progress: bool = True) -> Path:
    """Run every missing task of ``plan`` in this process, then write the dataset."""
    parts = PartsFolder(plan)
    parts.open()
    pending = [t for t in plan.tasks if not parts.done(t)]
    if len(pending) < len(plan.tasks):
        logger.info("resuming: %d of %d tasks already done", len(plan.tasks) - len(pending), len(plan.tasks))
    with _progress(len(plan.tasks), len(plan.tasks) - len(pending), progress) as bar:
        for task in pending:
            result = execute_task(ctx, plan, task)
            parts.save(task, result)
            logger.info("%s: %s %.2f s, peak %.0f MB", task.label, result.diagnostics["model"],
                        result.diagnostics["wall_time_s"], result.diagnostics["peak_memory_mb"])
            bar.update(1)
    path = write_dataset(plan, parts, device=ctx.describe())
    parts.remove()
    return path


def write_dataset(plan: Plan, parts: PartsFolder, device: str) -> Path:
    """Assemble the HDF5 dataset from the finished parts (one writer, atomic rename)."""
    study = plan.study
    output = Path(plan.config.output)
    with atomic_h5(output) as h5:
        writer = DatasetWriter(
            h5, plan.config.sweep_axes, plan.wavelengths_um, plan.directions_deg, plan.grid.resolution,
            study.illumination.polarization, study.output_options.per_polarization,
        )
        writer.create(config_text=plan.config.text, study=study.name, software_version=__version__, device=device)
        shape = plan.config.case_shape
        for case, case_index in enumerate(np.ndindex(*shape) if shape else [()]):
            surface = plan.surface(case)
            writer.write_case(tuple(case_index), str(case), surface.z, surface.size_um, surface.statistics(),
                              plan.index(case))
        rows = []
        for task in plan.tasks:
            result = parts.load(task)
            pol = plan.config.cases[task.case].illumination.polarization
            brdf = result.brdf(pol)
            writer.write_result(task.case_index, task.wavelength, task.incidence, result.brdf_sp, brdf,
                                result.albedo_sp, float(albedo(brdf, plan.grid)))
            rows.append({"id": task.id, "case": task.case, "wavelength_index": task.wavelength,
                         "incidence_index": task.incidence, "status": "done", **result.diagnostics})
        writer.write_tasks(_uniform_rows(rows))
    return output


def _uniform_rows(rows: list[dict]) -> list[dict]:
    """Give every row the same keys (missing diagnostics become empty strings)."""
    keys = list(dict.fromkeys(k for r in rows for k in r))
    return [{k: r.get(k, "") for k in keys} for r in rows]
