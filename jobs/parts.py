"""Finished task outputs on disk: ``<output>.parts/``, for resume and for the final assembly.

Every file is written atomically (under a temporary name, fsync, rename), so a run that dies
loses only the tasks in flight. ``manifest.json`` records the plan's fingerprint: a folder of a
different configuration is refused. Files: ``task-<id>.npz`` (result tasks: arrays + JSON
diagnostics), ``patch-<id>.npz`` (sub-area far fields, kept until the dataset is written),
``failed-<id>.json`` (diagnostics of a task that failed for good).
"""

from __future__ import annotations

import json
import os
import shutil
import threading
from pathlib import Path

import numpy as np

from wavebrdf import __version__
from wavebrdf.solver.farfield import FarField

__all__ = ["PartsFolder", "ResumeError", "atomic_write"]


class ResumeError(RuntimeError):
    """Existing partial results belong to a different configuration."""


def atomic_write(path: Path, write) -> None:
    """Write ``path`` through ``write(file)`` under a temporary name, fsync, then rename."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    with open(tmp, "wb") as fh:
        write(fh)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


class PartsFolder:
    """Finished task outputs next to the dataset (see the module docstring)."""

    def __init__(self, plan):
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
        payload = json.dumps({**expected, "software_version": __version__}).encode()
        atomic_write(self.manifest, lambda fh: fh.write(payload))

    def _file(self, task) -> Path:
        prefix = "patch" if task.kind == "patch" else "task"
        return self.path / f"{prefix}-{task.id:06d}.npz"

    def done(self, task) -> bool:
        return self._file(task).exists()

    def save_arrays(self, task, diagnostics: dict, **arrays: np.ndarray) -> None:
        """Store a task's arrays and diagnostics (atomic)."""
        payload = {**arrays, "diagnostics": np.array(json.dumps(diagnostics))}
        atomic_write(self._file(task), lambda fh: np.savez(fh, **payload))

    def load_arrays(self, task) -> tuple[dict, dict]:
        with np.load(self._file(task)) as data:
            arrays = {k: data[k] for k in data.files if k != "diagnostics"}
            return arrays, json.loads(str(data["diagnostics"]))

    def save_farfield(self, task, ff: FarField, diagnostics: dict) -> None:
        arrays = {"E": ff.E, "incident_power": ff.incident_power,
                  "scalars": np.array([ff.wavelength_um, ff.exterior_index, ff.theta_i, ff.phi_i])}
        if ff.H is not None:
            arrays["H"] = ff.H
        self.save_arrays(task, diagnostics, **arrays)

    def load_farfield(self, task) -> FarField:
        arrays, diagnostics = self.load_arrays(task)
        lam, n1, theta, phi = arrays["scalars"]
        return FarField(grid=self.plan.grid, wavelength_um=float(lam), exterior_index=float(n1),
                        theta_i=float(theta), phi_i=float(phi), E=arrays["E"], H=arrays.get("H"),
                        incident_power=arrays["incident_power"], diagnostics=diagnostics)

    def load_diagnostics(self, task) -> dict:
        return self.load_arrays(task)[1]

    def save_failure(self, task, diagnostics: dict) -> None:
        payload = json.dumps(diagnostics).encode()
        atomic_write(self.path / f"failed-{task.id:06d}.json", lambda fh: fh.write(payload))

    def failure(self, task) -> dict | None:
        path = self.path / f"failed-{task.id:06d}.json"
        return json.loads(path.read_text()) if path.exists() else None

    def clear_failure(self, task) -> None:
        (self.path / f"failed-{task.id:06d}.json").unlink(missing_ok=True)

    def remove(self) -> None:
        shutil.rmtree(self.path, ignore_errors=True)
