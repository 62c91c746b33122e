"""A validated study: the typed objects jobs/config.py makes of a config, which plan, tasks and
store read. Paths are resolved, tables read and defaults that depend on other sections filled
in; ``[steering]``, ``[run]`` and ``[output]`` are their sections' dataclasses
(jobs/sections.py) as parsed. Each spec builds its solver object (``build()``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from wavebrdf.jobs.sections import OutputSection, RunSection, SteeringSection
from wavebrdf.jobs.steering import GlobalSurface
from wavebrdf.solver.materials import Material
from wavebrdf.solver.models import get_model, model_class
from wavebrdf.solver.surface import HeightField, SurfaceError, generate, load_heights

__all__ = ["FiberSpec", "IlluminationSpec", "MaterialSpec", "ModelSpec", "Study", "StudyConfig", "SurfaceSpec"]

OUTLINE_NODES = 360  # a circle's or an ellipse's outline without [fiber] segments (the Mie model needs no mesh)


@dataclass(frozen=True)
class SurfaceSpec:
    size_um: float | tuple[float, float]  # L, or (L_x, L_y) for a rectangular (steering) surface
    file: Path | None
    generator: str | None
    cells: int | tuple[int, int]  # N, or (N_x, N_y)
    seed: int
    parameters: dict  # the generator's keys as given (converted)

    @property
    def rectangular(self) -> bool:
        """A generated surface with two different sides (files: known once read)."""
        return self.file is None and isinstance(self.cells, tuple)

    def build(self):
        """Load or generate the :class:`~wavebrdf.solver.surface.HeightField` — or, for a
        rectangle (``size_um``/``cells`` pairs, or a non-square file), the steering layer's
        :class:`~wavebrdf.jobs.steering.GlobalSurface` (refused outside ``[steering]`` studies)."""
        if self.file is not None:
            z = load_heights(self.file)
            sides = self.size_um if isinstance(self.size_um, tuple) else None
            if z.ndim == 2 and z.shape[0] != z.shape[1] and min(z.shape) > 1:
                if sides is None:
                    raise SurfaceError(f"height matrix must be square ((N+1)x(N+1)), got {z.shape[0]}x{z.shape[1]} "
                                       "(rows = x, columns = y); a rectangular global surface of a [steering] study "
                                       "needs size_um = [L_x, L_y]")

                return GlobalSurface(z, sides)
            if sides is not None and sides[0] != sides[1]:
                raise SurfaceError(f"size_um = [{sides[0]:g}, {sides[1]:g}] is not square but the file holds "
                                   f"{z.shape[0]}x{z.shape[1]} heights")
            return HeightField(z, sides[0] if sides else self.size_um)
        if self.rectangular:
            return GlobalSurface.generated(self.generator, cells=self.cells, sides_um=self.size_um, seed=self.seed,
                                           **self.parameters)
        return generate(self.generator, cells=self.cells, size_um=self.size_um, seed=self.seed, **self.parameters)


@dataclass(frozen=True)
class MaterialSpec:
    name: str | None
    table: tuple | None  # rows (λ µm, n, κ): [material] table, or the rows read from ``file``
    n: float | None
    kappa: float
    exterior_index: float
    file: Path | None = None  # [material] file (its rows are ``table``)

    def build(self):
        if self.name is not None:
            return Material.from_name(self.name)
        if self.table is not None:
            return Material.from_table(self.table, name=f"file {self.file.name}" if self.file else "table")
        return Material.from_constant(self.n, self.kappa)


@dataclass(frozen=True)
class IlluminationSpec:
    wavelengths_um: tuple[float, ...]
    directions_deg: tuple[tuple[float, float], ...]  # surfaces (empty for fibers)
    waist_um: float | None
    polarization: str
    beam: str
    theta_i_deg: tuple[float, ...] = ()  # fibers
    phi_i_deg: tuple[float, ...] | None = None  # fibers: explicit azimuths (None: bins)


@dataclass(frozen=True)
class FiberSpec:
    """Cross section of a fiber study ([fiber]); lengths in µm."""

    shape: str
    radius_um: float | None
    semi_axes_um: tuple[float, float] | None
    points_file: Path | None
    segments: int | None
    rotation_deg: float
    longitudinal_variance: float = 0.02  # d'Eon's v (rad²), the dataset's default for M0

    @property
    def meshed(self) -> bool:
        """Its nodes are a mesh chosen for it (``segments``, or a polygon's own points), not the
        :data:`OUTLINE_NODES` of a smooth shape's outline, which models that need no mesh read."""
        return self.shape == "polygon" or self.segments is not None

    def build(self):
        """The :class:`~wavebrdf.solver.fiber.CrossSection`."""
        from wavebrdf.solver import fiber

        rotation = np.deg2rad(self.rotation_deg)
        if self.shape == "circle":
            return fiber.circle(self.radius_um, self.segments or OUTLINE_NODES, rotation=rotation)
        if self.shape == "ellipse":
            return fiber.ellipse(*self.semi_axes_um, self.segments or OUTLINE_NODES, rotation=rotation)
        section = fiber.load_shape(self.points_file, segments=self.segments)
        if self.rotation_deg:
            c, s = np.cos(rotation), np.sin(rotation)
            section = fiber.CrossSection(section.nodes @ np.array([[c, s], [-s, c]]), name=section.name)
        return section


@dataclass(frozen=True)
class ModelSpec:
    """The model of a study: its registry name, precision and parsed Options dataclass."""

    name: str
    precision: str
    options: Any = None

    def build(self):
        """A new instance of the model with these options."""
        return get_model(self.name, self.options)

    @property
    def capabilities(self):
        return model_class(self.name).capabilities


@dataclass(frozen=True)
class Study:
    """One fully validated case of a study (one combination of the sweep values)."""

    name: str
    output: Path
    surface: SurfaceSpec | None
    material: MaterialSpec
    illumination: IlluminationSpec
    model: ModelSpec
    output_options: OutputSection
    steering: SteeringSection | None
    run: RunSection
    fiber: FiberSpec | None
    sections: dict = field(repr=False)  # every section's validated values (jobs/sections.py section_record)
    sweep_values: dict = field(default_factory=dict)  # {"surface.rms_height_um": 0.1, ...}

    @property
    def is_fiber(self) -> bool:
        return self.fiber is not None


@dataclass(frozen=True)
class StudyConfig:
    """A parsed config file: its text, the sweep axes and the validated cases."""

    text: str
    path: Path | None
    sweep_axes: dict  # {"section.key": (values...)} in file order
    cases: tuple[Study, ...]

    @property
    def name(self) -> str:
        return self.cases[0].name

    @property
    def output(self) -> Path:
        return self.cases[0].output

    @property
    def case_shape(self) -> tuple[int, ...]:
        return tuple(len(v) for v in self.sweep_axes.values())
