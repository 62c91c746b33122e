"""Study kinds: a surface study (a height field → BRDFs) and a fiber study (a fiber cross section →
BCSDF tables), two kinds behind one interface.

A config is of the kind whose section it gives (``[surface]`` or ``[fiber]``); the study carries
it (``Study.kind``), a dataset names it (root attribute ``kind``; :func:`study_kind`), and every
layer where the two differ asks the kind instead of testing which one it has:

================  ===========================================================================
asked by          what the kind answers
================  ===========================================================================
config            ``section`` and ``geometry`` (a config gives exactly one kind's section),
                  ``spec`` (the section's spec), ``illumination_keys`` (keys only it reads),
                  ``required_illumination``, ``model_inputs`` (the ``Capabilities.takes`` of its
                  models), ``check_sections`` (what it refuses across sections)
load checks       ``check(study, index)``: the built geometry and the model's own checks
plan, tasks       ``tasks(plan)``, ``scene(plan, task)`` (what the task's model simulates),
                  ``direction_rad``, ``phi_text`` (progress lines), ``input_files`` (fingerprint)
store             ``writer(h5, plan)``, ``write_case``, ``task_row`` (the layouts: jobs/store.py)
render, inspect   ``pictures`` (jobs/pictures/<kind>.py), ``directions_axis``, ``summary_table``
compare, Mitsuba  ``comparable`` (``wavebrdf compare`` measures its rungs), ``plugin``, ``scenes``
================  ===========================================================================

A new kind is one :class:`StudyKind` here, added to :data:`STUDY_KINDS`, with its config section
(jobs/sections.py), its dataset layout and writer (jobs/store.py) and its pictures module.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from pathlib import Path
from types import ModuleType
from typing import ClassVar

import numpy as np

from wavebrdf.jobs.errors import ConfigError, fmt
from wavebrdf.jobs.pictures import fiber as fiber_pictures
from wavebrdf.jobs.pictures import surface as surface_pictures
from wavebrdf.jobs.plan import fiber_tasks, surface_tasks
from wavebrdf.jobs.progress import degrees_text
from wavebrdf.jobs.store import FiberDatasetWriter, SurfaceDatasetWriter
from wavebrdf.jobs.study import FiberSpec, Study, SurfaceSpec
from wavebrdf.jobs.study_checks import check_model, check_surface, rectangle_outside_steering
from wavebrdf.solver.models import FiberScene

__all__ = ["STUDY_KINDS", "FiberKind", "StudyKind", "SurfaceKind", "study_kind"]


class StudyKind(ABC):
    """What differs between kinds of study (the module docstring lists who asks what)."""

    name: ClassVar[str]  # the dataset's ``kind`` attribute (its layout: jobs/store.py LAYOUTS)
    section: ClassVar[str]  # the config section that makes a study of this kind
    geometry: ClassVar[str]  # what that section describes, in words
    model_inputs: ClassVar[tuple[str, ...]]  # Capabilities.takes of the models it runs
    illumination_keys: ClassVar[tuple[str, ...]]  # [illumination] keys only this kind reads
    required_illumination: ClassVar[tuple[str, ...]]
    directions_axis: ClassVar[str]  # the dataset dimension of its per-direction pictures
    comparable: ClassVar[bool]  # ``wavebrdf compare`` can measure its models against each other
    plugin: ClassVar[str]  # the Mitsuba plugin that reads its datasets
    scenes: ClassVar[tuple[str, ...]]  # the Mitsuba scenes (wavebrdf.mitsuba.render_scene) that show them
    pictures: ClassVar[ModuleType]  # jobs/pictures/<kind>.py: KINDS, Case, PER_CASE, PER_DIRECTION, available

    def __repr__(self) -> str:
        return f"<study kind {self.name!r}>"

    @abstractmethod
    def spec(self, section, keys: dict, given: dict, base_dir: Path) -> tuple[object, dict]:
        """(the spec of the kind's config section, the keys the study's record keeps besides the
        section's own): ``section`` parsed, ``keys`` its other keys, ``given`` as the config gives it."""

    def check_sections(self, spec, data: dict) -> None:
        """Refuse what this kind cannot do with the config's other sections (``data``: the config
        as given); called after the model is known."""

    @abstractmethod
    def check(self, study: Study, index: np.ndarray) -> None:
        """The checks that need the built geometry, and the model's own checks at the hardest
        scenes (``index``: n − jκ at every wavelength); a ConfigError naming the key."""

    @abstractmethod
    def tasks(self, plan) -> list:
        """The plan's tasks (jobs/plan.py Task)."""

    @abstractmethod
    def scene(self, plan, task):
        """What ``task``'s model simulates (a SurfaceScene or a FiberScene)."""

    @abstractmethod
    def direction_rad(self, plan, task) -> tuple[float, float]:
        """(θ, φ) that ``task`` simulates, in radians."""

    @abstractmethod
    def phi_text(self, plan, task) -> str:
        """φ_i of ``task`` in degrees, as progress lines and ``plan`` show it."""

    @abstractmethod
    def input_files(self, study: Study) -> list[tuple[str, str, Path]]:
        """(section, key, path) of the files the study's geometry is read from (their contents
        enter the plan's fingerprint)."""

    @abstractmethod
    def writer(self, h5, plan):
        """The dataset writer of this kind's layout (jobs/store.py)."""

    @abstractmethod
    def write_case(self, writer, plan, case: int, case_index: tuple[int, ...]) -> None:
        """The per-case data of the dataset: the geometry, the material index, ..."""

    @abstractmethod
    def task_row(self, task) -> dict:
        """The columns of ``task``'s row in the dataset's task table that say what it computed."""

    @abstractmethod
    def summary_table(self, ds, coords: dict):
        """``wavebrdf inspect``'s table of a dataset of this kind: (heading, row labels,
        values(case index, row) over wavelengths, bracketed values(case index, row) or None)."""


class SurfaceKind(StudyKind):
    """A height field ([surface]): one task per (case, wavelength, incident direction), or steered
    sub-areas; BRDFs on the projected hemisphere."""

    name = "surface"
    section = "surface"
    geometry = "a height field"
    model_inputs = ("height_field", "statistics")
    illumination_keys = ("directions_deg", "directions_file", "angles", "waist_um", "beam")
    required_illumination = ("directions_deg", "waist_um")
    directions_axis = "incidence"
    comparable = True
    plugin = "wavebrdf"
    scenes = ("sphere", "plate")
    pictures = surface_pictures

    def spec(self, section, keys, given, base_dir):
        spec = SurfaceSpec.from_section(section, keys, given, base_dir)
        return spec, spec.parameters  # the generator's keys, converted

    def check_sections(self, spec: SurfaceSpec, data: dict) -> None:
        if spec.rectangular and "steering" not in data:
            raise rectangle_outside_steering(f"size_um = {fmt(list(spec.size_um))}, cells = {fmt(list(spec.cells))}")

    def check(self, study, index):
        check_surface(study, index)

    def tasks(self, plan):
        return surface_tasks(plan)

    def scene(self, plan, task):
        return plan.scene(task)

    def direction_rad(self, plan, task):
        return plan.surface_direction_rad(task)

    def phi_text(self, plan, task):
        return f"{degrees_text(float(np.rad2deg(plan.direction_rad(task)[1])), 1)}°"

    def input_files(self, study):
        return [] if study.surface.file is None else [("surface", "file", study.surface.file)]

    def writer(self, h5, plan):
        study = plan.study
        return SurfaceDatasetWriter(h5, plan.config.sweep_axes, plan.wavelengths_um, plan.directions_deg,
                                    plan.grid.resolution, study.illumination.polarization,
                                    study.output_options.per_polarization, study.output_options.polarization)

    def write_case(self, writer, plan, case, case_index):
        """The height field with its statistics, the material index, the steering layout."""
        surface = plan.surface(case)
        writer.write_case(case_index, str(case), surface.z, surface.size_um, surface.statistics(), plan.index(case),
                          surface.parameters, surface.ensemble)
        if case in plan.steering:
            writer.write_steering(case_index, plan.steering[case])

    def task_row(self, task):
        return {"id": task.id, "kind": task.kind, "case": task.case, "wavelength_index": task.wavelength,
                "incidence_index": task.incidence, "basic_index": task.basic, "patch": "x".join(map(str, task.patch))}

    def summary_table(self, ds, coords):
        a = ds.albedo
        rows = [f"{degrees_text(t, 2):>6} {degrees_text(p, 2):>7}" for t, p in zip(coords["theta_i"], coords["phi_i"])]
        polarization = f", {ds.brdf_polarization}" if ds.brdf_polarization else ""
        return (f"albedo{polarization} (rows: incidence θi/φi (deg); columns: wavelengths):", rows,
                lambda ci, r: a[ci + (slice(None), r)], None)


class FiberKind(StudyKind):
    """A fiber cross section ([fiber]): one task per (case, wavelength, θ_i) solving every φ_i;
    BCSDF tables."""

    name = "fiber"
    section = "fiber"
    geometry = "a fiber cross section"
    model_inputs = ("cross_section",)
    illumination_keys = ("theta_i_deg", "phi_i_deg")
    required_illumination = ("theta_i_deg",)
    directions_axis = "theta_i"
    comparable = False
    plugin = "wavebrdf_fiber"
    scenes = ("fibers",)
    pictures = fiber_pictures
    DEFAULT_PHI_I_BINS = 72  # φ_i bins of non-circular cross sections

    def spec(self, section, keys, given, base_dir):
        return FiberSpec.from_section(section, base_dir), keys

    def check_sections(self, spec, data):
        if "steering" in data:
            raise ConfigError("[steering] applies to height fields, not to fibers")

    def check(self, study, index):
        """The cross section builds; the model's own checks (e.g. the mesh it needs)."""
        from wavebrdf.solver.fiber import ShapeError  # the fiber package imports scipy

        try:
            section = study.fiber.build()
        except (ShapeError, OSError) as exc:
            raise ConfigError(f"[fiber] {exc}") from None
        theta = np.deg2rad(np.asarray(study.illumination.theta_i_deg, dtype=float))
        check_model(study, lambda w, t: self.study_scene(study, section, w, float(theta[t]), complex(index[w])),
                    theta)

    def tasks(self, plan):
        return fiber_tasks(plan)

    def scene(self, plan, task):
        """The (λ, θ_i) a fiber task solves, every φ_i at once."""
        theta, _ = self.direction_rad(plan, task)
        return self.study_scene(plan.config.cases[task.case], plan.cross_section(task.case), task.wavelength, theta,
                                complex(plan.index(task.case)[task.wavelength]))

    def direction_rad(self, plan, task):
        """θ_i from the plane normal to the axis; φ = 0 (a task solves every φ_i)."""
        return float(np.deg2rad(plan.config.cases[task.case].illumination.theta_i_deg[task.incidence])), 0.0

    def phi_text(self, plan, task):
        """Every φ_i of the table: "all 36", or the one value."""
        phis = self.phi_i_axis_deg(plan.study)
        return f"{degrees_text(float(phis[0]), 1)}°" if len(phis) == 1 else f"all {len(phis)}"

    def input_files(self, study):
        return [] if study.fiber.points_file is None else [("fiber", "points_file", study.fiber.points_file)]

    def writer(self, h5, plan):
        study = plan.study
        return FiberDatasetWriter(h5, plan.config.sweep_axes, plan.wavelengths_um,
                                  np.array(study.illumination.theta_i_deg), self.phi_i_axis_deg(study),
                                  self.phi_r_axis_deg(study),
                                  phi_i_binned=study.illumination.phi_i_deg is None and self.phi_i_bins(study) > 1)

    def write_case(self, writer, plan, case, case_index):
        """The cross section and its width seen from each φ_i, the material index, M0's variance."""
        section = plan.cross_section(case)
        writer.write_case(case_index, str(case), section.nodes,
                          section.width(np.deg2rad(self.phi_i_axis_deg(plan.study))), plan.index(case),
                          plan.config.cases[case].fiber.longitudinal_variance)

    def task_row(self, task):
        return {"id": task.id, "kind": task.kind, "case": task.case, "wavelength_index": task.wavelength,
                "theta_index": task.incidence}

    def summary_table(self, ds, coords):
        c_ext = ds["C_ext"].mean(axis=-2).mean(axis=-1)  # over polarization, then φ_i
        c_sca = ds["C_sca"].mean(axis=-2).mean(axis=-1)
        return ("C_ext (µm, unpolarized, mean over φ_i) [albedo C_sca/C_ext]; rows θi, columns wavelengths:",
                coords["theta_i"], lambda ci, r: c_ext[ci + (slice(None), r)],
                lambda ci, r: c_sca[ci + (slice(None), r)] / c_ext[ci + (slice(None), r)])

    def phi_i_bins(self, study: Study) -> int:
        """The number of φ_i bins (ignored when explicit φ_i samples are given): ``[output]
        phi_i_bins``, else 1 for circles (rotation invariant), :attr:`DEFAULT_PHI_I_BINS` otherwise."""
        if study.output_options.phi_i_bins is not None:
            return study.output_options.phi_i_bins
        return 1 if study.fiber.shape == "circle" else self.DEFAULT_PHI_I_BINS

    def phi_i_axis_deg(self, study: Study) -> np.ndarray:
        """The dataset's φ_i coordinate (degrees): explicit samples or bin centres."""
        explicit = study.illumination.phi_i_deg
        if explicit is not None:
            return np.array(explicit, dtype=float)
        n = self.phi_i_bins(study)
        return np.zeros(1) if n == 1 else 360.0 * np.arange(n) / n

    def phi_r_axis_deg(self, study: Study) -> np.ndarray:
        """φ_r bin centres (degrees)."""
        bins = study.output_options.phi_r_bins
        return 360.0 * np.arange(bins) / bins

    def study_scene(self, study: Study, section, wavelength: int, theta_i: float, index: complex) -> FiberScene:
        """The scene of ``study``'s fiber (cross section ``section``) at wavelength number
        ``wavelength`` and θ_i (radians), every φ_i at once."""
        explicit = study.illumination.phi_i_deg
        spec = study.fiber
        return FiberScene(
            cross_section=section,
            wavelength_um=study.illumination.wavelengths_um[wavelength],
            index=index,
            theta_i=theta_i,
            phi_i=None if explicit is None else tuple(np.deg2rad(explicit)),
            phi_i_bins=self.phi_i_bins(study),
            phi_r_bins=study.output_options.phi_r_bins,
            radius_um=spec.radius_um if spec.shape == "circle" else None,
            precision=study.model.precision,
            shape=spec.shape,
            meshed=spec.meshed,
        )


STUDY_KINDS: dict[str, StudyKind] = {kind.name: kind for kind in (SurfaceKind(), FiberKind())}


def study_kind(name: str) -> StudyKind:
    """The kind a dataset's ``kind`` attribute (or a kind's name) names."""
    if name not in STUDY_KINDS:
        raise KeyError(f"unknown study kind {name!r} (known: {', '.join(STUDY_KINDS)})")
    return STUDY_KINDS[name]
