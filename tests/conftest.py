"""Shared fixtures: one OpenCL context per test session (device from WAVEBRDF_DEVICE); a record of
the models the comparisons' measuring process runs."""

from __future__ import annotations

import os

import numpy as np
import pytest

os.environ.setdefault("POCL_CACHE_DIR", os.path.join(os.path.dirname(__file__), "..", ".cache", "pocl"))


@pytest.fixture(scope="session")
def cl_ctx():
    """The ComputeContext all OpenCL tests run on (double precision required)."""
    from wavebrdf.solver.opencl import create_context

    return create_context()


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture
def models_run(monkeypatch):
    """(model name, the scene's surface cells) of every model a ``MeasuringProcess`` runs from now
    on, in order; the models still run (the list is what ran, not what was asked for)."""
    from wavebrdf.jobs.compare import MeasuringProcess

    ran = []
    measure = MeasuringProcess.measure

    def recorded(self, name, options, scene, label):
        ran.append((name, scene.surface.cells))
        return measure(self, name, options, scene, label)

    monkeypatch.setattr(MeasuringProcess, "measure", recorded)
    return ran
