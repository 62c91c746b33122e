"""Far field of the solved surface currents by a direct quadrature sum (bem3d.md §9).

With F_J(r̂) = ∫ J e^{+jk₁ r̂·r'} dA' and F_M likewise (M = η₀M̃), the radiated field into the
exterior is E·e^{−jk₁r}/r, H·e^{−jk₁r}/r with (e^{+jωt}, ωμ₀ = η₀k₀, ωε₁ = k₀n₁²/η₀)::

    E = −(jη₀k₀/4π) [F_J − r̂(r̂·F_J)] + (jk₁/4π) r̂ × F_M
    H = −(jk₁/4π) r̂ × F_J − (jk₀n₁²/(4πη₀)) [F_M − r̂(r̂·F_M)]

(:func:`fields_from_integrals`, also used by the AIM far field of grid sources, aim/farfield.py).
The integrals are sums over tensor Gauss points of every element (``farfield_order``), computed
by the OpenCL kernel ``bem_radiation_integrals`` (kernels/bem_farfield.cl; NumPy twin
:func:`radiation_integrals_numpy`), one work-item per direction.
"""

from __future__ import annotations

import numpy as np

from wavebrdf.solver.bem3d.elements import launch_size
from wavebrdf.solver.bem3d.excitation import SurfaceRule, surface_currents
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import BEMMesh
from wavebrdf.solver.farfield import ETA0, FarField, HemisphereGrid
from wavebrdf.solver.precision import Precision

__all__ = [
    "farfield_on_grid",
    "fields_from_integrals",
    "radiated_fields",
    "radiated_power",
    "radiation_integrals_numpy",
    "radiation_integrals_opencl",
]

DIRECTION_CHUNK = 1 << 16


def radiation_integrals_numpy(directions, points, weights, k, chunk: int = 2048):
    """F[d, s, :] = Σ_q weights[q, s, :] e^{jk d·r_q}; shapes (M, 3), (Q, 3), (Q, S, 3) → (M, S, 3)."""
    directions = np.asarray(directions, dtype=float)
    weights = np.asarray(weights, dtype=complex)
    Q, S, _ = weights.shape
    flat = weights.reshape(Q, S * 3)
    out = np.empty((len(directions), S * 3), dtype=complex)
    for s in range(0, len(directions), chunk):
        phase = np.exp(1j * k * (directions[s : s + chunk] @ np.asarray(points, dtype=float).T))
        out[s : s + chunk] = phase @ flat
    return out.reshape(len(directions), S, 3)


def radiation_integrals_opencl(ctx, directions, points, weights, k):
    """OpenCL twin of :func:`radiation_integrals_numpy`."""
    import pyopencl as cl

    weights = np.ascontiguousarray(weights, dtype=np.complex128)
    Q, S, _ = weights.shape
    knl = ctx.kernel("bem_farfield.cl", "bem_radiation_integrals",
                     ctx.defines(Precision.DOUBLE, lanes=ctx.vector_lanes(Precision.DOUBLE), BEM_NSETS=S))
    pts = ctx.to_device(points, np.float64)
    wbuf = ctx.to_device(weights)
    directions = np.ascontiguousarray(directions, dtype=np.float64)
    out = np.empty((len(directions), S, 3), dtype=np.complex128)
    for s in range(0, len(directions), DIRECTION_CHUNK):
        d = directions[s : s + DIRECTION_CHUNK]
        dbuf = ctx.to_device(d)
        obuf = cl.Buffer(ctx.context, cl.mem_flags.WRITE_ONLY, len(d) * S * 3 * 16)
        knl(ctx.queue, *launch_size(ctx, len(d)), dbuf, np.int32(len(d)), pts, wbuf, np.int32(Q), np.float64(k), obuf)
        cl.enqueue_copy(ctx.queue, out[s : s + len(d)], obuf)
    ctx.queue.finish()
    return out


def radiated_fields(ctx, mesh: BEMMesh, media: Media, x: np.ndarray, directions: np.ndarray, rule: SurfaceRule):
    """E, H far-field amplitudes (e^{−jk₁r}/r removed) of solutions ``x`` (P, 2N_b) in ``directions``.

    Returns arrays of shape (P, M, 3). ``ctx`` None uses the NumPy twin.
    """
    x = np.atleast_2d(x)
    n_sol = x.shape[0]
    j, m = surface_currents(mesh, x, rule)  # (P, N², q, 3)
    w = rule.weights[None, None, :, None]
    sets = np.concatenate([j * w, ETA0 * m * w], axis=0)  # (2P, N², q, 3): J sets then M sets
    weights = np.moveaxis(sets.reshape(2 * n_sol, -1, 3), 0, 1)  # (Q, 2P, 3)
    points = rule.r.reshape(-1, 3)
    k1 = media.k0 * media.exterior_index
    if ctx is None:
        F = radiation_integrals_numpy(directions, points, weights, k1)
    else:
        F = radiation_integrals_opencl(ctx, directions, points, weights, k1)
    FJ = np.moveaxis(F[:, :n_sol], 1, 0)  # (P, M, 3)
    FM = np.moveaxis(F[:, n_sol:], 1, 0)
    return fields_from_integrals(media, np.asarray(directions, dtype=float)[None], FJ, FM)


def fields_from_integrals(media: Media, directions: np.ndarray, FJ: np.ndarray, FM: np.ndarray):
    """E, H (e^{−jk₁r}/r removed) from the radiation integrals F_J, F_M (M = η₀M̃) in ``directions``
    (the formulas of the module docstring); shapes (…, 3), broadcast."""
    rhat = np.asarray(directions, dtype=float)

    def transverse(F):
        return F - rhat * np.sum(rhat * F, axis=-1, keepdims=True)

    k0, n1 = media.k0, media.exterior_index
    k1 = k0 * n1
    c = 1.0 / (4.0 * np.pi)
    E = -1j * ETA0 * k0 * c * transverse(FJ) + 1j * k1 * c * np.cross(rhat, FM)
    H = -1j * k1 * c * np.cross(rhat, FJ) - 1j * k0 * n1**2 / ETA0 * c * transverse(FM)
    return E, H


def farfield_on_grid(ctx, mesh: BEMMesh, media: Media, x: np.ndarray, grid: HemisphereGrid, rule: SurfaceRule,
                     *, theta_i: float, phi_i: float, incident_power, diagnostics=None) -> FarField:
    """FarField (polarizations s, p = rows of ``x``) on the projected-hemisphere ``grid``."""
    inside = grid.inside
    dirs = grid.directions[inside]
    E_in, H_in = radiated_fields(ctx, mesh, media, x, dirs, rule)
    res = grid.resolution
    E = np.zeros((2, 3, res, res), dtype=complex)
    H = np.zeros((2, 3, res, res), dtype=complex)
    for p in range(2):
        E[p][:, inside] = E_in[p].T
        H[p][:, inside] = H_in[p].T
    return FarField(
        grid=grid, wavelength_um=media.wavelength_um, exterior_index=media.exterior_index,
        theta_i=float(theta_i), phi_i=float(phi_i), E=E, H=H, incident_power=incident_power,
        diagnostics=dict(diagnostics or {}),
    )


def radiated_power(ctx, mesh: BEMMesh, media: Media, x: np.ndarray, rule: SurfaceRule, *, mu_points: int = 96,
                   phi_points: int = 192) -> np.ndarray:
    """Power radiated into the upper hemisphere, ∫ |½Re(E × H*)| dω, per solution (shape (P,)).

    Gauss–Legendre in μ = cos θ_o ∈ (0, 1) and the trapezoid rule in φ (periodic, spectrally
    accurate): unlike a sum over projected-hemisphere pixels it has no 1/μ rim singularity, so it
    gives the albedo to quadrature accuracy whatever the output resolution.
    """
    mu, wmu = np.polynomial.legendre.leggauss(mu_points)
    mu, wmu = 0.5 * (mu + 1.0), 0.5 * wmu
    phi = 2 * np.pi * np.arange(phi_points) / phi_points
    MU, PHI = np.meshgrid(mu, phi, indexing="ij")
    st = np.sqrt(1 - MU**2)
    dirs = np.stack([st * np.cos(PHI), st * np.sin(PHI), MU], axis=-1).reshape(-1, 3)
    weights = (wmu[:, None] * np.full(phi_points, 2 * np.pi / phi_points)[None, :]).ravel()
    E, H = radiated_fields(ctx, mesh, media, x, dirs, rule)
    S = 0.5 * np.real(np.cross(E, np.conj(H)))
    return np.sum(np.linalg.norm(S, axis=-1) * weights, axis=-1)
