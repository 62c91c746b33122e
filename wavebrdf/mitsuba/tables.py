"""A surface dataset turned into the tables the ``"wavebrdf"`` Mitsuba plugin evaluates (NumPy).

Nothing here imports Mitsuba: :func:`load_tables` reads one sweep case of a surface dataset
(``jobs/store.py`` layout) and returns a :class:`Tables`:

* ``f[k, c, i, j]``: the BRDF (1/sr) of table ``k`` in channel ``c`` at pixel centre
  (u_i, v_j) of the dataset's projected-hemisphere grid (u = x, v = y direction cosine of ω_o,
  pixel side 2/res); 0 at pixel centres outside the disk but for the ring of pixels next to it,
  which a bilinear lookup inside the disk reads and which hold their nearest pixel's value inside
  (:func:`_lookup_support`; missing values inside it take the nearest finite pixel's too).
  Channels: the dataset's wavelengths ("spectral"), linear sRGB through the dataset's own
  spectrum → XYZ → sRGB path of ``solver/spectrum.py`` ("rgb", negatives clipped to 0 and
  reported), or its luminance Y ("mono").
* incidence of each table (θ_k, φ_k) and the interpolation ``scheme``: "isotropic" (tables
  rotated to φ = 0, those with equal θ averaged, mirror-symmetrised v → −v, the θ = 0 table
  averaged over rotations; linear in θ), "grid" (a θ × φ product grid: bilinear, φ periodic),
  "nearest" (any other direction set: the nearest tabulated direction).
* sampling tables: per table a piecewise-constant density over the cells between pixel centres
  (:func:`cell_edges`) proportional to the integral of the bilinear channel-mean f times the
  cell's largest μ_o (so positive wherever f is), plus 1 % spread over the disk, as a row
  marginal CDF and per-row conditional CDFs.
* ``shift_gain[k]``: for a table translated by s in (u, v) (the plugin's lobe alignment over
  incidence), A_k(0)/A_k(s), where A_k(s) is the channel-mean albedo of the translated table
  that stays inside the unit disk; on a lattice s = m·h, |m| < SHIFT_BINS, h = 2/SHIFT_BINS,
  capped at MAX_GAIN. Multiplying a translated table by it restores its albedo, so the
  interpolated BRDF's albedo is the interpolation of the tabulated albedos.

Polarized variants (``polarized=True``): f is the unpolarized BRDF M₀₀ of the dataset's Mueller
matrices (stored, or derived from its Jones matrices; frames of ``solver/polarimetry.py``) and
``mueller_ratio`` holds the 15 other elements over M₀₀, in the regular frames of
``solver/polarimetry.py`` (first axes ``regular_axis`` of ω_i and ω_o in the table frame, turned by
the table's incidence azimuth φ_k: smooth across ω_o's pole, unlike the dataset's s/p frames, and
turning with the incidence like them), each blurred like f and combined over
wavelengths into channels before the division (|ratio| ≤ 1); read one wavelength at a time. The
isotropic mirror v → −v negates the elements that couple (I, Q) with (U, V) (a mirror flips U and
V); it and the rotation to φ_i = 0 are done in the s/p frames, which turn with the geometry.

Speckle: a computed BRDF of one surface realization under a finite footprint is speckled; the
tables are blurred by a Gaussian of standard deviation ``smooth_sigma`` (u units, per wavelength)
within the unit disk, keeping each table's albedo (:func:`_smooth`).
Default: λ/(2π w) with w the config's ``illumination.waist_um``, the angular spread of the
footprint's own far-field intensity (exp(−r²/w²) amplitude → exp(−k²w²Δu²/2) intensity); 0 when
the config names no waist.
"""

from __future__ import annotations

import logging
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from wavebrdf.jobs.store import Dataset
from wavebrdf.jobs.study_kinds import STUDY_KINDS, study_kind
from wavebrdf.solver.polarimetry import to_regular_frames
from wavebrdf.solver.spectrum import outside_visible, spectral_weights, xyz_to_linear_srgb
from wavebrdf.solver.surface import GENERATORS, SurfaceError

__all__ = ["CHANNELS", "SCHEMES", "Tables", "case_config", "cell_edges", "channel_matrix", "isotropy_from_config",
           "load_tables", "open_for_plugin"]

logger = logging.getLogger("wavebrdf")

CHANNELS = ("spectral", "rgb", "mono")
SCHEMES = ("isotropic", "grid", "nearest")
DEFENSIVE = 0.01  # fraction of the sampling density spread over the disk
ANGLE_TOL_DEG = 1e-6
SHIFT_BINS = 64  # coarse grid of the translated-albedo table (per axis over the disk's diameter)
MAX_GAIN = 4.0


@dataclass
class Tables:
    """What the plugin evaluates; see the module docstring. Angles in radians."""

    f: np.ndarray  # (n_tab, C, res, res) float32, 1/sr
    channels: str
    wavelengths_um: np.ndarray  # dataset wavelengths (the channel axis when channels == "spectral")
    theta: np.ndarray  # (n_tab,) incidence polar angle of each table
    phi: np.ndarray  # (n_tab,) incidence azimuth (0 for every isotropic table)
    scheme: str
    grid_theta: np.ndarray  # (n_T,) sorted θ rows (scheme "grid"; the θ of each table for "isotropic")
    grid_phi: np.ndarray  # (n_P,) sorted φ columns in [0, 2π) (scheme "grid")
    grid_index: np.ndarray  # (n_T, n_P) table index of each grid node (scheme "grid")
    pmf: np.ndarray  # (n_tab, res + 1, res + 1) probability of each sampling cell (sums to 1)
    row_cdf: np.ndarray  # (n_tab, res + 2)
    col_cdf: np.ndarray  # (n_tab, res + 1, res + 2)
    shift_gain: np.ndarray  # (n_tab, 2 SHIFT_BINS − 1, 2 SHIFT_BINS − 1)
    diagnostics: dict = field(default_factory=dict)
    mueller_ratio: np.ndarray | None = None  # (n_tab, 15 C, res, res): M[e]/M[0, 0], e = 1…15 row-major, channel-minor

    @property
    def shift_step(self) -> float:
        """Lattice step h of ``shift_gain`` (u units); entry (a, b) is s = ((a, b) − (M − 1)) h."""
        return 2.0 / SHIFT_BINS

    @property
    def resolution(self) -> int:
        return self.f.shape[-1]

    @property
    def pixel(self) -> float:
        """Pixel side Δu = Δv = 2/res."""
        return 2.0 / self.resolution

    def albedo(self, k: int) -> np.ndarray:
        """(C,) Σ f Δu Δv of table ``k`` over the pixels whose centres lie inside the unit disk (the
        dataset's albedo sum; the ring beyond them only serves the lookup)."""
        return np.sum(self.f[k].astype(np.float64) * _disk(self.resolution), axis=(-2, -1)) * self.pixel ** 2

    @property
    def incident_uv(self) -> np.ndarray:
        """(n_tab, 2) projected incident directions a_k = sin θ_k (cos φ_k, sin φ_k)."""
        return np.sin(self.theta)[:, None] * np.stack([np.cos(self.phi), np.sin(self.phi)], axis=-1)


def case_config(config_text: str, swept: dict | None = None) -> dict:
    """The study's config (TOML text) as one sweep case saw it: ``swept`` {dotted key: value}
    replaces the base values (a waist or a correlation length may be swept); {} if unreadable."""
    try:
        config = tomllib.loads(config_text)
    except tomllib.TOMLDecodeError:
        return {}
    for key, value in (swept or {}).items():
        *sections, last = key.split(".")
        table = config
        for section in sections:
            table = table.setdefault(section, {})
        table[last] = value.tolist() if isinstance(value, (np.ndarray, np.generic)) else value
    return config


def isotropy_from_config(config: dict) -> tuple[bool, str]:
    """Whether the study's surface is declared statistically isotropic, and why: its generator's
    options say so (``isotropic`` of solver/surface.py's registry: a flat surface, a gaussian
    ensemble with one correlation length). Surfaces from files are not. ``config``: the case's
    (:func:`case_config`)."""
    if not config:
        return False, "config unreadable: not declared isotropic"
    surface = config.get("surface", {})
    chosen = GENERATORS.get(surface.get("generator"))
    if chosen is None:
        return False, "config: surface from a file, not declared isotropic"
    try:
        isotropic = chosen.options({k: v for k, v in surface.items() if k in chosen.keys}).isotropic
    except SurfaceError as exc:
        return False, f"config: {exc}; not declared isotropic"
    return isotropic, f"config: {chosen.name} surface {'statistically isotropic' if isotropic else 'not isotropic'}"


def open_for_plugin(path, kind: str, channels: str) -> Dataset:
    """Open ``path`` for the plugin of datasets of ``kind`` ("surface" or "fiber"; the study kind's
    ``plugin``), checking the channel kind and the dataset kind (messages name the plugin and the
    property)."""
    plugin = study_kind(kind).plugin
    if channels not in CHANNELS:
        raise ValueError(f"[{plugin} plugin] channels = {channels!r}: expected one of {', '.join(CHANNELS)}")
    ds = Dataset(path)
    if ds.kind != kind:
        ds.close()
        others = "; ".join(f'{k.name}s: "{k.plugin}"' for k in STUDY_KINDS.values() if k.name != kind)
        raise ValueError(f"[{plugin} plugin] filename = {str(path)!r}: a {ds.kind} dataset; the \"{plugin}\" "
                         f"plugin reads {kind} datasets ({others})")
    return ds


def _waist_um(config: dict) -> float | None:
    waist = config.get("illumination", {}).get("waist_um")
    return float(waist) if waist else None


def _pixel_centres(res: int) -> np.ndarray:
    return 2.0 * (np.arange(res) + 0.5) / res - 1.0


def _disk(res: int) -> np.ndarray:
    """The pixels whose centres lie inside the unit disk (res × res, boolean)."""
    centres = _pixel_centres(res)
    return centres[:, None] ** 2 + centres[None, :] ** 2 < 1.0


def _lookup_support(res: int) -> np.ndarray:
    """The pixels a bilinear lookup inside the unit disk reads: the disk's pixels and the ring of
    pixels next to them (8-neighbours), whose centres lie outside it. The ring keeps its filled-in
    values (the nearest pixel's inside, :func:`_fill_outside`), so a query between the last pixel
    centre inside the disk and the rim is not interpolated toward 0 (which lost 1.5 % of a broad
    lobe's albedo from θ_i = 70°); everything beyond the ring is 0."""
    from scipy.ndimage import binary_dilation

    return binary_dilation(_disk(res), structure=np.ones((3, 3), dtype=bool))


def _fill_outside(cube: np.ndarray, where: str, axes: str = "(wavelength, incidence)") -> tuple[np.ndarray, int]:
    """Replace non-finite pixels of each (…, res, res) image by the nearest finite pixel (one
    distance transform per distinct mask: usually just the disk's)."""
    from scipy.ndimage import distance_transform_edt

    out = np.array(cube, dtype=np.float64)
    filled = 0
    flat = out.reshape(-1, *out.shape[-2:])
    nearest: dict[bytes, tuple] = {}
    for n, image in enumerate(flat):
        bad = ~np.isfinite(image)
        if not bad.any():
            continue
        if bad.all():
            raise ValueError(f"{where}: image {np.unravel_index(n, out.shape[:-2])} {axes} "
                             "holds no finite value (a failed task?)")
        key = np.packbits(bad).tobytes()
        if key not in nearest:
            nearest[key] = tuple(distance_transform_edt(bad, return_distances=False, return_indices=True))
        flat[n] = image[nearest[key]]
        filled += int(bad.sum())
    return out, filled


def _rotate(image: np.ndarray, phi: float) -> np.ndarray:
    """Image re-expressed in a frame rotated by −φ: g(p) = f(R(φ) p) (bilinear, edge-clamped)."""
    from scipy.ndimage import map_coordinates

    if abs(np.remainder(phi + np.pi, 2 * np.pi) - np.pi) < 1e-12:
        return image
    res = image.shape[-1]
    U, V = np.meshgrid(_pixel_centres(res), _pixel_centres(res), indexing="ij")
    c, s = np.cos(phi), np.sin(phi)
    su, sv = c * U - s * V, s * U + c * V
    coords = np.stack([(su + 1.0) * res / 2.0 - 0.5, (sv + 1.0) * res / 2.0 - 0.5])
    return np.stack([map_coordinates(ch, coords, order=1, mode="nearest") for ch in image])


def _radial_average(image: np.ndarray) -> np.ndarray:
    """Average of each channel over rotations about the pole (binned in the radius)."""
    res = image.shape[-1]
    U, V = np.meshgrid(_pixel_centres(res), _pixel_centres(res), indexing="ij")
    r = np.hypot(U, V)
    bins = np.minimum((r / (2.0 / res)).astype(int), int(np.ceil(np.sqrt(2) * res / 2)))
    counts = np.bincount(bins.ravel())
    out = np.empty_like(image)
    for c, ch in enumerate(image):
        profile = np.bincount(bins.ravel(), weights=ch.ravel()) / np.maximum(counts, 1)
        out[c] = profile[bins]
    return out


def _smooth(cube: np.ndarray, sigma_u: np.ndarray) -> np.ndarray:
    """Gaussian blur of each wavelength's images (cube: n_tab, L, res, res) by σ (u units) within
    the unit disk: the blur of f·D over the blur of D (D the pixels whose centres are inside), so
    the values filled in outside never enter, then scaled to the image's own sum over D, so each
    table keeps its albedo (Σ f Δu Δv) where the blur reaches the rim."""
    from scipy.ndimage import gaussian_filter

    res = cube.shape[-1]
    inside = _disk(res).astype(float)
    out = cube.copy()
    for wl, sigma in enumerate(sigma_u):
        if sigma > 0:
            width = sigma * res / 2.0
            weight = gaussian_filter(inside, width, mode="constant")
            for k in range(cube.shape[0]):
                image = np.where(inside > 0, cube[k, wl], 0.0)
                blurred = gaussian_filter(image, width, mode="constant") / np.maximum(weight, 1e-300)
                total, kept = image.sum(), (blurred * inside).sum()
                out[k, wl] = np.where(inside > 0, blurred * (total / kept if kept > 0 else 1.0), cube[k, wl])
    return out


def channel_matrix(wavelengths_um: np.ndarray, channels: str) -> np.ndarray:
    """(C, L): spectrum sampled at ``wavelengths_um`` → linear sRGB ("rgb") or luminance Y ("mono")."""
    weights = spectral_weights(wavelengths_um)  # XYZ = W @ spectrum
    return weights[1:2] if channels == "mono" else xyz_to_linear_srgb(weights.T).T


def _to_channels(cube: np.ndarray, wavelengths_um: np.ndarray, channels: str) -> tuple[np.ndarray, float]:
    """(n_tab, L, res, res) spectra → (n_tab, C, res, res); returns the clipped (negative) fraction."""
    if channels == "spectral":
        return cube, 0.0
    matrix = channel_matrix(wavelengths_um, channels)  # (C, L)
    out = np.einsum("cl,klij->kcij", matrix, cube)
    negative = float(np.mean(out < 0))
    return np.maximum(out, 0.0), negative


def _grid_layout(theta_deg: np.ndarray, phi_deg: np.ndarray):
    """θ rows, φ columns and the table of each node when the directions form a θ × φ product grid
    (one θ = 0 direction may stand for every φ); None otherwise."""
    phi_deg = np.remainder(phi_deg, 360.0)
    polar = theta_deg > ANGLE_TOL_DEG
    thetas = np.unique(np.round(theta_deg[polar], 9))
    phis = np.unique(np.round(phi_deg[polar], 9))
    normal = np.flatnonzero(~polar)
    if len(normal) > 1 or len(thetas) == 0:
        return None
    index = np.full((len(thetas), len(phis)), -1, dtype=np.int64)
    for k in np.flatnonzero(polar):
        t = np.searchsorted(thetas, np.round(theta_deg[k], 9))
        p = np.searchsorted(phis, np.round(phi_deg[k], 9))
        if index[t, p] >= 0:
            return None
        index[t, p] = k
    if (index < 0).any():
        return None
    if len(normal):
        thetas = np.concatenate([[0.0], thetas])
        index = np.concatenate([np.full((1, len(phis)), normal[0]), index])
    return np.deg2rad(thetas), np.deg2rad(phis), index


def cell_edges(res: int) -> np.ndarray:
    """Edges (res + 2,) of the sampling cells along u (or v): −1, the res pixel centres, +1.
    Cell i spans [edges[i], edges[i+1]]; on it the bilinear f interpolates its corner nodes."""
    return np.concatenate([[-1.0], _pixel_centres(res), [1.0]])


def _sampling(f: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cell pmf and its row-marginal and per-row conditional CDFs.

    The cells lie between pixel centres (:func:`cell_edges`, (res + 1)² per table), where the
    bilinear f is spanned by the four corner nodes: weight = channel-mean corner average × cell
    area × the largest μ in the cell (positive wherever f is), plus DEFENSIVE spread over the
    cells that touch the disk."""
    n_tab, res = f.shape[0], f.shape[-1]
    edges = cell_edges(res)
    width = np.diff(edges)
    near = np.where(edges[:-1] * edges[1:] <= 0, 0.0, np.minimum(np.abs(edges[:-1]), np.abs(edges[1:])))
    r_min2 = near[:, None] ** 2 + near[None, :] ** 2
    touches = r_min2 < 1.0
    mu_max = np.sqrt(np.clip(1.0 - r_min2, 0.0, None))
    padded = np.pad(f.mean(axis=1), ((0, 0), (1, 1), (1, 1)), mode="edge")  # nodes, edge-clamped
    corners = 0.25 * (padded[:, :-1, :-1] + padded[:, 1:, :-1] + padded[:, :-1, 1:] + padded[:, 1:, 1:])
    weight = corners * (width[:, None] * width[None, :]) * mu_max * touches
    total = weight.sum(axis=(1, 2), keepdims=True)
    if np.any(total <= 0):
        raise ValueError("a table has no positive value on the disk: nothing to sample")
    area = (width[:, None] * width[None, :]) * touches
    pmf = (1.0 - DEFENSIVE) * weight / total + DEFENSIVE * area / area.sum()
    row_cdf = np.concatenate([np.zeros((n_tab, 1)), np.cumsum(pmf.sum(axis=2), axis=1)], axis=1)
    row_cdf /= row_cdf[:, -1:]
    col_cdf = np.concatenate([np.zeros((n_tab, res + 1, 1)), np.cumsum(pmf, axis=2)], axis=2)
    col_cdf /= np.where(col_cdf[:, :, -1:] > 0, col_cdf[:, :, -1:], 1.0)
    return pmf, row_cdf, col_cdf


def _shift_gain(f: np.ndarray) -> np.ndarray:
    """A_k(0)/A_k(s) on the lattice s = m·h (see the module docstring), from the channel-mean
    tables binned onto SHIFT_BINS² cells: A(m) = Σ_c G[c] · [cell c − m lies in the disk]."""
    from scipy.signal import fftconvolve

    n_tab, res = f.shape[0], f.shape[-1]
    centres = _pixel_centres(res)
    cell = np.minimum(((centres + 1.0) / 2.0 * SHIFT_BINS).astype(int), SHIFT_BINS - 1)
    mass = f.mean(axis=1) * _disk(res) * (2.0 / res) ** 2  # (n_tab, res, res), the disk's pixels
    coarse = np.zeros((n_tab, SHIFT_BINS, SHIFT_BINS))
    np.add.at(coarse, (slice(None), cell[:, None], cell[None, :]), mass)
    c = _pixel_centres(SHIFT_BINS)
    disk = (c[:, None] ** 2 + c[None, :] ** 2 < 1.0).astype(float)
    # correlate: A[m] = Σ_i G[i] D[i − m], m = −(B − 1)…B − 1  ⇔  full convolution with D flipped
    albedo = np.stack([fftconvolve(g, disk[::-1, ::-1], mode="full") for g in coarse])
    albedo = np.maximum(albedo, 0.0)
    centre = albedo[:, SHIFT_BINS - 1, SHIFT_BINS - 1][:, None, None]
    return np.minimum(centre / np.maximum(albedo, centre / MAX_GAIN), MAX_GAIN)


def load_tables(path: str | Path, *, case: int = 0, channels: str = "rgb", smooth_sigma: float | None = None,
                isotropic: bool | None = None, polarized: bool = False) -> Tables:
    """Read sweep case ``case`` (flat C-order index over the sweep axes) of surface dataset
    ``path`` into :class:`Tables` (see the module docstring).

    ``smooth_sigma``: speckle blur in u units (None: λ/(2π w) from the config, 0: none).
    ``isotropic``: use rotation invariance in φ (None: as the config declares it).
    ``polarized``: also the Mueller ratio tables (a dataset with Jones or Mueller matrices).
    """
    start = time.perf_counter()
    where = f"[wavebrdf plugin] filename = {str(path)!r}"
    with open_for_plugin(path, "surface", channels) as ds:
        coords = ds.coords
        lead = ds.sweep_shape
        n_cases = int(np.prod(lead))
        if not 0 <= case < n_cases:
            raise ValueError(f"[wavebrdf plugin] case = {case}: the dataset has {n_cases} sweep case(s) "
                             f"(flat index over {ds.sweep_keys or 'no sweep'})")
        case_index = np.unravel_index(case, lead) if lead else ()
        brdf = np.asarray(ds.h5["brdf"][tuple(int(i) for i in case_index)], dtype=np.float64)  # (L, n_inc, res, res)
        if polarized:
            if ds.polarimetry == "intensity":
                raise ValueError(f"{where}: a polarized variant needs the dataset's Jones or Mueller matrices; run "
                                 "its study with [output] polarization = \"jones\" (or \"mueller\")")
            lead = tuple(int(i) for i in case_index)  # the unpolarized BRDF M00, one wavelength at a time
            brdf = np.stack([np.asarray(ds.mueller(lead + (n,))[:, 0, 0], dtype=np.float64)
                             for n in range(brdf.shape[0])])
        config = case_config(ds.config, {key: coords[key][i] for key, i in zip(ds.sweep_keys, case_index)})
        polarization = ds.brdf_polarization
        albedo = np.asarray(ds.h5["albedo"][tuple(int(i) for i in case_index)], dtype=float)
    wavelengths = np.asarray(coords["wavelength_um"], dtype=float)
    order = np.argsort(wavelengths)
    wavelengths, brdf, albedo = wavelengths[order], brdf[order], albedo[order]
    theta_deg = np.asarray(coords["theta_i"], dtype=float)
    phi_deg = np.asarray(coords["phi_i"], dtype=float)

    cube, filled = _fill_outside(brdf, where)
    cube = np.moveaxis(cube, 1, 0)  # (n_inc, L, res, res)

    if isotropic is None:
        isotropic, why = isotropy_from_config(config)
    else:
        why = "plugin property"
    if isotropic:
        cube, theta = _canonical_isotropic(cube, theta_deg, phi_deg)
        phi = np.zeros_like(theta)
        scheme, grid_theta, grid_phi, grid_index = "isotropic", theta, np.zeros(1), np.arange(len(theta))[:, None]
    else:
        theta, phi = np.deg2rad(theta_deg), np.deg2rad(np.remainder(phi_deg, 360.0))
        layout = _grid_layout(theta_deg, phi_deg)
        if layout is None:
            scheme, grid_theta, grid_phi, grid_index = "nearest", theta, np.zeros(1), np.arange(len(theta))[:, None]
        else:
            scheme, (grid_theta, grid_phi, grid_index) = "grid", layout

    waist = _waist_um(config)
    if smooth_sigma is None:
        sigma = wavelengths / (2 * np.pi * waist) if waist else np.zeros_like(wavelengths)
    else:
        if not np.isfinite(smooth_sigma) or smooth_sigma < 0:
            raise ValueError(f"[wavebrdf plugin] smooth_sigma = {smooth_sigma!r}: must be a finite number >= 0 "
                             "(u units)")
        sigma = np.full_like(wavelengths, float(smooth_sigma))
    cube = _smooth(cube, sigma)
    f, clipped = _to_channels(cube, wavelengths, channels)
    f, _ = _fill_outside(np.where(_disk(f.shape[-1]), f, np.nan), where)  # the ring: its nearest pixel inside
    f[..., ~_lookup_support(f.shape[-1])] = 0.0
    ratio = None
    if polarized:
        ratio = _mueller_ratio(path, tuple(int(i) for i in case_index), order, theta_deg, phi_deg, bool(isotropic),
                               sigma, wavelengths, channels, where)
    pmf, row_cdf, col_cdf = _sampling(f)
    diagnostics = {
        "scheme": scheme,
        "isotropic": bool(isotropic),
        "isotropy_source": why,
        "tables": len(f),
        "resolution": f.shape[-1],
        "wavelengths_um": wavelengths.tolist(),
        "polarization": polarization,
        "smooth_sigma_u": sigma.tolist(),
        "filled_pixels": filled,
        "rgb_negative_fraction": clipped,
        "albedo_max": float(np.nanmax(albedo)) if np.isfinite(albedo).any() else float("nan"),
        "albedo_above_one": int(np.sum(albedo > 1.0)),
        "load_seconds": time.perf_counter() - start,
    }
    diagnostics["channels_note"] = (outside_visible(wavelengths) if channels != "spectral" else None) or ""
    if not polarized and polarization not in ("", "unpolarized"):  # logged by the plugin (bsdfs.py)
        diagnostics["polarization_note"] = (
            f"the dataset's BRDF is {polarization}-polarized ([illumination] polarization = \"{polarization}\") and "
            "renders as the unpolarized BRDF a renderer expects (for flat glass at 60°, R_s = 0.177 against "
            "(R_s + R_p)/2 = 0.089): run the study unpolarized, or with [output] polarization = \"jones\" for the "
            "polarized variants")
    if diagnostics["channels_note"]:
        logger.warning("%s, channels = %r: %s", where, channels, diagnostics["channels_note"])
    if diagnostics["albedo_above_one"]:
        logger.warning("%s: %d stored albedo(s) exceed 1 (max %.4f): the model's energy bound is violated",
                       where, diagnostics["albedo_above_one"], diagnostics["albedo_max"])
    return Tables(f=f.astype(np.float32), channels=channels, wavelengths_um=wavelengths, theta=theta, phi=phi,
                  scheme=scheme, grid_theta=grid_theta, grid_phi=grid_phi, grid_index=grid_index, pmf=pmf,
                  row_cdf=row_cdf, col_cdf=col_cdf, shift_gain=_shift_gain(f), diagnostics=diagnostics,
                  mueller_ratio=ratio)


MIRROR_SIGN = np.outer([1, 1, -1, -1], [1, 1, -1, -1]).ravel()  # Mueller elements under the mirror v → −v


def _mueller_ratio(path, case_index: tuple, order: np.ndarray, theta_deg: np.ndarray, phi_deg: np.ndarray,
                   isotropic: bool, sigma_u: np.ndarray, wavelengths_um: np.ndarray, channels: str,
                   where: str) -> np.ndarray:
    """(n_tab, 15·C, res, res) ratios M[e]/M[0, 0] per channel (element-major), one wavelength at a
    time (``order``: the dataset's wavelength indices in ascending λ): the Mueller matrices filled
    outside the disk, made canonical like f (isotropic: rotated to φ_i = 0, averaged per θ,
    mirror-symmetrised with MIRROR_SIGN), turned from the s/p frames to the regular frames of
    ``solver/polarimetry.py`` taken about each table's own incidence azimuth φ_k (``to_regular_frames``
    with reference φ_k: smooth across ω_o's pole, so blur and bilinear lookup are meaningful there,
    and turning with the incidence like the s/p frames, so tables of neighbouring φ_k blend in the
    query's frames; the plugin turns a θ = 0 table's to the query's azimuth, since there the frames
    do not follow the incidence), blurred within the disk (no albedo rescaling: it cancels in the ratio), combined over
    wavelengths into channels, divided, clipped to [−1, 1]; 0 beyond the lookup's ring
    (:func:`_lookup_support`)."""
    from scipy.ndimage import gaussian_filter

    combined = None
    with Dataset(path) as ds:
        for n, l in enumerate(order):
            M = np.asarray(ds.mueller(case_index + (int(l),)), dtype=np.float32)  # (n_inc, 4, 4, res, res)
            n_inc, res = M.shape[0], M.shape[-1]
            M, _ = _fill_outside(M.reshape(n_inc, 16, res, res), f"{where} (wavelength index {int(l)})",
                                 "(incidence, Mueller element)")
            if isotropic:
                M, _ = _canonical_isotropic(M, theta_deg, phi_deg, MIRROR_SIGN)
                table_phi = np.zeros(len(M))
            else:
                table_phi = np.deg2rad(phi_deg)
            centres = _pixel_centres(res)
            U, V = np.meshgrid(centres, centres, indexing="ij")
            inside = _disk(res)
            M = np.stack([to_regular_frames(m.reshape(4, 4, res, res), U, V, phi, reference_phi=phi)
                          for m, phi in zip(M, table_phi)])
            if sigma_u[n] > 0:
                width = sigma_u[n] * res / 2.0
                weight = np.maximum(gaussian_filter(inside.astype(float), width, mode="constant"), 1e-300)
                for k in range(len(M)):
                    for e in range(16):
                        image = np.where(inside, M[k, e // 4, e % 4], 0.0)
                        M[k, e // 4, e % 4] = gaussian_filter(image, width, mode="constant") / weight
            M = M.reshape(len(M), 16, res, res).astype(np.float32)
            if combined is None:
                n_chan = len(wavelengths_um) if channels == "spectral" else channel_matrix(wavelengths_um, channels).shape[0]
                combined = np.zeros((len(M), n_chan, 16, res, res), dtype=np.float32)
            if channels == "spectral":
                combined[:, n] = M
            else:
                weights = channel_matrix(wavelengths_um, channels)[:, n]
                combined += weights[None, :, None, None, None].astype(np.float32) * M[:, None]
    m00 = combined[:, :, :1]
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(m00 > 0, combined[:, :, 1:] / np.where(m00 > 0, m00, 1.0), 0.0)
    ratio = np.clip(ratio, -1.0, 1.0) * _lookup_support(ratio.shape[-1])
    return np.ascontiguousarray(np.moveaxis(ratio, 2, 1).reshape(len(ratio), -1, *ratio.shape[-2:])).astype(np.float32)


def _canonical_isotropic(cube: np.ndarray, theta_deg: np.ndarray, phi_deg: np.ndarray,
                         mirror_sign: np.ndarray | None = None):
    """Tables of an isotropic surface rotated to φ_i = 0, averaged per θ, symmetrised (v → −v, each
    channel times its ``mirror_sign``, default +1; rotation average at θ = 0 for intensities only:
    Mueller elements (``mirror_sign`` given) are tied to the incident s/p frame, which rotates with
    the table); returns (tables sorted by θ, θ in radians)."""
    keys = np.round(theta_deg, 9)
    thetas = np.unique(keys)
    sign = np.ones(cube.shape[1]) if mirror_sign is None else np.asarray(mirror_sign, dtype=float)
    out = np.empty((len(thetas),) + cube.shape[1:])
    for t, value in enumerate(thetas):
        members = np.flatnonzero(keys == value)
        mean = np.mean([_rotate(cube[k], np.deg2rad(phi_deg[k])) for k in members], axis=0)
        mean = 0.5 * (mean + sign[:, None, None] * mean[..., ::-1])
        out[t] = _radial_average(mean) if value <= ANGLE_TOL_DEG and mirror_sign is None else mean
    return out, np.deg2rad(thetas)
