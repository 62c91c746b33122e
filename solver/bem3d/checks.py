"""Warnings of the 3D BEM: situations that give a result of doubtful accuracy, said out loud.

Every check emits a :class:`BEMWarning` subclass (or the :class:`FootprintWarning` that all
surface models share, solver/footprint.py) through :func:`warnings.warn` and records the message
in the run's diagnostics, so a batch run keeps it next to the result.
"""

from __future__ import annotations

import warnings

import numpy as np

from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.footprint import FootprintWarning
from wavebrdf.solver.validity import cells_fix

__all__ = [
    "BEMWarning",
    "FootprintWarning",
    "MaterialWarning",
    "ResolutionWarning",
    "SolverWarning",
    "beam_spectrum_message",
    "check_beam_spectrum",
    "check_continuation_flux",
    "check_footprint",
    "check_material",
    "check_resolution",
    "check_surface_plasmons",
    "emit",
    "footprint_leaks",
    "footprint_message",
    "resolution_messages",
]

OUTSIDE_FRACTION = 1e-3  # incident power falling outside the patch above which we warn
SPECTRUM_CUT = 1e-2  # share of the exact beam's Gaussian spectrum beyond the light cone above which we warn
EXTERIOR_CELLS_PER_WAVELENGTH = 6.0  # d ≤ λ₁/6
INTERIOR_KD = 4.0  # |k₂| d above which the interior field (wavelength, skin depth) is under-resolved
HIGH_CONTRAST = 10.0  # |n₂/n₁| at and above which PMCHWT conditioning degrades
LOW_REFLECTANCE = 1e-4  # normal reflectance below which the discretization error dominates the BRDF
RESIDUAL = 1e-8  # relative residual of the direct solve above which we warn


class BEMWarning(UserWarning):
    """Base class of the 3D BEM warnings."""


class MaterialWarning(BEMWarning):
    """The material is at an extreme (very weak absorber, very high contrast)."""


class ResolutionWarning(BEMWarning):
    """The mesh is too coarse for the exterior or the interior wavelength / skin depth."""


class SolverWarning(BEMWarning):
    """The linear solve did not reach the expected residual."""


def emit(diagnostics: dict | None, category: type[Warning], message: str, stacklevel: int = 3) -> None:
    """warnings.warn the message and append it to ``diagnostics["warnings"]``."""
    if diagnostics is not None:
        diagnostics.setdefault("warnings", []).append(f"{category.__name__}: {message}")
    warnings.warn(message, category, stacklevel=stacklevel)


def _check_power_outside(fraction: float, key: str, message: str, diagnostics=None):
    """Record ``fraction`` (of the incident power) as ``diagnostics[key]``; warn with ``message``
    (a FootprintWarning) when it exceeds OUTSIDE_FRACTION."""
    if diagnostics is not None:
        diagnostics[key] = float(fraction)
    if footprint_leaks(fraction):
        emit(diagnostics, FootprintWarning, message, stacklevel=4)


def footprint_message(outside_fraction: float, theta_i: float, patch_um: float, beam: str) -> str:
    """The FootprintWarning's text for ``outside_fraction`` of the incident power outside the patch."""
    return (f"{outside_fraction:.3g} of the incident power of the {beam} beam at θ_i = "
            f"{np.rad2deg(theta_i):.4g}° falls outside the {patch_um:g} µm patch (limit {OUTSIDE_FRACTION:g}): "
            "the currents are truncated at the patch edge, so edge diffraction and a wrong Φ_i enter "
            "the BRDF; use a larger patch or a smaller waist (grazing incidence spreads the footprint)")


def footprint_leaks(outside_fraction: float) -> bool:
    """Whether a share of the incident power outside the patch (or beyond the continuation) is
    warned of: above OUTSIDE_FRACTION, or not a number."""
    return not np.isfinite(outside_fraction) or outside_fraction > OUTSIDE_FRACTION


def check_footprint(outside_fraction: float, theta_i: float, patch_um: float, beam: str, diagnostics=None):
    """Warn when more than OUTSIDE_FRACTION of the incident power crosses z = 0 outside the patch."""
    _check_power_outside(outside_fraction, "incident_outside_fraction",
                         footprint_message(outside_fraction, theta_i, patch_um, beam), diagnostics)


def check_continuation_flux(flux_left: float, theta_i: float, extent_um: float, diagnostics=None):
    """Warn when more than OUTSIDE_FRACTION of the incident power crosses z = 0 beyond the flat
    continuation's extended mesh (side ``extent_um``), where the currents whose field enters the
    patch's right-hand side stop (the far field radiates them on the whole plane)."""
    _check_power_outside(
        flux_left, "continuation_flux_left",
        f"{flux_left:.3g} of the incident power of the exact beam at θ_i = {np.rad2deg(theta_i):.4g}° falls "
        f"beyond the flat continuation ({extent_um:.4g} µm square; limit {OUTSIDE_FRACTION:g}): the light cone "
        "cuts the beam's spectrum and its footprint's tails reach past the continuation, whose currents' "
        "field on the patch stops there; use a larger waist (docs/dataset.md, 'toward grazing')", diagnostics)


def check_beam_spectrum(evanescent_fraction: float, theta_i: float, waist_um: float, wavelength_um: float,
                        diagnostics=None):
    """Warn when the exact beam drops more than SPECTRUM_CUT of its Gaussian spectrum at the light
    cone (``ExactGaussianBeam.evanescent_fraction``)."""
    if diagnostics is not None:
        diagnostics["beam_evanescent_fraction"] = float(evanescent_fraction)
    message = beam_spectrum_message(evanescent_fraction, theta_i, waist_um, wavelength_um)
    if message:
        emit(diagnostics, FootprintWarning, message)


def beam_spectrum_message(evanescent_fraction: float, theta_i: float, waist_um: float,
                          wavelength_um: float) -> str | None:
    """The FootprintWarning's text when the exact beam drops more than SPECTRUM_CUT of its
    Gaussian spectrum at the light cone (None: it does not)."""
    if not evanescent_fraction > SPECTRUM_CUT:
        return None
    return (f"the exact beam at θ_i = {np.rad2deg(theta_i):.4g}° with waist {waist_um:g} µm "
            f"(λ = {wavelength_um:g} µm) drops {evanescent_fraction:.2g} of its Gaussian spectrum beyond the light "
            f"cone (limit {SPECTRUM_CUT:g}): "
            "its footprint is not the Gaussian of that waist but has long tails along the plane of incidence, "
            "which a pinned patch's edge cuts and which move a flat-continued patch's currents with the extent "
            "of the continuation (at 80°, waist 2.4 µm at λ 0.4 µm: M00 at the mirror by 3-4 %; docs/dataset.md, "
            "'toward grazing'); use a larger waist")


def check_material(media: Media, patch_um: float, diagnostics=None):
    """Warn for weak absorbers (absorption length > patch), near index matching (R < LOW_REFLECTANCE)
    and high-contrast materials."""
    n2 = media.index
    kappa = media.kappa
    if kappa > 0:
        absorption_length = media.wavelength_um / (4 * np.pi * kappa)
        if absorption_length > patch_um:
            emit(
                diagnostics,
                MaterialWarning,
                f"weakly absorbing material n₂ = {n2:.6g}: the absorption length λ/(4πκ) = "
                f"{absorption_length:.3g} µm exceeds the patch ({patch_um:g} µm), so the material acts as "
                "transparent here; the interior is an unbounded half-space (full interior operator, no "
                "truncation) and light transmitted into it is not returned",
            )
    reflectance = abs((n2 - media.exterior_index) / (n2 + media.exterior_index)) ** 2
    if reflectance < LOW_REFLECTANCE:
        emit(
            diagnostics,
            MaterialWarning,
            f"near index matching n₂ = {n2:.6g} (n₁ = {media.exterior_index:g}): the normal reflectance "
            f"{reflectance:.3g} is below the discretization floor of the PMCHWT currents (~1e-6 of Φ_i; "
            "n = 1.0001 gave 7.6e-7 instead of 2.5e-9), so the BRDF is dominated by that error",
        )
    contrast = abs(n2) / media.exterior_index
    if contrast >= HIGH_CONTRAST:
        emit(
            diagnostics,
            MaterialWarning,
            f"high-contrast material |n₂/n₁| = {contrast:.3g} (n₂ = {n2:.6g}): PMCHWT conditioning degrades "
            "and the skin depth λ/(2πκ) = "
            f"{media.wavelength_um / (2 * np.pi * max(kappa, 1e-300)):.3g} µm is tiny; check the residual and "
            "the convergence in the mesh size",
        )


def check_surface_plasmons(media: Media, patch_um: float, diagnostics=None):
    """Warn when the interface carries surface plasmons (Re ε₂/ε₁ < −1) that outlive the patch:
    relief launches them, and a patch edge, pinned or continued as a plane, sends them back."""
    eps = complex(media.index) ** 2 / media.exterior_index**2
    if eps.real >= -1:
        return
    k_spp = media.k0 * media.exterior_index * np.sqrt(eps / (eps + 1))
    length = 1.0 / (2.0 * abs(k_spp.imag)) if k_spp.imag != 0 else np.inf
    if length > patch_um:
        emit(
            diagnostics,
            MaterialWarning,
            f"n₂ = {media.index:.6g} carries surface plasmons with an intensity decay length of {length:.3g} µm, "
            f"longer than the patch ({patch_um:g} µm): relief launches them and the patch edge returns them "
            "(pinned or continued alike), which moved the BRDF of a bump on aluminium by ~2% between patch "
            "sizes (docs/aim.md, flat continuation)",
        )


def resolution_messages(media: Media, surface) -> list[str]:
    """What :func:`check_resolution` says of ``surface``'s mesh size d (µm), each with its fix:
    d above λ₁/EXTERIOR_CELLS_PER_WAVELENGTH, |k₂| d above INTERIOR_KD. ``wavebrdf plan`` shows
    them (BEMModel.validity) before the solve raises them."""
    d = surface.spacing_um
    messages = []
    lam1 = media.wavelength_um / media.exterior_index
    exterior = lam1 / EXTERIOR_CELLS_PER_WAVELENGTH
    if d > exterior * (1 + 1e-9):
        messages.append(f"mesh size d = {d:g} µm exceeds λ₁/{EXTERIOR_CELLS_PER_WAVELENGTH:g} = {exterior:.4g} µm: "
                        f"the currents are under-resolved; use {cells_fix(surface, exterior)}")
    k2 = abs(media.wavenumbers[1])
    if k2 * d > INTERIOR_KD:
        messages.append(f"d is too coarse for the interior field: |k₂| d = {k2 * d:.3g} > {INTERIOR_KD:g} "
                        f"(interior wavelength λ/|n₂| = {media.wavelength_um / abs(media.index):.3g} µm, d = {d:g} µm); "
                        f"use {cells_fix(surface, INTERIOR_KD / k2)}")
    return messages


def check_resolution(media: Media, surface, diagnostics=None):
    """Warn (ResolutionWarning) when d exceeds λ₁/6 or |k₂| d exceeds INTERIOR_KD."""
    for message in resolution_messages(media, surface):
        emit(diagnostics, ResolutionWarning, message)
