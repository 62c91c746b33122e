"""Right-hand sides and surface quantities on the true bilinear surface.

Scaled PMCHWT right-hand side (bem3d.md §4.1), per polarization::

    b_E(g) = ∫ f_g · E_inc dA,      b_H(g) = −η₀ ∫ f_g · H_inc dA

by tensor Gauss quadrature on each element of the basis' support (f dA = c t du dv).

Surface currents from a solution x = [J | M̃] (mesh.py ordering) are evaluated at the same kind
of quadrature points as ``j = J·𝒥`` and ``m = M̃·𝒥`` (𝒥 = |r_u × r_v|, i.e. current times area
element per du dv), which is what the far-field sum and the surface power need.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wavebrdf.solver.beams import BEAMS, make_beam
from wavebrdf.solver.bem3d.checks import check_footprint
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import SLOT_TANGENT, BEMMesh, slot_weight
from wavebrdf.solver.bem3d.quadrature import tensor_rule
from wavebrdf.solver.farfield import ETA0

__all__ = ["BeamExcitation", "SurfaceRule", "beam_excitation", "power_into_material", "right_hand_side",
           "surface_currents"]


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
    def build(cls, mesh: BEMMesh, order: int) -> "SurfaceRule":
        u, v, w = tensor_rule(order)
        elems = np.arange(mesh.n_elements)[:, None]
        r, ru, rv = mesh.points(elems, u[None, :], v[None, :])
        return cls(u=u, v=v, weights=w, r=r, ru=ru, rv=rv)

    def slot_vectors(self) -> np.ndarray:
        """c_a t_a at every point: shape (N², q, 4, 3)."""
        c = slot_weight(self.u, self.v)  # (4, q)
        t = np.stack([self.ru, self.rv], axis=2)[:, :, SLOT_TANGENT, :]  # (N², q, 4, 3)
        return c.T[None, :, :, None] * t


def right_hand_side(mesh: BEMMesh, fields: tuple[np.ndarray, np.ndarray], rule: SurfaceRule) -> np.ndarray:
    """b = [b_E | b_H] per polarization, shape (2, 2N_b), from E, H (2, N², q, 3) at ``rule``."""
    E, H = fields
    ct = rule.slot_vectors()  # (N², q, 4, 3)
    w = rule.weights
    proj_E = np.einsum("eqac,peqc,q->pea", ct, E, w)  # (2, N², 4)
    proj_H = np.einsum("eqac,peqc,q->pea", ct, H, w)
    be, bs = mesh.basis_elements, mesh.basis_slots
    b_E = proj_E[:, be[:, 0], bs[:, 0]] + proj_E[:, be[:, 1], bs[:, 1]]
    b_H = proj_H[:, be[:, 0], bs[:, 0]] + proj_H[:, be[:, 1], bs[:, 1]]
    return np.concatenate([b_E, -ETA0 * b_H], axis=1)


def surface_currents(mesh: BEMMesh, x: np.ndarray, rule: SurfaceRule) -> tuple[np.ndarray, np.ndarray]:
    """(j, m) = (J, M̃)·𝒥 at the rule's points for solutions ``x`` (..., 2N_b); shape (..., N², q, 3)."""
    x = np.asarray(x)
    nb = mesh.n_bases
    slots = mesh.element_bases  # (N², 4), −1 on the boundary
    present = slots >= 0
    ct = rule.slot_vectors()
    out = []
    for block in (x[..., :nb], x[..., nb:]):
        coeff = np.where(present, block[..., np.maximum(slots, 0)], 0.0)  # (..., N², 4)
        out.append(np.einsum("...ea,eqac->...eqc", coeff, ct))
    return out[0], out[1]


def power_into_material(mesh: BEMMesh, x: np.ndarray, rule: SurfaceRule) -> np.ndarray:
    """Power crossing the surface into the material, ½ Re ∫ n̂·(M × J*) dA (W), shape x.shape[:-1].

    Positive for a passive material: absorbed (metal) or transmitted (dielectric) power.
    """
    j, m = surface_currents(mesh, x, rule)
    normal = np.cross(rule.ru, rule.rv)
    jac = np.linalg.norm(normal, axis=-1)
    integrand = np.einsum("eqc,...eqc->...eq", normal, np.cross(m, np.conj(j))) / jac**2
    return 0.5 * ETA0 * np.real(np.einsum("...eq,q->...", integrand, rule.weights))


@dataclass(frozen=True)
class BeamExcitation:
    """An incident beam on a patch: the beam object, right-hand sides b (2, n) and its power (2,) (W)."""

    beam: object
    rhs: np.ndarray
    incident_power: np.ndarray


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
    if beam != "plane" and diagnostics is not None and extent_um is None:
        check_footprint(inc.outside_fraction(L), theta_i, L, beam, diagnostics)
    power = inc.incident_power(L)
    if not np.all(np.isfinite(power) & (power > 0)):
        raise FloatingPointError(
            f"the {beam} beam's incident power through the patch is {power} (not positive): at "
            f"θ_i = {np.rad2deg(theta_i):.4g}° with waist {waist_um} µm on a {L:g} µm patch the beam is not "
            "a beam there (paraxial breakdown or footprint far beyond the patch); use beam = 'exact', a "
            "larger waist or a larger patch"
        )
    rule = SurfaceRule.build(mesh, rhs_order)
    return BeamExcitation(inc, right_hand_side(mesh, inc.fields(rule.r), rule), power)
