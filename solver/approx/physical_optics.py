"""Vector physical optics, first order (approx.md §3.6) → FarField (polarization-resolved,
cross-polarization included).

Conventions: e^{+jωt}, index n − jκ, µm. Incident field: the footprint plane wave of every rung of
the Kirchhoff family (:func:`~wavebrdf.solver.footprint.footprint_plane_wave`),
E_i = W e^{+jk ω_i·r} ê, H_i = (n₁/η₀) k̂ × E_i, k̂ = −ω_i, ê_s ⟂ plane of incidence, ê_p = ê_s × k̂,
W = exp(−|x − c|²/w²), |E₀| = 1 V/µm.

At each lit node (ω_i·m > 0 and V_i = 1) the tangent-plane fields give the currents

    J dS = m̃ × (H_i + H_r) dx dy,   M dS = −m̃ × (E_i + E_r) dx dy,   m̃ = (−h_x, −h_y, 1),

with E_r = r_s (ê·ŝ) ŝ + r_p (ê·p̂_i) p̂_r in the node's local s/p frame (approx.md §1; any ŝ ⟂ m
at normal local incidence, where r_s = −r_p) and Fresnel r_s, r_p at the exact local angle
(complex index, kernels/wb_fresnel.h). Node slopes: central differences (the mean of the bilinear
cells' gradients at the node; one-sided on the patch border). Shadowed or back-facing nodes carry
no current. The incident field's own currents, m̃ × H_i and −m̃ × E_i on every node, are then
subtracted: for a Maxwell incident field on the whole surface they radiate nothing into the upper
half-space (the extinction theorem), and the footprint plane wave's radiate only a leak of its
non-Maxwell ∇W part (at n₂ = n₁: 1e-2 of Φ_i at 60°, 1% of glass's R at 30°, w = 4 µm). So lit nodes
carry the reflected field's currents, unlit ones minus the incident field's (their shadow), and the
index-matched interface reflects exactly nothing. The far field (Balanis' radiation integrals for e^{+jωt})

    E_far(ω_o) = (jk/4π) ω_o × (η₁ ω_o × N + L),   N = Σ J Δ² e^{+jk(ω_i + ω_o)·r}, L likewise,

uses the Kirchhoff rung's exact machinery for the μ_o dependence (Chebyshev/Jacobi–Anger
expansion of e^{+jkμ_o z} and chirp-z transforms onto the pixel centres): 6 current components × 2
incident polarizations per order. BRDF f = |E_far|²/(|E₀|² μ_i μ_o Δ²ΣW²) (FarField
normalisation); on a flat patch the mirror direction gets exactly r_s, r_p (peak |r|² A_eff/λ₁²,
A_eff = (ΣWΔ²)²/ΣW²Δ²).

Shadowing (``shadowing = "rays"``): V_i from the ray tracer of the geometric rungs
(:func:`wavebrdf.solver.approx.raytrace.node_visibility`: the ray from the node toward ω_i escapes,
``border`` "periodic" | "clamp" beyond the patch) and the back-facing test; ``"none"``: the local
back-facing test ω_i·m̃ > 0 only (also, with a warning and ``diagnostics["shadowing"]`` saying so,
when the ray tracer is not installed). Masking V_o is not applied (classical PO radiates every lit
current); the footprint-weighted shadowed and back-facing fractions are reported in the
diagnostics, as is the albedo in excess of 1.

Lit by the beam (``incidence = "beam"``): the full-wave solver's exact Gaussian beam
(:func:`wavebrdf.solver.beams.scene_beam`) as its plane waves (k̂_m, E_m), each node carrying
Δ² Σ_m e^{−jk k̂_m·(r − f)} e^{−jk ω_i·r} × the currents above for wave m (its own local frame and
Fresnel coefficients at its own local angle; V_i that of the beam axis), normalised by that beam's
Φ_i: a plane then reflects every plane wave of the beam exactly, where the footprint plane wave gives
every direction θ_i's Fresnel coefficients (docs/approx.md, po).

OpenCL kernels in kernels/physical_optics.cl (currents, per-pixel radiation) with host FFTs; NumPy
twins with ``ctx=None``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from wavebrdf.solver.approx.kirchhoff import (
    FootprintModel,
    KirchhoffSetup,
    albedo_excess,
    beam_geometry,
    chebyshev_cost,
    chebyshev_device_bytes,
    chebyshev_transform,
    chebyshev_transform_numpy,
    node_positions,
    transform_orders,
)
from wavebrdf.solver.approx.raytrace import SHADOWING, lit_nodes, node_slopes
from wavebrdf.solver.beams import INCIDENCE, BeamWaves, scene_beam, steering_fields
from wavebrdf.solver.farfield import FarField
from wavebrdf.solver.footprint import incident_basis
from wavebrdf.solver.fresnel import fresnel_rs_rp
from wavebrdf.solver.models import Capabilities, Estimate, SurfaceScene
from wavebrdf.solver.options import option
from wavebrdf.solver.precision import Precision
from wavebrdf.solver.validity import beam_incidence_remedy, check_lit_facets, check_waist

__all__ = [
    "POModel",
    "POOptions",
    "po_beam_currents_numpy",
    "po_currents_numpy",
    "po_farfield",
]

CHANNELS = 12  # 2 polarizations × (J'_x, J'_y, J'_z, M_x, M_y, M_z)
BEAM_SECONDS_PER_NODE_WAVE = 7e-8  # po_beam_currents on 2 cores (PoCL, double or single: 5.5–8.6e-8; docs/approx.md)


def _wave_currents_numpy(mt: np.ndarray, lit: np.ndarray, k_hat: np.ndarray, e: np.ndarray,
                         eta: complex) -> np.ndarray:
    """Twin of ``po_wave_currents``: (12, na, nb) currents J' = η₁J, M per unit dx dy at nodes of
    m̃ ``mt`` (na, nb, 3) from one plane wave of direction ``k_hat`` and polarization vectors ``e``
    (2, 3; complex for a beam's waves): the reflected field's where ``lit`` and −k̂·m > 0, else minus
    the incident field's."""
    m = mt / np.linalg.norm(mt, axis=-1, keepdims=True)
    c = -(m @ k_hat)
    s = np.cross(k_hat, m)
    s2 = np.sum(s * s, axis=-1)
    degenerate = s2 < 1e-24
    if np.any(degenerate):
        md = m[degenerate]
        a = np.where((np.abs(md[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
        s[degenerate] = np.cross(md, a)
        s2 = np.sum(s * s, axis=-1)
    s = s / np.sqrt(s2)[..., None]
    p_i = np.cross(s, k_hat)
    k_r = k_hat + 2.0 * c[..., None] * m
    p_r = np.cross(s, k_r)
    r_s, r_p = fresnel_rs_rp(eta, np.clip(c, 0.0, 1.0))
    on = (lit & (c > 0))[..., None]
    out = np.zeros((CHANNELS,) + mt.shape[:-1], dtype=complex)
    for p, ep in enumerate(e):
        E_r = (r_s * (s @ ep))[..., None] * s + (r_p * (p_i @ ep))[..., None] * p_r
        # lit: the reflected field's currents; unlit: minus the incident field's (module docstring)
        J = np.where(on, np.cross(mt, np.cross(k_r, E_r)), -np.cross(mt, np.cross(k_hat, ep)))
        M = np.where(on, -np.cross(mt, E_r), np.cross(mt, np.broadcast_to(ep, mt.shape)))
        out[6 * p : 6 * p + 6] = np.moveaxis(np.concatenate([J, M], axis=-1), -1, 0)
    return out


def _normal(slopes: np.ndarray) -> np.ndarray:
    """m̃ = (−h_x, −h_y, 1) on the nodes, (na, nb, 3)."""
    return np.stack([-slopes[0], -slopes[1], np.ones_like(slopes[0])], axis=-1)


def po_currents_numpy(window: np.ndarray, slopes: np.ndarray, lit: np.ndarray, omega_i: np.ndarray,
                      polarizations: np.ndarray, eta: complex) -> np.ndarray:
    """Twin of the kernel po_currents: (12, na, nb) apertures Δ²W·(J', M) per polarization, J' = η₁J
    (lit nodes: the reflected field's currents; unlit: minus the incident field's)."""
    k_hat = -np.asarray(omega_i, dtype=float)
    return _wave_currents_numpy(_normal(slopes), lit, k_hat, np.asarray(polarizations), eta) * window


def po_beam_currents_numpy(positions: np.ndarray, slopes: np.ndarray, lit: np.ndarray, waves: BeamWaves,
                           eta: complex, area: float) -> np.ndarray:
    """Twin of the kernel po_beam_currents: (12, na, nb) apertures Δ² Σ_m e^{j(φ_m − q_m·r)}
    (J', M)(k̂_m, E_m), each wave's currents at its own local angle."""
    mt = _normal(slopes)
    out = np.zeros((CHANNELS,) + slopes.shape[1:], dtype=complex)
    for k_hat, e, (qx, qy, qz, phi) in zip(waves.directions, waves.amplitudes, waves.phases):
        phase = area * np.exp(1j * (phi - positions @ np.array([qx, qy, qz])))
        out += _wave_currents_numpy(mt, lit, k_hat, e, eta) * phase
    return out


def _currents_opencl(ctx, window, slopes, lit, omega_i, polarizations, eta, precision: Precision):
    import pyopencl as cl

    real = precision.real
    cplx = np.dtype(np.complex128 if real == np.float64 else np.complex64)
    nodes = window.size
    knl = ctx.kernel("physical_optics.cl", "po_currents", ctx.defines(precision))
    out = cl.Buffer(ctx.context, cl.mem_flags.WRITE_ONLY, CHANNELS * nodes * cplx.itemsize)
    knl(ctx.queue, (nodes,), None, ctx.to_device(slopes, real), ctx.to_device(window, cplx),
        ctx.to_device(lit, np.uint8), np.int32(nodes), *(real.type(w) for w in omega_i),
        ctx.to_device(polarizations, real), np.array(eta, dtype=cplx), out)
    currents = np.empty((CHANNELS,) + window.shape, dtype=cplx)
    cl.enqueue_copy(ctx.queue, currents, out)
    return currents


def _beam_currents_opencl(ctx, positions, slopes, lit, waves: BeamWaves, eta, area: float, precision: Precision):
    import pyopencl as cl

    real = precision.real
    cplx = precision.complex
    nodes = lit.size
    knl = ctx.kernel("physical_optics.cl", "po_beam_currents", ctx.defines(precision))
    out = cl.Buffer(ctx.context, cl.mem_flags.WRITE_ONLY, CHANNELS * nodes * cplx.itemsize)
    knl(ctx.queue, (nodes,), None, ctx.to_device(beam_geometry(slopes, positions), real), ctx.to_device(lit, np.uint8),
        np.int32(nodes), np.int32(len(waves.directions)), ctx.to_device(waves.table(), real),
        ctx.to_device(waves.amplitudes, cplx), np.array(eta, dtype=cplx), real.type(area), out)
    currents = np.empty((CHANNELS,) + lit.shape, dtype=cplx)
    cl.enqueue_copy(ctx.queue, currents, out)
    return currents


def _radiate_numpy(setup: KirchhoffSetup, currents: np.ndarray) -> np.ndarray:
    """Twin of the transform + kernel po_farfield: E (2, 3, res, res)."""
    grid = setup.grid
    mu_o = grid.mu
    phase = 1j * setup.k / (4 * np.pi) * np.exp(1j * setup.k * (setup.mu_i + mu_o) * setup.dz_ref)
    I = np.stack(chebyshev_transform_numpy(setup, currents)) * phase
    o = np.moveaxis(grid.directions, -1, 0)  # (3, res, res)
    E = np.zeros((2, 3) + mu_o.shape, dtype=complex)
    for p in range(2):
        N, L = I[6 * p : 6 * p + 3], I[6 * p + 3 : 6 * p + 6]
        E[p] = o * np.sum(o * N, axis=0) - N + np.cross(o, L, axis=0)
    return np.where(grid.inside, E, 0.0)


def _radiate_opencl(ctx, setup: KirchhoffSetup, currents: np.ndarray, precision: Precision) -> np.ndarray:
    import pyopencl as cl

    real = precision.real
    cplx = np.dtype(np.complex128 if real == np.float64 else np.complex64)
    res = setup.grid.resolution
    acc, _ = chebyshev_transform(ctx, setup, currents, precision)
    plane = res * res * cplx.itemsize
    acc_all = cl.Buffer(ctx.context, cl.mem_flags.READ_WRITE, CHANNELS * plane)
    for c, buf in enumerate(acc):
        cl.enqueue_copy(ctx.queue, acc_all, buf, dst_offset=c * plane, byte_count=plane)
    knl = ctx.kernel("physical_optics.cl", "po_farfield", ctx.defines(precision))
    E_dev = cl.Buffer(ctx.context, cl.mem_flags.WRITE_ONLY, 6 * plane)
    knl(ctx.queue, (res * res,), None, acc_all, ctx.to_device(setup.czt_x.post, cplx),
        ctx.to_device(setup.czt_y.post, cplx), np.int32(res), real.type(setup.k), real.type(setup.mu_i),
        real.type(setup.dz_ref), E_dev)
    E = np.empty((2, 3, res, res), dtype=cplx)
    cl.enqueue_copy(ctx.queue, E, E_dev)
    ctx.queue.finish()
    return E.astype(np.complex128, copy=False)


def po_farfield(ctx, scene: SurfaceScene, shadowing: str = "rays", border: str = "periodic",
                incidence: str = "footprint") -> FarField:
    """Physical-optics far field of ``scene`` (``ctx`` None: NumPy twins, double precision);
    ``shadowing`` "rays" | "none" and ``border`` "periodic" | "clamp" choose V_i (module docstring);
    ``incidence`` "footprint" | "beam" the incident field (a plane-wave scene, waist None, is lit by
    its one plane wave either way)."""
    t0 = time.perf_counter()
    if incidence not in INCIDENCE:
        raise ValueError(f"po incidence must be one of {INCIDENCE}, got {incidence!r}")
    precision = scene.precision
    if ctx is None and not precision.fp64:
        raise ValueError(f"the NumPy reference runs in double precision only, got precision = {precision!r}")
    setup = KirchhoffSetup.from_scene(scene)
    if not setup.z_mid.any():  # a plane: e^{jkμ_o z} = 1, no expansion
        setup = setup.flattened(setup.window)
    surface, theta_i, phi_i = scene.surface, scene.theta_i, scene.phi_i
    omega_i, e_s, e_p = incident_basis(theta_i, phi_i)
    polarizations = np.stack([e_s, e_p])
    slopes = node_slopes(surface)
    front, lit, shadowing = lit_nodes(ctx, surface, omega_i, slopes, shadowing, border, precision)
    t_lit = time.perf_counter()
    beam = incidence == "beam" and scene.waist_um is not None
    power, extra = None, {}
    if beam:
        waves = BeamWaves.of(scene)
        positions, area = node_positions(setup, surface), surface.spacing_um ** 2
        if ctx is None:
            currents = po_beam_currents_numpy(positions, slopes, lit, waves, setup.eta, area)
        else:
            currents = _beam_currents_opencl(ctx, positions, slopes, lit, waves, setup.eta, area, precision)
        power, extra = waves.incident_power, {"plane_waves": len(waves.directions)}  # the full-wave solver's Φ_i
    elif ctx is None:
        currents = po_currents_numpy(setup.window, slopes, lit, omega_i, polarizations, setup.eta)
    else:
        currents = _currents_opencl(ctx, setup.window, slopes, lit, omega_i, polarizations, setup.eta, precision)
    t_currents = time.perf_counter()
    E = _radiate_numpy(setup, currents) if ctx is None else _radiate_opencl(ctx, setup, currents, precision)
    weight = np.abs(setup.window) ** 2
    total = weight.sum()
    ff = setup.farfield(
        E, theta_i, phi_i, model="po", incident_power=power, device="numpy" if ctx is None else ctx.describe(),
        precision=precision, shadowing=shadowing, back_facing_fraction=float(weight[~front].sum() / total),
        shadowed_fraction=float(weight[front & ~lit].sum() / total), time_visibility_s=t_lit - t0,
        incidence="beam" if beam else "footprint", time_currents_s=t_currents - t_lit,
        wall_time_s=time.perf_counter() - t0, **extra,
    )
    ff.diagnostics["albedo_excess"] = albedo_excess(ff)
    if not beam:  # the beam's plane waves each reflect at their own angle: no spread error to predict
        check_waist(scene, ff.diagnostics, "po", remedy=beam_incidence_remedy("po"))
    check_lit_facets(scene, ff, "po", lit)
    return ff


@dataclass(frozen=True)
class POOptions:
    shadowing: str = option("rays", choices=SHADOWING,
                            doc="V_i: 'rays' = ray-traced (raytrace.node_visibility) and back-facing test; "
                                "'none' = the local back-facing test ω_i·m > 0 only")
    border: str = option("periodic", choices=("periodic", "clamp"),
                         doc="height field beyond the patch for the ray-traced V_i (raytrace.py)")
    incidence: str = option("footprint", choices=INCIDENCE,
                            doc="incident field: 'footprint' = the footprint plane wave, Fresnel at θ_i's local "
                                "angle (the Kirchhoff family's); 'beam' = the full-wave solver's exact beam as "
                                "plane waves, each with Fresnel at its own local angle (exact on a plane; "
                                "docs/approx.md)")


class POModel(FootprintModel):
    """``[model] name = "po"``: vector physical optics, first order (approx.md §3.6)."""

    name = "po"
    summary = ("vector physical optics: tangent-plane currents on the lit surface, polarization-resolved with "
               "cross-polarization")
    sampling = frozenset({"lattice", "pixels", "realization"})
    Options = POOptions
    capabilities = Capabilities(takes="height_field", returns="fields", polarized=True, steerable=True,
                                reciprocal=False, conserves_energy=False, rung=8, single_scattering=True,
                                vector_fields=True)

    def run(self, ctx, scene: SurfaceScene) -> FarField:
        return po_farfield(ctx, scene, self.options.shadowing, self.options.border, self.options.incidence)

    def waist_remedy(self) -> str | None:
        return beam_incidence_remedy(self.name, self.options.incidence)

    def steered_fresnel(self) -> str | None:
        """Lit by the footprint, the currents take Fresnel at ω_i; lit by the beam, each plane wave
        reflects at its own angle."""
        return None if self.options.incidence == "beam" else "incidence"

    def incident_fields(self, scene: SurfaceScene, points):
        """The footprint plane wave, or with ``incidence = "beam"`` the full-wave solver's exact beam."""
        if self.options.incidence == "beam" and scene.waist_um is not None:
            return steering_fields(scene_beam(scene, "exact"), points)
        return super().incident_fields(scene, points)

    def estimate(self, scene: SurfaceScene) -> Estimate:
        nodes = scene.surface.cells + 1
        res = scene.grid.resolution
        orders = transform_orders(scene)
        memory, seconds = chebyshev_cost(nodes, res, orders, channels=CHANNELS)
        memory += 16.0 * (CHANNELS + 4) * nodes**2
        seconds += 2e-7 * nodes**2 if self.options.shadowing == "rays" else 0.0
        if self.options.incidence == "beam" and scene.waist_um is not None:
            waves = BeamWaves.count(scene)
            seconds += BEAM_SECONDS_PER_NODE_WAVE * nodes**2 * waves
            memory += 8.0 * 16 * waves
        held, largest = chebyshev_device_bytes(nodes, res, orders, channels=CHANNELS, precision=scene.precision)
        item = float(scene.precision.complex.itemsize)
        currents, planes = item * CHANNELS * nodes**2, item * CHANNELS * res * res  # one buffer each
        return Estimate(memory, seconds, f"{orders} Chebyshev orders × {CHANNELS} currents, {nodes}² nodes, "
                                         f"{res}² pixels", device_bytes=held + currents + planes,
                        largest_buffer_bytes=max(largest, currents, planes))
