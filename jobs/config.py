"""Study configuration: TOML → validated, typed objects; sweeps expanded into cases.

Every problem is reported as a :class:`ConfigError` whose one-line message names the key, the
value and what is allowed, e.g. ``[illumination] wavelengths_um = [-0.4]: values must be > 0``.
Each section is an options dataclass (jobs/sections.py: keys, types, physical ranges and
choices, parsed by solver/options.py); ``[surface]`` also takes its generator's keys
(solver/surface.py GENERATORS), ``[model]`` its model's (``[model.<name>]`` as well). This module
checks what spans sections — exactly one of ``[surface]`` and ``[fiber]``, the keys a surface or
a fiber study takes, keys that would be ignored (``kappa`` with ``name``, ``cells`` with
``file``), the model against the study — and builds one :class:`~wavebrdf.jobs.study.Study` per
sweep case; jobs/study_checks.py then checks the built objects. Relative ``surface.file``,
``material.file``, ``illumination.directions_file`` and ``fiber.points_file`` paths are resolved
against the config file's folder (jobs/input_files.py reads them), ``study.output`` against the
working directory (jobs/output_path.py). Lists of numbers may be ``{start, stop, count}`` ranges
and directions a ``{theta, phi}`` grid (jobs/ranges.py); :func:`load_config` also takes a dict
and ``--set``-style overrides (jobs/overrides.py). The sections and their keys: docs/config.md.

``[sweep] "section.key" = [values...]`` gives one case per combination of the values.
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
import itertools
from pathlib import Path
from typing import Any

from wavebrdf.jobs.errors import ConfigError, exactly_one, fail, fmt
from wavebrdf.jobs.input_files import (read_config_text, read_directions_file, read_material_rows,
                                       resolve_input_path)
from wavebrdf.jobs.output_path import check_output_path
from wavebrdf.jobs.overrides import dict_config_text, overridden_text, parse_toml
from wavebrdf.jobs.ranges import RANGE_KEYS, expand_range
from wavebrdf.jobs.sections import (MODEL_SECTIONS, SCHEMA, SECTIONS, IlluminationSection, MaterialSection,
                                    ModelSection, OutputSection, RunSection, StudySection, config_errors, parse_section,
                                    section_record)
from wavebrdf.jobs.study import IlluminationSpec, MaterialSpec, ModelSpec, Study, StudyConfig
from wavebrdf.jobs.study_checks import check_study
from wavebrdf.jobs.study_kinds import STUDY_KINDS
from wavebrdf.solver.models import model_class, model_names, rungs
from wavebrdf.solver.options import parse_options

__all__ = ["SCHEMA", "ConfigError", "Study", "StudyConfig", "load_config", "parse_config"]

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
    "output.polarization": "every case must store the same variables",
    "output.per_polarization": "every case must store the same variables",
    "illumination.polarization": "the dataset labels its BRDF with one polarization; store s and p beside it with "
                                 "[output] per_polarization = true (brdf_sp)",
    "run.executor": "it does not change the results",
    "run.workers": "it does not change the results",
    "run.retries": "it does not change the results",
    "run.prologue": "it does not change the results",
}
REQUIRED_SECTIONS = ("material", "illumination", "model")  # + the section of one study kind


def _suggest(key: str, options) -> str:
    close = difflib.get_close_matches(key, list(options), n=1)
    return f"; did you mean {close[0]!r}?" if close else ""


def _build_study(data: dict, base_dir: Path, default_name: str, sweep_values: dict,
                 output: str | Path | None = None) -> Study:
    for section in data:
        if section not in SECTIONS and section != "sweep":
            raise ConfigError(f"[{section}]: unknown section{_suggest(section, SECTIONS)} "
                              f"(allowed: {', '.join(SECTIONS)})")
    for section in REQUIRED_SECTIONS:
        if section not in data:
            raise ConfigError(f"[{section}]: missing required section")
    parsed = {name: parse_section(name, data[name]) for name in SECTIONS if name in data}
    given = {name: parsed[name][0] if name in parsed else None for name in SECTIONS}  # None: absent
    others = {name: parsed[name][1] if name in parsed else {} for name in SECTIONS}

    study_section = given["study"] or StudySection()
    name = study_section.name or default_name
    output = check_output_path(str(output or study_section.output or f"{name}.h5"))
    kinds = [kind for kind in STUDY_KINDS.values() if kind.section in data]
    if len(kinds) != 1:
        raise ConfigError("give exactly one of " + " or ".join(f"[{k.section}] ({k.geometry})"
                                                              for k in STUDY_KINDS.values()))
    kind = kinds[0]
    spec, others[kind.section] = kind.spec(given[kind.section], others[kind.section], data[kind.section], base_dir)
    material, material_rows = _material_spec(given["material"], data["material"], base_dir)
    wavelengths = given["illumination"].wavelengths_um
    if wavelengths is None:
        if material.file is None:
            raise ConfigError("[illumination] wavelengths_um: missing required key")
        wavelengths = tuple(row[0] for row in material.table)  # the reference's default
    illumination = _illumination_spec(given["illumination"], data["illumination"], wavelengths, kind, base_dir)
    model = _model_spec(given["model"], others["model"], kind)
    out = given["output"] or OutputSection()
    if not model.capabilities.polarized and (illumination.polarization != "unpolarized" or out.per_polarization):
        raise ConfigError(f"[illumination] polarization = \"{illumination.polarization}\" / [output] per_polarization: "
                          f"model {model.name!r} does not resolve polarization (its s and p are the same); "
                          "use polarization = \"unpolarized\" and per_polarization = false")
    if out.polarization != "intensity" and not model.capabilities.vector_fields:
        what = ("scalar fields per polarization (E_s on φ_o, E_p on θ_o: no cross-polarization, so its Jones "
                "matrix is diagonal in every direction)" if model.capabilities.returns == "fields"
                else model.capabilities.returns.replace("_", " "))
        raise ConfigError(f"[output] polarization = \"{out.polarization}\": model {model.name!r} returns {what}; "
                          "Jones and Mueller matrices come from the vector-field models "
                          f"{', '.join(n for n in rungs() if model_class(n).capabilities.vector_fields)} (or auto)")
    kind.check_sections(spec, data)
    if "steering" in data and not model.capabilities.steerable:
        raise ConfigError(f"[steering]: model {model.name!r} cannot be steered (it returns "
                          f"{model.capabilities.returns}, not coherent fields with their incident beam); "
                          "remove [steering] or choose a steerable model")
    steering = given["steering"]
    if steering is not None:
        steering = dataclasses.replace(steering, shift_um=steering.shift_um or illumination.waist_um)

    record = {name: section_record(name, given[name], others[name]) for name in SECTIONS}
    if material_rows is not None:
        record["material"]["table"] = material_rows  # results depend on the file's rows, not its name
    record["illumination"].update(wavelengths_um=illumination.wavelengths_um,
                                  directions_deg=illumination.directions_deg or None)
    study = Study(name=name, output=output, kind=kind, material=material, illumination=illumination, model=model,
                  output_options=out, steering=steering, run=given["run"] or RunSection(), sections=record,
                  sweep_values=dict(sweep_values), **{kind.section: spec})
    check_study(study)
    return study


def _model_spec(m: ModelSection, given: dict, kind) -> ModelSpec:
    """[model]: a registered model that takes the input of this study's ``kind``, with its Options
    parsed from the other keys of [model] and [model.<name>]."""
    takes = kind.model_inputs
    if m.name not in model_names() or model_class(m.name).capabilities.takes not in takes:
        allowed = [n for t in takes for n in model_names(t)]  # imports every model: the error path only
        raise fail("model", "name", m.name, f"a {kind.name} study needs one of {', '.join(repr(n) for n in allowed)}")
    given = dict(given)
    own = given.pop(m.name, None)  # [model.<name>] table
    if own is not None:
        if not isinstance(own, dict):
            raise fail("model", m.name, own, f"must be a table of the {m.name} model's options")
        both = sorted(set(own) & set(given))
        if both:
            raise ConfigError(f"[model.{m.name}] {both[0]}: also given in [model]; give it once")
        given.update(own)
    with config_errors():
        options = parse_options(model_class(m.name).Options, given, "model")
    return ModelSpec(m.name, m.precision, options)


def _material_spec(m: MaterialSection, given: dict, base_dir: Path) -> tuple[MaterialSpec, list | None]:
    """[material] and, with a file, the file's rows (λ, n, κ)."""
    _material_source(m, given)
    file = rows = None
    if m.file is not None:
        file = resolve_input_path(m.file, base_dir)
        rows = read_material_rows(m.file, file)
    table = rows if rows is not None else m.table
    return MaterialSpec(m.name, None if table is None else tuple(map(tuple, table)), m.n, m.kappa,
                        m.exterior_index, file), rows


def _material_source(m: MaterialSection, given: dict) -> None:
    """[material]: exactly one of name, table, file, n; kappa only with n."""
    sources = [k for k in ("name", "table", "file", "n") if getattr(m, k) is not None]
    if "file" in sources and len(sources) > 1:
        other = next(k for k in sources if k != "file")
        raise ConfigError(f"[material] file and {other}: give one of them (material.file = {fmt(m.file)} is a "
                          f"table of λ, n, κ rows; material.{other} is another source of the index)")
    if "kappa" in given and m.file is not None:
        raise ConfigError(f"[material] file and kappa: give one of them (material.file = {fmt(m.file)} holds "
                          "κ per wavelength; kappa goes with a constant n)")
    exactly_one("material", m, ("name", "table", "file", "n"))
    if "kappa" in given and m.n is None:  # it would be ignored: the source gives its own κ
        source = "name" if m.name is not None else "table"
        what = (f"material.name = {fmt(m.name)} gives its own κ per wavelength" if source == "name"
                else "material.table gives κ in its third column")
        raise ConfigError(f"[material] kappa = {fmt(given['kappa'])} and {source}: kappa would be ignored ({what}); "
                          "remove kappa, or give a constant index as n and kappa instead")


def _illumination_spec(ill: IlluminationSection, given: dict, wavelengths: tuple[float, ...], kind,
                       base_dir: Path) -> IlluminationSpec:
    """[illumination] of a study of ``kind``: none of the keys only other kinds read, the ones it
    needs; directions from directions_deg or directions_file."""
    for other in STUDY_KINDS.values():
        for key in other.illumination_keys if other is not kind else ():
            if key in given:
                raise ConfigError(f"[illumination] {key}: not used in a {kind.name} study")
    directions = ill.directions_deg
    if ill.directions_file is not None:
        if directions is not None:
            raise ConfigError(f"[illumination] directions_deg and directions_file: give one of them (directions_file = "
                              f"{fmt(ill.directions_file)} lists the directions already)")
        path = resolve_input_path(ill.directions_file, base_dir)  # its directions, in degrees:
        directions = read_directions_file(ill.directions_file, path, ill.angles or "rad")
    elif ill.angles is not None:
        raise ConfigError(f"[illumination] angles = {fmt(ill.angles)}: only used with directions_file (the units "
                          "of its θ, φ columns); directions_deg is in degrees")
    ill = dataclasses.replace(ill, directions_deg=directions)
    for key in kind.required_illumination:
        if getattr(ill, key) is None:
            raise ConfigError(f"[illumination] {key}: missing required key")
    return IlluminationSpec(wavelengths, directions or (), ill.waist_um, ill.polarization, ill.beam,
                            ill.theta_i_deg or (), ill.phi_i_deg)


def _set_dotted(data: dict, dotted: str, value: Any) -> None:
    section, key = dotted.split(".", 1)
    data.setdefault(section, {})[key] = value


def _sweep_identity(value) -> str:
    """What makes two sweep values the same: 2 and 2.0 are one number (True and 1 are not)."""
    return repr(float(value)) if isinstance(value, (int, float)) and not isinstance(value, bool) else repr(value)


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
        if section not in SCHEMA or (key not in SCHEMA[section] and section not in MODEL_SECTIONS):
            raise ConfigError(f"[sweep] {dotted}: not a config key{_suggest(dotted, _all_keys())}")
        if dotted in NOT_SWEEPABLE:
            raise ConfigError(f"[sweep] {dotted}: cannot be swept ({NOT_SWEEPABLE[dotted]})")
        if not isinstance(values, list) or not values:
            raise ConfigError(f"[sweep] {dotted} = {fmt(values)}: must be a non-empty list of values")
        if len(set(map(_sweep_identity, values))) != len(values):
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
        text = read_config_text(path)
    if overrides:
        text = overridden_text(text, overrides, path)
    if output is None:
        return parse_config(text, path)
    cfg = parse_config(text, path, output=output)
    note = f"\n# --output given on the command line: {output}\n"
    return StudyConfig(text=text + note, path=path, sweep_axes=cfg.sweep_axes, cases=cfg.cases)
