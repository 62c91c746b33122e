"""Warm starts across wavelengths (solver/bem3d/warm_start.py, solver/krylov.py ``x0``).

References: a direct solve (numpy) for the Krylov initial guess; for the full wave, the cold AIM
solve of the same scene (every solve from zero), which a warm start may change only within the
Krylov tolerance, whatever the order of the wavelengths. The products saved are counted on a
3-wavelength sweep of a small rough aluminium patch at oblique incidence.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import replace

import numpy as np
import pytest

from wavebrdf.solver.bem3d import BEMSolver
from wavebrdf.solver.bem3d.aim import AIMOptions
from wavebrdf.solver.bem3d.mesh import BEMMesh
from wavebrdf.solver.bem3d.warm_start import WarmStarts, incident_phase, surface_key
from wavebrdf.solver.farfield import HemisphereGrid, albedo
from wavebrdf.solver.krylov import solve
from wavebrdf.solver.metrics import relative_l2
from wavebrdf.solver.surface import HeightField, generate

logger = logging.getLogger(__name__)

# the reference simulator's aluminium rows (solver/data/aluminium_bemsim.csv): λ µm, n − jκ
ALUMINIUM = ((0.400, 0.46582 - 4.7119j), (0.412, 0.4998 - 4.8561j), (0.424, 0.53508 - 4.9991j))


# --- Krylov: the initial guess ---------------------------------------------------------------


@pytest.fixture(scope="module")
def system():
    """A complex-symmetric indefinite matrix (like scaled PMCHWT), 2 right-hand sides, the direct
    solution and a rough approximate inverse."""
    rng = np.random.default_rng(3)
    n = 200
    B = rng.standard_normal((n, n)) + 1j * rng.standard_normal((n, n))
    A = (B + B.T) / np.sqrt(n) + np.diag(np.where(np.arange(n) % 2, 4.0, -4.0) + 1j)
    b = rng.standard_normal((2, n)) + 1j * rng.standard_normal((2, n))
    M = np.linalg.inv(A + 0.3 * np.diag(np.diag(A)))
    return A, b, np.linalg.solve(A, b.T).T, M


@pytest.mark.parametrize("method, preconditioned", [("gmres", False), ("csym", False), ("bicgstab", False),
                                                     ("gmres", True), ("bicgstab", True)])
def test_a_scaled_copy_of_the_solution_is_found_by_the_guess_alone(system, method, preconditioned):
    """x0 = c·x* with a complex c: the least-squares scale recovers x* (one product, no iteration)."""
    A, b, exact, M = system
    pre = (lambda X: X @ M.T) if preconditioned else None
    result = solve(lambda X: X @ A.T, b, method=method, tol=1e-8, x0=(0.3 - 2.0j) * exact, preconditioner=pre)
    assert result.iterations.tolist() == [1, 1] and np.all(result.initial_residual < 1e-10)
    assert np.allclose(result.x, exact, rtol=0, atol=1e-9 * np.abs(exact).max())


@pytest.mark.parametrize("method", ["gmres", "bicgstab"])
def test_a_preconditioned_warm_start_reaches_the_cold_solution_in_fewer_products(system, method):
    A, b, exact, M = system
    rng = np.random.default_rng(5)
    near = exact * (1 + 0.01 * rng.standard_normal(exact.shape))  # 1 % off, entry by entry
    kwargs = dict(method=method, tol=1e-9, max_iterations=2000, restart=300, preconditioner=lambda X: X @ M.T)
    cold = solve(lambda X: X @ A.T, b, **kwargs)
    warm = solve(lambda X: X @ A.T, b, x0=near, **kwargs)
    true = np.linalg.norm(b - warm.x @ A.T, axis=1) / np.linalg.norm(b, axis=1)
    logger.info("%s: cold %s, warm %s products, initial residual %s", method, cold.iterations, warm.iterations,
                warm.initial_residual)
    assert np.all(true <= 1e-9) and np.allclose(true, warm.true_residual)
    assert np.all(warm.iterations < cold.iterations) and np.all(warm.initial_residual < 0.05)
    assert np.allclose(warm.x, exact, rtol=0, atol=1e-6 * np.abs(exact).max())


def test_a_useless_guess_is_dropped_and_a_bad_shape_refused(system):
    A, b, exact, _ = system
    rng = np.random.default_rng(9)
    noise = rng.standard_normal(b.shape) + 1j * rng.standard_normal(b.shape)
    cold = solve(lambda X: X @ A.T, b, tol=1e-8, max_iterations=2000, restart=300)
    result = solve(lambda X: X @ A.T, b, tol=1e-8, max_iterations=2000, restart=300, x0=noise)
    assert np.all(result.initial_residual == 1.0)  # a zero start: the guess gains less than 10 %
    assert np.array_equal(result.iterations, cold.iterations + 1)  # only the guess's product is lost
    assert np.allclose(result.x, exact, rtol=0, atol=1e-6 * np.abs(exact).max())
    with pytest.raises(ValueError, match=r"x0 has shape \(1, 200\).*\(2, 200\)"):
        solve(lambda X: X @ A.T, b, x0=noise[:1])


# --- the cache --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def small_mesh():
    return BEMMesh(generate("gaussian", cells=8, size_um=0.4, seed=1, rms_height_um=0.02, correlation_um=0.2))


def test_the_guess_extrapolates_currents_linear_in_k_after_the_phase_move(small_mesh):
    """x(k) = (a + k c)·e^{+j k ω_i·r}: kept at k₀, k₁, the guess at k₂ is x(k₂) (complex64
    storage); with one kept solution it is the moved one."""
    mesh, theta, phi = small_mesh, 0.5, 1.1
    rng = np.random.default_rng(1)
    a, c = (rng.standard_normal((2, 2 * mesh.n_bases)) + 1j * rng.standard_normal((2, 2 * mesh.n_bases))
            for _ in range(2))
    omega = np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    r = np.concatenate([mesh.basis_centres, mesh.basis_centres]) @ omega  # independent of incident_phase

    def x(k):
        return (a + k * c) * np.exp(1j * k * r)

    warm, key = WarmStarts(), surface_key(mesh, 1.0)
    ks = 2 * np.pi / np.array([0.4, 0.412, 0.424])
    warm.keep(key, "inc", ks[0], 0.4, x(ks[0]))
    guess, source = warm.guess(key, "inc", mesh, ks[1], theta, phi)
    assert source == (0.4,)
    assert np.allclose(guess, x(ks[0]) * np.exp(1j * (ks[1] - ks[0]) * r), rtol=0, atol=1e-5 * np.abs(a).max())
    warm.keep(key, "inc", ks[1], 0.412, x(ks[1]))
    guess, source = warm.guess(key, "inc", mesh, ks[2], theta, phi)
    assert source == (0.4, 0.412)
    assert np.allclose(guess, x(ks[2]), rtol=0, atol=1e-5 * np.abs(x(ks[2])).max())
    assert np.allclose(incident_phase(mesh, 0.7, theta, phi), np.exp(0.7j * r))


def test_the_cache_is_bounded(small_mesh):
    """Two solutions per key (the newest at other wavenumbers), one surface at a time, at most
    max_bytes; nothing kept for an unknown key or another mesh size."""
    mesh = small_mesh
    n = 2 * mesh.n_bases
    x = np.ones((2, n), dtype=complex)
    one = x.astype(np.complex64).nbytes
    warm = WarmStarts(max_bytes=5 * one)
    s1, s2 = surface_key(mesh, 1.0), surface_key(mesh, 1.5)
    for k in (10.0, 11.0, 12.0):
        warm.keep(s1, "a", k, 2 * np.pi / k, x)
    assert len(warm) == 1 and warm.bytes() == 2 * one
    assert [kept.wavenumber for kept in warm._kept[(s1, "a")]] == [11.0, 12.0]
    warm.keep(s1, "a", 12.0, 2 * np.pi / 12.0, 2 * x)  # the same wavenumber again replaces it
    assert [kept.wavenumber for kept in warm._kept[(s1, "a")]] == [11.0, 12.0] and warm.bytes() == 2 * one
    for key, k in (("b", 10.0), ("b", 11.0), ("c", 10.0), ("c", 11.0)):
        warm.keep(s1, key, k, 1.0, x)
    assert warm.bytes() <= 5 * one and (s1, "c") in warm._kept and len(warm._kept[(s1, "c")]) == 2
    assert (s1, "a") not in warm._kept  # the oldest key went first
    warm.keep(s2, "a", 10.0, 1.0, x)  # another surface evicts the first one's solutions
    assert len(warm) == 1 and warm.bytes() == one
    assert warm.guess(s1, "c", mesh, 12.0, 0.0, 0.0) is None and warm.guess(s2, "z", mesh, 12.0, 0.0, 0.0) is None
    other = BEMMesh(HeightField(np.zeros((5, 5)), 0.2))
    assert warm.guess(s2, "a", other, 12.0, 0.0, 0.0) is None
    WarmStarts(max_bytes=one - 1).keep(s1, "a", 10.0, 1.0, x)  # too big: not kept, no error
    tiny = WarmStarts(max_bytes=one - 1)
    tiny.keep(s1, "a", 10.0, 1.0, x)
    assert len(tiny) == 0
    with pytest.raises(ValueError, match="max_bytes"):
        WarmStarts(max_bytes=-1)


# --- the full wave: a 3-wavelength sweep of a small patch ---------------------------------------


def sweep(ctx, order, warm: bool):
    """BRDF (s, p) and diagnostics per wavelength of ALUMINIUM (in ``order``) on a 0.8 µm rough
    aluminium patch (d = 0.025 µm, 3 968 unknowns), θ_i = 30°, φ_i = 0.3 rad."""
    surface = generate("gaussian", cells=32, size_um=0.8, seed=1, rms_height_um=0.1, correlation_um=1.0)
    grid = HemisphereGrid(64)
    cache = WarmStarts() if warm else None
    aim = replace(AIMOptions(), warm_start=warm)
    out = {}
    for i in order:
        lam, index = ALUMINIUM[i]
        with warnings.catch_warnings():  # the small patch truncates ~2 % of the beam, the same for every run
            warnings.simplefilter("ignore")
            solver = BEMSolver(ctx, surface, lam, index, method="aim", aim=aim, warm_starts=cache)
            ff = solver.farfield(np.deg2rad(30.0), 0.3, grid, waist_um=surface.size_um / 4.8)
        out[i] = (ff.brdf(), ff.diagnostics)
    return grid, out


@pytest.fixture(scope="module")
def sweeps(cl_ctx):
    grid, cold = sweep(cl_ctx, (0, 1, 2), warm=False)
    _, warm = sweep(cl_ctx, (0, 1, 2), warm=True)
    _, backward = sweep(cl_ctx, (2, 1, 0), warm=True)
    return grid, cold, warm, backward


def test_warm_solves_equal_cold_ones_within_the_tolerance_in_either_order(sweeps):
    grid, cold, warm, backward = sweeps
    tol = AIMOptions().tolerance
    for run in (warm, backward):
        for i, (brdf, diag) in run.items():
            ref = cold[i][0]
            l2 = relative_l2(brdf, ref, grid)
            d_albedo = np.abs(albedo(brdf, grid) / albedo(ref, grid) - 1)
            logger.info("λ %.3f: BRDF L2 vs cold %s, albedo %s, products %s (cold %s), initial residual %s",
                        ALUMINIUM[i][0], l2, d_albedo, diag["iterations"], cold[i][1]["iterations"],
                        diag.get("initial_residual"))
            assert np.all(np.array(diag["residual"]) <= tol)
            assert np.all(l2 <= 10 * tol) and np.all(d_albedo <= 10 * tol)


def test_warm_starts_save_products_on_a_sweep(sweeps):
    _, cold, warm, backward = sweeps
    for run, later in ((warm, (1, 2)), (backward, (1, 0))):
        first = ({0, 1, 2} - set(later)).pop()
        assert "initial_residual" not in run[first][1] and "warm_start_from_um" not in run[first][1]
        assert run[first][1]["iterations"] == cold[first][1]["iterations"]  # nothing kept yet: a cold solve
        for i in later:
            assert np.all(np.array(run[i][1]["initial_residual"]) < 0.2)
            assert sum(run[i][1]["iterations"]) < sum(cold[i][1]["iterations"])
    assert tuple(warm[2][1]["warm_start_from_um"]) == (0.4, 0.412)  # the third solve extrapolates from two


# --- the wavelength-independent set-up: the static tables kept across a patch's wavelengths -----


def test_a_patch_keeps_its_static_tables_for_its_next_wavelength_with_the_same_result(cl_ctx, monkeypatch):
    """The bem model run at two wavelengths of one patch, then at another patch: the second
    set-up computes no static singular table (it reuses the first's), the third computes its own
    (the first patch's freed before its set-up starts), and every BRDF equals that of runs
    computing them afresh (``reuse_setup = false``) bit for bit (cold solves: the warm start is
    off in both)."""
    import weakref

    from wavebrdf.solver.bem3d import driver
    from wavebrdf.solver.models import SurfaceScene, get_model

    alive_at_setup = []
    build = driver.BEMSolver.__init__

    def recording(self, *args, static_tables=None, **kwargs):
        alive_at_setup.append([ref() is not None for ref in kept_refs])
        build(self, *args, static_tables=static_tables, **kwargs)

    monkeypatch.setattr(driver.BEMSolver, "__init__", recording)
    kept_refs: list = []

    patch = generate("gaussian", cells=32, size_um=0.8, seed=1, rms_height_um=0.1, correlation_um=1.0)
    other = generate("gaussian", cells=32, size_um=0.8, seed=2, rms_height_um=0.1, correlation_um=1.0)
    runs = ((patch, ALUMINIUM[0]), (patch, ALUMINIUM[1]), (other, ALUMINIUM[1]))

    def run(reuse: bool):
        model = get_model("bem", {"method": "aim", "aim": {"warm_start": False, "reuse_setup": reuse}})
        out = []
        for surface, (lam, index) in runs:
            scene = SurfaceScene(surface=surface, wavelength_um=lam, index=index, theta_i=0.3, phi_i=0.2,
                                 waist_um=surface.size_um / 4.8, grid=HemisphereGrid(64))
            with warnings.catch_warnings():  # the small patch truncates ~2 % of the beam, the same for every run
                warnings.simplefilter("ignore")
                ff = model.run(cl_ctx, scene)
            out.append((ff.brdf(), ff.diagnostics["aim_setup"]))
            if reuse:
                kept_refs.append(weakref.ref(model.solver(cl_ctx, scene).operator.static_tables))
        return out

    kept = run(True)
    # the first patch's tables are there for its second set-up and gone before the other patch's
    assert alive_at_setup[:3] == [[], [True], [False, False]]
    fresh = run(False)
    assert [setup["static_tables_reused"] for _, setup in kept] == [False, True, False]
    assert not any(setup["static_tables_reused"] for _, setup in fresh)
    static_s = [setup["near_detail"]["element_static_s"] for _, setup in kept]
    assert static_s[1] == 0.0 < min(static_s[0], static_s[2])
    for (a, _), (b, _) in zip(kept, fresh):
        assert np.array_equal(a, b, equal_nan=True)  # NaN outside the hemisphere


def test_the_flat_continuation_keeps_no_tables_of_its_ring(cl_ctx):
    """With ``edge = "flat"`` only the patch's static tables are kept for the next wavelength: the
    continuation's ring operator frees its own after its set-up."""
    surface = generate("gaussian", cells=24, size_um=0.6, seed=1, rms_height_um=0.02, correlation_um=0.2)
    z = surface.z.copy()
    z[:3], z[-3:], z[:, :3], z[:, -3:] = 0.0, 0.0, 0.0, 0.0  # a border in one plane
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        solver = BEMSolver(cl_ctx, HeightField(z, surface.size_um), 0.4, ALUMINIUM[0][1], method="aim",
                           aim={"edge": "flat"})
    assert solver.operator.static_tables is not None and solver.operator.static_tables.bytes() > 0
    assert solver.continuation.ring_operator.static_tables is None
