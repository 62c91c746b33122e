"""Surface generators of the scenes that separate the ladder's rungs (solver/surface.py): their
statistics against their parameters, their geometry (cube corners, spherical caps, hemispheres)
from first principles, periodicity, the ensemble they record, refusals, and the statistics each
writes into a dataset through the CLI."""

from __future__ import annotations

import dataclasses
import itertools
import logging
import textwrap

import h5py
import numpy as np
import pytest

from wavebrdf.jobs.cli import main
from wavebrdf.jobs.config import SCHEMA, ConfigError, parse_config
from wavebrdf.solver.surface import GENERATORS, GaussianEnsemble, HeightField, SurfaceError, generate, refined

logger = logging.getLogger(__name__)


def cell_slopes(surface: HeightField) -> tuple[np.ndarray, np.ndarray]:
    """∂z/∂x, ∂z/∂y of the bilinear surface at the cell centres (written here from the bilinear
    interpolant, not taken from wavebrdf)."""
    z, d = surface.z, surface.spacing_um
    zx = 0.5 * (z[1:, 1:] + z[1:, :-1] - z[:-1, 1:] - z[:-1, :-1]) / d
    zy = 0.5 * (z[1:, 1:] - z[1:, :-1] + z[:-1, 1:] - z[:-1, :-1]) / d
    return zx, zy


def slope_axis_deg(surface: HeightField) -> float:
    """Direction (degrees, mod 180) of the smallest slope variance: the long correlation axis."""
    zx, zy = cell_slopes(surface)
    cov = np.cov(np.stack([zx.ravel(), zy.ravel()]))
    values, vectors = np.linalg.eigh(cov)
    v = vectors[:, 0]
    return float(np.rad2deg(np.arctan2(v[1], v[0])) % 180.0)


def angle_difference_deg(a: float, b: float) -> float:
    return abs((a - b + 90.0) % 180.0 - 90.0)


# ============================================================================================
# Gaussian ensembles: "gaussian" (scalar or [T_x', T_y'] + angle) and "brushed"


def original_gaussian(cells, size_um, seed, rms, corr):
    """The isotropic generator as it was before anisotropy was added (its outputs are in datasets)."""
    rng = np.random.default_rng(seed)
    n, d = cells, size_um / cells
    k = 2 * np.pi * np.fft.fftfreq(n, d)
    kx, ky = np.meshgrid(k, k, indexing="ij")
    psd = np.exp(-(kx**2 + ky**2) * corr**2 / 4.0)
    field = np.real(np.fft.ifft2(np.fft.fft2(rng.standard_normal((n, n))) * np.sqrt(psd)))
    field -= field.mean()
    field = field * (rms / field.std())
    z = np.empty((n + 1, n + 1))
    z[:n, :n] = field
    z[n, :n] = field[0]
    z[:, n] = z[:, 0]
    return z


def test_isotropic_gaussian_is_bit_identical_to_the_original():
    for cells, size, seed, rms, corr in ((64, 8.0, 3, 0.1, 1.0), (33, 3.0, 0, 0.05, 0.3), (40, 4.0, 2, 0.05, 0.8)):
        surface = generate("gaussian", cells=cells, size_um=size, seed=seed, rms_height_um=rms, correlation_um=corr)
        assert np.array_equal(surface.z, original_gaussian(cells, size, seed, rms, corr))
        assert surface.ensemble == GaussianEnsemble(rms, (corr, corr), 0.0)
        # an equal pair is the same isotropic surface
        pair = generate("gaussian", cells=cells, size_um=size, seed=seed, rms_height_um=rms,
                        correlation_um=[corr, corr])
        assert np.array_equal(pair.z, surface.z)


@pytest.mark.parametrize("correlation,angle", [(1.0, None), ([2.0, 0.6], 30.0), ([0.7, 1.8], -50.0)],
                         ids=["isotropic", "rotated-30", "rotated-minus-50"])
def test_gaussian_statistics_match_the_parameters(correlation, angle):
    """rms height exact; 1/e correlation lengths along x and y (mean of 8 realizations on a 32 µm
    patch) within 6% of exp(−x'²/T_x'² − y'²/T_y'²) cut along the axes, L_x = (cos²α/T_x'² +
    sin²α/T_y'²)^(−1/2); the long axis of the slope covariance within 4° of α; rms slope within
    5% of √(2σ²(1/T_x'² + 1/T_y'²))."""
    sigma, size, cells = 0.1, 32.0, 256
    params = dict(rms_height_um=sigma, correlation_um=correlation)
    if angle is not None:
        params["angle_deg"] = angle
    tx, ty = (correlation, correlation) if np.ndim(correlation) == 0 else correlation
    a = np.deg2rad(angle or 0.0)
    expected = (1 / np.sqrt(np.cos(a) ** 2 / tx**2 + np.sin(a) ** 2 / ty**2),
                1 / np.sqrt(np.sin(a) ** 2 / tx**2 + np.cos(a) ** 2 / ty**2))
    lengths, axes, slopes = [], [], []
    for seed in range(8):
        surface = generate("gaussian", cells=cells, size_um=size, seed=seed, **params)
        stats = surface.statistics()
        assert stats["rms_height_um"] == pytest.approx(sigma, rel=1e-12)
        assert surface.ensemble == GaussianEnsemble(sigma, (tx, ty), angle or 0.0)
        assert surface.periodic == (True, True) and surface.parameters["periodic"] == "xy"
        lengths.append((stats["correlation_length_x_um"], stats["correlation_length_y_um"]))
        axes.append(slope_axis_deg(surface))
        slopes.append(stats["rms_slope"])
    measured = np.mean(lengths, axis=0)
    logger.info("T = %s, α = %s: correlation lengths %s (spread %s) vs %s; slope axis %s; rms slope %.4f vs %.4f",
                correlation, angle, measured, np.std(lengths, axis=0), expected, np.round(axes, 1),
                np.mean(slopes), np.sqrt(2 * sigma**2 * (1 / tx**2 + 1 / ty**2)))
    assert np.all(np.abs(measured / np.array(expected) - 1) < 0.06)
    assert np.mean(slopes) == pytest.approx(np.sqrt(2 * sigma**2 * (1 / tx**2 + 1 / ty**2)), rel=0.05)
    if tx != ty:
        long_axis = np.rad2deg(a) if tx > ty else np.rad2deg(a) + 90.0
        assert all(angle_difference_deg(x, long_axis) < 4.0 for x in axes), axes


def test_brushed_grooves():
    """Along/across lengths and the groove direction; defaults [L/4, L/40] along x; an ensemble."""
    surface = generate("brushed", cells=256, size_um=32.0, seed=1, rms_height_um=0.05,
                       correlation_um=[4.0, 0.4], angle_deg=70.0)
    assert surface.ensemble == GaussianEnsemble(0.05, (4.0, 0.4), 70.0)
    assert angle_difference_deg(slope_axis_deg(surface), 70.0) < 3.0
    assert surface.statistics()["rms_height_um"] == pytest.approx(0.05, rel=1e-12)
    default = generate("brushed", cells=256, size_um=32.0, seed=1, rms_height_um=0.05)
    assert default.ensemble == GaussianEnsemble(0.05, (8.0, 0.8), 0.0)
    assert default.parameters["correlation_um"] == [8.0, 0.8] and default.parameters["angle_deg"] == 0.0
    assert angle_difference_deg(slope_axis_deg(default), 0.0) < 3.0
    stats = default.statistics()
    assert stats["correlation_length_x_um"] > 5 * stats["correlation_length_y_um"]


# ============================================================================================
# Deterministic microsurfaces


def face_normals(surface: HeightField, slope: float, tol: float = 1e-9) -> np.ndarray:
    """Distinct unit normals (−h_x, −h_y, 1)/|…| of the planar cells (no bilinear twist) whose
    slope is ``slope``."""
    z = surface.z
    zx, zy = cell_slopes(surface)
    twist = np.abs(z[1:, 1:] + z[:-1, :-1] - z[1:, :-1] - z[:-1, 1:])
    planar = (twist < tol) & (np.abs(np.hypot(zx, zy) - slope) < 1e-9)
    m = np.stack([-zx[planar], -zy[planar], np.ones(planar.sum())], axis=1)
    m /= np.linalg.norm(m, axis=1, keepdims=True)
    return np.unique(np.round(m, 9), axis=0)


def reflect(direction: np.ndarray, normal: np.ndarray) -> np.ndarray:
    return direction - 2 * np.dot(direction, normal) * normal


def test_corner_cubes_are_retroreflectors():
    """Faces at arccos(1/√3) = 54.74° from ẑ; six face orientations (up and down triangles) that
    form two triples of mutually perpendicular normals; a ray reflected by the three faces of a
    triple, in any order, leaves along −its direction; ridges at 0 and apexes at −a/√6;
    periodic along x, not along y."""
    a = 2.0
    surface = generate("corner-cubes", cells=240, size_um=12.0, period_um=a)
    normals = face_normals(surface, np.sqrt(2.0))
    assert len(normals) == 6
    assert np.allclose(normals[:, 2], 1 / np.sqrt(3.0))
    triples = [t for t in itertools.combinations(range(6), 3)
               if all(abs(np.dot(normals[i], normals[j])) < 1e-9 for i, j in itertools.combinations(t, 2))]
    assert len(triples) == 2 and set(triples[0]) | set(triples[1]) == set(range(6))
    rng = np.random.default_rng(1)
    for triple in triples:
        for _ in range(5):
            d = rng.normal(size=3)
            d[2] = -abs(d[2]) - 0.5  # travelling down toward the surface
            d /= np.linalg.norm(d)
            for order in itertools.permutations(triple):
                out = d
                for i in order:
                    out = reflect(out, normals[i])
                assert np.allclose(out, -d, atol=1e-12)
    assert surface.z.max() == pytest.approx(0.0, abs=1e-12)
    stats = surface.statistics()
    logger.info("corner cubes a = %g: %s, parameters %s", a, stats, surface.parameters)
    assert stats["peak_to_valley_um"] == pytest.approx(a / np.sqrt(6.0), rel=0.02)  # apexes between nodes
    assert surface.parameters["depth_um"] == pytest.approx(a / np.sqrt(6.0), rel=1e-12)
    assert stats["max_slope"] == pytest.approx(np.sqrt(2.0), rel=1e-9)
    assert surface.periodic == (True, False) and surface.parameters["periodic"] == "x"
    assert surface.ensemble is None


def test_full_corner_cubes_tile_continuously_with_one_triple_of_faces():
    """shape = "full": hexagonal-aperture cube corners on a triangular lattice of apexes. One triple
    of mutually perpendicular faces at 54.74° from ẑ (every cube has the same orientation), a ray
    reflected by the three leaves along −its direction; the height field is continuous (no step
    steeper than the faces between neighbouring nodes); apexes at −a√(2/3), rims at 0 and −a/√6."""
    a = 2.0
    surface = generate("corner-cubes", cells=240, size_um=12.0, period_um=a, shape="full")
    normals = face_normals(surface, np.sqrt(2.0))
    assert len(normals) == 3
    assert np.allclose(normals[:, 2], 1 / np.sqrt(3.0))
    assert all(abs(np.dot(normals[i], normals[j])) < 1e-9 for i, j in itertools.combinations(range(3), 2))
    d = np.array([0.3, -0.2, -0.93])
    d /= np.linalg.norm(d)
    for order in itertools.permutations(range(3)):
        out = d
        for i in order:
            out = reflect(out, normals[i])
        assert np.allclose(out, -d, atol=1e-12)
    z, step = surface.z, surface.spacing_um
    assert max(np.abs(np.diff(z, axis=0)).max(), np.abs(np.diff(z, axis=1)).max()) <= np.sqrt(2.0) * step * (1 + 1e-9)
    assert z.min() == pytest.approx(-a * np.sqrt(2.0 / 3.0), abs=1e-9)  # apexes on nodes (a multiple of d)
    assert surface.parameters["depth_um"] == pytest.approx(a * np.sqrt(2.0 / 3.0), rel=1e-12)
    assert -0.02 * a < z.max() <= 0.0
    assert surface.periodic == (True, False)
    with pytest.raises(SurfaceError, match="surface.shape = 'round'"):
        generate("corner-cubes", cells=240, size_um=12.0, period_um=a, shape="round")


def test_canted_corner_cubes_tilt_every_cube_axis():
    """cant_deg = τ toward cant_azimuth_deg = ψ: still one triple of mutually perpendicular faces,
    whose cube axis (n₁ + n₂ + n₃)/√3 is at τ from ẑ toward ψ; continuous (no step steeper than the
    steepest face); apexes at the depth D below the highest rim, D checked against a brute-force
    lower envelope of the pits built here from a scipy rotation; periodic along x. Refusals: a cant
    that would lay a cube edge below its apex, and a cant on triangular corners."""
    from scipy.spatial.transform import Rotation

    a, tau, psi = 2.0, 12.0, 40.0
    surface = generate("corner-cubes", cells=240, size_um=12.0, period_um=a, shape="full", cant_deg=tau,
                       cant_azimuth_deg=psi)
    z = surface.z
    zx, zy = cell_slopes(surface)
    twist = np.abs(z[1:, 1:] + z[:-1, :-1] - z[1:, :-1] - z[:-1, 1:])
    m = np.stack([-zx[twist < 1e-9], -zy[twist < 1e-9], np.ones(np.sum(twist < 1e-9))], axis=1)
    m /= np.linalg.norm(m, axis=1, keepdims=True)
    normals, counts = np.unique(np.round(m, 9), axis=0, return_counts=True)
    normals = normals[counts > 0.05 * counts.sum()]  # the faces (not the few cells across a rim)
    assert len(normals) == 3
    assert all(abs(np.dot(normals[i], normals[j])) < 1e-8 for i, j in itertools.combinations(range(3), 2))
    axis = normals.sum(axis=0) / np.sqrt(3.0)
    assert np.degrees(np.arccos(axis[2])) == pytest.approx(tau, abs=1e-6)
    assert np.degrees(np.arctan2(axis[1], axis[0])) == pytest.approx(psi, abs=1e-6)
    steepest = np.max(np.hypot(normals[:, 0], normals[:, 1]) / normals[:, 2])
    step = surface.spacing_um
    assert max(np.abs(np.diff(z, axis=0)).max(), np.abs(np.diff(z, axis=1)).max()) <= steepest * step * (1 + 1e-9)
    # brute force: the untilted cube's faces rotated by τ about the horizontal axis ⟂ ψ
    up = np.array([[0.0, 1.0], [-np.sqrt(3) / 2, -0.5], [np.sqrt(3) / 2, -0.5]])
    untilted = np.column_stack([np.sqrt(2.0) * up, np.ones(3)]) / np.sqrt(3.0)
    rot = Rotation.from_rotvec(np.radians(tau) * np.array([-np.sin(np.radians(psi)), np.cos(np.radians(psi)), 0.0]))
    n = rot.apply(untilted)
    g = -n[:, :2] / n[:, 2:]
    s = np.linspace(0.0, 1.0, 401)
    lattice = np.array([[a, 0.5 * a], [0.0, 0.5 * np.sqrt(3.0) * a]])
    cell = np.stack(np.meshgrid(s, s, indexing="ij"), axis=-1) @ lattice.T
    envelope = np.full(cell.shape[:2], np.inf)
    for i, j in itertools.product(range(-4, 6), repeat=2):
        envelope = np.minimum(envelope, np.max((cell - lattice @ np.array([i, j])) @ g.T, axis=-1))
    depth = surface.parameters["depth_um"]
    assert envelope.max() <= depth * (1 + 1e-12) and envelope.max() == pytest.approx(depth, rel=2e-3)
    assert z.min() == pytest.approx(-depth, abs=1e-9)  # apexes on nodes along y = 0
    assert -0.02 * a < z.max() <= 0.0
    assert surface.periodic == (True, False)
    assert surface.parameters["cant_deg"] == tau and surface.parameters["cant_azimuth_deg"] == psi
    with pytest.raises(SurfaceError, match="surface.cant_deg = 36"):
        generate("corner-cubes", cells=240, size_um=12.0, period_um=a, shape="full", cant_deg=36)
    with pytest.raises(SurfaceError, match="shape = \"full\""):
        generate("corner-cubes", cells=240, size_um=12.0, period_um=a, cant_deg=5)


def test_spherical_pits():
    """Caps of the sphere of radius R centred R − D above the plane: depth D, rim radius
    √(2RD − D²) (pit area fraction π a²/Λ²), flat between pits; periodic."""
    R, D, period, size, cells = 1.5, 0.6, 2.5, 10.0, 200  # pit centres on nodes: Λ/2 = 25 d
    surface = generate("spherical-pits", cells=cells, size_um=size, radius_um=R, depth_um=D, period_um=period)
    z = surface.z
    assert z.min() == pytest.approx(-D, abs=1e-12) and z.max() == 0.0
    X, Y = np.meshgrid(surface.x, surface.y, indexing="ij")
    cx = (np.floor((X + size / 2) / period) + 0.5) * period - size / 2
    cy = (np.floor((Y + size / 2) / period) + 0.5) * period - size / 2
    inside = z < 0
    rho2 = (X - cx) ** 2 + (Y - cy) ** 2
    assert np.allclose(rho2[inside] + (z[inside] - (R - D)) ** 2, R**2, atol=1e-12)
    rim = np.sqrt(2 * R * D - D**2)
    assert np.all(rho2[inside] < rim**2) and np.all(rho2[~inside] >= rim**2 - 1e-9)
    tile = z[:-1, :-1]
    assert np.mean(tile < 0) == pytest.approx(np.pi * rim**2 / period**2, rel=0.03)
    assert surface.parameters["rim_radius_um"] == pytest.approx(rim)
    assert surface.periodic == (True, True) and surface.ensemble is None


@pytest.mark.parametrize("placement", ["square", "random"])
def test_hemispheres(placement):
    """Hemispheres z = √(r² − ρ²) on z = 0: the covered fraction of the tile equals the recorded
    fill (so random ones do not overlap) and is within 5% of the requested fill; periodic."""
    r, fill, size, cells = 0.8, 0.4, 16.0, 320
    surface = generate("hemispheres", cells=cells, size_um=size, seed=5, radius_um=r, fill=fill, placement=placement)
    params = surface.parameters
    tile = surface.z[:-1, :-1]
    covered = float(np.mean(tile > 0))
    logger.info("%s: %s, covered %.4f", placement, params, covered)
    assert params["fill_realized"] == pytest.approx(params["hemispheres"] * np.pi * r**2 / size**2)
    assert covered == pytest.approx(params["fill_realized"], rel=0.03)
    assert params["fill_realized"] == pytest.approx(fill, rel=0.05)
    assert 0 <= tile.min() and tile.max() <= r
    assert surface.periodic == (True, True) and surface.ensemble is None
    if placement == "square":
        period = size / np.sqrt(params["hemispheres"])
        assert period == pytest.approx(r * np.sqrt(np.pi / params["fill_realized"]))


def test_sinusoid_correlation_length_is_analytic():
    """The ACF of a cos(2πx/Λ) is cos(2πτ/Λ): 1/e at τ = Λ arccos(1/e)/(2π); none along y."""
    surface = generate("sinusoid", cells=400, size_um=8.0, amplitude_um=0.1, period_um=2.0)
    stats = surface.statistics()
    assert stats["correlation_length_x_um"] == pytest.approx(2.0 * np.arccos(np.exp(-1)) / (2 * np.pi), rel=1e-3)
    assert np.isnan(stats["correlation_length_y_um"])
    assert np.isnan(generate("flat", cells=8, size_um=1.0).statistics()["correlation_length_x_um"])


# ============================================================================================
# The HeightField seam and refusals


def test_height_field_keeps_its_contract():
    z = np.zeros((5, 5))
    plain = HeightField(z, 1.0)
    assert plain.ensemble is None and plain.parameters is None
    with pytest.raises(dataclasses.FrozenInstanceError):
        plain.ensemble = GaussianEnsemble(0.1, (1.0, 1.0))
    ens = HeightField(z, 1.0, ensemble=GaussianEnsemble(0.1, (1.0, 2.0), 10.0))
    assert ens == plain  # the ensemble is not part of the comparison
    with pytest.raises(SurfaceError, match="correlation_um"):
        GaussianEnsemble(0.1, (1.0, -1.0))
    with pytest.raises(SurfaceError, match="rms_height_um"):
        GaussianEnsemble(-0.1, (1.0, 1.0))
    assert set(SCHEMA["surface"]["generator"].choices) == set(GENERATORS)


BAD = [
    ("corner-cubes", dict(period_um=3.0), "surface.period_um = 3"),
    ("spherical-pits", dict(radius_um=1.0, depth_um=1.2, period_um=2.5), "surface.depth_um = 1.2"),
    ("spherical-pits", dict(radius_um=2.0, depth_um=1.5, period_um=2.5), "rim diameter"),
    ("hemispheres", dict(radius_um=1.0, fill=0.9), "surface.fill = 0.9"),
    ("hemispheres", dict(radius_um=1.0, fill=0.6), "surface.fill = 0.6"),
    ("hemispheres", dict(radius_um=0.5, fill=0.6, placement="random"), "surface.fill = 0.6"),
    ("hemispheres", dict(radius_um=0.5, fill=0.3, placement="hexagonal"), "surface.placement"),
    ("gaussian", dict(rms_height_um=0.1, correlation_um=[1.0, 2.0, 3.0]), "surface.correlation_um"),
    ("gaussian", dict(rms_height_um=0.1, correlation_um=1.0, angle_deg=20.0), "surface.angle_deg = 20"),
    ("gaussian", dict(rms_height_um=0.1, correlation_um=[1.0, 1.0], angle_deg=20.0), "equal lengths: isotropic"),
    ("brushed", dict(rms_height_um=0.1, correlation_um=[0.2, 2.0]), "surface.correlation_um"),
    ("brushed", dict(rms_height_um=0.1, correlation_um=0.5), "surface.correlation_um"),
    ("gaussian", dict(rms_height_um=0.1, correlation_um=1.0, fill=0.2), "surface.fill"),
]


@pytest.mark.parametrize("generator,params,message", BAD)
def test_bad_generator_values_are_refused(generator, params, message):
    with pytest.raises(SurfaceError, match=message.replace("[", r"\[").replace(".", r"\.")):
        generate(generator, cells=40, size_um=10.0, **params)


def _config(surface: str, tmp_path, model="kirchhoff", resolution=16) -> str:
    return textwrap.dedent(f"""
        [study]
        output = "{tmp_path / 'out.h5'}"
        [surface]
        size_um = 10.0
        cells = 40
        {surface}
        [material]
        n = 1.5
        [illumination]
        wavelengths_um = [0.5]
        directions_deg = [[20, 0]]
        waist_um = 1.5
        [model]
        name = "{model}"
        [output]
        resolution = {resolution}
        """)


@pytest.mark.parametrize("surface,message", [
    ('generator = "corner-cubes"\nperiod_um = 3.0', "[surface] surface.period_um = 3"),
    ('generator = "hemispheres"\nradius_um = 1.0\nfill = 1.5', "[surface] fill = 1.5"),
    ('generator = "hemispheres"\nradius_um = 1.0\nfill = 0.3\nplacement = "hex"', "[surface] placement = \"hex\""),
    ('generator = "gaussian"\nrms_height_um = 0.1\ncorrelation_um = [1.0, -2.0]', "[surface] correlation_um"),
    ('generator = "gaussian"\nrms_height_um = 0.1\ncorrelation_um = 1.0\nradius_um = 2.0', "surface.radius_um"),
    ('generator = "spherical-pits"\nradius_um = 1.0\nperiod_um = 2.5', "surface.depth_um"),
    ('generator = "pyramids"', "[surface] generator = \"pyramids\""),
])
def test_config_refuses_bad_surface_keys(tmp_path, surface, message):
    with pytest.raises(ConfigError) as info:
        parse_config(_config(surface, tmp_path))
    assert message in str(info.value), str(info.value)


# ============================================================================================
# Every generator reports its statistics in the dataset (through the CLI)

DATASET_CASES = {
    "gaussian": 'rms_height_um = 0.05\ncorrelation_um = [1.2, 0.6]\nangle_deg = 30.0',
    "brushed": 'rms_height_um = 0.05\ncorrelation_um = [2.0, 0.4]\nangle_deg = 45.0',
    "corner-cubes": 'period_um = 2.0',
    "spherical-pits": 'radius_um = 1.0\ndepth_um = 0.3\nperiod_um = 2.5',
    "hemispheres": 'radius_um = 0.5\nfill = 0.2\nplacement = "random"',
}
SEEDED = ("gaussian", "brushed", "hemispheres")  # the cases that draw at random (a seed elsewhere is refused)
STAT_KEYS = ("rms_height_um", "peak_to_valley_um", "rms_slope", "max_slope", "correlation_length_x_um",
             "correlation_length_y_um")


@pytest.mark.parametrize("generator", list(DATASET_CASES))
def test_dataset_records_statistics_and_parameters(tmp_path, capsys, generator):
    """wavebrdf run → surface/height_0 attributes: the measured statistics (those of the HeightField the
    study used), the generator's name and parameters, and the ensemble of random generators."""
    cfg = tmp_path / f"{generator}.toml"
    seed = 3 if generator in SEEDED else 0
    cfg.write_text(_config(f'generator = "{generator}"\n' + (f"seed = {seed}\n" if seed else "")
                           + DATASET_CASES[generator], tmp_path))
    assert main(["run", str(cfg), "-q", "--no-render"]) == 0, capsys.readouterr().err
    capsys.readouterr()
    with h5py.File(tmp_path / "out.h5", "r") as h5:
        attrs = dict(h5["surface/height_0"].attrs)
        heights = h5["surface/height_0"][()]
    params = dict(line.split(" = ") for line in DATASET_CASES[generator].splitlines())
    surface = generate(generator, cells=40, size_um=10.0, seed=seed,
                       **{k: eval(v) if not v.startswith('"') else v.strip('"') for k, v in params.items()})
    assert np.array_equal(heights, surface.z)
    expected = surface.statistics()
    for key in STAT_KEYS:
        assert np.isfinite(attrs[key]) and attrs[key] == pytest.approx(expected[key], rel=1e-12), key
    assert attrs["generator"] == generator and attrs["generator_seed"] == seed
    for key, value in params.items():
        stored = attrs[f"generator_{key}"]
        assert (stored == value.strip('"')) if value.startswith('"') else np.allclose(stored, eval(value)), key
    assert attrs["generator_periodic"] == surface.parameters["periodic"]
    if generator in ("gaussian", "brushed"):
        assert attrs["ensemble"] == "gaussian" and attrs["ensemble_rms_height_um"] == 0.05
        assert list(attrs["ensemble_correlation_um"]) == list(surface.ensemble.correlation_um)
    else:
        assert "ensemble" not in attrs


def test_list_values_cannot_be_swept(tmp_path):
    """A sweep coordinate is 1-D: correlation pairs are refused in [sweep] (scalars still sweep)."""
    base = _config('generator = "gaussian"\nrms_height_um = 0.05\ncorrelation_um = 1.0', tmp_path)
    with pytest.raises(ConfigError, match=r"\[sweep\] surface.correlation_um"):
        parse_config(base + '[sweep]\n"surface.correlation_um" = [[1.0, 0.5], [2.0, 0.5]]\n')
    assert len(parse_config(base + '[sweep]\n"surface.correlation_um" = [1.0, 2.0]\n').cases) == 2


def test_refined_realization_is_the_band_limited_surface_through_every_coarse_node():
    """A random realization refined for a mesh-convergence study is the same surface: a periodic
    field with a spectrum below the coarse Nyquist frequency (an analytic sum of a few plane waves,
    tagged as a grid-drawn "gaussian") is reproduced at every fine node, not merely at the coarse
    ones; a deterministic generator is rebuilt and equals its own analytic heights."""
    n, size = 24, 3.0
    def waves(cells):
        t = size / cells * np.arange(cells)
        x, y = np.meshgrid(t, t, indexing="ij")
        k = 2 * np.pi / size
        return 0.05 * np.cos(3 * k * x + 1.0) + 0.02 * np.sin(2 * k * x - 5 * k * y) + 0.01 * np.cos(11 * k * y)

    def nodes(tile):
        return np.pad(tile, ((0, 1), (0, 1)), mode="wrap")

    coarse = HeightField(nodes(waves(n)), size, parameters={"generator": "gaussian", "seed": 1})
    for cells in (36, 48, 61):
        fine = refined(coarse, cells)
        assert fine.cells == cells and np.allclose(fine.z, nodes(waves(cells)), atol=1e-12, rtol=0)
    grating = generate("sinusoid", cells=20, size_um=4.0, amplitude_um=0.04, period_um=1.0)
    fine = refined(grating, 60)
    assert np.allclose(fine.z[::3, ::3], grating.z, atol=1e-14, rtol=0) and np.ptp(fine.z[1::3, 1::3]) > 0
    assert np.allclose(fine.z, generate("sinusoid", cells=60, size_um=4.0, amplitude_um=0.04, period_um=1.0).z)
    with pytest.raises(SurfaceError, match="cells must be an integer >= the field's 20"):
        refined(grating, 10)


def test_a_grid_independent_surface_rebuilt_at_fewer_cells_has_the_nodes_it_shares_with_the_finer_one():
    """A deterministic surface generated anew on a coarser grid (a convergence pair below a table's
    spacing) is the same geometry: at every node the coarse and fine grids share (every k-th fine
    node) the heights agree, for a grating, corner cubes and the random-placed hemispheres (their
    disk centres are drawn independently of the grid); a realization drawn on the grid is refused."""
    from wavebrdf.solver.surface import rebuilt, subdivided

    fields = [generate("sinusoid", cells=60, size_um=4.0, amplitude_um=0.04, period_um=1.0),
              generate("corner-cubes", cells=36, size_um=1.8, period_um=0.6, seed=3),
              generate("hemispheres", cells=48, size_um=2.4, radius_um=0.3, fill=0.3, placement="random", seed=7)]
    for fine in fields:
        for k in (2, 3):
            coarse = rebuilt(fine, fine.cells // k)
            assert coarse.cells == fine.cells // k and coarse.size_um == fine.size_um
            assert np.allclose(coarse.z, fine.z[::k, ::k], atol=1e-13, rtol=0)
        assert np.array_equal(rebuilt(fine, fine.cells).z, fine.z)
    with pytest.raises(SurfaceError, match="'gaussian' realization is drawn on its grid"):
        rebuilt(generate("gaussian", cells=24, size_um=2.0, rms_height_um=0.05, correlation_um=0.5), 12)
    with pytest.raises(SurfaceError, match="records no generator"):
        rebuilt(subdivided(fields[1], 2), 36)


def test_subdivided_surface_is_the_same_bilinear_surface_on_a_finer_mesh():
    """A solver-convergence study on a fixed geometry: every element of the subdivided surface's
    BEM mesh lies on the coarse surface's bilinear patches (scipy's linear interpolation on the
    rectangular grid is the bilinear interpolant), at random points inside it, not only at the
    coarse nodes, so the fine mesh differs from the coarse one in its discretization alone."""
    from scipy.interpolate import RegularGridInterpolator

    from wavebrdf.solver.bem3d.mesh import BEMMesh, bilinear_frame
    from wavebrdf.solver.surface import subdivided

    coarse = generate("corner-cubes", cells=18, size_um=1.8, period_um=0.6, seed=3)
    surface = RegularGridInterpolator((coarse.x, coarse.y), coarse.z, method="linear")
    rng = np.random.default_rng(5)
    for factor in (2, 3):
        fine = subdivided(coarse, factor)
        assert fine.cells == 18 * factor and fine.size_um == coarse.size_um
        assert np.array_equal(fine.z[::factor, ::factor], coarse.z)
        mesh = BEMMesh(fine, z_reference=0.0)
        u, v = rng.uniform(-1, 1, (2, mesh.n_elements))
        r, _, _ = bilinear_frame(mesh.geometry, mesh.half, u, v)
        assert np.allclose(r[:, 2], surface(np.clip(r[:, :2], -0.9, 0.9)), atol=1e-13, rtol=0)
    assert fine.parameters["subdivided_from_cells"] == 18 and fine.parameters["subdivided_from"] == "corner-cubes"
    assert np.allclose(refined(fine, 2 * fine.cells).z[::2, ::2], fine.z, rtol=0, atol=1e-12)  # not rebuilt
    assert np.array_equal(subdivided(coarse, 1).z, coarse.z)
    for bad in (1.5, 0):
        with pytest.raises(SurfaceError, match=f"factor must be an integer >= 1, got {bad}"):
            subdivided(coarse, bad)


def test_a_sinusoid_is_periodic_only_where_its_period_divides_the_patch():
    """A sinusoid repeats its edge row whatever its period (the patch is centred, cos is even), but
    continues seamlessly only where whole periods fit: 3.33 periods along x are not periodic (a
    slope jump at the seam), and its correlation length along x is the non-periodic estimate's,
    within 2 % of the closed form Λ·arccos(1/e)/(2π) (the wrapped autocorrelation was 7 % off);
    12 µm holds 4 periods: periodic; at 30° whole periods fit along y only."""
    closed = 3.0 * np.arccos(1.0 / np.e) / (2.0 * np.pi)
    odd = generate("sinusoid", cells=128, size_um=10.0, amplitude_um=0.1, period_um=3.0)
    assert odd.periodic == (False, True) and odd.parameters["periodic"] == "y"
    assert odd.statistics()["correlation_length_x_um"] == pytest.approx(closed, rel=0.02)
    whole = generate("sinusoid", cells=128, size_um=12.0, amplitude_um=0.1, period_um=3.0)
    assert whole.periodic == (True, True)
    assert whole.statistics()["correlation_length_x_um"] == pytest.approx(closed, rel=0.002)
    turned = generate("sinusoid", cells=128, size_um=12.0, amplitude_um=0.1, period_um=3.0, angle_deg=30.0)
    assert turned.periodic == (False, True)


@pytest.mark.parametrize("generator, keys, message", [
    ("hemispheres", {"radius_um": 0.05, "fill": 0.3}, "the hemispheres' diameter 2r = 0.1 µm spans 0.64"),
    ("corner-cubes", {"period_um": 0.5}, "the cubes' period a = 0.5 µm spans 3.2"),
    ("spherical-pits", {"radius_um": 0.1, "depth_um": 0.05, "period_um": 0.625}, "the pits' rim diameter"),
])
def test_features_the_grid_cannot_hold_are_refused(generator, keys, message):
    """A hemisphere, pit or cube narrower than four grid spacings has the grid's slopes, not its own
    (cubes of period 3.2 spacings: rms slope 0.46 for faces of slope √2): refused, naming the cells
    that would hold it."""
    with pytest.raises(SurfaceError, match="fewer than 4") as info:
        generate(generator, cells=64, size_um=10.0, **keys)
    assert message in str(info.value) and "use surface.cells ≥" in str(info.value), str(info.value)


def test_a_seed_that_changes_nothing_is_refused(tmp_path):
    """A seed given to a generator that draws nothing (sinusoid, pits, cubes, flat, hemispheres on a
    lattice) would be ignored, and a sweep over it would repeat one surface as "realizations"."""
    sinusoid = 'generator = "sinusoid"\namplitude_um = 0.1\nperiod_um = 2.0'
    with pytest.raises(ConfigError, match=r'seed = 3 and generator = "sinusoid": seed would be ignored'):
        parse_config(_config(sinusoid + "\nseed = 3", tmp_path))
    with pytest.raises(ConfigError, match="seed would be ignored"):
        parse_config(_config(sinusoid, tmp_path) + '[sweep]\n"surface.seed" = [1, 2]\n')
    lattice = 'generator = "hemispheres"\nradius_um = 0.5\nfill = 0.3'
    with pytest.raises(ConfigError, match="seed would be ignored"):
        parse_config(_config(lattice + "\nseed = 3", tmp_path))
    assert len(parse_config(_config(lattice + '\nplacement = "random"', tmp_path)
                            + '[sweep]\n"surface.seed" = [1, 2]\n').cases) == 2


def test_sweep_values_equal_as_numbers_are_one_value(tmp_path):
    """2 and 2.0 are the same index: a sweep over them would run one case twice."""
    base = _config('generator = "gaussian"\nrms_height_um = 0.05\ncorrelation_um = 1.0', tmp_path)
    with pytest.raises(ConfigError, match="values must be distinct"):
        parse_config(base + '[sweep]\n"material.n" = [2, 2.0]\n')
