"""Progress inside one model run: the seam between a solver and whoever shows it.

A model reports through ``ctx.progress`` (the :class:`~wavebrdf.solver.opencl.ComputeContext` it is
given): ``ctx.progress(stage, fraction, **figures)`` with a stage name ("projection", "near field",
"preconditioner", "krylov", "far field", ...), the fraction of that stage done (None: unknown)
and figures such as ``products`` (Krylov operator products so far) and ``residual`` (relative).
Solvers never print; the batch layer (jobs/progress.py) decides what is shown, where and how often.
Reports must be cheap: a solver calls at most about once a second (:class:`RateLimit`).
"""

from __future__ import annotations

import time

__all__ = ["RateLimit", "silent"]


def silent(stage: str, fraction: float | None = None, **figures) -> None:
    """The reporter of a context nobody watches."""


class RateLimit:
    """True at most once per ``seconds`` (and on the first call)."""

    def __init__(self, seconds: float = 1.0):
        self.seconds = seconds
        self._last = -float("inf")

    def __call__(self) -> bool:
        now = time.monotonic()
        if now - self._last < self.seconds:
            return False
        self._last = now
        return True
