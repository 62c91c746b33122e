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

The transform is shared with the other rungs of the family (Harvey–Shack, physical optics):
:func:`chebyshev_transform` (OpenCL + host FFTs) and :func:`chebyshev_transform_numpy` (its twin)
take any number of apertures ("channels") on the nodes and return Σ_n T_n(2μ_o − 1)·CZT[g_n] on the
pixels; each rung then applies its own per-pixel factors.
"""

from __future__ import annotations

import dataclasses
import logging
import time
import warnings
from dataclasses import dataclass

import numpy as np
import scipy.fft
import scipy.special

from wavebrdf.solver.czt import ChirpZAxis
from wavebrdf.solver.farfield import ETA0, BRDFResult, FarField, HemisphereGrid, albedo, transverse_basis
from wavebrdf.solver.footprint import (FootprintWarning, edge_fraction, footprint_edge_warning, footprint_plane_wave,
                                      gaussian_footprint)
from wavebrdf.solver.fresnel import fresnel_rs_rp
from wavebrdf.solver.models import Capabilities, Estimate, Model, SurfaceScene
from wavebrdf.solver.precision import Precision
from wavebrdf.solver.surface import HeightField
from wavebrdf.solver.validity import check_lit_facets, check_waist

logger = logging.getLogger(__name__)

__all__ = [
    "Aperture",
    "FootprintModel",
    "albedo_excess",
    "KirchhoffModel",
    "KirchhoffSetup",
    "chebyshev_order",
    "chebyshev_transform",
    "chebyshev_cost",
    "chebyshev_device_bytes",
    "chebyshev_transform_numpy",
    "check_incidence",
    "beam_geometry",
    "footprint_power",
    "node_positions",
    "kirchhoff_farfield",
    "kirchhoff_farfield_numpy",
    "scalar_farfield_numpy",
    "scene_footprint",
    "transform_orders",
]

BESSEL_TAIL = 1e-12  # truncate the Jacobi–Anger series where |J_n(x_max)| falls below this


def chebyshev_order(x_max: float, tail: float = BESSEL_TAIL) -> int:
    """Smallest n_max ≥ x_max with |J_n(x_max)| < tail for n > n_max (Jacobi–Anger truncation)."""
    n = max(int(np.ceil(x_max)), 1)
    while abs(scipy.special.jv(n + 1, x_max)) >= tail or abs(scipy.special.jv(n + 2, x_max)) >= tail:
        n += 1
    return n


def check_incidence(theta_i: float, index: complex) -> None:
    """Refuse an incidence outside [0°, 90°) or a gain medium (κ < 0 in n − jκ)."""
    if not 0.0 <= theta_i < 0.5 * np.pi:
        raise ValueError(f"incident theta must be in [0°, 90°), got {np.rad2deg(theta_i):g}°")
    if np.imag(index) > 0:
        raise ValueError(f"index must be n - j*kappa with kappa >= 0, got {index!r}")


def albedo_excess(result: BRDFResult) -> float:
    """max(0, albedo − 1) over the polarizations: the energy a rung creates beyond the incident."""
    return float(max(0.0, albedo(result.brdf(), result.grid).max() - 1.0))


def scene_footprint(scene: SurfaceScene) -> np.ndarray:
    """The scene's footprint W on the nodes (its waist, about its footprint centre)."""
    return gaussian_footprint(scene.surface, scene.waist_um, scene.footprint_centre_um)


def footprint_power(exterior_index: float, mu_i: float, weight_sum: float) -> np.ndarray:
    """Φ_i per polarization (W) of the footprint plane wave with |E₀| = 1 V/µm through the mean
    plane: n₁/(2η₀) μ_i Δ² Σ W² (``weight_sum`` = Δ² Σ |W|², µm²)."""
    power = exterior_index / (2 * ETA0) * mu_i * weight_sum
    return np.array([power, power])


@dataclass
class Aperture:
    """The illuminated surface as every rung of the family transforms it (no direction enters).

    ``window`` = Δ² W on the nodes (complex), ``z_mid`` the heights about the mid-height, ``dz_ref``
    mid-height − phase-reference height (µm), ``weight_sum`` = Δ² Σ |W|² (µm²).
    """

    k: float
    exterior_index: float
    lambda1: float
    z_mid: np.ndarray
    dz_ref: float
    window: np.ndarray
    weight_sum: float

    @classmethod
    def from_scene(cls, scene: SurfaceScene) -> "Aperture":
        """The aperture of a scene: its Gaussian footprint about ``footprint_centre_um``."""
        return cls.build(scene.surface, scene.wavelength_um, scene_footprint(scene), scene.exterior_index,
                         scene.z_reference, stacklevel=5)

    @classmethod
    def build(cls, surface: HeightField, wavelength_um: float, window: np.ndarray | None, exterior_index: float = 1.0,
              z_reference: float | None = None, waist_um: float | None = None, stacklevel: int = 4) -> "Aperture":
        """``window``: footprint on the nodes, or None for the Gaussian of ``waist_um``; warns
        (FootprintWarning) when the footprint reaches the patch edge."""
        if not (np.isfinite(wavelength_um) and wavelength_um > 0):
            raise ValueError(f"wavelength must be > 0 µm, got {wavelength_um!r}")
        if window is None:
            window = gaussian_footprint(surface, waist_um)
        window = np.asarray(window)
        window = window.astype(complex if np.iscomplexobj(window) else float)
        if window.shape != surface.z.shape:
            raise ValueError(f"footprint shape {window.shape} != height matrix {surface.z.shape}")
        message = footprint_edge_warning(edge_fraction(window), surface.size_um)
        if message:
            warnings.warn(message, FootprintWarning, stacklevel=stacklevel)
        d = surface.spacing_um
        z_ref = float(np.mean(surface.z)) if z_reference is None else float(z_reference)
        mid = 0.5 * (surface.z.max() + surface.z.min())
        return cls(
            k=2 * np.pi * exterior_index / wavelength_um,
            exterior_index=float(exterior_index),
            lambda1=wavelength_um / exterior_index,
            z_mid=surface.z - mid,
            dz_ref=mid - z_ref,
            window=(window * d * d).astype(complex),
            weight_sum=float(np.sum(np.abs(window) ** 2) * d * d),
        )


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
    def from_scene(cls, scene: SurfaceScene) -> "KirchhoffSetup":
        """The set-up of a scene (its Gaussian footprint about ``footprint_centre_um``)."""
        return cls.build(scene.surface, scene.wavelength_um, scene.index, scene.theta_i, scene.phi_i, scene.grid,
                         scene_footprint(scene), scene.exterior_index, scene.z_reference)

    @classmethod
    def build(cls, surface: HeightField, wavelength_um: float, index: complex, theta_i: float, phi_i: float,
              grid: HemisphereGrid, window: np.ndarray | None, exterior_index: float = 1.0,
              z_reference: float | None = None, waist_um: float | None = None) -> "KirchhoffSetup":
        """The set-up of one (surface, λ, index, incidence) on ``grid``; ``window``: footprint on
        the nodes, or None for the Gaussian of ``waist_um``."""
        check_incidence(theta_i, index)
        ap = Aperture.build(surface, wavelength_um, window, exterior_index, z_reference, waist_um)
        k = ap.k
        d = surface.spacing_um
        n_max = chebyshev_order(0.5 * k * np.abs(ap.z_mid).max())
        u_i = np.sin(theta_i) * np.array([np.cos(phi_i), np.sin(phi_i)])
        n_out = grid.resolution
        ds = 2.0 / n_out
        u0 = grid.u[0]
        n_nodes = surface.cells + 1
        czt_x = ChirpZAxis.plan(k, surface.x[0], d, n_nodes, u_i[0] + u0, ds, n_out)
        czt_y = ChirpZAxis.plan(k, surface.y[0], d, n_nodes, u_i[1] + u0, ds, n_out)
        return cls(
            k=k,
            exterior_index=ap.exterior_index,
            lambda1=ap.lambda1,
            mu_i=float(np.cos(theta_i)),
            u_i=u_i,
            eta=complex(index) / exterior_index,
            z_mid=ap.z_mid,
            dz_ref=ap.dz_ref,
            window=ap.window,
            weight_sum=ap.weight_sum,
            n_max=n_max,
            czt_x=czt_x,
            czt_y=czt_y,
            grid=grid,
        )

    def incident_power(self) -> np.ndarray:
        """Φ_i per polarization (W) for |E₀| = 1 V/µm: n₁/(2η₀) μ_i Δ² Σ W²."""
        return footprint_power(self.exterior_index, self.mu_i, self.weight_sum)

    def flattened(self, window: np.ndarray) -> "KirchhoffSetup":
        """The same geometry with the aperture ``window`` (Δ²·g on the nodes, any phase included)
        transformed over the plane z = mid-height: no Chebyshev expansion (n_max = 0)."""
        return dataclasses.replace(self, z_mid=np.zeros_like(self.z_mid), window=np.asarray(window, dtype=complex),
                                   n_max=0)

    def farfield(self, E: np.ndarray, theta_i: float, phi_i: float, model: str = "kirchhoff",
                 incident_power: np.ndarray | None = None, **diagnostics) -> FarField:
        """The FarField of ``E``, normalised by the footprint's Φ_i or the ``incident_power`` given."""
        return FarField(
            grid=self.grid,
            wavelength_um=self.lambda1 * self.exterior_index,
            exterior_index=self.exterior_index,
            theta_i=theta_i,
            phi_i=phi_i,
            E=E,
            incident_power=self.incident_power() if incident_power is None else incident_power,
            diagnostics={"model": model, "chebyshev_terms": self.n_max + 1, **diagnostics},
        )


def beam_geometry(slopes: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """(5, nodes) h_x, h_y, x, y, z − z_ref: the nodes as the beam kernels read them
    (kernels/wb_beam_waves.h) from ``slopes`` (2, na, nb) and :func:`node_positions`."""
    return np.concatenate([slopes.reshape(2, -1), np.moveaxis(positions, -1, 0).reshape(3, -1)])


def node_positions(setup: KirchhoffSetup, surface) -> np.ndarray:
    """(na, nb, 3) node positions x, y and height above the phase-reference plane (µm)."""
    X, Y = np.meshgrid(surface.x, surface.y, indexing="ij")
    return np.stack([X, Y, setup.z_mid + setup.dz_ref], axis=-1)


def _chunk_orders(n_total: int, res: int, length: int, budget_bytes: float = 256e6) -> int:
    """How many Chebyshev orders to transform at once within a memory budget."""
    per_order = 16.0 * res * length * 2
    return int(max(1, min(n_total, budget_bytes // per_order)))


def transform_orders(scene: SurfaceScene) -> int:
    """Chebyshev orders of the scene's μ_o expansion (n_max + 1), from its height range."""
    k = 2 * np.pi * scene.exterior_index / scene.wavelength_um
    return chebyshev_order(0.5 * k * 0.5 * np.ptp(scene.surface.z)) + 1


def chebyshev_cost(nodes: int, res: int, orders: int, channels: int = 1) -> tuple[float, float]:
    """(bytes, seconds) of :func:`chebyshev_transform` plus a pixel assembly: ``orders`` orders of
    ``channels`` apertures (one after the other) on nodes² nodes onto res² pixels, in blocks of the
    memory budget."""
    length = nodes + res
    chunk = _chunk_orders(orders, res, length)
    memory = 16.0 * (orders * nodes**2 + 2 * chunk * res * length + (7 + channels) * res * res) + 150e6
    # measured here: ~3e-9 s per (order × line × FFT-length × log2 length), plus the pixel work
    seconds = 3e-9 * channels * orders * length * length * np.log2(length) + 1.5e-7 * res * res + 0.05
    return memory, seconds


def chebyshev_device_bytes(nodes: int, res: int, orders: int, channels: int = 1,
                           precision: Precision = Precision.DOUBLE) -> tuple[float, float]:
    """(held, largest) device bytes of :func:`chebyshev_transform` plus the pixel assembly: the
    orders' fields (orders × nodes²), one transformed block of orders (chunk × res × (nodes + res)),
    the ``channels`` accumulators and the field planes (6 × res²); ``largest`` is the biggest single
    buffer, which must fit the device's max allocation."""
    item = float(precision.complex.itemsize)
    length = nodes + res
    fields = item * orders * nodes**2
    block = item * _chunk_orders(orders, res, length) * res * length
    planes = item * 6 * res * res
    held = fields + block + planes + item * channels * res * res + 1.5 * item * nodes**2  # + heights, window
    return held, max(fields, block, planes)


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
    precision: Precision = Precision.DOUBLE,
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
        if not precision.fp64:
            raise ValueError(f"the NumPy reference runs in double precision only, got precision = {precision!r}")
        return _farfield_numpy(setup, theta_i, phi_i, t0)
    return _farfield_opencl(ctx, setup, theta_i, phi_i, precision, t0)


def kirchhoff_farfield_numpy(*args, **kwargs) -> FarField:
    """The same model in plain NumPy/SciPy (double precision, numpy.fft, one thread): the
    arguments of :func:`kirchhoff_farfield` without ``ctx``."""
    return kirchhoff_farfield(None, *args, **kwargs)


def chebyshev_transform(ctx, setup: KirchhoffSetup, windows: np.ndarray, precision: Precision,
                        budget_bytes: float = 256e6) -> tuple[list, dict]:
    """Σ_n T_n(2μ_o − 1)·CZT_x CZT_y[g_n] of each aperture ("channel") of ``windows`` (nchan, na, nb)
    on the pixels of ``setup.grid``, without the chirp-z post factors (OpenCL kernels, host FFTs).

    g_n = windows[c]·e^{jk(μ_i+½)z} ε_n j^n J_n(kz/2) (z = ``setup.z_mid``), one channel at a time:
    all its orders are generated, then transformed in blocks that fit ``budget_bytes``; apertures
    that vanish (e.g. J_z, M_z of PO on a plane) are skipped. Returns one device buffer (res, res)
    per channel and the stage times (s).
    """
    import pyopencl as cl

    t0 = time.perf_counter()
    real = precision.real
    cplx = np.dtype(np.complex128 if real == np.float64 else np.complex64)
    defines = ctx.defines(precision, NMAX_BUF=max(16, setup.n_max + 1))
    queue = ctx.queue
    na, nb = setup.z_mid.shape
    nchan = windows.shape[0]
    res = setup.grid.resolution
    n_orders = setup.n_max + 1
    mf = cl.mem_flags
    to_device = ctx.to_device
    fields_knl = ctx.kernel("kirchhoff.cl", "kirchhoff_fields", defines)
    acc_knl = ctx.kernel("kirchhoff.cl", "kirchhoff_accumulate", defines)
    z_dev = to_device(setup.z_mid, real)
    pre_x, pre_y = to_device(setup.czt_x.pre, cplx), to_device(setup.czt_y.pre, cplx)
    acc = [cl.Buffer(ctx.context, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=np.zeros(res * res, cplx))
           for _ in range(nchan)]
    chunk = _chunk_orders(n_orders, res, max(setup.czt_x.length, setup.czt_y.length), budget_bytes)
    workers = ctx.fft_workers
    times = {"fields": 0.0, "transform": 0.0}
    for c in range(nchan):
        if not windows[c].any():  # a vanishing aperture (e.g. J_z, M_z of PO on a plane): acc = 0
            continue
        t1 = time.perf_counter()
        fields_dev = cl.Buffer(ctx.context, mf.READ_WRITE, n_orders * na * nb * cplx.itemsize)
        fields_knl(
            queue, (na * nb,), None, z_dev, to_device(windows[c], cplx), pre_x, pre_y,
            np.int32(na), np.int32(nb), np.int32(setup.n_max),
            real.type(setup.k), real.type(setup.mu_i), fields_dev,
        )
        fields = np.empty((n_orders, na, nb), dtype=cplx)
        cl.enqueue_copy(queue, fields, fields_dev)
        del fields_dev
        t2 = time.perf_counter()
        for n0 in range(0, n_orders, chunk):
            block = setup.czt_x.convolve(fields[n0 : n0 + chunk], axis=1, workers=workers)
            # y transform left un-sliced (rows of length L): the kernel reads the first res columns
            block = setup.czt_y.convolve(block, axis=2, workers=workers, trim=False).astype(cplx, copy=False)
            block_dev = cl.Buffer(ctx.context, mf.READ_ONLY | mf.USE_HOST_PTR, hostbuf=block)
            acc_knl(queue, (res * res,), None, block_dev, np.int32(n0), np.int32(block.shape[0]),
                    np.int32(res), np.int32(block.shape[2]), acc[c])
            queue.finish()
        del fields
        times["fields"] += t2 - t1
        times["transform"] += time.perf_counter() - t2
    times["total"] = time.perf_counter() - t0
    return acc, times


def chebyshev_transform_numpy(setup: KirchhoffSetup, windows: np.ndarray) -> list[np.ndarray]:
    """NumPy/SciPy twin of :func:`chebyshev_transform` (double precision), with the chirp-z post
    factors applied: per channel, Σ_n T_n(2μ_o − 1)·I_n on the pixels, (res, res) (any value
    outside the disk)."""
    grid = setup.grid
    n = np.arange(setup.n_max + 1)
    eps_jn = np.where(n == 0, 1.0, 2.0) * (1j**n)
    bessel = scipy.special.jv(n[:, None, None], 0.5 * setup.k * setup.z_mid[None])
    out, cheb = [], None
    for window in windows:
        if not window.any():  # a vanishing aperture
            out.append(np.zeros(grid.mu.shape, dtype=complex))
            continue
        base = window * np.exp(1j * setup.k * (setup.mu_i + 0.5) * setup.z_mid)
        fields = eps_jn[:, None, None] * bessel * base[None]
        transformed = setup.czt_y(setup.czt_x(fields, axis=1, fft=np.fft), axis=2, fft=np.fft)
        if cheb is None:
            t_cheb = 2.0 * grid.mu - 1.0
            cheb = np.cos(n[:, None, None] * np.arccos(np.clip(t_cheb, -1, 1))[None])
        out.append(np.sum(cheb * transformed, axis=0))
    return out


def _farfield_opencl(ctx, setup: KirchhoffSetup, theta_i: float, phi_i: float, precision: Precision,
                     t0: float) -> FarField:
    """OpenCL kernels for the fields and the per-pixel assembly, host FFTs."""
    import pyopencl as cl

    grid = setup.grid
    real = precision.real
    cplx = np.dtype(np.complex128 if real == np.float64 else np.complex64)
    defines = ctx.defines(precision, NMAX_BUF=max(16, setup.n_max + 1))
    queue = ctx.queue
    res = grid.resolution
    (acc_dev,), times = chebyshev_transform(ctx, setup, setup.window[None], precision)
    t_transform = time.perf_counter()

    far_knl = ctx.kernel("kirchhoff.cl", "kirchhoff_farfield", defines)
    E_dev = cl.Buffer(ctx.context, cl.mem_flags.WRITE_ONLY, 6 * res * res * cplx.itemsize)
    to_device = ctx.to_device
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
        time_fields_s=(t_transform - t0) - times["transform"], time_transform_s=times["transform"],
        time_assembly_s=t_end - t_transform, wall_time_s=t_end - t0,
    )


def scalar_farfield_numpy(grid: HemisphereGrid, amp: np.ndarray, r_s, r_p) -> np.ndarray:
    """E (2 pol, 3, res, res) of a scalar rung: s ↔ φ̂_o·amp·r_s, p ↔ θ̂_o·amp·r_p (twin of the
    kernel helper store_scalar_farfield); ``amp`` must be 0 outside the disk."""
    U, V = grid.uv
    theta_hat, phi_hat = transverse_basis(U, V)
    E = np.empty((2, 3) + U.shape, dtype=complex)
    E[0] = np.moveaxis(phi_hat, -1, 0) * (amp * r_s)[None]
    E[1] = np.moveaxis(theta_hat, -1, 0) * (amp * r_p)[None]
    return E


def _farfield_numpy(s: KirchhoffSetup, theta_i: float, phi_i: float, t0: float) -> FarField:
    """The NumPy/SciPy twin of the kernels."""
    grid = s.grid
    U, V = grid.uv
    inside = grid.inside
    mu_o = grid.mu
    I = chebyshev_transform_numpy(s, s.window[None])[0] * np.exp(1j * s.k * (s.mu_i + mu_o) * s.dz_ref)

    mu_safe = np.where(inside, mu_o, 1.0)
    cos_io = s.u_i[0] * U + s.u_i[1] * V + s.mu_i * mu_safe
    omega_k = (1 + cos_io) ** 2 / (s.mu_i * mu_safe * (s.mu_i + mu_safe) ** 2)
    r_s, r_p = fresnel_rs_rp(s.eta, np.sqrt(np.clip(0.5 * (1 + cos_io), 0, None)))
    amp = np.where(inside, I * np.sqrt(s.mu_i * mu_safe * omega_k) / s.lambda1, 0.0)
    E = scalar_farfield_numpy(grid, amp, r_s, r_p)
    return s.farfield(E, theta_i, phi_i, device="numpy", precision=Precision.DOUBLE,
                      wall_time_s=time.perf_counter() - t0)


class FootprintModel(Model):
    """Base of the rungs lit by the footprint plane wave (kirchhoff, ohs, ghs, po): their incident
    fields, which make them steerable."""

    def incident_fields(self, scene: SurfaceScene, points):
        """The footprint as a locally plane wave (:func:`~wavebrdf.solver.footprint.footprint_plane_wave`)."""
        return footprint_plane_wave(scene.wavelength_um, scene.exterior_index, scene.theta_i, scene.phi_i,
                                    scene.waist_um, scene.footprint_centre_um, points)

    def steered_fresnel(self) -> str | None:
        """ohs and ghs take Fresnel at the footprint's direction ω_i (outside the integral)."""
        return "incidence"


class KirchhoffModel(FootprintModel):
    """Registry adapter: ``[model] name = "kirchhoff"`` (no options of its own)."""

    name = "kirchhoff"
    summary = ("scalar Kirchhoff (tangent-plane) approximation of a rough surface: single scattering, Fresnel at "
               "the half vector; fast")
    sampling = frozenset({"lattice", "pixels", "realization"})
    capabilities = Capabilities(takes="height_field", returns="fields", polarized=True, steerable=True,
                                reciprocal=True, conserves_energy=False, rung=4, single_scattering=True)

    def steered_fresnel(self) -> str | None:
        """Fresnel at the half vector of ω_i and ω_o: steered from ω_b, at the half vector of ω_b and
        the requested mirror direction (a flat glass patch steered from 58.7° to 75° measured 0.183
        in s and 0.0115 in p: between Fresnel's at 58.7°, 0.166 / 0.0007, and at that half vector,
        66.8°, 0.251 / 0.021; at 75°, 0.399 / 0.107)."""
        return "half vector"

    def run(self, ctx, scene: SurfaceScene) -> FarField:
        ff = kirchhoff_farfield(
            ctx, scene.surface, scene.wavelength_um, scene.index, scene.theta_i, scene.phi_i,
            scene.grid, window=scene_footprint(scene), exterior_index=scene.exterior_index,
            z_reference=scene.z_reference, precision=scene.precision,
        )
        check_waist(scene, ff.diagnostics, self.name, self.waist_remedy())
        check_lit_facets(scene, ff, self.name)
        return ff

    def waist_remedy(self) -> str | None:
        return "ghs"

    def estimate(self, scene: SurfaceScene) -> Estimate:
        nodes = scene.surface.cells + 1
        res = scene.grid.resolution
        orders = transform_orders(scene)
        memory, seconds = chebyshev_cost(nodes, res, orders)
        held, largest = chebyshev_device_bytes(nodes, res, orders, precision=scene.precision)
        return Estimate(memory, seconds, f"{orders} Chebyshev orders, {nodes}² nodes, {res}² pixels",
                        device_bytes=held, largest_buffer_bytes=largest)
