"""Machine resources: memory from /proc/meminfo and this process's peak memory."""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import resource

__all__ = ["meminfo_bytes", "peak_memory_mb", "peak_resident_bytes", "release_free_memory", "reset_peak_memory",
           "resident_memory_mb"]


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
    """Peak resident memory of this process (MB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


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


def peak_resident_bytes() -> float:
    """Peak resident memory of this process since start or the last :func:`reset_peak_memory`
    (bytes; VmHWM), NaN where /proc is missing."""
    kb = _proc_kb("/proc/self/status", "VmHWM")
    return float("nan") if kb is None else kb * 1024.0


def reset_peak_memory() -> float:
    """Give the C heap's free pages back, reset this process's peak RSS to its current RSS (Linux
    ``clear_refs`` 5) and return that baseline in bytes; NaN where the kernel does not allow it."""
    release_free_memory()
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        return float("nan")
    return peak_resident_bytes()
