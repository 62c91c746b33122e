"""Shared fixtures: one OpenCL context per test session (device from WAVEBRDF_DEVICE)."""

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
