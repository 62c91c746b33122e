"""Geometric-optics ray tracing of bilinear height fields (approx.md §3.1–3.2): the tracer behind
the ``gs``/``gm`` rungs, and the visibility and multiple-scattering API of the other rungs.

Surface: the bilinear interpolant of the (N+1)² node heights, traced exactly (kernels/
wb_heightfield.h: a 2-D DDA over the cells the ray's xy projection crosses, the exact quadratic
root of h(x(τ), y(τ)) = z(τ) in each cell, the bilinear normal (−h_x, −h_y, 1)/|…| at the hit).
``border``: "periodic" (period L, node N taken as node 0; use it for generated periodic surfaces,
the mismatch of a non-periodic one is reported as ``periodic_seam_um``) or "clamp" (the edge
heights extended outward: constant along the outward normal beyond an edge, the corner height
beyond a corner).

Estimator (equal-power rays, approx.md §3.1): R rays cross the reference plane z = z_ref (the
scene's ``z_reference``, else the surface mean) at points drawn with the footprint intensity
|W|² = exp(−2|x − c|²/w²) (w = ``scene.waist_um``, c = ``scene.footprint_centre_um``: the footprint
of every rung), travelling along −ω_i; each carries Φ_i/R. At each hit: Fresnel r_s, r_p of the
index n − jκ (kernels/wb_fresnel.h) at the local cosine, the Stokes vector rotated into the
facet's s/p frame and multiplied by the facet's Mueller matrix, specular reflection
ω_r = 2(ω_i·m)m − ω_i; refracted power leaves (``into_material``). A path ends when it escapes
(deposited in the projected-disk pixel of its direction), or when it hits the surface again after
``max_depth`` reflections (``truncated``: for ``gs``, max_depth = 1, that is the masked energy),
or at the per-segment step cap (``lost``, reported). Outputs are per *incident* polarization s|p
(Stokes (1, ±1, 0, 0) in the frame e_s ⟂ plane of incidence, p = e_s × k̂) and the detector is
polarization-insensitive. A pixel whose centre lies outside the unit disk sends its deposits to
the inside pixel nearest to its centre, so the albedo Σ f ΔuΔv is exactly the escaped energy.
Per pixel of area A_p = (2/res)²: I = P μ_o/A_p (IntensityResult), i.e. f = P/(Φ_i A_p).

Origins are a rank-1 lattice (the R2 sequence) Cranley–Patterson-shifted by a hash of ``seed``:
reproducible, independent of work-group sizes, and of lower noise than random points; two seeds
give independent estimates (the noise measure of benchmarks/bench_raytrace.py).

The hit geometry (per bounce: local cosine, frame rotation; per ray: exit pixel, depth) is kept
(:class:`PathGeometry`), so another index or wavelength reruns only the Fresnel/Mueller weights
(``path_weights``), never the trace. Two implementations of everything: OpenCL kernels
(kernels/raytrace.cl) and a vectorized NumPy twin (``ctx=None``; double precision) with the same
arithmetic, used in tests and benchmarks.

API for other rungs: :func:`trace_paths` (→ :class:`RayTrace`, the intensity split into depth 1
``single`` and depth ≥ 2 ``multiple``), :func:`node_visibility`, :func:`cell_visibility`,
:func:`surface_visibility`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
import scipy.special

from wavebrdf.solver.farfield import ETA0, HemisphereGrid, IntensityResult
from wavebrdf.solver.fresnel import fresnel_rs_rp
from wavebrdf.solver.precision import Precision
from wavebrdf.solver.surface import HeightField

__all__ = [
    "BORDERS",
    "GridSurface",
    "PathGeometry",
    "RayTrace",
    "cell_visibility",
    "lit_nodes",
    "node_slopes",
    "node_visibility",
    "origins",
    "pixel_remap",
    "surface_visibility",
    "trace_paths",
]

BORDERS = ("periodic", "clamp")
SHADOWING = ("rays", "none")  # V_i of the wave rungs: ray traced, or the back-facing test only
HIT, ESCAPE, LOST = 0, 1, 2  # hf_trace status (wb_heightfield.h)
TRUNCATED_CODE, LOST_CODE = -1, -2  # ray outcome codes besides an exit pixel (raytrace.cl)
BIG = 1e30  # HF_BIG
BATCH_RAYS = 1 << 20  # rays per kernel launch
BLOCK = 8  # cells per side of the blocks a ray above their highest node skips
SHADOW_SAMPLES = 1 << 16  # surface points of the shadowed-fraction estimate
KEEP_BYTES = 1 << 30  # kept geometry larger than this is not kept (the trace streams instead)
# the R2 sequence (rank-1 lattice of the plastic number g: steps 1/g, 1/g²) in 32-bit fixed point
_PLASTIC = 1.32471795724474602596
R2_STEPS = (int(round(2**32 / _PLASTIC)) & 0xFFFFFFFF, int(round(2**32 / _PLASTIC**2)) & 0xFFFFFFFF)
RECORD_BYTES = {np.dtype(np.float64): 3 * 8 + 4, np.dtype(np.float32): 3 * 4 + 4}
RAY_BYTES = 4 + 1 + 4  # per kept ray: accumulation bin and depth (host), chain head (device)


def _tiny(real: np.dtype) -> float:
    return 1e-12 if real == np.float64 else 1e-5  # RT_TINY


# ---------------------------------------------------------------------------------------------
# Geometry in grid units


@dataclass(frozen=True)
class GridSurface:
    """A height field in the tracer's grid units: x, y from the patch corner divided by the node
    spacing d (node i at X = i), heights (z − z_ref)/d."""

    z: np.ndarray  # (n+1, n+1) float64
    n: int
    periodic: bool
    zmax: float
    spacing_um: float
    size_um: float
    z_ref_um: float
    max_steps: int
    seam_um: float  # periodic border: max |z[N] − z[0]| over the two edges (0 for clamp)
    block: int  # cells per block side of the skip structure (1: none)
    block_max: np.ndarray  # (nb, nb) highest node of each block (grid units)

    @classmethod
    def build(cls, surface: HeightField, border: str = "periodic", z_reference: float | None = None) -> "GridSurface":
        if border not in BORDERS:
            raise ValueError(f"border = {border!r}: must be one of {', '.join(map(repr, BORDERS))}")
        d = surface.spacing_um
        z_ref = float(np.mean(surface.z)) if z_reference is None else float(z_reference)
        z = np.ascontiguousarray((surface.z - z_ref) / d, dtype=np.float64)
        n = surface.cells
        seam = 0.0
        if border == "periodic":
            seam = float(max(np.abs(surface.z[-1] - surface.z[0]).max(), np.abs(surface.z[:, -1] - surface.z[:, 0]).max()))
        # per segment: the longest path over the patch below z_max is a few patch widths at grazing
        max_steps = int(max(4096, 64 * n))
        block = BLOCK if n >= 2 * BLOCK else 1
        traced = z.copy()
        if border == "periodic":  # the traced surface: node N is node 0
            traced[n, :], traced[:, n] = traced[0, :], traced[:, 0]
        nb = -(-n // block)
        cell_max = np.full((nb * block, nb * block), -np.inf)  # highest corner of each cell
        cell_max[:n, :n] = np.maximum(np.maximum(traced[:-1, :-1], traced[1:, :-1]),
                                      np.maximum(traced[:-1, 1:], traced[1:, 1:]))
        block_max = cell_max.reshape(nb, block, nb, block).max(axis=(1, 3))
        return cls(z, n, border == "periodic", float(z.max()), d, surface.size_um, z_ref, max_steps, seam, block,
                   np.ascontiguousarray(block_max))

    def kernel_args(self, ctx, real) -> list:
        """The HF_SURFACE_ARGS of kernels/raytrace.cl."""
        return [ctx.to_device(self.z, real), ctx.to_device(self.block_max, real), np.int32(self.n),
                np.int32(self.periodic), np.int32(self.block), np.int32(self.block_max.shape[0]),
                np.int32(self.max_steps), real.type(self.zmax)]

    def to_grid(self, x_um, y_um) -> tuple[np.ndarray, np.ndarray]:
        """Patch coordinates (µm, centred) → grid units."""
        half = 0.5 * self.size_um
        return (np.asarray(x_um, float) + half) / self.spacing_um, (np.asarray(y_um, float) + half) / self.spacing_um


@lru_cache(maxsize=8)
def pixel_remap(resolution: int) -> np.ndarray:
    """Pixel index (i·res + j) → the pixel that receives its deposits: itself when its centre lies
    inside the unit disk, else the inside pixel whose centre is nearest to its centre."""
    from scipy.spatial import cKDTree

    grid = HemisphereGrid(resolution)
    U, V = grid.uv
    inside = grid.inside.ravel()
    centres = np.stack([U.ravel(), V.ravel()], axis=1)
    inside_index = np.flatnonzero(inside)
    remap = np.arange(resolution * resolution, dtype=np.int32)
    outside = np.flatnonzero(~inside)
    if outside.size:
        _, nearest = cKDTree(centres[inside_index]).query(centres[outside])
        remap[outside] = inside_index[nearest]
    remap.setflags(write=False)
    return remap


def _splitmix(x: int) -> int:
    x = (x + 0x9E3779B97F4A7C15) & 0xFFFFFFFFFFFFFFFF
    x = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) & 0xFFFFFFFFFFFFFFFF
    x = ((x ^ (x >> 27)) * 0x94D049BB133111EB) & 0xFFFFFFFFFFFFFFFF
    return x ^ (x >> 31)


def _shifts(seed: int) -> tuple[int, int]:
    """Cranley–Patterson shifts (32-bit) of the R2 lattice for ``seed``."""
    h = _splitmix(int(seed))
    return h & 0xFFFFFFFF, (h >> 32) & 0xFFFFFFFF


def _lattice(seed: int, first: int, count: int) -> tuple[np.ndarray, np.ndarray]:
    """(u1, u2) in (0, 1) of rays first … first+count−1 (exact 32-bit integer arithmetic)."""
    shift1, shift2 = _shifts(seed)
    index = np.arange(first, first + count, dtype=np.uint64) & 0xFFFFFFFF
    q1 = (shift1 + index * R2_STEPS[0]) & 0xFFFFFFFF
    q2 = (shift2 + index * R2_STEPS[1]) & 0xFFFFFFFF
    scale = 2.0**-32
    return (q1.astype(np.float64) + 0.5) * scale, (q2.astype(np.float64) + 0.5) * scale


def origins(seed: int, first: int, count: int, centre, sigma: float, extent: float) -> tuple[np.ndarray, np.ndarray]:
    """Ray origins (units of ``centre``/``sigma``/``extent``): density exp(−|x − c|²/(2σ²))
    (Box–Muller of the shifted R2 lattice; the footprint |W|² = exp(−2r²/w²) has σ = w/2), or
    uniform over [0, extent)² when σ = 0 (plane-wave illumination of the patch)."""
    u1, u2 = _lattice(seed, first, count)
    if sigma <= 0:
        return u1 * extent, u2 * extent
    r = sigma * np.sqrt(-2.0 * np.log(u1))
    phi = 2.0 * np.pi * u2
    return centre[0] + r * np.cos(phi), centre[1] + r * np.sin(phi)


def _gaussian_outside(size_um: float, centre, waist_um: float | None) -> float:
    """Fraction of the footprint intensity |W|² outside the patch (square of side size_um)."""
    if waist_um is None:
        return 0.0
    sigma = 0.5 * waist_um
    inside = 1.0
    for c in centre:
        lo, hi = (-0.5 * size_um - c) / (np.sqrt(2) * sigma), (0.5 * size_um - c) / (np.sqrt(2) * sigma)
        inside *= 0.5 * (scipy.special.erf(hi) - scipy.special.erf(lo))
    return float(max(0.0, 1.0 - inside))


@dataclass(frozen=True)
class TraceSetup:
    """Everything the trace kernel needs for one (surface, border, incidence, footprint, grid)."""

    surface: GridSurface
    omega_i: np.ndarray  # (3,) toward the light
    e_s: np.ndarray  # (3,) incident s vector
    centre: tuple[float, float]  # footprint centre, grid units
    sigma: float  # origin std per axis, grid units (w/2 / d); 0: uniform over the patch (no waist)
    resolution: int
    max_depth: int
    seed: int

    @classmethod
    def build(cls, scene, *, max_depth: int, border: str, seed: int) -> "TraceSetup":
        if not 0.0 <= scene.theta_i < 0.5 * np.pi:
            raise ValueError(f"incident theta must be in [0°, 90°), got {np.rad2deg(scene.theta_i):g}°")
        if scene.waist_um is not None and not (np.isfinite(scene.waist_um) and scene.waist_um > 0):
            raise ValueError(f"illumination.waist_um must be > 0 (or None: a plane wave), got {scene.waist_um!r}")
        if not 1 <= int(max_depth) <= 255:
            raise ValueError(f"max_depth = {max_depth!r}: must be in [1, 255]")
        gs = GridSurface.build(scene.surface, border, scene.z_reference)
        st, ct = np.sin(scene.theta_i), np.cos(scene.theta_i)
        omega = np.array([st * np.cos(scene.phi_i), st * np.sin(scene.phi_i), ct])
        e_s = np.array([-np.sin(scene.phi_i), np.cos(scene.phi_i), 0.0])
        cx, cy = gs.to_grid(*scene.footprint_centre_um)
        sigma = 0.0 if scene.waist_um is None else 0.5 * scene.waist_um / gs.spacing_um
        return cls(gs, omega, e_s, (float(cx), float(cy)), sigma, scene.grid.resolution, int(max_depth), int(seed))

    def start(self, first: int, count: int):
        """Start cells, positions and height of rays first … (where they cross z = z_max)."""
        gs = self.surface
        x0, y0 = origins(self.seed, first, count, self.centre, self.sigma, gs.n)
        lift = (gs.zmax - 0.0) / self.omega_i[2]
        (a, s), (b, t) = _locate(x0 + self.omega_i[0] * lift, gs), _locate(y0 + self.omega_i[1] * lift, gs)
        return a, b, s, t, np.full(count, gs.zmax)


# ---------------------------------------------------------------------------------------------
# NumPy twin of wb_heightfield.h and raytrace.cl


def _node(i: np.ndarray, gs: GridSurface) -> np.ndarray:
    return np.mod(i, gs.n) if gs.periodic else np.clip(i, 0, gs.n)


def _cell(gs: GridSurface, a: np.ndarray, b: np.ndarray):
    """hf_cell: bilinear coefficients (A, B, C, D) of cells (a, b)."""
    i0, i1, j0, j1 = _node(a, gs), _node(a + 1, gs), _node(b, gs), _node(b + 1, gs)
    z = gs.z
    c00, c10, c01, c11 = z[i0, j0], z[i1, j0], z[i0, j1], z[i1, j1]
    return c00, c10 - c00, c01 - c00, (c11 - c10) - (c01 - c00)


def _wrap(a: np.ndarray, gs: GridSurface) -> np.ndarray:
    return np.mod(a, gs.n) if gs.periodic else a


def _locate(x: np.ndarray, gs: GridSurface):
    """hf_locate: (cell, position in it) of grid coordinates x."""
    if gs.periodic:
        x = x - gs.n * np.floor(x / gs.n)
    f = np.floor(x)
    return _wrap(f.astype(np.int64), gs), np.clip(x - f, 0.0, 1.0)


def _surface_point(gs: GridSurface, x: np.ndarray, y: np.ndarray):
    """hf_surface_point: (a, b, s, t, z) of the surface above grid positions (x, y)."""
    (a, s), (b, t) = _locate(x, gs), _locate(y, gs)
    A, B, C, D = _cell(gs, a, b)
    return a, b, s, t, A + B * s + C * t + D * s * t


def _exit(x, size, w, iw):
    """hf_exit, vectorized."""
    return np.where(w > 0.0, (size - x) * iw, np.where(w < 0.0, -x * iw, BIG))


def _advance(x, size, c0, w, L, crossing):
    """hf_advance, vectorized: (cell, position)."""
    y = x + w * L
    c = np.clip(np.floor(y), 0.0, size - 1.0)
    s = np.where(crossing, np.where(w > 0.0, 0.0, 1.0), np.clip(y - c, 0.0, 1.0))
    cell = np.where(crossing, np.where(w > 0.0, c0 + size.astype(np.int64), c0 - 1), c0 + c.astype(np.int64))
    return cell, s


def _root(alpha, beta, gamma, L):
    """hf_root, vectorized."""
    with np.errstate(divide="ignore", invalid="ignore"):
        linear = -gamma / beta
        disc = np.maximum(beta * beta - 4.0 * alpha * gamma, 0.0)
        q = -0.5 * (beta + np.copysign(np.sqrt(disc), beta))
        r1 = q / alpha
        r2 = np.where(q != 0.0, gamma / q, r1)
        lo, hi = np.minimum(r1, r2), np.maximum(r1, r2)
        tau = np.where(alpha == 0.0, linear, np.where(lo > 0.0, lo, hi))
    return np.clip(tau, 0.0, L)


def _trace_numpy(gs: GridSurface, a, b, s, t, zr, wx, wy, wz, on_surface: bool, leaving: bool):
    """hf_trace over arrays of rays: status (HIT | ESCAPE | LOST) and, for hits, the hit point
    (a, b, s, t, z) and the gradient (hx, hy); the inputs are not modified."""
    m = a.size
    status = np.full(m, LOST, dtype=np.int8)
    out = [np.array(v, copy=True) for v in (a, b, s, t, zr)]
    hx, hy = np.zeros(m), np.zeros(m)
    ids = np.arange(m)
    a, b, s, t, zr = (np.array(v, copy=True) for v in (a, b, s, t, zr))
    wx, wy, wz = (np.broadcast_to(np.asarray(v, float), (m,)).copy() for v in (wx, wy, wz))
    with np.errstate(divide="ignore"):
        ix, iy = np.where(wx != 0.0, 1.0 / wx, 0.0), np.where(wy != 0.0, 1.0 / wy, 0.0)
    gamma = np.zeros(m)
    have = np.full(m, bool(on_surface))
    first = np.ones(m, dtype=bool)

    def keep(mask):
        nonlocal ids, a, b, s, t, zr, wx, wy, wz, ix, iy, gamma, have, first
        ids, a, b, s, t, zr, wx, wy, wz, ix, iy, gamma, have, first = (
            v[mask] for v in (ids, a, b, s, t, zr, wx, wy, wz, ix, iy, gamma, have, first))

    for _ in range(gs.max_steps):
        if ids.size == 0:
            break
        esc = (wz >= 0.0) & (zr >= gs.zmax)
        status[ids[esc]] = ESCAPE
        keep(~esc)
        if gs.block > 1:  # block skip
            kb, n = gs.block, gs.n
            inside = (a >= 0) & (a < n) & (b >= 0) & (b < n)
            ja, jb = np.where(inside, a // kb, 0), np.where(inside, b // kb, 0)
            top = gs.block_max[ja, jb]
            xa, yb = (a - ja * kb) + s, (b - jb * kb) + t
            sa, sb = np.minimum(kb, n - ja * kb).astype(float), np.minimum(kb, n - jb * kb).astype(float)
            bx, by = _exit(xa, sa, wx, ix), _exit(yb, sb, wy, iy)
            LB = np.minimum(bx, by)
            skip = inside & (zr > top) & (zr + wz * LB > top)
            if skip.any():
                na, ns = _advance(xa[skip], sa[skip], ja[skip] * kb, wx[skip], LB[skip], (bx <= by)[skip])
                nb_, nt = _advance(yb[skip], sb[skip], jb[skip] * kb, wy[skip], LB[skip], (by <= bx)[skip])
                a[skip], s[skip], b[skip], t[skip] = _wrap(na, gs), ns, _wrap(nb_, gs), nt
                zr[skip] = zr[skip] + wz[skip] * LB[skip]
                have[skip] = False
                first[skip] = False
            if skip.all():
                continue
            cell_step = ~skip
        else:
            cell_step = np.ones(ids.size, dtype=bool)
        A, B, C, D = _cell(gs, a, b)
        gamma = np.where(have | ~cell_step, gamma, zr - (A + B * s + C * t + D * s * t))
        have = have | cell_step
        one = np.ones(ids.size)
        lx, ly = _exit(s, one, wx, ix), _exit(t, one, wy, iy)
        if not gs.periodic:  # beyond an edge, moving away: no boundary along that axis
            lx = np.where(((a >= gs.n) & (wx >= 0.0)) | ((a < 0) & (wx <= 0.0)), BIG, lx)
            ly = np.where(((b >= gs.n) & (wy >= 0.0)) | ((b < 0) & (wy <= 0.0)), BIG, ly)
        L = np.minimum(lx, ly)
        beta = wz - (B + D * t) * wx - (C + D * s) * wy
        alpha = -D * wx * wy
        if leaving:
            beta = np.where(first, np.maximum(beta, 0.0), beta)
        gexit = gamma + L * (beta + L * alpha)
        at_zero = (gamma < 0.0) | ((gamma == 0.0) & ((beta < 0.0) | ((beta == 0.0) & (alpha < 0.0))))
        crossing = ~at_zero & (gexit < 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            tv = -beta / (2.0 * alpha)
            dip = (~at_zero & ~crossing & (alpha > 0.0) & (tv > 0.0) & (tv < L)
                   & (gamma + tv * (beta + tv * alpha) < 0.0))
        hit = cell_step & (L > 0.0) & (at_zero | crossing | dip)
        if hit.any():
            tau = np.where(at_zero, 0.0, _root(alpha, beta, gamma, L))[hit]
            sh = np.clip(s[hit] + wx[hit] * tau, 0.0, 1.0)
            th = np.clip(t[hit] + wy[hit] * tau, 0.0, 1.0)
            h_ids = ids[hit]
            status[h_ids] = HIT
            out[0][h_ids], out[1][h_ids], out[2][h_ids], out[3][h_ids] = a[hit], b[hit], sh, th
            out[4][h_ids] = A[hit] + B[hit] * sh + C[hit] * th + D[hit] * sh * th
            hx[h_ids] = B[hit] + D[hit] * th
            hy[h_ids] = C[hit] + D[hit] * sh
        c = cell_step & ~hit
        first[c] = False
        zr = np.where(c, zr + wz * L, zr)
        esc = c & (wz >= 0.0) & (zr >= gs.zmax)
        status[ids[esc]] = ESCAPE
        gamma = np.where(c, gexit, gamma)
        na, ns = _advance(s, one, a, wx, L, lx <= ly)
        nb_, nt = _advance(t, one, b, wy, L, ly <= lx)
        a, s = np.where(c, _wrap(na, gs), a), np.where(c, ns, s)
        b, t = np.where(c, _wrap(nb_, gs), b), np.where(c, nt, t)
        keep(~hit & ~esc)
    return status, out, hx, hy


def _pixels(wx, wy, res: int) -> np.ndarray:
    i = np.clip(np.floor((wx + 1.0) * 0.5 * res), 0, res - 1).astype(np.int64)
    j = np.clip(np.floor((wy + 1.0) * 0.5 * res), 0, res - 1).astype(np.int64)
    return pixel_remap(res)[i * res + j]


def _trace_batch_numpy(setup: TraceSetup, first: int, count: int) -> dict:
    """trace_paths of raytrace.cl over rays first … first+count−1: code, depth, head, rec, next
    (records allocated bounce by bounce in ray order)."""
    gs = setup.surface
    a, b, s, t, zr = setup.start(first, count)
    w = np.tile(-setup.omega_i, (count, 1))
    sv = np.tile(setup.e_s, (count, 1))
    code = np.full(count, LOST_CODE, dtype=np.int32)
    depth = np.zeros(count, dtype=np.uint8)
    head = np.full(count, -1, dtype=np.int32)
    recs, nexts, prev = [], [], np.full(count, -1, dtype=np.int64)
    ids = np.arange(count)
    n_rec, d = 0, 0
    tiny = _tiny(np.dtype(np.float64))
    while ids.size:
        status, (a, b, s, t, zr), hx, hy = _trace_numpy(gs, a, b, s, t, zr, w[:, 0], w[:, 1], w[:, 2], d > 0, d > 0)
        esc = status == ESCAPE
        code[ids[esc]] = _pixels(w[esc, 0], w[esc, 1], setup.resolution)
        hit = status == HIT
        if d == setup.max_depth:
            code[ids[hit]] = TRUNCATED_CODE
            break
        ids, a, b, s, t, zr, hx, hy, w, sv, prev = (v[hit] for v in (ids, a, b, s, t, zr, hx, hy, w, sv, prev))
        inv = 1.0 / np.sqrt(hx * hx + hy * hy + 1.0)
        m = np.stack([-hx * inv, -hy * inv, inv], axis=1)
        c = np.clip(-(w[:, 0] * m[:, 0] + w[:, 1] * m[:, 1] + w[:, 2] * m[:, 2]), 0.0, 1.0)
        f = np.stack([w[:, 1] * m[:, 2] - w[:, 2] * m[:, 1], w[:, 2] * m[:, 0] - w[:, 0] * m[:, 2],
                      w[:, 0] * m[:, 1] - w[:, 1] * m[:, 0]], axis=1)
        fn = np.sqrt(f[:, 0] * f[:, 0] + f[:, 1] * f[:, 1] + f[:, 2] * f[:, 2])
        ok = fn > tiny
        f = np.where(ok[:, None], f / np.where(ok, fn, 1.0)[:, None], sv)
        p = np.stack([sv[:, 1] * w[:, 2] - sv[:, 2] * w[:, 1], sv[:, 2] * w[:, 0] - sv[:, 0] * w[:, 2],
                      sv[:, 0] * w[:, 1] - sv[:, 1] * w[:, 0]], axis=1)
        cp = sv[:, 0] * f[:, 0] + sv[:, 1] * f[:, 1] + sv[:, 2] * f[:, 2]
        sp = p[:, 0] * f[:, 0] + p[:, 1] * f[:, 1] + p[:, 2] * f[:, 2]
        nn = cp * cp + sp * sp
        slots = n_rec + np.arange(ids.size)
        recs.append(np.stack([c, (cp * cp - sp * sp) / nn, 2.0 * sp * cp / nn], axis=1))
        nexts.append(np.full(ids.size, -1, dtype=np.int32))
        linked = prev >= 0
        if d > 0:
            nexts[-2][prev[linked] - (n_rec - nexts[-2].size)] = slots[linked]
        head[ids[~linked]] = slots[~linked]
        prev = slots
        n_rec += ids.size
        depth[ids] += 1
        d += 1
        w = w + 2.0 * c[:, None] * m
        w = w * (1.0 / np.sqrt(w[:, 0] * w[:, 0] + w[:, 1] * w[:, 1] + w[:, 2] * w[:, 2]))[:, None]
        fw = f[:, 0] * w[:, 0] + f[:, 1] * w[:, 1] + f[:, 2] * w[:, 2]
        f = f - fw[:, None] * w
        sv = f * (1.0 / np.sqrt(f[:, 0] * f[:, 0] + f[:, 1] * f[:, 1] + f[:, 2] * f[:, 2]))[:, None]
    rec = np.concatenate(recs).ravel() if recs else np.zeros(0)
    nxt = np.concatenate(nexts) if nexts else np.zeros(0, dtype=np.int32)
    return {"code": code, "depth": depth, "head": head, "rec": rec, "next": nxt}


def _weights_numpy(head: np.ndarray, rec: np.ndarray, nxt: np.ndarray, eta: complex) -> np.ndarray:
    """path_weights of raytrace.cl: (count, 2) final intensities for s and p incidence."""
    count = head.size
    stokes = np.zeros((2, 4, count))
    stokes[:, 0] = 1.0
    stokes[0, 1], stokes[1, 1] = 1.0, -1.0
    cur = head.astype(np.int64)
    act = np.flatnonzero(cur >= 0)
    while act.size:
        r = cur[act]
        c, c2, s2 = rec[3 * r], rec[3 * r + 1], rec[3 * r + 2]
        rs, rp = fresnel_rs_rp(eta, c)
        Rs, Rp = np.abs(rs) ** 2, np.abs(rp) ** 2
        x = rs * np.conj(rp)
        total, diff = 0.5 * (Rs + Rp), 0.5 * (Rs - Rp)
        for S in stokes:
            I, Q, U, V = S[0, act], S[1, act], S[2, act], S[3, act]
            q, u = c2 * Q + s2 * U, c2 * U - s2 * Q
            S[0, act] = total * I + diff * q
            S[1, act] = diff * I + total * q
            S[2, act] = x.real * u - x.imag * V
            S[3, act] = x.imag * u + x.real * V
        cur[act] = nxt[r]
        act = act[cur[act] >= 0]
    return np.stack([stokes[0, 0], stokes[1, 0]], axis=1)


# ---------------------------------------------------------------------------------------------
# OpenCL


def _kernel(ctx, name: str, precision: Precision):
    return ctx.kernel("raytrace.cl", name, ctx.defines(precision))


class _DeviceBatch:
    """A traced batch on the device: chain heads, records and links (kept for reweighting)."""

    def __init__(self, queue, head, rec, nxt, count: int, records: int, real):
        self.queue, self.head, self.rec, self.next = queue, head, rec, nxt
        self.count, self.records, self.real = count, records, real

    def host(self) -> dict:
        """head, rec, next copied to the host (tests, debugging)."""
        import pyopencl as cl

        queue = self.queue
        head = np.empty(self.count, np.int32)
        rec = np.empty(3 * max(self.records, 1), self.real)
        nxt = np.empty(max(self.records, 1), np.int32)
        for dst, src in ((head, self.head), (rec, self.rec), (nxt, self.next)):
            cl.enqueue_copy(queue, dst, src)
        return {"head": head, "rec": rec[: 3 * self.records].astype(np.float64), "next": nxt[: self.records]}


def _trace_batch_cl(ctx, setup: TraceSetup, first: int, count: int, capacity: int, precision: Precision):
    """trace_paths over rays first … first+count−1; reruns once with the exact record count if
    the records overflowed ``capacity``. Returns (code, depth, _DeviceBatch)."""
    import pyopencl as cl

    gs = setup.surface
    real = precision.real
    knl = _kernel(ctx, "trace_paths", precision)
    mf = cl.mem_flags
    surface_args = gs.kernel_args(ctx, real)
    remap_dev = ctx.to_device(pixel_remap(setup.resolution), np.int32)
    shift1, shift2 = _shifts(setup.seed)
    code_dev = cl.Buffer(ctx.context, mf.WRITE_ONLY, 4 * count)
    depth_dev = cl.Buffer(ctx.context, mf.WRITE_ONLY, count)
    head_dev = cl.Buffer(ctx.context, mf.READ_WRITE, 4 * count)
    counter = np.zeros(1, np.int32)
    for _ in range(2):
        capacity = max(int(capacity), 1)
        rec_dev = cl.Buffer(ctx.context, mf.READ_WRITE, 3 * capacity * real.itemsize)
        next_dev = cl.Buffer(ctx.context, mf.READ_WRITE, 4 * capacity)
        counter_dev = ctx.to_device(np.full(1, count, np.int32), writable=True)  # deeper records after slot count
        knl(ctx.queue, (count,), None, *surface_args, real.type(setup.centre[0]), real.type(setup.centre[1]), real.type(setup.sigma),
            real.type(0.0), np.uint32(shift1), np.uint32(shift2), np.uint32(R2_STEPS[0]), np.uint32(R2_STEPS[1]),
            np.uint32(first & 0xFFFFFFFF), *(real.type(v) for v in setup.omega_i), *(real.type(v) for v in setup.e_s),
            np.int32(setup.max_depth), np.int32(setup.resolution), remap_dev, np.int32(capacity), code_dev,
            depth_dev, head_dev, rec_dev, next_dev, counter_dev)
        cl.enqueue_copy(ctx.queue, counter, counter_dev)
        if counter[0] <= capacity:
            break
        capacity = int(counter[0])
    else:  # pragma: no cover - the rerun has the exact count
        raise RuntimeError("ray records overflowed twice")
    code = np.empty(count, np.int32)
    depth = np.empty(count, np.uint8)
    cl.enqueue_copy(ctx.queue, code, code_dev)
    cl.enqueue_copy(ctx.queue, depth, depth_dev)
    return code, depth, _DeviceBatch(ctx.queue, head_dev, rec_dev, next_dev, count, int(counter[0]), real)


def _weights_cl(ctx, batch: _DeviceBatch, eta: complex, precision: Precision) -> np.ndarray:
    import pyopencl as cl

    real = precision.real
    knl = _kernel(ctx, "path_weights", precision)
    out_dev = cl.Buffer(ctx.context, cl.mem_flags.WRITE_ONLY, 2 * batch.count * real.itemsize)
    knl(ctx.queue, (batch.count,), None, batch.head, batch.rec, batch.next, real.type(eta.real),
        real.type(eta.imag), out_dev)
    out = np.empty((batch.count, 2), real)
    cl.enqueue_copy(ctx.queue, out, out_dev)
    return out.astype(np.float64, copy=False)


# ---------------------------------------------------------------------------------------------
# Kept geometry, accumulation, results


@dataclass
class _Batch:
    """One traced batch: accumulation bins and depth per ray (host) and the records (device
    buffers, or NumPy arrays for the twin)."""

    bins: np.ndarray  # int32 per ray: pixel (+ res² for depth ≥ 2), 2res² truncated, 2res²+1 lost
    depth: np.ndarray  # uint8 per ray
    records: object  # _DeviceBatch | dict(head, rec, next)
    n_records: int

    def nbytes(self, real: np.dtype) -> int:
        return self.bins.size * RAY_BYTES + self.n_records * RECORD_BYTES[np.dtype(real)]


@dataclass
class PathGeometry:
    """The traced paths of one (surface, border, incidence, footprint, grid, rays, seed,
    max_depth, precision): everything but the Fresnel/Mueller weights. ``complete`` is False when
    it was not kept (larger than ``keep_bytes`` of :func:`trace_paths`); then it serves no
    reweighting."""

    setup: TraceSetup
    rays: int
    precision: Precision
    device: str
    batches: list = field(default_factory=list)
    shadowed_fraction: float = 0.0
    lost_rays: int = 0
    bounces: int = 0  # reflections of all rays
    trace_seconds: float = 0.0
    complete: bool = True

    @property
    def nbytes(self) -> int:
        real = self.precision.real
        return int(sum(b.nbytes(real) for b in self.batches))

    @property
    def mean_bounces(self) -> float:
        return self.bounces / max(self.rays, 1)

    def chains(self) -> list[dict]:
        """Per batch: head, rec (3 per record: c, cos 2ψ, sin 2ψ), next on the host."""
        return [b.records.host() if isinstance(b.records, _DeviceBatch) else b.records for b in self.batches]


class _Accumulator:
    """Sums the ray weights per bin (np.bincount: no atomics) and per depth."""

    def __init__(self, res: int, max_depth: int):
        self.res, self.max_depth = res, max_depth
        self.bins = np.zeros((2, 2 * res * res + 2))
        self.by_depth = np.zeros((2, max_depth + 1))
        self.weight_seconds = self.bin_seconds = 0.0

    def add(self, batch: "_Batch", weights: np.ndarray) -> None:
        t0 = time.perf_counter()
        n = self.bins.shape[1]
        escaped = batch.bins < 2 * self.res * self.res
        depth = batch.depth[escaped]
        for p in range(2):
            self.bins[p] += np.bincount(batch.bins, weights=weights[:, p], minlength=n)
            self.by_depth[p] += np.bincount(depth, weights=weights[escaped, p], minlength=self.max_depth + 1)
        self.bin_seconds += time.perf_counter() - t0


def _bins(code: np.ndarray, depth: np.ndarray, res: int) -> np.ndarray:
    pixels = res * res
    bins = np.where(code >= 0, code + pixels * (depth >= 2), np.where(code == TRUNCATED_CODE, 2 * pixels,
                                                                      2 * pixels + 1))
    return bins.astype(np.int32)


@dataclass
class RayTrace:
    """Result of :func:`trace_paths`: radiant intensity per incident polarization s|p (W/sr, the
    IntensityResult convention: I = P μ_o/A_p for the power P deposited in a pixel) split by path
    depth, the incident power Φ_i, and where the rest of the energy went (fractions of Φ_i, per
    polarization, shape (2,)).

    single     (2, res, res) paths with one reflection
    multiple   (2, res, res) paths with two or more (the GM⁺ term of Falster's WM)
    escaped_by_depth   (2, max_depth + 1) fraction of Φ_i leaving after d reflections
    truncated  still hitting the surface after max_depth reflections (GS: the masked energy)
    into_material      refracted or absorbed (1 − escaped − truncated − lost)
    lost       rays stopped by the per-segment step cap (should be 0)
    shadowed_fraction  footprint-weighted fraction of the surface not lit from ω_i

    Another rung adds a part to its own BRDF through the BRDF, each with its own Φ_i:
    ``result("multiple").brdf()`` is f_GM⁺ (sr⁻¹, NaN outside the disk).
    """

    grid: HemisphereGrid
    wavelength_um: float
    theta_i: float
    phi_i: float
    single: np.ndarray
    multiple: np.ndarray
    incident_power: np.ndarray
    escaped_by_depth: np.ndarray
    truncated: np.ndarray
    into_material: np.ndarray
    lost: np.ndarray
    shadowed_fraction: float
    diagnostics: dict = field(default_factory=dict)
    geometry: PathGeometry | None = None

    def intensity(self) -> np.ndarray:
        return self.single + self.multiple

    @property
    def escaped(self) -> np.ndarray:
        """Fraction of Φ_i leaving the surface (the albedo), per polarization."""
        return self.escaped_by_depth.sum(axis=1)

    def result(self, part: str = "all") -> IntensityResult:
        """An IntensityResult of ``part``: "all", "single" or "multiple"."""
        if part not in ("all", "single", "multiple"):
            raise ValueError(f"part must be 'all', 'single' or 'multiple', got {part!r}")
        intensity = {"all": self.single + self.multiple, "single": self.single, "multiple": self.multiple}[part]
        return IntensityResult(self.grid, self.wavelength_um, self.theta_i, self.phi_i, intensity,
                               self.incident_power.copy(), dict(self.diagnostics))


def _shadowed_fraction(ctx, setup: TraceSetup, rays: int, precision: Precision) -> float:
    """Fraction of footprint-weighted surface points (the first rays' origins) hidden from ω_i."""
    gs = setup.surface
    count = min(rays, SHADOW_SAMPLES)
    x, y = origins(setup.seed, 0, count, setup.centre, setup.sigma, gs.n)
    visible = _visibility(ctx, gs, np.stack([x, y], axis=1), setup.omega_i[None], precision)
    return float(1.0 - visible.mean())


def _check_geometry(geometry: PathGeometry, setup: TraceSetup, rays: int, precision: Precision) -> None:
    g = geometry.setup
    same = (g.resolution == setup.resolution and g.max_depth == setup.max_depth and g.seed == setup.seed
            and np.array_equal(g.omega_i, setup.omega_i) and g.centre == setup.centre and g.sigma == setup.sigma
            and g.surface.periodic == setup.surface.periodic and np.array_equal(g.surface.z, setup.surface.z)
            and geometry.rays == rays and geometry.precision == precision and geometry.complete)
    if not same:
        raise ValueError("the kept path geometry was traced for another surface, incidence, footprint, grid, "
                         "border, ray count, seed, depth or precision")


def trace_paths(ctx, scene, *, rays: int, max_depth: int, border: str = "periodic", seed: int = 0,
                geometry: PathGeometry | None = None, keep: bool = True, keep_bytes: int = KEEP_BYTES) -> RayTrace:
    """Geometric-optics paths of ``scene`` (a SurfaceScene; ``ctx`` None: the NumPy twin, double).

    ``rays`` equal-power rays, at most ``max_depth`` reflections (1: single scattering, GS),
    ``border`` "periodic" | "clamp", ``seed`` of the origin lattice. ``geometry``: a
    :class:`PathGeometry` kept from an earlier call with the same surface, incidence, footprint,
    grid, border, rays, seed and max_depth: only the Fresnel/Mueller weights of ``scene.index``
    are computed (no trace). ``keep``: keep the geometry in the result (``RayTrace.geometry``) when
    it fits ``keep_bytes``. ``scene.waist_um`` None: a plane wave, origins uniform over the patch.

    Φ_i = n₁/(2η₀) μ_i ∫|W|² dA (|E₀| = 1 V/µm as the wave rungs; L² for a plane wave).
    """
    t0 = time.perf_counter()
    rays = int(rays)
    if rays < 1:
        raise ValueError(f"rays = {rays!r}: must be >= 1")
    if np.imag(scene.index) > 0:
        raise ValueError(f"material index must be n - j*kappa with kappa >= 0, got {scene.index!r}")
    precision = scene.precision if ctx is not None else Precision.DOUBLE
    if ctx is None and not scene.precision.fp64:
        raise ValueError(f"the NumPy twin runs in double precision only, got precision = {scene.precision!r}")
    setup = TraceSetup.build(scene, max_depth=max_depth, border=border, seed=seed)
    res = setup.resolution
    eta = complex(scene.index) / scene.exterior_index
    acc = _Accumulator(res, setup.max_depth)
    reused = geometry is not None
    if reused:
        _check_geometry(geometry, setup, rays, precision)
        for batch in geometry.batches:
            acc.add(batch, _weigh(ctx, batch, eta, precision, acc))
    else:
        device = "numpy" if ctx is None else ctx.describe()
        geometry = PathGeometry(setup, rays, precision, device)
        mean_depth = 1.0 if setup.max_depth == 1 else 1.5
        t_trace = time.perf_counter()
        for first in range(0, rays, BATCH_RAYS):
            count = min(BATCH_RAYS, rays - first)
            if ctx is None:
                raw = _trace_batch_numpy(setup, first, count)
                code, depth = raw["code"], raw["depth"]
                records = {k: raw[k] for k in ("head", "rec", "next")}
                n_records = raw["next"].size
            else:
                capacity = count + int(np.ceil(count * min(setup.max_depth - 1, 1.25 * (mean_depth - 1)))) + 64
                code, depth, records = _trace_batch_cl(ctx, setup, first, count, capacity, precision)
                n_records = records.records
            mean_depth = max(n_records / count, 1.0)
            batch = _Batch(_bins(code, depth, res), depth, records, n_records)
            acc.add(batch, _weigh(ctx, batch, eta, precision, acc))
            if keep and geometry.complete:
                geometry.batches.append(batch)
                if geometry.nbytes > keep_bytes:
                    geometry.batches.clear()
                    geometry.complete = False
            geometry.lost_rays += int(np.count_nonzero(code == LOST_CODE))
            geometry.bounces += int(depth.sum(dtype=np.int64))
        geometry.shadowed_fraction = _shadowed_fraction(ctx, setup, rays, precision)
        geometry.trace_seconds = time.perf_counter() - t_trace - acc.weight_seconds - acc.bin_seconds
        if not keep:
            geometry.complete = False
    return _finish(scene, setup, geometry, acc, rays, reused, time.perf_counter() - t0)


def _weigh(ctx, batch: _Batch, eta: complex, precision: Precision, acc: _Accumulator) -> np.ndarray:
    """The final (s, p) weights of the batch's rays for ``eta`` (timed into ``acc``)."""
    t0 = time.perf_counter()
    if isinstance(batch.records, _DeviceBatch):
        weights = _weights_cl(ctx, batch.records, eta, precision)
    else:
        r = batch.records
        weights = _weights_numpy(r["head"], r["rec"], r["next"], eta)
    acc.weight_seconds += time.perf_counter() - t0
    return weights


def _finish(scene, setup: TraceSetup, geometry: PathGeometry, acc: _Accumulator, rays: int, reused: bool,
            wall: float) -> RayTrace:
    grid = scene.grid
    res = grid.resolution
    pixels = res * res
    area = setup.surface.size_um**2 if scene.waist_um is None else np.pi * scene.waist_um**2 / 2
    power = scene.exterior_index / (2 * ETA0) * np.cos(scene.theta_i) * area  # μ_i ∫|W|² dA, |E₀| = 1 V/µm
    scale = power / rays * grid.mu / grid.pixel_area  # I = P μ_o / A_p
    single = acc.bins[:, :pixels].reshape(2, res, res) * scale
    multiple = acc.bins[:, pixels : 2 * pixels].reshape(2, res, res) * scale
    truncated = acc.bins[:, 2 * pixels] / rays
    lost = acc.bins[:, 2 * pixels + 1] / rays
    by_depth = acc.by_depth / rays
    escaped = by_depth.sum(axis=1)
    into = 1.0 - escaped - truncated - lost
    gs = setup.surface
    outside = _gaussian_outside(gs.size_um, scene.footprint_centre_um, scene.waist_um)
    diagnostics = {
        "rays": rays,
        "max_depth": setup.max_depth,
        "border": "periodic" if gs.periodic else "clamp",
        "seed": setup.seed,
        "precision": geometry.precision,
        "device": geometry.device,
        "escaped_fraction": escaped.tolist(),
        "truncated_energy_fraction": truncated.tolist(),
        "into_material_fraction": into.tolist(),
        "lost_energy_fraction": lost.tolist(),
        "lost_rays": geometry.lost_rays,
        "multiple_fraction": by_depth[:, 2:].sum(axis=1).tolist(),
        "energy_by_depth": by_depth.mean(axis=0)[: min(setup.max_depth, 8) + 1].tolist(),
        "mean_bounces": geometry.mean_bounces,
        "shadowed_fraction": geometry.shadowed_fraction,
        "incident_outside_fraction": outside,
        "periodic_seam_um": gs.seam_um,
        "geometry_reused": reused,
        "geometry_kept": geometry.complete and bool(geometry.batches),
        "geometry_bytes": geometry.nbytes,
        "time_trace_s": 0.0 if reused else geometry.trace_seconds,
        "time_weights_s": acc.weight_seconds,
        "time_binning_s": acc.bin_seconds,
        "wall_time_s": wall,
    }
    return RayTrace(grid, scene.wavelength_um, scene.theta_i, scene.phi_i, single, multiple,
                    np.array([power, power]), by_depth, truncated, into, lost, geometry.shadowed_fraction,
                    diagnostics, geometry if geometry.complete and geometry.batches else None)


# ---------------------------------------------------------------------------------------------
# Visibility


def _directions(directions) -> np.ndarray:
    d = np.atleast_2d(np.asarray(directions, dtype=float))
    if d.ndim != 2 or d.shape[1] != 3:
        raise ValueError(f"directions must have shape (M, 3), got {np.shape(directions)}")
    norm = np.linalg.norm(d, axis=1)
    if not np.all(np.abs(norm - 1.0) < 1e-9):
        raise ValueError(f"directions must be unit vectors, got norms {norm[np.abs(norm - 1) >= 1e-9][:3]}")
    if np.any(d[:, 2] < 0):
        raise ValueError(f"directions must lie in the upper hemisphere (z >= 0), got z = {d[d[:, 2] < 0, 2][:3]}")
    return d


def _visibility(ctx, gs: GridSurface, points: np.ndarray, directions: np.ndarray, precision: Precision) -> np.ndarray:
    """(M, P) bool: the ray from the surface above each grid point toward each direction escapes."""
    m, npts = directions.shape[0], points.shape[0]
    if ctx is None:
        if not precision.fp64:
            raise ValueError(f"the NumPy twin runs in double precision only, got precision = {precision!r}")
        a, b, s, t, zr = _surface_point(gs, points[:, 0], points[:, 1])
        out = np.empty((m, npts), dtype=bool)
        for k, w in enumerate(directions):
            status, *_ = _trace_numpy(gs, a, b, s, t, zr, w[0], w[1], w[2], True, False)
            out[k] = status == ESCAPE
        return out
    import pyopencl as cl

    real = precision.real
    knl = _kernel(ctx, "visibility", precision)
    surface_args = gs.kernel_args(ctx, real)
    pts_dev = ctx.to_device(points, real)
    out = np.empty((m, npts), dtype=np.uint8)
    per_launch = max(1, (1 << 24) // max(npts, 1))
    for k0 in range(0, m, per_launch):
        k1 = min(m, k0 + per_launch)
        dirs_dev = ctx.to_device(directions[k0:k1], real)
        out_dev = cl.Buffer(ctx.context, cl.mem_flags.WRITE_ONLY, (k1 - k0) * npts)
        knl(ctx.queue, ((k1 - k0) * npts,), None, *surface_args, pts_dev, np.int32(npts), dirs_dev, out_dev)
        cl.enqueue_copy(ctx.queue, out[k0:k1], out_dev)
    return out.astype(bool)


def surface_visibility(ctx, surface: HeightField, points_um, directions, border: str = "periodic",
                       precision: Precision = Precision.DOUBLE) -> np.ndarray:
    """(M, P) bool: True where the ray from the surface point above ``points_um`` (P, 2) (patch
    coordinates, µm) toward the unit direction ``directions[m]`` ((M, 3), upper hemisphere)
    escapes the height field. A point whose local tangent plane faces away from the direction
    is not visible. ``ctx`` None: the NumPy twin."""
    gs = GridSurface.build(surface, border)
    pts = np.asarray(points_um, dtype=float).reshape(-1, 2)
    x, y = gs.to_grid(pts[:, 0], pts[:, 1])
    return _visibility(ctx, gs, np.stack([x, y], axis=1), _directions(directions), precision)


def node_visibility(ctx, surface: HeightField, directions, border: str = "periodic",
                    precision: Precision = Precision.DOUBLE) -> np.ndarray:
    """(M, N+1, N+1) bool: True where the ray from node (x_i, y_j, z_ij) toward the unit direction
    ``directions[m]`` ((M, 3), upper hemisphere) escapes the height field — V_i for ω_i, V_o for ω_o
    in the wave rungs with visibility (approx.md §3.4). Where the gradient of the bilinear surface
    jumps at a node, the cell the ray enters decides; a node facing away from the direction is not
    visible. ``border`` as in :func:`trace_paths` (periodic: node N is node 0). ``ctx`` None: the
    NumPy twin."""
    gs = GridSurface.build(surface, border)
    i = np.arange(gs.n + 1, dtype=float)
    X, Y = np.meshgrid(i, i, indexing="ij")
    vis = _visibility(ctx, gs, np.stack([X.ravel(), Y.ravel()], axis=1), _directions(directions), precision)
    return vis.reshape(-1, gs.n + 1, gs.n + 1)


def node_slopes(surface: HeightField) -> np.ndarray:
    """(h_x, h_y) at the nodes, shape (2, N+1, N+1): central differences, i.e. the mean of the
    gradients of the bilinear cells meeting at the node (one-sided on the patch border)."""
    d = surface.spacing_um
    return np.stack(np.gradient(surface.z, d, d, edge_order=1))


def lit_nodes(ctx, surface: HeightField, omega_i: np.ndarray, slopes: np.ndarray, shadowing: str,
              border: str = "periodic",
              precision: Precision = Precision.DOUBLE) -> tuple[np.ndarray, np.ndarray, str]:
    """(front, lit, how) node masks of the wave rungs' V_i (po, ws-v): front = ω_i·m̃ > 0; lit =
    front and, for ``shadowing = "rays"``, the ray from the node toward ω_i escapes
    (:func:`node_visibility`); ``how`` names the test."""
    if shadowing not in SHADOWING:
        raise ValueError(f"shadowing = {shadowing!r}: must be one of {SHADOWING}")
    front = omega_i[2] - omega_i[0] * slopes[0] - omega_i[1] * slopes[1] > 0
    if shadowing == "none":
        return front, front, "none"
    visible = node_visibility(ctx, surface, omega_i[None], border=border, precision=precision)[0]
    return front, front & visible, "rays"


def cell_visibility(ctx, surface: HeightField, directions, border: str = "periodic",
                    precision: Precision = Precision.DOUBLE) -> np.ndarray:
    """(M, N, N) bool: :func:`node_visibility` at the cell centres (x_i + d/2, y_j + d/2) on the
    bilinear surface (height = mean of the four corners)."""
    gs = GridSurface.build(surface, border)
    c = np.arange(gs.n, dtype=float) + 0.5
    X, Y = np.meshgrid(c, c, indexing="ij")
    vis = _visibility(ctx, gs, np.stack([X.ravel(), Y.ravel()], axis=1), _directions(directions), precision)
    return vis.reshape(-1, gs.n, gs.n)
