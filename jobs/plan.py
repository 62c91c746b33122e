"""Planning: expand a study into tasks (sweep case × wavelength × incident direction).

Each :class:`Task` is one independent simulation that returns a FarField. The :class:`Plan`
builds the :class:`~wavebrdf.solver.models.SurfaceScene` of a task on demand and carries a
memory/time estimate per task from the model.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from functools import cached_property, lru_cache

import numpy as np

from wavebrdf.jobs.config import Study, StudyConfig
from wavebrdf.solver.farfield import HemisphereGrid
from wavebrdf.solver.models import Estimate, SurfaceScene, get_model

__all__ = ["Plan", "Task", "plan_study"]


@dataclass(frozen=True)
class Task:
    """One simulation: indices into the study's axes."""

    id: int
    case: int  # flat index of the sweep case
    case_index: tuple[int, ...]  # multi-index along the sweep axes
    wavelength: int
    incidence: int

    @property
    def label(self) -> str:
        return f"task {self.id} (case {self.case}, wavelength #{self.wavelength}, incidence #{self.incidence})"


@dataclass
class Plan:
    config: StudyConfig
    tasks: list[Task]
    _surfaces: dict = field(default_factory=dict, repr=False)

    @property
    def study(self) -> Study:
        return self.config.cases[0]

    @cached_property
    def grid(self) -> HemisphereGrid:
        return HemisphereGrid(self.study.output_options.resolution)

    @property
    def wavelengths_um(self) -> np.ndarray:
        return np.array(self.study.illumination.wavelengths_um)

    @property
    def directions_deg(self) -> np.ndarray:
        return np.array(self.study.illumination.directions_deg)

    def surface(self, case: int):
        if case not in self._surfaces:
            self._surfaces[case] = self.config.cases[case].surface.build()
        return self._surfaces[case]

    def index(self, case: int) -> np.ndarray:
        """Material index n − jκ of ``case`` at every wavelength."""
        return _material_index(self.config.cases[case].material, tuple(self.wavelengths_um))

    def scene(self, task: Task) -> SurfaceScene:
        study = self.config.cases[task.case]
        theta, phi = study.illumination.directions_deg[task.incidence]
        return SurfaceScene(
            surface=self.surface(task.case),
            wavelength_um=study.illumination.wavelengths_um[task.wavelength],
            index=complex(self.index(task.case)[task.wavelength]),
            theta_i=np.deg2rad(theta),
            phi_i=np.deg2rad(phi),
            waist_um=study.illumination.waist_um,
            grid=self.grid,
            exterior_index=study.material.exterior_index,
            beam=study.illumination.beam,
            precision=study.model.precision,
        )

    def model_name(self, task: Task) -> str:
        return self.config.cases[task.case].model.name

    def estimate(self, task: Task) -> Estimate:
        return get_model(self.model_name(task)).estimate(self.scene(task))

    @cached_property
    def fingerprint(self) -> str:
        """Hash of everything that determines the results (not the output path or name)."""
        cases = []
        for study in self.config.cases:
            sections = {s: dict(v) for s, v in study.sections.items()}
            sections["study"] = {}
            if study.surface.file is not None:
                sections["surface"]["file"] = _file_digest(str(study.surface.file))
            cases.append(sections)
        blob = json.dumps({"cases": cases, "sweep": {k: list(v) for k, v in self.config.sweep_axes.items()}},
                          sort_keys=True, default=repr)
        return hashlib.sha256(blob.encode()).hexdigest()[:20]


@lru_cache(maxsize=64)
def _material_index(material_spec, wavelengths: tuple[float, ...]) -> np.ndarray:
    return material_spec.build().index(np.array(wavelengths))


@lru_cache(maxsize=64)
def _file_digest(path: str) -> str:
    with open(path, "rb") as fh:
        return hashlib.sha256(fh.read()).hexdigest()[:20]


def plan_study(config: StudyConfig) -> Plan:
    """All tasks of ``config`` in a fixed order (case-major, then wavelength, then incidence)."""
    shape = config.case_shape
    n_wl = len(config.cases[0].illumination.wavelengths_um)
    n_inc = len(config.cases[0].illumination.directions_deg)
    tasks = []
    for case, case_index in enumerate(np.ndindex(*shape) if shape else [()]):
        for wl in range(n_wl):
            for inc in range(n_inc):
                tasks.append(Task(len(tasks), case, tuple(int(i) for i in case_index), wl, inc))
    return Plan(config, tasks)
