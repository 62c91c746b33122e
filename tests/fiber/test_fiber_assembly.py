"""The fiber BEM matrix: OpenCL kernels against their NumPy/scipy twins, closed-form singular
integrals against adaptive quadrature, and structural identities (T13, discrete reciprocity)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from wavebrdf.solver.fiber import BEMQuadrature, FiberAssembler, circle, ellipse, fiber_media, polygon
from wavebrdf.solver.fiber.assembly import (
    fiber_assemble_reference,
    fiber_pair_moments_reference,
    log_moments_reference,
    static_moments_reference,
)
from wavebrdf.solver.precision import Precision

DEG = np.pi / 180

CASES = {
    "ellipse-lossy-oblique": (ellipse(0.4, 0.25, 24), 0.5, 1.55 - 0.02j, 30.0),
    "circle-lossless-normal": (circle(0.3, 30), 0.5, 1.55, 0.0),
    "circle-grazing": (circle(0.3, 20), 0.5, 1.55 - 0.02j, 89.9),
    "metal-like": (ellipse(0.3, 0.2, 20), 0.5, 2.0 - 3.0j, 45.0),  # |k_ρ|Δ > 2.5 on near pairs
    "graded-square": (polygon([[0, 0], [0.6, 0], [0.6, 0.6], [0, 0.6]], 16, corner_grading=2), 0.5, 1.55, 20.0),
}


def _rel(a, b):
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


@pytest.mark.parametrize("case", list(CASES))
def test_kernels_match_numpy_reference(cl_ctx, case):
    shape, lam, m, theta = CASES[case]
    media = fiber_media(lam, m, theta * DEG)
    assembler = FiberAssembler(cl_ctx, shape)
    ref_i, ref_k = fiber_pair_moments_reference(shape, media)
    mom_i, mom_k = assembler.moments(media)
    assert _rel(mom_i, ref_i) < 1e-11
    assert _rel(mom_k, ref_k) < 1e-11
    z_ref = fiber_assemble_reference(shape, ref_i, ref_k, media)
    assert _rel(assembler.matrix(media), z_ref) < 1e-11


def test_single_precision_build(cl_ctx):
    shape, lam, m, theta = CASES["ellipse-lossy-oblique"]
    media = fiber_media(lam, m, theta * DEG)
    z64 = FiberAssembler(cl_ctx, shape).matrix(media)
    z32 = FiberAssembler(cl_ctx, shape, precision=Precision.SINGLE).matrix(media)
    assert z32.dtype == np.complex64
    assert _rel(z32, z64) < 1e-4


@pytest.mark.parametrize("point", [(0.3, 0.2), (0.5, 1e-3), (1.3, 0.0), (-0.2, -0.4), (0.0, 0.05)])
def test_closed_form_singular_integrals(point):
    """∫ Λ_β ln R ds' and ∫ Λ_β d/R² ds' over the element [0, 1]·(cos 0.3, sin 0.3)·1.2."""
    t = np.array([np.cos(0.3), np.sin(0.3)])
    length = 1.2
    p0 = np.zeros(2)
    normal = np.array([t[1], -t[0]])
    x = p0 + point[0] * length * t + point[1] * normal
    d = (x - p0) @ np.array([t[1], -t[0]])  # z.((x - p) x t)
    got_log = log_moments_reference(x, p0, t, length)
    got_static = static_moments_reference(x, p0, t, length)
    for beta, hat in enumerate((lambda s: 1 - s / length, lambda s: s / length)):
        def dist(s):
            return np.hypot(*(x - p0 - s * t))
        kink = [point[0] * length] if 0 < point[0] < 1 else None
        want_log = quad(lambda s: hat(s) * np.log(dist(s)), 0, length, points=kink, limit=200)[0]
        assert got_log[beta] == pytest.approx(want_log, rel=1e-10, abs=1e-12)
        if abs(d) > 0:
            want_static = quad(lambda s: hat(s) * d / dist(s) ** 2, 0, length, points=kink, limit=200)[0]
            assert got_static[beta] == pytest.approx(want_static, rel=1e-9, abs=1e-12)
        else:
            assert got_static[beta] == 0.0


def test_t13_normal_incidence_decouples(cl_ctx):
    """At θ_i = 0 the oblique couplings L^tz, L^zt, K^tt vanish identically: {J_z, M_t} and
    {J_t, M_z} form two independent systems, each complex-symmetric once the H rows are negated."""
    shape = ellipse(0.4, 0.25, 24)
    z = FiberAssembler(cl_ctx, shape).matrix(fiber_media(0.5, 1.55 - 0.02j, 0.0))
    n = shape.segments
    blocks = {(r, c): z[r * n:(r + 1) * n, c * n:(c + 1) * n] for r in range(4) for c in range(4)}
    # rows E_t, E_z, H_t, H_z; columns J_t, J_z, M_t, M_z
    for r, c in [(0, 1), (1, 0), (0, 2), (2, 0), (2, 3), (3, 2), (1, 3), (3, 1)]:
        assert np.all(blocks[r, c] == 0), (r, c)
    for rows, cols in (((1, 2), (1, 2)), ((0, 3), (0, 3))):
        sub = np.block([[blocks[r, c] * (1 if r < 2 else -1) for c in cols] for r in rows])
        assert _rel(sub, sub.T) < 1e-13


def test_discrete_reciprocity_identity(cl_ctx):
    """Z(θ)ᵀ = S Z(-θ) S with S = diag(1, 1, -1, -1) per block: the Galerkin form of reciprocity
    (it makes T7 hold to rounding error)."""
    shape = ellipse(0.4, 0.25, 24)
    assembler = FiberAssembler(cl_ctx, shape)
    zp = assembler.matrix(fiber_media(0.5, 1.55 - 0.02j, 0.5))
    zm = assembler.matrix(fiber_media(0.5, 1.55 - 0.02j, -0.5))
    s = np.repeat([1.0, 1.0, -1.0, -1.0], shape.segments)
    assert _rel(zp.T, s[:, None] * zm * s[None, :]) < 1e-13


def test_quadrature_validation():
    with pytest.raises(ValueError, match="far_points"):
        BEMQuadrature(far_points=0)
    with pytest.raises(ValueError, match="near_factor"):
        BEMQuadrature(near_factor=0.5)


def test_rhs_matches_pointwise_quadrature_of_incident_fields():
    """Right-hand sides (factorised per element) against a brute-force 12-point quadrature of
    t̂·E_i, E_iz, t̂·η₀H_i, η₀H_iz times the hats."""
    from wavebrdf.solver.fiber.incidence import gauss_legendre_unit, incident_fields, rhs_vectors

    shape = ellipse(0.4, 0.25, 30)
    media = fiber_media(0.5, 1.55, 0.4)
    phi = [0.1, 2.0]
    got = rhs_vectors(shape, media, phi)
    n = shape.segments
    s, w = gauss_legendre_unit(12)
    pts = shape.nodes[:, None, :] + s[None, :, None] * shape.edges[:, None, :]
    tangent3 = np.c_[shape.tangents, np.zeros(n)]
    want = np.zeros_like(got)
    for block, field in enumerate(incident_fields(media, phi, pts.reshape(-1, 2))):
        field = field.reshape(2 * len(phi), n, s.size, 3)
        for comp, values in enumerate((np.einsum("pnqc,nc->pnq", field, tangent3), field[..., 2])):
            start = np.einsum("pnq,q,n->np", values, w * (1 - s), shape.lengths)
            end = np.einsum("pnq,q,n->np", values, w * s, shape.lengths)
            want[(2 * block + comp) * n:(2 * block + comp + 1) * n] = start + np.roll(end, 1, axis=0)
    assert _rel(got, want) < 1e-13
