"""Machine resources: memory from /proc/meminfo, this process's peak memory, its BLAS threads and
numpy's huge-page advice."""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import logging
import os
import resource

logger = logging.getLogger(__name__)

__all__ = ["HUGE_PAGE_PROBE", "huge_page_advice", "huge_pages_pay", "meminfo_bytes", "one_blas_thread", "peak_memory_mb", "peak_resident_bytes", "release_free_memory",
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


HUGE_PAGE_PROBE_BYTES = 16 * 2**20  # fresh memory first-touched with and without the advice
THP_SETTINGS = "/sys/kernel/mm/transparent_hugepage"
HUGE_PAGE_PROBE: dict = {}  # the last huge_pages_pay measurement: advised_s, plain_s, pays


def _first_touch_seconds(nbytes: int, advise: bool) -> float:
    """Seconds to write one byte into every 4 KiB page of a fresh anonymous mapping of ``nbytes``,
    advised ``MADV_HUGEPAGE`` or not (the mapping is released after)."""
    import mmap
    import time

    import numpy as np

    buf = mmap.mmap(-1, nbytes, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS)
    try:
        if advise:
            buf.madvise(mmap.MADV_HUGEPAGE)
        pages = np.frombuffer(buf, dtype=np.uint8)
        start = time.perf_counter()
        pages[::4096] = 1
        elapsed = time.perf_counter() - start
        del pages
        return elapsed
    finally:
        buf.close()


def huge_pages_pay() -> bool:
    """Whether advised huge pages fill faster here than 4 KiB pages, measured now: True where the
    kernel honours ``MADV_HUGEPAGE`` and a fresh advised mapping of HUGE_PAGE_PROBE_BYTES is
    first-touched in no more time than an unadvised one (best of two each, ~30 ms with the
    mappings); False where transparent huge pages are off or advised faults stall on compaction
    (virtual machines that hand free memory back to their host: seconds per GiB, docs/aim.md).
    The timings and the answer are kept in :data:`HUGE_PAGE_PROBE` and logged."""
    try:
        with open(f"{THP_SETTINGS}/enabled") as fh:
            mode = fh.read()
    except OSError:
        return False
    if "[never]" in mode:
        return False
    try:
        advised = min(_first_touch_seconds(HUGE_PAGE_PROBE_BYTES, True) for _ in range(2))
        plain = min(_first_touch_seconds(HUGE_PAGE_PROBE_BYTES, False) for _ in range(2))
    except (OSError, ValueError, AttributeError):  # no MADV_HUGEPAGE on this platform
        return False
    pays = advised <= plain
    HUGE_PAGE_PROBE.update(advised_s=advised, plain_s=plain, pays=pays)
    logger.info("huge pages: advised first touch of %d MiB %.2f ms, plain %.2f ms: advice %s",
                HUGE_PAGE_PROBE_BYTES // 2**20, 1e3 * advised, 1e3 * plain, "on" if pays else "off")
    return pays


def huge_page_advice(enabled: bool | None = None) -> bool | None:
    """Set whether numpy advises the kernel to back its large arrays with transparent huge pages
    (``madvise(MADV_HUGEPAGE)``); returns the previous setting (None where this numpy has no
    such switch: nothing is changed).

    ``enabled`` None: as the user set ``NUMPY_MADVISE_HUGEPAGE`` (numpy's own switch), else as
    :func:`huge_pages_pay` measures. Where advised first touches compact memory synchronously
    (``defrag = madvise`` on a VM returning free pages to its host) filling a fresh 360 MB array
    took 3–5.5 s with the advice and 0.25 s without, and the AIM near-field set-up of 101 760
    unknowns 170 s against 107 s; where huge pages are at hand they spare the page faults of the
    far field's and the beam's large temporaries (146 688 unknowns, 1024² output: 17.1 → 9.2 s,
    system time 14.3 → 3.5 s; docs/aim.md)."""
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
        enabled = huge_pages_pay()
    return _set_madvise_hugepage(bool(enabled))
