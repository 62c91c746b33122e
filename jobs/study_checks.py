"""The checks of a validated study that need its built objects, run at load so that a study that
cannot run is refused before a task starts: the material's index at every wavelength (within a
material file's rows), then those of the study's kind (jobs/study_kinds.py): a surface's memory
and contents (:func:`check_surface`), a fiber's cross section, and the model's own refusals at the
hardest scenes (:func:`check_model`). Each refusal is a one-line ConfigError.
"""

from __future__ import annotations

import numpy as np

from wavebrdf.jobs.errors import ConfigError, fail, fmt
from wavebrdf.jobs.input_files import height_file_shape, input_file_problem
from wavebrdf.jobs.study import Study
from wavebrdf.solver.farfield import HemisphereGrid
from wavebrdf.solver.materials import MaterialError
from wavebrdf.solver.models import SurfaceScene
from wavebrdf.solver.resources import meminfo_bytes
from wavebrdf.solver.surface import SurfaceError

__all__ = ["SURFACE_BYTES_PER_NODE", "check_model", "check_study", "check_surface", "rectangle_outside_steering"]

SURFACE_BYTES_PER_NODE = 96  # peak while a height field is built and analysed (measured: gaussian 90)


def rectangle_outside_steering(what: str) -> ConfigError:
    """The refusal of a rectangular surface (``what``: the keys that make it one) outside steering."""
    return ConfigError(f"[surface] {what}: a rectangular surface is only accepted as the global surface of a "
                       "[steering] study (its patches are square); other studies need a square surface "
                       "(size_um = L, cells = N, or an (N+1)x(N+1) height file)")


def check_study(study: Study) -> None:
    """Checks that need the built objects: the material's range, then those of the study's kind
    (``study.kind.check``: the height field or the cross section, and the model's own checks)."""
    try:
        material = study.material.build()
        if study.material.file is not None:
            _check_file_range(study, material.wavelength_range_um)
        index = material.index(np.array(study.illumination.wavelengths_um))
    except MaterialError as exc:
        raise ConfigError(f"[material] {exc}") from None
    if np.any(np.imag(index) > 0):  # pragma: no cover - Material guarantees κ >= 0
        raise ConfigError("[material]: negative kappa (gain medium)")
    study.kind.check(study, index)


def check_surface(study: Study, index) -> None:
    """A surface study: the height field's memory and contents, a rectangle only under steering,
    the model's own checks on whole-surface scenes (``index``: n − jκ at every wavelength)."""
    _check_surface_size(study)
    try:
        surface = study.surface.build()
    except SurfaceError as exc:
        file = study.surface.file
        where = f" (file = {fmt(str(file))})" if file is not None and str(file) not in str(exc) else ""
        raise ConfigError(f"[surface] {exc}{where}") from None
    if study.steering is None and study.surface.file is not None and surface.z.shape[0] != surface.z.shape[1]:
        raise rectangle_outside_steering(f"file = {fmt(str(study.surface.file))} holds "
                                         f"{surface.z.shape[0]}x{surface.z.shape[1]} heights")
    if study.steering is None:
        directions = np.deg2rad(np.asarray(study.illumination.directions_deg, dtype=float))
        ill, grid = study.illumination, HemisphereGrid(study.output_options.resolution)
        check_model(study, lambda w, d: SurfaceScene(
            surface, float(ill.wavelengths_um[w]), complex(index[w]), float(directions[d, 0]),
            float(directions[d, 1]), ill.waist_um, grid, study.material.exterior_index, ill.beam,
            study.model.precision), directions[:, 0])


def check_model(study: Study, scene, theta_i) -> None:
    """The model's own checks (Model.check: its options and the sampling refusals) on ``scene(w,
    d)`` at the case's shortest and longest wavelength ``w``, each with the first incident
    direction ``d`` and the most oblique (largest |``theta_i``[d]|): the lattice and lobe limits are
    hardest at short λ and large θ_i."""
    lams = np.asarray(study.illumination.wavelengths_um, dtype=float)
    model = study.model.build()
    for w in sorted({int(np.argmin(lams)), int(np.argmax(lams))}):
        for d in sorted({0, int(np.argmax(np.abs(theta_i)))}):
            try:
                model.check(scene(w, d))
            except ValueError as exc:
                raise ConfigError(str(exc)) from None


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
