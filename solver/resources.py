"""Machine resources: memory from /proc/meminfo and this process's peak memory."""

from __future__ import annotations

import os
import resource

__all__ = ["meminfo_bytes", "peak_memory_mb"]


def meminfo_bytes(field: str = "MemTotal") -> int:
    """A /proc/meminfo field in bytes ("MemTotal", "MemAvailable", ...); physical memory when the
    file or field is missing (non-Linux)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith(f"{field}:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))


def peak_memory_mb() -> float:
    """Peak resident memory of this process (MB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
