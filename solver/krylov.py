"""Krylov solvers for A x = b with several right-hand sides solved side by side.

All solvers take ``matvec(X) -> A X`` on blocks X of shape (P, n) (one row per right-hand side),
so the operator is applied to both polarizations in one call (the AIM FFTs and the sparse
near-field pass then serve both). Right-hand sides that converge drop out of later products.

Methods (``method``):

``"gmres"``
    restarted GMRES(m) with modified Gram–Schmidt (Saad & Schultz 1986); minimal residual over
    the Krylov space, m + 1 stored vectors per right-hand side. With ``deflate`` = k > 0:
    GMRES-DR(m, k) (Morgan 2002), which keeps the k harmonic Ritz vectors nearest zero across
    each restart, in the same m + 1 vectors.
``"csym"``
    complex-symmetric MINRES (A = Aᵀ, not Hermitian): the Saunders–Simon–Yip tridiagonalization
    A V̄_k = V_{k+1} T_k with a minimal-residual QR of T_k (Bunse-Gerstner & Stöver 1999; the
    solver of the reference code, bem3d.md §7). Short recurrences, 4 stored vectors per
    right-hand side; the right-hand sides run in lockstep.
``"bicgstab"``
    BiCGStab (van der Vorst 1992), two products per iteration.

Preconditioning (``preconditioner``, a callable M(X) ≈ A⁻¹X on blocks): right preconditioning,
A M u = b, x = M u, so the residual is that of the original system ("gmres", "bicgstab"). A
preconditioner with ``flexible = True`` (an inner iterative solve: not a fixed linear map) is used
by flexible GMRES (FGMRES, Saad 1993; "gmres" without deflation only): each step's preconditioned
vector z_j = M(v_j) is kept beside v_j (twice GMRES's stored vectors) and x = Z y.

:func:`gmres_steps` runs a fixed number of GMRES steps from zero, without a stopping test: the
inner solve of such a preconditioner.

Initial guess (``x0``): taken scaled by the complex factor α = (A x0)ᴴ b / ‖A x0‖² per right-hand
side, the least-squares fit of A x0 to b (one product; its residual ‖b − α A x0‖ is never above
‖b‖, and α = 0 where A x0 = 0 or the fit gains less than :data:`MIN_GUESS_GAIN`). The solver then
finds the correction u from zero, A (M) u = b − α A x0, preconditioned as a cold solve is, to the
same stopping rule on the residual of the original system, x = α x0 + (M) u.

Stopping: the recurrence estimate of ‖r‖/‖b‖ ≤ ``tol``; the true residual ‖b − A x‖/‖b‖ is then
computed and must also be ≤ ``tol`` (otherwise the solver restarts from x, up to ``max_iterations``
products in all). A solve that does not reach it raises :class:`KrylovNotConverged`, which
carries a ``diagnostics`` dict (the scheduler records it and marks the task failed).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg.blas

from wavebrdf.solver.progress import RateLimit

logger = logging.getLogger(__name__)

__all__ = ["KRYLOV_METHODS", "MIN_GUESS_GAIN", "KrylovNotConverged", "KrylovResult", "gmres_steps", "solve"]

KRYLOV_METHODS = ("gmres", "csym", "bicgstab")
MIN_GUESS_GAIN = 0.1  # an initial guess is used where it lowers ‖r‖/‖b‖ to 0.9 or less


class KrylovNotConverged(RuntimeError):
    """The iterative solve missed its tolerance; ``diagnostics`` holds iterations and residuals."""

    def __init__(self, message: str, diagnostics: dict):
        super().__init__(message)
        self.diagnostics = diagnostics


@dataclass
class KrylovResult:
    """Solutions x (P, n), products per right-hand side, recurrence and true residuals, history."""

    x: np.ndarray
    method: str
    iterations: np.ndarray
    residual: np.ndarray
    true_residual: np.ndarray
    converged: np.ndarray
    seconds: float
    history: list = field(default_factory=list)
    initial_residual: np.ndarray | None = None  # ‖b − α A x0‖/‖b‖ per right-hand side (1: zero start)

    def diagnostics(self) -> dict:
        figures = {
            "krylov_method": self.method,
            "iterations": [int(i) for i in self.iterations],
            "residual": [float(r) for r in self.true_residual],
            "recurrence_residual": [float(r) for r in self.residual],
            "converged": bool(np.all(self.converged)),
            "solve_s": self.seconds,
        }
        if self.initial_residual is not None:
            figures["initial_residual"] = [float(r) for r in self.initial_residual]
        return figures


def _norms(X: np.ndarray) -> np.ndarray:
    return np.sqrt(np.sum(np.abs(X) ** 2, axis=-1))


class _Counter:
    """Wraps matvec, counting products per right-hand side and recording residual history."""

    def __init__(self, matvec, P: int, progress=None):
        self.matvec = matvec
        self.products = np.zeros(P, dtype=np.int64)
        self.history: list[list[float]] = [[] for _ in range(P)]
        self.progress = progress  # progress("krylov", None, products=, residual=) about once a second
        self._due = RateLimit(1.0)

    def __call__(self, X: np.ndarray, which: np.ndarray) -> np.ndarray:
        self.products[which] += 1
        return self.matvec(X)

    def record(self, which, residuals):
        for i, r in zip(np.atleast_1d(which), np.atleast_1d(residuals)):
            self.history[int(i)].append(float(r))
        if self.progress is not None and self._due():
            latest = [h[-1] for h in self.history if h]
            self.progress("krylov", None, products=int(self.products.max()), residual=max(latest))


def _givens(a: np.ndarray, b: np.ndarray):
    """Complex Givens (c real, s complex) with [c s; −s̄ c][a; b] = [ρ; 0], vectorized."""
    abs_a = np.abs(a)
    rho = np.sqrt(abs_a**2 + np.abs(b) ** 2)
    safe = np.where(abs_a > 0, abs_a, 1.0)
    phase = np.where(abs_a > 0, a / safe, 1.0)
    rho_safe = np.where(rho > 0, rho, 1.0)
    c = np.where(rho > 0, abs_a / rho_safe, 1.0)
    s = np.where(rho > 0, phase * np.conj(b) / rho_safe, 0.0)
    return c, s, phase * rho


# ---------------------------------------------------------------------------------------------


def _arnoldi(A: _Counter, V, H, idx, rows, j, passes: int = 1, operand=None):
    """Arnoldi step j for the rows ``idx`` of V and H (right-hand sides ``rows``): V[idx, j + 1]
    and H[idx, : j + 2, j] by modified Gram–Schmidt of A ``operand`` (default V[idx, j]; FGMRES:
    the preconditioned vector), ``passes`` times (2: reorthogonalized, for a basis carried across
    restarts); returns ‖w‖ per row (0: breakdown)."""
    w = np.ascontiguousarray(A(V[idx, j] if operand is None else operand, rows), dtype=V.dtype)
    H[idx, : j + 1, j] = 0.0
    axpy = scipy.linalg.blas.get_blas_funcs("axpy", (w,))
    for _ in range(passes):
        for i in range(j + 1):
            for a, p in enumerate(idx):  # BLAS on the rows in place: no copies of V's vectors
                h = np.vdot(V[p, i], w[a])
                H[p, i, j] += h
                row = axpy(V[p, i], w[a], a=-h)
                if row.ctypes.data != w[a].ctypes.data:  # updated in place unless BLAS had to copy
                    w[a] = row
    hn = _norms(w)
    H[idx, j + 1, j] = hn
    V[idx, j + 1] = w / np.where(hn > 0, hn, 1.0)[:, None]
    return hn


def _gmres_cycle(A: _Counter, x, r, bnorm, which, tol, m, budget, flexible=None):
    """One GMRES(m) cycle for the right-hand sides ``which``; updates x in place. ``flexible``: a
    preconditioner that may change from step to step (FGMRES, Saad 1993): A is then the plain
    operator, each step's z_j = flexible(v_j) is kept and x += Z y."""
    P, n = len(which), x.shape[1]
    beta = _norms(r)
    V = np.zeros((P, m + 1, n), dtype=x.dtype)
    Z = None if flexible is None else np.zeros((P, m, n), dtype=x.dtype)
    V[:, 0] = r / beta[:, None]
    H = np.zeros((P, m + 1, m), dtype=x.dtype)
    cs = np.zeros((P, m))
    sn = np.zeros((P, m), dtype=x.dtype)
    g = np.zeros((P, m + 1), dtype=x.dtype)
    g[:, 0] = beta
    steps = np.zeros(P, dtype=np.int64)  # Krylov dimension reached by each right-hand side
    live = np.ones(P, dtype=bool)
    for j in range(m):
        idx = np.flatnonzero(live & (A.products[which] < budget))
        if len(idx) == 0:
            break
        operand = None
        if Z is not None:
            Z[idx, j] = flexible(V[idx, j])
            operand = Z[idx, j]
        hn = _arnoldi(A, V, H, idx, which[idx], j, operand=operand)
        for i in range(j):  # previous rotations on column j
            a, b = H[idx, i, j], H[idx, i + 1, j]
            H[idx, i, j] = cs[idx, i] * a + sn[idx, i] * b
            H[idx, i + 1, j] = -np.conj(sn[idx, i]) * a + cs[idx, i] * b
        c, s, rho = _givens(H[idx, j, j], H[idx, j + 1, j])
        cs[idx, j], sn[idx, j] = c, s
        H[idx, j, j], H[idx, j + 1, j] = rho, 0.0
        g[idx, j + 1] = -np.conj(s) * g[idx, j]
        g[idx, j] = c * g[idx, j]
        steps[idx] = j + 1
        res = np.abs(g[idx, j + 1]) / bnorm[idx]
        A.record(which[idx], res)
        live[idx[(res <= tol) | (hn == 0)]] = False
    for p in range(P):
        k = steps[p]
        if k == 0:
            continue
        try:
            y = np.linalg.solve(np.triu(H[p, :k, :k]), g[p, :k])
        except np.linalg.LinAlgError:  # singular H: FGMRES can break down with a changing preconditioner
            y = np.linalg.lstsq(np.triu(H[p, :k, :k]), g[p, :k], rcond=None)[0]
        x[p] += y @ (V[p, :k] if Z is None else Z[p, :k])
    return np.abs(g[np.arange(P), steps]) / bnorm


def _gmres(A, b, x, tol, max_iterations, restart, bnorm, flexible=None):
    P = len(b)
    everyone = np.arange(P)
    r = b - A(x, everyone) if np.any(x) else b.copy()
    true = _norms(r) / bnorm
    estimate = true.copy()
    active = true > tol
    while np.any(active) and np.any(A.products[active] < max_iterations):
        which = np.flatnonzero(active & (A.products < max_iterations))
        x_w = x[which]  # a copy (fancy indexing): the cycle updates it, then it is written back
        estimate[which] = _gmres_cycle(A, x_w, r[which], bnorm[which], which, tol, restart, max_iterations, flexible)
        x[which] = x_w
        r[which] = b[which] - A(x[which], which)
        true[which] = _norms(r[which]) / bnorm[which]
        active = true > tol
    return x, estimate, true


def _least_squares(Hbar: np.ndarray, c: np.ndarray):
    """(y, c − H̄ y) of min ‖c − H̄ y‖ for a small (j+1) × j matrix, in double precision."""
    y = np.linalg.lstsq(Hbar, c, rcond=None)[0]
    return y, c - Hbar @ y


def _deflate(H: np.ndarray, rho: np.ndarray, k: int):
    """The restart of GMRES-DR (Morgan 2002): the (m+1) × (k+1) orthonormal Q whose first k columns
    span the k harmonic Ritz vectors of H̄ (m+1) × m nearest zero and whose span holds the residual
    coefficients ``rho``; the next cycle starts from V Q, H̄ ← Qᴴ H̄ Q[:m, :k], c ← Qᴴ rho."""
    m = H.shape[1]
    Hm = H[:m, :m]
    f = np.linalg.solve(Hm.conj().T, np.eye(m)[-1])
    theta, G = np.linalg.eig(Hm + np.abs(H[m, m - 1]) ** 2 * np.outer(f, np.eye(m)[-1]))
    basis = np.zeros((m + 1, k + 1), dtype=complex)
    basis[:m, :k] = G[:, np.argsort(np.abs(theta))[:k]]
    basis[:, k] = rho
    return np.linalg.qr(basis)[0]


def _gmres_dr(A, b, x, tol, max_iterations, m, k, bnorm):
    """GMRES-DR(m, k): restarted GMRES that keeps, at each restart, the k harmonic Ritz vectors
    nearest zero beside the residual (Morgan 2002), so the slow modes a plain restart forgets are
    deflated; same stored vectors as GMRES(m). The residual is carried in the Arnoldi basis between
    cycles and the true one computed where the estimate reaches ``tol`` (a miss restarts afresh)."""
    P, n = b.shape
    everyone = np.arange(P)
    r = b - A(x, everyone) if np.any(x) else b.copy()
    true = _norms(r) / bnorm
    estimate = true.copy()
    V = np.zeros((P, m + 1, n), dtype=b.dtype)
    H = np.zeros((P, m + 1, m), dtype=complex)
    c = np.zeros((P, m + 1), dtype=complex)
    first = np.zeros(P, dtype=np.int64)  # the columns a cycle inherits from the last (0: a fresh start)
    fresh = np.ones(P, dtype=bool)
    active = true > tol
    while True:
        which = np.flatnonzero(active & (A.products < max_iterations))
        if len(which) == 0:
            break
        for p in which[fresh[which]]:
            beta = np.linalg.norm(r[p])
            V[p, 0] = r[p] / beta
            H[p], c[p], first[p] = 0.0, 0.0, 0
            c[p, 0] = beta
        fresh[which] = False
        steps = first.copy()
        live = np.zeros(P, dtype=bool)
        live[which] = True
        for j in range(int(first[which].min()), m):
            idx = which[live[which] & (first[which] <= j) & (A.products[which] < max_iterations)]
            if len(idx) == 0:
                break
            hn = _arnoldi(A, V, H, idx, idx, j, passes=2)
            steps[idx] = j + 1
            res = np.array([np.linalg.norm(_least_squares(H[p, : j + 2, : j + 1], c[p, : j + 2])[1])
                            for p in idx]) / bnorm[idx]
            estimate[idx] = res
            A.record(idx, res)
            live[idx[(res <= tol) | (hn == 0)]] = False
        check = []
        for p in which:
            j = int(steps[p])
            if j == 0:
                continue
            y, rho = _least_squares(H[p, : j + 1, :j], c[p, : j + 1])
            x[p] += y.astype(V.dtype) @ V[p, :j]
            estimate[p] = np.linalg.norm(rho) / bnorm[p]
            if estimate[p] <= tol or j < m or A.products[p] >= max_iterations:
                check.append(p)
                continue
            try:
                Q = _deflate(H[p], rho, k)
            except np.linalg.LinAlgError:  # singular H_m (exact stagnation): restart plainly
                check.append(p)
                continue
            V[p, : k + 1] = Q.T.astype(V.dtype) @ V[p]
            H[p, : k + 1, :k] = Q.conj().T @ H[p] @ Q[:m, :k]
            H[p, k + 1 :], H[p, :, k:] = 0.0, 0.0
            c[p] = 0.0
            c[p, : k + 1] = Q.conj().T @ rho
            first[p] = k
        if check:
            check = np.array(check)
            r[check] = b[check] - A(x[check], check)
            true[check] = _norms(r[check]) / bnorm[check]
            active[check] = true[check] > tol
            fresh[check] = True
    return x, estimate, true


def _csym(A, b, x, tol, max_iterations, bnorm):
    """Complex-symmetric MINRES on the SSY tridiagonalization; the right-hand sides iterate in
    lockstep (one product call serves all that are still iterating), each with its own
    recurrence, exactly as if solved alone."""
    P, n = b.shape
    estimate = np.zeros(P)
    true = np.zeros(P)
    pending = np.arange(P)
    while len(pending):  # restarts from the current x when the true residual misses tol
        r0 = b[pending].copy()
        started = np.flatnonzero(np.any(x[pending] != 0, axis=1))
        if len(started):
            r0[started] -= A(x[pending[started]], pending[started])
        beta1 = _norms(r0)
        true[pending] = beta1 / bnorm[pending]
        estimate[pending] = true[pending]  # a right-hand side that needs no iteration keeps its true residual
        going = (true[pending] > tol) & (A.products[pending] < max_iterations)
        pending, r0, beta1 = pending[going], r0[going], beta1[going]
        if len(pending):
            _csym_cycle(A, x, pending, r0, beta1, bnorm, tol, max_iterations, estimate)
    return x, estimate, true


def _csym_cycle(A, x, rows, r0, beta1, bnorm, tol, max_iterations, estimate):
    """One MINRES run from residuals r0 (k, n) of the right-hand sides ``rows``, until each
    one's recurrence estimate reaches tol (or its products reach ``max_iterations``)."""
    k = len(r0)
    vdtype = r0.dtype
    v = r0 / beta1[:, None].astype(vdtype)
    v_prev = np.zeros_like(v)
    d1 = np.zeros_like(v)  # directions d_{k−1}, d_{k−2}
    d2 = np.zeros_like(v)
    beta = np.zeros(k)
    # QR state: rotations k−1, k−2 and the rotated right-hand side
    c1, c2 = np.ones(k), np.ones(k)
    s1, s2 = np.zeros(k, dtype=complex), np.zeros(k, dtype=complex)
    phi = beta1.astype(complex)
    active = np.arange(k)
    while len(active):
        active = active[A.products[rows[active]] < max_iterations]
        if not len(active):
            break
        a = active
        va = v[a]
        va_conj = np.conj(va)
        q = A(va_conj, rows[a])
        alpha = np.sum(va_conj * q, axis=1).astype(complex)
        q -= alpha[:, None].astype(vdtype) * va + beta[a][:, None].astype(vdtype) * v_prev[a]
        beta_next = _norms(q).astype(float)
        # column k of T: (β_k, α_k, β_{k+1}) on rows (k−1, k, k+1)
        e2 = s2[a] * beta[a]  # row k−2 after rotation k−2 (row k−2 entry starts at 0)
        t = c2[a] * beta[a]
        e1 = c1[a] * t + s1[a] * alpha
        diag = -np.conj(s1[a]) * t + c1[a] * alpha
        c, s, rho = _givens(diag, beta_next)
        d = (va_conj - e1[:, None].astype(vdtype) * d1[a] - e2[:, None].astype(vdtype) * d2[a]) \
            / rho[:, None].astype(vdtype)
        tau = c * phi[a]
        phi[a] = -np.conj(s) * phi[a]
        x[rows[a]] += tau[:, None].astype(vdtype) * d
        d2[a], d1[a] = d1[a], d
        c2[a], s2[a], c1[a], s1[a] = c1[a], s1[a], c, s
        v_prev[a] = va
        v[a] = q / np.where(beta_next > 0, beta_next, 1.0)[:, None].astype(vdtype)
        beta[a] = beta_next
        estimate[rows[a]] = np.abs(phi[a]) / bnorm[rows[a]]
        A.record(rows[a], estimate[rows[a]])
        active = a[(estimate[rows[a]] > tol) & (beta_next != 0)]


def _bicgstab(A, b, x, tol, max_iterations, bnorm):
    P = len(b)
    everyone = np.arange(P)
    estimate = np.zeros(P)
    while True:
        r = b - A(x, everyone) if np.any(x) else b.copy()
        true = _norms(r) / bnorm
        active = np.flatnonzero((true > tol) & (A.products < max_iterations))
        if len(active) == 0:
            return x, np.where(estimate > 0, estimate, true), true
        r_hat = r.copy()
        rho, alpha, omega = (np.ones(P, dtype=b.dtype) for _ in range(3))
        v = np.zeros_like(b)
        p_dir = np.zeros_like(b)
        live = np.zeros(P, dtype=bool)
        live[active] = True
        while True:
            idx = np.flatnonzero(live & (A.products < max_iterations))
            if len(idx) == 0:
                break
            rho_new = np.sum(np.conj(r_hat[idx]) * r[idx], axis=1)
            beta = (rho_new / rho[idx]) * (alpha[idx] / omega[idx])
            p_dir[idx] = r[idx] + beta[:, None] * (p_dir[idx] - omega[idx, None] * v[idx])
            v[idx] = A(p_dir[idx], idx)
            alpha[idx] = rho_new / np.sum(np.conj(r_hat[idx]) * v[idx], axis=1)
            s = r[idx] - alpha[idx, None] * v[idx]
            t = A(s, idx)
            omega[idx] = np.sum(np.conj(t) * s, axis=1) / np.sum(np.abs(t) ** 2, axis=1)
            x[idx] += alpha[idx, None] * p_dir[idx] + omega[idx, None] * s
            r[idx] = s - omega[idx, None] * t
            rho[idx] = rho_new
            res = _norms(r[idx]) / bnorm[idx]
            estimate[idx] = res
            A.record(idx, res)
            live[idx[res <= tol]] = False
        # loop back: true residual check and restart if needed


def _scaled_guess(A: _Counter, apply, b: np.ndarray, x0: np.ndarray, bnorm: np.ndarray):
    """(α x0, b − α A x0, ‖b − α A x0‖/‖b‖) with the least-squares α per right-hand side (module
    docstring); one product of ``apply`` (the unpreconditioned operator) for the rows with x0 ≠ 0."""
    start = np.zeros_like(b)
    r = b.copy()
    rows = np.flatnonzero(np.any(x0 != 0, axis=1))
    if len(rows):
        A.products[rows] += 1
        w = apply(x0[rows])
        ww = np.sum(np.abs(w) ** 2, axis=1)
        alpha = np.sum(np.conj(w) * b[rows], axis=1) / np.where(ww > 0, ww, 1.0)
        fitted = b[rows] - alpha[:, None] * w
        useful = (ww > 0) & (_norms(fitted) <= (1.0 - MIN_GUESS_GAIN) * bnorm[rows])
        start[rows[useful]] = alpha[useful, None] * x0[rows[useful]]
        r[rows[useful]] = fitted[useful]
    return start, r, _norms(r) / bnorm


def solve(matvec, b: np.ndarray, *, method: str = "gmres", tol: float = 1e-4, max_iterations: int = 1000,
          restart: int = 60, deflate: int = 0, x0: np.ndarray | None = None, preconditioner=None,
          progress=None) -> KrylovResult:
    """Solve A x = b for right-hand sides b (P, n); see the module docstring.

    ``max_iterations`` bounds the operator products per right-hand side (the initial guess's one
    included). ``x0`` (P, n): an initial guess, least-squares scaled (module docstring). ``progress``
    (solver/progress.py) receives ``("krylov", None, products=, residual=)`` about once a second.
    Raises :class:`KrylovNotConverged` (with ``diagnostics``) if the true residual misses ``tol``.
    """
    if method not in KRYLOV_METHODS:
        raise ValueError(f"krylov method must be one of {KRYLOV_METHODS}, got {method!r}")
    if preconditioner is not None and method == "csym":
        raise ValueError("krylov method 'csym' takes no preconditioner (it needs a symmetric one); use 'gmres'")
    if not (0 < tol < 1):
        raise ValueError(f"krylov tolerance must be in (0, 1), got {tol!r}")
    if int(max_iterations) != max_iterations or max_iterations < 1:
        raise ValueError(f"krylov max_iterations must be a positive integer, got {max_iterations!r}")
    if int(restart) != restart or restart < 1:
        raise ValueError(f"krylov restart must be a positive integer, got {restart!r}")
    if int(deflate) != deflate or not 0 <= deflate < restart:
        raise ValueError(f"krylov deflate must be an integer in [0, restart = {restart}), got {deflate!r}")
    flexible = preconditioner is not None and bool(getattr(preconditioner, "flexible", False))
    if flexible and (method != "gmres" or deflate):
        raise ValueError(f"a flexible preconditioner (an inner solve) needs krylov method 'gmres' without deflation "
                         f"(FGMRES); got method {method!r}, deflate {deflate!r}")
    b = np.atleast_2d(np.asarray(b))
    dtype = np.result_type(b, np.complex64)
    b = b.astype(dtype, copy=False)
    bnorm = _norms(b)
    if np.any(bnorm == 0):
        raise ValueError("krylov: a right-hand side is zero")

    def apply(X):
        return np.asarray(matvec(X)).astype(dtype, copy=False)

    if preconditioner is None or flexible:
        A = _Counter(apply, len(b), progress)
    else:
        A = _Counter(lambda X: apply(preconditioner(X)), len(b), progress)
    t0 = time.perf_counter()
    start, r, initial = None, b, None
    if x0 is not None:
        x0 = np.atleast_2d(np.asarray(x0))
        if x0.shape != b.shape:
            raise ValueError(f"krylov: x0 has shape {x0.shape}, the right-hand sides {b.shape}")
        start, r, initial = _scaled_guess(A, apply, b, x0.astype(dtype, copy=False), bnorm)
    x = np.zeros_like(b)
    if method == "gmres" and deflate:
        x, estimate, true = _gmres_dr(A, r, x, tol, max_iterations, int(restart), int(deflate), bnorm)
    elif method == "gmres":
        x, estimate, true = _gmres(A, r, x, tol, max_iterations, int(restart), bnorm,
                                   flexible=preconditioner if flexible else None)
    elif method == "csym":
        x, estimate, true = _csym(A, r, x, tol, max_iterations, bnorm)
    else:
        x, estimate, true = _bicgstab(A, r, x, tol, max_iterations, bnorm)
    if preconditioner is not None and not flexible:
        x = np.asarray(preconditioner(x)).astype(dtype, copy=False)
    if start is not None:
        x = start + x
    result = KrylovResult(x=x, method=method, iterations=A.products.copy(), residual=estimate, true_residual=true,
                          converged=true <= tol, seconds=time.perf_counter() - t0, history=A.history,
                          initial_residual=initial)
    logger.info("%s: %s products, true residual %s (tol %g) in %.2f s", method, result.iterations.tolist(),
                np.array2string(true, precision=2), tol, result.seconds)
    if not np.all(result.converged):
        diag = result.diagnostics()
        diag.update(tolerance=tol, max_iterations=int(max_iterations))
        raise KrylovNotConverged(
            f"{method} did not converge: relative residual {np.array2string(true, precision=3)} > {tol:g} after "
            f"{result.iterations.tolist()} operator products (limit {max_iterations})",
            diag,
        )
    return result


def gmres_steps(matvec, b: np.ndarray, steps: int, preconditioner=None) -> np.ndarray:
    """x (P, n) after ``steps`` GMRES steps on A x = b from zero for each right-hand side of b (P,
    n), right-preconditioned by the fixed ``preconditioner`` (None: none); no stopping test (a
    right-hand side stops early only at an exact breakdown), no restart. In b's precision (complex:
    at least complex64)."""
    if int(steps) != steps or steps < 1:
        raise ValueError(f"gmres_steps: steps must be a positive integer, got {steps!r}")
    b = np.atleast_2d(b)
    b = b.astype(np.result_type(b, np.complex64), copy=False)
    bnorm = _norms(b)
    if preconditioner is None:
        A = _Counter(lambda X: np.asarray(matvec(X)).astype(b.dtype, copy=False), len(b))
    else:
        A = _Counter(lambda X: np.asarray(matvec(preconditioner(X))).astype(b.dtype, copy=False), len(b))
    x = np.zeros_like(b)
    rows = np.flatnonzero(bnorm > 0)
    if len(rows):
        x_w = x[rows]
        _gmres_cycle(A, x_w, b[rows], bnorm[rows], rows, 0.0, int(steps), int(steps))
        x[rows] = x_w
    return x if preconditioner is None else np.asarray(preconditioner(x)).astype(b.dtype, copy=False)
