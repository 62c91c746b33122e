"""BCSDF tables of fibers: the azimuthal scattering function N_wave over (λ, θ_i, φ_i, φ_r) and
d'Eon's longitudinal function M₀ (fiber.md §6, §14.8–9).

The fiber BCSDF is S = M₀(θ_i, θ_r) · N_wave(λ, θ_i, φ_i, φ_r) with a single lobe ([P] eq. 31):
N_wave = (dC_s/dφ_r)/C_ext (1/rad, unpolarized = the mean of the two polarizations' dC_s/dφ over
their mean C_ext); ∫ N_wave dφ_r = C_sca/C_ext, the albedo. The table stores N_wave (``bcsdf``)
and the raw quantities it is made of (dC_s/dφ, C_ext, C_sca, C_abs), never renormalised slices.

Sampling (§14.8): φ_r and φ_i are grouped into bins centred on i·2π/n (bin i covers
[(i-½), (i+½))·2π/n); each bin is the box average of ``s`` equally spaced samples with
n·s >= max(360, 4(k₀ r_max + 10)). A single φ_i bin (``n_phi_i = 1``, for circles) means the
one incidence azimuth φ_i = 0 without averaging; explicit ``phi_i`` values (a config's
``phi_i_deg``) are point samples, not bins.

Effective cross section for renderers ([P] §5.1, §6): C_e = C_ext, clamped to C_e <= 6 C_g with
C_g the geometric width seen from φ_i (``C_eff``, ``C_eff_clamped``). Near grazing incidence
C_ext grows without bound (fiber.md §12), which is what the clamp is for.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Callable, Iterator

import numpy as np
import scipy.special as sp

from wavebrdf.solver.fiber.farfield import angular_oversampling, bin_average, bin_centres, bin_samples
from wavebrdf.solver.fiber.results import power_balance_error

logger = logging.getLogger(__name__)

__all__ = [
    "BCSDFSlice",
    "BCSDFTable",
    "C_EFF_CLAMP",
    "bcsdf_slices",
    "bcsdf_table",
    "effective_width",
    "longitudinal_cdf",
    "longitudinal_m0",
]

C_EFF_CLAMP = 6.0  # C_e <= 6 C_g ([P])
DEFAULT_LONGITUDINAL_VARIANCE = 0.02  # d'Eon's v (rad²): [P] leaves it to the renderer; ~8° lobe


def effective_width(C_ext_unpolarized, C_geom):
    """C_e = C_ext clamped to 6 C_g (µm; [P] §5.1, §6): the width rays must see."""
    return np.minimum(C_ext_unpolarized, C_EFF_CLAMP * np.asarray(C_geom, dtype=float))


def longitudinal_m0(theta_i, theta_r, v):
    """d'Eon's longitudinal scattering function M₀ (1/rad), peak at θ_r = -θ_i.

    M₀ = exp(-sinθ_i sinθ_r / v) I₀(cosθ_i cosθ_r / v) / (2v sinh(1/v)), evaluated in the log
    domain (I₀(a) = e^a ive₀(a), 2v sinh(1/v) = v e^{1/v}(1 - e^{-2/v})) so that small
    variances v (down to ~1e-3) neither overflow nor lose precision. ∫ M₀ cosθ_r dθ_r = 1.
    """
    theta_i, theta_r, v = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (theta_i, theta_r, v)))
    if np.any(v <= 0):
        raise ValueError(f"longitudinal variance v must be > 0, got {v.min()!r}")
    a = np.cos(theta_i) * np.cos(theta_r) / v
    b = np.sin(theta_i) * np.sin(theta_r) / v
    log_m0 = a - b + np.log(sp.ive(0, a)) - np.log(v) - 1.0 / v - np.log1p(-np.exp(-2.0 / v))
    return np.exp(log_m0)


def longitudinal_cdf(theta_i, v, edges) -> np.ndarray:
    """CDF of θ_r under the density M₀(θ_i, θ_r; v) cosθ_r at ``edges`` (radians, ascending,
    spanning [-π/2, π/2]); shape (len(theta_i), len(edges)), 0 at the first edge, 1 at the last.
    16-point Gauss–Legendre per cell, then normalised (the integral is 1 to < 1e-6 anyway)."""
    theta_i = np.atleast_1d(np.asarray(theta_i, dtype=float))
    edges = np.asarray(edges, dtype=float)
    x, w = np.polynomial.legendre.leggauss(16)
    half = np.diff(edges) / 2
    nodes = (edges[:-1] + edges[1:])[:, None] / 2 + half[:, None] * x  # (K, 16)
    density = longitudinal_m0(theta_i[:, None, None], nodes, v) * np.cos(nodes)
    cells = (density * w).sum(axis=-1) * half  # (T, K)
    cdf = np.concatenate([np.zeros((theta_i.size, 1)), np.cumsum(cells, axis=-1)], axis=-1)
    return cdf / cdf[:, -1:]


def _as_index_function(index) -> Callable[[float, int], complex]:
    """index: complex, array over wavelengths, or callable λ -> m (all in the n - jκ convention)."""
    if callable(index):
        return lambda lam, i: complex(index(lam))
    arr = np.atleast_1d(np.asarray(index, dtype=complex))
    if arr.size == 1:
        return lambda lam, i: complex(arr[0])
    return lambda lam, i: complex(arr[i])


@dataclass
class BCSDFSlice:
    """One (λ, θ_i) slice of a BCSDF table (what one solve produces; one HDF5 chunk)."""

    wavelength_index: int
    theta_index: int
    index: complex
    dCs_dphi: np.ndarray  # (2, P, R) µm/rad, per polarization, bins
    C_ext: np.ndarray  # (2, P) µm
    C_sca: np.ndarray  # (2, P)
    C_abs: np.ndarray  # (2, P)
    seconds: float
    timings: dict = field(default_factory=dict)


def _phi_i_samples(n_phi_i: int, r_max: float, wavelength_um: float, explicit=None) -> tuple[np.ndarray, int]:
    if explicit is not None:
        return np.atleast_1d(np.asarray(explicit, dtype=float)), 1
    if n_phi_i == 1:
        return np.zeros(1), 1
    per_bin = angular_oversampling(n_phi_i, r_max, wavelength_um)
    return bin_samples(n_phi_i, per_bin), per_bin


def bcsdf_slices(model, wavelengths_um, index, theta_i, n_phi_i: int = 360,
                 n_phi_r: int = 360, phi_i=None) -> Iterator[BCSDFSlice]:
    """Solve every (λ, θ_i) in turn and yield its slice (λ-major order).

    ``model`` is a :class:`~wavebrdf.solver.fiber.bem.FiberBEM` or a
    :class:`~wavebrdf.solver.fiber.mie.MieFiber`; angles in radians; ``phi_i`` (optional)
    replaces the ``n_phi_i`` bins by explicit incidence azimuths.
    """
    lams = np.atleast_1d(np.asarray(wavelengths_um, dtype=float))
    thetas = np.atleast_1d(np.asarray(theta_i, dtype=float))
    for name, n in (("n_phi_i", n_phi_i), ("n_phi_r", n_phi_r)):
        if isinstance(n, bool) or int(n) != n or n < 1:
            raise ValueError(f"{name} must be a positive integer, got {n!r}")
    if np.any(np.abs(thetas) >= np.pi / 2):
        raise ValueError("theta_i must stay below 90° (grazing incidence is never sampled, fiber.md §12)")
    index_of = _as_index_function(index)
    for li, lam in enumerate(lams):
        samples, per_bin_i = _phi_i_samples(n_phi_i, model.r_max, lam, phi_i)
        for ti, theta in enumerate(thetas):
            t0 = time.perf_counter()
            m = index_of(lam, li)
            res = model.scattering(lam, m, theta, samples, phi_r=None, bins=n_phi_r)
            yield BCSDFSlice(
                wavelength_index=li,
                theta_index=ti,
                index=m,
                dCs_dphi=bin_average(res.dCs_dphi, per_bin_i, axis=1),
                C_ext=bin_average(res.C_ext, per_bin_i, axis=1),
                C_sca=bin_average(res.C_sca, per_bin_i, axis=1),
                C_abs=bin_average(res.C_abs, per_bin_i, axis=1),
                seconds=time.perf_counter() - t0,
                timings=res.timings,
            )


@dataclass
class BCSDFTable:
    """A BCSDF table in memory. Angles in radians, lengths in µm.

    Shapes: L wavelengths, T incidence angles, P φ_i bins, R φ_r bins, polarization axis of 2
    ("parallel", "perpendicular").
    """

    wavelength_um: np.ndarray  # (L,)
    theta_i: np.ndarray  # (T,)
    phi_i: np.ndarray  # (P,) bin centres, or explicit point samples (phi_i_binned False)
    phi_r: np.ndarray  # (R,) bin centres
    index: np.ndarray  # (L,) complex, n - jκ
    dCs_dphi: np.ndarray  # (L, T, 2, P, R) float32, µm/rad, bin averages
    C_ext: np.ndarray  # (L, T, 2, P)
    C_sca: np.ndarray  # (L, T, 2, P)
    C_abs: np.ndarray  # (L, T, 2, P)
    C_geom: np.ndarray  # (P,) geometric width seen from φ_i
    model: str = ""
    seconds: float = 0.0
    phi_i_binned: bool = True
    polarizations: tuple = ("parallel", "perpendicular")

    @property
    def phi_r_width(self) -> float:
        return 2.0 * np.pi / self.phi_r.size

    @property
    def bcsdf(self) -> np.ndarray:
        """Unpolarized N_wave = mean_pol(dC_s/dφ) / mean_pol(C_ext), (L, T, P, R) float32, 1/rad."""
        num = self.dCs_dphi.mean(axis=2, dtype=np.float64)
        return (num / self.C_ext.mean(axis=2)[..., None]).astype(np.float32)

    @property
    def power_balance_error(self) -> np.ndarray:
        """|C_ext - C_sca - C_abs| / C_ext, (L, T, 2, P)."""
        return power_balance_error(self.C_ext, self.C_sca, self.C_abs)

    @property
    def C_eff(self) -> np.ndarray:
        """Effective width for renderers: unpolarized C_ext clamped to 6 C_g, (L, T, P)."""
        return effective_width(self.C_ext.mean(axis=2), self.C_geom)

    @property
    def C_eff_clamped(self) -> np.ndarray:
        """Where the clamp C_e <= 6 C_g acted, (L, T, P) bool."""
        return self.C_ext.mean(axis=2) > C_EFF_CLAMP * self.C_geom


def bcsdf_table(model, wavelengths_um, index, theta_i, n_phi_i: int = 360, n_phi_r: int = 360,
                progress: Callable[[int, int, BCSDFSlice], None] | None = None,
                model_name: str = "", phi_i=None) -> BCSDFTable:
    """Compute a full BCSDF table in memory; ``progress(done, total, slice)`` after each solve.

    ``model``: FiberBEM (any cross section) or MieFiber (circles); ``index``: complex, array over
    wavelengths or callable λ -> m; ``theta_i``: radians, |θ_i| < π/2; ``phi_i``: explicit
    incidence azimuths (radians) instead of ``n_phi_i`` bins.
    """
    lams = np.atleast_1d(np.asarray(wavelengths_um, dtype=float))
    thetas = np.atleast_1d(np.asarray(theta_i, dtype=float))
    explicit = None if phi_i is None else np.atleast_1d(np.asarray(phi_i, dtype=float))
    if explicit is not None:
        n_phi_i = explicit.size
    L, T, P, R = lams.size, thetas.size, int(n_phi_i), int(n_phi_r)
    if explicit is not None:
        phi_i = explicit
    else:
        phi_i = np.zeros(1) if P == 1 else bin_centres(P)
    table = BCSDFTable(
        wavelength_um=lams,
        theta_i=thetas,
        phi_i=phi_i,
        phi_r=bin_centres(R),
        index=np.zeros(L, dtype=complex),
        dCs_dphi=np.zeros((L, T, 2, P, R), dtype=np.float32),
        C_ext=np.zeros((L, T, 2, P)),
        C_sca=np.zeros((L, T, 2, P)),
        C_abs=np.zeros((L, T, 2, P)),
        C_geom=np.asarray(model.width(phi_i), dtype=float),
        model=model_name or type(model).__name__,
        phi_i_binned=explicit is None and P > 1,
    )
    t0 = time.perf_counter()
    for done, sl in enumerate(bcsdf_slices(model, lams, index, thetas, P, R, phi_i=explicit), start=1):
        li, ti = sl.wavelength_index, sl.theta_index
        table.index[li] = sl.index
        table.dCs_dphi[li, ti] = sl.dCs_dphi
        table.C_ext[li, ti], table.C_sca[li, ti], table.C_abs[li, ti] = sl.C_ext, sl.C_sca, sl.C_abs
        if progress is not None:
            progress(done, L * T, sl)
    table.seconds = time.perf_counter() - t0
    worst = float(np.max(table.power_balance_error))
    logger.info("BCSDF table %s: %d x %d solves in %.1f s, worst power balance %.1e",
                table.model, L, T, table.seconds, worst)
    return table
