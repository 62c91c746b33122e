"""The geometric-optics tracer (solver/approx/raytrace.py, kernels/raytrace.cl) against analytic
references: V-grooves (bounce counts, per-order energies, exit directions and polarization from an
independent 2-D unfolding + vector Jones calculation), a tilted plane, the lit fraction of grooves
at grazing incidence, energy conservation on a perfect conductor, scale invariance; the NumPy twin
against the kernels on the same rays; reweighting a kept geometry against a fresh trace.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest

from references import fresnel_coefficients
from wavebrdf.solver.approx import raytrace as rt
from wavebrdf.solver.farfield import HemisphereGrid, albedo
from wavebrdf.solver.models import SurfaceScene
from wavebrdf.solver.precision import Precision
from wavebrdf.solver.surface import HeightField, generate

logger = logging.getLogger(__name__)

DEG = np.pi / 180
GLASS = 1.5
ALUMINIUM = 0.46582 - 4.7119j
PEC = 1e-3 - 1e7j  # |r|² = 1 − O(1e-7)


def scene(surface, index=GLASS, theta_deg=0.0, phi_deg=0.0, waist=None, res=64, **kw) -> SurfaceScene:
    """waist None: a plane wave (ray origins uniform over the periodic patch)."""
    return SurfaceScene(surface, 0.5, complex(index), theta_deg * DEG, phi_deg * DEG, waist, HemisphereGrid(res), **kw)


# ---------------------------------------------------------------------------------------------
# V-grooves: 2-D unfolding (Xie & Hanrahan 2018) and explicit vector Jones fields


def v_grooves(alpha_deg: float, periods: int = 4, half: int = 8, depth_um: float = 1.0) -> HeightField:
    """Symmetric grooves along y: z = tan α |x − x_c| in each period (2·half cells), ridges and
    vertices on nodes, so the bilinear surface is exactly the V profile; periodic on the patch."""
    tan_a = np.tan(alpha_deg * DEG)
    d = depth_um / tan_a / half
    n = 2 * half * periods
    i = np.arange(n + 1)
    profile = tan_a * d * np.abs(np.mod(i, 2 * half) - half)
    return HeightField(np.repeat(profile[:, None], n + 1, axis=1), n * d)


def reflect(k, n):
    return k - 2.0 * np.dot(k, n) * n


def groove_reference(alpha_deg: float, omega_i: np.ndarray, index: complex, max_bounces: int = 16):
    """Per bounce count: the fraction of rays (entry points uniform across the groove opening),
    the exit direction and the reflected intensity for incident s and p (unit intensity), from the
    unfolded wedge fan (facets at ±β from the vertical, images at (2j+1)β) and explicit fields
    E_r = r_s E_s ŝ + r_p E_p p̂_r, ŝ = k̂×m/|·|, p̂ = ŝ×k̂ (approx.md §1), r from tests/references.py."""
    beta = (90.0 - alpha_deg) * DEG
    ell = 1.0
    H, W = ell * np.cos(beta), 2 * ell * np.sin(beta)
    k3 = -np.asarray(omega_i, float)  # propagation
    kxz = np.array([k3[0], k3[2]]) / np.hypot(k3[0], k3[2])  # 2-D (x, z) unfolding direction
    # critical entry positions: lines through the apex and the fan vertices (radius ℓ, angles (2j+1)β)
    crit = [-W / 2, W / 2, H * kxz[0] / kxz[1]]
    for j in range(-max_bounces - 1, max_bounces + 1):
        ang = (2 * j + 1) * beta
        if abs(ang) >= np.pi:
            continue
        px, pz = ell * np.sin(ang), ell * np.cos(ang)
        crit.append(px + (H - pz) * kxz[0] / kxz[1])
    crit = np.unique(np.clip(crit, -W / 2, W / 2))
    normals = {+1: np.array([-np.cos(beta), 0.0, np.sin(beta)]), -1: np.array([np.cos(beta), 0.0, np.sin(beta)])}
    out: dict[int, dict] = {}
    for lo, hi in zip(crit[:-1], crit[1:]):
        if hi - lo < 1e-14:
            continue
        xe = 0.5 * (lo + hi)
        p = np.array([xe, H])
        sweep = np.sign(p[1] * kxz[0] - p[0] * kxz[1])  # sign of dψ/dτ, ψ from +z toward +x
        hits = []
        for j in range(max_bounces + 1):
            ang = sweep * (2 * j + 1) * beta
            u = np.array([np.sin(ang), np.cos(ang)])
            # p + τ k = r u  →  (τ, r) by Cramer's rule; parallel: never crossed
            det = -kxz[0] * u[1] + kxz[1] * u[0]
            if abs(det) < 1e-14:
                break
            tau, r = (p[0] * u[1] - p[1] * u[0]) / det, (kxz[1] * p[0] - kxz[0] * p[1]) / det
            if tau <= 0 or r <= 0 or r >= ell:
                break
            hits.append(+1 if (j % 2 == 0) == (sweep > 0) else -1)  # facet side: right (+1), left (−1)
        # real-space path with explicit fields, for incident s and p
        e_s = np.array([-np.sin(np.arctan2(omega_i[1], omega_i[0])), np.cos(np.arctan2(omega_i[1], omega_i[0])), 0.0])
        fields = [e_s.astype(complex), np.cross(e_s, k3).astype(complex)]
        k = k3.copy()
        for side in hits:
            m = normals[side]
            c = -np.dot(k, m)
            s_hat = np.cross(k, m)
            s_hat /= np.linalg.norm(s_hat)
            k_r = reflect(k, m)
            p_i, p_r = np.cross(s_hat, k), np.cross(s_hat, k_r)
            r_s, r_p = fresnel_coefficients(1.0, index, np.arccos(np.clip(c, -1, 1)))
            fields = [r_s * np.dot(E, s_hat) * s_hat + r_p * np.dot(E, p_i) * p_r for E in fields]
            k = k_r
        entry = out.setdefault(len(hits), {"fraction": 0.0, "energy": np.zeros(2), "direction": k})
        w = (hi - lo) / W
        entry["fraction"] += w
        entry["energy"] += w * np.array([np.vdot(E, E).real for E in fields])
    return out


@pytest.mark.parametrize("alpha_deg,theta_deg,phi_deg,index", [
    (60.0, 0.0, 0.0, GLASS), (60.0, 35.0, 0.0, ALUMINIUM), (70.0, 20.0, 30.0, ALUMINIUM), (45.0, 50.0, 60.0, GLASS)])
def test_v_grooves_bounce_orders(cl_ctx, alpha_deg, theta_deg, phi_deg, index):
    """Per bounce order: energy (s and p, with the polarization rotated at every facet) and the
    exit direction (its pixel) = the analytic groove reference within 2e-3 of Φ_i."""
    surface = v_grooves(alpha_deg)
    sc = scene(surface, index, theta_deg, phi_deg, res=128)
    trace = rt.trace_paths(cl_ctx, sc, rays=1 << 17, max_depth=32, seed=3)
    omega = np.array([np.sin(sc.theta_i) * np.cos(sc.phi_i), np.sin(sc.theta_i) * np.sin(sc.phi_i), np.cos(sc.theta_i)])
    ref = groove_reference(alpha_deg, omega, index)
    grid = sc.grid
    for k, entry in sorted(ref.items()):
        got = trace.escaped_by_depth[:, k]
        logger.info("α=%g θ=%g φ=%g k=%d: fraction %.5f, energy s,p %s vs %s", alpha_deg, theta_deg, phi_deg, k,
                    entry["fraction"], got, entry["energy"])
        assert np.allclose(got, entry["energy"], atol=2e-3), (k, got, entry["energy"])
        # the energy of order k sits in the pixel of its exit direction
        i, j = (int(np.clip(np.floor((c + 1) * 0.5 * grid.resolution), 0, grid.resolution - 1))
                for c in entry["direction"][:2])
        image = trace.single if k == 1 else trace.multiple
        in_pixel = image[:, i, j] / trace.incident_power / grid.mu[i, j] * grid.pixel_area
        assert np.all(in_pixel >= entry["energy"] - 2e-3), (k, in_pixel, entry["energy"])
    assert abs(sum(e["fraction"] for e in ref.values()) - 1) < 1e-12
    assert np.all(trace.lost == 0) and np.all(trace.truncated == 0)
    assert np.allclose(trace.escaped_by_depth.sum(axis=1), sum(e["energy"] for e in ref.values()), atol=2e-3)


def test_v_groove_lit_fraction_at_grazing(cl_ctx):
    """Grooves of slope 30° at θ_i = 80° across them: lit fraction 1/(1 + tan α tan θ) (the sunny
    facet's lower part lies in the shadow of the opposite ridge, the other facet faces away);
    per node the same rule decides (node_visibility, kernels and the NumPy twin)."""
    alpha, theta = 30.0, 80.0
    surface = v_grooves(alpha, periods=4, half=10)
    sc = scene(surface, GLASS, theta, 0.0, res=32)
    trace = rt.trace_paths(cl_ctx, sc, rays=1 << 16, max_depth=1)
    lit = 1 / (1 + np.tan(alpha * DEG) * np.tan(theta * DEG))
    logger.info("shadowed fraction %.5f vs analytic %.5f", trace.shadowed_fraction, 1 - lit)
    assert abs(trace.shadowed_fraction - (1 - lit)) < 2e-3
    omega = np.array([[np.sin(theta * DEG), 0.0, np.cos(theta * DEG)]])
    vis = rt.node_visibility(cl_ctx, surface, omega)[0]
    assert np.array_equal(vis, rt.node_visibility(None, surface, omega)[0])
    # analytic per node: position from the vertex of its groove (period 2·half cells)
    half, d = 10, surface.spacing_um
    offset = (np.mod(np.arange(surface.cells + 1), 2 * half) - half) * d  # < 0: sunny (left) facet
    W2 = half * d
    cot = 1 / np.tan(theta * DEG)
    tan_a = np.tan(alpha * DEG)
    lit_node = (offset < 0) & (-offset >= W2 * (tan_a - cot) / (tan_a + cot)) | (np.abs(offset) == W2)
    assert np.array_equal(vis, np.repeat(lit_node[:, None], surface.cells + 1, axis=1))


# ---------------------------------------------------------------------------------------------
# Tilted plane, perfect conductor, scale invariance


@pytest.mark.parametrize("slopes", [(0.2, 0.0), (0.15, -0.25)])
def test_tilted_plane(cl_ctx, slopes):
    """h = ax + by (clamp border, footprint inside the patch): all energy in the pixel of the facet
    mirror direction; albedo s,p = |E_r|² of the explicitly reflected incident s/p fields."""
    a, b = slopes
    n = 64
    x = np.linspace(-5.0, 5.0, n + 1)
    X, Y = np.meshgrid(x, x, indexing="ij")
    surface = HeightField(a * X + b * Y, 10.0)
    sc = scene(surface, ALUMINIUM, 40.0, 20.0, waist=1.5, res=256)
    trace = rt.trace_paths(cl_ctx, sc, rays=1 << 14, max_depth=4, border="clamp")
    omega = np.array([np.sin(sc.theta_i) * np.cos(sc.phi_i), np.sin(sc.theta_i) * np.sin(sc.phi_i), np.cos(sc.theta_i)])
    m = np.array([-a, -b, 1.0]) / np.sqrt(1 + a * a + b * b)
    mirror = 2 * np.dot(omega, m) * m - omega
    k = -omega
    s_hat = np.cross(k, m) / np.linalg.norm(np.cross(k, m))
    e_s = np.array([-np.sin(sc.phi_i), np.cos(sc.phi_i), 0.0])
    r_s, r_p = fresnel_coefficients(1.0, ALUMINIUM, np.arccos(np.dot(omega, m)))
    expected = []
    for E in (e_s, np.cross(e_s, k)):
        Er = r_s * np.dot(E, s_hat) * s_hat + r_p * np.dot(E, np.cross(s_hat, k)) * np.cross(s_hat, mirror)
        expected.append(np.vdot(Er, Er).real)
    result = trace.result()
    got = albedo(result.brdf(), sc.grid)
    logger.info("tilted (%g, %g): albedo %s vs %s", a, b, got, expected)
    assert np.allclose(got, expected, rtol=1e-9)
    i, j = np.unravel_index(np.argmax(result.intensity()[0]), (256, 256))
    assert abs(sc.grid.u[i] - mirror[0]) <= 1 / 256 and abs(sc.grid.u[j] - mirror[1]) <= 1 / 256
    assert np.count_nonzero(result.intensity()[0]) == 1


def test_perfect_conductor_conserves_energy(cl_ctx):
    """|r| → 1 on a steep random surface (multiple bounces): albedo = 1 − truncated − O(1e-6)."""
    surface = generate("gaussian", cells=96, size_um=6.0, rms_height_um=0.5, correlation_um=0.6, seed=4)
    for theta in (0.0, 60.0):
        sc = scene(surface, PEC, theta, 10.0, waist=2.0, res=64)
        trace = rt.trace_paths(cl_ctx, sc, rays=1 << 15, max_depth=6)
        a = albedo(trace.result().brdf(), sc.grid)
        logger.info("PEC θ=%g: albedo %s, truncated %s, multiple %s, mean bounces %.3f", theta, a, trace.truncated,
                    trace.diagnostics["multiple_fraction"], trace.diagnostics["mean_bounces"])
        assert trace.diagnostics["multiple_fraction"][0] > 0.05  # the case exercises multiple bounces
        assert np.all(trace.truncated > 0)
        assert np.allclose(a + trace.truncated, 1.0, atol=1e-5)
        assert np.all(trace.lost == 0)


def test_extremes_stay_finite(cl_ctx):
    """approx.md §7 item 11: θ_i up to 89°, rms slope 3, a single step edge (16:1 over one cell),
    glass and a strong metal, both borders: finite non-negative BRDFs, albedo ≤ 1, power into the
    material ≥ 0, no ray stopped by the step cap."""
    step = np.zeros((33, 33))
    step[16:, :] = 2.0
    surfaces = {"step": HeightField(step, 4.0),
                "steep": generate("gaussian", cells=64, size_um=2.0, rms_height_um=0.3, correlation_um=0.2, seed=8)}
    for name, surface in surfaces.items():
        for border in rt.BORDERS:
            for theta in (0.0, 85.0, 89.0):
                for index in (GLASS, 0.5 - 5j):
                    sc = scene(surface, index, theta, 15.0, waist=1.0, res=32)
                    trace = rt.trace_paths(cl_ctx, sc, rays=1 << 12, max_depth=32, border=border)
                    f = trace.result().brdf()[:, sc.grid.inside]
                    a = albedo(trace.result().brdf(), sc.grid)
                    assert np.all(np.isfinite(f)) and np.all(f >= 0), (name, border, theta)
                    assert np.all(a <= 1 + 1e-12) and np.all(trace.into_material >= -1e-12), (name, border, theta, a)
                    assert trace.diagnostics["lost_rays"] == 0, (name, border, theta)


def test_scale_invariance(cl_ctx):
    """Scaling x, y, h and the footprint leaves GO unchanged; λ enters only through the index."""
    surface = generate("gaussian", cells=64, size_um=4.0, rms_height_um=0.2, correlation_um=0.5, seed=2)
    base = scene(surface, ALUMINIUM, 30.0, 40.0, waist=1.0, res=48)
    ref = rt.trace_paths(cl_ctx, base, rays=1 << 14, max_depth=8).intensity()
    scaled = HeightField(surface.z * 3.0, surface.size_um * 3.0)
    sc = SurfaceScene(scaled, 0.5, complex(ALUMINIUM), base.theta_i, base.phi_i, 3.0, base.grid)
    other = rt.trace_paths(cl_ctx, sc, rays=1 << 14, max_depth=8).intensity()
    power = 9.0  # Φ_i ∝ w²
    assert np.allclose(other / power, ref, rtol=1e-9, atol=1e-12 * ref.max())
    sc = SurfaceScene(surface, 1.7, complex(ALUMINIUM), base.theta_i, base.phi_i, 1.0, base.grid)
    assert np.array_equal(rt.trace_paths(cl_ctx, sc, rays=1 << 14, max_depth=8).intensity(), ref)


# ---------------------------------------------------------------------------------------------
# NumPy twin, reweighting, visibility API


def test_numpy_twin_matches_kernels_on_the_same_rays(cl_ctx):
    """Same rays, same estimator: exit pixel and depth identical, per-bounce geometry and weights
    within 1e-10 (only libm and FMA contraction differ)."""
    surface = generate("gaussian", cells=64, size_um=4.0, rms_height_um=0.35, correlation_um=0.5, seed=7)
    for border in ("periodic", "clamp"):
        sc = scene(surface, ALUMINIUM, 50.0, 30.0, waist=1.2, res=64)
        setup = rt.TraceSetup.build(sc, max_depth=12, border=border, seed=5)
        ref = rt._trace_batch_numpy(setup, 1000, 1200)
        code, depth, batch = rt._trace_batch_cl(cl_ctx, setup, 1000, 1200, 4000, Precision.DOUBLE)
        assert np.array_equal(code, ref["code"]) and np.array_equal(depth, ref["depth"])
        assert depth.max() >= 3 and not np.any(code == rt.LOST_CODE)
        dev = batch.host()

        def chains(d):
            out = []
            for h in d["head"]:
                recs = []
                while h >= 0:
                    recs.append(d["rec"][3 * h : 3 * h + 3])
                    h = d["next"][h]
                out.append(np.array(recs).reshape(-1, 3))
            return np.concatenate(out)

        assert np.allclose(chains(dev), chains(ref), rtol=0, atol=1e-10)
        w_np = rt._weights_numpy(ref["head"], ref["rec"], ref["next"], ALUMINIUM)
        w_cl = rt._weights_cl(cl_ctx, batch, ALUMINIUM, Precision.DOUBLE)
        assert np.allclose(w_cl, w_np, rtol=0, atol=1e-10)
    # the whole estimator
    sc = scene(surface, GLASS, 20.0, 0.0, waist=1.2, res=32)
    a = rt.trace_paths(cl_ctx, sc, rays=1000, max_depth=4, seed=1)
    b = rt.trace_paths(None, sc, rays=1000, max_depth=4, seed=1)
    assert np.allclose(a.intensity(), b.intensity(), rtol=1e-10, atol=1e-12 * a.intensity().max())
    assert a.shadowed_fraction == b.shadowed_fraction


def test_reweighting_equals_a_fresh_trace(cl_ctx):
    """A kept geometry reweighted for another index (another wavelength) = a fresh trace, bit for
    bit, and nothing is traced."""
    surface = generate("gaussian", cells=64, size_um=4.0, rms_height_um=0.3, correlation_um=0.5, seed=1)
    first = rt.trace_paths(cl_ctx, scene(surface, GLASS, 35.0, 10.0, waist=1.0, res=64), rays=1 << 14, max_depth=16)
    assert first.geometry is not None and not first.diagnostics["geometry_reused"]
    other = scene(surface, ALUMINIUM, 35.0, 10.0, waist=1.0, res=64)
    reweighted = rt.trace_paths(cl_ctx, other, rays=1 << 14, max_depth=16, geometry=first.geometry)
    fresh = rt.trace_paths(cl_ctx, other, rays=1 << 14, max_depth=16)
    assert reweighted.diagnostics["geometry_reused"] and reweighted.diagnostics["time_trace_s"] == 0.0
    assert np.array_equal(reweighted.single, fresh.single) and np.array_equal(reweighted.multiple, fresh.multiple)
    assert np.array_equal(reweighted.truncated, fresh.truncated)
    with pytest.raises(ValueError, match="kept path geometry"):
        rt.trace_paths(cl_ctx, scene(surface, GLASS, 36.0, 10.0, waist=1.0, res=64), rays=1 << 14, max_depth=16,
                       geometry=first.geometry)


def test_visibility_api(cl_ctx):
    """node/cell visibility: shapes, kernels = twin, a flat surface sees everything, a node facing
    away from a direction is not visible, bad directions refused."""
    surface = generate("gaussian", cells=32, size_um=2.0, rms_height_um=0.15, correlation_um=0.3, seed=5)
    dirs = np.array([[0, 0, 1.0], [np.sin(1.2), 0, np.cos(1.2)], [0.3, -0.5, np.sqrt(1 - 0.34)]])
    for fn, shape in ((rt.node_visibility, (3, 33, 33)), (rt.cell_visibility, (3, 32, 32))):
        for border in rt.BORDERS:
            vis = fn(cl_ctx, surface, dirs, border=border)
            assert vis.shape == shape and vis.dtype == bool
            assert np.array_equal(vis, fn(None, surface, dirs, border=border))
            assert 0.3 < vis[1].mean() < 0.95 and vis[0].mean() > 0.9
    flat = generate("flat", cells=8, size_um=1.0)
    assert rt.node_visibility(cl_ctx, flat, dirs).all()
    # a node whose four cells all face away from the direction cannot see it
    z = np.zeros((9, 9))
    z[:, :] = 0.5 * np.arange(9)[:, None]  # slope 0.5·8/1 µm → 4 along x: facets face −x
    ramp = HeightField(z, 1.0)
    away = np.array([[np.sin(0.5), 0, np.cos(0.5)]])
    assert not rt.node_visibility(cl_ctx, ramp, away, border="clamp")[0, 1:-1, 1:-1].any()
    with pytest.raises(ValueError, match="upper hemisphere"):
        rt.node_visibility(cl_ctx, flat, [[0, 0, -1.0]])
    with pytest.raises(ValueError, match="unit vectors"):
        rt.node_visibility(cl_ctx, flat, [[0, 0, 2.0]])


def test_single_precision_agrees(cl_ctx):
    """precision = "single" (float kernels): albedo and lobe within 1e-3 of double on the same rays."""
    surface = generate("gaussian", cells=64, size_um=4.0, rms_height_um=0.25, correlation_um=0.5, seed=6)
    results = [rt.trace_paths(cl_ctx, scene(surface, ALUMINIUM, 40.0, 10.0, waist=1.5, res=32, precision=p),
                              rays=1 << 15, max_depth=8) for p in ("double", "single")]
    d, s = (r.intensity() for r in results)
    assert results[1].diagnostics["precision"] == "single"
    assert np.allclose(results[1].escaped, results[0].escaped, rtol=1e-3)
    assert np.sqrt(np.sum((s - d) ** 2) / np.sum(d**2)) < 1e-2


def test_pixel_remap_keeps_every_deposit_inside():
    for res in (16, 33, 64):
        grid = HemisphereGrid(res)
        remap = rt.pixel_remap(res)
        assert grid.inside.ravel()[remap].all()
        inside = np.flatnonzero(grid.inside.ravel())
        assert np.array_equal(remap[inside], inside)
