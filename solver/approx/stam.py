"""Stam's expected Kirchhoff BRDF of a Gaussian random surface (Stam 1999; approx.md §3.3) →
IntensityResult. No realization: only the scene's :class:`~wavebrdf.solver.surface.GaussianEnsemble`.

It is the expected value, over realizations of the ensemble, of exactly what the ``kirchhoff``
model computes for one realization with the same footprint W = exp(−|x − c|²/w²)
(solver/approx/kirchhoff.py):

    f = |r(θ_h)|² Ω_K |I(s)|² / (λ₁² ∫W²),   I(s) = ∫ W e^{+jk[s·x + (μ_i+μ_o) h]} d²x,

with s = u_i + u_o, k = 2πn₁/λ, λ₁ = λ/n₁, Ω_K = (1 + ω_i·ω_o)²/(μ_i μ_o (μ_i+μ_o)²) and r_s, r_p
at the half-vector angle. For Gaussian heights (rms σ, correlation C_h = exp(−x'²/T_x'² −
y'²/T_y'², x' rotated by ``angle_deg``), with g = (k(μ_i+μ_o)σ)² and the footprint's
autocorrelation ∫W(x)W(x+τ)d²x = (πw²/2) e^{−|τ|²/(2w²)}:

    E f = |r|² Ω_K / λ₁² · Σ_m e^{−g} g^m/m! · π/√(a_x a_y) · exp(−q_x'²/(4a_x) − q_y'²/(4a_y)),
    a_x,y(m) = 1/(2w²) + m/T_x',y'²,   q' = k s on the ensemble's axes.

m = 0 is the coherent specular lobe (the footprint's own spectrum, weight e^{−g}); m ≥ 1 the
diffuse part. Each Gaussian term is averaged over the output pixel (exactly, by erf differences,
where it is separable in the grid axes: :class:`_GaussianTerms`), so a lobe narrower than the pixel
keeps its power (before: the σ = 0 ensemble at λ = 0.1 / 0.05 / 0.01 µm gave 0.0117 / 1.6e-6 / 0
for Fresnel's 0.0415, point-sampled). The Poisson weights are summed in log space (no overflow) from m = 0 until every
pixel's weight is below ``tolerance`` and m > 3g (Stam's rule). Pixels with g above
``go_threshold`` use the geometric-optics form instead: the same Gaussian at m = g, i.e.
a = 1/(2w²) + g/T², which is the Beckmann slope distribution (α = 2σ/T per axis) broadened by the
footprint's spectrum (f → |r|² D_Beckmann(ω_h)/(4μ_iμ_o) for w → ∞), times the factor
1 + (g/2)(ln f)'' + (g/2)((ln f)')² of the Poisson spread of m about g. Measured against the
series (relative L2 over the lobe): 1–3% without that factor at g = 100, 0.15% with it
(tests/approx/test_stam.py checks both forms where they overlap).

The realization's patch does not enter (the footprint is taken on an unbounded realization), nor
does the footprint centre (stationarity). Closed form per output pixel, vectorized in NumPy:
no OpenCL kernel, since the cost is (≤ 3·go_threshold terms) × pixels elementwise exponentials,
about 1 s for the 2·10⁵ pixels of a 512² grid at the threshold, and the Poisson weights want
double precision (``precision = "single"`` evaluates the Gaussian terms and sums in float32).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.special

from wavebrdf.solver.farfield import ETA0, HemisphereGrid, IntensityResult
from wavebrdf.solver.fresnel import fresnel_rs_rp
from wavebrdf.solver.models import Capabilities, Estimate, Model, SurfaceScene
from wavebrdf.solver.options import option
from wavebrdf.solver.surface import GaussianEnsemble
from wavebrdf.solver.validity import check_waist

__all__ = ["GO_THRESHOLD", "StamModel", "StamOptions", "stam_brdf"]

GO_THRESHOLD = 100.0  # g above which the geometric-optics form replaces the series (0.15% off there)


@dataclass(frozen=True)
class StamOptions:
    go_threshold: float = option(GO_THRESHOLD, low=0.0, doc="g = (k(μ_i+μ_o)σ)² above which a pixel uses the "
                                 "geometric-optics (Beckmann) form instead of the series (0: GO everywhere)")
    tolerance: float = option(1e-12, low=0.0, low_open=True, high=1e-3,
                              doc="the series stops once every pixel's Poisson weight is below this (and m > 3g)")


def stam_brdf(ensemble: GaussianEnsemble, wavelength_um: float, index: complex, theta_i: float, phi_i: float,
              grid: HemisphereGrid, waist_um: float, exterior_index: float = 1.0, *,
              go_threshold: float = GO_THRESHOLD, tolerance: float = 1e-12,
              dtype=np.float64) -> tuple[np.ndarray, np.ndarray, dict]:
    """Expected Kirchhoff BRDF (sr⁻¹) per polarization s|p, shape (2, res, res) (NaN outside the
    disk), its coherent (m = 0) part of the same shape, and diagnostics. Lengths in µm, angles in
    radians, ``index`` = n − jκ of the material below, footprint waist w = ``waist_um``."""
    if not (np.isfinite(wavelength_um) and wavelength_um > 0):
        raise ValueError(f"wavelength must be > 0 µm, got {wavelength_um!r}")
    if not 0.0 <= theta_i < 0.5 * np.pi:
        raise ValueError(f"incident theta must be in [0°, 90°), got {np.rad2deg(theta_i):g}°")
    if np.imag(index) > 0:
        raise ValueError(f"index must be n - j*kappa with kappa >= 0, got {index!r}")
    if not (np.isfinite(waist_um) and waist_um > 0):
        raise ValueError(f"illumination.waist_um must be > 0, got {waist_um!r}")
    k = 2 * np.pi * exterior_index / wavelength_um
    lambda1 = wavelength_um / exterior_index
    mu_i = np.cos(theta_i)
    u_i = np.sin(theta_i) * np.array([np.cos(phi_i), np.sin(phi_i)])
    inside = grid.inside
    U, V = grid.uv
    u, v, mu_o = U[inside], V[inside], grid.mu[inside]

    qx, qy = k * (u_i[0] + u), k * (u_i[1] + v)
    g = (k * (mu_i + mu_o) * ensemble.rms_height_um) ** 2
    cos_io = u_i[0] * u + u_i[1] * v + mu_i * mu_o
    omega_k = (1 + cos_io) ** 2 / (mu_i * mu_o * (mu_i + mu_o) ** 2)
    r_s, r_p = fresnel_rs_rp(complex(index) / exterior_index, np.sqrt(np.clip(0.5 * (1 + cos_io), 0, None)))

    term = _GaussianTerms(0.5 / waist_um**2, ensemble, qx, qy, 0.5 * k * 2.0 / grid.resolution, dtype)
    series = g <= go_threshold
    total = np.zeros(g.shape, dtype=dtype)
    coherent = np.zeros(g.shape, dtype=dtype)
    terms = 0
    if np.any(series):
        total[series], coherent[series], terms = _poisson_series(term.subset(series), g[series], tolerance, dtype)
    go = ~series
    if np.any(go):
        total[go] = term.subset(go).geometric(g[go])

    out = np.full((2,) + inside.shape, np.nan)
    coherent_out = np.full((2,) + inside.shape, np.nan)
    scale = omega_k / lambda1**2
    for p, r in enumerate((r_s, r_p)):
        out[p][inside] = np.abs(r) ** 2 * scale * total
        coherent_out[p][inside] = np.abs(r) ** 2 * scale * coherent
    area = grid.pixel_area
    albedo = np.nansum(out, axis=(1, 2)) * area
    albedo_coherent = np.nansum(coherent_out, axis=(1, 2)) * area
    diagnostics = {
        "g_specular": float((2 * k * mu_i * ensemble.rms_height_um) ** 2),
        "terms": int(terms),
        "form": "series" if not np.any(go) else ("GO" if not np.any(series) else "series+GO"),
        "go_pixel_fraction": float(np.mean(go)),
        "coherent_fraction": float(np.sum(albedo_coherent) / np.sum(albedo)) if np.sum(albedo) > 0 else 0.0,
        "albedo_excess": float(max(0.0, albedo.max() - 1.0)),
    }
    return out, coherent_out, diagnostics


def _box_average(c: np.ndarray, h: float) -> np.ndarray:
    """Mean of exp(−t²) over t ∈ [c − h, c + h] (erfc differences on the tail side, so the tails
    keep their relative precision)."""
    t = np.abs(c)
    return np.sqrt(np.pi) / (4 * h) * (scipy.special.erfc(t - h) - scipy.special.erfc(t + h))


class _GaussianTerms:
    """The m-th Gaussian term π/√(a_x a_y) exp(−q_x'²/(4a_x) − q_y'²/(4a_y)), a = b + m/T², averaged
    over each output pixel (q = k(u_i + u) spans ±``half_q`` about the centre along x and y) where
    it is narrower than the pixel (σ_q = √(2a) below 2·half_q): exactly, a product of erf
    differences, where the term is separable in the grid axes (a_x = a_y — always at m = 0 — or
    the ensemble's axes at a multiple of 90°). At the pixel centre otherwise: a wider lobe, whose
    point samples integrate it (and the pixel's varying Fresnel and obliquity factors) to
    4 exp(−2π²σ²/Δ²) < 1e-8, the terms m ≥ 1 of a turned anisotropic ensemble, and :meth:`geometric`. The albedo, Σ f Δu Δv, is then the lobes' integral however narrow
    they are (a specular lobe of σ = λ₁/(2πw) below the pixel is no longer point-sampled)."""

    def __init__(self, b: float, ensemble: GaussianEnsemble, qx: np.ndarray, qy: np.ndarray, half_q: float, dtype):
        self.b = b
        self.ensemble = ensemble
        self.inv_t2 = [1.0 / t**2 for t in ensemble.correlation_um]
        self.qx, self.qy = qx, qy
        self.qxr, self.qyr = ensemble.rotated(qx, qy)
        self.qx2, self.qy2 = self.qxr**2, self.qyr**2
        self.half_q = half_q
        turn = np.mod(ensemble.angle_deg, 90.0)
        self.aligned = bool(np.isclose(turn, 0.0) or np.isclose(turn, 90.0))
        self.dtype = dtype

    def subset(self, pixels: np.ndarray) -> "_GaussianTerms":
        """The terms on the pixels selected by the mask ``pixels``."""
        return _GaussianTerms(self.b, self.ensemble, self.qx[pixels], self.qy[pixels], self.half_q, self.dtype)

    def _point(self, ax, ay) -> np.ndarray:
        return np.pi / np.sqrt(ax * ay) * np.exp(-self.qx2 / (4 * ax) - self.qy2 / (4 * ay))

    def __call__(self, m) -> np.ndarray:
        """The pixel-averaged term for ``m`` (a scalar)."""
        ax, ay = self.b + m * self.inv_t2[0], self.b + m * self.inv_t2[1]
        if np.sqrt(2 * min(ax, ay)) >= 2 * self.half_q:  # σ_q ≥ the pixel: the point sample is exact to 4e^{−2π²}
            return self._point(ax, ay).astype(self.dtype, copy=False)
        if ax == ay:
            px, py = self.qx, self.qy
        elif self.aligned:
            px, py = self.qxr, self.qyr  # the pixel is a box on these axes too
        else:
            return self._point(ax, ay).astype(self.dtype, copy=False)
        sx, sy = 2 * np.sqrt(ax), 2 * np.sqrt(ay)
        value = (np.pi / np.sqrt(ax * ay) * _box_average(px / sx, self.half_q / sx)
                 * _box_average(py / sy, self.half_q / sy))
        return value.astype(self.dtype, copy=False)

    def geometric(self, g: np.ndarray, corrected: bool = True) -> np.ndarray:
        """The geometric-optics form: the term at m = g (Beckmann broadened by the footprint),
        times 1 + (g/2) f''/f, the Poisson variance (Var m = g) of the second-order expansion
        of E f(m) about m = g (relative error O(1/g²) instead of O(1/g))."""
        value = self._point(self.b + g * self.inv_t2[0], self.b + g * self.inv_t2[1]).astype(self.dtype, copy=False)
        if not corrected:
            return value
        d1 = np.zeros_like(g)
        d2 = np.zeros_like(g)
        for c, q2 in ((self.inv_t2[0], self.qx2), (self.inv_t2[1], self.qy2)):
            a = self.b + g * c
            d1 += -c / (2 * a) + 0.25 * q2 * c / a**2  # d ln f / dm
            d2 += c**2 / (2 * a**2) - 0.5 * q2 * c**2 / a**3  # d² ln f / dm²
        return (value * (1 + 0.5 * g * (d2 + d1**2))).astype(self.dtype, copy=False)


def _poisson_series(term: _GaussianTerms, g: np.ndarray, tolerance: float, dtype):
    """Σ_m e^{−g} g^m/m! term(m) per pixel (weights in log space), from m = 0 until every
    weight is below ``tolerance`` and m > 3 max g. Returns (sum, m = 0 part, number of terms)."""
    with np.errstate(divide="ignore"):
        log_g = np.log(g)  # −inf where g = 0: only m = 0 contributes there
    g_max = float(g.max())
    total = np.zeros(g.shape, dtype=dtype)
    m = 0
    while True:
        weight = np.exp(-g if m == 0 else m * log_g - g - scipy.special.gammaln(m + 1))
        value = weight.astype(dtype) * term(m)
        if m == 0:
            coherent = value
        total += value
        if m > 3 * g_max and weight.max() < tolerance:
            return total, coherent, m + 1
        m += 1


class StamModel(Model):
    """Registry adapter: ``[model] name = "stam"``; takes the surface's Gaussian ensemble."""

    name = "stam"
    summary = "Stam 1999: the expected Kirchhoff BRDF of a Gaussian random surface from its statistics, no realization"
    Options = StamOptions
    capabilities = Capabilities(takes="statistics", returns="intensity", polarized=True, steerable=False,
                                reciprocal=True, conserves_energy=False, rung=5, single_scattering=True)

    def check(self, scene: SurfaceScene) -> None:
        surface = scene.surface
        if getattr(surface, "ensemble", None) is None:
            params = getattr(surface, "parameters", None)
            source = ("surface.file (a measured height matrix)" if params is None
                      else f"surface.generator = \"{params['generator']}\" (a deterministic surface)")
            raise ValueError(f"[model] name = \"stam\": the stam model takes surface statistics (a Gaussian "
                             f"ensemble), and {source} has none; use surface.generator = \"gaussian\" or "
                             "\"brushed\"")

    def run(self, ctx, scene: SurfaceScene) -> IntensityResult:
        t0 = time.perf_counter()
        self.check(scene)
        dtype = scene.precision.real
        brdf, _, diagnostics = stam_brdf(
            scene.surface.ensemble, scene.wavelength_um, scene.index, scene.theta_i, scene.phi_i, scene.grid,
            scene.waist_um, scene.exterior_index, go_threshold=self.options.go_threshold,
            tolerance=self.options.tolerance, dtype=dtype)
        # Φ_i of the kirchhoff model's footprint for |E₀| = 1 V/µm: n₁/(2η₀) μ_i ∫W², ∫W² = πw²/2
        power = scene.exterior_index / (2 * ETA0) * np.cos(scene.theta_i) * 0.5 * np.pi * scene.waist_um**2
        mu = scene.grid.mu
        intensity = np.where(scene.grid.inside, np.nan_to_num(brdf) * power * mu, 0.0)
        result = IntensityResult(grid=scene.grid, wavelength_um=scene.wavelength_um, theta_i=scene.theta_i,
                                 phi_i=scene.phi_i, radiant_intensity=intensity,
                                 incident_power=np.array([power, power]),
                                 diagnostics={"model": self.name, "precision": scene.precision, **diagnostics,
                                              "wall_time_s": time.perf_counter() - t0})
        check_waist(scene, result.diagnostics, self.name, self.waist_remedy())
        return result

    def waist_remedy(self) -> str | None:
        return "ghs"

    def estimate(self, scene: SurfaceScene) -> Estimate:
        pixels = float(np.count_nonzero(scene.grid.inside))
        ens = scene.surface.ensemble
        sigma = 0.0 if ens is None else ens.rms_height_um
        k = 2 * np.pi * scene.exterior_index / scene.wavelength_um
        g_max = min((k * (np.cos(scene.theta_i) + 1) * sigma) ** 2, self.options.go_threshold)
        terms = 1 + int(np.ceil(max(3 * g_max, g_max + 10 * np.sqrt(g_max) + 10))) if g_max > 0 else 1
        memory = 40 * 8.0 * pixels + 8 * 8.0 * scene.grid.resolution**2 + 60e6  # + the OpenCL context
        seconds = 2.5e-8 * terms * pixels + 2e-7 * pixels + 0.01
        return Estimate(memory, seconds, f"{terms} series terms, {int(pixels)} pixels",
                        device_bytes=0.0, largest_buffer_bytes=0.0)  # host NumPy only: nothing on the device
