"""A validated study: the typed objects jobs/config.py makes of a config, which plan, tasks and
store read. Paths are resolved, tables read and defaults that depend on other sections filled
in; ``[steering]``, ``[run]`` and ``[output]`` are their sections' dataclasses
(jobs/sections.py) as parsed. The specs of ``[surface]`` and ``[fiber]`` are made from their
sections (``from_section``) and build their solver objects (``build()``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from wavebrdf.jobs.errors import ConfigError, exactly_one, fmt
from wavebrdf.jobs.input_files import resolve_input_path
from wavebrdf.jobs.sections import (FIBER_SHAPE_KEYS, FiberSection, OutputSection, RunSection, SteeringSection,
                                    SurfaceSection, parse_generator)
from wavebrdf.jobs.steering import GlobalSurface
from wavebrdf.solver.materials import Material
from wavebrdf.solver.models import get_model, model_class
from wavebrdf.solver.precision import Precision
from wavebrdf.solver.surface import GENERATORS, HeightField, SurfaceError, generate, load_heights

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

    @classmethod
    def from_section(cls, s: SurfaceSection, generator_keys: dict, given: dict, base_dir: Path) -> "SurfaceSpec":
        """[surface]: a file or a generator with its keys (``generator_keys``, as given; ``given``:
        the section as the config gives it; relative paths against ``base_dir``)."""
        exactly_one("surface", s, ("file", "generator"))
        file, parameters = None, {}
        size, cells = s.size_um, s.cells
        if s.file is not None:
            file = resolve_input_path(s.file, base_dir)
            if generator_keys:
                raise ConfigError(f"[surface] {next(iter(generator_keys))}: only used with a generator, not with "
                                  "surface.file")
            for key, why in (("cells", "the file's matrix of (N+1)×(N+1) heights gives N"),
                             ("seed", "the heights are read, not drawn")):
                if key in given:  # it would be ignored
                    raise ConfigError(f"[surface] {key} = {fmt(given[key])} and file = {fmt(s.file)}: {key} would "
                                      f"be ignored ({why}); remove {key}")
        else:
            parameters = parse_generator(s.generator, generator_keys)
            if "seed" in given and not GENERATORS[s.generator].Options(**parameters).draws_at_random:
                raise ConfigError(f"[surface] seed = {fmt(given['seed'])} and generator = {fmt(s.generator)}: seed "
                                  "would be ignored (this generator draws nothing at random: every seed gives the "
                                  "same surface); remove seed")
            if isinstance(size, tuple) or isinstance(cells, tuple):  # a rectangle: L_x/N_x = L_y/N_y
                sides = size if isinstance(size, tuple) else (size, size)
                counts = cells if isinstance(cells, tuple) else (cells, cells)
                dx, dy = sides[0] / counts[0], sides[1] / counts[1]
                if abs(dx - dy) > 1e-9 * max(dx, dy):
                    raise ConfigError(f"[surface] size_um = {fmt(list(sides))}, cells = {fmt(list(counts))}: cells "
                                      f"must be square (spacing {dx:.6g} µm along x, {dy:.6g} µm along y); for a "
                                      "rectangle give both as [x, y] pairs with "
                                      "size_um[0]/cells[0] = size_um[1]/cells[1]")
                size, cells = (float(sides[0]), float(sides[1])), (int(counts[0]), int(counts[1]))
                if counts[0] == counts[1]:
                    size, cells = size[0], cells[0]
        return cls(size, file, s.generator, cells, s.seed, parameters)

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

    @classmethod
    def from_section(cls, f: FiberSection, base_dir: Path) -> "FiberSpec":
        """[fiber]: the keys its shape needs, and no other shape's (``points_file`` against ``base_dir``)."""
        needed = FIBER_SHAPE_KEYS[f.shape]
        for key in set(FIBER_SHAPE_KEYS.values()):
            if key == needed and getattr(f, key) is None:
                raise ConfigError(f"[fiber] {key}: required for shape = \"{f.shape}\"")
            if key != needed and getattr(f, key) is not None:
                raise ConfigError(f"[fiber] {key}: not used with shape = \"{f.shape}\" (it needs {needed})")
        points = None if f.points_file is None else resolve_input_path(f.points_file, base_dir)
        return cls(f.shape, f.radius_um, f.semi_axes_um, points, f.segments, f.rotation_deg, f.longitudinal_variance)

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
    """The model of a study: its registry name, the precision of its tasks (resolved once, from
    ``[model] precision``) and its parsed Options dataclass."""

    name: str
    precision: Precision
    options: Any = None

    def build(self):
        """A new instance of the model with these options."""
        return get_model(self.name, self.options)

    @property
    def capabilities(self):
        return model_class(self.name).capabilities


@dataclass(frozen=True)
class Study:
    """One fully validated case of a study (one combination of the sweep values). ``kind``: its
    :class:`~wavebrdf.jobs.study_kinds.StudyKind`, which everything that differs between surface
    and fiber studies asks; ``surface`` or ``fiber``: the spec of the section that made it that kind
    (the other is None)."""

    name: str
    output: Path
    kind: Any  # a jobs/study_kinds.py StudyKind (that module imports this one)
    material: MaterialSpec
    illumination: IlluminationSpec
    model: ModelSpec
    output_options: OutputSection
    steering: SteeringSection | None
    run: RunSection
    sections: dict = field(repr=False)  # every section's validated values (jobs/sections.py section_record)
    sweep_values: dict = field(default_factory=dict)  # {"surface.rms_height_um": 0.1, ...}
    surface: SurfaceSpec | None = None
    fiber: FiberSpec | None = None


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

    def case_indices(self) -> list[tuple[int, tuple[int, ...]]]:
        """(case, its index along the sweep axes) of every case, C order."""
        shape = self.case_shape
        return [(case, tuple(map(int, index))) for case, index in enumerate(np.ndindex(*shape) if shape else [()])]
