"""``wavebrdf export DATASET --format F [-o FILE]``: one sweep case of a dataset written in another
tool's file format.

:data:`FORMATS` maps a format name to an :class:`ExportFormat`: its file suffix, the dataset kinds
it takes and its writer, a function ``(dataset path, case, options) -> (write(fh), summary)``
imported when the format is used. Formats:

* ``rgl``: the RGL material file (``.bsdf``) of Mitsuba 3's built-in ``measured`` BSDF and
  pbrt-v4's measured material, built by :mod:`wavebrdf.mitsuba.rgl` (docs/export.md).

The case is chosen by ``--case N`` (flat C-order index over the sweep axes) or
``--sweep KEY=VALUE`` (one per swept key); a dataset without a sweep has one case. The file is
written atomically (a temporary name, then a rename); the output's folder may be missing one
level, as for ``run``.
"""

from __future__ import annotations

import argparse
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from wavebrdf._version import __version__
from wavebrdf.jobs.output_path import make_output_folder
from wavebrdf.jobs.parts import atomic_write
from wavebrdf.jobs.store import Dataset, not_a_dataset
from wavebrdf.solver.models import model_class, model_names

__all__ = ["FORMATS", "ExportError", "ExportFormat", "add_case_flags", "add_export_parser", "export_dataset",
           "non_reciprocal_models", "select_case"]


class ExportError(ValueError):
    """A dataset, case or option the export cannot take; the message names it and what would do."""


@dataclass(frozen=True)
class ExportFormat:
    """A file format ``export`` writes: ``build(path, case, options)`` returns (``write(fh)``,
    a one-line summary); ``kinds``: the dataset kinds (jobs/study_kinds.py) it takes; ``owns(path)``:
    whether an existing file is of this format (an export replaces no other file)."""

    name: str
    suffix: str
    summary: str
    kinds: tuple[str, ...]
    build: Callable
    owns: Callable


@dataclass(frozen=True)
class ExportOptions:
    """What the formats read: ``channels`` ("spectral" | "rgb"), ``resolution`` (sample-space
    nodes per axis), ``smooth_sigma`` (speckle blur in u units; None: as the dataset's config),
    ``isotropic`` (None: as the config declares), ``description`` (text stored in the file)."""

    channels: str = "spectral"
    resolution: int | None = None
    smooth_sigma: float | None = None
    isotropic: bool | None = None
    description: str = ""


def _build_rgl(path: Path, case: int, options: ExportOptions):
    from wavebrdf.mitsuba.rgl import rgl_fields, write_tensor_file

    try:
        made = rgl_fields(path, case=case, channels=options.channels, resolution=options.resolution,
                          smooth_sigma=options.smooth_sigma, isotropic=options.isotropic,
                          description=options.description)
    except ValueError as exc:  # RGLError and the tables' refusals (a failed task's image, bad options)
        raise ExportError(str(exc)) from None
    d = made.diagnostics
    lams = d["wavelengths_um"]
    what = ("linear sRGB" if d["channels"] == "rgb" else f"1 wavelength {lams[0]:g} µm" if len(lams) == 1
            else f"{len(lams)} wavelengths {lams[0]:g}–{lams[-1]:g} µm")
    why = "--isotropic" if options.isotropic is not None else d["isotropy_source"]
    summary = (f"RGL {d['channels']} ({what}), {'isotropic' if d['isotropic'] else 'anisotropic'} "
               f"({why}): {len(d['theta_i_deg'])} θ_i × {len(d['phi_i_deg'])} φ_i, sample space "
               f"{d['sample_resolution']}², {d['bytes'] / 2**20:.1f} MiB")
    if d["channels_note"]:  # the tables' (wavebrdf/mitsuba/tables.py): colour made of no visible wavelength
        summary += f"; note: {d['channels_note']} (--channels spectral keeps the data's own wavelengths)"
    if d.get("albedo_note"):  # wavebrdf/mitsuba/rgl.py: a slice's albedo off its table's
        summary += f"; note: {d['albedo_note']}"
    if d["polarization"] not in ("", "unpolarized"):  # the format is read as unpolarized
        summary += (f"; note: the dataset's BRDF is {d['polarization']}-polarized ([illumination] polarization = "
                    f"\"{d['polarization']}\"), and so is the file's: not the unpolarized BRDF a renderer expects")
    return (lambda fh: write_tensor_file(fh, made.fields)), summary


def _is_tensor_file(path: Path) -> bool:
    from wavebrdf.mitsuba.rgl import is_tensor_file

    return is_tensor_file(path)


FORMATS: dict[str, ExportFormat] = {
    "rgl": ExportFormat("rgl", ".bsdf", "RGL material file: Mitsuba 3 'measured' BSDF, pbrt-v4 measured material",
                        ("surface",), _build_rgl, _is_tensor_file),
}


def select_case(ds: Dataset, case: int | None = None, sweep: list[tuple[str, str]] | None = None) -> int:
    """The flat case index (C order over the sweep axes) that ``case`` or ``sweep`` ((key, value
    text) pairs naming every swept key) selects; a dataset without a sweep has case 0 only."""
    keys = ds.sweep_keys
    coords = ds.coords
    lead = ds.sweep_shape
    n_cases = int(np.prod(lead))
    listing = "; ".join(f"{k} = {', '.join(map(str, coords[k]))}" for k in keys)
    if case is not None and sweep:
        raise ExportError("--case and --sweep: give one of them")
    if case is not None:
        if not 0 <= case < n_cases:
            raise ExportError(f"--case {case}: the dataset has {n_cases} case(s) (flat index over "
                              f"{', '.join(keys) or 'no sweep'})")
        return case
    if not sweep:
        if n_cases == 1:
            return 0
        raise ExportError(f"{ds.path}: {n_cases} sweep cases ({listing}): choose one with --case N (0–{n_cases - 1}) "
                          "or --sweep KEY=VALUE for each swept key")
    if not keys:
        raise ExportError(f"--sweep {sweep[0][0]}={sweep[0][1]}: {ds.path} has no sweep")
    given = dict(sweep)
    if len(given) != len(sweep) or set(given) != set(keys):
        raise ExportError(f"--sweep {' '.join(f'{k}={v}' for k, v in sweep)}: name each swept key once "
                          f"({', '.join(keys)})")
    index = []
    for key in keys:
        values, text = coords[key], given[key]
        if values.dtype.kind in "fiu":
            try:
                wanted = float(text)
            except ValueError:
                raise ExportError(f"--sweep {key}={text}: not a number (values: {', '.join(map(str, values))})") \
                    from None
            hits = np.flatnonzero(np.isclose(values.astype(float), wanted, rtol=1e-9, atol=1e-12))
        else:
            hits = np.flatnonzero(values == text)
        if len(hits) != 1:
            raise ExportError(f"--sweep {key}={text}: not a swept value (values: {', '.join(map(str, values))})")
        index.append(int(hits[0]))
    return int(np.ravel_multi_index(index, lead))


def _description(ds: Dataset, case: int, fmt: ExportFormat) -> str:
    """What the file holds: the software, the dataset and study, the case and its swept values, the model."""
    keys = ds.sweep_keys
    coords = ds.coords
    values = ", ".join(f"{k} = {coords[k][i]}" for k, i in zip(keys, np.unravel_index(case, ds.sweep_shape)))
    try:
        model = tomllib.loads(ds.config).get("model", {}).get("name", "?")
    except tomllib.TOMLDecodeError:
        model = "?"
    polarization = ds.brdf_polarization
    return (f"wavebrdf {__version__} export ({fmt.name}) of {ds.path.name}: study {ds.attrs.get('study')!r}, "
            f"case {case}{f' ({values})' if values else ''}, model {model}, "
            f"{f'{polarization} BRDF, ' if polarization else ''}created {ds.attrs.get('created')}")


def export_dataset(dataset: str | Path, out: str | Path | None = None, *, fmt: str = "rgl", case: int | None = None,
                   sweep: list[tuple[str, str]] | None = None, **options) -> dict:
    """Write one case of ``dataset`` in format ``fmt`` to ``out`` (default: beside the dataset,
    ``<stem>[_case<N>]<suffix>``); ``options``: :class:`ExportOptions` fields. Returns
    {"path", "case", "summary", "seconds"}."""
    if fmt not in FORMATS:
        raise ExportError(f"--format {fmt}: expected one of {', '.join(FORMATS)}")
    chosen = FORMATS[fmt]
    start = time.perf_counter()
    dataset = Path(dataset)
    with Dataset(dataset) as ds:
        if ds.kind not in chosen.kinds:
            raise ExportError(f"{dataset}: a {ds.kind} dataset; --format {fmt} takes {', '.join(chosen.kinds)} "
                              "datasets")
        case = select_case(ds, case, sweep)
        several = bool(ds.sweep_keys)
        description = options.pop("description", None) or _description(ds, case, chosen)
        swapped = non_reciprocal_models(ds)
    if out is None:
        rgb = "_rgb" if options.get("channels") == "rgb" else ""
        out = dataset.with_name(f"{dataset.stem}{f'_case{case}' if several else ''}{rgb}{chosen.suffix}")
    out = Path(out)
    if out.is_dir():
        raise ExportError(f"-o {out}: is a folder (give a file name, e.g. {out / (dataset.stem + chosen.suffix)})")
    if out.resolve() == dataset.resolve() or (out.is_file() and not_a_dataset(out) is None):
        raise ExportError(f"-o {out}: is a wavebrdf dataset; an export never replaces one (give another file name, "
                          f"e.g. {dataset.with_suffix(chosen.suffix)})")
    if out.suffix != chosen.suffix:
        raise ExportError(f"-o {out}: a {fmt} file ends in {chosen.suffix} (e.g. {out.with_suffix(chosen.suffix)})")
    if out.exists() and not chosen.owns(out):
        raise ExportError(f"-o {out}: exists and is not a {fmt} file; an export replaces only its own format's files "
                          "(give another file name, or move it away)")
    write, summary = chosen.build(dataset, case, ExportOptions(description=description, **options))
    make_output_folder(out)
    atomic_write(out, write)
    if swapped:
        summary += (f"; note: {', '.join(swapped)} {'is' if len(swapped) == 1 else 'are'} not reciprocal, and a "
                    "renderer looks the file up with its camera-side direction as the incidence (f(ω_o → ω_i) "
                    "where the dataset holds f(ω_i → ω_o))")
    return {"path": out, "case": case, "summary": summary, "seconds": time.perf_counter() - start}


def non_reciprocal_models(ds: Dataset) -> list[str]:
    """The models that computed the dataset's tasks (its config's where the task table is empty)
    whose capabilities say they are not reciprocal: their tables read backwards in a renderer."""
    names = {m.decode() if isinstance(m, bytes) else str(m) for m in ds.tasks.get("model", [])}
    if not names:
        try:
            names = {tomllib.loads(ds.config).get("model", {}).get("name", "")}
        except tomllib.TOMLDecodeError:
            return []
    return sorted(n for n in names if n in model_names() and not model_class(n).capabilities.reciprocal)


def _sweep_pair(text: str) -> tuple[str, str]:
    key, sep, value = text.partition("=")
    if not sep or not key.strip() or not value.strip():
        raise argparse.ArgumentTypeError(f"--sweep {text}: expected KEY=VALUE (a swept key and one of its values)")
    return key.strip(), value.strip()


def _resolution(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    from wavebrdf.mitsuba.rgl import RESOLUTION_RANGE

    low, high = RESOLUTION_RANGE
    if not low <= value <= high:
        raise argparse.ArgumentTypeError(f"--resolution {text}: must be an integer from {low} to {high}")
    return value


def _sigma(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not np.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"--smooth-sigma {text}: must be a finite number >= 0 (u units)")
    return value


def cmd_export(args) -> int:
    result = export_dataset(args.file, args.output, fmt=args.format, case=args.case, sweep=args.sweep,
                            channels=args.channels, resolution=args.resolution, smooth_sigma=args.smooth_sigma,
                            isotropic=args.isotropic)
    print(f"wrote {result['path']} (case {result['case']}; {result['summary']}) in {result['seconds']:.1f} s")
    return 0


def add_case_flags(parser, prefix: str = "") -> None:
    """``--case N`` or ``--sweep KEY=VALUE`` (:func:`select_case`) on ``parser``; ``prefix`` heads
    their help (e.g. "with --scene: ")."""
    which = parser.add_mutually_exclusive_group()
    which.add_argument("--case", type=int, help=f"{prefix}sweep case: flat index in C order over the sweep axes")
    which.add_argument("--sweep", action="append", type=_sweep_pair, metavar="KEY=VALUE",
                       help=f"{prefix}sweep case by value, once per swept key (e.g. surface.rms_height_um=0.05)")


def add_export_parser(sub) -> None:
    """The ``export`` subcommand on the CLI's subparsers."""
    p = sub.add_parser("export", help="write one case of a dataset in another tool's format: "
                                      + "; ".join(f"{f.name} ({f.summary})" for f in FORMATS.values()))
    p.add_argument("file", type=Path, help="a wavebrdf dataset")
    p.add_argument("--format", "-f", choices=list(FORMATS), default="rgl", help="output format (default rgl)")
    p.add_argument("--output", "-o", type=Path, help="output file (default: <dataset stem>[_case<N>].bsdf beside it)")
    add_case_flags(p)
    p.add_argument("--channels", choices=["spectral", "rgb"], default="spectral",
                   help="rgl: the dataset's wavelengths (Mitsuba spectral variants, pbrt-v4) or linear sRGB "
                        "(Mitsuba RGB variants); default spectral")
    p.add_argument("--resolution", type=_resolution,
                   help="rgl: sample-space nodes per axis of the spectra and luminance tables (default 128 for "
                        "isotropic data, 64 for anisotropic)")
    p.add_argument("--smooth-sigma", type=_sigma,
                   help="speckle blur in u units (default: λ/(2π·waist) from the dataset's config, as the "
                        "wavebrdf plugin; 0: none)")
    p.add_argument("--isotropic", action=argparse.BooleanOptionalAction, default=None,
                   help="treat the surface as statistically isotropic, or (--no-isotropic) not (default: as its "
                        "config declares)")
    p.set_defaults(func=cmd_export)
