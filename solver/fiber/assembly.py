"""The 4N×4N PMCHWT matrix of a fiber cross section (fiber.md §3–4): OpenCL and NumPy twins.

Two steps, each an OpenCL kernel in ``kernels/fiber_bem.cl`` with a NumPy reference of the same
name plus ``_reference``:

``fiber_pair_moments``
    for every element pair (a, b) and both media p (0 = outside, 1 = fiber), the hat-weighted
    integrals I^{αβ} = ∬ Λ_α Λ_β G_p and Kz^{αβ} = ∬ Λ_α Λ_β h_p ẑ·(R̂ × t̂_b), arrays of shape
    (2, N, N, 4) with the last index 2α + β. Far pairs use Q_far×Q_far Gauss–Legendre; near
    pairs (self, adjacent, and any pair whose centres are closer than ``near_factor`` times the
    longer element) subtract -ln R/(2π) and -1/(2πR) and integrate them in closed form.
``fiber_assemble``
    the matrix from the moments: rows test [E_t, E_z, η₀H_t, η₀H_z] with the hats, columns are
    the coefficients of [η₀J_t, η₀J_z, M_t, M_z] (the scaling of fiber.md §2, entries O(1)).

The reference evaluates the Hankel functions with scipy (AMOS), so a kernel-vs-reference test
checks the device Hankel code, the quadrature and the assembly together.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from wavebrdf.solver.fiber.hankel import EULER_GAMMA, hankel2_01_scipy
from wavebrdf.solver.fiber.incidence import FiberMedia, gauss_legendre_unit
from wavebrdf.solver.fiber.shapes import CrossSection
from wavebrdf.solver.precision import Precision

logger = logging.getLogger(__name__)

__all__ = [
    "BEMQuadrature",
    "FiberAssembler",
    "fiber_assemble_reference",
    "fiber_pair_moments_reference",
    "medium_coefficients",
]

KERNEL_FILE = "fiber_bem.cl"


@dataclass(frozen=True)
class BEMQuadrature:
    """Quadrature orders of the fiber BEM (defaults validated against Mie, see tests/fiber)."""

    far_points: int = 3  # Gauss–Legendre points per element for well-separated pairs
    near_points: int = 8  # ... for near pairs (with singularity subtraction)
    near_factor: float = 2.5  # near: centre distance < near_factor · max(Δ_a, Δ_b)
    rhs_points: int = 6  # incident-field test integrals
    farfield_points: int = 6  # radiation integrals

    def __post_init__(self):
        for name in ("far_points", "near_points", "rhs_points", "farfield_points"):
            v = getattr(self, name)
            if isinstance(v, bool) or int(v) != v or not 1 <= v <= 32:
                raise ValueError(f"quadrature {name} must be an integer in 1..32, got {v!r}")
        if not (np.isfinite(self.near_factor) and self.near_factor >= 1.0):
            raise ValueError(f"quadrature near_factor must be >= 1, got {self.near_factor!r}")


def medium_coefficients(media: FiberMedia) -> np.ndarray:
    """Per-medium constants of the assembly, shape (2, 4): 1/k², k_ρ²/k², μ_r, ε_r."""
    k2 = media.k * media.k
    return np.stack([1.0 / k2, media.krho**2 / k2, media.mu_r, media.eps_r], axis=1)


# ------------------------------------------------------------------------------------------
# NumPy reference
# ------------------------------------------------------------------------------------------


def _near_pairs(shape: CrossSection, near_factor: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unordered pairs a <= b and their near flags."""
    n = shape.segments
    a, b = np.triu_indices(n)
    centres = shape.nodes + 0.5 * shape.edges
    dist = np.hypot(*(centres[a] - centres[b]).T)
    near = dist < near_factor * np.maximum(shape.lengths[a], shape.lengths[b])
    return a, b, near


def _cross_z(v, t):
    return v[..., 0] * t[..., 1] - v[..., 1] * t[..., 0]


def log_moments_reference(x: np.ndarray, p: np.ndarray, t: np.ndarray, length: np.ndarray) -> np.ndarray:
    """∫ Λ_β ln R ds' over the element (p, t, length) for points x; shape (..., 2) (start, end hat)."""
    rel = x - p
    u0 = np.sum(rel * t, axis=-1)
    h = np.abs(_cross_z(rel, t))
    ue, us = length - u0, -u0
    re2, rs2 = ue * ue + h * h, us * us + h * h
    with np.errstate(divide="ignore", invalid="ignore"):
        lre = np.where(re2 > 0, 0.5 * np.log(re2), 0.0)
        lrs = np.where(rs2 > 0, 0.5 * np.log(rs2), 0.0)
        i0 = ue * lre - us * lrs - (ue - us) + np.where(h > 0, h * np.arctan2(h * (ue - us), h * h + ue * us), 0.0)
    i1 = 0.5 * (re2 * lre - rs2 * lrs) - 0.25 * (ue * ue - us * us) + u0 * i0
    return np.stack([i0 - i1 / length, i1 / length], axis=-1)


def static_moments_reference(x: np.ndarray, p: np.ndarray, t: np.ndarray, length: np.ndarray) -> np.ndarray:
    """∫ Λ_β d/R² ds' with d = ẑ·((x - p) × t), shape (..., 2)."""
    rel = x - p
    u0 = np.sum(rel * t, axis=-1)
    d = _cross_z(rel, t)
    ue, us = length - u0, -u0
    j0 = np.arctan2(d * (ue - us), d * d + ue * us)
    with np.errstate(divide="ignore", invalid="ignore"):
        j1 = np.where(d != 0, 0.5 * d * np.log((ue * ue + d * d) / (us * us + d * d)), 0.0) + u0 * j0
    return np.stack([j0 - j1 / length, j1 / length], axis=-1)


def _green_and_gradient(k: complex, dist: np.ndarray):
    h0, h1 = hankel2_01_scipy(k * dist)
    return -0.25j * h0, 0.25j * k * h1


def _pair_points(shape, a, b, s):
    pa = shape.nodes[a][:, None, :] + s[None, :, None] * shape.edges[a][:, None, :]  # (P, Q, 2)
    pb = shape.nodes[b][:, None, :] + s[None, :, None] * shape.edges[b][:, None, :]
    return pa, pb


def fiber_pair_moments_reference(shape: CrossSection, media: FiberMedia,
                                 quadrature: BEMQuadrature = BEMQuadrature()):
    """NumPy twin of the kernel ``fiber_pair_moments``: (mom_i, mom_k), each (2, N, N, 4) complex."""
    n = shape.segments
    mom_i = np.zeros((2, n, n, 4), dtype=complex)
    mom_k = np.zeros((2, n, n, 4), dtype=complex)
    a_all, b_all, near_all = _near_pairs(shape, quadrature.near_factor)
    t = shape.tangents
    for near in (False, True):
        sel = near_all == near
        a, b = a_all[sel], b_all[sel]
        if a.size == 0:
            continue
        s, w = gauss_legendre_unit(quadrature.near_points if near else quadrature.far_points)
        pa, pb = _pair_points(shape, a, b, s)
        rvec = pa[:, :, None, :] - pb[:, None, :, :]  # (P, Qa, Qb, 2)
        dist = np.hypot(rvec[..., 0], rvec[..., 1])
        hats = np.stack([1.0 - s, s])  # (2, Q)
        wgt = (w[:, None] * w[None, :])[None] * (shape.lengths[a] * shape.lengths[b])[:, None, None]
        self_pair = a == b
        with np.errstate(divide="ignore", invalid="ignore"):
            cb = np.where(dist > 0, _cross_z(rvec, t[b][:, None, None, :]) / dist, 0.0)
            ca = np.where(dist > 0, -_cross_z(rvec, t[a][:, None, None, :]) / dist, 0.0)
        cb[self_pair] = 0.0
        ca[self_pair] = 0.0
        ii = np.zeros((2, a.size, 2, 2), dtype=complex)
        kab = np.zeros_like(ii)
        kba = np.zeros_like(ii)  # indexed [p, pair, β, α]
        if near:
            # closed-form singular parts, outer Gauss points on a (log, static for Kz(a,b)) and b
            ilog = np.einsum("q,aq,pqb->pab", w, hats, log_moments_reference(
                pa, shape.nodes[b][:, None], t[b][:, None], shape.lengths[b][:, None])) * shape.lengths[a][:, None, None]
            sab = np.einsum("q,aq,pqb->pab", w, hats, static_moments_reference(
                pa, shape.nodes[b][:, None], t[b][:, None], shape.lengths[b][:, None])) * shape.lengths[a][:, None, None]
            sba = np.einsum("q,bq,pqa->pba", w, hats, static_moments_reference(
                pb, shape.nodes[a][:, None], t[a][:, None], shape.lengths[a][:, None])) * shape.lengths[b][:, None, None]
            sab[self_pair] = 0.0
            sba[self_pair] = 0.0
            for p in range(2):
                ii[p] = -ilog / (2 * np.pi)
                kab[p] = -sab / (2 * np.pi)
                kba[p] = -sba / (2 * np.pi)
        for p in range(2):
            k = media.krho[p]
            safe = np.where(dist > 0, dist, 1.0)
            g, h = _green_and_gradient(k, safe)
            if near:
                limit = 0.25 / 1j - (np.log(k / 2) + EULER_GAMMA) / (2 * np.pi)
                g = np.where(dist > 0, g + np.log(safe) / (2 * np.pi), limit)
                h = np.where(dist > 0, h + 1.0 / (2 * np.pi * safe), 0.0)
            ii[p] += np.einsum("pij,ai,bj->pab", wgt * g, hats, hats)
            kab[p] += np.einsum("pij,ai,bj->pab", wgt * h * cb, hats, hats)
            kba[p] += np.einsum("pij,ai,bj->pba", wgt * h * ca, hats, hats)
        for p in range(2):
            mom_i[p, a, b] = ii[p].reshape(-1, 4)
            mom_i[p, b, a] = ii[p].transpose(0, 2, 1).reshape(-1, 4)
            mom_k[p, a, b] = kab[p].reshape(-1, 4)
            off = ~self_pair
            mom_k[p, b[off], a[off]] = kba[p][off].reshape(-1, 4)
    return mom_i, mom_k


def fiber_assemble_reference(shape: CrossSection, mom_i: np.ndarray, mom_k: np.ndarray,
                             media: FiberMedia) -> np.ndarray:
    """NumPy twin of the kernel ``fiber_assemble``: the 4N×4N matrix (complex128)."""
    n = shape.segments
    coef = medium_coefficients(media)
    idx = np.arange(n)
    t, length = shape.tangents, shape.lengths
    acc = {key: np.zeros((n, n), dtype=complex) for key in
           ("ltt_e", "ltz_e", "lzt_e", "lzz_e", "ltt_h", "ltz_h", "lzt_h", "lzz_h", "ktt", "ktz", "kzt")}
    for al in (0, 1):
        a = ((idx - al) % n)[:, None]
        sa = -1.0 if al == 0 else 1.0
        for be in (0, 1):
            b = ((idx - be) % n)[None, :]
            sb = -1.0 if be == 0 else 1.0
            tt = np.sum(t[a] * t[b], axis=-1)
            tzt = -_cross_z(t[a], t[b])
            for p in range(2):
                mom = mom_i[p][a, b]  # (n, n, 4)
                iab = mom[..., 2 * al + be]
                irow = mom[..., 2 * al] + mom[..., 2 * al + 1]
                icol = mom[..., be] + mom[..., 2 + be]
                itot = mom.sum(axis=-1)
                inv_k2, kr2_k2, mu, eps = coef[p]
                ltt = tt * iab - inv_k2 * itot * sa * sb / (length[a] * length[b])
                ltz = 1j * media.kz * inv_k2 * icol * (-sa / length[a])
                lzt = 1j * media.kz * inv_k2 * irow * (sb / length[b])
                lzz = kr2_k2 * iab
                for name, val in (("ltt", ltt), ("ltz", ltz), ("lzt", lzt), ("lzz", lzz)):
                    acc[name + "_e"] += mu * val
                    acc[name + "_h"] += eps * val
                acc["ktt"] += 1j * media.kz * tzt * iab
                acc["ktz"] += mom_k[p][b, a][..., 2 * be + al]
                acc["kzt"] += mom_k[p][a, b][..., 2 * al + be]
    jk0 = 1j * media.k0
    zero = np.zeros((n, n), dtype=complex)
    return np.block([
        [jk0 * acc["ltt_e"], jk0 * acc["ltz_e"], acc["ktt"], acc["ktz"]],
        [jk0 * acc["lzt_e"], jk0 * acc["lzz_e"], acc["kzt"], zero],
        [-acc["ktt"], -acc["ktz"], jk0 * acc["ltt_h"], jk0 * acc["ltz_h"]],
        [-acc["kzt"], zero, jk0 * acc["lzt_h"], jk0 * acc["lzz_h"]],
    ])


# ------------------------------------------------------------------------------------------
# OpenCL
# ------------------------------------------------------------------------------------------


class FiberAssembler:
    """Assembles the fiber matrix on an OpenCL device for one cross section.

    The node coordinates and quadrature rules are uploaded once; :meth:`matrix` runs the two
    kernels for one (λ, θ_i, index) and returns the matrix on the host (complex128 or
    complex64 for ``precision`` single).
    """

    def __init__(self, ctx, shape: CrossSection, quadrature: BEMQuadrature = BEMQuadrature(),
                 precision: Precision = Precision.DOUBLE):
        import pyopencl as cl

        self.ctx = ctx
        self.shape = shape
        self.quadrature = quadrature
        self.real, self.cplx = precision.real, precision.complex
        self.defines = ctx.defines(precision, Q_FAR=quadrature.far_points, Q_NEAR=quadrature.near_points)
        mf = cl.mem_flags
        n = shape.segments
        upload = ctx.to_device

        self._nodes = upload(shape.nodes.astype(self.real))
        self._gl_far = upload(np.stack(gauss_legendre_unit(quadrature.far_points), axis=1).astype(self.real))
        self._gl_near = upload(np.stack(gauss_legendre_unit(quadrature.near_points), axis=1).astype(self.real))
        mom_bytes = 2 * n * n * 4 * self.cplx.itemsize
        self._mom_i = cl.Buffer(ctx.context, mf.READ_WRITE, mom_bytes)
        self._mom_k = cl.Buffer(ctx.context, mf.READ_WRITE, mom_bytes)
        self._zmat = cl.Buffer(ctx.context, mf.WRITE_ONLY, (4 * n) ** 2 * self.cplx.itemsize)

    def _constant(self, values):
        import pyopencl as cl

        return cl.Buffer(self.ctx.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                         hostbuf=np.ascontiguousarray(values, dtype=self.cplx))

    def _run_moments(self, media: FiberMedia) -> None:
        n = self.shape.segments
        knl = self.ctx.kernel(KERNEL_FILE, "fiber_pair_moments", self.defines)
        knl(self.ctx.queue, (n, n), None, self._nodes, self._constant(media.krho), self._gl_far,
            self._gl_near, np.int32(n), self.real.type(self.quadrature.near_factor), self._mom_i,
            self._mom_k)

    def moments(self, media: FiberMedia) -> tuple[np.ndarray, np.ndarray]:
        """Device twin of :func:`fiber_pair_moments_reference`: (mom_i, mom_k), (2, N, N, 4)."""
        import pyopencl as cl

        n = self.shape.segments
        self._run_moments(media)
        mom_i = np.empty((2, n, n, 4), dtype=self.cplx)
        mom_k = np.empty_like(mom_i)
        cl.enqueue_copy(self.ctx.queue, mom_i, self._mom_i)
        cl.enqueue_copy(self.ctx.queue, mom_k, self._mom_k)
        return mom_i, mom_k

    def matrix(self, media: FiberMedia) -> np.ndarray:
        """The 4N×4N system matrix for ``media`` (moments and assembly on the device)."""
        import pyopencl as cl

        n = self.shape.segments
        self._run_moments(media)
        knl = self.ctx.kernel(KERNEL_FILE, "fiber_assemble", self.defines)
        knl(self.ctx.queue, (n, n), None, self._nodes, self._mom_i, self._mom_k,
            self._constant(medium_coefficients(media).ravel()), self.real.type(media.k0),
            self.real.type(media.kz), np.int32(n), self._zmat)
        z = np.empty((4 * n, 4 * n), dtype=self.cplx)
        cl.enqueue_copy(self.ctx.queue, z, self._zmat)
        return z
