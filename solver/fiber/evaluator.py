"""The full fiber BCSDF of a stored table: S(θ_i, θ_r, φ_i, φ_r, λ) = M₀(θ_i, θ_r; v) · N_wave
(seed 004 §5.2, fiber.md §6), evaluated anywhere by interpolating the tabulated N_wave.

Conventions (fiber.md §0): fiber axis ẑ; θ measured from the plane normal to the axis; ω =
(cosθ cosφ, cosθ sinφ, sinθ); ω_i points toward the light, ω_r toward the viewer; the specular
cone is θ_r = -θ_i and forward scattering is φ_r = φ_i + π. Angles in radians, wavelengths in µm.

S is a density per steradian of outgoing direction, per unit of power the fiber extinguishes
(a ray that hits the fiber's effective width C_e = C_ext scatters into dω_r with probability
S dω_r, [P] §5.2.2): d'Eon's M₀ satisfies ∫ M₀ cosθ_r dθ_r = 1 and ∫ N_wave dφ_r = C_sca/C_ext,
so ∫_{S²} S dω_r = ∫∫ S cosθ_r dθ_r dφ_r = C_sca/C_ext, the albedo. There is no 1/cos²θ_d factor:
that belongs to Marschner's Gaussian M, not to d'Eon's cosθ-normalised M₀.

Interpolation of N_wave: linear in λ, in θ_i and in φ_i (periodic between bin centres; linear
between explicit point samples) and in φ_r (periodic between bin centres); held constant beyond
the first/last λ and θ_i. The fiber is invariant under z → -z, so N_wave(-θ_i) = N_wave(θ_i):
tables with θ_i >= 0 answer negative θ_i by |θ_i|. Circles (one φ_i) depend on φ_r - φ_i only.
Linear interpolation of periodic bin averages integrates to their sum × bin width, so the
interpolated N_wave keeps the albedo of its interpolation nodes.

Sampling tables: :func:`azimuthal_cdf` (CDF over the φ_r bins of each (λ, θ_i, φ_i), at the bins'
upper edges) and :func:`~wavebrdf.solver.fiber.bcsdf.longitudinal_cdf` (θ_r for M₀).
"""

from __future__ import annotations

import warnings

import numpy as np

from wavebrdf.solver.fiber.bcsdf import longitudinal_m0
from wavebrdf.solver.validity import ValidityWarning

__all__ = ["FiberBCSDF", "M0_CDF_EDGES_DEG", "azimuthal_cdf"]

M0_CDF_EDGES_DEG = np.linspace(-90.0, 90.0, 361)  # θ_r nodes of the stored M₀ CDF (every 0.5°)


def azimuthal_cdf(bcsdf: np.ndarray) -> np.ndarray:
    """CDF over the last axis (φ_r bins of equal width) at each bin's upper edge: the sampling
    table of N_wave per (λ, θ_i, φ_i); a bin-uniform CDF where a slice sums to 0."""
    n = np.asarray(bcsdf, dtype=np.float64)
    cdf = np.cumsum(np.maximum(n, 0.0), axis=-1)
    total = cdf[..., -1:]
    uniform = np.broadcast_to(np.arange(1, n.shape[-1] + 1) / n.shape[-1], n.shape)
    return np.where(total > 0, cdf / np.where(total > 0, total, 1.0), uniform)


def _is_circle(nodes: np.ndarray, tolerance: float = 1e-3) -> bool:
    """Whether polygon ``nodes`` (N, 2) lie on one circle about their mean, to ``tolerance`` of its radius."""
    radii = np.hypot(*(np.asarray(nodes, dtype=float) - np.mean(nodes, axis=0)).T)
    return bool(np.ptp(radii) <= tolerance * np.max(radii))


def _clamped(grid: np.ndarray, x: np.ndarray):
    """Linear-interpolation nodes (i0, i1, w1) on an ascending grid, constant beyond its ends."""
    if grid.size == 1:
        zero = np.zeros(x.shape, dtype=np.int64)
        return zero, zero, np.zeros(x.shape)
    x = np.clip(x, grid[0], grid[-1])
    i0 = np.clip(np.searchsorted(grid, x, side="right") - 1, 0, grid.size - 2)
    w1 = (x - grid[i0]) / (grid[i0 + 1] - grid[i0])
    return i0, i0 + 1, w1


def _periodic(n: int, x: np.ndarray):
    """Nodes (i0, i1, w1) between bin centres i·2π/n, periodic."""
    t = np.asarray(x, dtype=float) / (2 * np.pi / n)
    f = np.floor(t)
    i0 = f.astype(np.int64) % n
    return i0, (i0 + 1) % n, t - f


class FiberBCSDF:
    """S = M₀ · N_wave of one fiber table (see the module docstring for the conventions).

    ``bcsdf``: N_wave (L, T, P, R) in 1/rad; ``C_eff``: C_e (L, T, P) in µm; angles in radians;
    ``phi_i_binned``: φ_i are bin centres i·2π/P (else point samples; P = 1: a circle).
    """

    def __init__(self, wavelength_um, theta_i, phi_i, bcsdf, C_eff, variance: float, *, phi_i_binned: bool,
                 cdf=None, C_geom=None):
        self.wavelength_um = np.asarray(wavelength_um, dtype=float)
        self.theta_i = np.asarray(theta_i, dtype=float)
        self.phi_i = np.atleast_1d(np.asarray(phi_i, dtype=float))
        self.table = np.asarray(bcsdf, dtype=np.float64)
        self.C_eff = np.asarray(C_eff, dtype=np.float64)
        self.cdf = azimuthal_cdf(self.table) if cdf is None else np.asarray(cdf, dtype=np.float64)  # sampling
        self.C_geom = None if C_geom is None else np.asarray(C_geom, dtype=float)
        self.variance = float(variance)
        self.phi_i_binned = bool(phi_i_binned)
        L, T, P, R = self.table.shape
        if (L, T, P) != (self.wavelength_um.size, self.theta_i.size, self.phi_i.size) or self.C_eff.shape != (L, T, P):
            raise ValueError(f"table shapes disagree: bcsdf {self.table.shape}, C_eff {self.C_eff.shape}, "
                             f"axes {(self.wavelength_um.size, self.theta_i.size, self.phi_i.size)}")
        self.mirror_theta = bool(np.all(self.theta_i >= 0))
        self._sort(1, np.argsort(self.theta_i, kind="stable"))  # grids must ascend (configs need not)
        if not self.phi_i_binned and P > 1:
            self._sort(2, np.argsort(self.phi_i, kind="stable"))

    def _sort(self, axis: int, order: np.ndarray) -> None:
        grid = "theta_i" if axis == 1 else "phi_i"
        setattr(self, grid, getattr(self, grid)[order])
        self.table, self.cdf = np.take(self.table, order, axis), np.take(self.cdf, order, axis)
        self.C_eff = np.take(self.C_eff, order, axis)

    @classmethod
    def from_dataset(cls, ds, case: int = 0) -> "FiberBCSDF":
        """From an open fiber :class:`~wavebrdf.jobs.store.Dataset` (``case``: flat index in C order
        over the sweep axes). Datasets written before C_eff was stored get C_ext clamped to 6 C_g."""
        from wavebrdf.solver.fiber.bcsdf import DEFAULT_LONGITUDINAL_VARIANCE, effective_width

        if ds.kind != "fiber":
            raise ValueError(f"{ds.path}: not a fiber dataset (kind = {ds.kind!r})")
        h5 = ds.h5
        lead_shape = h5["bcsdf"].shape[:-4]
        n_cases = int(np.prod(lead_shape)) if lead_shape else 1
        if not 0 <= int(case) < n_cases:
            raise ValueError(f"{ds.path}: case = {case!r} out of range (0 .. {n_cases - 1})")
        where = np.unravel_index(int(case), lead_shape) if lead_shape else ()
        if "C_eff" in h5:
            c_eff = h5["C_eff"][where]
        else:
            c_eff = effective_width(h5["C_ext"][where].mean(axis=2), h5["C_geom"][where][None, None, :])
        stored = "longitudinal_variance" in h5
        variance = h5["longitudinal_variance"][where] if stored else DEFAULT_LONGITUDINAL_VARIANCE
        sampling = h5["phi_i"].attrs.get("sampling", "")
        sampling = sampling.decode() if isinstance(sampling, bytes) else str(sampling)
        table = h5["bcsdf"][where]
        if not (np.isfinite(table).all() and np.isfinite(c_eff).all()):
            raise ValueError(f"{ds.path}: the table of case {case} has missing (NaN) entries: failed tasks; "
                             "rerun the study")
        nodes = ds.case_variable(int(case))
        if h5["phi_i"].shape[0] == 1 and nodes is not None and not _is_circle(nodes[()]):
            warnings.warn(f"{ds.path}: case {case} holds one φ_i ({float(h5['phi_i'][0]):g}°) of a cross section "
                          "that is not a circle: other φ_i are read from it as if the fiber were rotation invariant; "
                          "compute the study with [output] phi_i_bins or several [illumination] phi_i_deg",
                          ValidityWarning, stacklevel=2)
        return cls(h5["wavelength_um"][()], np.deg2rad(h5["theta_i"][()]), np.deg2rad(h5["phi_i"][()]), table,
                   c_eff, float(variance), phi_i_binned=sampling.startswith("bin"),
                   cdf=h5["phi_r_cdf"][where] if "phi_r_cdf" in h5 else None, C_geom=h5["C_geom"][where])

    # -- interpolation ---------------------------------------------------------------------------
    def _incidence_nodes(self, theta_i, phi_i, wavelength_um):
        """[(weight, l, t, p)] of the 8 (λ, θ_i, φ_i) interpolation corners."""
        L, T, P, _ = self.table.shape
        theta = np.abs(theta_i) if self.mirror_theta else theta_i
        lam = _clamped(self.wavelength_um, wavelength_um)
        th = _clamped(self.theta_i, theta)
        if P == 1:
            ph = (np.zeros(theta.shape, dtype=np.int64),) * 2 + (np.zeros(theta.shape),)
        elif self.phi_i_binned:
            ph = _periodic(P, phi_i)
        else:
            ph = _clamped(self.phi_i, phi_i)
        out = []
        for l, wl in ((lam[0], 1 - lam[2]), (lam[1], lam[2])):
            for t, wt in ((th[0], 1 - th[2]), (th[1], th[2])):
                for p, wp in ((ph[0], 1 - ph[2]), (ph[1], ph[2])):
                    out.append((wl * wt * wp, l, t, p))
        return out

    def _broadcast(self, *args):
        return np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in args))

    def azimuthal(self, theta_i, phi_i, phi_r, wavelength_um) -> np.ndarray:
        """N_wave (1/rad), interpolated; arrays broadcast together."""
        theta_i, phi_i, phi_r, lam = self._broadcast(theta_i, phi_i, phi_r, wavelength_um)
        R = self.table.shape[-1]
        # one φ_i (circles, rotation invariant): the table holds φ_r for its own φ_i, turned with the query's
        rel = phi_r - (phi_i - self.phi_i[0]) if self.table.shape[2] == 1 else phi_r
        r0, r1, wr = _periodic(R, rel)
        out = np.zeros(theta_i.shape)
        for w, l, t, p in self._incidence_nodes(theta_i, phi_i, lam):
            out += w * ((1 - wr) * self.table[l, t, p, r0] + wr * self.table[l, t, p, r1])
        return out

    def effective_width(self, theta_i, phi_i, wavelength_um) -> np.ndarray:
        """C_e (µm), interpolated like N_wave."""
        theta_i, phi_i, lam = self._broadcast(theta_i, phi_i, wavelength_um)
        out = np.zeros(theta_i.shape)
        for w, l, t, p in self._incidence_nodes(theta_i, phi_i, lam):
            out += w * self.C_eff[l, t, p]
        return out

    def __call__(self, theta_i, theta_r, phi_i, phi_r, wavelength_um, variance=None) -> np.ndarray:
        """S = M₀(θ_i, θ_r; v) · N_wave(λ, θ_i, φ_i, φ_r) in 1/sr (v: the stored default if None)."""
        v = self.variance if variance is None else float(variance)
        theta_i, theta_r, phi_i, phi_r, lam = self._broadcast(theta_i, theta_r, phi_i, phi_r, wavelength_um)
        if np.any(np.abs(theta_i) > np.pi / 2) or np.any(np.abs(theta_r) > np.pi / 2):
            raise ValueError("theta_i and theta_r are angles from the normal plane: |θ| <= π/2 (radians)")
        return longitudinal_m0(theta_i, theta_r, v) * self.azimuthal(theta_i, phi_i, phi_r, lam)
