"""The sections of a study config, each declared once as an options dataclass.

Every section is parsed by the options mechanism of solver/options.py (types, physical ranges in
their units, choices, rows, the nearest valid key), so each refusal is one line
``[section] key = value: problem`` (a :class:`~wavebrdf.jobs.errors.ConfigError`). The choices
are read from where each concept lives: generators (solver/surface.py), beams (solver/beams.py),
polarizations (solver/farfield.py), precisions (solver/precision.py), executors
(jobs/executors.py). Keys of ``[surface]`` beyond its own belong to its generator, checked by
the generator's options dataclass (:func:`parse_generator`); those of ``[model]`` and
``[compare]`` to models (jobs/config.py). Checks across sections (a fiber study takes no
``waist_um``, a file surface no ``seed``) are jobs/config.py's.

:data:`SCHEMA` lists every section's keys; :func:`section_record` gives the validated values a
study's fingerprint hashes (jobs/plan.py).
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

from wavebrdf.jobs.errors import ConfigError
from wavebrdf.jobs.executors import AUTO, executor_names
from wavebrdf.jobs.ranges import direction_identity, expand_directions, expand_range
from wavebrdf.solver.beams import BEAMS
from wavebrdf.solver.farfield import POLARIZATION_MODES
from wavebrdf.solver.materials import INDEX_COLUMNS, INDEX_KAPPA, INDEX_N
from wavebrdf.solver.models import model_names
from wavebrdf.solver.options import (ANGLE_DEG, LENGTH_UM, WAVELENGTH_UM, Limits, OptionField, OptionsError, option,
                                     option_fields, parse_open_options, parse_options)
from wavebrdf.solver.polarimetry import POLARIMETRY
from wavebrdf.solver.precision import PRECISIONS, Precision
from wavebrdf.solver.surface import GENERATORS, SurfaceError

__all__ = [
    "FIBER_SHAPE_KEYS", "MODEL_SECTIONS", "SCHEMA", "SECTIONS", "CompareSection", "FiberSection", "IlluminationSection",
    "MaterialSection", "ModelSection", "OutputSection", "RunSection", "SteeringSection", "StudySection",
    "SurfaceSection", "check_key", "config_errors", "parse_generator", "parse_section", "section_record",
]

FIBER_SHAPE_KEYS = {"circle": "radius_um", "ellipse": "semi_axes_um", "polygon": "points_file"}  # shape → its key


def _patches(value):
    """"auto", or [mx, my] with integers >= 1 or "auto" (as many as fit along that axis)."""
    if value == "auto":
        return value
    if (not isinstance(value, (list, tuple)) or len(value) != 2
            or any(v != "auto" and (isinstance(v, bool) or not isinstance(v, int) or v < 1) for v in value)):
        raise ValueError('must be "auto" or [mx, my] with integers >= 1 (either may be "auto")')
    return tuple(v if v == "auto" else int(v) for v in value)


def _model_names(value):
    """A registered model name, or a non-empty list of them."""
    names = value if isinstance(value, list) else [value]
    if not names or not all(isinstance(n, str) for n in names):
        raise ValueError("must be a model name or a non-empty list of model names")
    unknown = [n for n in names if n not in model_names()]
    if unknown:
        raise ValueError(f"{unknown[0]!r} is not a registered model (available: {', '.join(model_names())})")
    return value


def _plain_name(value):
    """A study name: it names the default output ``<name>.h5`` and the SLURM script, so it must be
    a plain file name (no folders, no "..", no control characters)."""
    if not isinstance(value, str) or not value.strip():
        raise ValueError("must be a non-empty string")
    if any(sep in value for sep in ("/", "\\")) or ".." in value or not value.isprintable() or len(value) > 200:
        raise ValueError("must be a plain name (no '/', '\\', '..' or control characters, at most 200 "
                         "characters); choose the output path with [study] output")
    return value


@dataclass(frozen=True)
class StudySection:
    name: str | None = option(None, parse=_plain_name, doc="names the default output <name>.h5 and the SLURM "
                                                           "script (default: the config file's name)")
    output: str | None = option(None, doc="the dataset, .h5/.hdf5/.nc, relative to the working directory")


@dataclass(frozen=True)
class SurfaceSection:
    """A height field from a file or a generator; the generator's own keys come beside these."""

    file: str | None = option(None, doc="(N+1)×(N+1) heights in µm (.txt/.csv/.npy/.h5, rows = x), relative to "
                                        "the config's folder")
    size_um: float | tuple[float, float] = option(None, required=True, limits=LENGTH_UM,
                                                  doc="side L, or [L_x, L_y] (a rectangle: [steering] only)")
    generator: str | None = option(None, choices=GENERATORS.keys(), doc="solver/surface.py GENERATORS")
    cells: int | tuple[int, int] = option(256, low=3, doc="N, or [N_x, N_y]: spacing size_um / cells")
    seed: int = option(0, low=0, doc="of a random generator")


@dataclass(frozen=True)
class MaterialSection:
    """One source of the index n − jκ: name, table, file or n (+ kappa)."""

    name: str | None = option(None, doc="a built-in material (solver/materials.py)")
    table: tuple[tuple[float, float, float], ...] | None = option(None, columns=INDEX_COLUMNS,
                                                                  doc="[λ µm, n, κ] rows")
    file: str | None = option(None, doc="the reference simulator's wvl.txt: rows λ (µm), n, κ")
    n: float | None = option(None, limits=INDEX_N, doc="a constant index n − jκ")
    kappa: float = option(0.0, limits=INDEX_KAPPA)
    exterior_index: float = option(1.0, limits=Limits(low=1.0, high=10.0, note="the index of the medium above the "
                                                                                "surface"),
                                   doc="air 1, water 1.33, an immersion oil 1.5, a semiconductor up to ~4")


@dataclass(frozen=True)
class IlluminationSection:
    """Wavelengths and incident directions (surfaces: θ, φ and a beam; fibers: θ_i, φ_i)."""

    wavelengths_um: tuple[float, ...] | None = option(None, limits=WAVELENGTH_UM, distinct=True, expand=expand_range,
                                                      doc="vacuum wavelengths (default with material.file: its rows)")
    directions_deg: tuple[tuple[float, float], ...] | None = option(
        None, columns=(("theta_deg", Limits(low=0, high=90, high_open=True, unit="degrees")), ("phi_deg", ANGLE_DEG)),
        row="direction", distinct=direction_identity, expand=expand_directions,
        doc="[θ, φ] toward the light (surfaces)")
    directions_file: str | None = option(None, doc="the reference simulator's wi.txt: rows θ, φ (surfaces)")
    angles: str | None = option(None, choices=("rad", "deg"), doc="units of directions_file (default rad)")
    waist_um: float | None = option(None, limits=LENGTH_UM, doc="Gaussian footprint exp(−r²/w²) (surfaces)")
    theta_i_deg: tuple[float, ...] | None = option(
        None, limits=Limits(low=-90, high=90, low_open=True, high_open=True, unit="degrees"), distinct=True,
        expand=expand_range, doc="fibers: from the plane normal to the axis")
    phi_i_deg: tuple[float, ...] | None = option(
        None, limits=Limits(low=-360, high=360, low_open=True, high_open=True, unit="degrees"), distinct=True,
        expand=expand_range, doc="fibers: incidence azimuths (default: bins)")
    polarization: str = option("unpolarized", choices=POLARIZATION_MODES)
    beam: str = option("exact", choices=BEAMS)


@dataclass(frozen=True)
class ModelSection:
    """The model; its own options are the other keys (and [model.<name>])."""

    name: str = option(None, required=True, doc="a registered model (wavebrdf models)")
    precision: Precision = option(Precision.DOUBLE, choices=PRECISIONS, parse=Precision.of,
                                  doc="kernels and FFTs (the task's one precision, solver/precision.py)")


@dataclass(frozen=True)
class SteeringSection:
    patches: tuple[int | str, int | str] | str = option(None, required=True, parse=_patches,
                                                        doc='[mx, my] sub-areas, or "auto" (either may be "auto")')
    patch_size_um: float = option(None, required=True, limits=LENGTH_UM)
    shift_um: float | None = option(None, limits=LENGTH_UM, doc="between sub-areas (default: the waist)")
    hexagon_fill: float = option(0.97, limits=Limits(low=0.05, high=10.0),
                                 doc="hexagon radius as a fraction of sin(λ_min/(π w)); > 1 steers beyond aliasing")


@dataclass(frozen=True)
class CompareSection:
    """`wavebrdf compare` only; [compare.<model>] tables hold other models' options."""

    models: str | tuple[str, ...] | None = option(None, parse=_model_names)
    reference: str | tuple[str, ...] | None = option(None, parse=_model_names)


@dataclass(frozen=True)
class RunSection:
    executor: str = option(AUTO, choices=executor_names())
    workers: int | None = option(None, low=1, high=4096, doc="per node")
    memory_gb: float | None = option(None, limits=Limits(low=0, low_open=True, span=(1e-3, 1e6), unit="GiB",
                                                         note="per node"))
    retries: int = option(1, low=0, high=100)
    prologue: str | None = option(None, doc="`wavebrdf submit`: shell lines before the run (module loads, venv)")


@dataclass(frozen=True)
class FiberSection:
    """A fiber's cross section (instead of [surface]); lengths in µm."""

    shape: str = option(None, required=True, choices=tuple(FIBER_SHAPE_KEYS))
    radius_um: float | None = option(None, limits=LENGTH_UM)
    semi_axes_um: tuple[float, float] | None = option(None, limits=LENGTH_UM)
    points_file: str | None = option(None, doc="polygon/spline outline (solver/fiber/shapes.py)")
    segments: int | None = option(None, low=8, high=20_000, doc="a 50 µm fiber at 0.4 µm needs ~15 000")
    rotation_deg: float = option(0.0, limits=ANGLE_DEG)
    longitudinal_variance: float = option(0.02, limits=Limits(low=1e-3, high=10.0),
                                          doc="d'Eon's v (rad²): the dataset's default for M0")


@dataclass(frozen=True)
class OutputSection:
    phi_r_bins: int = option(360, low=8, high=100_000, doc="fibers: BCSDF azimuth bins")
    phi_i_bins: int | None = option(None, low=1, high=100_000, doc="fibers (default: 1 for circles, 72 otherwise)")
    resolution: int = option(512, low=16, high=8192, doc="projected-hemisphere image side")
    per_polarization: bool = option(False)
    polarization: str = option("intensity", choices=POLARIMETRY,
                               doc="surfaces: also store per pixel the Jones matrix (2×2 complex, s/p in and out) or "
                                   "the Mueller matrix (4×4) of models returning coherent fields (docs/dataset.md)")


SECTIONS: dict[str, type] = {
    "study": StudySection, "surface": SurfaceSection, "material": MaterialSection, "illumination": IlluminationSection,
    "model": ModelSection, "steering": SteeringSection, "compare": CompareSection, "run": RunSection,
    "fiber": FiberSection, "output": OutputSection,
}
MODEL_SECTIONS = ("model", "compare")  # their other keys are models' options: any key, which the model checks


def _generator_fields() -> dict[str, OptionField]:
    """Every generator's keys (the first declaration of each)."""
    out: dict[str, OptionField] = {}
    for chosen in GENERATORS.values():
        for key, f in option_fields(chosen.Options).items():
            out.setdefault(key, f)
    return out


SCHEMA: dict[str, dict[str, OptionField]] = {
    name: {**option_fields(cls), **(_generator_fields() if name == "surface" else {})} for name, cls in SECTIONS.items()
}


@contextmanager
def config_errors():
    """An option's refusal (OptionsError) raised as the config's one-line ConfigError."""
    try:
        yield
    except OptionsError as exc:
        raise ConfigError(str(exc)) from None


def parse_section(name: str, raw: Any) -> tuple[Any, dict]:
    """(section ``name`` parsed, its other keys as given: a generator's or a model's)."""
    cls = SECTIONS[name]
    with config_errors():
        if name == "surface":
            return parse_open_options(cls, raw, name, _generator_fields())
        if name in MODEL_SECTIONS:
            return parse_open_options(cls, raw, name)
        return parse_options(cls, raw, name), {}


def parse_generator(name: str, given: dict) -> dict:
    """The keys ``given`` for generator ``name``, converted, in the generator's order: each must
    be one it takes, and every key it needs must be there (in the generator's words), within its
    declared range."""
    chosen = GENERATORS[name]
    try:
        chosen.check_keys(given)
    except SurfaceError as exc:
        raise ConfigError(f"[surface] {exc}") from None
    with config_errors():
        options = parse_options(chosen.Options, given, "surface")
    return {key: getattr(options, key) for key in option_fields(chosen.Options) if key in given}


def check_key(section: str, key: str, value: Any):
    """``[section] key = value`` converted, alone (no check that spans keys), or its ConfigError."""
    with config_errors():
        return SCHEMA[section][key].convert(section, value)


def section_record(name: str, section: Any = None, others: dict | None = None) -> dict:
    """The values of section ``name`` as a study's fingerprint hashes them: every key of the
    section (an absent section: its defaults, None when required), [surface] with every
    generator's keys (``others``, converted; None when absent, unless a key says
    ``record_absent=False``), [model] and [compare] with their other keys as given
    (``"options"``)."""
    fields = option_fields(SECTIONS[name])
    out = {key: getattr(section, key) if section is not None else None if f.required else f.default
           for key, f in fields.items()}
    if name == "surface":
        given = others or {}
        out.update({key: given.get(key) for key, f in _generator_fields().items() if key in given or f.record_absent})
    elif name in MODEL_SECTIONS:
        out["options"] = dict(others or {})
    return out
