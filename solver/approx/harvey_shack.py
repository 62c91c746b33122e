"""Harvey–Shack rungs OHS and GHS (approx.md §3.3, "Unified discrete form") → FarField.

    f(ω_i, ω_o) = K |r(θ_i)|² (μ_o/μ_i) |I(s)|² / (λ₁² Δ² Σ W²),   s = u_i + u_o,
    I(s) = Δ² Σ_ab W_ab exp(+jk[s·x_ab + c_z (z_ab − z_ref)])      (e^{+jωt}, k = 2πn₁/λ),

    OHS (original Harvey–Shack):    c_z = 2,          K = 1
    GHS (generalized Harvey–Shack): c_z = μ_i + μ_o,  K = 1 / Σ_disk (μ_o/μ_i)|I|²/(λ₁²Δ²ΣW²) Δu²

with the footprint W = exp(−|x − c|²/w²) of every rung. Ω = μ_o/μ_i is the obliquity of [Y]
(Yan et al. 2018 waveBrdf.cpp, C1 = cos θ_o/(λ² cos θ_i) for "OHS"/"GHS"); it is not reciprocal.

**Fresnel** sits outside the integral, at the incidence angle θ_i (Harvey–Shack's transfer function
scales the scattered radiance by the surface's specular reflectance R(θ_i); [Y] carries no Fresnel
factor). One transform therefore serves both polarizations: s ↔ φ̂_o·r_s, p ↔ θ̂_o·r_p, as in the
Kirchhoff rung, and the all-incidence trick keeps working (r depends on ω_i only).

**GHS renormalization** (Krywonos et al. 2011, JOSA A 28:1121, as pinned in approx.md): the
unrenormalized GHS scatter function integrates to the specular reflectance over the whole
direction-cosine plane; the part beyond the unit circle is evanescent, so the propagating part is
rescaled by K = total / propagating. Here the total is R(θ_i) by construction, so
K = 1 / (propagating albedo of the Fresnel-free scatter function on the output grid) and the GHS
albedo equals |r_s(θ_i)|², |r_p(θ_i)|² on any surface. Diagnostics report K
("ghs_renormalization"), the unrenormalized propagating albedo, and the evanescent fraction
1 − Σ_disk |I|² Δu² / (λ₁² Δ² Σ W²): the share of the footprint's angular spectrum (Parseval,
exact for OHS's s-independent phase) landing at |u_o| ≥ 1.

**Transforms.**

* per incidence: the Kirchhoff rung's exact Chebyshev/chirp-z transform onto the pixel centres
  (GHS: Kirchhoff's integral itself; OHS: the flat transform of W e^{2jk(z − z_mid)}).
* all incidences (approx.md §3.3 item 3): the phase depends on ω_i only through s (OHS) or through
  s and τ = μ_i + μ_o − 1 (GHS: e^{jk(1+τ)z} = e^{jkz} Σ_n ε_n j^n J_n(kz) T_n(τ)). So one set of
  transforms per (surface, λ, footprint) — one for OHS, n_max + 1 for GHS — on the s grid serves
  every incidence: :class:`SGrid`, kept by the model instance. The s grid is the inverse FFT of the
  deapodized aperture at 2× oversampling, and P(s) at s = u_i + u_o is its Gaussian gridding
  (Greengard & Lee 2004): error ≈ exp(−π·spread/√2) relative to Σ|g| (1.7e-6 for spread = 6);
  tested against the per-incidence chirp-z evaluation. The pixels form a tensor grid in s, so the
  gridding is separable: orders × 2·spread × res × (M + res) multiply-adds per incidence.
  ``transform = "auto"`` (default) uses it while the s grid fits ``max_grid_mb``. Outside the disk
  E = 0.

K < 1 can occur: where Ω = μ_o/μ_i > 1 (grazing incidence) the unrenormalized propagating part
exceeds R(θ_i).

Both paths have OpenCL kernels (kernels/harvey_shack.cl) and NumPy twins (``ctx=None``).

The rungs keep the phase, so they are steerable (the footprint plane wave of
:class:`~wavebrdf.solver.approx.kirchhoff.FootprintModel`); a steered GHS field sums patch fields
each renormalized by its own K.
"""

from __future__ import annotations

import hashlib
import time
import warnings
from collections import OrderedDict
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.fft
import scipy.sparse
import scipy.special

from wavebrdf.solver.approx.kirchhoff import (
    Aperture,
    FootprintModel,
    KirchhoffSetup,
    albedo_excess,
    chebyshev_cost,
    chebyshev_device_bytes,
    chebyshev_order,
    chebyshev_transform,
    chebyshev_transform_numpy,
    check_incidence,
    footprint_power,
    scalar_farfield_numpy,
    transform_orders,
)
from wavebrdf.solver.czt import fast_length
from wavebrdf.solver.farfield import FarField, HemisphereGrid
from wavebrdf.solver.footprint import FootprintWarning, edge_fraction, footprint_edge_warning
from wavebrdf.solver.fresnel import fresnel_rs_rp
from wavebrdf.solver.models import Capabilities, Estimate, SurfaceScene
from wavebrdf.solver.options import option
from wavebrdf.solver.precision import Precision
from wavebrdf.solver.validity import check_evanescent_loss, check_waist

__all__ = [
    "GHSModel",
    "HarveyShackOptions",
    "OHSModel",
    "SGrid",
    "gridding_plan",
    "harvey_shack_farfield",
]

VARIANTS = ("ohs", "ghs")


def _check_variant(variant: str) -> None:
    if variant not in VARIANTS:
        raise ValueError(f"Harvey-Shack variant must be one of {VARIANTS}, got {variant!r}")


def gridding_plan(n_nodes: int, spread: int) -> tuple[int, int, float, np.ndarray]:
    """Gaussian gridding of Σ_a g_a e^{jaσ} (a < n_nodes) at 2× oversampling.

    Returns (c, M, τ, deapodization): node c is the grid's index 0, M the grid size (2π/M per
    step), τ the kernel exp(−σ²/(4τ)) balancing aliasing exp(−τM(M−2B)) against truncation
    exp(−π²spread²/(M²τ)) (B = max |a − c|), and the factors 1/c_a that divide the samples.
    """
    c = n_nodes // 2
    b_max = max(c, n_nodes - 1 - c)
    M = fast_length(2 * (2 * b_max + 1))
    tau = np.pi * spread / (M**1.5 * np.sqrt(M - 2 * b_max))
    b = np.arange(n_nodes) - c
    deapodization = 1.0 / (np.sqrt(tau / np.pi) * np.exp(-b * b * tau))
    return c, M, float(tau), deapodization


def _fresnel_at_incidence(index: complex, exterior_index: float, theta_i: float) -> tuple[complex, complex]:
    r_s, r_p = fresnel_rs_rp(complex(index) / exterior_index, np.cos(theta_i))
    return complex(r_s), complex(r_p)


@dataclass
class SGrid:
    """The all-incidence transform of one (surface, λ, footprint): P_n on the s = u_i + u_o grid.

    Q[n] = inverse FFT (M × M) of the deapodized order-n aperture; P_n(s) = Σ φ(σ − σ_m) Q[n]_m
    with σ = kΔs, φ(σ) = exp(−σ²/(4τ)) separable, 2·spread nodes per axis.
    """

    variant: str
    Q: np.ndarray  # (orders, M, M)
    M: int
    tau: float
    spread: int
    scale: float  # grid steps per unit of s: Δ M / λ₁
    centre: tuple[float, float]  # node of grid index 0 (patch coordinates, µm)
    k: float
    lambda1: float
    exterior_index: float
    dz_ref: float
    weight_sum: float
    precision: Precision
    build_time_s: float = 0.0
    edge_warning: str | None = None  # the footprint's FootprintWarning, raised again by each scene that reuses the grid
    _device: dict = field(default_factory=dict, repr=False)

    @property
    def orders(self) -> int:
        return self.Q.shape[0]

    @property
    def nbytes(self) -> int:
        return int(self.Q.nbytes)

    @staticmethod
    def shape(scene: SurfaceScene, variant: str, spread: int = 6) -> tuple[int, int]:
        """(orders, M) of the s grid that :meth:`build` would make for ``scene``, without building it."""
        _, M, _, _ = gridding_plan(scene.surface.cells + 1, spread)
        k = 2 * np.pi * scene.exterior_index / scene.wavelength_um
        orders = 1 if variant == "ohs" else chebyshev_order(k * 0.5 * np.ptp(scene.surface.z)) + 1
        return orders, M

    @classmethod
    def build(cls, ctx, scene: SurfaceScene, variant: str, spread: int = 6) -> "SGrid":
        """Transform the scene's apertures once (``ctx`` None: NumPy twin, double precision); the
        incidence, index and output grid of ``scene`` do not enter."""
        _check_variant(variant)
        t0 = time.perf_counter()
        precision = scene.precision
        if ctx is None and not precision.fp64:
            raise ValueError(f"the NumPy reference runs in double precision only, got precision = {precision!r}")
        ap = Aperture.from_scene(scene)
        surface = scene.surface
        n_nodes = surface.cells + 1
        c, M, tau, deapod = gridding_plan(n_nodes, spread)
        if variant == "ohs":  # one order: W e^{2jk z'} (z' = z − mid-height)
            z = np.zeros_like(ap.z_mid)
            aperture = ap.window * np.exp(2j * ap.k * ap.z_mid)
            n_max = 0
        else:  # e^{jk(1+τ)z'} = e^{jkz'} Σ_n ε_n j^n J_n(kz') T_n(τ)
            z = ap.z_mid
            aperture = ap.window
            n_max = chebyshev_order(ap.k * np.abs(z).max())
        if ctx is None:
            fields = _tau_fields_numpy(z, aperture, ap.k, n_max, deapod)
        else:
            fields = _tau_fields_opencl(ctx, z, aperture, ap.k, n_max, deapod, precision)
        index = (np.arange(n_nodes) - c) % M
        workers = ctx.fft_workers if ctx is not None else None
        Q = np.empty((n_max + 1, M, M), dtype=precision.complex)
        for n in range(n_max + 1):  # one order at a time: the grid is the memory that stays
            G = np.zeros((M, M), dtype=complex)
            G[index[:, None], index[None, :]] = fields[n]
            Q[n] = scipy.fft.ifft2(G, overwrite_x=True, workers=workers)
        del fields
        return cls(
            variant=variant, Q=Q, M=M, tau=tau, spread=spread, scale=surface.spacing_um * M / ap.lambda1,
            centre=(float(surface.x[c]), float(surface.y[c])), k=ap.k, lambda1=ap.lambda1,
            exterior_index=ap.exterior_index, dz_ref=ap.dz_ref, weight_sum=ap.weight_sum, precision=precision,
            build_time_s=time.perf_counter() - t0,
            edge_warning=footprint_edge_warning(edge_fraction(np.abs(ap.window)), surface.size_um),
        )

    def axis_weights(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, int, int]:
        """Gridding along one axis at the values ``s`` (res,): node indices (res, 2·spread) into
        [0, M), their weights, and the window (c0, ncols) of grid lines they touch (mod M)."""
        t = s * self.scale
        first = np.floor(t).astype(np.int64) - self.spread + 1
        nodes = first[:, None] + np.arange(2 * self.spread)[None]
        d = (t[:, None] - nodes) * (2 * np.pi / self.M)
        weights = np.exp(-d * d / (4.0 * self.tau))
        lo, hi = int(nodes.min()), int(nodes.max())
        c0, ncols = (0, self.M) if hi - lo + 1 >= self.M else (lo % self.M, hi - lo + 1)
        return (nodes % self.M).astype(np.int32), weights, c0, ncols

    def transform(self, ctx, theta_i: float, phi_i: float, grid: HemisphereGrid, precision: Precision):
        """acc = Σ_n T_n(μ_i + μ_o − 1)·Wx Q_n Wyᵀ on the pixels and the per-axis post factors
        e^{jk s_x x_c}, e^{jk s_y y_c}: the input of the pixel assembly (``ctx`` None: NumPy arrays)."""
        u_i = np.sin(theta_i) * np.array([np.cos(phi_i), np.sin(phi_i)])
        mu_i = float(np.cos(theta_i))
        s_x, s_y = u_i[0] + grid.u, u_i[1] + grid.u
        ix, wx, _, _ = self.axis_weights(s_x)
        iy, wy, c0, ncols = self.axis_weights(s_y)
        post_x = np.exp(1j * self.k * s_x * self.centre[0])
        post_y = np.exp(1j * self.k * s_y * self.centre[1])
        if ctx is None:
            return self._transform_numpy(ix, wx, iy, wy, mu_i, grid), post_x, post_y
        import pyopencl as cl

        real = precision.real
        cplx = np.dtype(np.complex128 if real == np.float64 else np.complex64)
        key = (id(ctx.context), precision)
        if key not in self._device:
            self._device.clear()
            self._device[key] = [ctx.to_device(q, cplx) for q in self.Q]
        res = grid.resolution
        defines = ctx.defines(precision, SPREAD=self.spread)
        rows_knl = ctx.kernel("harvey_shack.cl", "sgrid_rows", defines)
        cols_knl = ctx.kernel("harvey_shack.cl", "sgrid_columns", defines)
        mf = cl.mem_flags
        ix_dev, iy_dev = ctx.to_device(ix, np.int32), ctx.to_device(iy, np.int32)
        wx_dev, wy_dev = ctx.to_device(wx, real), ctx.to_device(wy, real)
        rows = cl.Buffer(ctx.context, mf.READ_WRITE, res * ncols * cplx.itemsize)
        acc = cl.Buffer(ctx.context, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=np.zeros(res * res, cplx))
        ints = (np.int32(self.M), np.int32(res), np.int32(c0), np.int32(ncols))
        for n, q in enumerate(self._device[key]):
            rows_knl(ctx.queue, (res * ncols,), None, q, ix_dev, wx_dev, *ints, rows)
            cols_knl(ctx.queue, (res * res,), None, rows, iy_dev, wy_dev, *ints, np.int32(n), real.type(mu_i), acc)
        ctx.queue.finish()
        return acc, post_x, post_y

    def _transform_numpy(self, ix, wx, iy, wy, mu_i, grid: HemisphereGrid) -> np.ndarray:
        """Twin of the kernels sgrid_rows and sgrid_columns (sparse gridding matrices)."""
        res = grid.resolution
        rows = np.repeat(np.arange(res), 2 * self.spread)
        Wx = scipy.sparse.csr_matrix((wx.ravel(), (rows, ix.ravel())), shape=(res, self.M))
        Wy = scipy.sparse.csr_matrix((wy.ravel(), (rows, iy.ravel())), shape=(res, self.M))
        tau = np.clip(mu_i + grid.mu - 1.0, -1.0, 1.0)
        acc = np.zeros((res, res), dtype=complex)
        for n in range(self.orders):
            cheb = 1.0 if n == 0 else np.cos(n * np.arccos(tau))
            acc += cheb * (Wy @ (Wx @ self.Q[n].astype(complex, copy=False)).T).T
        return np.where(grid.inside, acc, 0.0)


def _tau_fields_numpy(z, aperture, k, n_max, deapod) -> np.ndarray:
    """ε_n j^n J_n(kz) e^{jkz} · aperture · deapodization (orders, na, nb): the twin of the Kirchhoff
    fields kernel run with wavenumber 2k at μ_i = 0."""
    n = np.arange(n_max + 1)
    eps_jn = np.where(n == 0, 1.0, 2.0) * (1j**n)
    base = aperture * np.exp(1j * k * z) * np.outer(deapod, deapod)
    return eps_jn[:, None, None] * scipy.special.jv(n[:, None, None], k * z[None]) * base[None]


def _tau_fields_opencl(ctx, z, aperture, k, n_max, deapod, precision: Precision) -> np.ndarray:
    """The Kirchhoff fields kernel with wavenumber 2k and μ_i = 0 (e^{jkz} J_n(kz)), pre-factors =
    the deapodization."""
    import pyopencl as cl

    real = precision.real
    cplx = np.dtype(np.complex128 if real == np.float64 else np.complex64)
    na, nb = z.shape
    orders = n_max + 1
    knl = ctx.kernel("kirchhoff.cl", "kirchhoff_fields", ctx.defines(precision, NMAX_BUF=max(16, orders)))
    out = cl.Buffer(ctx.context, cl.mem_flags.WRITE_ONLY, orders * na * nb * cplx.itemsize)
    pre = ctx.to_device(deapod.astype(complex), cplx)
    knl(ctx.queue, (na * nb,), None, ctx.to_device(z, real), ctx.to_device(aperture, cplx), pre, pre,
        np.int32(na), np.int32(nb), np.int32(n_max), real.type(2 * k), real.type(0.0), out)
    fields = np.empty((orders, na, nb), dtype=cplx)
    cl.enqueue_copy(ctx.queue, fields, out)
    return fields


def _assemble(ctx, acc, post_x, post_y, grid: HemisphereGrid, variant: str, k: float, mu_i: float, dz_ref: float,
              lambda1: float, r_s: complex, r_p: complex, precision: Precision) -> np.ndarray:
    """E (2, 3, res, res) before renormalization: I = acc·post_x·post_y·e^{jk c_z dz_ref},
    amplitude I μ_o/λ₁ (Ω = μ_o/μ_i), s ↔ φ̂_o r_s, p ↔ θ̂_o r_p (kernel hs_farfield; ``ctx`` None:
    its twin, ``acc`` an array)."""
    ghs = variant == "ghs"
    if ctx is None:
        mu_o = grid.mu
        cz = (mu_i + mu_o) if ghs else 2.0
        I = acc * np.outer(post_x, post_y) * np.exp(1j * k * cz * dz_ref)
        return scalar_farfield_numpy(grid, np.where(grid.inside, I * mu_o / lambda1, 0.0), r_s, r_p)
    import pyopencl as cl

    real = precision.real
    cplx = np.dtype(np.complex128 if real == np.float64 else np.complex64)
    res = grid.resolution
    knl = ctx.kernel("harvey_shack.cl", "hs_farfield", ctx.defines(precision))
    E_dev = cl.Buffer(ctx.context, cl.mem_flags.WRITE_ONLY, 6 * res * res * cplx.itemsize)
    knl(ctx.queue, (res * res,), None, acc, ctx.to_device(post_x, cplx), ctx.to_device(post_y, cplx), np.int32(res),
        np.int32(ghs), real.type(k), real.type(mu_i), real.type(dz_ref), real.type(1.0 / lambda1),
        np.array(r_s, dtype=cplx), np.array(r_p, dtype=cplx), E_dev)
    E = np.empty((2, 3, res, res), dtype=cplx)
    cl.enqueue_copy(ctx.queue, E, E_dev)
    ctx.queue.finish()
    return E.astype(np.complex128, copy=False)


def _per_incidence_transform(ctx, setup: KirchhoffSetup, variant: str, precision: Precision):
    """(acc, post_x, post_y) of the exact chirp-z transform of one incidence."""
    if variant == "ohs":  # the flat transform of W e^{2jk z'}; the assembly adds e^{2jk dz_ref}
        setup = setup.flattened(setup.window * np.exp(2j * setup.k * setup.z_mid))
    if ctx is None:  # the twin applies the post factors itself
        ones = np.ones(setup.grid.resolution)
        return chebyshev_transform_numpy(setup, setup.window[None])[0], ones, ones
    (acc,), _ = chebyshev_transform(ctx, setup, setup.window[None], precision)
    return acc, setup.czt_x.post, setup.czt_y.post


def _energy(E: np.ndarray, grid: HemisphereGrid, r_s: complex, r_p: complex, mu_i: float,
            weight_sum: float) -> tuple[float, float]:
    """(unrenormalized Fresnel-free propagating albedo Σ Ω|I|²/(λ₁²Δ²ΣW²) Δu², fraction of the
    Parseval total Σ|I|²Δu²/(λ₁²Δ²ΣW²) inside the disk), from E = φ̂/θ̂ · I μ_o/λ₁ · r."""
    pol, fresnel = max(enumerate((abs(r_s) ** 2, abs(r_p) ** 2)), key=lambda item: item[1])
    if fresnel == 0.0:
        return float("nan"), float("nan")
    amp2 = np.einsum("cij,cij->ij", E[pol].real, E[pol].real) + np.einsum("cij,cij->ij", E[pol].imag, E[pol].imag)
    amp2 /= fresnel  # |I μ_o/λ₁|², 0 outside the disk
    mu_o = np.where(grid.inside, grid.mu, 1.0)
    propagating = float(np.sum(amp2 / mu_o) * grid.pixel_area / (mu_i * weight_sum))
    in_disk = float(np.sum(amp2 / mu_o**2) * grid.pixel_area / weight_sum)
    return propagating, in_disk


def harvey_shack_farfield(ctx, scene: SurfaceScene, variant: str, sgrid: SGrid | None = None) -> FarField:
    """OHS or GHS far field of ``scene`` (``ctx`` None: the NumPy twins, double precision).

    ``sgrid``: the all-incidence transform of the scene's surface, λ and footprint
    (:meth:`SGrid.build`); None: the exact per-incidence chirp-z transform.
    """
    _check_variant(variant)
    t0 = time.perf_counter()
    precision = scene.precision
    if ctx is None and not precision.fp64:
        raise ValueError(f"the NumPy reference runs in double precision only, got precision = {precision!r}")
    check_incidence(scene.theta_i, scene.index)
    r_s, r_p = _fresnel_at_incidence(scene.index, scene.exterior_index, scene.theta_i)
    mu_i = float(np.cos(scene.theta_i))
    grid = scene.grid
    if sgrid is None:
        setup = KirchhoffSetup.from_scene(scene)
        acc, post_x, post_y = _per_incidence_transform(ctx, setup, variant, precision)
        k, lambda1, dz_ref, weight_sum = setup.k, setup.lambda1, setup.dz_ref, setup.weight_sum
        orders, transform = (setup.n_max + 1 if variant == "ghs" else 1), "per_incidence"
    else:
        if sgrid.variant != variant:
            raise ValueError(f"s grid built for {sgrid.variant!r}, asked for {variant!r}")
        acc, post_x, post_y = sgrid.transform(ctx, scene.theta_i, scene.phi_i, grid, precision)
        k, lambda1, dz_ref, weight_sum = sgrid.k, sgrid.lambda1, sgrid.dz_ref, sgrid.weight_sum
        orders, transform = sgrid.orders, "all_incidence"
    E = _assemble(ctx, acc, post_x, post_y, grid, variant, k, mu_i, dz_ref, lambda1, r_s, r_p, precision)
    propagating, in_disk = _energy(E, grid, r_s, r_p, mu_i, weight_sum)
    diagnostics = {
        "model": variant,
        "transform": transform,
        "transform_orders": orders,
        "fresnel_angle": "incidence",
        "propagating_albedo_unnormalized": propagating,
        "evanescent_fraction": 1.0 - in_disk,
    }
    if variant == "ohs":
        check_evanescent_loss(1.0 - in_disk, diagnostics, scene.theta_i)
        check_waist(scene, diagnostics, variant)
    if variant == "ghs":
        K = 1.0 / propagating if np.isfinite(propagating) and propagating > 0 else 1.0
        E *= np.sqrt(K)
        diagnostics["ghs_renormalization"] = K
    diagnostics.update(device="numpy" if ctx is None else ctx.describe(), precision=precision,
                       wall_time_s=time.perf_counter() - t0)
    ff = FarField(grid=grid, wavelength_um=scene.wavelength_um, exterior_index=float(scene.exterior_index),
                  theta_i=scene.theta_i, phi_i=scene.phi_i, E=E,
                  incident_power=footprint_power(scene.exterior_index, mu_i, weight_sum), diagnostics=diagnostics)
    ff.diagnostics["albedo_excess"] = albedo_excess(ff)
    return ff


@dataclass(frozen=True)
class HarveyShackOptions:
    transform: str = option("auto", choices=("auto", "all_incidence", "per_incidence"),
                            doc="all_incidence: one transform per (surface, λ, footprint) kept for every ω_i "
                                "(approx.md §3.3 item 3); per_incidence: exact chirp-z per ω_i; auto: "
                                "all_incidence while its s grid fits max_grid_mb")
    spread: int = option(6, low=2, high=12,
                         doc="half-width (grid nodes) of the all-incidence interpolation stencil; "
                             "error ≈ exp(−2.2·spread)")
    max_grid_mb: float = option(1024.0, low=0.0, low_open=True,
                                doc="auto: largest s grid (MB) kept for all incidences; all_incidence refuses larger")


class HarveyShackModel(FootprintModel):
    """Shared adapter of the OHS and GHS rungs (``variant``); keeps the all-incidence s grids of the
    last surfaces it saw (key: surface content hash, λ, footprint, z reference, precision)."""

    variant = "ohs"
    Options = HarveyShackOptions
    capabilities = Capabilities(takes="height_field", returns="fields", polarized=True, steerable=True,
                                reciprocal=False, conserves_energy=False, single_scattering=True)
    CACHE_ENTRIES = 2

    def __init__(self, options=None):
        super().__init__(options)
        self._grids: OrderedDict = OrderedDict()

    def _grid_shape(self, scene: SurfaceScene) -> tuple[int, int]:
        return SGrid.shape(scene, self.variant, self.options.spread)

    def _grid_bytes(self, scene: SurfaceScene) -> float:
        orders, M = self._grid_shape(scene)
        return float(orders * M * M * scene.precision.complex.itemsize)

    def _all_incidence(self, scene: SurfaceScene) -> bool:
        if self.options.transform == "per_incidence":
            return False
        return self.options.transform == "all_incidence" or self._grid_bytes(scene) <= self.options.max_grid_mb * 2**20

    def check(self, scene: SurfaceScene) -> None:
        if self.options.transform == "all_incidence":
            mb = self._grid_bytes(scene) / 2**20
            if mb > self.options.max_grid_mb:
                raise ValueError(f"[model.{self.name}] transform = \"all_incidence\": the s grid needs {mb:.0f} MB "
                                 f"> max_grid_mb = {self.options.max_grid_mb:g}; use \"per_incidence\" or \"auto\"")

    def _sgrid(self, ctx, scene: SurfaceScene) -> tuple[SGrid, bool]:
        """The scene's s grid and whether it was kept from an earlier scene."""
        z = np.ascontiguousarray(scene.surface.z)
        key = (hashlib.sha1(z.tobytes()).hexdigest(), z.shape, scene.surface.size_um, scene.wavelength_um,
               scene.exterior_index, scene.waist_um, tuple(scene.footprint_centre_um), scene.z_reference,
               scene.precision, id(ctx))
        if key in self._grids:
            self._grids.move_to_end(key)
            return self._grids[key], True
        while len(self._grids) >= self.CACHE_ENTRIES:
            self._grids.popitem(last=False)
        grid = self._grids[key] = SGrid.build(ctx, scene, self.variant, self.options.spread)
        return grid, False

    def run(self, ctx, scene: SurfaceScene) -> FarField:
        if not self._all_incidence(scene):
            return harvey_shack_farfield(ctx, scene, self.variant)
        sgrid, reused = self._sgrid(ctx, scene)
        if reused and sgrid.edge_warning:  # built (and warned) for an earlier scene: this one is cut the same
            warnings.warn(sgrid.edge_warning, FootprintWarning, stacklevel=2)
        ff = harvey_shack_farfield(ctx, scene, self.variant, sgrid)
        ff.diagnostics.update(sgrid_reused=reused, sgrid_size=sgrid.M, sgrid_mb=sgrid.nbytes / 2**20,
                              sgrid_build_s=0.0 if reused else sgrid.build_time_s)
        return ff

    def estimate(self, scene: SurfaceScene) -> Estimate:
        nodes = scene.surface.cells + 1
        res = scene.grid.resolution
        orders, M = self._grid_shape(scene)
        if not self._all_incidence(scene):
            orders = transform_orders(scene) if self.variant == "ghs" else 1
            memory, seconds = chebyshev_cost(nodes, res, orders)
            held, largest = chebyshev_device_bytes(nodes, res, orders, precision=scene.precision)
            return Estimate(memory, seconds, f"per incidence: {orders} order(s), {nodes}² nodes, {res}² pixels",
                            device_bytes=held, largest_buffer_bytes=largest)
        # the first incidence builds the grid (one M² FFT per order); each incidence then grids
        # separably: orders × 2·spread × res × (M + res) complex multiply-adds
        build = 3e-9 * orders * M * M * np.log2(M)
        per_incidence = 6e-9 * orders * 2 * self.options.spread * res * (M + res) + 1.5e-7 * res * res + 0.05
        memory = 2.0 * self._grid_bytes(scene) + 16.0 * (orders * nodes**2 + 2 * M * M + 8 * res * res) + 150e6
        # device: the grid's orders (one M² buffer each, kept), the build's order fields, the
        # gridded rows (res × M at most), the accumulator and the field planes
        item = float(scene.precision.complex.itemsize)
        fields, rows, planes = item * orders * nodes**2, item * res * M, item * 6 * res * res
        return Estimate(memory, build + per_incidence,
                        f"all incidences: {orders} order(s) on a {M}² s grid (built once, {build:.2g} s), {res}² pixels",
                        device_bytes=self._grid_bytes(scene) + fields + rows + planes + item * res * res,
                        largest_buffer_bytes=max(item * M * M, fields, rows, planes))

    def release(self) -> None:
        self._grids.clear()


class OHSModel(HarveyShackModel):
    """``[model] name = "ohs"``: original Harvey–Shack (c_z = 2k, Ω = μ_o/μ_i, Fresnel at θ_i)."""

    name = "ohs"
    summary = "original Harvey-Shack scalar diffraction; one transform per wavelength serves every incident direction"
    sampling = frozenset({"lattice", "pixels", "realization"})
    variant = "ohs"
    capabilities = replace(HarveyShackModel.capabilities, rung=2)

    def waist_remedy(self) -> str | None:
        return "ghs"  # harvey_shack_farfield's check_waist


class GHSModel(HarveyShackModel):
    """``[model] name = "ghs"``: generalized Harvey–Shack (c_z = k(μ_i+μ_o), Ω = μ_o/μ_i, Fresnel at
    θ_i, propagating part renormalized by Krywonos' K)."""

    name = "ghs"
    summary = ("generalized Harvey-Shack scalar diffraction (Krywonos' renormalization); one transform per "
               "wavelength serves every incident direction")
    sampling = frozenset({"lattice", "realization"})  # renormalized: the albedo does not depend on the pixels
    variant = "ghs"
    capabilities = replace(HarveyShackModel.capabilities, rung=3)
