"""The checks of a validated study that need its built objects, run at load so that a study that
cannot run is refused before a task starts: the material's index at every wavelength (within a
material file's rows), the height field's memory and contents, the model's own refusals at the
hardest scenes, the fiber's cross section. Each refusal is a one-line ConfigError.
"""

from __future__ import annotations

import numpy as np

from wavebrdf.jobs.errors import ConfigError, fail, fmt
from wavebrdf.jobs.input_files import height_file_shape, input_file_problem
from wavebrdf.jobs.study import Study
from wavebrdf.solver.farfield import HemisphereGrid
from wavebrdf.solver.materials import MaterialError
from wavebrdf.solver.models import FiberScene, SurfaceScene
from wavebrdf.solver.resources import meminfo_bytes
from wavebrdf.solver.surface import SurfaceError

__all__ = ["DEFAULT_PHI_I_BINS", "SURFACE_BYTES_PER_NODE", "check_study", "fiber_phi_i_bins", "fiber_scene",
           "rectangle_outside_steering"]

SURFACE_BYTES_PER_NODE = 96  # peak while a height field is built and analysed (measured: gaussian 90)
DEFAULT_PHI_I_BINS = 72  # fiber tables of non-circular cross sections


def rectangle_outside_steering(what: str) -> ConfigError:
    """The refusal of a rectangular surface (``what``: the keys that make it one) outside steering."""
    return ConfigError(f"[surface] {what}: a rectangular surface is only accepted as the global surface of a "
                       "[steering] study (its patches are square); other studies need a square surface "
                       "(size_um = L, cells = N, or an (N+1)x(N+1) height file)")


def check_study(study: Study) -> None:
    """Checks that need the built objects: material range, height matrix contents, the model's
    own checks, the fiber's shape."""
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
            raise rectangle_outside_steering(f"file = {fmt(str(study.surface.file))} holds "
                                             f"{surface.z.shape[0]}x{surface.z.shape[1]} heights")
        if study.steering is None:
            _check_model_scene(study, surface, index)
    if study.fiber is not None:
        from wavebrdf.solver.fiber import ShapeError

        try:
            section = study.fiber.build()
        except (ShapeError, OSError) as exc:
            raise ConfigError(f"[fiber] {exc}") from None
        _check_model_fiber(study, section, index)


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


def _check_model_fiber(study: Study, section, index) -> None:
    """The fiber model's own checks (Model.check: the cross section it needs) at the case's
    shortest and longest wavelength, each with the first and the most oblique θ_i."""
    ill = study.illumination
    lams = np.asarray(ill.wavelengths_um, dtype=float)
    thetas = np.deg2rad(np.asarray(ill.theta_i_deg, dtype=float))
    model = study.model.build()
    for w in sorted({int(np.argmin(lams)), int(np.argmax(lams))}):
        for t in sorted({0, int(np.argmax(np.abs(thetas)))}):
            try:
                model.check(fiber_scene(study, section, w, float(thetas[t]), complex(index[w])))
            except ValueError as exc:
                raise ConfigError(str(exc)) from None


def fiber_phi_i_bins(study: Study) -> int:
    """Fiber tables: the number of φ_i bins (ignored when explicit φ_i samples are given):
    ``[output] phi_i_bins``, else 1 for circles (rotation invariant), :data:`DEFAULT_PHI_I_BINS`
    otherwise."""
    if study.output_options.phi_i_bins is not None:
        return study.output_options.phi_i_bins
    return 1 if study.fiber.shape == "circle" else DEFAULT_PHI_I_BINS


def fiber_scene(study: Study, section, wavelength: int, theta_i: float, index: complex) -> FiberScene:
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
        phi_i_bins=fiber_phi_i_bins(study),
        phi_r_bins=study.output_options.phi_r_bins,
        radius_um=spec.radius_um if spec.shape == "circle" else None,
        precision=study.model.precision,
        shape=spec.shape,
        meshed=spec.meshed,
    )
