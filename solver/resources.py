"""Machine resources: memory from /proc/meminfo, this process's peak memory, its BLAS threads and
numpy's huge-page advice."""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import os
import resource

__all__ = ["huge_page_advice", "meminfo_bytes", "one_blas_thread", "peak_memory_mb", "peak_resident_bytes", "release_free_memory",
           "reset_peak_memory", "resident_memory_mb", "restart_stage_peak", "stage_peak_bytes"]

# Peaks (bytes) that stage clocks (solver/stages.py) carried over their resets of VmHWM: since the
# last reset_peak_memory (a measurement's baseline) and over the process's life (ru_maxrss, which
# the same kernel counter feeds, is lowered by those resets).
_carried = {"since_reset": 0.0, "lifetime": 0.0}


def _proc_kb(path: str, field: str) -> int | None:
    """The kB value of ``field`` in a /proc status-style file, None when the file or field is missing."""
    try:
        with open(path) as fh:
            for line in fh:
                if line.startswith(f"{field}:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return None


def meminfo_bytes(field: str = "MemTotal") -> int:
    """A /proc/meminfo field in bytes ("MemTotal", "MemAvailable", ...); physical memory when the
    file or field is missing (non-Linux)."""
    kb = _proc_kb("/proc/meminfo", field)
    if kb is not None:
        return kb * 1024
    return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))


def peak_memory_mb() -> float:
    """Peak resident memory of this process over its life (MB), stage resets included."""
    return max(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, _carried["lifetime"] / 2**20)


def resident_memory_mb() -> float:
    """Current resident memory of this process (MB; VmRSS), 0 where /proc is missing."""
    kb = _proc_kb("/proc/self/status", "VmRSS")
    return 0.0 if kb is None else kb / 1024.0


def release_free_memory() -> None:
    """Return the C heap's free pages to the system (glibc malloc_trim; a no-op elsewhere).

    Large sparse factorizations (SuperLU) free gigabytes of working memory that glibc would
    otherwise keep resident for the rest of the run.
    """
    name = ctypes.util.find_library("c")
    try:
        trim = getattr(ctypes.CDLL(name), "malloc_trim")
    except (OSError, AttributeError, TypeError):
        return
    trim(0)


def stage_peak_bytes() -> float:
    """Peak resident memory (bytes; VmHWM) since the last reset of either kind, NaN where /proc is missing."""
    kb = _proc_kb("/proc/self/status", "VmHWM")
    return float("nan") if kb is None else kb * 1024.0


def peak_resident_bytes() -> float:
    """Peak resident memory of this process since start or the last :func:`reset_peak_memory`
    (bytes; VmHWM and what stage clocks carried over their resets), NaN where /proc is missing."""
    return max(stage_peak_bytes(), _carried["since_reset"])


def _clear_peak() -> bool:
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        return False
    return True


def restart_stage_peak() -> float:
    """Start a stage's peak: carry the peak so far over, reset VmHWM to the current RSS (without
    giving heap pages back: that would change what is measured) and return the RSS in bytes;
    NaN where the kernel does not allow it. :func:`peak_resident_bytes` and
    :func:`peak_memory_mb` still see the carried peak."""
    peak = stage_peak_bytes()
    if peak == peak:  # not NaN
        _carried["since_reset"] = max(_carried["since_reset"], peak)
        _carried["lifetime"] = max(_carried["lifetime"], peak)
    if not _clear_peak():
        return float("nan")
    return stage_peak_bytes()


def reset_peak_memory() -> float:
    """Give the C heap's free pages back, reset this process's peak RSS to its current RSS (Linux
    ``clear_refs`` 5) and return that baseline in bytes; NaN where the kernel does not allow it."""
    release_free_memory()
    peak = stage_peak_bytes()
    if peak == peak:
        _carried["lifetime"] = max(_carried["lifetime"], peak)
    _carried["since_reset"] = 0.0
    if not _clear_peak():
        return float("nan")
    return peak_resident_bytes()


_blas_controller = None


@contextlib.contextmanager
def one_blas_thread():
    """Run the block with every loaded BLAS (numpy's and scipy's OpenBLAS) on one thread.

    For code that makes many small BLAS calls, such as SuperLU's supernodal factorization and
    triangular solves: OpenBLAS's threads spin-wait between calls, which on a loaded 2-core node
    cost 70x the CPU time of the factorization itself (measured: a 16 128-unknown near-field LU
    took 30 CPU-s with 2 BLAS threads while another job ran, 0.43 CPU-s with one). The limit is
    lifted on exit; entering costs ~30 µs."""
    global _blas_controller
    from threadpoolctl import ThreadpoolController

    if _blas_controller is None:  # after scipy has loaded its own OpenBLAS (the callers import it first)
        _blas_controller = ThreadpoolController()
    with _blas_controller.limit(limits=1, user_api="blas"):
        yield


def huge_page_advice(enabled: bool | None = None) -> bool | None:
    """Set whether numpy advises the kernel to back its large arrays with transparent huge pages
    (``madvise(MADV_HUGEPAGE)``); returns the previous setting (None where this numpy has no
    such switch: nothing is changed).

    ``enabled`` None: off unless the user set ``NUMPY_MADVISE_HUGEPAGE`` (numpy's own switch,
    then left as it chose). Off by default because with the common ``defrag = madvise`` setting
    every first touch of an advised page may compact memory synchronously: on the reference
    virtual machines (ENVIRONMENT.md) filling a fresh 360 MB array took 3–5.5 s with the advice
    (nearly all system time) and 0.25 s without, and the AIM near-field set-up of 101 760
    unknowns dropped from 170 s to 107 s wall (system 61 → 19 s) with AIM products unchanged
    (0.203 vs 0.212 s)."""
    try:
        from numpy._core.multiarray import _set_madvise_hugepage
    except ImportError:  # numpy < 2
        try:
            from numpy.core.multiarray import _set_madvise_hugepage
        except ImportError:
            return None
    if enabled is None:
        if "NUMPY_MADVISE_HUGEPAGE" in os.environ:
            return _set_madvise_hugepage(os.environ["NUMPY_MADVISE_HUGEPAGE"] not in ("", "0"))
        enabled = False
    return _set_madvise_hugepage(bool(enabled))
