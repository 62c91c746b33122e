"""Planning: expand a study into tasks, with a memory/time estimate for each.

Without steering, one ``direct`` task per (sweep case, wavelength, incident direction). With
``[steering]``, the requested directions are mapped to basic directions (hexagon territories,
jobs/steering.py) and the plan holds one ``patch`` task per (case, wavelength, basic direction,
sub-area) plus one ``synth`` task per (case, wavelength, requested direction) that depends on
the patch tasks of its basic direction; patch tasks run sub-area → wavelength → basic direction
(the scheduler keeps a sub-area on one worker, jobs/scheduler.py). Every task's result slot in the dataset is given by
(case, wavelength, incidence) of the direct/synth tasks (:func:`surface_tasks`). Fiber studies
have one ``fiber`` task per (case, wavelength, θ_i) that solves every φ_i and both polarizations at
once (:func:`fiber_tasks`). The study's kind (jobs/study_kinds.py) says which layout a study takes,
the scene and direction of each task; what each task kind runs, estimates, saves and writes is the
table jobs/tasks.py ``KINDS``.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from dataclasses import dataclass, field
from functools import cached_property, lru_cache

import numpy as np

from wavebrdf.jobs.study import ModelSpec, Study, StudyConfig
from wavebrdf.jobs.executors import resolve_executor
from wavebrdf.jobs.spot_checks import add_spot_checks
from wavebrdf.jobs.steering import HexagonTiling, PatchLayout
from wavebrdf.jobs.tasks import KINDS
from wavebrdf.solver.farfield import HemisphereGrid
from wavebrdf.solver.models import Estimate, FiberScene, SurfaceScene
from wavebrdf.solver.opencl import OpenCLUnavailable, choose_device, list_devices
from wavebrdf.solver.resources import meminfo_bytes

logger = logging.getLogger(__name__)

__all__ = ["Plan", "PlanError", "Task", "check_memory", "device_info", "estimate_tasks", "fiber_tasks", "format_bytes",
           "format_number", "node_memory_bytes", "plan_study", "surface_tasks"]

ESTIMATE_PROGRESS_S = 10.0  # seconds between the progress lines of estimate_tasks


class PlanError(ValueError):
    """The study cannot be planned as configured (e.g. tasks do not fit in memory)."""


@dataclass(frozen=True)
class Task:
    """One unit of work. ``kind``: "direct" | "patch" | "synth" | "fiber" | "check" (``incidence`` = θ_i
    index). A "check" (``auto``'s spot check, jobs/spot_checks.py) has the indices of the direct or
    patch task whose scene it checks; ``checks``: the spot checks whose measurements a task's model
    reads (also in ``depends``)."""

    id: int
    kind: str
    case: int
    case_index: tuple[int, ...]
    wavelength: int
    incidence: int = -1  # direct / synth: requested direction
    basic: int = -1  # patch / synth: basic direction
    patch: tuple[int, ...] = ()  # patch: (a, b)
    depends: tuple[int, ...] = ()
    checks: tuple[int, ...] = ()

    @property
    def on_patch(self) -> bool:
        """It simulates one steering sub-area (a patch task or a patch's spot check)."""
        return bool(self.patch)

    @property
    def label(self) -> str:
        where = f"case {self.case}, λ#{self.wavelength}"
        if self.on_patch:
            return f"{self.kind} {self.patch} of basic #{self.basic} ({where})"
        return f"{self.kind} incidence #{self.incidence} ({where})"

    @property
    def writes_result(self) -> bool:
        return KINDS[self.kind].writes_result

    @property
    def key(self) -> str:
        """What the task computes, as stored in its part file: kind, case, wavelength, incidence,
        basic direction, patch (indices)."""
        patch = "x".join(map(str, self.patch)) or "-"
        return (f"{self.kind}:case={self.case}:wl={self.wavelength}:inc={self.incidence}:basic={self.basic}"
                f":patch={patch}")


@dataclass
class CaseSteering:
    """Steering set-up of one case: layout, basic directions, assignment of each request."""

    layout: PatchLayout
    basics_rad: np.ndarray  # (K, 2)
    basic_of: np.ndarray  # (n_incidence,) index into basics
    tiling: HexagonTiling


@dataclass
class Plan:
    config: StudyConfig
    tasks: list[Task] = field(default_factory=list)
    steering: dict[int, CaseSteering] = field(default_factory=dict)
    _geometry: dict = field(default_factory=dict, repr=False)  # built height fields / cross sections
    tasks_per_node: int | None = None  # set by `plan`/`run` to what they check memory with (None: from [run])
    spot_check_units: dict = field(default_factory=dict, repr=False)  # case → auto's (CheckUnits, checked ones)
    series_heads: dict = field(default_factory=dict, repr=False)  # task → first task of its series (spot checks)

    @property
    def study(self) -> Study:
        return self.config.cases[0]

    @cached_property
    def grid(self) -> HemisphereGrid:
        return HemisphereGrid(self.study.output_options.resolution)

    @cached_property
    def wavelengths_um(self) -> np.ndarray:
        """The study's vacuum wavelengths (µm), built once (read-only: shared by every task)."""
        return _read_only(np.array(self.study.illumination.wavelengths_um))

    @cached_property
    def directions_deg(self) -> np.ndarray:
        """The requested incident directions (θ, φ) in degrees, built once (read-only)."""
        return _read_only(np.array(self.study.illumination.directions_deg))

    @property
    def needs_fp64(self) -> bool:
        """Whether a case runs at [model] precision = "double" (the device needs cl_khr_fp64)."""
        return any(case.model.precision.fp64 for case in self.config.cases)

    def cross_section(self, case: int):
        """The fiber cross section of ``case``, built once."""
        key = ("fiber", case)
        if key not in self._geometry:
            self._geometry[key] = self.config.cases[case].fiber.build()
        return self._geometry[key]

    def surface(self, case: int):
        """The (global) height field of ``case``, built once."""
        key = ("surface", case)
        if key not in self._geometry:
            self._geometry[key] = self.config.cases[case].surface.build()
        return self._geometry[key]

    def index(self, case: int) -> np.ndarray:
        """Material index n − jκ of ``case`` at every wavelength, computed once per case (a task
        reads its entry in O(1), so planning stays linear in the number of tasks)."""
        key = ("index", case)
        if key not in self._geometry:
            material = self.config.cases[case].material
            self._geometry[key] = _read_only(_material_index(material, self.study.illumination.wavelengths_um))
        return self._geometry[key]

    def direction_rad(self, task: Task) -> tuple[float, float]:
        """(θ, φ) simulated by ``task`` (its study kind's ``direction_rad``)."""
        return self.study.kind.direction_rad(self, task)

    def surface_direction_rad(self, task: Task) -> tuple[float, float]:
        """(θ, φ) of a surface task: the basic direction for patches, else the requested one."""
        if task.on_patch:
            theta, phi = self.steering[task.case].basics_rad[task.basic]
            return float(theta), float(phi)
        theta, phi = self.config.cases[task.case].illumination.directions_deg[task.incidence]
        return float(np.deg2rad(theta)), float(np.deg2rad(phi))

    def scene(self, task: Task, *, basic: int | None = None) -> SurfaceScene:
        """The scene a task simulates. For synth tasks, ``basic`` gives the patch-beam scene
        (basic direction, footprint at the patch centre) used for the incident power."""
        study = self.config.cases[task.case]
        surface = self.surface(task.case)
        z_reference = None
        if task.on_patch or basic is not None:
            st = self.steering[task.case]
            patch = task.patch if task.on_patch else st.layout.indices[0]
            z_reference = float(np.mean(surface.z))
            surface = st.layout.cut(surface, patch)
            theta, phi = st.basics_rad[task.basic if basic is None else basic]
        else:
            theta, phi = self.surface_direction_rad(task)
        return SurfaceScene(
            surface=surface,
            wavelength_um=study.illumination.wavelengths_um[task.wavelength],
            index=complex(self.index(task.case)[task.wavelength]),
            theta_i=float(theta),
            phi_i=float(phi),
            waist_um=study.illumination.waist_um,
            grid=self.grid,
            exterior_index=study.material.exterior_index,
            beam=study.illumination.beam,
            precision=study.model.precision,
            z_reference=z_reference,
            memory_budget_bytes=self.task_memory_budget(task.case),
            coherent=task.on_patch,
            polarimetric=study.output_options.polarization != "intensity",
        )

    def task_memory_budget(self, case: int) -> float:
        """Bytes one task may use: [run] memory_gb (default: this node's memory) over the tasks at
        once on a node, as ``plan`` and ``run`` count them (jobs/executors.py)."""
        study = self.config.cases[case]
        node = study.run.memory_gb * 2**30 if study.run.memory_gb else node_memory_bytes()
        if self.tasks_per_node is not None:
            return node / max(1, self.tasks_per_node)
        return node / max(1, resolve_executor(study.run.executor).tasks_per_node(study))

    def model_scene(self, task: Task) -> SurfaceScene | FiberScene:
        """What the task's model simulates (its study kind's ``scene``): the (patch) surface scene,
        or a fiber scene."""
        return self.study.kind.scene(self, task)

    def model_spec(self, task: Task) -> ModelSpec:
        return self.config.cases[task.case].model

    def model_name(self, task: Task) -> str:
        return self.model_spec(task).name

    def estimate(self, task: Task) -> Estimate:
        """Memory/time of ``task`` (jobs/tasks.py KINDS)."""
        return KINDS[task.kind].estimate(self, task)

    @cached_property
    def fingerprint(self) -> str:
        """Hash of everything that determines the results (not the output path or name)."""
        cases = []
        for study in self.config.cases:
            sections = {s: dict(v) for s, v in study.sections.items() if s not in ("study", "run")}
            for section, key, path in study.kind.input_files(study):
                sections[section][key] = _file_digest(str(path))
            cases.append(sections)
        blob = json.dumps({"cases": cases, "sweep": {k: list(v) for k, v in self.config.sweep_axes.items()}},
                          sort_keys=True, default=repr)
        return hashlib.sha256(blob.encode()).hexdigest()[:20]

    def result_tasks(self) -> list[Task]:
        return [t for t in self.tasks if t.writes_result]


def _material_index(material_spec, wavelengths: tuple[float, ...]) -> np.ndarray:
    """n − jκ of ``material_spec`` at ``wavelengths`` (µm)."""
    return material_spec.build().index(np.array(wavelengths))


def _read_only(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


@lru_cache(maxsize=64)
def _file_digest(path: str) -> str:
    with open(path, "rb") as fh:
        return hashlib.sha256(fh.read()).hexdigest()[:20]


def _case_steering(plan: Plan, case: int) -> CaseSteering:
    study = plan.config.cases[case]
    spec = study.steering
    surface = plan.surface(case)
    try:  # "auto" per axis; the surface may be a rectangle (GlobalSurface)
        layout = PatchLayout.for_surface(surface, spec.patches, spec.patch_size_um, spec.shift_um)
        layout.check(surface)
    except ValueError as exc:
        raise PlanError(f"[steering] {exc}") from None
    tiling = HexagonTiling.for_beam(min(study.illumination.wavelengths_um), study.illumination.waist_um,
                                    study.material.exterior_index, spec.hexagon_fill)
    if spec.hexagon_fill > 1.0:
        logger.warning("[steering] hexagon_fill = %g > 1: derived directions may lie beyond the aliasing limit "
                       "λ_min/(π w) and show grating-lobe artefacts", spec.hexagon_fill)
    directions = np.deg2rad(np.array(study.illumination.directions_deg))
    basic_of, basics = tiling.assign(directions)
    return CaseSteering(layout, basics, basic_of, tiling)


def plan_study(config: StudyConfig) -> Plan:
    """All tasks of ``config``, as its study kind lays them out (``tasks``)."""
    plan = Plan(config)
    plan.tasks = config.cases[0].kind.tasks(plan)
    return plan


def fiber_tasks(plan: Plan) -> list[Task]:
    """A fiber study's tasks: one per (case, wavelength, θ_i), every φ_i at once."""
    ill = plan.study.illumination
    return [Task(i, "fiber", case, case_index, wl, th)
            for i, (case, case_index, wl, th) in enumerate(
                (c, ci, wl, th) for c, ci in plan.config.case_indices()
                for wl in range(len(ill.wavelengths_um)) for th in range(len(ill.theta_i_deg)))]


def surface_tasks(plan: Plan) -> list[Task]:
    """A surface study's tasks: patch tasks first (case, sub-area, wavelength, basic direction),
    then the result tasks (case, wavelength, direction), then auto's spot checks."""
    config = plan.config
    n_wl = len(config.cases[0].illumination.wavelengths_um)
    n_inc = len(config.cases[0].illumination.directions_deg)
    cases = config.case_indices()
    tasks: list[Task] = []
    patch_ids: dict[tuple, list[int]] = {}
    for case, case_index in cases:
        if config.cases[case].steering is None:
            continue
        model = config.cases[case].model
        if not model.capabilities.steerable:
            raise PlanError(f"[steering]: model {model.name!r} cannot be steered (it returns "
                            f"{model.capabilities.returns}); remove [steering] or choose a steerable model")
        st = plan.steering[case] = _case_steering(plan, case)
        # sub-area-major, then wavelength: one operator serves all basic directions, and each
        # solve starts from the previous wavelength's solution of its sub-area (bem3d/warm_start.py)
        for patch in st.layout.indices:
            for wl in range(n_wl):
                for b in range(len(st.basics_rad)):
                    patch_ids.setdefault((case, wl, b), []).append(len(tasks))
                    tasks.append(Task(len(tasks), "patch", case, case_index, wl, basic=b,
                                      patch=patch))
    for case, case_index in cases:
        st = plan.steering.get(case)
        for wl in range(n_wl):
            for inc in range(n_inc):
                if st is None:
                    tasks.append(Task(len(tasks), "direct", case, case_index, wl, inc))
                else:
                    b = int(st.basic_of[inc])
                    tasks.append(Task(len(tasks), "synth", case, case_index, wl, inc, basic=b,
                                      depends=tuple(patch_ids[(case, wl, b)])))
    plan.tasks = tasks
    add_spot_checks(plan)
    return plan.tasks


def node_memory_bytes() -> float:
    """Physical memory of this machine (bytes)."""
    return float(meminfo_bytes("MemTotal"))


def device_info(spec: str | None = None):
    """The OpenCL device a run would use (``spec``, else WAVEBRDF_DEVICE, else auto) as a
    :class:`~wavebrdf.solver.opencl.DeviceInfo`, without creating a context; None without OpenCL."""
    try:
        return choose_device(spec or os.environ.get("WAVEBRDF_DEVICE", "auto"), list_devices())
    except OpenCLUnavailable:
        return None


def format_bytes(size: float) -> str:
    """``size`` bytes in GiB with 3 significant digits ("9.4 GiB", "0.0143 GiB", "9.31e+240 GiB"):
    never a long string of digits, whatever the size."""
    return f"{size / 2**30:.3g} GiB"


def format_number(value: float, width: int = 0, decimals: int = 2) -> str:
    """``value`` with ``decimals`` decimals while that stays short (< 1e6), else in engineering
    form ("4.72e+12"), right-aligned in ``width``: table cells of `plan` never run to many digits."""
    text = f"{value:.{decimals}f}" if abs(value) < 1e6 else f"{value:.3g}"
    return text.rjust(width)


def _largest(rows, value):
    """(value, task, estimate) of the largest reported ``value(estimate)`` (None when no task reports it)."""
    found = [(value(e), t, e) for e, t in rows if value(e) is not None]
    return max(found, key=lambda x: x[0]) if found else None


def estimate_tasks(plan: Plan) -> list[Estimate]:
    """Every task's estimate, in order, with a line on stderr every :data:`ESTIMATE_PROGRESS_S`
    while it lasts (a study of thousands of full-wave patches fits its AIM settings per patch:
    minutes for configs/reference_subareas.toml)."""
    from wavebrdf.jobs.progress import emit

    out, started = [], time.monotonic()
    last = started
    for done, task in enumerate(plan.tasks, 1):
        out.append(plan.estimate(task))
        now = time.monotonic()
        if now - last >= ESTIMATE_PROGRESS_S and done < len(plan.tasks):
            last = now
            emit(f"estimated {done} of {len(plan.tasks)} tasks in {now - started:.0f} s")
    return out


def check_memory(plan: Plan, workers_per_node: int, memory_gb: float | None = None, device=None,
                 estimates: list[Estimate] | None = None) -> float:
    """Refuse a plan whose tasks cannot fit; return the node's host memory budget (bytes).

    Host: the largest task times the tasks at once per node against ``memory_gb`` (default:
    this machine's RAM). ``device`` (a DeviceInfo, shared by the node's workers): the largest
    single buffer a task reports (``Estimate.largest_buffer_bytes``) against the device's max
    allocation, and its device memory (``Estimate.device_bytes``, else that buffer) times the
    tasks at once against the device's global memory. ``estimates``: those of ``plan.tasks``
    when already computed."""
    budget = (memory_gb * 2**30) if memory_gb else node_memory_bytes()
    rows = list(zip(estimates or estimate_tasks(plan), plan.tasks))
    need, task, _ = _largest(rows, lambda e: e.memory_bytes)
    gib = 2**30
    if need * workers_per_node > budget:
        raise PlanError(
            f"{task.label} needs about {format_bytes(need)}; with {workers_per_node} task(s) at once per node "
            f"that is {format_bytes(need * workers_per_node)}, more than the node's {format_bytes(budget)} "
            "([run] memory_gb). Use fewer workers/ranks per node, a coarser grid or smaller patches."
        )
    if device is None:
        return budget
    where = f"device {device.name!r}"
    largest = _largest(rows, lambda e: e.largest_buffer_bytes)
    if largest is not None and largest[0] > device.max_alloc_gib * gib:
        size, task, estimate = largest
        raise PlanError(
            f"{task.label} needs one device buffer of {format_bytes(size)} ({estimate.detail}), more than the max "
            f"allocation of the {where} "
            f"({format_bytes(device.max_alloc_gib * gib)}). Use a coarser grid or smaller patches, or another device "
            "(WAVEBRDF_DEVICE; 'wavebrdf devices' lists them)."
        )
    held = _largest(rows, lambda e: e.device_bytes or e.largest_buffer_bytes)
    if held is not None and held[0] * workers_per_node > device.global_mem_gib * gib:
        size, task, _ = held
        raise PlanError(
            f"{task.label} holds about {format_bytes(size)} on the device; with {workers_per_node} task(s) at once "
            f"that is {format_bytes(size * workers_per_node)}, more than the global memory of the {where} "
            f"({format_bytes(device.global_mem_gib * gib)}). Use fewer workers/ranks per node, a coarser grid or "
            "smaller patches, or another device (WAVEBRDF_DEVICE)."
        )
    return budget
