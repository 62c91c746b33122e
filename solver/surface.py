"""Height fields: loading, validation, generators, statistics and the ensembles they come from.

A :class:`HeightField` holds an (N+1)×(N+1) matrix of corner heights z[i, j] in µm on a square
patch of side L (µm): row index i ↔ x, column index j ↔ y, spacing d = L/N, and node
coordinates x_i = −L/2 + i·d (the patch is centred on the origin). Between nodes the surface is
the bilinear interpolant (the representation every model shares).

Generators (:func:`generate`, docs/approx.md "Surface generators") are a registry,
:data:`GENERATORS`: a new one is a function decorated with :func:`generator`, which names it and
declares its options dataclass (keys, types, ranges: solver/options.py); the config's
``[surface]`` section, :func:`generate` and the Mitsuba tables read the registry. They return
height fields that are periodic on the patch wherever their geometry allows (row N repeats row 0 and column N column 0
exactly), so periodic ray tracing and FFTs see no seam: "flat", "gaussian", "brushed",
"sinusoid" (when the period divides the patch along its direction), "spherical-pits",
"hemispheres"; "corner-cubes" is periodic along x only (its hexagonal lattice has the period
√3·a along y, which no square patch fits). Random generators also record the
:class:`GaussianEnsemble` they draw from (``HeightField.ensemble``), which the statistical
models (``stam``) take instead of the realization.
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Callable

import numpy as np

from wavebrdf.solver.options import ANGLE_DEG, LENGTH_UM, Limits, option, option_fields

__all__ = [
    "GENERATORS",
    "GaussianEnsemble",
    "Generator",
    "GeneratorOptions",
    "HeightField",
    "SurfaceError",
    "checked_heights",
    "generate",
    "generate_like",
    "generator",
    "load_heights",
    "rebuilt",
    "refined",
    "subdivided",
]

MIN_NODES = 4  # at least 3×3 cells
MAX_SEARCHED_CELLS = 4096  # minimal_cells searches grids up to this (its spectrum sums stay ~100 MB)
PERIOD_TOLERANCE = 1e-6  # relative: size_um / period_um must be this close to an integer


class SurfaceError(ValueError):
    """Invalid height-field input; the message names the problem."""


@dataclass(frozen=True)
class GaussianEnsemble:
    """The stationary Gaussian random process a realization was drawn from (µm, degrees)."""

    rms_height_um: float
    correlation_um: tuple[float, float]  # 1/e lengths (T_x', T_y') of C_h = exp(−x'²/T_x'² − y'²/T_y'²)
    angle_deg: float = 0.0  # rotation of the x' axis from x

    def __post_init__(self):
        if not (np.isfinite(self.rms_height_um) and self.rms_height_um >= 0):
            raise SurfaceError(f"GaussianEnsemble.rms_height_um must be a finite number >= 0, got {self.rms_height_um!r}")
        pair = tuple(float(c) for c in np.broadcast_to(np.asarray(self.correlation_um, dtype=float), (2,)))
        if not all(np.isfinite(c) and c > 0 for c in pair):
            raise SurfaceError(f"GaussianEnsemble.correlation_um must be two finite numbers > 0, got {self.correlation_um!r}")
        if not np.isfinite(self.angle_deg):
            raise SurfaceError(f"GaussianEnsemble.angle_deg must be finite, got {self.angle_deg!r}")
        object.__setattr__(self, "rms_height_um", float(self.rms_height_um))
        object.__setattr__(self, "correlation_um", pair)
        object.__setattr__(self, "angle_deg", float(self.angle_deg))

    def rotated(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Coordinates (x', y') of the vectors (x, y) along the ensemble's principal axes."""
        a = np.deg2rad(self.angle_deg)
        c, s = np.cos(a), np.sin(a)
        return c * np.asarray(x) + s * np.asarray(y), -s * np.asarray(x) + c * np.asarray(y)

    def correlation(self, dx, dy) -> np.ndarray:
        """Normalised height autocorrelation C_h(Δx, Δy) = exp(−x'²/T_x'² − y'²/T_y'²)."""
        xr, yr = self.rotated(dx, dy)
        tx, ty = self.correlation_um
        return np.exp(-((xr / tx) ** 2) - (yr / ty) ** 2)

    @property
    def slope_rms(self) -> tuple[float, float]:
        """rms slopes along x' and y': √2 σ/T (the Beckmann roughness is α = 2σ/T = √2 × this)."""
        return tuple(np.sqrt(2.0) * self.rms_height_um / t for t in self.correlation_um)

    def grid_statistics(self) -> dict[str, float]:
        """The ensemble's statistics along the grid axes: 1/e correlation lengths along x and y (µm)
        and the rms |∇z| = σ √(2/T_x'² + 2/T_y'²)."""
        a = np.deg2rad(self.angle_deg)
        c2, s2 = np.cos(a) ** 2, np.sin(a) ** 2
        tx, ty = self.correlation_um
        return {"correlation_x_um": float(1.0 / np.sqrt(c2 / tx**2 + s2 / ty**2)),
                "correlation_y_um": float(1.0 / np.sqrt(s2 / tx**2 + c2 / ty**2)),
                "rms_slope": float(self.rms_height_um * np.sqrt(2.0 / tx**2 + 2.0 / ty**2))}

    def sampled_statistics(self, cells: int, size_um: float) -> dict[str, float]:
        """The statistics a realization of the generators (:func:`_gaussian_tile`) has in
        expectation on ``cells`` × ``cells`` nodes of a ``size_um`` patch, as
        :meth:`HeightField.statistics` measures them: the spectrum is the ensemble's PSD on the
        grid's DFT frequencies (cut at Nyquist π/d, mean removed), so the 1/e lengths of its
        autocorrelation along x and y (µm, linear between lags) and the rms slope of the
        bilinear cells' gradient (transfer |2 sin(k_x d/2)/d · cos(k_y d/2)|², and in y) follow
        without drawing one. Deterministic: no seed enters."""
        return _sampled_statistics(self, int(cells), float(size_um))

    def minimal_cells(self, size_um: float, tolerance: float, start: int = MIN_NODES - 1) -> int | None:
        """The fewest cells (≥ ``start``) on a ``size_um`` patch whose :meth:`sampled_statistics`
        are within ``tolerance`` (relative) of :meth:`grid_statistics`; None when no grid of up to
        :data:`MAX_SEARCHED_CELLS` reaches them (the patch is too small: finite size, not spacing)."""
        wanted = self.grid_statistics()

        def within(cells: int) -> bool:
            got = self.sampled_statistics(cells, size_um)
            return all(abs(got[key] / wanted[key] - 1) <= tolerance for key in wanted)

        low, high = int(start), int(start)
        while not within(high):
            low, high = high, 2 * high
            if high > MAX_SEARCHED_CELLS:
                return None
        while high - low > 1:
            mid = (low + high) // 2
            low, high = (low, mid) if within(mid) else (mid, high)
        return high

    def attributes(self) -> dict:
        """Flat, HDF5-storable description (prefix ``ensemble_``)."""
        return {"ensemble": "gaussian", "ensemble_rms_height_um": self.rms_height_um,
                "ensemble_correlation_um": list(self.correlation_um), "ensemble_angle_deg": self.angle_deg}


def _sampled_statistics(ensemble: GaussianEnsemble, cells: int, size_um: float) -> dict[str, float]:
    """:meth:`GaussianEnsemble.sampled_statistics` (separable sums where the PSD's axes are the
    grid's, else the N×N spectrum)."""
    d = size_um / cells
    k = 2 * np.pi * np.fft.fftfreq(cells, d)
    tx, ty = ensemble.correlation_um
    lags = np.arange(cells // 2 + 1)
    phase = np.cos(np.outer(lags, k) * d)  # (lags, k)
    slope = 4 * np.sin(0.5 * k * d) ** 2 / d**2
    half = np.cos(0.5 * k * d) ** 2
    quarter = np.isclose(np.mod(ensemble.angle_deg, 90.0), 0.0) or np.isclose(np.mod(ensemble.angle_deg, 90.0), 90.0)
    with np.errstate(invalid="ignore", divide="ignore"):  # total = 0: handled below
        if tx == ty or quarter:
            turned = tx != ty and np.isclose(np.mod(ensemble.angle_deg, 180.0), 90.0)
            ax, ay = (ty, tx) if turned else (tx, ty)
            px, py = np.exp(-(k * ax) ** 2 / 4), np.exp(-(k * ay) ** 2 / 4)  # psd = px ⊗ py, minus the k = 0 term
            total = px.sum() * py.sum() - 1.0
            acf_x = (phase @ px * py.sum() - 1.0) / total
            acf_y = (phase @ py * px.sum() - 1.0) / total
            grad = ((slope @ px) * (half @ py) + (half @ px) * (slope @ py)) / total  # k = 0 adds nothing
        else:
            kx, ky = np.meshgrid(k, k, indexing="ij")
            kr, ks = ensemble.rotated(kx, ky)
            psd = np.exp(-((kr * tx) ** 2 + (ks * ty) ** 2) / 4)
            psd[0, 0] = 0.0
            total = psd.sum()
            acf_x = phase @ psd.sum(axis=1) / total
            acf_y = phase @ psd.sum(axis=0) / total
            grad = float(np.sum(psd * (slope[:, None] * half[None, :] + half[:, None] * slope[None, :]))) / total
    if not total > 0:  # the grid holds none of the ensemble's power beyond the mean (T ≫ the patch)
        return {"correlation_x_um": float("inf"), "correlation_y_um": float("inf"), "rms_slope": 0.0}
    level = np.exp(-1.0)
    return {"correlation_x_um": float(_first_crossing(acf_x, level) * d),
            "correlation_y_um": float(_first_crossing(acf_y, level) * d),
            "rms_slope": float(ensemble.rms_height_um * np.sqrt(grad))}


def checked_heights(z, *, square: bool) -> np.ndarray:
    """``z`` as a float matrix of at least MIN_NODES nodes per side (and square if asked), finite;
    else SurfaceError naming the problem (shape, or the first NaN/inf)."""
    z = np.asarray(z, dtype=float)
    if z.ndim != 2:
        raise SurfaceError(f"height matrix must be 2-D, got {z.ndim}-D")
    if square and z.shape[0] != z.shape[1]:
        raise SurfaceError(f"height matrix must be square ((N+1)x(N+1)), got {z.shape[0]}x{z.shape[1]}")
    if min(z.shape) < MIN_NODES:
        raise SurfaceError(f"height matrix is too small: {z.shape[0]}x{z.shape[1]}, need at least "
                           f"{MIN_NODES}x{MIN_NODES}" if square else
                           f"height matrix is too small: {z.shape[0]}x{z.shape[1]}, need at least {MIN_NODES} "
                           "nodes along each side")
    if not np.all(np.isfinite(z)):
        bad = np.argwhere(~np.isfinite(z))[0]
        raise SurfaceError(f"height matrix contains NaN/inf (first at row {bad[0]}, column {bad[1]})")
    return z


@dataclass(frozen=True)
class HeightField:
    """Corner heights ``z`` (µm, shape (N+1, N+1)) on a square patch of side ``size_um``.

    ``ensemble``: the Gaussian process of a random realization (None for files, deterministic
    generators and cut patches); ``parameters``: the generator's name, seed and parameters as
    built (None for files). Neither takes part in comparisons.
    """

    z: np.ndarray
    size_um: float
    origin_um: tuple[float, float] = (0.0, 0.0)  # patch centre in global coordinates
    ensemble: GaussianEnsemble | None = field(default=None, compare=False)
    parameters: dict | None = field(default=None, compare=False, repr=False)

    def __post_init__(self):
        z = checked_heights(self.z, square=True)
        if not (np.isfinite(self.size_um) and self.size_um > 0):
            raise SurfaceError(f"surface size_um must be a positive number, got {self.size_um!r}")
        if self.ensemble is not None and not isinstance(self.ensemble, GaussianEnsemble):
            raise SurfaceError(f"HeightField.ensemble must be a GaussianEnsemble or None, got {self.ensemble!r}")
        object.__setattr__(self, "z", z)

    @property
    def cells(self) -> int:
        """Number of cells N along each side."""
        return self.z.shape[0] - 1

    @property
    def spacing_um(self) -> float:
        """Grid spacing d = L/N (µm)."""
        return self.size_um / self.cells

    @cached_property
    def x(self) -> np.ndarray:
        """Node coordinates along x (rows), µm, centred on the patch centre."""
        return -0.5 * self.size_um + self.spacing_um * np.arange(self.cells + 1)

    @property
    def y(self) -> np.ndarray:
        """Node coordinates along y (columns); the same as :attr:`x` for a square patch."""
        return self.x

    @property
    def periodic(self) -> tuple[bool, bool]:
        """Whether the surface continues seamlessly across the x / y edges: as its generator recorded
        it (``parameters["periodic"]``: a sinusoid whose period does not divide the patch can repeat
        its edge row and still have a slope jump there), else whether the last row (x) / column (y)
        repeats the first, to 1e-9 of the peak-to-valley height."""
        recorded = (self.parameters or {}).get("periodic")
        if isinstance(recorded, str):
            return "x" in recorded, "y" in recorded
        return _periodic_axes(self.z)

    def statistics(self) -> dict[str, float]:
        """rms height and peak-to-valley of the nodes (of the N×N tile when periodic, so that each
        point counts once), rms / max slope of the bilinear surface (cell centres), and the
        correlation lengths along x and y (µm; NaN when undefined)."""
        slope = self.slopes()
        heights = self._tile()
        heights = heights - heights.mean()
        length_x, length_y = self.correlation_lengths()
        return {
            "rms_height_um": float(np.sqrt(np.mean(heights**2))),
            "peak_to_valley_um": float(np.ptp(heights)),
            "rms_slope": self.rms_slope(),
            "max_slope": float(slope.max()),
            "correlation_length_x_um": length_x,
            "correlation_length_y_um": length_y,
        }

    def gradient(self) -> tuple[np.ndarray, np.ndarray]:
        """(∂z/∂x, ∂z/∂y) of the bilinear surface at the cell centres, each (N, N) (dimensionless)."""
        z = self.z
        d = self.spacing_um
        zx = 0.5 * (z[1:, 1:] + z[1:, :-1] - z[:-1, 1:] - z[:-1, :-1]) / d
        zy = 0.5 * (z[1:, 1:] - z[1:, :-1] + z[:-1, 1:] - z[:-1, :-1]) / d
        return zx, zy

    def slopes(self) -> np.ndarray:
        """|∇z| of the bilinear surface at the cell centres, shape (N, N) (dimensionless)."""
        return np.hypot(*self.gradient())

    def rms_slope(self) -> float:
        """rms of :meth:`slopes` (dimensionless)."""
        return float(np.sqrt(np.mean(self.slopes() ** 2)))

    def rms_slope_along(self, phi: float) -> float:
        """rms of the slope along the azimuth ``phi`` (radians from x toward y), ∂z/∂x cos φ + ∂z/∂y sin φ
        at the cell centres (dimensionless; an isotropic surface's is its :meth:`rms_slope` / √2)."""
        zx, zy = self.gradient()
        return float(np.sqrt(np.mean((zx * np.cos(phi) + zy * np.sin(phi)) ** 2)))

    def rms_slope_below(self, scale_um: float) -> float:
        """rms slope of the relief finer than ``scale_um`` (µm): of z minus z smoothed by a
        Gaussian of standard deviation ``scale_um`` (a field periodic on both axes wraps; any other
        has its best-fit plane removed first and repeats its edge nodes). At ``scale_um`` = λ it is the slope at and below the wavelength's
        scale, the part of the roughness that couples the fields of nearby elements and slows the
        full-wave solve (the planner's product count; dimensionless)."""
        from scipy.ndimage import gaussian_filter

        if not (np.isfinite(scale_um) and scale_um > 0):
            raise ValueError(f"rms_slope_below: scale_um must be a finite number > 0, got {scale_um!r}")
        sigma = scale_um / self.spacing_um
        if all(self.periodic):
            tile = self.z[:-1, :-1]
            fine = np.pad(tile - gaussian_filter(tile, sigma=sigma, mode="wrap"), ((0, 1), (0, 1)), mode="wrap")
        else:  # a tilt would bend at the repeated edges: take the plane out first
            x = np.linspace(-0.5, 0.5, self.cells + 1)
            design = np.stack([np.ones(self.z.size), np.repeat(x, x.size), np.tile(x, x.size)], axis=1)
            plane = design @ np.linalg.lstsq(design, self.z.ravel(), rcond=None)[0]
            z = self.z - plane.reshape(self.z.shape)
            fine = z - gaussian_filter(z, sigma=sigma, mode="nearest")
        return HeightField(fine, self.size_um).rms_slope()

    def _tile(self) -> np.ndarray:
        """The nodes that are distinct points: the N×N tile when periodic, else all (N+1)²."""
        return self.z[:-1, :-1] if all(self.periodic) else self.z

    def autocorrelation(self) -> tuple[np.ndarray, np.ndarray]:
        """Normalised autocorrelation of the mean-removed heights along x and along y,
        ACF(τ)/ACF(0) for lags τ = 0, 1, … in units of the spacing (the 2-D ACF on its axes).
        Periodic along both axes (:attr:`periodic`): the circular ACF of the N×N tile; otherwise
        the linear (zero-padded, biased) ACF of the nodes. All zeros for a flat surface."""
        z = self._tile()
        z = z - z.mean()
        periodic = all(self.periodic)
        out = []
        for axis in (0, 1):
            n = z.shape[axis] if periodic else 2 * z.shape[axis]
            spectrum = np.fft.rfft(z, n=n, axis=axis)
            acf = np.fft.irfft(np.abs(spectrum) ** 2, n=n, axis=axis).sum(axis=1 - axis)
            out.append(acf / acf[0] if acf[0] > 0 else np.zeros_like(acf))
        return out[0], out[1]

    def correlation_lengths(self) -> tuple[float, float]:
        """1/e lengths (µm) of the measured autocorrelation along x and along y (first crossing of
        1/e, linearly interpolated between lags); NaN where it does not fall to 1/e within half
        the patch, or for a flat surface."""
        half = self.cells // 2
        return tuple(float(_first_crossing(line[: half + 1], np.exp(-1.0)) * self.spacing_um)
                     for line in self.autocorrelation())


MIN_FEATURE_SPACINGS = 4  # grid spacings across a feature (hemisphere, pit, cube) below which it is refused


def _check_resolved(width_um: float, key: str, what: str, cells: int, size_um: float) -> None:
    """SurfaceError unless a feature ``width_um`` wide spans MIN_FEATURE_SPACINGS grid spacings:
    below that its slopes and heights are the grid's, not the feature's (corner cubes a = 3.2
    spacings: rms slope 0.46 for faces of slope √2), and nothing downstream would say so."""
    spacing = size_um / cells
    if width_um < MIN_FEATURE_SPACINGS * spacing * (1 - 1e-12):
        fewest = int(np.ceil(MIN_FEATURE_SPACINGS * size_um / width_um))
        raise SurfaceError(f"surface.{key}: {what} = {width_um:.4g} µm spans {width_um / spacing:.3g} grid spacings "
                           f"(size_um/cells = {spacing:.4g} µm), fewer than {MIN_FEATURE_SPACINGS}: the grid cannot hold "
                           f"its shape (its slopes and heights would be the grid's); use surface.cells ≥ {fewest}")


def _periodic_axes(z: np.ndarray) -> tuple[bool, bool]:
    """Whether the last row / column of ``z`` repeats the first (to 1e-9 of its peak-to-valley)."""
    atol = 1e-9 * max(float(np.ptp(z)), np.finfo(float).tiny)
    return bool(np.allclose(z[-1], z[0], rtol=0, atol=atol)), bool(np.allclose(z[:, -1], z[:, 0], rtol=0, atol=atol))


def _first_crossing(values: np.ndarray, level: float) -> float:
    """Fractional index where ``values`` (starting above ``level``) first falls to ``level``."""
    if values[0] <= level:
        return float("nan")
    below = np.nonzero(values <= level)[0]
    if below.size == 0:
        return float("nan")
    i = int(below[0])
    return i - 1 + (values[i - 1] - level) / (values[i - 1] - values[i])


def load_heights(path: str | Path) -> np.ndarray:
    """Read a height matrix (µm) from ``.npy`` (real numbers: float or integer dtype) or a
    comma/whitespace-separated ``.txt``/``.csv`` (``#`` comments)."""
    path = Path(path)
    if not path.is_file():
        what = "is a folder" if path.is_dir() else "is not a regular file" if path.exists() else "does not exist"
        raise SurfaceError(f"surface file {str(path)!r} {what}")
    try:
        if path.suffix == ".npy":
            with open(path, "rb") as fh:
                if fh.read(6) != b"\x93NUMPY":
                    raise SurfaceError(f"surface file {str(path)!r} is not a .npy file (no NumPy header); "
                                       "name a text matrix .txt or .csv")
            z = np.load(path, mmap_mode="r", allow_pickle=False)  # the dtype is checked before reading
            if z.dtype.kind not in "fiu":
                kind = f"structured ({', '.join(z.dtype.names)})" if z.dtype.names else str(z.dtype)
                raise SurfaceError(f"surface file {str(path)!r} holds {kind} values; heights must be real numbers "
                                   "(a float or integer dtype)")
        else:
            rows = []  # one row at a time: no list of strings for the whole file
            with open(path, encoding="utf-8") as fh:
                for line in fh:
                    line = line.strip()
                    if line and not line.startswith("#"):
                        rows.append(np.array(line.replace(",", " ").split(), dtype=float))
            lengths = {len(r) for r in rows}
            if len(lengths) > 1:
                raise SurfaceError(
                    f"surface file {str(path)!r}: rows have different lengths {sorted(lengths)}"
                )
            z = np.array(rows)
    except SurfaceError:
        raise
    except (ValueError, OSError) as exc:
        raise SurfaceError(f"surface file {str(path)!r} cannot be read as a height matrix: {exc}") from exc
    return np.array(z, dtype=float)


# ---------------------------------------------------------------------------------------------
# Generators. Each returns an (N+1)x(N+1) height matrix for a patch of side L with N cells, or a
# (matrix, GaussianEnsemble | None, extra parameters) triple.


def _periodic_nodes(tile: np.ndarray) -> np.ndarray:
    """(N+1)² nodes from an N×N periodic tile: row N repeats row 0, column N column 0 (exactly)."""
    n = tile.shape[0]
    z = np.empty((n + 1, n + 1))
    z[:n, :n] = tile
    z[n, :n] = tile[0]
    z[:, n] = z[:, 0]
    return z


def _tile_coordinates(cells: int, size_um: float) -> tuple[np.ndarray, np.ndarray]:
    """(X, Y) of the N×N tile nodes measured from the patch corner (−L/2, −L/2), µm."""
    t = size_um / cells * np.arange(cells)
    return np.meshgrid(t, t, indexing="ij")


def _cells_per_period(size_um: float, period_um: float, key: str = "period_um") -> int:
    """The whole number of periods on the patch; refuses a period that does not divide it."""
    ratio = size_um / period_um
    count = int(round(ratio))
    if count < 1 or abs(ratio - count) > PERIOD_TOLERANCE * max(ratio, 1.0):
        low, high = max(1, int(np.floor(ratio))), int(np.floor(ratio)) + 1
        raise SurfaceError(
            f"surface.{key} = {period_um:g} does not divide surface.size_um = {size_um:g} "
            f"({ratio:.4g} periods); the patch must hold whole periods to be periodic: use "
            f"{key} = {size_um / high:.6g} or {size_um / low:.6g}"
        )
    return count


def _correlation_pair(value, key: str = "correlation_um") -> tuple[float, float] | float:
    """A scalar correlation length (isotropic) or a pair [T_x', T_y'], each finite and > 0."""
    if np.ndim(value) == 0:
        values, scalar = (value,), True
    else:
        values, scalar = tuple(np.asarray(value, dtype=float).ravel()), False
        if len(values) != 2:
            raise SurfaceError(f"surface.{key} = {value!r}: must be a number or [a, b] with two numbers")
    if not all(np.isfinite(v) and v > 0 for v in values):
        raise SurfaceError(f"surface.{key} = {value!r}: must be > 0")
    return float(values[0]) if scalar else (float(values[0]), float(values[1]))


def _gaussian_tile(cells: int, size_um: float, rng, rms_height_um: float, correlation, angle_deg: float):
    """Periodic N×N Gaussian random field with the Gaussian autocorrelation of ``correlation``
    (a scalar T: exp(−r²/T²); a pair (T_x', T_y') on axes rotated by ``angle_deg``), scaled to
    the requested rms height exactly. Spectral synthesis: white noise filtered by √PSD,
    PSD ∝ exp(−(k_x'² T_x'² + k_y'² T_y'²)/4). The exact rms is that of the patch after its mean
    (the PSD's k = 0 share, ε ≈ πT_x'T_y'/L²) is removed, so the realization's small-scale height
    variance exceeds the ensemble's σ² by about ε: keep L ≫ T when comparing with the ensemble."""
    if rms_height_um < 0:
        raise SurfaceError(f"surface.rms_height_um must be >= 0, got {rms_height_um}")
    n = cells
    d = size_um / cells
    k = 2 * np.pi * np.fft.fftfreq(n, d)
    kx, ky = np.meshgrid(k, k, indexing="ij")
    if np.ndim(correlation) == 0 or correlation[0] == correlation[1]:
        t = correlation if np.ndim(correlation) == 0 else correlation[0]
        psd = np.exp(-(kx**2 + ky**2) * t**2 / 4.0)  # isotropic (the original generator, bit for bit)
    else:
        a = np.deg2rad(angle_deg)
        kr = np.cos(a) * kx + np.sin(a) * ky
        ks = -np.sin(a) * kx + np.cos(a) * ky
        psd = np.exp(-(kr**2 * correlation[0] ** 2 + ks**2 * correlation[1] ** 2) / 4.0)
    noise = rng.standard_normal((n, n))
    tile = np.real(np.fft.ifft2(np.fft.fft2(noise) * np.sqrt(psd)))
    tile -= tile.mean()
    std = tile.std()
    return tile * (rms_height_um / std) if std > 0 else tile


# ---------------------------------------------------------------------------------------------
# The generator registry: each generator below is its options dataclass and one decorated function


class GeneratorOptions:
    """Base of every generator's options dataclass. ``isotropic``: whether the surfaces they
    describe are statistically invariant under rotations about z (the Mitsuba tables then use
    rotation invariance in φ_i); no, unless a generator's options say so. ``draws_at_random``:
    whether the seed changes the surface (a seed given to a generator that draws nothing would be
    ignored, and a sweep over it would repeat one surface)."""

    isotropic = False
    draws_at_random = False


@dataclass(frozen=True)
class Generator:
    """A registered generator: ``draw(cells, size_um, rng, options)`` returns the (N+1)×(N+1)
    heights (µm), or (heights, its :class:`GaussianEnsemble` or None, further parameters to
    record); ``Options`` is its options dataclass; ``cell_dependent``: a random realization drawn
    on the grid itself (:func:`refined` interpolates it instead of drawing it again)."""

    name: str
    Options: type
    draw: Callable
    cell_dependent: bool = False

    @property
    def keys(self) -> tuple[str, ...]:
        """The ``[surface]`` keys it takes (besides size_um, cells and seed)."""
        return tuple(option_fields(self.Options))

    def check_keys(self, params) -> None:
        """SurfaceError unless ``params`` holds every key the generator needs and no other."""
        fields = option_fields(self.Options)
        missing = [key for key, f in fields.items() if f.required and key not in params]
        if missing:
            raise SurfaceError(f"surface.generator = {self.name!r} needs {', '.join('surface.' + m for m in missing)}")
        unknown = sorted(set(params) - set(fields))
        if unknown:
            raise SurfaceError(
                f"surface.generator = {self.name!r} does not take {', '.join('surface.' + u for u in unknown)}"
            )

    def options(self, params: dict):
        """Its options from keyword values (:meth:`check_keys`). The values are checked by the
        draw, and, from a config, by their declared ranges first (jobs/sections.py)."""
        self.check_keys(params)
        return self.Options(**params)


GENERATORS: dict[str, Generator] = {}


def generator(name: str, options: type, *, cell_dependent: bool = False) -> Callable:
    """Register the decorated draw function as generator ``name`` with the options dataclass
    ``options`` (a :class:`GeneratorOptions`)."""

    def register(draw: Callable) -> Callable:
        GENERATORS[name] = Generator(name, options, draw, cell_dependent)
        return draw

    return register


def _length(doc: str, *, required: bool = True, limits: Limits = LENGTH_UM):
    """A generator's length key (µm)."""
    return option(None, required=required, limits=limits, doc=doc)


def _rms_height():
    return _length("rms height σ (0: a flat realization of the ensemble)",
                   limits=dataclasses.replace(LENGTH_UM, low=0, low_open=False))


@dataclass(frozen=True)
class FlatOptions(GeneratorOptions):
    """z = 0."""

    isotropic = True


@generator("flat", FlatOptions)
def _flat(cells: int, size_um: float, rng, options: FlatOptions) -> np.ndarray:
    return np.zeros((cells + 1, cells + 1))


@dataclass(frozen=True)
class GaussianOptions(GeneratorOptions):
    draws_at_random = True
    rms_height_um: float = _rms_height()
    correlation_um: float | tuple[float, float] = _length("1/e length T of exp(−r²/T²), or [T_x', T_y'] along axes "
                                                          "rotated by angle_deg")
    angle_deg: float | None = option(None, limits=ANGLE_DEG, doc="rotation of the x' axis from x (with a pair)")

    @property
    def isotropic(self) -> bool:
        """A scalar correlation length, or two equal ones."""
        c = self.correlation_um
        return np.ndim(c) == 0 or bool(np.isclose(c[0], c[1]))


@generator("gaussian", GaussianOptions, cell_dependent=True)
def _gaussian(cells: int, size_um: float, rng, options: GaussianOptions):
    """Gaussian random surface, autocorrelation exp(−r²/T²) (scalar ``correlation_um``) or
    exp(−x'²/T_x'² − y'²/T_y'²) (``correlation_um = [T_x', T_y']``, x' rotated by ``angle_deg``
    from x), periodic on the patch; the rms height is exact."""
    correlation = _correlation_pair(options.correlation_um)
    angle_deg = options.angle_deg
    if angle_deg is not None and np.ndim(correlation) == 0:
        raise SurfaceError(f"surface.angle_deg = {angle_deg:g} has no effect with a scalar surface.correlation_um "
                           f"= {correlation:g} (isotropic); give correlation_um = [T_x, T_y] to rotate")
    if angle_deg is not None and np.ndim(correlation) == 1 and options.isotropic:
        raise SurfaceError(f"surface.angle_deg = {angle_deg:g} has no effect with surface.correlation_um = "
                           f"{list(correlation)} (equal lengths: isotropic); give unequal lengths to rotate")
    angle = 0.0 if angle_deg is None else float(angle_deg)
    pair = (correlation, correlation) if np.ndim(correlation) == 0 else correlation
    tile = _gaussian_tile(cells, size_um, rng, options.rms_height_um, correlation, angle)
    return _periodic_nodes(tile), GaussianEnsemble(options.rms_height_um, pair, angle), {}


BRUSHED_ASPECT = 10.0  # default along/across ratio of the brushed generator
BRUSHED_ALONG_FRACTION = 0.25  # default along-groove correlation length, as a fraction of the patch


@dataclass(frozen=True)
class BrushedOptions(GeneratorOptions):
    draws_at_random = True
    rms_height_um: float = _rms_height()
    correlation_um: float | tuple[float, float] | None = _length("[along, across] grooves (default [L/4, L/40])",
                                                                 required=False)
    angle_deg: float = option(0.0, limits=ANGLE_DEG, doc="groove direction from x")


@generator("brushed", BrushedOptions, cell_dependent=True)
def _brushed(cells: int, size_um: float, rng, options: BrushedOptions):
    """Brushed grooves: a Gaussian random surface elongated along the groove direction.

    ``correlation_um = [along, across]`` (default [L/4, L/40]: grooves a quarter of the patch long,
    ten times narrower, so the patch holds ≥ 4 correlation lengths along them);
    ``angle_deg``: groove direction from x (default 0: grooves along x).
    """
    rms_height_um, correlation_um, angle_deg = options.rms_height_um, options.correlation_um, options.angle_deg
    if correlation_um is None:
        along = BRUSHED_ALONG_FRACTION * size_um
        pair = (along, along / BRUSHED_ASPECT)
    else:
        pair = _correlation_pair(correlation_um)
        if np.ndim(pair) == 0:
            raise SurfaceError(f"surface.correlation_um = {correlation_um!r}: the brushed generator takes "
                               "[along, across] (two lengths), or nothing for the default [L/4, L/40]")
        if pair[0] < pair[1]:
            raise SurfaceError(f"surface.correlation_um = {list(pair)}: brushed grooves are [along, across] "
                               "with along >= across (turn them with angle_deg)")
    tile = _gaussian_tile(cells, size_um, rng, rms_height_um, pair, angle_deg)
    return (_periodic_nodes(tile), GaussianEnsemble(rms_height_um, pair, angle_deg),
            {"correlation_um": list(pair), "angle_deg": float(angle_deg)})


@dataclass(frozen=True)
class SinusoidOptions(GeneratorOptions):
    amplitude_um: float = _length("amplitude a (either sign)", limits=dataclasses.replace(LENGTH_UM, low=None))
    period_um: float = _length("period Λ")
    angle_deg: float = option(0.0, limits=ANGLE_DEG, doc="direction α of the wave vector from x")


@generator("sinusoid", SinusoidOptions)
def _sinusoid(cells: int, size_um: float, rng, options: SinusoidOptions) -> np.ndarray:
    """h = a cos(2π (x cos α + y sin α)/Λ) with x, y the node coordinates; the period along each
    grid axis, Λ/|cos α| and Λ/|sin α|, must exceed two spacings (Nyquist), else the nodes hold
    another, longer sinusoid (refused, naming the fewest cells)."""
    amplitude_um, period_um, angle_deg = options.amplitude_um, options.period_um, options.angle_deg
    if period_um <= 0:
        raise SurfaceError(f"surface.period_um must be > 0, got {period_um}")
    a = np.deg2rad(angle_deg)
    along = max(abs(np.cos(a)), abs(np.sin(a)))  # the grid axis the sinusoid varies fastest along
    d = size_um / cells
    if period_um <= 2 * d * along:
        fewest = int(np.floor(2 * size_um * along / period_um)) + 1
        raise SurfaceError(f"surface.period_um = {period_um:g} is not above two spacings (Nyquist) of the grid along "
                           f"its direction: 2·size_um/cells·max(|cos α|, |sin α|) = 2·{size_um:g}/{cells}·{along:.4g} "
                           f"= {2 * d * along:.4g} µm, so the nodes would hold an aliased, longer sinusoid; use "
                           f"surface.cells ≥ {fewest}")
    x = -0.5 * size_um + size_um / cells * np.arange(cells + 1)
    X, Y = np.meshgrid(x, x, indexing="ij")
    periods = size_um * np.abs([np.cos(a), np.sin(a)]) / period_um  # along x and y
    whole = np.abs(periods - np.round(periods)) <= 1e-9 * np.maximum(periods, 1.0)
    z = amplitude_um * np.cos(2 * np.pi * (X * np.cos(a) + Y * np.sin(a)) / period_um)
    return z, None, {"periodic": "".join(axis for axis, w in zip("xy", whole) if w)}


CUBE_FACE_SLOPE = np.sqrt(2.0)  # tan of the 54.74° (arccos 1/√3) between a face normal and the cube axis ẑ


def corner_cube_normals() -> np.ndarray:
    """Unit normals (3, 3) of the three faces of an up-pointing triangular cube corner of the
    "corner-cubes" generator: horizontal parts along the triangle's inward side normals (120°
    apart), each at arccos(1/√3) from ẑ — mutually perpendicular."""
    inward = np.array([[0.0, 1.0], [-np.sqrt(3) / 2, -0.5], [np.sqrt(3) / 2, -0.5]])
    return np.column_stack([CUBE_FACE_SLOPE * inward, np.ones(3)]) / np.sqrt(3.0)


def _cant_rotation(cant_deg: float, cant_azimuth_deg: float) -> np.ndarray:
    """Rotation (3, 3) tilting ẑ by ``cant_deg`` toward the azimuth ``cant_azimuth_deg`` (from +x)."""
    tau, psi = np.deg2rad(cant_deg), np.deg2rad(cant_azimuth_deg)
    axis = np.array([-np.sin(psi), np.cos(psi), 0.0])
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(tau) * k + (1.0 - np.cos(tau)) * k @ k


MAX_CANT_DEG = float(np.rad2deg(np.arccos(1.0 / np.sqrt(3.0))))  # 54.74°: a cube edge lies down at 90° − this


def _cube_pit_envelope(points: np.ndarray, apexes: np.ndarray, gradients: np.ndarray) -> np.ndarray:
    """min over apexes c of max over faces j of g_j·(x − c): the lower envelope of cube-corner pits
    with their apexes at height 0 (``points`` (..., 2), ``apexes`` (M, 2), ``gradients`` (3, 2))."""
    offsets = points[..., None, :] - apexes  # (..., M, 2)
    return np.min(np.max(offsets @ gradients.T, axis=-1), axis=-1)


def _highest_rim(basis: np.ndarray, gradients: np.ndarray) -> float:
    """Exact maximum of the pit envelope (the highest rim point above the apexes): the envelope is
    piecewise linear, so its maximum lies where three of the face planes of nearby pits meet; every
    such point is evaluated on the envelope and the largest value kept."""
    near = np.array([(i, j) for i in range(-1, 3) for j in range(-1, 3)], float) @ basis.T
    around = np.array([(i, j) for i in range(-3, 5) for j in range(-3, 5)], float) @ basis.T
    planes = [(g, c) for c in near for g in gradients]  # z = g·(x − c)
    a = np.array([[-g[0], -g[1], 1.0] for g, _ in planes])
    b = np.array([-g @ c for g, c in planes])
    idx = np.array(list(itertools.combinations(range(len(planes)), 3)))
    m = a[idx]
    solvable = np.abs(np.linalg.det(m)) > 1e-12
    xyz = np.linalg.solve(m[solvable], b[idx[solvable]][..., None])[..., 0]
    return float(np.max(_cube_pit_envelope(xyz[:, :2], around, gradients)))


CUBE_SHAPES = ("triangular", "full")


@dataclass(frozen=True)
class CornerCubeOptions(GeneratorOptions):
    period_um: float = _length("lattice constant a (must divide size_um)")
    shape: str = option("triangular", choices=CUBE_SHAPES, doc="triangular corners, or full (hexagonal) ones")
    cant_deg: float = option(0.0, limits=ANGLE_DEG, record_absent=False,
                             doc="tilt of every cube's axis (full corners; < 35.26)")
    cant_azimuth_deg: float = option(0.0, limits=ANGLE_DEG, record_absent=False,
                                     doc="azimuth from x toward which the axes tilt")


@generator("corner-cubes", CornerCubeOptions)
def _corner_cubes(cells: int, size_um: float, rng, options: CornerCubeOptions):
    """Array of cube corners (retroreflectors) whose three faces rise from the apex at slope √2
    (normals at arccos(1/√3) = 54.74° from ẑ, mutually perpendicular); a = ``period_um``.

    ``shape = "triangular"``: three families of ridges at 0°, 60° and 120° through common points
    cut the plane into equilateral triangles of side a (the hexagonal lattice constant; ridge
    spacing P = a√3/2); in each triangle the trihedral corner

        z = −√2 · min_j dist(x, ridge lines of family j),

    ridges at z = 0, apexes at −√2 P/3 = −a/√6. Up and down triangles are both cube corners
    (rotated by 60°); an ideal one returns 2/3 of the light at normal incidence.

    ``shape = "full"``: full cube corners, their apexes on a triangular lattice of spacing a: the
    lower envelope of the cube-corner pits z = max_j(g_j·(x − c)) − D over the apexes c, with
    g_j = −n_j,xy / n_j,z from the face normals n_j. Uncanted (g_j = −√2 û_j) the apertures are
    hexagons with rims at 0 and −a/√6 alternating and apexes at D = a√(2/3); an ideal one returns all
    the light at normal incidence. ``cant_deg`` tilts every cube's axis by that angle toward the
    azimuth ``cant_azimuth_deg`` (the canted cube corners of retroreflective sheeting: the
    retroreflection peaks near θ_i ≈ 2× the cant on that side and widens the entrance angles);
    the apertures then change shape, the surface stays continuous, and D is the highest rim above
    the apexes (computed exactly). The cant must stay below 90° − 54.74° = 35.26° so that every cube
    edge still rises from its apex (a height field).

    Either is periodic along x when a divides the patch (required); not along y (period √3 a).
    The depth follows from the period: the face angles are fixed by orthogonality.
    """
    period_um, shape, cant_deg, cant_azimuth_deg = (options.period_um, options.shape, options.cant_deg,
                                                    options.cant_azimuth_deg)
    if shape not in CUBE_SHAPES:
        raise SurfaceError(f"surface.shape = {shape!r}: must be {_either(CUBE_SHAPES)} (corner-cubes)")
    cant_limit = 90.0 - MAX_CANT_DEG
    if not (np.isfinite(cant_deg) and 0.0 <= cant_deg < cant_limit):
        raise SurfaceError(f"surface.cant_deg = {cant_deg!r}: must be >= 0 and < {cant_limit:.2f} (a cube edge "
                           "would fall below its apex)")
    if cant_deg and shape != "full":
        raise SurfaceError(f"surface.cant_deg = {cant_deg!r}: canted cube corners need surface.shape = \"full\"")
    if not np.isfinite(cant_azimuth_deg):
        raise SurfaceError(f"surface.cant_azimuth_deg = {cant_azimuth_deg!r}: must be a finite angle in degrees")
    n_x = _cells_per_period(size_um, period_um)
    _check_resolved(period_um, "period_um", "the cubes' period a", cells, size_um)
    X, Y = np.meshgrid(*(size_um / cells * np.arange(cells + 1),) * 2, indexing="ij")
    if shape == "triangular":
        normals = corner_cube_normals()[:, :2] / np.sqrt(2.0 / 3.0)  # unit horizontal directions
        ridge = period_um * np.sqrt(3.0) / 2.0
        distance = np.full(X.shape, np.inf)
        for d in normals:
            t = d[0] * X + d[1] * Y
            distance = np.minimum(distance, np.abs(t - ridge * np.round(t / ridge)))
        z = -CUBE_FACE_SLOPE * distance
        depth = CUBE_FACE_SLOPE * ridge / 3.0
    else:
        normals = corner_cube_normals() @ _cant_rotation(cant_deg, cant_azimuth_deg).T
        gradients = -normals[:, :2] / normals[:, 2:]
        basis = np.array([[period_um, 0.5 * period_um], [0.0, 0.5 * np.sqrt(3.0) * period_um]])  # lattice columns
        points = np.stack([X, Y], axis=-1)
        cell = np.floor(points @ np.linalg.inv(basis).T)
        # The lowest pit at a point has its apex within two lattice cells of it (cant < 35.26°).
        z = np.full(X.shape, np.inf)
        for corner in itertools.product(range(-2, 4), repeat=2):
            offset = points - (cell + np.array(corner)) @ basis.T
            z = np.minimum(z, np.max(offset @ gradients.T, axis=-1))
        depth = _highest_rim(basis, gradients)
        z = z - depth
    z[-1] = z[0]  # exact period along x (a divides the patch)
    extra = {"cubes_along_x": n_x, "depth_um": float(depth), "periodic": "x"}
    return z, None, extra


@dataclass(frozen=True)
class SphericalPitOptions(GeneratorOptions):
    radius_um: float = _length("sphere radius R")
    depth_um: float = _length("pit depth D ≤ R")
    period_um: float = _length("square lattice period Λ (must divide size_um)")


@generator("spherical-pits", SphericalPitOptions)
def _spherical_pits(cells: int, size_um: float, rng, options: SphericalPitOptions):
    """Square lattice (period Λ = ``period_um``, dividing the patch) of spherical caps of radius R
    cut to depth D ≤ R into the plane z = 0: z = (R − D) − √(R² − ρ²) inside the rim radius
    a = √(2RD − D²), 0 outside; the rim must fit the cell (2a ≤ Λ). Periodic."""
    radius_um, depth_um, period_um = options.radius_um, options.depth_um, options.period_um
    if radius_um <= 0:
        raise SurfaceError(f"surface.radius_um must be > 0, got {radius_um}")
    if not 0 < depth_um <= radius_um:
        raise SurfaceError(f"surface.depth_um = {depth_um:g}: must be > 0 and <= radius_um = {radius_um:g} "
                           "(a spherical cap no deeper than a hemisphere)")
    count = _cells_per_period(size_um, period_um)
    rim = np.sqrt(2 * radius_um * depth_um - depth_um**2)
    if 2 * rim > period_um * (1 + 1e-12):
        raise SurfaceError(f"surface.period_um = {period_um:g}: the pits' rim diameter 2√(2RD − D²) = {2 * rim:.6g} µm "
                           f"(radius_um = {radius_um:g}, depth_um = {depth_um:g}) does not fit the cell")
    _check_resolved(2 * rim, "radius_um", "the pits' rim diameter 2√(2RD − D²)", cells, size_um)
    X, Y = _tile_coordinates(cells, size_um)
    rho2 = _cell_offset(X, period_um) ** 2 + _cell_offset(Y, period_um) ** 2
    cap = (radius_um - depth_um) - np.sqrt(np.clip(radius_um**2 - rho2, 0.0, None))
    tile = np.where(rho2 < rim**2, np.minimum(cap, 0.0), 0.0)
    return _periodic_nodes(tile), None, {"rim_radius_um": float(rim), "pits_per_side": count,
                                         "fill": float(np.pi * rim**2 / period_um**2)}


def _cell_offset(t: np.ndarray, period_um: float) -> np.ndarray:
    """Offset of coordinate ``t`` (from the patch corner) from the centre of its lattice cell."""
    return np.mod(t, period_um) - 0.5 * period_um


HEMISPHERE_RANDOM_MAX_FILL = 0.5  # random sequential placement jams near 0.547
HEMISPHERE_FILL_SLACK = 0.05  # square lattice: largest relative change of fill to fit whole cells


PLACEMENTS = ("square", "random")


@dataclass(frozen=True)
class HemisphereOptions(GeneratorOptions):
    radius_um: float = _length("hemisphere radius r")
    fill: float = option(None, required=True, limits=Limits(low=0, low_open=True, high=1, span=(1e-6, 1),
                                                            note="area fraction"),
                         doc="area fraction the footprints cover")
    placement: str = option("square", choices=PLACEMENTS, doc="a square lattice, or random non-overlapping")

    @property
    def draws_at_random(self) -> bool:
        return self.placement == "random"


@generator("hemispheres", HemisphereOptions)
def _hemispheres(cells: int, size_um: float, rng, options: HemisphereOptions):
    """Hemispheres of radius r standing on the plane z = 0, covering the area fraction ``fill``
    (Falster et al.'s HEMISPHERES-like microsurface): z = √(r² − ρ²) within each footprint.

    ``placement = "square"``: a square lattice whose period Λ = r√(π/fill) is rounded so that whole
    cells fill the patch (refused when that changes the fill by more than 5%; fill ≤ π/4, the
    touching limit); ``"random"``: round(fill·L²/(πr²)) non-overlapping hemispheres placed uniformly
    at random (``seed``) with periodic wrap (fill ≤ 0.5). The realized fill is recorded. Periodic.
    """
    radius_um, fill, placement = options.radius_um, options.fill, options.placement
    if radius_um <= 0:
        raise SurfaceError(f"surface.radius_um must be > 0, got {radius_um}")
    _check_resolved(2 * radius_um, "radius_um", "the hemispheres' diameter 2r", cells, size_um)
    X, Y = _tile_coordinates(cells, size_um)
    if placement == "square":
        if not 0 < fill <= np.pi / 4:
            raise SurfaceError(f"surface.fill = {fill:g}: must be in (0, π/4 = 0.7854] for placement = \"square\" "
                               "(π/4: touching hemispheres)")
        per_side = max(1, int(round(size_um / (radius_um * np.sqrt(np.pi / fill)))))
        options = sorted({max(1, per_side - 1), per_side, per_side + 1})
        fills = {n: np.pi * (radius_um * n / size_um) ** 2 for n in options}
        realized = fills[per_side]
        if realized > np.pi / 4 * (1 + 1e-12) or abs(realized / fill - 1) > HEMISPHERE_FILL_SLACK:
            valid = ", ".join(f"{f:.4g} ({n}x{n})" for n, f in fills.items() if f <= np.pi / 4)
            raise SurfaceError(f"surface.fill = {fill:g}: whole lattice cells of radius_um = {radius_um:g} on "
                               f"size_um = {size_um:g} give fill {realized:.4g}; choose one of {valid or 'none'}"
                               " (or placement = \"random\")")
        period = size_um / per_side
        rho2 = _cell_offset(X, period) ** 2 + _cell_offset(Y, period) ** 2
        centres = per_side**2
    elif placement == "random":
        if not 0 < fill <= HEMISPHERE_RANDOM_MAX_FILL:
            raise SurfaceError(f"surface.fill = {fill:g}: must be in (0, {HEMISPHERE_RANDOM_MAX_FILL}] for "
                               "placement = \"random\" (random non-overlapping placement jams near 0.55)")
        if 2 * radius_um > size_um:
            raise SurfaceError(f"surface.radius_um = {radius_um:g}: a hemisphere does not fit the "
                               f"{size_um:g} µm patch")
        centres = max(1, int(round(fill * size_um**2 / (np.pi * radius_um**2))))
        points = _random_disks(rng, centres, radius_um, size_um)
        rho2 = np.full(X.shape, np.inf)
        for cx, cy in points:
            dx = X - cx - size_um * np.round((X - cx) / size_um)
            dy = Y - cy - size_um * np.round((Y - cy) / size_um)
            rho2 = np.minimum(rho2, dx**2 + dy**2)
    else:
        raise SurfaceError(f"surface.placement = {placement!r}: must be {_either(PLACEMENTS)}")
    tile = np.sqrt(np.clip(radius_um**2 - rho2, 0.0, None))
    return _periodic_nodes(tile), None, {"hemispheres": int(centres),
                                         "fill_realized": float(centres * np.pi * radius_um**2 / size_um**2)}


def _random_disks(rng, count: int, radius_um: float, size_um: float, attempts: int = 5000) -> np.ndarray:
    """Centres of ``count`` non-overlapping disks on the periodic square [0, L)² (random sequential
    addition); SurfaceError when it jams."""
    points = np.empty((0, 2))
    for _ in range(count):
        for _ in range(attempts):
            p = rng.uniform(0.0, size_um, 2)
            delta = points - p
            delta -= size_um * np.round(delta / size_um)
            if not len(points) or np.min(np.sum(delta**2, axis=1)) >= (2 * radius_um) ** 2:
                points = np.vstack([points, p])
                break
        else:
            raise SurfaceError(f"surface.fill: cannot place {count} non-overlapping hemispheres of radius_um = "
                               f"{radius_um:g} on size_um = {size_um:g} (placed {len(points)}); lower the fill")
    return points


def _either(choices: tuple[str, ...]) -> str:
    """'"a" or "b"' (the choices of a refusal)."""
    return " or ".join(f'"{c}"' for c in choices)


def generate(name: str, *, cells: int, size_um: float, seed: int = 0, **params) -> HeightField:
    """Build a :class:`HeightField` with generator ``name`` (a key of :data:`GENERATORS`).

    The result records the generator's name, seed and parameters (``parameters``) and, for random
    generators, its :class:`GaussianEnsemble` (``ensemble``).
    """
    if name not in GENERATORS:
        raise SurfaceError(f"surface.generator must be one of {sorted(GENERATORS)}, got {name!r}")
    if int(cells) != cells or cells < MIN_NODES - 1:
        raise SurfaceError(f"surface.cells must be an integer >= {MIN_NODES - 1}, got {cells!r}")
    if not (np.isfinite(size_um) and size_um > 0):
        raise SurfaceError(f"surface.size_um must be a positive number, got {size_um!r}")
    chosen = GENERATORS[name]
    options = chosen.options(params)
    rng = np.random.default_rng(seed)
    out = chosen.draw(int(cells), float(size_um), rng, options)
    z, ensemble, extra = out if isinstance(out, tuple) else (out, None, {})
    periodic = extra.pop("periodic", "".join(a for a, p in zip("xy", _periodic_axes(z)) if p))
    recorded = {"generator": name, "seed": int(seed), **{k: _plain(v) for k, v in params.items()}, **extra,
                "periodic": periodic}
    return HeightField(z, float(size_um), ensemble=ensemble, parameters=recorded)


def refined(field: HeightField, cells: int) -> HeightField:
    """The same surface on a finer grid of ``cells`` cells a side (a mesh-convergence study).

    Deterministic generators (and "hemispheres", whose disk centres do not depend on the grid)
    are rebuilt at ``cells`` from their recorded parameters; a random realization drawn on the
    grid ("gaussian", "brushed") is trigonometrically interpolated from its periodic tile, which
    keeps every coarse node and adds no spectrum above the coarse grid's Nyquist frequency; any
    other field (a file, a cut patch) by bicubic splines through its nodes.
    """
    if int(cells) != cells or cells < field.cells:
        raise SurfaceError(f"refined: cells must be an integer >= the field's {field.cells}, got {cells!r}")
    cells = int(cells)
    chosen = GENERATORS.get((field.parameters or {}).get("generator"))
    if chosen is not None and not chosen.cell_dependent:
        return rebuilt(field, cells)
    if chosen is not None and chosen.cell_dependent and all(field.periodic):
        z = _periodic_nodes(_fourier_interpolated(field.z[:-1, :-1], cells))
    else:
        from scipy.interpolate import RectBivariateSpline

        coarse, fine = np.linspace(0.0, 1.0, field.cells + 1), np.linspace(0.0, 1.0, cells + 1)
        z = RectBivariateSpline(coarse, coarse, field.z, kx=3, ky=3)(fine, fine)
    recorded = None if field.parameters is None else {**field.parameters, "refined_from_cells": field.cells}
    return HeightField(z, field.size_um, field.origin_um, field.ensemble, recorded)


def rebuilt(field: HeightField, cells: int) -> HeightField:
    """The same deterministic surface generated anew at ``cells`` cells a side, finer or coarser:
    a generator whose geometry does not depend on the grid (its :attr:`Generator.cell_dependent`
    false: gratings, cubes, "hemispheres"), from the parameters ``field`` records. A random
    realization drawn on the grid has no version at other cells: refused (:func:`refined` refines it)."""
    if int(cells) != cells or cells < MIN_NODES - 1:
        raise SurfaceError(f"rebuilt: cells must be an integer >= {MIN_NODES - 1}, got {cells!r}")
    chosen = GENERATORS.get((field.parameters or {}).get("generator"))
    if chosen is None:
        raise SurfaceError("rebuilt: the surface records no generator (a file, a cut patch or a subdivided "
                           "surface): it cannot be generated at other cells")
    if chosen.cell_dependent:
        raise SurfaceError(f"rebuilt: a {chosen.name!r} realization is drawn on its grid and has no version at "
                           "other cells (refined interpolates it to finer ones)")
    out = generate_like(field, cells)
    return HeightField(out.z, field.size_um, field.origin_um, out.ensemble, out.parameters)


def generate_like(field: HeightField, cells: int, size_um: float | None = None) -> HeightField:
    """``field``'s generator with its seed and its own parameters (not what it records of its
    realization, e.g. a realized fill or count) at ``cells`` cells a side on a ``size_um`` patch
    (default the field's): the same surface where the generator does not depend on the grid and the
    size is kept (:func:`rebuilt`), a new draw of the same statistics otherwise."""
    params = dict(field.parameters or {})
    chosen = GENERATORS.get(params.pop("generator", None))
    if chosen is None:
        raise SurfaceError("the surface records no generator (a file, a cut patch or a subdivided surface): it "
                           "cannot be generated anew")
    kept = {k: v for k, v in params.items() if k in chosen.keys}
    return generate(chosen.name, cells=int(cells), size_um=field.size_um if size_um is None else size_um,
                    seed=params.get("seed", 0), **kept)


def subdivided(field: HeightField, factor: int) -> HeightField:
    """The same bilinear surface on a grid ``factor`` times finer (a solver-convergence study on a
    fixed geometry): every cell's bilinear patch z = z00 + z10 u + z01 v + z11 u v (the BEM's
    element, bem3d/mesh.py) split into factor² patches by bilinear interpolation of its four
    nodes, so each sub-patch lies on it exactly. Unlike :func:`refined`, the geometry does not
    change: what changes between the two meshes is the solver's discretization alone."""
    if int(factor) != factor or factor < 1:
        raise SurfaceError(f"subdivided: factor must be an integer >= 1, got {factor!r}")
    factor = int(factor)
    z = np.asarray(field.z, dtype=np.float64)
    steps = np.arange(field.cells * factor + 1) / factor  # fine nodes in coarse cell units
    cell = np.minimum(np.floor(steps).astype(np.int64), field.cells - 1)
    t = steps - cell
    a, b = cell[:, None], cell[None, :]
    ti, tj = t[:, None], t[None, :]
    fine = ((1 - ti) * (1 - tj) * z[a, b] + ti * (1 - tj) * z[a + 1, b]
            + (1 - ti) * tj * z[a, b + 1] + ti * tj * z[a + 1, b + 1])
    # no "generator": refined() would rebuild the scene instead of keeping this geometry
    recorded = None if field.parameters is None else {
        **{k: v for k, v in field.parameters.items() if k != "generator"},
        "subdivided_from": field.parameters.get("generator", "heights"), "subdivided_from_cells": field.cells}
    return HeightField(fine, field.size_um, field.origin_um, field.ensemble, recorded)


def _fourier_interpolated(tile: np.ndarray, cells: int) -> np.ndarray:
    """The periodic N×N ``tile`` sampled on an M×M grid by trigonometric interpolation (its
    spectrum zero-padded; an even N's Nyquist row and column split between ±N/2, so the result is
    real and passes through every original node when M is a multiple of N)."""
    n = tile.shape[0]
    low = (n + 1) // 2  # frequencies 0 .. low−1, then the n − low negative ones
    index = np.r_[0:low, cells - (n - low):cells]
    padded = np.zeros((cells, cells), dtype=complex)
    padded[np.ix_(index, index)] = np.fft.fft2(tile)
    if n % 2 == 0 and cells > n:
        minus, plus = cells - n // 2, n // 2
        for axis in (0, 1):
            half = 0.5 * np.take(padded, minus, axis=axis)
            if axis == 0:
                padded[minus, :], padded[plus, :] = half, half
            else:
                padded[:, minus], padded[:, plus] = half, half
    return np.real(np.fft.ifft2(padded)) * (cells / n) ** 2


def _plain(value):
    """Parameter values as HDF5-storable plain types (lists for pairs)."""
    return list(map(float, value)) if np.ndim(value) else value
