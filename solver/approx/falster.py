"""Falster et al. 2020: Kirchhoff with ray-traced shadowing and masking (``ws-v``, their
single-scattering term) and that term plus path-traced secondary bounces (``wm``; approx.md §3.4–3.5,
seed 002 Eqs. 17 and 19).

WS-V is the per-facet Kirchhoff form of approx.md §3.3 with Sancer's visibility flags (e^{+jωt}):

    I(ω_o) = Σ_nodes Δ² W V_i V_o a e^{+jk[s·x + (μ_i+μ_o) z]},   s = u_i + u_o,
    a = m̃·[(ω_i + ω_o) r(θ_l) + (ω_o − ω_i)]
      = (m̃·ω_i)(r − 1) + (m̃·ω_o)(r + 1),     m̃ = (−h_x, −h_y, 1),  cos θ_l = ω_i·m,
    f = |I|² / (4 μ_i μ_o λ₁² Δ² Σ W²),

per polarization (a scalar s pass with r_s(θ_l) and a p pass with r_p(θ_l); Fresnel at the local
angle, so the (ω_o − ω_i) term is not reciprocal). The r-free part m̃·(ω_o − ω_i) summed over every
node, unshadowed and unmasked, is subtracted: it equals (1/(jk(μ_i+μ_o))) ∫ (ω_o − ω_i)·∇W e^{jk…}
(by parts: m̃·(ω_o − ω_i) e^{jkφ} is a divergence), the footprint's own leak, which reflects from an
index-matched interface (1e-2 of Φ_i at 60°, w = 4 µm) and biases glass by ~1%; what remains of that
term is its shadow and mask boundaries. On a plane it is then Fresnel's mirror r (μ_i+μ_o)/(2√(μ_iμ_o)).
With m̃·ω_o = −h_x u_o − h_y v_o + μ_o the amplitude splits into four apertures that do not depend
on ω_o — (m̃·ω_i)(r − 1), −h_x(r + 1), −h_y(r + 1), (r + 1) — each transformed exactly onto the
pixels by the Kirchhoff family's Chebyshev/chirp-z transform (kirchhoff.chebyshev_transform) and
recombined per pixel with (1, u_o, v_o, μ_o). This is the deterministic grid sum: no Monte Carlo
|Σ|² bias (approx.md §3.4 caveat).

V_i is ray traced once per incidence (raytrace.node_visibility, back-facing nodes included).
V_o depends on the output direction: it is ray traced at ``masking_classes``² directions (the mean
directions of square blocks of output pixels) and each pixel takes its block's mask (approx.md
§3.4, "masking classes": the error sits at block borders). The masked far field is the unmasked
transform minus a direct sum over the lit nodes its class masks (kernels/falster.cl), exact for
the class mask and cheap where few nodes are masked.

Lit by the beam (``incidence = "beam"``): the scalar beam of
:meth:`~wavebrdf.solver.beams.BeamWaves.scalar_amplitudes` (the full-wave solver's exact beam,
each plane wave's |E_m| with the phase of its component along the beam's ê_s or ê_p), the four
apertures summed over its waves, Σ_m A_m Δ² e^{j(φ_m − q_m·r)} with ω_m for ω_i and r at wave m's
own local angle (a node lit by wave m where V_i, the axis's, and m̃·ω_m > 0; the r-free term
subtracted per wave), normalised by that beam's Φ_i: on a plane each wave reflects at its own angle.
WM's depth ≥ 2 part stays the path tracer's, its rays launched along the beam axis.

WM adds the incoherent depth ≥ 2 part of geometric-optics path tracing (raytrace.trace_paths,
``multiple``) to the WS-V BRDF, per incident polarization: f_WM = f_WS-V + f_GM⁺ (Falster Eq. 19).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from wavebrdf.solver.approx.geometric import RAYS_DEFAULT
from wavebrdf.solver.approx.kirchhoff import (
    KirchhoffSetup,
    albedo_excess,
    beam_geometry,
    chebyshev_cost,
    chebyshev_device_bytes,
    chebyshev_transform,
    chebyshev_transform_numpy,
    check_incidence,
    node_positions,
    transform_orders,
)
from wavebrdf.solver.approx.raytrace import BORDERS, lit_nodes, node_slopes, node_visibility, trace_paths
from wavebrdf.solver.beams import INCIDENCE, BeamWaves
from wavebrdf.solver.farfield import FarField, HemisphereGrid, IntensityResult, albedo, transverse_basis
from wavebrdf.solver.footprint import incident_basis
from wavebrdf.solver.fresnel import fresnel_rs_rp
from wavebrdf.solver.models import Capabilities, Estimate, Model, SurfaceScene
from wavebrdf.solver.options import option
from wavebrdf.solver.precision import Precision
from wavebrdf.solver.validity import beam_incidence_remedy, check_lit_facets, check_waist

__all__ = ["WMModel", "WMOptions", "WSVModel", "WSVOptions", "masking_blocks", "wsv_farfield"]

APERTURES = 4  # (m̃·ω_i)(r − 1), −h_x(r + 1), −h_y(r + 1), (r + 1): per polarization
WAVES_PER_PASS = 16  # plane waves of the beam summed per vectorised pass (_beam_apertures)
BEAM_SECONDS_PER_NODE_WAVE = 1e-7  # wsv_beam_sums on 2 cores (PoCL, double: 8e-8–1.2e-7; docs/approx.md)


@dataclass(frozen=True)
class WSVOptions:
    masking: str = option("rays", choices=("rays", "none"),
                          doc="V_o: 'rays' = ray traced per block of output directions; 'none' = every lit node "
                              "radiates into every direction (Kirchhoff with shadowing only)")
    masking_classes: int = option(16, low=1, high=512,
                                  doc="blocks of output pixels per axis; V_o is ray traced at each block's centre "
                                      "direction and shared by its pixels")
    border: str = option("periodic", choices=BORDERS,
                         doc="surface beyond the patch for the visibility rays (raytrace.py)")
    incidence: str = option("footprint", choices=INCIDENCE,
                            doc="incident field: 'footprint' = the footprint plane wave, Fresnel at θ_i's local "
                                "angle; 'beam' = the full-wave solver's exact beam as plane waves, each with "
                                "Fresnel at its own local angle (docs/approx.md)")


@dataclass(frozen=True)
class WMOptions(WSVOptions):
    """WS-V's options and the path tracer's for the depth ≥ 2 part."""

    rays: int = option(RAYS_DEFAULT, low=1, high=2**32 - 1, doc="equal-power rays of the depth ≥ 2 part (as gm)")
    max_depth: int = option(64, low=2, high=255, doc="reflections per path before it is truncated (reported)")
    seed: int = option(0, low=0, high=2**63 - 1, doc="seed of the ray-origin lattice")


def masking_blocks(grid: HemisphereGrid, classes: int) -> tuple[np.ndarray, np.ndarray]:
    """(block index per pixel (res, res), −1 outside the disk; unit direction per block (B, 3)):
    ``classes``² square blocks of pixels, each represented by the mean direction of its pixels
    inside the disk (blocks without such pixels are dropped)."""
    res = grid.resolution
    edges = np.linspace(0, res, min(classes, res) + 1).astype(int)
    which = np.searchsorted(edges, np.arange(res), side="right") - 1
    raw = which[:, None] * (len(edges) - 1) + which[None, :]
    raw = np.where(grid.inside, raw, -1)
    used, block = np.unique(raw[grid.inside], return_inverse=True)
    index = np.full((res, res), -1)
    index[grid.inside] = block
    U, V = grid.uv
    directions = np.empty((used.size, 3))
    for b in range(used.size):
        sel = index == b
        u, v = U[sel].mean(), V[sel].mean()
        rho = np.hypot(u, v)
        if rho >= 1.0:  # (cannot happen for a mean of points inside the disk; kept exact anyway)
            u, v = u / rho * (1 - 1e-9), v / rho * (1 - 1e-9)
        directions[b] = (u, v, np.sqrt(max(0.0, 1.0 - u * u - v * v)))
    return index, directions


def _apertures(setup: KirchhoffSetup, slopes: np.ndarray, lit: np.ndarray, omega_i: np.ndarray,
               leak: bool = True) -> np.ndarray:
    """The eight apertures (2 pol × 4) on the nodes, Δ² W included, shape (8, na, nb); with
    ``leak`` False, minus the r-free term m̃·(ω_o − ω_i) on every node (the footprint's leak)."""
    hx, hy = slopes
    m_dot_i = omega_i[2] - omega_i[0] * hx - omega_i[1] * hy  # m̃·ω_i
    cos_local = np.clip(m_dot_i / np.sqrt(1.0 + hx * hx + hy * hy), 0.0, 1.0)
    r = fresnel_rs_rp(setup.eta, cos_local)
    window = np.where(lit, setup.window, 0.0)
    all_nodes = 0.0 if leak else setup.window
    out = np.empty((2, APERTURES) + hx.shape, dtype=complex)
    for p in range(2):
        out[p, 0] = m_dot_i * (window * (r[p] - 1.0) + all_nodes)
        out[p, 1] = -hx * (window * (r[p] + 1.0) - all_nodes)
        out[p, 2] = -hy * (window * (r[p] + 1.0) - all_nodes)
        out[p, 3] = window * (r[p] + 1.0) - all_nodes
    return out.reshape(2 * APERTURES, *hx.shape)


def _beam_sums_numpy(setup: KirchhoffSetup, slopes: np.ndarray, lit: np.ndarray, waves: BeamWaves,
                     positions: np.ndarray, area: float) -> np.ndarray:
    """Twin of the kernel ``wsv_beam_sums`` (kernels/falster.cl): (2 pol, 4, na, nb) sums over the
    beam's waves — Σ_lit c_m w (ρ − 1), Σ_lit w (ρ + 1), Σ c_m w, Σ w — in chunks of
    :data:`WAVES_PER_PASS` waves."""
    hx, hy = slopes
    norm = np.sqrt(1.0 + hx * hx + hy * hy)
    unit_normal = np.stack([-hx, -hy, np.ones_like(hx)], axis=-1) / norm[..., None]
    amplitudes = waves.scalar_amplitudes()
    power = waves.power()
    out = np.zeros((2, 4) + hx.shape, dtype=complex)
    for start in range(0, len(waves.directions), WAVES_PER_PASS):
        chunk = slice(start, start + WAVES_PER_PASS)
        omega = -waves.directions[chunk]  # ω_m toward the light, (C, 3)
        m_dot = omega[:, 2] - hx[..., None] * omega[:, 0] - hy[..., None] * omega[:, 1]  # m̃·ω_m (na, nb, C)
        q, phi = waves.phases[chunk, :3], waves.phases[chunk, 3]
        phase = area * np.exp(1j * (phi - positions @ q.T))
        on = lit[..., None] & (m_dot > 0)
        r_s, r_p = fresnel_rs_rp(setup.eta, np.clip(m_dot / norm[..., None], 0.0, 1.0))
        s_local = np.cross(waves.directions[chunk], unit_normal[..., None, :])  # k̂_m × m (na, nb, C, 3)
        s_size = np.sum(s_local * s_local, axis=-1)
        for p, r in enumerate((r_s, r_p)):
            along_s = np.abs(np.einsum("...ck,ck->...c", s_local, waves.amplitudes[chunk, p])) ** 2
            scale = s_size * power[chunk, p]
            share_s = np.divide(along_s, scale, out=np.full_like(along_s, 0.5), where=(s_size > 1e-24) & (scale > 0))
            size = np.sqrt(share_s * np.abs(r_s) ** 2 + (1.0 - share_s) * np.abs(r_p) ** 2)
            magnitude = np.abs(r)
            reflection = size * np.divide(r, magnitude, out=np.ones_like(r), where=magnitude > 0)
            w = phase * amplitudes[chunk, p]
            lit_w = np.where(on, w, 0.0)
            out[p, 0] += np.sum(m_dot * lit_w * (reflection - 1.0), axis=-1)
            out[p, 1] += np.sum(lit_w * (reflection + 1.0), axis=-1)
            out[p, 2] += np.sum(m_dot * w, axis=-1)
            out[p, 3] += np.sum(w, axis=-1)
    return out


def _beam_sums_opencl(ctx, slopes: np.ndarray, lit: np.ndarray, waves: BeamWaves, positions: np.ndarray,
                      eta: complex, area: float, precision: Precision) -> np.ndarray:
    import pyopencl as cl

    real, cplx = precision.real, precision.complex
    nodes = lit.size
    knl = ctx.kernel("falster.cl", "wsv_beam_sums", ctx.defines(precision))
    out = cl.Buffer(ctx.context, cl.mem_flags.WRITE_ONLY, 8 * nodes * cplx.itemsize)
    knl(ctx.queue, (nodes,), None, ctx.to_device(beam_geometry(slopes, positions), real), ctx.to_device(lit, np.uint8),
        np.int32(nodes), np.int32(len(waves.directions)), ctx.to_device(waves.table(), real),
        ctx.to_device(waves.amplitudes, cplx), ctx.to_device(waves.scalar_amplitudes(), cplx),
        ctx.to_device(waves.power(), real), np.array(eta, dtype=cplx), real.type(area), out)
    sums = np.empty((2, 4) + lit.shape, dtype=cplx)
    cl.enqueue_copy(ctx.queue, sums, out)
    return sums.astype(complex)


def _beam_apertures(ctx, setup: KirchhoffSetup, slopes: np.ndarray, lit: np.ndarray, waves: BeamWaves,
                    positions: np.ndarray, area: float, precision: Precision) -> tuple[np.ndarray, np.ndarray]:
    """The eight apertures lit by the beam's plane waves (:class:`~wavebrdf.solver.beams.BeamWaves`,
    each its scalar amplitude A_m): Σ_m A_m Δ² e^{j(φ_m − q_m·r)} × the footprint's terms with ω_m
    for ω_i, a node lit by wave m where V_i (the beam axis's) and m̃·ω_m > 0. The reflection of
    wave m at a node is its local Fresnel reflectance for that wave's own polarization: of modulus
    √(w_s |r_s|² + (1 − w_s) |r_p|²), w_s = |E_m·ŝ|²/|E_m|² its share along the local ŝ = k̂_m × m
    (at normal local incidence ½), with the phase of the pass's r (r_s for s, r_p for p), so a plane
    reflects each wave's power exactly. Returns (with the leak, as :func:`_apertures`; without it:
    minus the r-free term m̃·(ω_o − ω_m) of every wave on every node), each (8, na, nb); ``ctx``
    None: the NumPy twin."""
    if ctx is None:
        sums = _beam_sums_numpy(setup, slopes, lit, waves, positions, area)
    else:
        sums = _beam_sums_opencl(ctx, slopes, lit, waves, positions, setup.eta, area, precision)
    hx, hy = slopes

    def assemble(zero_order: np.ndarray, first_order: np.ndarray) -> np.ndarray:
        out = np.stack([zero_order, -hx * first_order, -hy * first_order, first_order], axis=1)
        return out.reshape(2 * APERTURES, *hx.shape)

    lit0, lit1, free0, free1 = np.moveaxis(sums, 1, 0)
    return assemble(lit0, lit1), assemble(lit0 + free0, lit1 - free1)


def _transform(ctx, setup: KirchhoffSetup, windows: np.ndarray, precision: Precision) -> np.ndarray:
    """The transforms of ``windows`` on the pixels, chirp-z post factors and the reference-height
    phase applied, shape (channels, res, res)."""
    grid = setup.grid
    if ctx is None:
        out = np.stack(chebyshev_transform_numpy(setup, windows))
    else:
        import pyopencl as cl

        buffers, _ = chebyshev_transform(ctx, setup, windows, precision)
        res = grid.resolution
        cplx = precision.complex
        out = np.empty((len(buffers), res, res), dtype=cplx)
        for c, buf in enumerate(buffers):
            cl.enqueue_copy(ctx.queue, out[c].reshape(-1), buf)
        ctx.queue.finish()
        out = out.astype(complex) * (setup.czt_x.post[:, None] * setup.czt_y.post[None, :])[None]
    return out * np.exp(1j * setup.k * (setup.mu_i + grid.mu) * setup.dz_ref)[None]


def _masked_sums(ctx, setup: KirchhoffSetup, apertures: np.ndarray, block: np.ndarray, masked: list,
                 surface, omega_i: np.ndarray, precision: Precision) -> np.ndarray:
    """Σ over the nodes masked for each pixel's class of aperture × e^{+jk[s·x + (μ_i+μ_o) z]}
    (z about the mid-height), shape (8, res, res) (kernels/falster.cl; ``ctx`` None: NumPy)."""
    grid = setup.grid
    res = grid.resolution
    X, Y = np.meshgrid(surface.x, surface.y, indexing="ij")
    x, y, z = X.ravel(), Y.ravel(), setup.z_mid.ravel()
    ap = apertures.reshape(apertures.shape[0], -1)
    k, mu_i = setup.k, setup.mu_i
    if ctx is None:
        out = np.zeros((ap.shape[0], res, res), dtype=complex)
        U, V = grid.uv
        for c, nodes in enumerate(masked):
            pixels = np.flatnonzero((block == c).ravel())
            if not nodes.size or not pixels.size:
                continue
            u, v = U.ravel()[pixels], V.ravel()[pixels]
            mu_o = grid.mu.ravel()[pixels]
            phase = k * (np.outer(omega_i[0] + u, x[nodes]) + np.outer(omega_i[1] + v, y[nodes])
                         + np.outer(mu_i + mu_o, z[nodes]))
            out.reshape(ap.shape[0], -1)[:, pixels] = (np.exp(1j * phase) @ ap[:, nodes].T).T
        return out
    import pyopencl as cl

    real = precision.real
    cplx = np.dtype(np.complex128 if real == np.float64 else np.complex64)
    starts = np.concatenate([[0], np.cumsum([m.size for m in masked])]).astype(np.int32)
    nodes = np.concatenate(masked).astype(np.int32)
    out_dev = cl.Buffer(ctx.context, cl.mem_flags.WRITE_ONLY, ap.shape[0] * res * res * cplx.itemsize)
    knl = ctx.kernel("falster.cl", "wsv_masked_sum", ctx.defines(precision))
    to_device = ctx.to_device
    knl(ctx.queue, (res * res,), None, to_device(block.astype(np.int32).ravel(), np.int32),
        to_device(starts, np.int32), to_device(nodes, np.int32), to_device(x, real), to_device(y, real),
        to_device(z, real), to_device(ap, cplx), np.int32(res), np.int32(ap.shape[1]), real.type(k),
        real.type(omega_i[0]), real.type(omega_i[1]), real.type(mu_i), out_dev)
    out = np.empty((ap.shape[0], res, res), dtype=cplx)
    cl.enqueue_copy(ctx.queue, out, out_dev)
    ctx.queue.finish()
    return out.astype(complex)


def wsv_farfield(ctx, scene: SurfaceScene, masking: str = "rays", masking_classes: int = 16,
                 border: str = "periodic", incidence: str = "footprint", model: str = "ws-v") -> FarField:
    """WS-V far field of ``scene`` (module docstring); ``ctx`` None: NumPy twins (double);
    ``incidence`` "footprint" | "beam" the incident field (a plane-wave scene, waist None, is lit by
    its one plane wave either way); ``model`` the rung its warnings name ("ws-v", or "wm" for WM's
    single-scattering part)."""
    t0 = time.perf_counter()
    if incidence not in INCIDENCE:
        raise ValueError(f"{model} incidence must be one of {INCIDENCE}, got {incidence!r}")
    check_incidence(scene.theta_i, scene.index)
    precision = scene.precision
    if ctx is None and not precision.fp64:
        raise ValueError(f"the NumPy reference runs in double precision only, got precision = {precision!r}")
    setup = KirchhoffSetup.from_scene(scene)
    surface, grid = scene.surface, scene.grid
    flat = not setup.z_mid.any()
    if flat:  # a plane: e^{jkμ_o z} = 1 and nothing shadows or masks
        setup = setup.flattened(setup.window)
    omega_i, _, _ = incident_basis(scene.theta_i, scene.phi_i)
    slopes = node_slopes(surface)
    front, lit, _ = lit_nodes(ctx, surface, omega_i, slopes, "none" if flat else "rays", border, precision)
    t_vis = time.perf_counter()
    beam = incidence == "beam" and scene.waist_um is not None
    power, extra = None, {}
    if beam:
        waves = BeamWaves.of(scene)
        apertures, radiating = _beam_apertures(ctx, setup, slopes, lit, waves, node_positions(setup, surface),
                                               surface.spacing_um ** 2, precision)
        power, extra = waves.incident_power, {"plane_waves": len(waves.directions)}  # the full-wave solver's Φ_i
    else:
        apertures, radiating = _apertures(setup, slopes, lit, omega_i), _apertures(setup, slopes, lit, omega_i, False)
    t_apertures = time.perf_counter()

    weight = np.abs(setup.window) ** 2
    total = weight.sum()
    # nodes that radiate at all (the beam's field, cut at the light cone, reaches beyond the footprint)
    strength = np.abs(apertures).max(axis=0) ** 2 if beam else weight
    relevant = lit & (strength > 1e-12 * strength.max())
    block, directions = masking_blocks(grid, masking_classes)
    if masking == "none" or flat:
        masked = [np.zeros(0, dtype=np.int32) for _ in directions]
    else:
        visible = node_visibility(ctx, surface, directions, border=border, precision=precision)
        masked = [np.flatnonzero((relevant & ~v).ravel()).astype(np.int32) for v in visible]
    t_mask = time.perf_counter()

    channels = _transform(ctx, setup, radiating, precision)
    if any(m.size for m in masked):
        correction = _masked_sums(ctx, setup, apertures, block, masked, surface, omega_i, precision)
        channels = channels - correction * np.exp(1j * setup.k * (setup.mu_i + grid.mu) * setup.dz_ref)[None]
    masked_weight = np.array([weight.ravel()[m].sum() / total for m in masked])
    t_transform = time.perf_counter()

    res = grid.resolution
    U, V = grid.uv
    inside = grid.inside
    mu_o = np.where(inside, grid.mu, 1.0)
    ch = channels.reshape(2, APERTURES, res, res)
    I = ch[:, 0] + U * ch[:, 1] + V * ch[:, 2] + mu_o * ch[:, 3]  # (2 pol, res, res)
    amp = np.where(inside, I * 0.5 / setup.lambda1, 0.0)  # √(μ_i μ_o Ω) with Ω = 1/(4 μ_i μ_o)
    theta_hat, phi_hat = transverse_basis(U, V)
    E = np.empty((2, 3, res, res), dtype=complex)
    E[0] = np.moveaxis(phi_hat, -1, 0) * amp[0][None]
    E[1] = np.moveaxis(theta_hat, -1, 0) * amp[1][None]
    ff = setup.farfield(
        E, scene.theta_i, scene.phi_i, model="ws-v", incident_power=power,
        device="numpy" if ctx is None else ctx.describe(),
        precision=precision, back_facing_fraction=float(weight[~front].sum() / total),
        shadowed_fraction=float(weight[front & ~lit].sum() / total),
        masking_blocks=len(directions), masked_nodes=int(sum(m.size for m in masked)),
        masked_fraction_max=float(masked_weight.max()) if masked_weight.size else 0.0,
        time_visibility_s=t_vis - t0, time_apertures_s=t_apertures - t_vis, time_masking_s=t_mask - t_apertures,
        time_transform_s=t_transform - t_mask,
        wall_time_s=time.perf_counter() - t0, incidence="beam" if beam else "footprint", **extra,
    )
    ff.diagnostics["albedo_excess"] = albedo_excess(ff)
    if not beam:  # the beam's plane waves each reflect at their own angle: no spread error to predict
        check_waist(scene, ff.diagnostics, model, remedy=beam_incidence_remedy(model))
    check_lit_facets(scene, ff, model, lit, masking=masking != "none" and not flat)
    return ff


def _wsv_estimate(scene: SurfaceScene, options) -> Estimate:
    nodes = scene.surface.cells + 1
    res = scene.grid.resolution
    orders = transform_orders(scene)
    flat = not np.ptp(scene.surface.z) > 0
    blocks = min(options.masking_classes, res) ** 2
    memory, seconds = chebyshev_cost(nodes, res, orders, channels=2 * APERTURES)
    memory += 16.0 * (4 * 2 * APERTURES) * max(nodes**2, res * res)
    rays = 0 if flat else (1 + (blocks if options.masking == "rays" else 0)) * nodes**2
    # masked-node sums: a share of the nodes ~ the rms slope is masked toward the rim directions
    share = 0.0 if (flat or options.masking == "none") else min(1.0, 0.5 * scene.surface.statistics()["rms_slope"])
    terms = share * nodes**2 * res * res
    seconds += 5e-7 * rays + 2e-8 * terms
    if options.incidence == "beam" and scene.waist_um is not None:
        seconds += BEAM_SECONDS_PER_NODE_WAVE * nodes**2 * BeamWaves.count(scene)
    held, largest = chebyshev_device_bytes(nodes, res, orders, channels=2 * APERTURES, precision=scene.precision)
    item = float(scene.precision.complex.itemsize)
    masked = item * 2 * APERTURES * max(nodes**2, res * res)  # the apertures, the masked sums: one buffer each
    return Estimate(memory, seconds, f"{orders} Chebyshev orders × 8 apertures, {rays:.3g} visibility rays, "
                                     f"~{terms:.3g} masked-node terms", device_bytes=held + 2 * masked,
                    largest_buffer_bytes=max(largest, masked))


class WSVModel(Model):
    """``[model] name = "ws-v"``: Falster's single-scattering term (Kirchhoff + ray-traced V_i V_o)."""

    name = "ws-v"
    summary = "Falster et al. 2020: Kirchhoff with ray-traced shadowing and masking (single scattering)"
    sampling = frozenset({"lattice", "pixels", "realization"})
    Options = WSVOptions
    capabilities = Capabilities(takes="height_field", returns="fields", polarized=True, steerable=False,
                                reciprocal=False, conserves_energy=False, rung=6, single_scattering=True)

    def run(self, ctx, scene: SurfaceScene) -> FarField:
        o = self.options
        return wsv_farfield(ctx, scene, o.masking, o.masking_classes, o.border, o.incidence)

    def waist_remedy(self) -> str | None:
        return beam_incidence_remedy(self.name, self.options.incidence)

    def estimate(self, scene: SurfaceScene) -> Estimate:
        return _wsv_estimate(scene, self.options)


class WMModel(Model):
    """``[model] name = "wm"``: WS-V plus the path-traced depth ≥ 2 part (Falster Eq. 19), an
    incoherent sum: intensity only."""

    name = "wm"
    summary = "Falster et al. 2020: ws-v plus path-traced secondary bounces (intensity only)"
    sampling = frozenset({"lattice", "pixels", "realization"})
    Options = WMOptions
    capabilities = Capabilities(takes="height_field", returns="intensity", polarized=True, steerable=False,
                                reciprocal=False, conserves_energy=False, rung=7)

    def waist_remedy(self) -> str | None:  # its single-scattering part (ws-v's) warns as wm
        return beam_incidence_remedy(self.name, self.options.incidence)

    def run(self, ctx, scene: SurfaceScene) -> IntensityResult:
        o = self.options
        single = wsv_farfield(ctx, scene, o.masking, o.masking_classes, o.border, o.incidence, model=self.name)
        trace = trace_paths(ctx, scene, rays=o.rays, max_depth=o.max_depth, border=o.border, seed=o.seed, keep=False)
        grid = scene.grid
        f_single, f_multiple = single.brdf(), trace.result("multiple").brdf()
        brdf = np.nan_to_num(f_single) + np.nan_to_num(f_multiple)
        power = single.incident_power
        intensity = np.where(grid.inside, brdf * power[:, None, None] * grid.mu, 0.0)
        diagnostics = {k: v for k, v in single.diagnostics.items() if k != "model"}
        diagnostics.update(
            model=self.name,
            single_albedo=albedo(f_single, grid).tolist(),
            multiple_albedo=albedo(f_multiple, grid).tolist(),
            truncated_energy_fraction=trace.truncated.tolist(),
            rays=o.rays,
        )
        result = IntensityResult(grid, scene.wavelength_um, scene.theta_i, scene.phi_i, intensity, power, diagnostics)
        result.diagnostics["albedo_excess"] = albedo_excess(result)
        return result

    def estimate(self, scene: SurfaceScene) -> Estimate:
        from wavebrdf.solver.approx.geometric import GMModel

        wsv = _wsv_estimate(scene, self.options)
        gm = GMModel({k: getattr(self.options, k) for k in ("rays", "max_depth", "border", "seed")}).estimate(scene)
        return Estimate(max(wsv.memory_bytes, gm.memory_bytes), wsv.seconds + gm.seconds,
                        f"{wsv.detail}; {gm.detail}", device_bytes=max(wsv.device_bytes, gm.device_bytes),
                        largest_buffer_bytes=max(wsv.largest_buffer_bytes, gm.largest_buffer_bytes))
