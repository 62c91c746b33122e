"""OpenCL runtime: device choice, fp64 check, program builds with a complete cache key.

Nothing here runs at import. Callers create a :class:`ComputeContext` once and pass it to every
numerical routine (``ctx`` is always an explicit argument, never a module global).

Device choice (:func:`create_context`): an explicit ``spec`` argument, else the environment
variable ``WAVEBRDF_DEVICE``, else ``auto``:

``auto``
    the first GPU with double precision, else the first PoCL CPU device, else any CPU device.
``gpu`` / ``cpu`` / ``pocl``
    the first device of that kind.
``P:D``
    device D of platform P (indices as printed by ``wavebrdf devices``).
any other text
    the first device whose "platform / device" name contains it (case-insensitive).
"""

from __future__ import annotations

import logging
import os
import time
import warnings
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from wavebrdf.kernels import load_source, source_hash
from wavebrdf.solver.kernel_cache import LockedKernel, build_lock
from wavebrdf.solver.precision import Precision
from wavebrdf.solver.progress import silent

logger = logging.getLogger(__name__)

__all__ = [
    "ComputeContext",
    "DeviceInfo",
    "OpenCLUnavailable",
    "create_context",
    "fft_workers",
    "list_devices",
]

FFT_WORKERS_ENV = "WAVEBRDF_FFT_WORKERS"  # the batch layer sets it per worker (jobs/scheduler.py)


def fft_workers() -> int:
    """Threads for host FFTs (scipy.fft): ``WAVEBRDF_FFT_WORKERS`` when set (the batch layer caps
    each worker with it), else the CPUs this process may run on."""
    value = os.environ.get(FFT_WORKERS_ENV, "").strip()
    if value:
        try:
            workers = int(value)
        except ValueError:
            raise ValueError(f"{FFT_WORKERS_ENV}={value!r}: must be an integer >= 1") from None
        if workers < 1:
            raise ValueError(f"{FFT_WORKERS_ENV}={value!r}: must be an integer >= 1")
        return workers
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - non-Linux
        return max(1, os.cpu_count() or 1)

INSTALL_HINT = (
    "Install a CPU OpenCL runtime: 'sudo apt-get install pocl-opencl-icd' (Debian/Ubuntu), or "
    "without root 'pip install \"wavebrdf[pocl]\"' (PoCL wheel). For a GPU install the vendor "
    "driver, which registers an ICD file in /etc/OpenCL/vendors (or point OCL_ICD_VENDORS at "
    "a folder holding one). 'wavebrdf devices' lists what is visible."
)


class OpenCLUnavailable(RuntimeError):
    """No usable OpenCL platform/device; the message names the fix."""


@dataclass(frozen=True)
class DeviceInfo:
    """One OpenCL device as listed by ``wavebrdf devices``."""

    platform_index: int
    device_index: int
    platform: str
    platform_version: str
    name: str
    kind: str  # "GPU", "CPU", "ACCELERATOR", ...
    fp64: bool
    compute_units: int
    global_mem_gib: float
    max_alloc_gib: float
    unified_memory: bool = False  # CL_DEVICE_HOST_UNIFIED_MEMORY: CPUs and integrated GPUs
    max_work_group_size: int = 256

    @property
    def spec(self) -> str:
        return f"{self.platform_index}:{self.device_index}"

    @property
    def is_pocl(self) -> bool:
        return "portable computing language" in self.platform.lower() or "pocl" in (
            self.platform_version.lower()
        )


def _import_cl():
    try:
        import pyopencl as cl
    except ImportError as exc:  # pragma: no cover - pyopencl is a hard dependency
        raise OpenCLUnavailable(f"pyopencl is not importable ({exc}). {INSTALL_HINT}") from exc
    return cl


def _platforms():
    cl = _import_cl()
    try:
        platforms = cl.get_platforms()
    except (cl.LogicError, cl.RuntimeError) as exc:
        raise OpenCLUnavailable(f"No OpenCL platform found ({exc}). {INSTALL_HINT}") from exc
    if not platforms:
        raise OpenCLUnavailable(f"No OpenCL platform found. {INSTALL_HINT}")
    return platforms


def _describe(pi: int, di: int, platform, device) -> DeviceInfo:
    cl = _import_cl()
    kinds = [
        name
        for name, flag in (
            ("GPU", cl.device_type.GPU),
            ("CPU", cl.device_type.CPU),
            ("ACCELERATOR", cl.device_type.ACCELERATOR),
        )
        if device.type & flag
    ]
    return DeviceInfo(
        platform_index=pi,
        device_index=di,
        platform=platform.name.strip(),
        platform_version=platform.version.strip(),
        name=device.name.strip(),
        kind="/".join(kinds) or "OTHER",
        fp64="cl_khr_fp64" in device.extensions or device.double_fp_config != 0,
        compute_units=int(device.max_compute_units),
        global_mem_gib=device.global_mem_size / 2**30,
        max_alloc_gib=device.max_mem_alloc_size / 2**30,
        unified_memory=_unified_memory(device, kinds),
        max_work_group_size=int(device.max_work_group_size),
    )


def _unified_memory(device, kinds: list[str]) -> bool:
    """Whether the device works in host memory (CL_DEVICE_HOST_UNIFIED_MEMORY; its kind where a
    runtime does not answer the deprecated query)."""
    try:
        return bool(device.host_unified_memory)
    except Exception:
        return "CPU" in kinds


def list_devices() -> list[DeviceInfo]:
    """All OpenCL devices of all platforms (raises :class:`OpenCLUnavailable` if none)."""
    out = []
    for pi, platform in enumerate(_platforms()):
        try:
            devices = platform.get_devices()
        except Exception as exc:  # a broken ICD must not hide the others
            logger.warning("platform %s: cannot list devices (%s)", platform.name, exc)
            continue
        out.extend(_describe(pi, di, platform, d) for di, d in enumerate(devices))
    if not out:
        raise OpenCLUnavailable(f"OpenCL platforms exist but expose no device. {INSTALL_HINT}")
    return out


def choose_device(spec: str, infos: list[DeviceInfo], local_rank: int = 0) -> DeviceInfo:
    """The device ``spec`` names (module docstring). With several GPUs matching "auto" or "gpu",
    the process of local rank r on its node takes GPU r mod (number of GPUs): one GPU per rank."""
    spec_l = spec.strip().lower()
    listing = "; ".join(f"{i.spec} {i.platform} / {i.name} ({i.kind})" for i in infos)
    if spec_l in ("", "auto"):
        for pick in (
            lambda i: "GPU" in i.kind and i.fp64,
            lambda i: i.is_pocl and "CPU" in i.kind,
            lambda i: "CPU" in i.kind,
            lambda i: True,
        ):
            found = [i for i in infos if pick(i)]
            if found:
                return found[local_rank % len(found)] if "GPU" in found[0].kind else found[0]
    if spec_l in ("gpu", "cpu"):
        found = [i for i in infos if spec_l.upper() in i.kind]
        if spec_l == "gpu" and found:
            return found[local_rank % len(found)]
    elif spec_l == "pocl":
        found = [i for i in infos if i.is_pocl]
    elif ":" in spec_l and all(p.strip().isdigit() for p in spec_l.split(":", 1)):
        p, d = (int(x) for x in spec_l.split(":", 1))
        found = [i for i in infos if (i.platform_index, i.device_index) == (p, d)]
    else:
        found = [i for i in infos if spec_l in f"{i.platform} / {i.name}".lower()]
    if not found:
        raise OpenCLUnavailable(
            f"WAVEBRDF_DEVICE={spec!r} matches no OpenCL device. Available: {listing}. "
            "Use auto, gpu, cpu, pocl, P:D or part of a device name."
        )
    return found[0]


@dataclass
class ComputeContext:
    """An OpenCL context + in-order queue on one device, with a program cache.

    Programs are built from ``kernels/<file>`` with ``-D`` defines. The build key is
    (source hash with headers inlined, defines, device); the source hash also enters the
    options as ``-D WB_SOURCE_HASH=...`` so driver-side caches (PoCL, NVIDIA) see the complete key.
    """

    context: Any
    queue: Any
    info: DeviceInfo
    _programs: dict = field(default_factory=dict, repr=False)
    _kernels: dict = field(default_factory=dict, repr=False)
    build_seconds: float = 0.0  # program builds + kernels' first launches (PoCL compiles then), cache hits included
    progress: Any = field(default=silent, repr=False)  # progress(stage, fraction, **figures): solver/progress.py

    @property
    def device(self):
        return self.queue.device

    @property
    def fp64(self) -> bool:
        return self.info.fp64

    def describe(self) -> str:
        return f"{self.info.platform} / {self.info.name} ({self.info.kind})"

    @property
    def is_gpu(self) -> bool:
        return "GPU" in self.info.kind

    @property
    def fft_workers(self) -> int:
        """Threads for this process's host FFTs (:func:`fft_workers`)."""
        return fft_workers()

    def vector_lanes(self, precision: Precision = Precision.DOUBLE) -> int:
        """Items per work-item (``WB_VW``): 256-bit SIMD vectors on CPUs (4 doubles, 8 floats), 1 on
        GPUs, where work-items are the lanes."""
        if self.is_gpu:
            return 1
        return 4 if precision.fp64 else 8

    def defines(self, precision: Precision = Precision.DOUBLE, *, lanes: int | None = None, **extra) -> dict:
        """Kernel build defines for ``precision`` (``WB_FP64``) and, when ``lanes`` is given,
        ``WB_VW``; ``extra`` are added as they are."""
        out = {"WB_FP64": int(precision.fp64)}
        if lanes is not None:
            out["WB_VW"] = int(lanes)
        out.update(extra)
        return out

    def to_device(self, array: np.ndarray, dtype=None, *, writable: bool = False):
        """A device buffer holding a copy of ``array`` (converted to ``dtype`` if given)."""
        cl = _import_cl()
        host = np.ascontiguousarray(array, dtype=dtype)
        flags = (cl.mem_flags.READ_WRITE if writable else cl.mem_flags.READ_ONLY) | cl.mem_flags.COPY_HOST_PTR
        return cl.Buffer(self.context, flags, hostbuf=host)

    @property
    def shares_host_memory(self) -> bool:
        """True where buffers can live in host memory at no cost (USE_HOST_PTR): devices on the
        host's memory (CPUs, integrated GPUs), not discrete GPUs."""
        return self.info.unified_memory

    def work_group(self, size: int) -> int:
        """``size`` work-items per group, or fewer where the device allows fewer."""
        return max(1, min(int(size), self.info.max_work_group_size))

    def host_buffer(self, array: np.ndarray, access: str = "read"):
        """A buffer over the host ``array`` (C-contiguous, non-empty) for ``access`` "read" |
        "write" | "read_write" by kernels: the array's own memory on CPU devices (no copy, no
        fresh pages; the array must outlive the buffer), a copy ("read"), an empty buffer
        ("write") or both elsewhere; a non-contiguous array is copied for "read". Kernel writes
        reach the array through :meth:`read_into`."""
        cl = _import_cl()
        flags = {"read": cl.mem_flags.READ_ONLY, "write": cl.mem_flags.WRITE_ONLY,
                 "read_write": cl.mem_flags.READ_WRITE}
        if access not in flags:
            raise ValueError(f"access must be one of {tuple(flags)}, got {access!r}")
        if not array.flags.c_contiguous:
            if access == "read":  # nothing to share: a contiguous copy
                return self.to_device(array)
            raise ValueError(f"host_buffer for {access!r} needs a C-contiguous array, got strides {array.strides}")
        if array.nbytes == 0:
            raise ValueError(f"host_buffer needs a non-empty array, got shape {array.shape}")
        if self.shares_host_memory:
            return cl.Buffer(self.context, flags[access] | cl.mem_flags.USE_HOST_PTR, hostbuf=array)
        if access == "write":
            return cl.Buffer(self.context, flags[access], array.nbytes)
        return cl.Buffer(self.context, flags[access] | cl.mem_flags.COPY_HOST_PTR, hostbuf=array)

    def read_into(self, array: np.ndarray, buffer) -> None:
        """Make ``array`` hold ``buffer``'s content once the queued kernels are done: a map and
        unmap of a :meth:`host_buffer` over ``array`` on CPU devices (no copy where the runtime
        uses the host memory itself), a copy otherwise."""
        cl = _import_cl()
        over_array = (buffer.flags & cl.mem_flags.USE_HOST_PTR
                      and buffer.get_host_array(array.shape, array.dtype).ctypes.data == array.ctypes.data)
        if over_array:  # host_buffer(array) on a CPU device
            mapped, _ = cl.enqueue_map_buffer(self.queue, buffer, cl.map_flags.READ, 0, array.shape, array.dtype)
            mapped.base.release(self.queue)
            self.queue.finish()
            return
        cl.enqueue_copy(self.queue, array, buffer)

    def program(self, source: str, defines: Mapping[str, Any] | None = None):
        """Build (once) and return the program of ``kernels/<source>`` with ``defines``; a
        double-precision build (``WB_FP64`` = 1) on a device without cl_khr_fp64 is refused."""
        cl = _import_cl()
        text = load_source(source)
        digest = source_hash(text)
        items = tuple(sorted((str(k), str(v)) for k, v in (defines or {}).items()))
        key = (source, digest, items)
        prog = self._programs.get(key)
        if prog is None:
            if ("WB_FP64", "1") in items and not self.fp64:
                raise OpenCLUnavailable(
                    f"device {self.describe()} has no double precision (cl_khr_fp64), which these kernels "
                    "need (every model at [model] precision = \"double\"; the full-wave BEM's assembly at "
                    "any precision): choose another device with WAVEBRDF_DEVICE ('wavebrdf devices' lists "
                    "fp64), or precision = \"single\" for the approximate models"
                )
            options = [f"-DWB_SOURCE_HASH={digest}"] + [f"-D{k}={v}" for k, v in items]
            t0 = time.perf_counter()
            with warnings.catch_warnings(), build_lock(digest, " ".join(options), self.describe()):
                warnings.simplefilter("ignore", cl.CompilerWarning)
                try:
                    prog = cl.Program(self.context, text).build(options=options)
                except cl.RuntimeError as exc:
                    raise RuntimeError(
                        f"OpenCL build of kernels/{source} failed on {self.describe()} "
                        f"with options {options}:\n{exc}"
                    ) from exc
            self.build_seconds += time.perf_counter() - t0
            self._programs[key] = prog
        return prog

    def _account_build(self, seconds: float) -> None:
        self.build_seconds += seconds

    def kernel(self, source: str, name: str, defines: Mapping[str, Any] | None = None):
        """Return kernel ``name`` of ``kernels/<source>`` (one Kernel object per key)."""
        cl = _import_cl()
        prog = self.program(source, defines)
        key = (id(prog), name)
        knl = self._kernels.get(key)
        if knl is None:
            build = sorted((str(k), str(v)) for k, v in (defines or {}).items())
            knl = LockedKernel(cl.Kernel(prog, name), f"{source_hash(load_source(source))}:{name}:{build}:"
                               f"{self.describe()}", account=self._account_build)
            self._kernels[key] = knl
        return knl


def create_context(spec: str | None = None, *, require_fp64: bool = True, local_rank: int = 0) -> ComputeContext:
    """Create a :class:`ComputeContext` on the device chosen by ``spec`` / ``WAVEBRDF_DEVICE``
    (``local_rank``: this process's rank on its node, which picks its GPU, :func:`choose_device`)."""
    cl = _import_cl()
    if spec is None:
        spec = os.environ.get("WAVEBRDF_DEVICE", "auto")
    infos = list_devices()
    info = choose_device(spec, infos, local_rank)
    if require_fp64 and not info.fp64:
        raise OpenCLUnavailable(
            f"device {info.platform} / {info.name} has no double precision (cl_khr_fp64). "
            "Pick another with WAVEBRDF_DEVICE (see 'wavebrdf devices'), or run at "
            "[model] precision = \"single\"."
        )
    device = cl.get_platforms()[info.platform_index].get_devices()[info.device_index]
    context = cl.Context([device])
    queue = cl.CommandQueue(context)
    logger.info("OpenCL device: %s / %s", info.platform, info.name)
    return ComputeContext(context=context, queue=queue, info=info)
