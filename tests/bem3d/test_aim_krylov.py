"""Krylov solvers (solver/krylov.py) on complex-symmetric systems against a direct solve."""

from __future__ import annotations

import numpy as np
import pytest

from wavebrdf.solver.krylov import KRYLOV_METHODS, KrylovNotConverged, gmres_steps, solve


@pytest.fixture(scope="module")
def system():
    """A complex-symmetric, indefinite, non-Hermitian matrix (like scaled PMCHWT) and 2 RHS."""
    rng = np.random.default_rng(7)
    n = 300
    B = rng.standard_normal((n, n)) + 1j * rng.standard_normal((n, n))
    A = (B + B.T) / np.sqrt(n) + np.diag(np.where(np.arange(n) % 2, 4.0, -4.0) + 1j)
    b = rng.standard_normal((2, n)) + 1j * rng.standard_normal((2, n))
    return A, b, np.linalg.solve(A, b.T).T


@pytest.mark.parametrize("method", KRYLOV_METHODS)
def test_solvers_reach_the_direct_solution(system, method):
    A, b, exact = system
    result = solve(lambda X: X @ A.T, b, method=method, tol=1e-10, max_iterations=5000, restart=100)
    err = np.linalg.norm(result.x - exact, axis=1) / np.linalg.norm(exact, axis=1)
    true = np.linalg.norm(b - result.x @ A.T, axis=1) / np.linalg.norm(b, axis=1)
    print(method, result.iterations, err)
    assert np.all(true <= 1e-10) and np.allclose(true, result.true_residual)
    assert np.all(err < 1e-7)
    assert len(result.history[0]) > 0 and result.diagnostics()["converged"]


def test_right_preconditioning_keeps_the_residual_of_the_original_system(system):
    A, b, exact = system
    M = np.linalg.inv(A + 0.3 * np.diag(np.diag(A)))  # a rough approximate inverse
    plain = solve(lambda X: X @ A.T, b, tol=1e-9, max_iterations=2000, restart=300)
    pre = solve(lambda X: X @ A.T, b, tol=1e-9, max_iterations=2000, restart=300, preconditioner=lambda X: X @ M.T)
    assert np.all(pre.iterations < plain.iterations)
    assert np.allclose(pre.x, exact, rtol=0, atol=1e-6 * np.abs(exact).max())


def test_non_convergence_raises_with_diagnostics(system):
    A, b, _ = system
    with pytest.raises(KrylovNotConverged) as info:
        solve(lambda X: X @ A.T, b, method="gmres", tol=1e-12, max_iterations=5, restart=3)
    diag = info.value.diagnostics
    assert diag["converged"] is False and diag["max_iterations"] == 5
    assert len(diag["iterations"]) == 2 and all(r > 1e-12 for r in diag["residual"])


def test_bad_arguments_are_named():
    A = np.eye(3)
    with pytest.raises(ValueError, match="krylov method"):
        solve(lambda X: X, np.ones((1, 3)), method="cg")
    with pytest.raises(ValueError, match="tolerance"):
        solve(lambda X: X, np.ones((1, 3)), tol=0)
    with pytest.raises(ValueError, match="zero"):
        solve(lambda X: X @ A, np.zeros((1, 3)))


def test_csym_in_lockstep_is_each_right_hand_side_alone(system):
    """MINRES on both right-hand sides at once takes the products each takes alone (same
    iterates), in about as many operator calls as the longer one needs."""
    A, b, exact = system
    calls = []

    def matvec(X):
        calls.append(len(X))
        return X @ A.T

    both = solve(matvec, b, method="csym", tol=1e-8, max_iterations=5000)
    alone = [solve(lambda X: X @ A.T, b[p : p + 1], method="csym", tol=1e-8, max_iterations=5000) for p in range(2)]
    assert both.iterations.tolist() == [r.iterations[0] for r in alone]
    for p in range(2):
        assert np.allclose(both.x[p], alone[p].x[0], rtol=0, atol=1e-10 * np.abs(exact).max())
    assert len(calls) <= max(both.iterations) + 2 and max(calls) == 2


@pytest.fixture(scope="module")
def slow_modes():
    """A normal matrix whose spectrum is a disc around 1 plus six eigenvalues of modulus 0.01:
    restarted GMRES forgets the slow modes at each restart and stagnates."""
    rng = np.random.default_rng(3)
    n = 400
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)) + 1j * rng.standard_normal((n, n)))
    lam = 1 + 0.5 * np.sqrt(rng.random(n)) * np.exp(2j * np.pi * rng.random(n))
    lam[:6] = 0.01 * np.exp(2j * np.pi * np.arange(6) / 6)
    A = (Q * lam) @ Q.conj().T
    b = rng.standard_normal((2, n)) + 1j * rng.standard_normal((2, n))
    return A, b, np.linalg.solve(A, b.T).T


def test_deflated_restarts_keep_the_slow_modes(slow_modes):
    """GMRES-DR(20, 6) (Morgan 2002) reaches the direct solution where GMRES(20) stagnates: the
    six small eigenvalues are deflated instead of rediscovered in every cycle."""
    A, b, exact = slow_modes
    with pytest.raises(KrylovNotConverged):
        solve(lambda X: X @ A.T, b, tol=1e-8, max_iterations=1000, restart=20)
    result = solve(lambda X: X @ A.T, b, tol=1e-8, max_iterations=1000, restart=20, deflate=6)
    true = np.linalg.norm(b - result.x @ A.T, axis=1) / np.linalg.norm(b, axis=1)
    err = np.linalg.norm(result.x - exact, axis=1) / np.linalg.norm(exact, axis=1)
    assert np.all(true <= 1e-8) and np.allclose(true, result.true_residual)
    assert np.all(err < 1e-6)
    assert np.all(result.iterations < 150)  # measured 66–67 products


@pytest.mark.parametrize("dtype", [np.complex128, np.complex64])
def test_deflated_gmres_in_lockstep_is_each_right_hand_side_alone(system, dtype):
    """Both right-hand sides at once take the products and reach the solutions each does alone,
    in single and double precision, with a preconditioner."""
    A, b, exact = system
    M = np.linalg.inv(A + 0.3 * np.diag(np.diag(A)))
    tol = 1e-9 if dtype == np.complex128 else 1e-5

    def run(rhs):
        return solve(lambda X: (X @ A.T).astype(X.dtype), rhs.astype(dtype), tol=tol, max_iterations=2000,
                     restart=12, deflate=4, preconditioner=lambda X: (X @ M.T).astype(X.dtype))

    both = run(b)
    alone = [run(b[p : p + 1]) for p in range(2)]
    assert both.iterations.tolist() == [r.iterations[0] for r in alone]
    for p in range(2):
        assert np.allclose(both.x[p], alone[p].x[0], rtol=0, atol=10 * tol * np.abs(exact).max())
        assert np.linalg.norm(both.x[p] - exact[p]) / np.linalg.norm(exact[p]) < 100 * tol


def test_deflation_must_be_below_the_restart():
    with pytest.raises(ValueError, match="deflate"):
        solve(lambda X: X, np.ones((1, 3)), restart=5, deflate=5)
    with pytest.raises(ValueError, match="deflate"):
        solve(lambda X: X, np.ones((1, 3)), restart=5, deflate=-1)


def test_deflated_gmres_in_single_precision_keeps_its_basis_orthogonal():
    """complex64 right-hand sides, many deflated restarts: the kept basis is reorthogonalized, so
    the solve reaches 1e-4 instead of stalling on a drifting basis."""
    rng = np.random.default_rng(11)
    n = 600
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)) + 1j * rng.standard_normal((n, n)))
    lam = 1 + 0.9 * np.sqrt(rng.random(n)) * np.exp(2j * np.pi * rng.random(n))
    lam[:8] = 0.003 * np.exp(2j * np.pi * np.arange(8) / 8)
    A = ((Q * lam) @ Q.conj().T).astype(np.complex64)
    b = (rng.standard_normal((1, n)) + 1j * rng.standard_normal((1, n))).astype(np.complex64)
    result = solve(lambda X: X @ A.T, b, tol=1e-4, max_iterations=1500, restart=24, deflate=10)
    assert result.true_residual[0] <= 1e-4


def test_exact_stagnation_is_not_a_crash():
    """A cyclic shift with b = e1 makes H_m singular: GMRES-DR reports non-convergence as GMRES does."""
    n = 40
    A = np.roll(np.eye(n), 1, axis=0)
    b = np.eye(n)[:1].astype(complex)
    with pytest.raises(KrylovNotConverged):
        solve(lambda X: X @ A.T, b, tol=1e-8, max_iterations=60, restart=10, deflate=3)


class _Flexible:
    """A preconditioner that is not a fixed linear map: a few GMRES steps on a nearby matrix."""

    flexible = True

    def __init__(self, N, steps):
        self.N, self.steps = N, steps

    def __call__(self, X):
        return gmres_steps(lambda Y: Y @ self.N.T, X, self.steps)


def test_gmres_steps_minimize_the_residual_over_the_krylov_space(system):
    """k steps from zero give the x in span{b, A b, …, A^{k−1} b} of least residual (checked by a
    least-squares solve on that explicit basis), per right-hand side; n steps solve exactly."""
    A, b, exact = system
    k = 6
    x = gmres_steps(lambda X: X @ A.T, b, k)
    for p in range(len(b)):
        K = np.empty((len(A), k), dtype=complex)
        K[:, 0] = b[p]
        for i in range(1, k):
            K[:, i] = A @ K[:, i - 1]
        c = np.linalg.lstsq(A @ K, b[p], rcond=None)[0]
        assert np.linalg.norm(x[p] - K @ c) < 1e-8 * np.linalg.norm(K @ c)
    small = A[:12, :12]
    full = gmres_steps(lambda X: X @ small.T, b[:, :12], 12)
    assert np.allclose(full, np.linalg.solve(small, b[:, :12].T).T, atol=1e-8)


def test_a_fixed_preconditioner_gives_fgmres_the_iterates_of_right_preconditioned_gmres(system):
    """With a fixed linear M, FGMRES (the preconditioned vectors kept) and GMRES on A M take the same
    products to the same solution."""
    A, b, exact = system
    M = np.linalg.inv(A + 0.3 * np.diag(np.diag(A)))

    class Fixed:
        flexible = True

        def __call__(self, X):
            return X @ M.T

    for restart in (20, 3):  # 3: several cycles, each restarted from the true residual
        right = solve(lambda X: X @ A.T, b, tol=1e-9, max_iterations=2000, restart=restart,
                      preconditioner=lambda X: X @ M.T)
        flexible = solve(lambda X: X @ A.T, b, tol=1e-9, max_iterations=2000, restart=restart, preconditioner=Fixed())
        assert np.array_equal(right.iterations, flexible.iterations)
        assert np.allclose(flexible.x, exact, rtol=0, atol=1e-6 * np.abs(exact).max())
    assert max(flexible.iterations) > 3 * 2


def test_fgmres_converges_with_an_inner_solve_as_preconditioner(system):
    """An inner GMRES on a perturbed matrix as the preconditioner: FGMRES reaches the direct
    solution in fewer products than GMRES alone; the flexible preconditioner is refused by the
    methods that cannot take it."""
    A, b, exact = system
    rng = np.random.default_rng(3)
    N = A + 0.05 * (rng.standard_normal(A.shape) + 1j * rng.standard_normal(A.shape)) / np.sqrt(len(A))
    plain = solve(lambda X: X @ A.T, b, tol=1e-9, max_iterations=3000, restart=30)
    inner = solve(lambda X: X @ A.T, b, tol=1e-9, max_iterations=3000, restart=30, preconditioner=_Flexible(N, 40))
    print("products: GMRES(30)", plain.iterations, "FGMRES(30), 40 inner steps", inner.iterations)
    assert np.all(inner.iterations * 3 <= plain.iterations)
    assert np.allclose(inner.x, exact, rtol=0, atol=1e-6 * np.abs(exact).max())
    # restarted every 2 steps with 4 inner steps (several cycles), and from an initial guess
    short = solve(lambda X: X @ A.T, b, tol=1e-9, max_iterations=3000, restart=2, preconditioner=_Flexible(N, 4))
    assert max(short.iterations) > 2 * 3
    assert np.allclose(short.x, exact, rtol=0, atol=1e-6 * np.abs(exact).max())
    guess = exact + 1e-3 * np.abs(exact).max() * rng.standard_normal(exact.shape)
    warm = solve(lambda X: X @ A.T, b, tol=1e-9, max_iterations=3000, restart=30, preconditioner=_Flexible(N, 40),
                 x0=guess)
    assert np.all(warm.initial_residual < 0.1)
    assert np.allclose(warm.x, exact, rtol=0, atol=1e-6 * np.abs(exact).max())
    for method, deflate, why in (("csym", 0, "takes no preconditioner"), ("bicgstab", 0, "flexible preconditioner"),
                                 ("gmres", 5, "flexible preconditioner")):
        with pytest.raises(ValueError, match=why):
            solve(lambda X: X @ A.T, b, method=method, deflate=deflate, restart=30, preconditioner=_Flexible(N, 4))
