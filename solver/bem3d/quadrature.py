"""Quadrature rules for the element-pair integrals: Gauss–Legendre and singular (Duffy-type) maps.

All Galerkin integrals are over two parameter squares (u, v), (u', v') ∈ [−1, 1]² (the Jacobian
cancels, see mesh.py). Regular pairs use tensor Gauss–Legendre rules of order n per dimension.
Pairs that share a point use the transformations below (Sauter–Schwab family), written on the
canonical unit squares a = (a₁, a₂), b = (b₁, b₂) ∈ [0, 1]²: each maps [0, 1]⁴ onto a part of the
4-D domain with a Jacobian ξ^p that cancels the 1/R (and, for the double-layer part, 1/R²)
singularity, so the transformed integrand is analytic and Gauss–Legendre converges exponentially.

* self (same element), singular point set a = b. With z = b − a, each quadrant of z (signs
  σ₁, σ₂) is split along its diagonal: |z_i| = ξ, |z_j| = ξη (Jacobian ξ); the remaining
  variables run over the square of side (1−|z₁|)(1−|z₂|): a_k = max(0, −z_k) + t_k(1 − |z_k|).
  8 sub-domains.
* edge (shared edge a₁ = b₁ = 0 with a₂ = b₂ along it): with z = b₂ − a₂, the triple
  (a₁, b₁, |z|) is split by its largest member (= ξ, the others ξη₁, ξη₂; Jacobian ξ²), times
  the two signs of z; a₂ = max(0, −z) + t(1−|z|). 6 sub-domains.
* vertex (shared corner a = b = 0): the largest of (a₁, a₂, b₁, b₂) is ξ, the others ξη₁..₃
  (Jacobian ξ³). 4 sub-domains.

Every rule is invariant under exchanging the two elements (a ↔ b maps the point set onto
itself), which makes the assembled matrix complex-symmetric to rounding.

The rules return points in the canonical squares; ``orient`` maps them onto an element's (u, v)
given a 3-bit orientation code (see :func:`orientation_code`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

__all__ = [
    "CASE_EDGE",
    "CASE_REGULAR",
    "CASE_SELF",
    "CASE_VERTEX",
    "CASE_NAMES",
    "QuadratureOptions",
    "pair_case",
    "medium_weights",
    "regular_order",
    "singular_order",
    "singular_orders",
    "gauss_legendre",
    "orient",
    "orientation_code",
    "singular_rule",
    "tensor_rule",
]

CASE_REGULAR, CASE_SELF, CASE_EDGE, CASE_VERTEX = 0, 1, 2, 3
CASE_NAMES = {CASE_REGULAR: "regular", CASE_SELF: "self", CASE_EDGE: "edge", CASE_VERTEX: "vertex"}


@lru_cache(maxsize=None)
def gauss_legendre(order: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss–Legendre nodes and weights on [−1, 1] (read-only arrays)."""
    if int(order) != order or order < 1:
        raise ValueError(f"quadrature order must be an integer >= 1, got {order!r}")
    x, w = np.polynomial.legendre.leggauss(int(order))
    x.setflags(write=False)
    w.setflags(write=False)
    return x, w


def _unit_rule(order: int) -> tuple[np.ndarray, np.ndarray]:
    x, w = gauss_legendre(order)
    return 0.5 * (x + 1.0), 0.5 * w


def tensor_rule(order: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u, v, w) of the order² tensor Gauss rule on [−1, 1]² (weights sum to 4)."""
    x, w = gauss_legendre(order)
    U, V = np.meshgrid(x, x, indexing="ij")
    W = np.outer(w, w)
    return U.ravel(), V.ravel(), W.ravel()


def _grid4(order: int):
    x, w = _unit_rule(order)
    mesh = np.meshgrid(x, x, x, x, indexing="ij")
    weight = np.einsum("i,j,k,l->ijkl", w, w, w, w)
    return [m.ravel() for m in mesh], weight.ravel()


def _self_rule(order: int) -> np.ndarray:
    (xi, eta, t1, t2), w = _grid4(order)
    parts = []
    for s1 in (-1.0, 1.0):
        for s2 in (-1.0, 1.0):
            for diagonal in (0, 1):
                big, small = xi, xi * eta
                az1, az2 = (big, small) if diagonal == 0 else (small, big)
                z1, z2 = s1 * az1, s2 * az2
                a1 = np.maximum(0.0, -z1) + t1 * (1.0 - az1)
                a2 = np.maximum(0.0, -z2) + t2 * (1.0 - az2)
                jac = xi * (1.0 - az1) * (1.0 - az2)
                parts.append(np.stack([a1, a2, a1 + z1, a2 + z2, w * jac], axis=1))
    return np.concatenate(parts)


def _edge_rule(order: int) -> np.ndarray:
    (xi, e1, e2, t), w = _grid4(order)
    parts = []
    for sign in (-1.0, 1.0):
        for largest in range(3):
            triple = [xi * e1, xi * e2]
            triple.insert(largest, xi)  # (a1, b1, |z|) with member `largest` equal to ξ
            a1, b1, az = triple
            z = sign * az
            a2 = np.maximum(0.0, -z) + t * (1.0 - az)
            jac = xi**2 * (1.0 - az)
            parts.append(np.stack([a1, a2, b1, a2 + z, w * jac], axis=1))
    return np.concatenate(parts)


def _vertex_rule(order: int) -> np.ndarray:
    (xi, e1, e2, e3), w = _grid4(order)
    parts = []
    for largest in range(4):
        quad = [xi * e1, xi * e2, xi * e3]
        quad.insert(largest, xi)  # (a1, a2, b1, b2)
        parts.append(np.stack(quad + [w * xi**3], axis=1))
    return np.concatenate(parts)


_RULES = {CASE_SELF: _self_rule, CASE_EDGE: _edge_rule, CASE_VERTEX: _vertex_rule}


@lru_cache(maxsize=None)
def singular_rule(case: int, order: int) -> np.ndarray:
    """Points (a₁, a₂, b₁, b₂, w) on [0, 1]⁴ for ``case`` (self | edge | vertex), shape (P, 5).

    The weights integrate over the canonical squares (da db); multiply by 16 for du dv du' dv'.
    """
    if case not in _RULES:
        raise ValueError(f"singular case must be one of {sorted(_RULES)}, got {case!r}")
    gauss_legendre(order)  # validates the order
    rule = np.ascontiguousarray(_RULES[case](int(order)))
    rule.setflags(write=False)
    return rule


def orientation_code(swap: bool, flip_u: bool, flip_v: bool) -> int:
    """3-bit code: bit 0 swap (u from a₂, v from a₁), bit 1 flip u, bit 2 flip v."""
    return int(swap) | (int(flip_u) << 1) | (int(flip_v) << 2)


def orient(code, p1, p2):
    """(u, v) ∈ [−1, 1]² of canonical (p₁, p₂) ∈ [0, 1]² under orientation ``code``.

    u = 1 − 2p_u if flip_u else 2p_u − 1, with p_u = p₂ if swap else p₁ (likewise v).
    """
    code = np.asarray(code)
    swap = (code & 1).astype(bool)
    flip_u = ((code >> 1) & 1).astype(bool)
    flip_v = ((code >> 2) & 1).astype(bool)
    pu = np.where(swap, p2, p1)
    pv = np.where(swap, p1, p2)
    u = np.where(flip_u, 1.0 - 2.0 * pu, 2.0 * pu - 1.0)
    v = np.where(flip_v, 1.0 - 2.0 * pv, 2.0 * pv - 1.0)
    return u, v


def pair_case(ds, dt):
    """Case and orientation codes (test, source) for element offsets (Δs, Δt) = source − test.

    Returns (case, code_test, code_source) arrays; regular pairs get codes 0.
    """
    ds, dt = np.broadcast_arrays(np.asarray(ds), np.asarray(dt))
    ads, adt = np.abs(ds), np.abs(dt)
    case = np.full(np.broadcast(ds, dt).shape, CASE_REGULAR, dtype=np.int32)
    case[(ads == 0) & (adt == 0)] = CASE_SELF
    case[(ads + adt) == 1] = CASE_EDGE
    case[(ads == 1) & (adt == 1)] = CASE_VERTEX
    code_t = np.zeros(case.shape, dtype=np.int32)
    code_s = np.zeros(case.shape, dtype=np.int32)
    # edge across x (Δs = ±1): the shared edge is u = ±1 on the test element, ∓1 on the source;
    # a₁/b₁ measure the distance from it, a₂ = b₂ runs along it (v).
    ex = (case == CASE_EDGE) & (ads == 1)
    code_t[ex & (ds > 0)] = orientation_code(False, True, False)
    code_s[ex & (ds < 0)] = orientation_code(False, True, False)
    # edge across y (Δt = ±1): the same with u and v exchanged
    ey = (case == CASE_EDGE) & (adt == 1)
    code_t[ey & (dt > 0)] = orientation_code(True, False, True)
    code_t[ey & (dt < 0)] = orientation_code(True, False, False)
    code_s[ey & (dt > 0)] = orientation_code(True, False, False)
    code_s[ey & (dt < 0)] = orientation_code(True, False, True)
    # vertex: the test element's corner (sign Δs, sign Δt) meets the source's opposite corner
    vx = case == CASE_VERTEX
    code_t[vx] = ((ds[vx] > 0).astype(np.int32) << 1) | ((dt[vx] > 0).astype(np.int32) << 2)
    code_s[vx] = ((ds[vx] < 0).astype(np.int32) << 1) | ((dt[vx] < 0).astype(np.int32) << 2)
    return case, code_t, code_s


# ---------------------------------------------------------------------------------------------
# Order selection. The error models below are a priori estimates of Gauss–Legendre errors; their
# constants and the defaults of QuadratureOptions are checked against measured convergence
# tables (benchmarks/bench_bem3d.py --quadrature, docs/bem3d.md).


@dataclass(frozen=True)
class QuadratureOptions:
    """Quadrature settings of the element integrals, right-hand sides and far field.

    tolerance        target relative error of every element-pair table (each medium separately,
                     relative to the size of that medium's entries for the pair)
    static_order     Gauss order per dimension of the singular transforms for the static
                     1/R and ∇(1/R) parts (computed once per geometry)
    min_order, max_order   bounds of the distance/decay-adaptive orders (regular pairs and the
                     per-wavelength singular remainder)
    rhs_order        tensor Gauss order per element for the right-hand sides
    farfield_order   tensor Gauss order per element for the far-field sum and surface powers
    """

    tolerance: float = 1e-6
    static_order: int = 8
    min_order: int = 2
    max_order: int = 12
    rhs_order: int = 4
    farfield_order: int = 4

    def __post_init__(self):
        if not (0 < self.tolerance < 1):
            raise ValueError(f"quadrature.tolerance must be in (0, 1), got {self.tolerance!r}")
        for name in ("static_order", "min_order", "max_order", "rhs_order", "farfield_order"):
            value = getattr(self, name)
            if int(value) != value or not 1 <= value <= 40:
                raise ValueError(f"quadrature.{name} must be an integer in [1, 40], got {value!r}")
        if self.min_order > self.max_order:
            raise ValueError(
                f"quadrature.min_order ({self.min_order}) must not exceed max_order ({self.max_order})"
            )

    @classmethod
    def from_mapping(cls, values: dict | None) -> "QuadratureOptions":
        """Build from a config table; unknown keys are an error naming the key."""
        values = dict(values or {})
        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"unknown quadrature option(s) {unknown}; known: {sorted(known)}")
        return cls(**values)


def gauss_oscillation_error(order, alpha):
    """Gauss–Legendre remainder for e^{αx} on [−1, 1] relative to max|f| on the interval.

    |∫ f − G_n f| ≤ max|f^{(2n)}| 2^{2n+1} (n!)⁴ / ((2n+1) ((2n)!)³) with |f^{(2n)}| ≤ |α|^{2n} max|f|.
    """
    n = int(order)
    a = np.abs(np.asarray(alpha, dtype=float))
    logc = (2 * n + 1) * math.log(2.0) + 4 * math.lgamma(n + 1) - math.log(2 * n + 1) - 3 * math.lgamma(2 * n + 1)
    with np.errstate(divide="ignore"):
        return np.exp(2 * n * np.log(np.maximum(a, 1e-300)) + logc)


def gauss_proximity_error(order, x0):
    """Gauss–Legendre error for a 1/|x − x₀| singularity at x₀ > 1 (in half-lengths from the centre).

    The integrand is analytic inside the Bernstein ellipse through x₀, ρ = x₀ + √(x₀² − 1), and
    the error decays as 4ρ^{−2n}.
    """
    n = np.asarray(order, dtype=float)
    x0 = np.maximum(np.asarray(x0, dtype=float), 1.0 + 1e-9)
    rho = x0 + np.sqrt(x0 * x0 - 1.0)
    return 4.0 * rho ** (-2.0 * n)


def medium_weights(wavenumbers) -> list[float]:
    """Weight of each medium's tables in the matrix relative to the exterior: max(1, |k_i/k₁|²).

    (Z_MM weights medium i by n_i², so an error in a high-index interior counts that much more.)
    """
    k1 = abs(wavenumbers[0])
    return [max(1.0, (abs(k) / k1) ** 2) for k in wavenumbers]


def regular_order(options: QuadratureOptions, distance, radius_test, radius_source, half_length, wavenumbers):
    """Gauss order per pair of non-touching elements (arrays broadcast).

    distance: centre-to-centre distance (µm); radius_*: centre-to-corner radius of each element;
    half_length: largest parameter half-length |r_u|, |r_v| of the two elements. The error model
    of medium i, relative to the exterior scale of the pair's entries, is

        w_i · e^{−|Im k_i| gap} · [proximity(n, x₀) + oscillation(n, |k_i| ℓ)]

    with gap = distance − r_A − r_B (closest approach, lower bound), x₀ = (distance − max(r_A, r_B))/ℓ and
    w_i = medium_weights; the order is the smallest n ≤ max_order meeting the tolerance for
    every medium.
    """
    distance = np.asarray(distance, dtype=float)
    ra = np.asarray(radius_test, dtype=float)
    rb = np.asarray(radius_source, dtype=float)
    ell = np.asarray(half_length, dtype=float)
    x0 = (distance - np.maximum(ra, rb)) / ell  # symmetric in the two elements
    gap = np.maximum(distance - ra - rb, 0.0)
    weights = medium_weights(wavenumbers)
    shape = np.broadcast(distance, ra, rb, ell).shape
    x0, gap, ell = (np.broadcast_to(a, shape).ravel() for a in (x0, gap, ell))
    decay = [w * np.exp(-abs(np.imag(k)) * gap) for k, w in zip(wavenumbers, weights)]
    need = np.full(x0.shape, options.max_order, dtype=np.int32)
    open_ = np.arange(x0.size)  # pairs whose order is not settled yet
    for n in range(options.min_order, options.max_order + 1):
        if open_.size == 0:
            break
        prox = gauss_proximity_error(n, x0[open_])
        ok = np.ones(open_.size, dtype=bool)
        for k, d in zip(wavenumbers, decay):
            ok &= d[open_] * (prox + gauss_oscillation_error(n, abs(k) * ell[open_])) <= options.tolerance
        need[open_[ok]] = n
        open_ = open_[~ok]
    return need.reshape(shape)


def singular_orders(options: QuadratureOptions, half_length, wavenumbers) -> list[int]:
    """Gauss order of the singular transforms for the per-wavelength remainder G − G₀, per medium.

    After the transform the remainder is analytic with the scale of e^{−jkR}; medium i's order is
    the smallest n with w_i · oscillation(n, |k_i| ℓ) ≤ tolerance (n ≥ min_order, ≥ 2), w_i =
    medium_weights (a metal's interior needs more points than the exterior).
    """
    ell = float(np.max(half_length))
    orders = []
    for k, w in zip(wavenumbers, medium_weights(wavenumbers)):
        n = max(options.min_order, 2)
        while n < options.max_order and w * gauss_oscillation_error(n, abs(k) * ell) > options.tolerance:
            n += 1
        orders.append(n)
    return orders


def singular_order(options: QuadratureOptions, half_length, wavenumbers) -> int:
    """One order for every medium: the largest of :func:`singular_orders`."""
    return max(singular_orders(options, half_length, wavenumbers))
