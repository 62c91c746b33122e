"""The floating-point precision of a task's kernels, device buffers and FFTs.

One typed value per task: the config resolves ``[model] precision`` once (jobs/sections.py), the
plan puts it in the task's scene (``SurfaceScene.precision``, ``FiberScene.precision``), and the
models pass it down as it is; the full-wave AIM solver resolves its own once per scene from the
scene's, ``[model.aim] precision`` and its memory-budget fit (solver/bem3d/model.py
``aim_options``). What depends on it asks the value (:attr:`Precision.real`,
:attr:`Precision.complex`, :attr:`Precision.fp64`) instead of comparing strings; the device's
double-precision support is checked where a double-precision kernel is built
(:meth:`~wavebrdf.solver.opencl.ComputeContext.program`).

A :class:`Precision` equals its config word (``Precision.SINGLE == "single"``) and prints as it,
so messages, records and fingerprints read as the config does.
"""

from __future__ import annotations

from enum import StrEnum

import numpy as np

__all__ = ["PRECISIONS", "Precision"]


class Precision(StrEnum):
    """``"double"`` (float64 / complex128) or ``"single"`` (float32 / complex64)."""

    DOUBLE = "double"
    SINGLE = "single"

    def __repr__(self) -> str:
        return repr(self.value)  # as the config writes it, in messages and estimate details

    @classmethod
    def of(cls, value) -> Precision:
        """``value`` (a Precision or its word) as a Precision; ValueError naming the choices."""
        try:
            return cls(value)
        except ValueError:
            choices = ", ".join(f'"{p.value}"' for p in cls)
            raise ValueError(f"must be one of {choices}") from None

    @property
    def fp64(self) -> bool:
        """Kernels in double precision (``WB_FP64``): the device needs cl_khr_fp64."""
        return self is Precision.DOUBLE

    @property
    def real(self) -> np.dtype:
        return np.dtype(np.float64 if self.fp64 else np.float32)

    @property
    def complex(self) -> np.dtype:
        return np.dtype(np.complex128 if self.fp64 else np.complex64)


PRECISIONS = tuple(p.value for p in Precision)  # the config's words
