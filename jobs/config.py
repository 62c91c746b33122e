"""Study configuration: TOML → validated, typed objects; sweeps expanded into cases.

Every problem is reported as a :class:`ConfigError` whose one-line message names the key, the
value and what is allowed, e.g. ``[illumination] wavelengths_um = [-0.4]: values must be > 0``.
Every numeric key has a physical range (:class:`Number`: lengths 1 pm to 1 m, vacuum wavelengths
1 nm to 1 mm, ...), so a typo or a unit slip is refused at load, not in a task; keys that would
be ignored (``kappa`` with ``name``, ``cells`` with ``file``) are refused with the reason.
Relative ``surface.file``, ``material.file`` and ``illumination.directions_file`` paths are resolved
against the config file's folder; ``study.output``
against the working directory. Lists of numbers may be ``{start, stop, count}`` ranges and
directions a ``{theta, phi}`` grid (jobs/ranges.py); :func:`load_config` also takes a dict and
``--set``-style overrides (jobs/overrides.py).

Sections (see configs/*.toml and the README for a full example)::

    [study]        name, output
    [surface]      file + size_um | generator ("flat"|"gaussian"|"brushed"|"sinusoid"|"corner-cubes"|
                   "spherical-pits"|"hemispheres") + size_um, cells, seed, rms_height_um,
                   correlation_um (T or [T_x', T_y']), amplitude_um, period_um, angle_deg, radius_um,
                   depth_um, fill, placement ("square"|"random")
                   — size_um = [L_x, L_y] / cells = [N_x, N_y] (or a non-square file): a rectangular
                   global surface, [steering] studies only (patches stay square)
    [material]     name | table = [[λ_um, n, κ], ...] | file (the reference's wvl.txt: λ, n, κ rows) |
                   n (+ kappa); exterior_index (default 1)
    [illumination] wavelengths_um (default with material.file: the file's wavelengths),
                   directions_deg = [[θ, φ], ...] | directions_file (the reference's wi.txt: θ, φ
                   rows) + angles ("rad" (default) | "deg"), waist_um,
                   polarization ("unpolarized"|"s"|"p"), beam ("exact"|"paraxial"|"plane")
    [model]        name, precision ("double"|"single"), and the model's own options: the keys of
                   its Options dataclass, in [model] or in [model.<name>] (e.g. the bem model's
                   method and its [model.aim] table); unknown keys and bad values are refused
    [output]       resolution, per_polarization
    [steering]     patches ([mx, my] | "auto", either of mx, my may be "auto"), patch_size_um,
                   shift_um (default: the waist),
                   hexagon_fill (hexagon radius as a fraction of sin(λ_min/(π w)); > 1 steers
                   beyond the aliasing limit, with a warning)
    [run]          executor ("auto"|"serial"|"processes"|"mpi"), workers, memory_gb, retries
    [fiber]        shape ("circle"|"ellipse"|"polygon"), radius_um, semi_axes_um, points_file
                   (polygon/spline shape file, see solver/fiber/shapes.py), segments, rotation_deg
                   — instead of [surface];
                   then [illumination] takes theta_i_deg (+ phi_i_deg) instead of
                   directions_deg/waist_um, [model] name is "fiber-bem" or "mie", and [output]
                   phi_r_bins / phi_i_bins set the BCSDF table's azimuth bins
    [sweep]        "section.key" = [values...]: one case per combination
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
import itertools
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from wavebrdf.jobs.errors import ConfigError, fail, fmt
from wavebrdf.jobs.executors import AUTO, executor_names
from wavebrdf.jobs.overrides import dict_config_text, overridden_text, parse_toml
from wavebrdf.jobs.ranges import RANGE_KEYS, expand_directions, expand_range
from wavebrdf.jobs.steering import GlobalSurface
from wavebrdf.solver.farfield import HemisphereGrid
from wavebrdf.solver.materials import Material, MaterialError, read_index_file
from wavebrdf.solver.models import SurfaceScene, get_model, model_class, model_names
from wavebrdf.solver.number_rows import RowError, number_rows
from wavebrdf.solver.options import parse_options
from wavebrdf.solver.resources import meminfo_bytes
from wavebrdf.solver.surface import HeightField, SurfaceError, generate, load_heights

__all__ = [
    "ConfigError",
    "Study",
    "StudyConfig",
    "load_config",
    "parse_config",
    "register_section",
]

# solver/surface.py GENERATORS (listed here so that loading a config imports no solver module)
SURFACE_GENERATORS = ("flat", "gaussian", "brushed", "sinusoid", "corner-cubes", "spherical-pits", "hemispheres")
POLARIZATION_CHOICES = ("unpolarized", "s", "p")
BEAM_CHOICES = ("exact", "paraxial", "plane")
PRECISION_CHOICES = ("double", "single")
NOT_SWEEPABLE = {
    "illumination.wavelengths_um": "it is already a dataset axis; list the values there",
    "illumination.directions_deg": "it is already a dataset axis; list the directions there",
    "illumination.theta_i_deg": "it is already a dataset axis; list the angles there",
    "illumination.phi_i_deg": "it is already a dataset axis; list the angles there",
    "illumination.directions_file": "it is already a dataset axis; list the directions in one file",
    "illumination.angles": "it is already a dataset axis; list the directions in one file",
    "output.phi_r_bins": "every case must share one output grid",
    "output.phi_i_bins": "every case must share one output grid",
    "output.resolution": "every case must share one output grid",
    "study.output": "a study writes one dataset",
    "study.name": "a study has one name",
    "steering.patches": "the patch layout is shared by all cases",
}


# ---------------------------------------------------------------------------------------------
# Value checkers: each takes (section, key, value) and returns the converted value or raises.
# Numeric keys are :class:`Number` (or :class:`Rows` of them): their type, domain and physical
# range are data, stated in the refusal (and read by tests/test_inputs.py, which tries extreme
# values on every numeric key of SCHEMA).


def _interval(low, high, low_open=False, high_open=False) -> str:
    lo = "(-inf" if low is None else f"{'(' if low_open else '['}{low:g}"
    hi = "inf)" if high is None else f"{high:g}{')' if high_open else ']'}"
    return f"{lo}, {hi}"


@dataclass(frozen=True)
class Number:
    """A numeric key: its type, its domain and its physical range.

    ``low``/``high`` (``*_open``: excluded) are the domain (a negative length is refused as
    "must be > 0"); ``span`` = (smallest, largest) non-zero magnitude that is physics rather than
    a typo or a unit slip (lengths from 1 pm to 1 m), in ``unit``, explained by ``note``.
    ``form``: "one" (a number), "pair" ([a, b]), "one_or_pair" (either) or "list" (a non-empty
    list of distinct numbers, or a {start, stop, count} range, jobs/ranges.py)."""

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    integer: bool = False
    span: tuple[float, float] | None = None
    unit: str = ""
    note: str = ""
    form: str = "one"

    @property
    def range_text(self) -> str:
        """The accepted values in words, e.g. "0.001 to 1000 µm (vacuum wavelengths: 1 nm to 1 mm)"."""
        unit = f" {self.unit}" if self.unit else ""
        note = f" ({self.note})" if self.note else ""
        if self.span is None:
            return f"{_interval(self.low, self.high, self.low_open, self.high_open)}{unit}{note}"
        zero_allowed = self.low is None or (self.low == 0 and not self.low_open)
        zero = "0 or " if zero_allowed and self.span[0] > 0 else ""
        sign = "±" if self.low is None or self.low < 0 else ""
        return f"{zero}{sign}{self.span[0]:g} to {sign}{self.span[1]:g}{unit}{note}"

    @property
    def domain_text(self) -> str:
        if self.high is not None:
            return f"in {_interval(self.low, self.high, self.low_open, self.high_open)}"
        return "" if self.low is None else f"{'>' if self.low_open else '>='} {self.low:g}"

    def problem(self, value) -> str | None:
        """Why ``value`` is refused (None: accepted): type, finiteness, domain, physical range."""
        ok_type = isinstance(value, int) if self.integer else isinstance(value, (int, float))
        if isinstance(value, bool) or not ok_type:
            return f"must be {'an integer' if self.integer else 'a number'}"
        if self.integer and abs(value) >= 2**63:  # TOML integers are unbounded; numpy and HDF5 are not
            return "is too large (integers must lie within ±2**63)"
        if not self.integer and not math.isfinite(value):
            return "must be finite (not NaN/inf)"
        low, high = self.low, self.high
        if low is not None and (value <= low if self.low_open else value < low):
            return f"must be {'>' if self.low_open else '>='} {low}"
        if high is not None and (value >= high if self.high_open else value > high):
            note = f" ({self.note})" if self.note else ""
            return f"must be {'<' if self.high_open else '<='} {high:g}{' ' + self.unit if self.unit else ''}{note}"
        if self.span is not None and value != 0 and not self.span[0] <= abs(value) <= self.span[1]:
            return f"is {'below' if abs(value) < self.span[0] else 'above'} the physical range {self.range_text}"
        return None

    def item(self, section, key, value, whole=None):
        """``value`` converted (int or float), or a ConfigError naming the key and the value
        (``whole``: the key's list that holds ``value``, named instead, with the bad element)."""
        problem = self.problem(value)
        if problem is None:
            return int(value) if self.integer else float(value)
        if whole is None:
            raise fail(section, key, value, problem)
        if problem.startswith("is "):
            problem = f"values must lie within the physical range {self.range_text}"
        else:
            problem = f"values must be finite {'integers' if self.integer else 'numbers'} {self.domain_text}".rstrip()
        raise fail(section, key, whole, f"{problem} (bad: {fmt(value)})")

    def __call__(self, section, key, value):
        if self.form == "list":
            value = expand_range(section, key, value)  # {start, stop, count}
            if not isinstance(value, list) or not value:
                raise fail(section, key, value, "must be a non-empty list of numbers")
            out = tuple(self.item(section, key, item, whole=value) for item in value)
            if len(set(out)) != len(out):
                raise fail(section, key, value, "values must be distinct")
            return out
        if self.form == "pair" or (self.form == "one_or_pair" and isinstance(value, list)):
            if not isinstance(value, list) or len(value) != 2:
                either = "a number, or " if self.form == "one_or_pair" else ""
                raise fail(section, key, value, f"must be {either}[a, b] with two numbers {self.domain_text}")
            return tuple(self.item(section, key, v, whole=value) for v in value)
        return self.item(section, key, value)


@dataclass(frozen=True)
class Rows:
    """A non-empty list of rows of numbers, e.g. [[θ, φ], ...] or [[λ, n, κ], ...]: ``columns``
    are (name, Number) pairs; ``row`` names a row in messages; ``distinct``: rows may not repeat;
    ``expand``: turns a table form into the list first (direction grids, jobs/ranges.py)."""

    columns: tuple[tuple[str, Number], ...]
    row: str
    distinct: bool = False
    expand: Callable | None = None

    @property
    def shape_text(self) -> str:
        return "[" + ", ".join(name for name, _ in self.columns) + "]"

    def __call__(self, section, key, value):
        if self.expand is not None:
            value = self.expand(section, key, value)
        if not isinstance(value, list) or not value:
            raise fail(section, key, value, f"must be a non-empty list of {self.shape_text} rows")
        out = []
        for row in value:
            if not isinstance(row, list) or len(row) != len(self.columns):
                raise fail(section, key, value, f"each {self.row} must be {self.shape_text} (bad: {fmt(row)})")
            for (name, check), x in zip(self.columns, row):
                problem = check.problem(x)
                if problem is not None:
                    raise fail(section, key, value, f"{name} {problem} (bad: {fmt(x)} in {fmt(row)})")
            out.append(tuple(float(x) for x in row))
        if self.distinct and len(set(out)) != len(out):
            raise fail(section, key, value, f"{self.row}s must be distinct")
        return tuple(out)


# Physical ranges (µm, degrees): what the solvers are meant for, with room to spare; a value
# outside is a typo or a unit slip (nm for µm), refused at load rather than failing in a task.
LENGTH_SPAN = (1e-6, 1e6)


def _length(low: float = 0, low_open: bool = True, form: str = "one") -> Number:
    """A length in µm (> 0, unless ``low``/``low_open`` say otherwise) within LENGTH_SPAN."""
    return Number(low=low, low_open=low_open, span=LENGTH_SPAN, unit="µm", note="lengths: 1 pm to 1 m", form=form)


WAVELENGTH = Number(low=0, low_open=True, span=(1e-3, 1e3), unit="µm", note="vacuum wavelengths: 1 nm to 1 mm")
INDEX_N = Number(low=0, low_open=True, span=(1e-3, 1e4), note="the real part n of the index n − jκ")
INDEX_KAPPA = Number(low=0, high=1e4, note="κ of n − jκ; 1e3 is already a perfect conductor")
ANGLE_DEG = Number(low=-360, high=360, unit="degrees")


def _integer(low: int, high: int | None = None) -> Number:
    return Number(low=low, high=high, integer=True)


def _string(section, key, value):
    if not isinstance(value, str) or not value.strip():
        raise fail(section, key, value, "must be a non-empty string")
    return value


def _study_name(section, key, value):
    """A study name: it names the default output ``<name>.h5`` and the SLURM script, so it must be
    a plain file name (no folders, no "..", no control characters)."""
    name = _string(section, key, value)
    if any(sep in name for sep in ("/", "\\")) or ".." in name or not name.isprintable() or len(name) > 200:
        raise fail(section, key, value, "must be a plain name (no '/', '\\', '..' or control characters, at "
                   "most 200 characters); choose the output path with [study] output")
    return name


def _model_names(section, key, value):
    """A registered model name, or a non-empty list of them."""
    names = value if isinstance(value, list) else [value]
    if not names or not all(isinstance(n, str) for n in names):
        raise fail(section, key, value, "must be a model name or a non-empty list of model names")
    unknown = [n for n in names if n not in model_names()]
    if unknown:
        raise fail(section, key, value, f"{unknown[0]!r} is not a registered model "
                                         f"(available: {', '.join(model_names())})")
    return value


def _boolean(section, key, value):
    if not isinstance(value, bool):
        raise fail(section, key, value, "must be true or false")
    return value


def _choice(*choices: str) -> Callable:
    def check(section, key, value):
        if value not in choices:
            raise fail(section, key, value, f"must be one of {', '.join(repr(c) for c in choices)}")
        return value

    return check


def _patches(section, key, value):
    """"auto", or [mx, my] with integers >= 1 or "auto" (as many as fit along that axis)."""
    if value == "auto":
        return value
    if (
        not isinstance(value, list)
        or len(value) != 2
        or any(v != "auto" and (isinstance(v, bool) or not isinstance(v, int) or v < 1) for v in value)
    ):
        raise fail(section, key, value, 'must be "auto" or [mx, my] with integers >= 1 (either may be "auto")')
    return tuple(v if v == "auto" else int(v) for v in value)


def _direction_grid(section, key, value):
    return expand_directions(section, key, value)  # {theta = ..., phi = ...} grid


DIRECTIONS = Rows((("theta_deg", Number(low=0, high=90, high_open=True, unit="degrees")), ("phi_deg", ANGLE_DEG)),
                  "direction", distinct=True, expand=_direction_grid)
MATERIAL_TABLE = Rows((("wavelength_um", WAVELENGTH), ("n", INDEX_N), ("kappa", INDEX_KAPPA)), "row")


@dataclass(frozen=True)
class Spec:
    check: Callable
    default: Any = None
    required: bool = False


SCHEMA: dict[str, dict[str, Spec]] = {
    "study": {
        "name": Spec(_study_name),
        "output": Spec(_string),
    },
    "surface": {
        "file": Spec(_string),
        "size_um": Spec(_length(form="one_or_pair"), required=True),  # L, or [L_x, L_y] (rectangles: steering only)
        "generator": Spec(_choice(*SURFACE_GENERATORS)),
        "cells": Spec(Number(low=3, integer=True, form="one_or_pair"), default=256),  # N, or [N_x, N_y]
        "seed": Spec(_integer(0), default=0),
        "rms_height_um": Spec(_length(low=0, low_open=False)),  # 0: a flat realization of the ensemble
        "correlation_um": Spec(_length(form="one_or_pair")),
        "amplitude_um": Spec(_length(low=None)),  # either sign
        "period_um": Spec(_length()),
        "angle_deg": Spec(ANGLE_DEG),
        "radius_um": Spec(_length()),
        "depth_um": Spec(_length()),
        "fill": Spec(Number(low=0, low_open=True, high=1, span=(1e-6, 1), note="area fraction")),
        "placement": Spec(_choice("square", "random")),
        "shape": Spec(_choice("triangular", "full")),
    },
    "material": {
        "name": Spec(_string),
        "table": Spec(MATERIAL_TABLE),
        "file": Spec(_string),  # the reference simulator's wvl.txt: rows λ (µm), n, κ
        "n": Spec(INDEX_N),
        "kappa": Spec(INDEX_KAPPA, default=0.0),
        # the medium above: air 1, water 1.33, an immersion oil 1.5, a semiconductor up to ~4
        "exterior_index": Spec(Number(low=1.0, high=10.0, note="the index of the medium above the surface"),
                               default=1.0),
    },
    "illumination": {
        "wavelengths_um": Spec(dataclasses.replace(WAVELENGTH, form="list")),  # required; default with material.file: its wavelengths
        "directions_deg": Spec(DIRECTIONS),  # surfaces
        "directions_file": Spec(_string),  # surfaces: the reference simulator's wi.txt, rows θ, φ
        "angles": Spec(_choice("rad", "deg")),  # units of directions_file (default "rad", as wi.txt)
        "waist_um": Spec(_length()),  # surfaces
        "theta_i_deg": Spec(Number(low=-90, high=90, low_open=True, high_open=True, unit="degrees", form="list")),  # fibers: from the plane normal to the axis
        "phi_i_deg": Spec(Number(low=-360, high=360, low_open=True, high_open=True, unit="degrees", form="list")),  # fibers: incidence azimuths (else bins)
        "polarization": Spec(_choice(*POLARIZATION_CHOICES), default="unpolarized"),
        "beam": Spec(_choice(*BEAM_CHOICES), default="exact"),
    },
    "model": {  # the other keys are the model's Options (solver/models.py), checked by it
        "name": Spec(_string, required=True),
        "precision": Spec(_choice(*PRECISION_CHOICES), default="double"),
    },
    "steering": {
        "patches": Spec(_patches, required=True),
        "patch_size_um": Spec(_length(), required=True),
        "shift_um": Spec(_length()),  # default: the waist
        "hexagon_fill": Spec(Number(low=0.05, high=10.0), default=0.97),
    },
    "compare": {  # `wavebrdf compare` only; [compare.<model>] tables hold other models' options
        "models": Spec(_model_names),
        "reference": Spec(_model_names),
    },
    "run": {
        "executor": Spec(_choice(*executor_names()), default=AUTO),
        "workers": Spec(_integer(1, 4096)),  # per node
        "memory_gb": Spec(Number(low=0, low_open=True, span=(1e-3, 1e6), unit="GiB", note="per node")),
        "retries": Spec(_integer(0, 100), default=1),
        "prologue": Spec(_string),  # `wavebrdf submit`: shell lines before the run (module loads, venv)
    },
    "fiber": {
        "shape": Spec(_choice("circle", "ellipse", "polygon"), required=True),
        "radius_um": Spec(_length()),
        "semi_axes_um": Spec(_length(form="pair")),
        "points_file": Spec(_string),
        "segments": Spec(_integer(8, 20_000)),  # a 50 µm fiber at 0.4 µm needs ~15 000
        "rotation_deg": Spec(ANGLE_DEG, default=0.0),
        # d'Eon's longitudinal variance v (rad²): the dataset's default for M0, overridable at render time
        "longitudinal_variance": Spec(Number(low=1e-3, high=10.0), default=0.02),
    },
    "output": {
        "phi_r_bins": Spec(_integer(8, 100_000), default=360),
        "phi_i_bins": Spec(_integer(1, 100_000)),
        "resolution": Spec(_integer(16, 8192), default=512),
        "per_polarization": Spec(_boolean, default=False),
    },
}
REQUIRED_SECTIONS = ("material", "illumination", "model")  # + exactly one of [surface] / [fiber]
OPEN_SECTIONS = ("model", "compare")  # sections whose other keys belong to a plug-in (a model's Options)
SURFACE_ONLY_KEYS = ("directions_deg", "directions_file", "angles", "waist_um", "beam")
FIBER_ONLY_KEYS = ("theta_i_deg", "phi_i_deg")
GENERATOR_KEYS = ("rms_height_um", "correlation_um", "amplitude_um", "period_um", "angle_deg", "radius_um",
                  "depth_um", "fill", "placement", "shape")


def register_section(name: str, keys: dict[str, Spec]) -> None:
    """Let a later subsystem (steering, fibers, execution) add a config section."""
    SCHEMA[name] = keys


# ---------------------------------------------------------------------------------------------
# Typed study objects


@dataclass(frozen=True)
class SurfaceSpec:
    size_um: float | tuple[float, float]  # L, or (L_x, L_y) for a rectangular (steering) surface
    file: Path | None
    generator: str | None
    cells: int | tuple[int, int]  # N, or (N_x, N_y)
    seed: int
    parameters: dict

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

    def build(self):
        """The :class:`~wavebrdf.solver.fiber.CrossSection`."""
        from wavebrdf.solver import fiber

        rotation = np.deg2rad(self.rotation_deg)
        if self.shape == "circle":  # the Mie model needs no mesh: 360 nodes describe its outline
            return fiber.circle(self.radius_um, self.segments or 360, rotation=rotation)
        if self.shape == "ellipse":
            return fiber.ellipse(*self.semi_axes_um, self.segments, rotation=rotation)
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
class SteeringSpec:
    patches: tuple[int, int] | str
    patch_size_um: float
    shift_um: float
    hexagon_fill: float


@dataclass(frozen=True)
class RunSpec:
    executor: str
    workers: int | None
    memory_gb: float | None
    retries: int


@dataclass(frozen=True)
class OutputSpec:
    resolution: int
    per_polarization: bool
    phi_r_bins: int = 360  # fibers
    phi_i_bins: int | None = None  # fibers (None: 1 for circles, 72 otherwise)


@dataclass(frozen=True)
class Study:
    """One fully validated case of a study (one combination of the sweep values)."""

    name: str
    output: Path
    surface: SurfaceSpec | None
    material: MaterialSpec
    illumination: IlluminationSpec
    model: ModelSpec
    output_options: OutputSpec
    steering: SteeringSpec | None
    run: RunSpec
    fiber: FiberSpec | None
    sections: dict = field(repr=False)  # validated values of every section (incl. registered ones)
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


# ---------------------------------------------------------------------------------------------
# Parsing


def _suggest(key: str, options) -> str:
    close = difflib.get_close_matches(key, list(options), n=1)
    return f"; did you mean {close[0]!r}?" if close else ""


def _validate_section(section: str, raw: Any, present: bool = True) -> dict:
    """Check and convert one section; an absent optional section gets its defaults."""
    schema = SCHEMA[section]
    if not isinstance(raw, dict):
        raise ConfigError(f"[{section}] must be a table, got {fmt(raw)}")
    for key in raw:
        if key not in schema and section not in OPEN_SECTIONS:
            raise ConfigError(
                f"[{section}] {key}: unknown key{_suggest(key, schema)} (allowed: {', '.join(schema)})"
            )
    out = {}
    for key, spec in schema.items():
        if key in raw:
            out[key] = spec.check(section, key, raw[key])
        elif spec.required and present:
            raise ConfigError(f"[{section}] {key}: missing required key")
        else:
            out[key] = spec.default
    if section in OPEN_SECTIONS:
        out["options"] = {k: v for k, v in raw.items() if k not in schema}
    return out


def _exactly_one(section: str, values: dict, keys: tuple[str, ...]) -> str:
    given = [k for k in keys if values.get(k) is not None]
    if len(given) != 1:
        raise ConfigError(
            f"[{section}]: give exactly one of {', '.join(keys)} (got {', '.join(given) or 'none'})"
        )
    return given[0]


MAX_CONFIG_BYTES = 16 * 2**20


def input_file_problem(path: Path) -> str | None:
    """Why ``path`` cannot be read as an input file ("does not exist", "is a folder, not a file",
    "is not a regular file (a character device)", ...); None for a readable regular file."""
    import stat

    try:
        st = os.stat(path)
    except FileNotFoundError:
        return "does not exist"
    except OSError as exc:
        return f"cannot be read ({exc.strerror})"
    if stat.S_ISDIR(st.st_mode):
        return "is a folder, not a file"
    if not stat.S_ISREG(st.st_mode):
        kinds = ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                 (stat.S_ISFIFO, "a named pipe"), (stat.S_ISSOCK, "a socket"))
        kind = next((name for test, name in kinds if test(st.st_mode)), "not a file")
        return f"is not a regular file ({kind})"
    if not os.access(path, os.R_OK):
        return "is not readable (permission denied)"
    return None


def _check_output_path(raw_output: str) -> Path:
    """The dataset path: a .h5/.hdf5/.nc file name in a writable folder. The folder may be missing
    if its parent exists (``wavebrdf run`` creates that one level, as ``mkdir`` would: the shipped
    configs write to out/); deeper missing folders are refused, nothing is created here."""
    path = Path(raw_output).expanduser()
    if path.suffix not in (".h5", ".hdf5", ".nc"):
        raise fail("study", "output", raw_output, "must end in .h5 (or .hdf5/.nc)")
    parent = path.resolve().parent
    probe = parent
    while not probe.exists() and not probe.is_symlink():
        probe = probe.parent
    if not probe.is_dir():
        raise fail("study", "output", raw_output, f"folder {str(parent)!r} is not writable: {str(probe)!r} is "
                   "not a folder")
    if probe != parent and probe != parent.parent:
        raise fail("study", "output", raw_output, f"folder {str(parent)!r} does not exist, nor does "
                   f"{str(parent.parent)!r}; create the folder first")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise fail("study", "output", raw_output, f"folder {str(probe)!r} is not writable")
    if path.exists() and path.is_dir():
        raise fail("study", "output", raw_output, "is a folder")
    return path


def make_output_folder(output: Path) -> None:
    """Create the output's folder when it is the one missing level :func:`_check_output_path`
    allows (``wavebrdf run`` only, right before it takes the output's lock). The rule holds here
    too, for paths that never went through it (``compare --out``) or whose folders vanished since:
    at most the last folder level is created; a deeper missing chain is a one-line ConfigError."""
    folder = Path(output).expanduser().resolve().parent
    if folder.is_dir():
        return
    if not folder.parent.is_dir():
        raise ConfigError(f"output {str(output)!r}: folder {str(folder)!r} does not exist, nor does "
                          f"{str(folder.parent)!r}; create the folder first (only the last level is created)")
    try:
        folder.mkdir()
    except FileExistsError:
        if not folder.is_dir():
            raise ConfigError(f"output {str(output)!r}: {str(folder)!r} is not a folder") from None


def _build_study(data: dict, base_dir: Path, default_name: str, sweep_values: dict,
                 output: str | Path | None = None) -> Study:
    for section in data:
        if section not in SCHEMA and section != "sweep":
            raise ConfigError(f"[{section}]: unknown section{_suggest(section, SCHEMA)} (allowed: {', '.join(SCHEMA)})")
    for section in REQUIRED_SECTIONS:
        if section not in data:
            raise ConfigError(f"[{section}]: missing required section")
    v = {s: _validate_section(s, data.get(s, {}), s in data) for s in SCHEMA}

    name = v["study"]["name"] or default_name
    output = _check_output_path(str(output or v["study"]["output"] or f"{name}.h5"))
    if ("surface" in data) == ("fiber" in data):
        raise ConfigError("give exactly one of [surface] (a height field) or [fiber] (a fiber cross section)")
    surface = _surface_spec(v["surface"], base_dir, data["surface"]) if "surface" in data else None
    fiber = _fiber_spec(v["fiber"], base_dir) if "fiber" in data else None

    m = v["material"]
    _material_source(m, data.get("material", {}))
    material_file = None
    if m["file"] is not None:
        material_file = _input_path(m["file"], base_dir)
        m["table"] = _read_material_file(m["file"], material_file)  # results depend on its rows, not its name
    material = MaterialSpec(
        m["name"], None if m["table"] is None else tuple(map(tuple, m["table"])), m["n"], m["kappa"],
        m["exterior_index"], material_file,
    )
    if v["illumination"]["wavelengths_um"] is None:
        if material_file is None:
            raise ConfigError("[illumination] wavelengths_um: missing required key")
        v["illumination"]["wavelengths_um"] = tuple(row[0] for row in material.table)  # the reference's default
    illumination = _illumination_spec(v["illumination"], data.get("illumination", {}), fiber is not None, base_dir)
    model = _model_spec(v["model"], fiber is not None)
    if fiber is not None and model.name == "fiber-bem" and fiber.shape != "polygon" and fiber.segments is None:
        raise ConfigError(f"[fiber] segments: required by the fiber-bem model for shape = \"{fiber.shape}\" "
                          "(e.g. 300 for a 1 µm radius at 0.4 µm: >= 10 elements per interior wavelength)")
    if model.name == "mie" and fiber.shape != "circle":
        raise fail("model", "name", "mie", f"the Mie series solves circular fibers only, not fiber.shape = "
                   f"{fiber.shape!r}; use \"fiber-bem\"")
    o = v["output"]
    out = OutputSpec(o["resolution"], o["per_polarization"], o["phi_r_bins"], o["phi_i_bins"])
    steering = None
    if "steering" in data and fiber is not None:
        raise ConfigError("[steering] applies to height fields, not to fibers")
    if not model.capabilities.polarized and (illumination.polarization != "unpolarized" or out.per_polarization):
        raise ConfigError(f"[illumination] polarization = \"{illumination.polarization}\" / [output] per_polarization: "
                          f"model {model.name!r} does not resolve polarization (its s and p are the same); "
                          "use polarization = \"unpolarized\" and per_polarization = false")
    if "steering" in data and not model.capabilities.steerable:
        raise ConfigError(f"[steering]: model {model.name!r} cannot be steered (it returns "
                          f"{model.capabilities.returns}, not coherent fields with their incident beam); "
                          "remove [steering] or choose a steerable model")
    if surface is not None and surface.rectangular and "steering" not in data:
        raise _rectangle_outside_steering(f"size_um = {fmt(list(surface.size_um))}, cells = "
                                          f"{fmt(list(surface.cells))}")
    if "steering" in data:
        st = v["steering"]
        steering = SteeringSpec(st["patches"], st["patch_size_um"], st["shift_um"] or illumination.waist_um,
                                st["hexagon_fill"])
    r = v["run"]
    run = RunSpec(r["executor"], r["workers"], r["memory_gb"], r["retries"])
    study = Study(name, output, surface, material, illumination, model, out, steering, run, fiber, v,
                  dict(sweep_values))
    _check_physics(study)
    return study


def _model_spec(m: dict, is_fiber: bool) -> ModelSpec:
    """[model]: a registered model that takes this study's input, with its Options parsed."""
    takes = ("cross_section",) if is_fiber else ("height_field", "statistics")
    if m["name"] not in model_names() or model_class(m["name"]).capabilities.takes not in takes:
        allowed = [n for t in takes for n in model_names(t)]  # imports every model: the error path only
        kind = "fiber" if is_fiber else "surface"
        raise fail("model", "name", m["name"], f"a {kind} study needs one of {', '.join(repr(n) for n in allowed)}")
    cls = model_class(m["name"])
    given = dict(m["options"])
    own = given.pop(m["name"], None)  # [model.<name>] table
    if own is not None:
        if not isinstance(own, dict):
            raise fail("model", m["name"], own, f"must be a table of the {m['name']} model's options")
        both = sorted(set(own) & set(given))
        if both:
            raise ConfigError(f"[model.{m['name']}] {both[0]}: also given in [model]; give it once")
        given.update(own)
    try:
        options = parse_options(cls.Options, given, "model")
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    return ModelSpec(m["name"], m["precision"], options)


def _surface_spec(s: dict, base_dir: Path, given: dict) -> SurfaceSpec:
    _exactly_one("surface", s, ("file", "generator"))
    file = None
    size, cells = s["size_um"], s["cells"]
    if s["file"] is not None:
        file = _input_path(s["file"], base_dir)
        extra = [k for k in GENERATOR_KEYS if s[k] is not None]
        if extra:
            raise ConfigError(f"[surface] {extra[0]}: only used with a generator, not with surface.file")
        for key, why in (("cells", "the file's matrix of (N+1)×(N+1) heights gives N"),
                         ("seed", "the heights are read, not drawn")):
            if key in given:  # it would be ignored
                raise ConfigError(f"[surface] {key} = {fmt(given[key])} and file = {fmt(s['file'])}: {key} would "
                                  f"be ignored ({why}); remove {key}")
    elif isinstance(size, tuple) or isinstance(cells, tuple):  # a rectangle: L_x/N_x = L_y/N_y
        sides = size if isinstance(size, tuple) else (size, size)
        counts = cells if isinstance(cells, tuple) else (cells, cells)
        dx, dy = sides[0] / counts[0], sides[1] / counts[1]
        if abs(dx - dy) > 1e-9 * max(dx, dy):
            raise ConfigError(f"[surface] size_um = {fmt(list(sides))}, cells = {fmt(list(counts))}: cells must be "
                              f"square (spacing {dx:.6g} µm along x, {dy:.6g} µm along y); for a rectangle give "
                              "both as [x, y] pairs with size_um[0]/cells[0] = size_um[1]/cells[1]")
        size, cells = (float(sides[0]), float(sides[1])), (int(counts[0]), int(counts[1]))
        if counts[0] == counts[1]:
            size, cells = size[0], cells[0]
    params = {k: s[k] for k in GENERATOR_KEYS if s[k] is not None}
    return SurfaceSpec(size, file, s["generator"], cells, s["seed"], params)


def _input_path(value: str, base_dir: Path) -> Path:
    """An input file path; relative ones are taken from the config file's folder."""
    path = Path(value).expanduser()
    return path if path.is_absolute() else base_dir / path


def _rectangle_outside_steering(what: str) -> ConfigError:
    return ConfigError(f"[surface] {what}: a rectangular surface is only accepted as the global surface of a "
                       "[steering] study (its patches are square); other studies need a square surface "
                       "(size_um = L, cells = N, or an (N+1)x(N+1) height file)")


def _material_source(m: dict, given: dict) -> None:
    """[material]: exactly one of name, table, file, n; kappa only with n."""
    sources = [k for k in ("name", "table", "file", "n") if m.get(k) is not None]
    if "file" in sources and len(sources) > 1:
        other = next(k for k in sources if k != "file")
        raise ConfigError(f"[material] file and {other}: give one of them (material.file = {fmt(m['file'])} is a "
                          f"table of λ, n, κ rows; material.{other} is another source of the index)")
    if "kappa" in given and m.get("file") is not None:
        raise ConfigError(f"[material] file and kappa: give one of them (material.file = {fmt(m['file'])} holds "
                          "κ per wavelength; kappa goes with a constant n)")
    _exactly_one("material", m, ("name", "table", "file", "n"))
    if "kappa" in given and m.get("n") is None:  # it would be ignored: the source gives its own κ
        source = "name" if m.get("name") is not None else "table"
        what = (f"material.name = {fmt(m['name'])} gives its own κ per wavelength" if source == "name"
                else "material.table gives κ in its third column")
        raise ConfigError(f"[material] kappa = {fmt(given['kappa'])} and {source}: kappa would be ignored ({what}); "
                          "remove kappa, or give a constant index as n and kappa instead")


def _read_material_file(value: str, path: Path) -> list:
    """The rows (λ, n, κ) of ``[material] file`` as plain lists (ConfigError naming the key)."""
    problem = input_file_problem(path)
    if problem is not None:
        raise fail("material", "file", value, f"{str(path)!r} {problem}" if str(path) != value else problem)
    try:
        rows = read_index_file(path, label=value).tolist()
    except MaterialError as exc:
        raise ConfigError(f"[material] {exc}") from None
    for number, row in enumerate(rows, start=1):  # the physical ranges of [material] table
        for (name, check), x in zip(MATERIAL_TABLE.columns, row):
            problem = check.problem(x)
            if problem is not None:
                raise fail("material", "file", value, f"row {number}: {name} {problem} (bad: {x:g} in λ, n, κ = "
                           f"{', '.join(f'{v:g}' for v in row)})")
    return rows


FIBER_SHAPE_KEYS = {"circle": "radius_um", "ellipse": "semi_axes_um", "polygon": "points_file"}


def _fiber_spec(f: dict, base_dir: Path) -> FiberSpec:
    needed = FIBER_SHAPE_KEYS[f["shape"]]
    for key in set(FIBER_SHAPE_KEYS.values()):
        if key == needed and f[key] is None:
            raise ConfigError(f"[fiber] {key}: required for shape = \"{f['shape']}\"")
        if key != needed and f[key] is not None:
            raise ConfigError(f"[fiber] {key}: not used with shape = \"{f['shape']}\" (it needs {needed})")
    points = None
    if f["points_file"] is not None:
        points = Path(f["points_file"]).expanduser()
        points = points if points.is_absolute() else base_dir / points
    return FiberSpec(f["shape"], f["radius_um"], f["semi_axes_um"], points, f["segments"], f["rotation_deg"],
                     f["longitudinal_variance"])


def _illumination_spec(ill: dict, given: dict, is_fiber: bool, base_dir: Path) -> IlluminationSpec:
    wrong = FIBER_ONLY_KEYS if not is_fiber else SURFACE_ONLY_KEYS
    for key in wrong:
        if key in given:
            kind = "surface" if not is_fiber else "fiber"
            raise ConfigError(f"[illumination] {key}: not used in a {kind} study")
    if ill["directions_file"] is not None:
        if ill["directions_deg"] is not None:
            raise ConfigError(f"[illumination] directions_deg and directions_file: give one of them (directions_file = "
                              f"{fmt(ill['directions_file'])} lists the directions already)")
        path = _input_path(ill["directions_file"], base_dir)  # its directions, in degrees:
        ill["directions_deg"] = _read_directions_file(ill["directions_file"], path, ill["angles"] or "rad")
    elif ill["angles"] is not None:
        raise ConfigError(f"[illumination] angles = {fmt(ill['angles'])}: only used with directions_file (the units "
                          "of its θ, φ columns); directions_deg is in degrees")
    needed = ("theta_i_deg",) if is_fiber else ("directions_deg", "waist_um")
    for key in needed:
        if ill[key] is None:
            raise ConfigError(f"[illumination] {key}: missing required key")
    return IlluminationSpec(
        ill["wavelengths_um"], ill["directions_deg"] or (), ill["waist_um"], ill["polarization"], ill["beam"],
        ill["theta_i_deg"] or (), ill["phi_i_deg"],
    )


DIRECTIONS_FILE_MAX_BYTES = 16 * 2**20


def _read_directions_file(value: str, path: Path, angles: str) -> tuple[tuple[float, float], ...]:
    """``[illumination] directions_file`` (the reference simulator's wi.txt): one direction per
    row, θ then φ, in ``angles`` ("rad" as wi.txt, or "deg"), separated by commas and/or
    whitespace; blank lines, ``#``/``%`` comments and a first line of words (a header) are skipped.
    θ from the normal toward the light in [0, 90°); φ any finite azimuth. Returned in degrees;
    every problem is a ConfigError naming the key, the file, the line and the value."""
    problem = input_file_problem(path)
    if problem is None and path.stat().st_size > DIRECTIONS_FILE_MAX_BYTES:
        problem = f"is {path.stat().st_size / 2**20:.0f} MiB; a list of θ, φ rows is a small text file"
    if problem is not None:
        where = f"{str(path)!r} {problem}" if str(path) != value else problem
        raise fail("illumination", "directions_file", value, where)
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except (UnicodeDecodeError, OSError) as exc:
        raise fail("illumination", "directions_file", value, f"cannot be read as text ({exc})") from None
    unit, to_deg = ("rad", math.degrees) if angles == "rad" else ("deg", float)
    limit = "π/2 rad" if angles == "rad" else "90°"
    out: list[tuple[float, float]] = []
    rows: dict[tuple[float, float], int] = {}

    def bad(line_no, line, problem):
        text = line if len(line) <= 60 else line[:57] + "..."
        return fail("illumination", "directions_file", value, f"line {line_no} ({text!r}): {problem}")

    try:
        for line_no, line, (theta, phi) in number_rows(lines, ("theta", "phi")):
            if not (math.isfinite(theta) and math.isfinite(phi)):
                raise bad(line_no, line, "angles must be finite numbers (not NaN/inf)")
            theta_deg, phi_deg = to_deg(theta), to_deg(phi)
            if not 0.0 <= theta_deg < 90.0:
                hint = (" (the file looks like degrees: set angles = \"deg\")" if angles == "rad"
                        and theta > math.pi / 2 and theta < 90.0 else "")
                raise bad(line_no, line, f"theta = {theta:g} {unit} must be in [0, {limit}){hint}")
            if ANGLE_DEG.problem(phi_deg) is not None:
                raise bad(line_no, line, f"phi = {phi:g} {unit} must lie within ±{'2π rad' if angles == 'rad' else '360°'}")
            if (theta_deg, phi_deg) in rows:
                raise bad(line_no, line, f"repeats the direction of line {rows[(theta_deg, phi_deg)]}; directions "
                                         "must be distinct")
            rows[(theta_deg, phi_deg)] = line_no
            out.append((theta_deg, phi_deg))
    except RowError as exc:
        raise bad(exc.line_no, exc.line, f"{exc.problem}; rows are θ, φ in {unit} (angles = \"{angles}\")") from None
    if not out:
        raise fail("illumination", "directions_file", value, "holds no rows of θ, φ")
    return tuple(out)


def _check_physics(study: Study) -> None:
    """Checks that need the built objects: material range, height matrix contents."""
    try:
        material = study.material.build()
        if study.material.file is not None:
            _check_file_range(study, material.wavelength_range_um)
        index = material.index(np.array(study.illumination.wavelengths_um))
    except MaterialError as exc:
        raise ConfigError(f"[material] {exc}") from None
    if np.any(np.imag(index) > 0):  # pragma: no cover - Material guarantees κ >= 0
        raise ConfigError("[material]: negative kappa (gain medium)")
    if study.surface is not None:
        _check_surface_size(study)
        try:
            surface = study.surface.build()
        except SurfaceError as exc:
            file = study.surface.file
            where = f" (file = {fmt(str(file))})" if file is not None and str(file) not in str(exc) else ""
            raise ConfigError(f"[surface] {exc}{where}") from None
        if study.steering is None and study.surface.file is not None and surface.z.shape[0] != surface.z.shape[1]:
            raise _rectangle_outside_steering(f"file = {fmt(str(study.surface.file))} holds "
                                              f"{surface.z.shape[0]}x{surface.z.shape[1]} heights")
        if study.steering is None:
            _check_model_scene(study, surface, index)
    if study.fiber is not None:
        from wavebrdf.solver.fiber import ShapeError

        try:
            study.fiber.build()
        except (ShapeError, OSError) as exc:
            raise ConfigError(f"[fiber] {exc}") from None


def _check_file_range(study: Study, valid: tuple[float, float]) -> None:
    """Requested wavelengths must lie within [material] file's rows (no extrapolation)."""
    lo, hi = valid
    wavelengths = study.illumination.wavelengths_um
    outside = [lam for lam in wavelengths if lam < lo - 1e-12 or lam > hi + 1e-12]
    if outside:
        given = study.sections["material"]["file"]
        raise ConfigError(f"[illumination] wavelengths_um = {fmt(list(wavelengths))}: {fmt(outside)} µm lie(s) "
                          f"outside material.file = {fmt(given)}, which tabulates {lo:g}–{hi:g} µm (the index is "
                          "interpolated between its rows, never extrapolated)")


SURFACE_BYTES_PER_NODE = 96  # peak while a height field is built and analysed (measured: gaussian 90)


def height_file_shape(path: Path) -> tuple[int, ...] | None:
    """The shape of a height file without loading it: from a .npy header, or for text the length
    of the first row (the matrix must be square). None when the file has no readable header (the
    loader then says what is wrong)."""
    try:
        with open(path, "rb") as fh:
            if path.suffix == ".npy":
                version = np.lib.format.read_magic(fh)
                read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
                return tuple(read(fh)[0])
            for line in iter(lambda: fh.readline(2**26), b""):
                text = line.decode("utf-8", "replace").strip()
                if text and not text.startswith("#"):
                    n = len(text.replace(",", " ").split())  # a lower bound if the row is over 64 MiB
                    return (n, n)
    except (OSError, ValueError):
        return None
    return None


def _check_surface_size(study: Study) -> None:
    """Refuse a height field that cannot fit in memory before anything is allocated: its node
    count from [surface] cells, or from the file's header."""
    spec = study.surface
    if spec.file is not None:
        problem = input_file_problem(spec.file)
        if problem is not None:
            raise fail("surface", "file", str(spec.file), problem)
        shape = height_file_shape(spec.file)
        if shape is None or len(shape) != 2:
            return  # the loader names what is wrong with it
        key, value, what = "file", str(spec.file), f"its {shape[0]}×{shape[1]} heights need"
    else:
        cells = spec.cells if isinstance(spec.cells, tuple) else (spec.cells, spec.cells)
        shape = (cells[0] + 1, cells[1] + 1)
        if spec.rectangular:  # generated on the square of the longer side, then cropped
            shape = (max(shape), max(shape))
        key, value, what = "cells", spec.cells, f"a {shape[0]}×{shape[1]} height field needs"
    need = float(shape[0]) * shape[1] * SURFACE_BYTES_PER_NODE
    memory_gb = study.run.memory_gb
    budget = memory_gb * 2**30 if memory_gb else float(meminfo_bytes("MemTotal"))
    if need > budget:
        raise fail("surface", key, value, f"{what} about {need / 2**30:.3g} GiB to build and analyse "
                   f"({SURFACE_BYTES_PER_NODE} bytes per node), more than the node's {budget / 2**30:.1f} GiB "
                   "([run] memory_gb)")


def _check_model_scene(study: Study, surface, index) -> None:
    """The model's own checks (Model.check: its options and the sampling refusals) at the case's
    shortest and longest wavelength, each with the most oblique direction and the first one
    (the lattice and lobe limits are hardest at short λ and large θ_i; ``index``: n − jκ at every
    wavelength)."""
    ill = study.illumination
    lams = np.asarray(ill.wavelengths_um, dtype=float)
    directions = np.deg2rad(np.asarray(ill.directions_deg, dtype=float))
    model, grid = study.model.build(), HemisphereGrid(study.output_options.resolution)
    for w in sorted({int(np.argmin(lams)), int(np.argmax(lams))}):
        for d in sorted({0, int(np.argmax(directions[:, 0]))}):
            theta, phi = directions[d]
            scene = SurfaceScene(surface, float(lams[w]), complex(index[w]), float(theta), float(phi), ill.waist_um,
                                 grid, study.material.exterior_index, ill.beam, study.model.precision)
            try:
                model.check(scene)
            except ValueError as exc:
                raise ConfigError(str(exc)) from None


def _set_dotted(data: dict, dotted: str, value: Any) -> None:
    section, key = dotted.split(".", 1)
    data.setdefault(section, {})[key] = value


def parse_config(text: str, path: Path | None = None, output: str | Path | None = None) -> StudyConfig:
    """Parse and validate config ``text`` (from ``path`` if given, for relative file paths);
    ``output`` replaces ``[study] output`` (it alone is checked)."""
    data = parse_toml(text, f"{path}: " if path else "")
    base_dir = path.parent.resolve() if path else Path.cwd()
    default_name = path.stem if path else "study"

    sweep = data.pop("sweep", {})
    if not isinstance(sweep, dict):
        raise ConfigError(f"[sweep] must be a table of \"section.key\" = [values], got {fmt(sweep)}")
    axes: dict[str, tuple] = {}

    for dotted, values in _flatten_sweep(sweep).items():
        values = expand_range("sweep", dotted, values)  # {start, stop, count}
        section, _, key = dotted.partition(".")
        if section not in SCHEMA or (key not in SCHEMA[section] and section not in OPEN_SECTIONS):
            raise ConfigError(f"[sweep] {dotted}: not a config key{_suggest(dotted, _all_keys())}")
        if dotted in NOT_SWEEPABLE:
            raise ConfigError(f"[sweep] {dotted}: cannot be swept ({NOT_SWEEPABLE[dotted]})")
        if not isinstance(values, list) or not values:
            raise ConfigError(f"[sweep] {dotted} = {fmt(values)}: must be a non-empty list of values")
        if len(set(map(repr, values))) != len(values):
            raise ConfigError(f"[sweep] {dotted} = {fmt(values)}: values must be distinct")
        if any(isinstance(v, (list, dict)) for v in values):  # e.g. correlation_um = [T_x, T_y]
            raise ConfigError(f"[sweep] {dotted} = {fmt(values)}: values must be single numbers or strings "
                              "(each becomes a point of a 1-D dataset coordinate); run one study per list value")
        axes[dotted] = tuple(values)

    cases = []
    for combo in itertools.product(*axes.values()):
        case_data = copy.deepcopy(data)
        values = dict(zip(axes, combo))
        for dotted, value in values.items():
            _set_dotted(case_data, dotted, value)
        try:
            cases.append(_build_study(case_data, base_dir, default_name, values, output))
        except ConfigError as exc:
            if values:
                where = ", ".join(f"{k} = {fmt(x)}" for k, x in values.items())
                raise ConfigError(f"{exc} (in the sweep case {where})") from None
            raise
    return StudyConfig(text=text, path=path, sweep_axes=axes, cases=tuple(cases))


def _flatten_sweep(sweep: dict) -> dict:
    """Accept both ``"surface.seed" = [...]`` and a nested ``[sweep.surface] seed = [...]``."""
    flat = {}
    for key, value in sweep.items():
        if isinstance(value, dict) and set(value) != set(RANGE_KEYS):  # not a {start, stop, count} range
            for sub, inner in value.items():
                flat[f"{key}.{sub}"] = inner
        else:
            flat[key] = value
    return flat


def _all_keys() -> list[str]:
    return [f"{s}.{k}" for s, keys in SCHEMA.items() for k in keys]


def load_config(path: str | Path | dict | StudyConfig, output: str | Path | None = None,
                overrides=None) -> StudyConfig:
    """Read and validate a config file — or a dict of sections as TOML loads them (relative paths
    against the working directory), or the text of a loaded :class:`StudyConfig` (returned as it
    is when nothing changes); ``overrides`` ({dotted key: value} or [(key, value), ...],
    jobs/overrides.py) change keys before validation; ``output`` overrides ``[study] output``."""
    if isinstance(path, StudyConfig) and output is None and not overrides:
        return path
    if isinstance(path, (dict, StudyConfig)):
        text, path = (dict_config_text(path), None) if isinstance(path, dict) else (path.text, path.path)
    else:
        path = Path(path)
        text = _read_config_text(path)
    if overrides:
        text = overridden_text(text, overrides, path)
    if output is None:
        return parse_config(text, path)
    cfg = parse_config(text, path, output=output)
    note = f"\n# --output given on the command line: {output}\n"
    return StudyConfig(text=text + note, path=path, sweep_axes=cfg.sweep_axes, cases=cfg.cases)


def _read_config_text(path: Path) -> str:
    """The UTF-8 text of config file ``path`` (a one-line ConfigError if it cannot be one)."""
    problem = input_file_problem(path)
    if problem is None and path.stat().st_size > MAX_CONFIG_BYTES:
        problem = f"is {path.stat().st_size / 2**20:.0f} MiB; a config is a small TOML text file"
    if problem is not None:
        raise ConfigError(f"config file {str(path)!r} {problem}")
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"config file {str(path)!r} is not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset "
                          f"{exc.start}); a config is a TOML text file") from None
    return text
