"""The AIM base matrix B = Λᵀ G Λ applied by FFT convolution on the grid (bem3d.md §6.5).

For every group of grid media that share one projection (moment matching: both media in one
group; far-field matching: one group per medium, since Λ depends on k):

1. scatter: charges q = Λ x on the compact grid, 8 components per right-hand side
   [J_x, J_y, J_z, J_div, M_x, M_y, M_z, M_div] (kernel ``aim_scatter``);
2. forward FFT of each component onto the padded grid (pruned: the zero padding is never
   transformed);
3. multiplication by the kernel spectra with the PMCHWT coefficients, giving the grid fields
   [E_x, E_y, E_z, E_div, H_x, H_y, H_z, H_div] (kernel ``aim_fourier``, formulas in aim.cl);
4. inverse FFT (pruned: only the unpadded block is kept);
5. gather: y += Λᵀ F per rooftop (kernel ``aim_gather``).

That is 8 forward and 8 inverse FFTs per group and right-hand side (the reference plan 0 used
22 per medium). FFT backend: ``"host"`` (scipy.fft on host memory that the OpenCL buffers
share, zero-copy on CPU devices) or ``"vkfft"`` (pyvkfft on the device, for GPUs). ``"auto"``
picks the host FFT on CPU devices, where it was measured faster (docs/aim.md), and VkFFT on GPUs
when pyvkfft is installed. Host FFTs run on ``solver.opencl.fft_workers()`` threads (the
``WAVEBRDF_FFT_WORKERS`` cap of the batch layer, else the CPUs this process may use).

NumPy twins: :func:`scatter_numpy`, :func:`fourier_numpy`, :func:`gather_numpy` and
:meth:`BaseOperator.apply_numpy`.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np
import scipy.fft
import scipy.sparse

from wavebrdf.solver.bem3d.aim.green import KernelSpectra
from wavebrdf.solver.bem3d.aim.projection import Projection
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.farfield import ETA0
from wavebrdf.solver.opencl import fft_workers
from wavebrdf.solver.precision import Precision

logger = logging.getLogger(__name__)

__all__ = [
    "FFT_BACKENDS",
    "PACKED_BATCHES",
    "batch_chunks",
    "BaseOperator",
    "GridGroup",
    "forward_pruned",
    "fourier_coefficients",
    "fourier_numpy",
    "gather_numpy",
    "inverse_pruned",
    "projection_matrices",
    "scatter_numpy",
    "int4_arg",
]

FFT_BACKENDS = ("auto", "host", "vkfft")
PACKED_BATCHES = (1, 2, 4)  # right-hand sides per launch that aim.cl packs into one SIMD vector
SLAB_BYTES = 64 * 2**20  # spectrum slab of the host FFTs (BaseOperator._apply_host)


def batch_chunks(n: int):
    """Slices of n right-hand sides in packed batch sizes: pairs and, for odd n, a last single."""
    return [slice(i, min(n, i + 2)) for i in range(0, n, 2)]


def forward_pruned(q: np.ndarray, padded, workers: int | None = None) -> np.ndarray:
    """FFT of compact arrays (…, n_x, n_y, n_z) zero-padded to ``padded``, never transforming zeros."""
    a = scipy.fft.fft(q, n=padded[2], axis=-1, workers=workers)
    a = scipy.fft.fft(a, n=padded[1], axis=-2, workers=workers)
    return scipy.fft.fft(a, n=padded[0], axis=-3, workers=workers)


def inverse_pruned(Q: np.ndarray, shape, workers: int | None = None) -> np.ndarray:
    """Inverse FFT of padded spectra, keeping only the compact block [0, n) of every axis."""
    a = scipy.fft.ifft(Q, axis=-3, workers=workers)[..., : shape[0], :, :]
    a = scipy.fft.ifft(a, axis=-2, workers=workers)[..., :, : shape[1], :]
    return np.ascontiguousarray(scipy.fft.ifft(a, axis=-1, workers=workers)[..., : shape[2]])


def fourier_coefficients(media: Media, grid_media) -> np.ndarray:
    """(4, n) coefficients (ee_vec, mm_vec, ee_div, mm_div) of the grid media (media.py)."""
    c = media.pmchwt_coefficients()
    idx = list(grid_media)
    return np.stack([c["ee_vec"][idx], c["mm_vec"][idx], c["ee_div"][idx], c["mm_div"][idx]])


@dataclass
class GridGroup:
    """One projection and the grid media it serves, with their spectra (host arrays)."""

    projection: Projection
    media: tuple[int, ...]
    green: np.ndarray  # (n_media, P…) FFT of g_i
    gradient: np.ndarray  # (3, P…) η₀ Σ_i FFT(∂_a g_i)
    coefficients: np.ndarray  # (4, n_media)

    @classmethod
    def build(cls, projection: Projection, spectra: KernelSpectra, media: Media, indices, dtype):
        pos = [spectra.media.index(i) for i in indices]
        green = np.stack([spectra.green[p] for p in pos]).astype(dtype)
        gradient = (ETA0 * sum(spectra.gradient[p] for p in pos)).astype(dtype)
        return cls(projection, tuple(indices), green, gradient, fourier_coefficients(media, indices))


# ---------------------------------------------------------------------------------------------
# NumPy twins


def projection_matrices(projection: Projection, n_horizontal: int, components: int = 4) -> list[scipy.sparse.csc_matrix]:
    """Sparse (n_points × N_b) matrices Λ of the charge components (x, y, z, div)[:components].

    Built directly in CSC (column b = the S stencil weights of rooftop b; horizontal rooftops,
    b < n_horizontal, carry the x component, vertical ones y): no COO triplets, no sort, one
    shared index array, so the far field of a 6·10⁵-unknown patch needs ~0.6 GB here, not ~3 GB.
    """
    grid = projection.grid
    n_b = projection.weights.shape[1]
    S = grid.stencil_size
    rows = grid.linear_index(grid.stencil_points()).reshape(-1).astype(np.int32)  # < 2³¹ grid points
    shape = (grid.points, n_b)
    wt, wz, wd = (w.reshape(-1) for w in projection.weights)
    index_dtype = np.int32 if n_b * S < 2**31 else np.int64
    counts = np.arange(n_b + 1, dtype=index_dtype)
    horizontal = np.minimum(counts, n_horizontal) * S
    vertical = np.maximum(counts - n_horizontal, 0) * S
    split = n_horizontal * S
    mats = [
        scipy.sparse.csc_matrix((wt[:split], rows[:split], horizontal), shape=shape, copy=False),
        scipy.sparse.csc_matrix((wt[split:], rows[split:], vertical), shape=shape, copy=False),
        scipy.sparse.csc_matrix((wz, rows, counts * S), shape=shape, copy=False),
        scipy.sparse.csc_matrix((wd, rows, counts * S), shape=shape, copy=False),
    ]
    return mats[:components]


def scatter_numpy(mats, x: np.ndarray, n_b: int, shape) -> np.ndarray:
    """Charges (P, 8, n_x, n_y, n_z) of solutions x (P, 2N_b); twin of ``aim_scatter``."""
    x = np.atleast_2d(x)
    out = np.empty((len(x), 8) + tuple(shape), dtype=np.result_type(x, mats[0].dtype))
    for part, xs in enumerate((x[:, :n_b], x[:, n_b:])):
        for c, m in enumerate(mats):
            out[:, 4 * part + c] = (m @ xs.T).T.reshape((len(x),) + tuple(shape))
    return out


def fourier_numpy(green, gradient, coefficients, Q: np.ndarray) -> np.ndarray:
    """Grid-field spectra from charge spectra Q (P, 8, …); twin of ``aim_fourier``."""
    A, Ap, D, Dp = (np.tensordot(coefficients[r], green, axes=1) for r in range(4))
    B = gradient

    def curl(q):
        return [B[1] * q[2] - B[2] * q[1], B[2] * q[0] - B[0] * q[2], B[0] * q[1] - B[1] * q[0]]

    out = np.empty_like(Q)
    for p in range(len(Q)):
        qj, qm = Q[p, :3], Q[p, 4:7]
        cj, cm = curl(qj), curl(qm)
        for a in range(3):
            out[p, a] = A * qj[a] + cm[a]
            out[p, 4 + a] = Ap * qm[a] + cj[a]
        out[p, 3] = D * Q[p, 3]
        out[p, 7] = Dp * Q[p, 7]
    return out


def gather_numpy(mats, F: np.ndarray) -> np.ndarray:
    """y = Λᵀ F (P, 2N_b) from grid fields F (P, 8, …); twin of ``aim_gather``."""
    P = len(F)
    flat = F.reshape(P, 8, -1)
    e = sum(m.T @ flat[:, c].T for c, m in enumerate(mats)).T
    h = sum(m.T @ flat[:, 4 + c].T for c, m in enumerate(mats)).T
    return np.concatenate([e, h], axis=1)


# ---------------------------------------------------------------------------------------------
# The operator


class BaseOperator:
    """y = B x on the device (see the module docstring); ``apply_numpy`` is the reference."""

    def __init__(self, ctx, mesh, groups: list[GridGroup], *, precision: Precision = Precision.DOUBLE,
                 fft: str = "auto"):
        if fft not in FFT_BACKENDS:
            raise ValueError(f"aim fft must be one of {FFT_BACKENDS}, got {fft!r}")
        self.ctx = ctx
        self.mesh = mesh
        self.groups = groups
        self.grid = groups[0].projection.grid
        self.precision = precision
        self.workers = fft_workers()
        self.n_b = mesh.n_bases
        self.n_h = mesh.n_horizontal
        self.real, self.complex = precision.real, precision.complex
        self.fft = self._choose_fft(fft)
        # samples per work-item of aim_fourier (measured: docs/aim.md)
        self.fourier_lanes = 1 if ctx is None else ctx.vector_lanes(precision)
        self.timings = {"scatter_s": 0.0, "fft_s": 0.0, "fourier_s": 0.0, "gather_s": 0.0, "calls": 0}
        self._mats = None
        self._vkfft: dict = {}
        self._host: dict = {}
        if ctx is not None:
            self._upload()

    # -- set-up -----------------------------------------------------------------------------
    def _choose_fft(self, fft: str) -> str:
        if fft != "auto":
            return fft
        if self.ctx is not None and self.ctx.is_gpu:
            try:
                import pyvkfft.opencl  # noqa: F401

                return "vkfft"
            except ImportError:
                logger.warning("pyvkfft is not installed: AIM FFTs run on the host (pip install 'wavebrdf[fft]')")
        return "host"

    def _upload(self):
        ctx = self.ctx
        pointer, entries = self.grid.inverse_map()
        self._map = [ctx.to_device(a) for a in (pointer, entries)]
        self._origins = ctx.to_device(self.grid.origins, np.int32)
        self._device_groups = []
        self._host_weights = []  # arrays behind shared buffers
        for group in self.groups:
            w = group.projection.weights
            wdtype = self.real if not np.iscomplexobj(w) else self.complex
            by_basis = np.ascontiguousarray(w, wdtype)  # no copy when the dtype matches
            by_point = np.ascontiguousarray(by_basis.reshape(3, -1)[:, entries])  # streamed by aim_scatter
            self._host_weights += [by_basis, by_point]
            weights = (ctx.host_buffer(by_basis), ctx.host_buffer(by_point))  # shared on CPU devices
            green = ctx.host_buffer(group.green)
            gradient = ctx.host_buffer(group.gradient)
            coef = ctx.to_device(group.coefficients, self.complex)
            self._device_groups.append((weights, green, gradient, coef, np.iscomplexobj(w)))

    def _defines(self, batch: int, complex_weights: bool, n_media: int) -> dict:
        return self.ctx.defines(self.precision, AIM_BATCH=batch, AIM_COMPLEX_W=int(complex_weights),
                                AIM_NMED=n_media)

    # -- application ------------------------------------------------------------------------
    def apply(self, x: np.ndarray, y_buffer=None):
        """B x for x (P, 2N_b); adds into the device buffer ``y_buffer`` if given, else returns y."""
        import pyopencl as cl

        ctx = self.ctx
        mf = cl.mem_flags
        x = np.ascontiguousarray(np.atleast_2d(x), dtype=self.complex)
        if len(x) not in PACKED_BATCHES:
            if y_buffer is not None:
                raise ValueError(f"{len(x)} right-hand sides into one buffer: the kernels take {PACKED_BATCHES}")
            return np.concatenate([self.apply(x[c]) for c in batch_chunks(len(x))])
        x_buf = ctx.to_device(x)
        own_y = y_buffer is None
        if own_y:
            y_host = np.zeros_like(x)
            y_buffer = cl.Buffer(ctx.context, mf.READ_WRITE | mf.USE_HOST_PTR, hostbuf=y_host)
        for device_group, group in zip(self._device_groups, self.groups):
            if self.fft == "host":
                self._apply_host(len(x), x_buf, y_buffer, device_group, group)
            else:
                self._apply_device(len(x), x_buf, y_buffer, device_group, group)
        self.timings["calls"] += 1
        if own_y:
            _sync(ctx.queue, y_buffer, y_host)
            return y_host
        return y_buffer

    def _scatter(self, P, x_buf, q_buf, weights, defines, layout):
        knl = self.ctx.kernel("aim.cl", "aim_scatter", defines)
        knl(self.ctx.queue, (self.grid.points,), None, *self._map, int4_arg(self.grid.shape), int4_arg(layout),
            np.int32(self.grid.stencil_size), np.int32(self.n_b), np.int32(self.n_h), weights[1], x_buf, q_buf)

    def _fourier(self, Q_buf, green, gradient, coef, defines, samples: int | None = None, offset: int = 0):
        """``fourier_lanes`` samples per work-item (SIMD lanes) for whole vectors, then the rest one by
        one; ``Q_buf`` holds ``samples`` spectrum samples (default all) from sample ``offset``."""
        nfreq = self.grid.padded_points
        samples = nfreq if samples is None else samples
        done = 0
        for lanes in sorted({self.fourier_lanes, 1}, reverse=True):
            items = (samples - done) // lanes
            if items:
                knl = self.ctx.kernel("aim.cl", "aim_fourier", {**defines, "WB_VW": lanes})
                knl(self.ctx.queue, (items,), None, green, gradient, np.int64(nfreq), coef, Q_buf, np.int64(done),
                    np.int64(samples), np.int64(offset))
                done += items * lanes

    def _gather(self, F_buf, y_buffer, weights, defines, layout):
        sx, sy, sz = self.grid.stencil
        knl = self.ctx.kernel("aim.cl", "aim_gather", defines)
        knl(self.ctx.queue, (self.n_b,), None, self._origins, int4_arg(layout), np.int32(sx), np.int32(sy),
            np.int32(sz), np.int32(self.n_b), np.int32(self.n_h), weights[0], F_buf, y_buffer)

    def _apply_host(self, P, x_buf, y_buffer, device_group, group):
        """Charges and fields on host arrays kept between products; pruned scipy FFTs, in slabs.

        The charges are scattered into the first n_x planes of A (P, 8, p_x, n_y, n_z) and x
        transformed in place; then slab by slab of x frequencies the y and z transforms, the
        Fourier product and their inverses run on a slab array (P, 8, ·, p_y, p_z) and go back
        into A; the inverse x transform leaves the fields in A's first n_x planes, where the
        gather reads them. No array holds the whole padded spectrum (8P · p_x p_y p_z samples).
        A and the slab are kept (``_host_work``): fresh arrays of this size would be mapped and
        page-faulted in again every product (system time; ``release_work`` frees them)."""
        queue = self.ctx.queue
        weights, green, gradient, coef, cw = device_group
        defines = self._defines(P, cw, len(group.media))
        shape, padded, workers = self.grid.shape, self.grid.padded, self.workers
        work = self._host_work(P)
        A, A_buf, slab, slab_buf = work["A"], work["A_buf"], work["slab"], work["slab_buf"]
        layout = (padded[0], shape[1], shape[2])
        t0 = time.perf_counter()
        self._scatter(P, x_buf, A_buf, weights, defines, layout)
        _sync(queue, A_buf, A)
        A[:, :, shape[0]:] = 0  # after the read-back: a device copy of the buffer may hold old planes
        t1 = time.perf_counter()
        _fft_in_place(A, -3, workers)
        fft_s, fourier_s = time.perf_counter() - t1, 0.0
        plane = padded[1] * padded[2]
        planes = slab.shape[2]
        for x0 in range(0, padded[0], planes):
            ta = time.perf_counter()
            x1 = min(padded[0], x0 + planes)
            S = slab.reshape(-1)[: P * 8 * (x1 - x0) * plane].reshape((P, 8, x1 - x0) + tuple(padded[1:]))
            _pruned_plane_fft(S, A[:, :, x0:x1], workers)
            tb = time.perf_counter()
            _publish(queue, slab_buf, slab)
            self._fourier(slab_buf, green, gradient, coef, defines, samples=(x1 - x0) * plane, offset=x0 * plane)
            _sync(queue, slab_buf, slab)
            tc = time.perf_counter()
            _pruned_plane_fft(S, A[:, :, x0:x1], workers, inverse=True)
            fft_s += (tb - ta) + (time.perf_counter() - tc)
            fourier_s += tc - tb
        t3 = time.perf_counter()
        _fft_in_place(A, -3, workers, inverse=True)
        t4 = time.perf_counter()
        _publish(queue, A_buf, A)
        self._gather(A_buf, y_buffer, weights, defines, layout)
        queue.finish()
        t5 = time.perf_counter()
        self._record(t1 - t0, fft_s + (t4 - t3), fourier_s, t5 - t4)

    def _host_work(self, P: int) -> dict:
        """The host path's arrays and their OpenCL buffers, kept per batch size (one at a time):
        A (P, 8, p_x, n_y, n_z) and a slab (P, 8, slab_planes, p_y, p_z)."""
        if self._host.get("P") != P:
            import pyopencl as cl

            self._host = {}
            mf = cl.mem_flags
            shape, padded = self.grid.shape, self.grid.padded
            A = np.empty((P, 8, padded[0], shape[1], shape[2]), dtype=self.complex)
            slab = np.empty((P, 8, min(padded[0], self.slab_planes(P)), padded[1], padded[2]), dtype=self.complex)
            self._host = {"P": P, "A": A, "slab": slab,
                          "A_buf": cl.Buffer(self.ctx.context, mf.READ_WRITE | mf.USE_HOST_PTR, hostbuf=A),
                          "slab_buf": cl.Buffer(self.ctx.context, mf.READ_WRITE | mf.USE_HOST_PTR, hostbuf=slab)}
        return self._host

    def release_work(self) -> None:
        """Free the host arrays kept between products (after a solve: the far field needs the
        memory). The device path's VkFFT plan stays: it is built once per batch size."""
        self._host = {}

    def slab_planes(self, P: int) -> int:
        """x frequencies per slab of the host FFTs: about SLAB_BYTES of spectrum (P, 8, ·, p_y, p_z)."""
        plane = 8 * P * self.grid.padded[1] * self.grid.padded[2] * self.complex.itemsize
        return max(1, SLAB_BYTES // plane)

    def _apply_device(self, P, x_buf, y_buffer, device_group, group):
        """Charges and fields on zero-padded device arrays; VkFFT on the device (GPUs)."""
        queue = self.ctx.queue
        weights, green, gradient, coef, cw = device_group
        defines = self._defines(P, cw, len(group.media))
        Q, app = self._device_work(P)
        t0 = time.perf_counter()
        Q.fill(0)
        self._scatter(P, x_buf, Q.data, weights, defines, self.grid.padded)
        queue.finish()
        t1 = time.perf_counter()
        app.fft(Q)
        queue.finish()
        t2 = time.perf_counter()
        self._fourier(Q.data, green, gradient, coef, defines)
        queue.finish()
        t3 = time.perf_counter()
        app.ifft(Q)
        queue.finish()
        t4 = time.perf_counter()
        self._gather(Q.data, y_buffer, weights, defines, self.grid.padded)
        queue.finish()
        t5 = time.perf_counter()
        self._record(t1 - t0, (t2 - t1) + (t4 - t3), t3 - t2, t5 - t4)

    def _device_work(self, P: int):
        """Padded device array (8P transforms) and its VkFFT plan, kept per batch size."""
        if P not in self._vkfft:
            import pyopencl.array as cla
            from pyvkfft.opencl import VkFFTApp

            shape = (8 * P,) + tuple(self.grid.padded)
            Q = cla.zeros(self.ctx.queue, shape, self.complex)
            app = VkFFTApp(shape, self.complex, self.ctx.queue, ndim=3, inplace=True, norm=1)
            self._vkfft = {P: (Q, app)}  # one batch size at a time: the arrays are large
        return self._vkfft[P]

    def _record(self, scatter, fft, fourier, gather):
        self.timings["scatter_s"] += scatter
        self.timings["fft_s"] += fft
        self.timings["fourier_s"] += fourier
        self.timings["gather_s"] += gather

    def apply_numpy(self, x: np.ndarray) -> np.ndarray:
        """NumPy reference of :meth:`apply` (double precision, full FFTs)."""
        x = np.atleast_2d(x).astype(complex)
        if self._mats is None:
            self._mats = [projection_matrices(g.projection, self.n_h) for g in self.groups]
        y = np.zeros_like(x)
        padded = self.grid.padded
        for mats, group in zip(self._mats, self.groups):
            q = scatter_numpy(mats, x, self.n_b, self.grid.shape)
            Q = np.fft.fftn(q, s=padded, axes=(-3, -2, -1))
            F = np.fft.ifftn(fourier_numpy(group.green.astype(complex), group.gradient.astype(complex),
                                           group.coefficients, Q), axes=(-3, -2, -1))
            nx, ny, nz = self.grid.shape
            y += gather_numpy(mats, F[..., :nx, :ny, :nz])
        return y

    def bytes(self) -> int:
        """Device/host memory held by the operator (spectra, weights, maps)."""
        total = sum(g.green.nbytes + g.gradient.nbytes for g in self.groups)
        total += sum(2 * g.projection.weights.size * (self.real.itemsize * (2 if not g.projection.is_real else 1))
                     for g in self.groups)  # by basis and by grid point
        total += 4 * (self.grid.points + 1 + self.n_b * self.grid.stencil_size) + 12 * self.n_b
        return int(total)


def int4_arg(values):
    """An OpenCL int4 kernel argument from up to 4 integers (missing ones are 0)."""
    import pyopencl as cl

    return np.array(list(values) + [0] * (4 - len(values)), dtype=np.int32).view(cl.cltypes.int4)[0]


def _fft_in_place(a: np.ndarray, axis: int, workers: int, inverse: bool = False) -> None:
    """The (inverse) FFT of ``a`` along ``axis``, written into ``a`` (a view may be strided)."""
    out = (scipy.fft.ifft if inverse else scipy.fft.fft)(a, axis=axis, workers=workers, overwrite_x=True)
    if not np.may_share_memory(out, a):  # scipy chose a copy: move it back
        a[...] = out


def _pruned_plane_fft(S: np.ndarray, compact: np.ndarray, workers: int, inverse: bool = False) -> None:
    """The (y, z) transforms of a slab of x frequencies, pruned: forward, ``compact`` (…, n_y, n_z)
    zero-padded into ``S`` (…, p_y, p_z) and transformed there; inverse, ``S`` transformed back and
    its compact block written into ``compact``. The transform along the longer compact axis runs
    first (forward) or last (inverse), while the other axis holds its compact columns only: on a
    height field's grid (n_z ≪ n_y) that is n_z long y transforms instead of p_z ≈ 2 n_z of them,
    for p_y short z transforms instead of n_y (docs/aim.md, Performance: the FFT stage −15 % at
    10⁶ unknowns in double, −3 % in single)."""
    ny, nz = compact.shape[-2:]
    # the first transform (forward) runs on the compact columns of the other axis only
    first, second, pruned = (-2, -1, S[..., :nz]) if nz <= ny else (-1, -2, S[..., :ny, :])
    if not inverse:
        S[..., ny:, :] = 0
        S[..., :ny, nz:] = 0
        S[..., :ny, :nz] = compact
        _fft_in_place(pruned, first, workers)
        _fft_in_place(S, second, workers)
        return
    _fft_in_place(S, second, workers, inverse=True)
    _fft_in_place(pruned, first, workers, inverse=True)
    compact[...] = S[..., :ny, :nz]


def _publish(queue, buf, host: np.ndarray):
    """Make the device see the host's writes to a kept USE_HOST_PTR buffer (map for writing,
    discarding the device copy, + unmap). On CPU devices the buffer is the host array and this
    costs nothing; a GPU driver may hold a device copy that only an unmap refreshes."""
    import pyopencl as cl

    mapped, _ = cl.enqueue_map_buffer(queue, buf, cl.map_flags.WRITE_INVALIDATE_REGION, 0, host.shape, host.dtype)
    mapped.base.release(queue)


def _sync(queue, buf, host: np.ndarray):
    """Make the host array see the device writes to a USE_HOST_PTR buffer (map + unmap)."""
    import pyopencl as cl

    queue.finish()
    mapped, _ = cl.enqueue_map_buffer(queue, buf, cl.map_flags.READ, 0, host.shape, host.dtype)
    mapped.base.release(queue)
    queue.finish()
