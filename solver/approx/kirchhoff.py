"""Scalar Kirchhoff model (approx.md §3.3, by-parts form) → FarField.

    f(ω_i, ω_o) = |r(θ_h)|² Ω_K |I(s)|² / (λ₁² Δ² Σ W²),  s = u_i + u_o,
    I(s) = Δ² Σ_ab W_ab exp(+jk[s·x_ab + (μ_i+μ_o) z_ab]),
    Ω_K = (1 + ω_i·ω_o)² / (μ_i μ_o (μ_i+μ_o)²),

with k = 2πn₁/λ, λ₁ = λ/n₁, Fresnel r_s, r_p at the half-vector angle (cos θ_h =
√((1+ω_i·ω_o)/2)), and footprint W = exp(−|x − c|²/w²) (the full-wave beam's footprint,
bem3d.md §8). The μ_o dependence of the phase is expanded exactly in Chebyshev polynomials
(Jacobi–Anger, truncated where |J_n| < 1e-16), and every order is transformed onto the output
pixels exactly by chirp-z transforms, so no interpolation enters. One transform serves both
polarizations (Fresnel sits outside the integral).

Two implementations of the same formula: :func:`kirchhoff_farfield` (OpenCL kernels for the
fields and the per-pixel assembly, host FFTs) and :func:`kirchhoff_farfield_numpy` (NumPy/SciPy
only, the reference used in tests and benchmarks).
"""

from __future__ import annotations

import logging
import time
import warnings
from dataclasses import dataclass

import numpy as np
import scipy.fft
import scipy.special

from wavebrdf.solver.czt import ChirpZAxis
from wavebrdf.solver.farfield import ETA0, FarField, HemisphereGrid, transverse_basis
from wavebrdf.solver.footprint import EDGE_AMPLITUDE, FootprintWarning, edge_fraction, gaussian_footprint
from wavebrdf.solver.fresnel import fresnel_rs_rp
from wavebrdf.solver.models import Capabilities, Estimate, Model, SurfaceScene
from wavebrdf.solver.surface import HeightField

logger = logging.getLogger(__name__)

__all__ = [
    "KirchhoffModel",
    "KirchhoffSetup",
    "chebyshev_order",
    "kirchhoff_farfield",
    "kirchhoff_farfield_numpy",
]

BESSEL_TAIL = 1e-12  # truncate the Jacobi–Anger series where |J_n(x_max)| falls below this


def chebyshev_order(x_max: float, tail: float = BESSEL_TAIL) -> int:
    """Smallest n_max ≥ x_max with |J_n(x_max)| < tail for n > n_max (Jacobi–Anger truncation)."""
    n = max(int(np.ceil(x_max)), 1)
    while abs(scipy.special.jv(n + 1, x_max)) >= tail or abs(scipy.special.jv(n + 2, x_max)) >= tail:
        n += 1
    return n


@dataclass
class KirchhoffSetup:
    """Geometry, chirp-z plans and scalars shared by both implementations."""

    k: float
    exterior_index: float
    lambda1: float
    mu_i: float
    u_i: np.ndarray  # (2,)
    eta: complex
    z_mid: np.ndarray  # heights − mid-height (µm)
    dz_ref: float  # mid-height − reference height (µm)
    window: np.ndarray  # Δ² W (complex: footprint amplitude and phase relative to the plane wave)
    weight_sum: float  # Δ² Σ |W|²  (effective illuminated area, µm²)
    n_max: int
    czt_x: ChirpZAxis
    czt_y: ChirpZAxis
    grid: HemisphereGrid

    @classmethod
    def build(cls, surface: HeightField, wavelength_um: float, index: complex, theta_i: float, phi_i: float,
              grid: HemisphereGrid, window: np.ndarray | None, exterior_index: float = 1.0,
              z_reference: float | None = None, waist_um: float | None = None) -> "KirchhoffSetup":
        """The set-up of one (surface, λ, index, incidence) on ``grid``; ``window``: footprint on
        the nodes, or None for the Gaussian of ``waist_um``."""
        if not (np.isfinite(wavelength_um) and wavelength_um > 0):
            raise ValueError(f"wavelength must be > 0 µm, got {wavelength_um!r}")
        if not 0.0 <= theta_i < 0.5 * np.pi:
            raise ValueError(f"incident theta must be in [0°, 90°), got {np.rad2deg(theta_i):g}°")
        if np.imag(index) > 0:
            raise ValueError(f"index must be n - j*kappa with kappa >= 0, got {index!r}")
        if window is None:
            window = gaussian_footprint(surface, waist_um)
        window = np.asarray(window)
        window = window.astype(complex if np.iscomplexobj(window) else float)
        if window.shape != surface.z.shape:
            raise ValueError(f"footprint shape {window.shape} != height matrix {surface.z.shape}")
        edge = edge_fraction(window)
        if edge > EDGE_AMPLITUDE:
            warnings.warn(
                f"illumination footprint is {edge:.2g} of its peak at the patch edge "
                f"(patch {surface.size_um:g} µm): edge diffraction will show; use a larger patch or "
                "a smaller waist (patch >= ~5.3 waists)",
                FootprintWarning,
                stacklevel=3,
            )
        k = 2 * np.pi * exterior_index / wavelength_um
        d = surface.spacing_um
        z_ref = float(np.mean(surface.z)) if z_reference is None else float(z_reference)
        mid = 0.5 * (surface.z.max() + surface.z.min())
        z_mid = surface.z - mid
        n_max = chebyshev_order(0.5 * k * np.abs(z_mid).max())
        u_i = np.sin(theta_i) * np.array([np.cos(phi_i), np.sin(phi_i)])
        n_out = grid.resolution
        ds = 2.0 / n_out
        u0 = grid.u[0]
        n_nodes = surface.cells + 1
        czt_x = ChirpZAxis.plan(k, surface.x[0], d, n_nodes, u_i[0] + u0, ds, n_out)
        czt_y = ChirpZAxis.plan(k, surface.y[0], d, n_nodes, u_i[1] + u0, ds, n_out)
        return cls(
            k=k,
            exterior_index=float(exterior_index),
            lambda1=wavelength_um / exterior_index,
            mu_i=float(np.cos(theta_i)),
            u_i=u_i,
            eta=complex(index) / exterior_index,
            z_mid=z_mid,
            dz_ref=mid - z_ref,
            window=(window * d * d).astype(complex),
            weight_sum=float(np.sum(np.abs(window) ** 2) * d * d),
            n_max=n_max,
            czt_x=czt_x,
            czt_y=czt_y,
            grid=grid,
        )

    def incident_power(self) -> np.ndarray:
        """Φ_i per polarization (W) for |E₀| = 1 V/µm: n₁/(2η₀) μ_i Δ² Σ W²."""
        power = self.exterior_index / (2 * ETA0) * self.mu_i * self.weight_sum
        return np.array([power, power])

    def farfield(self, E: np.ndarray, theta_i: float, phi_i: float, **diagnostics) -> FarField:
        return FarField(
            grid=self.grid,
            wavelength_um=self.lambda1 * self.exterior_index,
            exterior_index=self.exterior_index,
            theta_i=theta_i,
            phi_i=phi_i,
            E=E,
            incident_power=self.incident_power(),
            diagnostics={"model": "kirchhoff", "chebyshev_terms": self.n_max + 1, **diagnostics},
        )


def _chunk_orders(n_total: int, res: int, length: int, budget_bytes: float = 256e6) -> int:
    """How many Chebyshev orders to transform at once within a memory budget."""
    per_order = 16.0 * res * length * 2
    return int(max(1, min(n_total, budget_bytes // per_order)))


def kirchhoff_farfield(
    ctx,
    surface: HeightField,
    wavelength_um: float,
    index: complex,
    theta_i: float,
    phi_i: float,
    grid: HemisphereGrid,
    *,
    waist_um: float | None = None,
    window: np.ndarray | None = None,
    exterior_index: float = 1.0,
    z_reference: float | None = None,
    precision: str = "double",
) -> FarField:
    """Kirchhoff far field of ``surface`` on ``grid`` computed with OpenCL kernels (``ctx`` None:
    the NumPy/SciPy reference, double precision only).

    Give either ``waist_um`` (Gaussian footprint centred on the patch) or an explicit
    footprint ``window`` on the surface nodes (real, or complex for a phase relative to the
    plane wave e^{+jk ω_i·r}, e.g. a sum of phase-stepped beams). ``z_reference`` is the height of the
    phase reference plane (default: the surface mean; patches of a larger surface pass the
    global mean). ``precision`` "single" runs kernels and FFTs in float32/complex64.
    """
    t0 = time.perf_counter()
    setup = KirchhoffSetup.build(
        surface, wavelength_um, index, theta_i, phi_i, grid, window, exterior_index, z_reference, waist_um
    )
    if ctx is None:
        if precision != "double":
            raise ValueError(f"the NumPy reference runs in double precision only, got precision = {precision!r}")
        return _farfield_numpy(setup, theta_i, phi_i, t0)
    return _farfield_opencl(ctx, setup, theta_i, phi_i, precision, t0)


def kirchhoff_farfield_numpy(*args, **kwargs) -> FarField:
    """The same model in plain NumPy/SciPy (double precision, numpy.fft, one thread): the
    arguments of :func:`kirchhoff_farfield` without ``ctx``."""
    return kirchhoff_farfield(None, *args, **kwargs)


def _farfield_opencl(ctx, setup: KirchhoffSetup, theta_i: float, phi_i: float, precision: str,
                     t0: float) -> FarField:
    """OpenCL kernels for the fields and the per-pixel assembly, host FFTs."""
    import pyopencl as cl

    grid = setup.grid
    real = ctx.real_dtype(precision)
    cplx = np.dtype(np.complex128 if real == np.float64 else np.complex64)
    defines = ctx.defines(precision, NMAX_BUF=max(16, setup.n_max + 1))
    queue = ctx.queue
    na, nb = setup.z_mid.shape
    res = grid.resolution
    n_orders = setup.n_max + 1
    mf = cl.mem_flags
    to_device = ctx.to_device

    fields_knl = ctx.kernel("kirchhoff.cl", "kirchhoff_fields", defines)
    fields_dev = cl.Buffer(ctx.context, mf.READ_WRITE, n_orders * na * nb * cplx.itemsize)
    fields_knl(
        queue, (na * nb,), None,
        to_device(setup.z_mid, real), to_device(setup.window, cplx),
        to_device(setup.czt_x.pre, cplx), to_device(setup.czt_y.pre, cplx),
        np.int32(na), np.int32(nb), np.int32(setup.n_max),
        real.type(setup.k), real.type(setup.mu_i), fields_dev,
    )
    fields = np.empty((n_orders, na, nb), dtype=cplx)
    cl.enqueue_copy(queue, fields, fields_dev)
    t_fields = time.perf_counter()

    acc_knl = ctx.kernel("kirchhoff.cl", "kirchhoff_accumulate", defines)
    acc_dev = cl.Buffer(ctx.context, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=np.zeros(res * res, cplx))
    chunk = _chunk_orders(n_orders, res, max(setup.czt_x.length, setup.czt_y.length))
    workers = ctx.fft_workers
    for n0 in range(0, n_orders, chunk):
        block = setup.czt_x.convolve(fields[n0 : n0 + chunk], axis=1, workers=workers)
        # y transform left un-sliced (rows of length L): the kernel reads the first res columns
        block = setup.czt_y.convolve(block, axis=2, workers=workers, trim=False).astype(cplx, copy=False)
        block_dev = cl.Buffer(ctx.context, mf.READ_ONLY | mf.USE_HOST_PTR, hostbuf=block)
        acc_knl(queue, (res * res,), None, block_dev, np.int32(n0), np.int32(block.shape[0]),
                np.int32(res), np.int32(block.shape[2]), acc_dev)
        queue.finish()
    t_transform = time.perf_counter()

    far_knl = ctx.kernel("kirchhoff.cl", "kirchhoff_farfield", defines)
    E_dev = cl.Buffer(ctx.context, mf.WRITE_ONLY, 6 * res * res * cplx.itemsize)
    far_knl(
        queue, (res * res,), None, acc_dev,
        to_device(setup.czt_x.post, cplx), to_device(setup.czt_y.post, cplx), np.int32(res),
        real.type(setup.k), real.type(setup.u_i[0]), real.type(setup.u_i[1]), real.type(setup.mu_i),
        real.type(setup.dz_ref), real.type(1.0 / setup.lambda1), np.array(setup.eta, dtype=cplx),
        E_dev,
    )
    E = np.empty((2, 3, res, res), dtype=cplx)
    cl.enqueue_copy(queue, E, E_dev)
    queue.finish()
    t_end = time.perf_counter()
    return setup.farfield(
        E.astype(np.complex128, copy=False), theta_i, phi_i,
        device=ctx.describe(), precision=precision,
        time_fields_s=t_fields - t0, time_transform_s=t_transform - t_fields,
        time_assembly_s=t_end - t_transform, wall_time_s=t_end - t0,
    )


def _farfield_numpy(s: KirchhoffSetup, theta_i: float, phi_i: float, t0: float) -> FarField:
    """The NumPy/SciPy twin of the kernels."""
    grid = s.grid
    n = np.arange(s.n_max + 1)
    eps_jn = np.where(n == 0, 1.0, 2.0) * (1j**n)
    bessel = scipy.special.jv(n[:, None, None], 0.5 * s.k * s.z_mid[None])
    base = s.window * np.exp(1j * s.k * (s.mu_i + 0.5) * s.z_mid)
    fields = eps_jn[:, None, None] * bessel * base[None]
    transformed = s.czt_y(s.czt_x(fields, axis=1, fft=np.fft), axis=2, fft=np.fft)

    U, V = grid.uv
    inside = grid.inside
    mu_o = grid.mu
    t_cheb = 2.0 * mu_o - 1.0
    cheb = np.cos(n[:, None, None] * np.arccos(np.clip(t_cheb, -1, 1))[None])
    I = np.sum(cheb * transformed, axis=0) * np.exp(1j * s.k * (s.mu_i + mu_o) * s.dz_ref)

    mu_safe = np.where(inside, mu_o, 1.0)
    cos_io = s.u_i[0] * U + s.u_i[1] * V + s.mu_i * mu_safe
    omega_k = (1 + cos_io) ** 2 / (s.mu_i * mu_safe * (s.mu_i + mu_safe) ** 2)
    r_s, r_p = fresnel_rs_rp(s.eta, np.sqrt(np.clip(0.5 * (1 + cos_io), 0, None)))
    amp = np.where(inside, I * np.sqrt(s.mu_i * mu_safe * omega_k) / s.lambda1, 0.0)
    theta_hat, phi_hat = transverse_basis(U, V)
    E = np.empty((2, 3) + U.shape, dtype=complex)
    E[0] = np.moveaxis(phi_hat, -1, 0) * (amp * r_s)[None]
    E[1] = np.moveaxis(theta_hat, -1, 0) * (amp * r_p)[None]
    return s.farfield(E, theta_i, phi_i, device="numpy", precision="double",
                      wall_time_s=time.perf_counter() - t0)


class KirchhoffModel(Model):
    """Registry adapter: ``[model] name = "kirchhoff"`` (no options of its own)."""

    name = "kirchhoff"
    capabilities = Capabilities(takes="height_field", returns="fields", polarized=True, steerable=True,
                                reciprocal=True, conserves_energy=False)

    def run(self, ctx, scene: SurfaceScene) -> FarField:
        window = gaussian_footprint(scene.surface, scene.waist_um, scene.footprint_centre_um)
        return kirchhoff_farfield(
            ctx, scene.surface, scene.wavelength_um, scene.index, scene.theta_i, scene.phi_i,
            scene.grid, window=window, exterior_index=scene.exterior_index,
            z_reference=scene.z_reference, precision=scene.precision,
        )

    def incident_fields(self, scene: SurfaceScene, points):
        """The footprint as a locally plane wave: E = W(r) e^{+jk ω_i·r} ê, H = (n₁/η₀) k̂ × E.

        k̂ = −ω_i; ê_s ⟂ plane of incidence, ê_p = ê_s × k̂ (|E₀| = 1 V/µm as in the FarField).
        """
        points = np.asarray(points, dtype=float)
        k = 2 * np.pi * scene.exterior_index / scene.wavelength_um
        st, ct = np.sin(scene.theta_i), np.cos(scene.theta_i)
        omega = np.array([st * np.cos(scene.phi_i), st * np.sin(scene.phi_i), ct])
        e_s = np.array([-np.sin(scene.phi_i), np.cos(scene.phi_i), 0.0])
        k_hat = -omega
        e_p = np.cross(e_s, k_hat)
        c = scene.footprint_centre_um
        r2 = (points[..., 0] - c[0]) ** 2 + (points[..., 1] - c[1]) ** 2
        amplitude = np.exp(-r2 / scene.waist_um**2) * np.exp(1j * k * (points @ omega))
        E = np.stack([np.multiply.outer(e, amplitude) for e in (e_s, e_p)])
        H = np.stack([np.multiply.outer(np.cross(k_hat, e), amplitude) for e in (e_s, e_p)])
        return E, H * (scene.exterior_index / ETA0)

    def estimate(self, scene: SurfaceScene) -> Estimate:
        nodes = scene.surface.cells + 1
        res = scene.grid.resolution
        k = 2 * np.pi * scene.exterior_index / scene.wavelength_um
        orders = chebyshev_order(0.5 * k * 0.5 * np.ptp(scene.surface.z)) + 1
        length = nodes + res
        chunk = _chunk_orders(orders, res, length)
        memory = 16.0 * (orders * nodes**2 + 2 * chunk * res * length + 8 * res * res) + 150e6
        # measured here: ~3e-9 s per (order × line × FFT-length × log2 length), plus the pixel work
        seconds = 3e-9 * orders * length * length * np.log2(length) + 1.5e-7 * res * res + 0.05
        return Estimate(memory, seconds, f"{orders} Chebyshev orders, {nodes}² nodes, {res}² pixels")
