"""Timing helpers shared by the benchmark scripts (imported as a sibling module)."""

from __future__ import annotations

import time


def best_of(repeat: int, fn):
    """(best wall time over ``repeat`` calls, the last result)."""
    times, result = [], None
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t0)
    return min(times), result
