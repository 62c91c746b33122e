"""Right-hand sides and surface quantities on the true bilinear surface.

Scaled PMCHWT right-hand side (bem3d.md §4.1), per polarization::

    b_E(g) = ∫ f_g · E_inc dA,      b_H(g) = −η₀ ∫ f_g · H_inc dA

by tensor Gauss quadrature on each element of the basis' support (f dA = c t du dv).

Surface currents from a solution x = [J | M̃] (mesh.py ordering) are evaluated at the same kind
of quadrature points as ``j = J·𝒥`` and ``m = M̃·𝒥`` (𝒥 = |r_u × r_v|, i.e. current times area
element per du dv), which is what the far-field sum and the surface power need.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from wavebrdf.solver.beams import BEAMS, make_beam
from wavebrdf.solver.bem3d.checks import (beam_spectrum_message, check_beam_spectrum, check_footprint, footprint_leaks,
                                          footprint_message)
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import SLOT_TANGENT, BEMMesh, slot_weight
from wavebrdf.solver.bem3d.quadrature import tensor_rule
from wavebrdf.solver.farfield import ETA0

__all__ = ["ELEMENT_BLOCK", "BeamExcitation", "SurfaceRule", "beam_excitation", "beam_right_hand_side",
           "element_blocks", "foreseen_beam_warnings", "power_into_material", "right_hand_side", "surface_currents"]

ELEMENT_BLOCK = 16384  # elements per block of quadrature-point arrays (excitation, surface power)


@dataclass(frozen=True)
class SurfaceRule:
    """Tensor Gauss points on every element: positions r (N², q, 3), tangents, weights (q,)."""

    u: np.ndarray
    v: np.ndarray
    weights: np.ndarray
    r: np.ndarray
    ru: np.ndarray
    rv: np.ndarray

    @classmethod
    def build(cls, mesh: BEMMesh, order: int, elements: np.ndarray | None = None) -> "SurfaceRule":
        """The rule on every element, or on ``elements`` (indices) only."""
        u, v, w = tensor_rule(order)
        elems = (np.arange(mesh.n_elements) if elements is None else np.asarray(elements))[:, None]
        r, ru, rv = mesh.points(elems, u[None, :], v[None, :])
        return cls(u=u, v=v, weights=w, r=r, ru=ru, rv=rv)

    def slot_vectors(self) -> np.ndarray:
        """c_a t_a at every point: shape (N², q, 4, 3)."""
        c = slot_weight(self.u, self.v)  # (4, q)
        t = np.stack([self.ru, self.rv], axis=2)[:, :, SLOT_TANGENT, :]  # (N², q, 4, 3)
        return c.T[None, :, :, None] * t


def element_blocks(mesh: BEMMesh, size: int = ELEMENT_BLOCK):
    """Element index ranges of at most ``size`` elements, covering the mesh in order."""
    for start in range(0, mesh.n_elements, size):
        yield np.arange(start, min(mesh.n_elements, start + size))


def _slot_projections(fields: tuple[np.ndarray, np.ndarray], rule: SurfaceRule) -> np.ndarray:
    """∫ c_a t_a · (E, H) per element and slot: shape (2 [E, H], 2 polarizations, elements, 4)."""
    ct = rule.slot_vectors() * rule.weights[None, :, None, None]  # (elements, q, 4, 3)
    e, q = ct.shape[:2]
    ct = ct.transpose(0, 2, 1, 3).reshape(e, 4, 3 * q)  # real: the fields' real and imaginary parts apart
    out = []
    for F in fields:
        F = np.asarray(F).reshape(F.shape[0], e, 3 * q)
        out.append(np.einsum("eak,pek->pea", ct, F.real) + 1j * np.einsum("eak,pek->pea", ct, F.imag))
    return np.stack(out)


def _basis_sums(mesh: BEMMesh, projections: np.ndarray) -> np.ndarray:
    """b = [b_E | −η₀ b_H] (2, 2N_b) from the slot projections of every element."""
    be, bs = mesh.basis_elements, mesh.basis_slots
    b = projections[:, :, be[:, 0], bs[:, 0]] + projections[:, :, be[:, 1], bs[:, 1]]
    return np.concatenate([b[0], -ETA0 * b[1]], axis=1)


def right_hand_side(mesh: BEMMesh, fields: tuple[np.ndarray, np.ndarray], rule: SurfaceRule) -> np.ndarray:
    """b = [b_E | b_H] per polarization, shape (2, 2N_b), from E, H (2, N², q, 3) at ``rule``."""
    return _basis_sums(mesh, _slot_projections(fields, rule))


def beam_right_hand_side(mesh: BEMMesh, beam, order: int) -> np.ndarray:
    """:func:`right_hand_side` of ``beam``'s fields (``beam.fields(points)`` → E, H), built over
    blocks of elements: the per-point fields of one block are held at a time, not the patch's."""
    projections = np.zeros((2, 2, mesh.n_elements, 4), dtype=complex)
    for elements in element_blocks(mesh):
        rule = SurfaceRule.build(mesh, order, elements)
        projections[:, :, elements] = _slot_projections(beam.fields(rule.r), rule)
    return _basis_sums(mesh, projections)


def surface_currents(mesh: BEMMesh, x: np.ndarray, rule: SurfaceRule,
                     elements: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(j, m) = (J, M̃)·𝒥 at the rule's points for solutions ``x`` (..., 2N_b); shape (..., N², q, 3)
    (or (..., len(elements), q, 3) for a rule built on ``elements``)."""
    x = np.asarray(x)
    nb = mesh.n_bases
    slots = mesh.element_bases if elements is None else mesh.element_bases[elements]  # (·, 4), −1 on the boundary
    present = slots >= 0
    ct = rule.slot_vectors()
    out = []
    for block in (x[..., :nb], x[..., nb:]):
        coeff = np.where(present, block[..., np.maximum(slots, 0)], 0.0)  # (..., N², 4)
        out.append(np.einsum("...ea,eqac->...eqc", coeff, ct))
    return out[0], out[1]


def power_into_material(mesh: BEMMesh, x: np.ndarray, order: int) -> np.ndarray:
    """Power crossing the surface into the material, ½ Re ∫ n̂·(M × J*) dA (W), shape x.shape[:-1],
    by tensor Gauss of ``order`` per element, over blocks of elements.

    Positive for a passive material: absorbed (metal) or transmitted (dielectric) power.
    """
    total = 0.0
    for elements in element_blocks(mesh):
        rule = SurfaceRule.build(mesh, order, elements)
        j, m = surface_currents(mesh, x, rule, elements)
        normal = np.cross(rule.ru, rule.rv)
        jac = np.linalg.norm(normal, axis=-1)
        integrand = np.einsum("eqc,...eqc->...eq", normal, np.cross(m, np.conj(j))) / jac**2
        total = total + 0.5 * ETA0 * np.real(np.einsum("...eq,q->...", integrand, rule.weights))
    return total


@dataclass(frozen=True)
class BeamExcitation:
    """An incident beam on a patch: the beam object, right-hand sides b (2, n) and its power (2,) (W)."""

    beam: object
    rhs: np.ndarray
    incident_power: np.ndarray


def _checked_fractions(inc, beam: str, patch_um: float, continued: bool) -> tuple[float | None, float | None]:
    """What the beam checks weigh, where they apply: the power outside the patch (not for a plane
    wave, nor with the flat continuation, whose currents carry beyond the patch) and the exact
    beam's spectrum beyond the light cone; None where a check does not apply."""
    outside = inc.outside_fraction(patch_um) if beam != "plane" and not continued else None
    return outside, (inc.evanescent_fraction if beam == "exact" else None)


@functools.lru_cache(maxsize=512)
def foreseen_beam_warnings(beam: str, wavelength_um: float, theta_i: float, phi_i: float, waist_um: float | None,
                           exterior_index: float, focus_um: tuple[float, float], patch_um: float,
                           continued: bool) -> tuple[str, ...]:
    """The FootprintWarnings :func:`beam_excitation` will raise for this beam on a patch of side
    ``patch_um`` (µm; angles in radians), in its words, before anything runs (the same checks,
    :func:`_checked_fractions`). Cached: a study's tasks share few beams, and the outside fraction
    is a numerical integral (≈ 0.5 s)."""
    if beam == "plane":
        return ()
    inc = make_beam(beam, wavelength_um, theta_i, phi_i, waist_um, exterior_index=exterior_index,
                    focus_um=(focus_um[0], focus_um[1], 0.0), patch_size_um=patch_um)
    outside, evanescent = _checked_fractions(inc, beam, patch_um, continued)
    found = []
    if outside is not None and footprint_leaks(outside):
        found.append(footprint_message(outside, theta_i, patch_um, beam))
    if evanescent is not None:
        message = beam_spectrum_message(evanescent, theta_i, waist_um, wavelength_um)
        found += [message] if message else []
    return tuple(found)


def beam_excitation(mesh: BEMMesh, media: Media, theta_i: float, phi_i: float, *, waist_um: float | None,
                    beam: str, focus_um, rhs_order: int, diagnostics: dict | None = None,
                    extent_um: float | None = None) -> BeamExcitation:
    """Build the named beam toward (θ_i, φ_i) (radians) focused at ``focus_um`` (x, y in µm) and its
    right-hand sides; warn (into ``diagnostics``) about a footprint leaking off the patch and
    refuse a beam whose incident power through the patch is not positive.

    ``extent_um``: side of the square on which the beam is needed (an exact beam's periodic copies
    stay negligible there); default the patch. A larger extent (the flat continuation's) also
    drops the footprint warning: the currents there are carried beyond the patch."""
    if beam not in BEAMS:
        raise ValueError(f"illumination.beam must be one of {BEAMS}, got {beam!r}")
    L = mesh.surface.size_um
    inc = make_beam(beam, media.wavelength_um, theta_i, phi_i, waist_um, exterior_index=media.exterior_index,
                    focus_um=(focus_um[0], focus_um[1], 0.0), patch_size_um=extent_um or L)
    if diagnostics is not None:
        outside, evanescent = _checked_fractions(inc, beam, L, continued=extent_um is not None)
        if outside is not None:
            check_footprint(outside, theta_i, L, beam, diagnostics)
        if evanescent is not None:
            check_beam_spectrum(evanescent, theta_i, waist_um, media.wavelength_um, diagnostics)
    power = inc.incident_power(L)
    if not np.all(np.isfinite(power) & (power > 0)):
        raise FloatingPointError(
            f"the {beam} beam's incident power through the patch is {power} (not positive): at "
            f"θ_i = {np.rad2deg(theta_i):.4g}° with waist {waist_um} µm on a {L:g} µm patch the beam is not "
            "a beam there (paraxial breakdown or footprint far beyond the patch); use beam = 'exact', a "
            "larger waist or a larger patch"
        )
    return BeamExcitation(inc, beam_right_hand_side(mesh, inc, rhs_order), power)
