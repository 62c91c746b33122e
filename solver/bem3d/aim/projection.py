"""Projection Λ of every rooftop onto its AIM stencil (bem3d.md §6.2).

Each basis f_g is replaced, for the far interactions, by point sources on its S stencil points.
Three scalar components are projected separately (mesh.py for the notation, f dA = c t du dv):

* ψ^t, the in-plane tangential component: f_x for horizontal, f_y for vertical rooftops
  (weight c·h at a quadrature point),
* ψ^z, the vertical component (weight c·t_z),
* ψ^d, the surface divergence (weight ±1, the slot sign; ∇·f dA = ± du dv).

Every projection is a weighted sum over quadrature points q of the basis (two halves, tensor
Gauss of ``order`` per element): Λ^c_{g,p} = Σ_q ψ^c_q W_p(r_q), with a per-stencil-point weight
function W_p of the point's position relative to the stencil. Two choices of W:

``"moments"`` (moment matching)
    W_p = tensor-product Lagrange polynomial of the stencil node p, so that
    Σ_p Λ_p (p − o)^α = ∫ ψ (r − o)^α dA for all multi-indices α < (s_x, s_y, s_z): the
    basis' moments are matched exactly. Λ is real and independent of the wavenumber, so one Λ
    serves both media.
``"farfield"`` (far-field or plane-wave matching, Yang & Yilmaz 2011)
    Λ minimises Σ_ℓ |Σ_p Λ_p e^{jk d̂_ℓ·p} − ∫ψ e^{jk d̂_ℓ·r} dA|² + τ²‖Λ‖² over a set of
    directions d̂_ℓ (Fibonacci points on the sphere or the upper hemisphere), τ relative to the
    largest singular value. Because the stencil geometry is the same for every basis, the
    pseudo-inverse P is computed once: W_p(r) = Σ_ℓ P_pℓ e^{jk d̂_ℓ·(r − o)}. Λ is complex and
    depends on k (one projection per medium).

The far field (aim/farfield.py) uses far-field matching on the upper hemisphere, which is
exactly the property it needs.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from wavebrdf.solver.bem3d.aim.grid import AIMGrid
from wavebrdf.solver.bem3d.mesh import SLOT_SIGN, SLOT_TANGENT, BEMMesh, slot_weight
from wavebrdf.solver.bem3d.quadrature import tensor_rule
from wavebrdf.solver.precision import Precision

logger = logging.getLogger(__name__)

__all__ = [
    "COMPONENTS",
    "PROJECTIONS",
    "Projection",
    "basis_quadrature",
    "fibonacci_directions",
    "lagrange_weights",
    "matching_operator",
    "plane_wave_moments_opencl",
    "plane_wave_phases",
    "project",
]

PROJECTIONS = ("moments", "farfield")
COMPONENTS = ("t", "z", "d")  # tangential in-plane, vertical, divergence
CHUNK = 4096  # bases per vectorized block


@dataclass(frozen=True)
class Projection:
    """Λ of all bases: ``weights`` (3, N_b, S) for components (t, z, d); real or complex.

    ``method`` "moments" | "farfield"; ``wavenumber`` the k(s) of far-field matching (None for
    moments); ``grid`` the AIM grid whose stencils the weights refer to.
    """

    grid: AIMGrid
    weights: np.ndarray
    method: str
    wavenumber: tuple[float, ...] | None = None

    @property
    def is_real(self) -> bool:
        return not np.iscomplexobj(self.weights)


def fibonacci_directions(count: int, hemisphere: bool = False) -> np.ndarray:
    """Quasi-uniform unit vectors (count, 3) on the sphere (or the upper hemisphere z > 0)."""
    if count < 1:
        raise ValueError(f"direction count must be >= 1, got {count!r}")
    i = np.arange(count) + 0.5
    z = 1.0 - i / count if hemisphere else 1.0 - 2.0 * i / count
    rho = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    return np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)


def basis_quadrature(mesh: BEMMesh, order: int = 4, bases=None):
    """Quadrature points of rooftops: positions r (B, 2q, 3) and component weights ψ (3, B, 2q).

    The two halves of each rooftop contribute q = order² tensor Gauss points each.
    """
    bases = np.arange(mesh.n_bases) if bases is None else np.asarray(bases)
    u, v, w = tensor_rule(order)
    elems = mesh.basis_elements[bases]  # (B, 2)
    slots = mesh.basis_slots[bases]
    r, ru, rv = mesh.points(elems[:, :, None], u[None, None, :], v[None, None, :])  # (B, 2, q, 3)
    c = slot_weight(u, v)[slots]  # (B, 2, q)
    tangent_z = np.where(SLOT_TANGENT[slots][:, :, None] == 0, ru[..., 2], rv[..., 2])
    psi = np.empty((3,) + c.shape)
    psi[0] = w * c * mesh.half
    psi[1] = w * c * tangent_z
    psi[2] = w * SLOT_SIGN[slots][:, :, None] * np.ones_like(c)
    n = len(bases)
    return r.reshape(n, -1, 3), psi.reshape(3, n, -1)


def lagrange_weights(xi: np.ndarray, size: int) -> np.ndarray:
    """1-D Lagrange basis of the nodes 0..size−1 at ``xi``: shape xi.shape + (size,)."""
    xi = np.asarray(xi, dtype=float)
    out = np.ones(xi.shape + (size,))
    for a in range(size):
        for b in range(size):
            if a != b:
                out[..., a] *= (xi - b) / (a - b)
    return out


def matching_operator(grid: AIMGrid, wavevectors: np.ndarray, regularization: float) -> np.ndarray:
    """P (S, L) = (AᴴA + τ²I)⁻¹Aᴴ with A_ℓp = e^{j k_ℓ·(p − o)}, τ = regularization·σ_max(A)."""
    offsets = grid.stencil_offsets * np.asarray(grid.spacing)  # (S, 3) µm
    A = np.exp(1j * wavevectors @ offsets.T)  # (L, S)
    s_max = np.linalg.norm(A, 2)
    tau = regularization * s_max
    gram = A.conj().T @ A + tau**2 * np.eye(A.shape[1])
    return np.linalg.solve(gram, A.conj().T)


REPEAT_FRACTION = 0.25  # share of distinct positions below which each distinct one is computed once


def plane_wave_phases(r: np.ndarray, wavevectors: np.ndarray) -> np.ndarray:
    """e^{j k_ℓ·r} for positions r (..., 3) µm and wavevectors (L, 3): shape (..., L).

    Positions that repeat exactly (flat or stepped meshes: the quadrature points of one lattice
    relative to their stencils take few distinct values) get their exponentials once."""
    flat = r.reshape(-1, 3)
    key = np.zeros(len(flat), dtype=np.int64)
    span = 1
    for c in range(3):
        values, inverse = np.unique(flat[:, c], return_inverse=True)
        span *= len(values)
        if len(values) > REPEAT_FRACTION * len(flat) or span >= 2**62:
            return np.exp(1j * (r @ wavevectors.T))
        key = key * len(values) + inverse.ravel()
    distinct, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    if len(distinct) > REPEAT_FRACTION * len(flat):
        return np.exp(1j * (r @ wavevectors.T))
    phases = np.exp(1j * (flat[first] @ wavevectors.T))
    return phases[inverse.ravel()].reshape(r.shape[:-1] + (len(wavevectors),))


def _local_coordinates(grid: AIMGrid, r: np.ndarray, bases: np.ndarray) -> np.ndarray:
    """Positions relative to each basis' stencil origin, in units of the spacings."""
    origin = (grid.origins[bases] + np.asarray(grid.lattice_start)) * np.asarray(grid.spacing)
    return (r - origin[:, None, :]) / np.asarray(grid.spacing)


def plane_wave_moments_opencl(ctx, r: np.ndarray, psi: np.ndarray, wavevectors: np.ndarray) -> np.ndarray:
    """Σ_q ψ^c_q e^{j k_ℓ·r_q} per basis on the device (kernels/aim_projection.cl), double
    precision: r (B, Q, 3) µm, ψ (3, B, Q), wavevectors (L, 3) µm⁻¹ → complex (3, B, L)."""
    r, psi, wavevectors = (np.asarray(a, dtype=np.float64) for a in (r, psi, wavevectors))
    if r.ndim != 3 or r.shape[2] != 3 or psi.shape != (3,) + r.shape[:2] or wavevectors.ndim != 2 \
            or wavevectors.shape[1] != 3 or min(r.shape[0], r.shape[1], len(wavevectors)) == 0:
        raise ValueError(f"plane-wave moments need r (B, Q, 3), psi (3, B, Q) and wavevectors (L, 3), all "
                         f"non-empty; got {r.shape}, {psi.shape}, {wavevectors.shape}")
    n_b, n_q, _ = r.shape
    out = np.empty((3, n_b, len(wavevectors)), dtype=np.complex128)
    buffer = ctx.host_buffer(out, "write")
    kernel = ctx.kernel("aim_projection.cl", "aim_plane_wave_moments", ctx.defines(Precision.DOUBLE))
    kernel(ctx.queue, (n_b * len(wavevectors),), None, ctx.to_device(r, np.float64), ctx.to_device(psi, np.float64),
           np.int32(n_b), np.int32(n_q), ctx.to_device(wavevectors, np.float64), np.int32(len(wavevectors)), buffer)
    ctx.read_into(out, buffer)
    return out


def project(mesh: BEMMesh, grid: AIMGrid, method: str = "moments", *, k=None,
            directions: int | np.ndarray | None = None, hemisphere: bool = False,
            regularization: float = 1e-3, order: int = 4, dtype=np.float64, ctx=None) -> Projection:
    """Λ of every basis of ``mesh`` on ``grid`` (see the module docstring).

    ``k`` (µm⁻¹, real, or a sequence of them: the plane waves of every k are matched at once)
    and ``directions`` (a count per k or an (L, 3) array; default 3S) are used by far-field
    matching only. ``dtype`` float32/float64 sets the storage precision (complex for far-field
    matching). ``ctx``: far-field matching sums its plane waves on that device (NumPy without).
    """
    if method not in PROJECTIONS:
        raise ValueError(f"aim projection must be one of {PROJECTIONS}, got {method!r}")
    n_b, S = mesh.n_bases, grid.stencil_size
    if method == "farfield":
        ks = np.atleast_1d(np.asarray(k if k is not None else np.nan))
        if np.iscomplexobj(ks) or not np.all(np.isfinite(ks)) or np.any(ks <= 0):
            raise ValueError(f"far-field matching needs real wavenumbers k > 0, got {k!r}")
        if directions is None or np.isscalar(directions):
            directions = fibonacci_directions(int(directions or 3 * S), hemisphere)
        directions = np.asarray(directions, dtype=float)
        wavevectors = np.concatenate([kk * directions for kk in ks])
        P = matching_operator(grid, wavevectors, regularization)
        out = np.empty((3, n_b, S), dtype=np.result_type(dtype, np.complex64))
    else:
        out = np.empty((3, n_b, S), dtype=dtype)
    sx, sy, sz = grid.stencil
    for start in range(0, n_b, CHUNK):
        bases = np.arange(start, min(n_b, start + CHUNK))
        r, psi = basis_quadrature(mesh, order, bases)
        xi = _local_coordinates(grid, r, bases)  # (B, Q, 3)
        if method == "moments":
            W = np.einsum(
                "bqa,bqc,bqe->bqace",
                lagrange_weights(xi[..., 0], sx), lagrange_weights(xi[..., 1], sy), lagrange_weights(xi[..., 2], sz),
            ).reshape(len(bases), -1, S)
            out[:, bases] = np.einsum("cbq,bqs->cbs", psi, W)
        else:
            positions = xi * np.asarray(grid.spacing)  # µm from the stencil origin
            if ctx is not None:
                moments = plane_wave_moments_opencl(ctx, positions, psi, wavevectors)
            else:
                moments = np.einsum("cbq,bql->cbl", psi, plane_wave_phases(positions, wavevectors))
            out[:, bases] = moments @ P.T
    logger.debug("projection %s: %d bases x %d stencil points", method, n_b, S)
    wavenumber = None if method == "moments" else tuple(float(kk) for kk in ks)
    return Projection(grid=grid, weights=out, method=method, wavenumber=wavenumber)
