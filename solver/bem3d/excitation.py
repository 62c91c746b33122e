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

from wavebrdf.solver.bem3d.mesh import SLOT_TANGENT, BEMMesh, slot_weight
from wavebrdf.solver.bem3d.quadrature import tensor_rule
from wavebrdf.solver.farfield import ETA0

__all__ = ["SurfaceRule", "power_into_material", "right_hand_side", "surface_currents"]


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
