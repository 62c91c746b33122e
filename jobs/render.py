"""PNG pictures of datasets (``wavebrdf render``, and ``wavebrdf run`` when it finishes).

Which pictures exist and what they show: jobs/pictures/ (surfaces: ``maps``, ``slices``,
``spectra``, ``albedo``, ``heights``; fibers: ``maps``, ``slices``, ``albedo``,
``cross-sections``). :func:`render_dataset` draws the chosen kinds for the chosen incidences,
at most ``max_images`` of them (a warning says how many were left out and how to get them), into
a staging folder that replaces the output folder's pictures only when all are written.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import re
import shutil
from pathlib import Path

from wavebrdf.jobs.errors import ConfigError
from wavebrdf.jobs.parts import StorageError, storage_error
from wavebrdf.jobs.pictures import DECADES, PictureOptions, pictures
from wavebrdf.jobs.pictures.common import MAX_DECADES
from wavebrdf.jobs.store import Dataset
from wavebrdf.jobs.study_kinds import STUDY_KINDS, StudyKind, study_kind

__all__ = ["MAX_IMAGES", "RenderedPictures", "add_render_flags", "render_dataset", "render_options"]

MAX_IMAGES = 200
logger = logging.getLogger("wavebrdf.render")


class RenderedPictures(list):
    """The paths written; ``total``: how many the options asked for (more when capped)."""

    total: int = 0


def _options(kind: StudyKind, n_directions: int, plots, incidences, decades, limits, directions) -> PictureOptions:
    """Checked :class:`PictureOptions` for a dataset of ``kind`` (a one-line ConfigError naming the
    option and value)."""
    allowed = kind.pictures.KINDS
    chosen = tuple(allowed) if plots is None else tuple(plots)
    unknown = [p for p in chosen if p not in allowed]
    if unknown or not chosen:
        raise ConfigError(f"--plots {','.join(chosen)}: {kind.name} datasets have the pictures {', '.join(allowed)}")
    if incidences is not None:
        bad = [i for i in incidences if not 0 <= i < n_directions]
        if bad or not incidences:
            raise ConfigError(f"--incidences {','.join(map(str, incidences))}: indices along {kind.directions_axis} "
                              f"are 0 to {n_directions - 1}")
    if not (math.isfinite(decades) and decades > 0):
        raise ConfigError(f"--decades {decades}: must be a number > 0")
    if limits is not None and not (0 < limits[0] < limits[1] and math.isfinite(limits[1])):
        raise ConfigError(f"--limits {limits[0]} {limits[1]}: need 0 < VMIN < VMAX")
    return PictureOptions(chosen, None if incidences is None else tuple(incidences), decades,
                          None if limits is None else tuple(limits),
                          None if directions is None else tuple(map(tuple, directions)))


def pictures_folder(path: str | Path) -> Path:
    """Where ``run`` and ``render`` put the PNGs of dataset ``path``: ``<stem>_png`` beside it."""
    path = Path(path)
    return path.with_name(path.stem + "_png")


def render_dataset(path: str | Path, out_dir: str | Path | None = None, *, plots=None, incidences=None,
                   max_images: int = MAX_IMAGES, decades: float = DECADES, limits=None,
                   directions=None) -> RenderedPictures:
    """Write the PNGs of dataset ``path`` into ``out_dir`` (default ``<stem>_png``); return their
    paths (a :class:`RenderedPictures`).

    ``plots``: kinds to draw (default: all of the dataset's kind); ``incidences``: indices along
    incidence (fibers: theta_i) for the per-direction pictures (default all); ``decades``: log
    range below the peak, or ``limits`` (vmin, vmax) in the variable's units; ``directions``:
    outgoing (θ_o, φ_o) degrees for spectra. At most ``max_images`` are drawn, in order (per
    case summaries first); a warning names how many were left out.

    The dataset is opened and checked before anything is created. The pictures are drawn into a
    temporary folder beside ``out_dir`` and moved into place only when all of them are written,
    so a failure (a damaged dataset, a full disk) leaves no partial set and an existing folder as
    it was."""
    path = Path(path)
    out_dir = Path(out_dir) if out_dir else pictures_folder(path)
    if isinstance(max_images, bool) or not isinstance(max_images, int) or max_images < 1:
        raise ConfigError(f"--max-images {max_images}: must be an integer >= 1")
    with Dataset(path) as ds:  # opened and checked: its shapes are known
        opts = _options(study_kind(ds.kind), ds.h5[ds.main_variable].shape[len(ds.sweep_keys) + 1], plots,
                        incidences, decades, limits, directions)
        written = _render(ds, path, out_dir, opts, max_images)
    return written


def _check_out_dir(out_dir: Path) -> None:
    """Refuse an output folder that cannot be written (a file there or above it, a missing or
    unwritable parent) with a :class:`StorageError` naming it: an output problem, not the dataset's."""
    def refuse(problem: str) -> StorageError:
        return StorageError(f"cannot write PNGs into {str(out_dir)!r}: {problem}; choose another folder with --out")

    if out_dir.exists() and not out_dir.is_dir():
        raise refuse("it is a file, not a folder")
    parent = out_dir.parent
    existing = next((p for p in (parent, *parent.parents) if p.exists()), None)
    if existing is not None and not existing.is_dir():
        raise refuse(f"{str(existing)!r} is a file, not a folder")
    if existing != parent:
        raise refuse(f"folder {str(parent)!r} does not exist")
    target = out_dir if out_dir.is_dir() else parent
    if not os.access(target, os.W_OK | os.X_OK):
        raise refuse(f"folder {str(target)!r} is not writable")


def _render(ds: Dataset, path: Path, out_dir: Path, opts: PictureOptions, max_images: int) -> RenderedPictures:
    _check_out_dir(out_dir)
    _remove_abandoned(out_dir)
    with ds.reading():
        wanted = pictures(ds, opts, study_kind(ds.kind).pictures)
    if not wanted:  # e.g. --plots polarization of an intensity dataset: said, not an empty folder
        raise ConfigError(f"--plots {','.join(opts.plots)}: {path.name} has none of these pictures (polarization "
                          "needs the Jones or Mueller matrices of [output] polarization = \"jones\" or "
                          "\"mueller\", spectra several wavelengths, heights a stored surface)")
    with ds.reading():
        staging = out_dir.with_name(f".{out_dir.name}.{os.getpid()}.tmp")
        names = []
        try:
            staging.mkdir()
            for picture in wanted[:max_images]:
                fig = picture.draw()
                names.append(f"{path.stem}{picture.suffix}.png")
                fig.savefig(staging / names[-1])
            if out_dir.is_dir():
                for name in names:
                    os.replace(staging / name, out_dir / name)
                staging.rmdir()
            else:
                os.rename(staging, out_dir)
        except BaseException as exc:
            shutil.rmtree(staging, ignore_errors=True)
            if isinstance(exc, OSError):
                raise storage_error(out_dir, exc) from None
            raise
    if len(wanted) > max_images:
        logger.warning("%s: wrote the first %d of %d pictures (the limit --max-images %d); choose fewer with "
                       "--plots/--incidences or raise --max-images", path.name, max_images, len(wanted), max_images)
    written = RenderedPictures(out_dir / name for name in names)
    written.total = len(wanted)
    return written


def add_render_flags(p: argparse.ArgumentParser) -> None:
    """``wavebrdf render``'s picture options (see :func:`render_dataset`)."""
    kinds = sorted({k for kind in STUDY_KINDS.values() for k in kind.pictures.KINDS})

    def listed(flag: str, convert):
        def parse(text: str):
            try:
                return [convert(x) for x in text.replace(";", ",").split(",") if x.strip()]
            except ValueError:
                raise argparse.ArgumentTypeError(f"{flag} {text}: expected a comma-separated list") from None
        return parse

    def direction(text: str):
        try:
            theta, phi = (float(x) for x in text.split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(f"--direction {text}: expected THETA,PHI in degrees") from None
        if not (0 <= theta < 90 and math.isfinite(phi)):
            raise argparse.ArgumentTypeError(f"--direction {text}: theta must be in [0, 90) degrees")
        return theta, phi

    p.add_argument("--plots", type=listed("--plots", str), metavar="KINDS",
                   help=f"pictures to draw, comma-separated: {', '.join(kinds)} (default: all of the dataset's kind)")
    p.add_argument("--incidences", type=listed("--incidences", int), metavar="I,J",
                   help="indices along incidence (fibers: theta_i) for the per-direction pictures (default: all)")
    p.add_argument("--max-images", type=int, default=MAX_IMAGES, metavar="N",
                   help=f"draw at most N pictures (default {MAX_IMAGES}); a warning says how many were left out")
    p.add_argument("--decades", type=float, default=DECADES,
                   help=f"log range below the peak, in (0, {MAX_DECADES:g}] (default {DECADES:g})")
    p.add_argument("--limits", type=float, nargs=2, metavar=("VMIN", "VMAX"),
                   help="fixed log colour/radius range in the variable's units (1/sr, 1/rad) instead of --decades")
    p.add_argument("--direction", type=direction, action="append", dest="directions", metavar="THETA,PHI",
                   help="outgoing direction (degrees) for the spectra pictures; repeatable (default: specular and "
                        "5° and 15° from it)")


def render_options(args) -> dict:
    """The keyword arguments of :func:`render_dataset` from parsed :func:`add_render_flags` flags."""
    return {"plots": args.plots, "incidences": args.incidences, "max_images": args.max_images,
            "decades": args.decades, "limits": args.limits, "directions": args.directions}


def _remove_abandoned(out_dir: Path) -> None:
    """Remove the staging folders of renders into ``out_dir`` whose process is gone."""
    pattern = re.compile(rf"\.{re.escape(out_dir.name)}\.(\d+)\.tmp")
    for entry in out_dir.parent.iterdir():
        found = pattern.fullmatch(entry.name)
        if found and entry.is_dir() and not _alive(int(found.group(1))):
            shutil.rmtree(entry, ignore_errors=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
