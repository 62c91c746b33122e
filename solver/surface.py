"""Height fields: loading, validation, generators and statistics.

A :class:`HeightField` holds an (N+1)×(N+1) matrix of corner heights z[i, j] in µm on a square
patch of side L (µm): row index i ↔ x, column index j ↔ y, spacing d = L/N, and node
coordinates x_i = −L/2 + i·d (the patch is centred on the origin). Between nodes the surface is
the bilinear interpolant (the representation every model shares).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

__all__ = ["HeightField", "SurfaceError", "generate", "load_heights", "GENERATORS"]

MIN_NODES = 4  # at least 3×3 cells


class SurfaceError(ValueError):
    """Invalid height-field input; the message names the problem."""


@dataclass(frozen=True)
class HeightField:
    """Corner heights ``z`` (µm, shape (N+1, N+1)) on a square patch of side ``size_um``."""

    z: np.ndarray
    size_um: float
    origin_um: tuple[float, float] = (0.0, 0.0)  # patch centre in global coordinates

    def __post_init__(self):
        z = np.asarray(self.z, dtype=float)
        if z.ndim != 2:
            raise SurfaceError(f"height matrix must be 2-D, got {z.ndim}-D")
        if z.shape[0] != z.shape[1]:
            raise SurfaceError(f"height matrix must be square ((N+1)x(N+1)), got {z.shape[0]}x{z.shape[1]}")
        if z.shape[0] < MIN_NODES:
            raise SurfaceError(
                f"height matrix is too small: {z.shape[0]}x{z.shape[1]}, need at least "
                f"{MIN_NODES}x{MIN_NODES}"
            )
        if not np.all(np.isfinite(z)):
            bad = np.argwhere(~np.isfinite(z))[0]
            raise SurfaceError(f"height matrix contains NaN/inf (first at row {bad[0]}, column {bad[1]})")
        if not (np.isfinite(self.size_um) and self.size_um > 0):
            raise SurfaceError(f"surface size_um must be a positive number, got {self.size_um!r}")
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

    def statistics(self) -> dict[str, float]:
        """rms height, peak-to-valley, rms / max slope of the bilinear surface (cell centres)."""
        z = self.z - self.z.mean()
        d = self.spacing_um
        zx = 0.5 * (z[1:, 1:] + z[1:, :-1] - z[:-1, 1:] - z[:-1, :-1]) / d
        zy = 0.5 * (z[1:, 1:] - z[1:, :-1] + z[:-1, 1:] - z[:-1, :-1]) / d
        slope = np.hypot(zx, zy)
        return {
            "rms_height_um": float(np.sqrt(np.mean(z**2))),
            "peak_to_valley_um": float(np.ptp(z)),
            "rms_slope": float(np.sqrt(np.mean(slope**2))),
            "max_slope": float(slope.max()),
        }


def load_heights(path: str | Path) -> np.ndarray:
    """Read a height matrix (µm) from ``.npy`` or a comma/whitespace-separated ``.txt``/``.csv``."""
    path = Path(path)
    if not path.is_file():
        raise SurfaceError(f"surface file {str(path)!r} does not exist")
    try:
        if path.suffix == ".npy":
            z = np.load(path, allow_pickle=False)
        else:
            text = path.read_text().replace(",", " ")
            rows = [r.split() for r in text.splitlines() if r.strip() and not r.lstrip().startswith("#")]
            lengths = {len(r) for r in rows}
            if len(lengths) > 1:
                raise SurfaceError(
                    f"surface file {str(path)!r}: rows have different lengths {sorted(lengths)}"
                )
            z = np.array(rows, dtype=float)
    except SurfaceError:
        raise
    except (ValueError, OSError) as exc:
        raise SurfaceError(f"surface file {str(path)!r} cannot be read as a height matrix: {exc}") from exc
    return np.asarray(z, dtype=float)


# ---------------------------------------------------------------------------------------------
# Generators. Each returns an (N+1)x(N+1) height matrix for a patch of side L with N cells.


def _flat(cells: int, size_um: float, rng) -> np.ndarray:
    return np.zeros((cells + 1, cells + 1))


def _gaussian(cells: int, size_um: float, rng, *, rms_height_um: float, correlation_um: float) -> np.ndarray:
    """Gaussian random surface with Gaussian autocorrelation exp(−r²/T²), periodic on the patch.

    Spectral synthesis: white noise filtered by the square root of the Gaussian PSD, then
    scaled to the requested rms height exactly.
    """
    if rms_height_um < 0:
        raise SurfaceError(f"surface.rms_height_um must be >= 0, got {rms_height_um}")
    if correlation_um <= 0:
        raise SurfaceError(f"surface.correlation_um must be > 0, got {correlation_um}")
    n = cells
    d = size_um / cells
    k = 2 * np.pi * np.fft.fftfreq(n, d)
    kx, ky = np.meshgrid(k, k, indexing="ij")
    psd = np.exp(-(kx**2 + ky**2) * correlation_um**2 / 4.0)
    noise = rng.standard_normal((n, n))
    field = np.real(np.fft.ifft2(np.fft.fft2(noise) * np.sqrt(psd)))
    field -= field.mean()
    std = field.std()
    field = field * (rms_height_um / std) if std > 0 else field
    z = np.empty((n + 1, n + 1))
    z[:n, :n] = field
    z[n, :n] = field[0]
    z[:, n] = z[:, 0]
    return z


def _sinusoid(
    cells: int, size_um: float, rng, *, amplitude_um: float, period_um: float, angle_deg: float = 0.0
) -> np.ndarray:
    """h = a cos(2π (x cos α + y sin α)/Λ) with x, y the node coordinates."""
    if period_um <= 0:
        raise SurfaceError(f"surface.period_um must be > 0, got {period_um}")
    x = -0.5 * size_um + size_um / cells * np.arange(cells + 1)
    X, Y = np.meshgrid(x, x, indexing="ij")
    a = np.deg2rad(angle_deg)
    return amplitude_um * np.cos(2 * np.pi * (X * np.cos(a) + Y * np.sin(a)) / period_um)


GENERATORS = {
    "flat": (_flat, ()),
    "gaussian": (_gaussian, ("rms_height_um", "correlation_um")),
    "sinusoid": (_sinusoid, ("amplitude_um", "period_um")),
}
OPTIONAL_PARAMETERS = {"sinusoid": ("angle_deg",)}


def generate(name: str, *, cells: int, size_um: float, seed: int = 0, **params) -> HeightField:
    """Build a :class:`HeightField` with generator ``name`` ("flat" | "gaussian" | "sinusoid")."""
    if name not in GENERATORS:
        raise SurfaceError(f"surface.generator must be one of {sorted(GENERATORS)}, got {name!r}")
    if int(cells) != cells or cells < MIN_NODES - 1:
        raise SurfaceError(f"surface.cells must be an integer >= {MIN_NODES - 1}, got {cells!r}")
    if not (np.isfinite(size_um) and size_um > 0):
        raise SurfaceError(f"surface.size_um must be a positive number, got {size_um!r}")
    func, required = GENERATORS[name]
    missing = [p for p in required if p not in params]
    if missing:
        raise SurfaceError(f"surface.generator = {name!r} needs {', '.join('surface.' + m for m in missing)}")
    allowed = set(required) | set(OPTIONAL_PARAMETERS.get(name, ()))
    unknown = sorted(set(params) - allowed)
    if unknown:
        raise SurfaceError(
            f"surface.generator = {name!r} does not take {', '.join('surface.' + u for u in unknown)}"
        )
    rng = np.random.default_rng(seed)
    return HeightField(func(int(cells), float(size_um), rng, **params), float(size_um))
