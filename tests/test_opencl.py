"""OpenCL runtime layer: device choice, build cache keys, kernel sources."""

from __future__ import annotations

import numpy as np
import pytest

from wavebrdf.kernels import load_source, source_hash
from wavebrdf.solver.opencl import OpenCLUnavailable, choose_device, list_devices


def test_device_listing_reports_fp64():
    infos = list_devices()
    assert infos and all(isinstance(i.fp64, bool) for i in infos)
    assert choose_device("auto", infos).fp64


def test_unknown_device_spec_lists_alternatives():
    infos = list_devices()
    with pytest.raises(OpenCLUnavailable, match="matches no OpenCL device. Available:"):
        choose_device("no-such-accelerator-9000", infos)
    assert choose_device(infos[0].spec, infos) == infos[0]


def test_sources_are_self_contained():
    text = load_source("kirchhoff.cl")
    assert '#include "' not in text
    assert "typedef real2_t cplx_t" in text and text.count("begin wb_types.h") == 1


def test_program_cache_key_covers_defines(cl_ctx):
    a = cl_ctx.program("kirchhoff.cl", {"WB_FP64": 1, "NMAX_BUF": 16})
    b = cl_ctx.program("kirchhoff.cl", {"NMAX_BUF": 16, "WB_FP64": 1})
    c = cl_ctx.program("kirchhoff.cl", {"WB_FP64": 0, "NMAX_BUF": 16})
    assert a is b and a is not c
    assert source_hash(load_source("kirchhoff.cl")) != source_hash(load_source("kirchhoff.cl") + " ")


def test_bessel_sequence_kernel_matches_scipy(cl_ctx):
    """The Miller-recurrence Bessel sequence in kirchhoff.cl against scipy.special.jv."""
    import pyopencl as cl
    import scipy.special


    x = np.concatenate([[0.0, 1e-9, -1e-7, 3e-6], np.linspace(-40, 40, 801)])
    nmax = 60
    knl = cl_ctx.kernel("kirchhoff.cl", "kirchhoff_fields", {"WB_FP64": 1, "NMAX_BUF": nmax + 1})
    n = x.size
    mf = cl.mem_flags
    buf = lambda a: cl.Buffer(cl_ctx.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(a))
    out = cl.Buffer(cl_ctx.context, mf.WRITE_ONLY, (nmax + 1) * n * 16)
    # k = 2, mu_i = -0.5 and unit window/chirps: g_n = eps_n j^n J_n(x)
    knl(cl_ctx.queue, (n,), None, buf(x), buf(np.ones(n, complex)), buf(np.ones(n, complex)), buf(np.ones(1, complex)),
        np.int32(n), np.int32(1), np.int32(nmax), np.float64(2.0), np.float64(-0.5), out)
    g = np.empty((nmax + 1, n), complex)
    cl.enqueue_copy(cl_ctx.queue, g, out)
    orders = np.arange(nmax + 1)
    expected = (np.where(orders == 0, 1, 2) * 1j**orders)[:, None] * scipy.special.jv(orders[:, None], x[None])
    assert np.max(np.abs(g - expected)) < 1e-13


WORKER_FFT_PROBE = """
import numpy as np
from wavebrdf.solver.opencl import create_context, fft_workers
from wavebrdf.solver.surface import generate
from wavebrdf.solver.bem3d.driver import BEMSolver

ctx = create_context()
solver = BEMSolver(ctx, generate("gaussian", cells=12, size_um=1.2, seed=1, rms_height_um=0.02, correlation_um=0.3),
                   0.5, 1.5, method="aim")
print(fft_workers(), ctx.fft_workers, solver.operator.base.workers)
"""


@pytest.mark.parametrize("workers_on_node", [1, 2])
def test_a_worker_uses_the_fft_threads_it_was_given(workers_on_node):
    """The batch layer caps each worker's threads with WAVEBRDF_FFT_WORKERS (worker_environment);
    the host FFTs of every model, AIM's included, must use that many threads, not every CPU."""
    import os
    import subprocess
    import sys

    from wavebrdf.jobs.node import worker_environment

    env = {**os.environ, **worker_environment(workers_on_node, 0, cores=2)}
    env["POCL_CACHE_DIR"] = os.environ["POCL_CACHE_DIR"]  # the suite's kernel cache: no rebuild
    out = subprocess.run([sys.executable, "-c", WORKER_FFT_PROBE], env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    expected = str(2 // workers_on_node)
    assert out.stdout.split() == [expected] * 3, out.stdout


def test_bad_fft_worker_count_is_refused(monkeypatch):
    from wavebrdf.solver.opencl import fft_workers

    monkeypatch.setenv("WAVEBRDF_FFT_WORKERS", "zero")
    with pytest.raises(ValueError, match="WAVEBRDF_FFT_WORKERS='zero': must be an integer >= 1"):
        fft_workers()
    monkeypatch.setenv("WAVEBRDF_FFT_WORKERS", "0")
    with pytest.raises(ValueError, match="must be an integer >= 1"):
        fft_workers()
