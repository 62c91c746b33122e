"""Where a long solve spends its time and memory: :class:`StageClock`.

Each stage (``with clock("near field"): ...``) records its wall seconds, the process's user and
system CPU seconds, the resident memory after it and its own peak (VmHWM reset at the stage's
start, solver/resources.py), so a run's diagnostics and ``bench_aim.py`` print one breakdown per
stage. A stage entered again (one per incident direction) accumulates its times and keeps the
largest memory figures. Memory is in MB (2²⁰ bytes), NaN where /proc is missing.
"""

from __future__ import annotations

import math
import os
import time
from contextlib import contextmanager

from wavebrdf.solver.resources import resident_memory_mb, restart_stage_peak, stage_peak_bytes

__all__ = ["StageClock", "format_stages"]

_open_peaks: list[list[float]] = []  # running peak (bytes) of every open stage, outermost first


def _larger(a: float, b: float) -> float:
    """max(a, b), NaN if either is NaN (a figure that could not be measured stays unknown)."""
    return math.nan if a != a or b != b else max(a, b)


class StageClock:
    """Ordered per-stage figures: ``stages[name]`` = {wall_s, user_s, system_s, calls, rss_mb
    (after), peak_mb (during), grew_mb (resident after − before)}."""

    def __init__(self):
        self.stages: dict[str, dict] = {}

    @contextmanager
    def __call__(self, name: str):
        so_far = stage_peak_bytes()
        for running in _open_peaks:
            running[0] = max(running[0], so_far)
        before = restart_stage_peak() / 2**20
        running = [0.0]
        _open_peaks.append(running)
        cpu0, t0 = os.times(), time.perf_counter()
        try:
            yield
        finally:
            cpu1, t1 = os.times(), time.perf_counter()
            _open_peaks.remove(running)
            raw = stage_peak_bytes()
            peak = max(running[0], raw) / 2**20 if raw == raw else math.nan  # NaN where /proc is missing
            after = resident_memory_mb() if raw == raw else math.nan
            entry = self.stages.setdefault(name, {"wall_s": 0.0, "user_s": 0.0, "system_s": 0.0, "calls": 0,
                                                  "rss_mb": 0.0, "peak_mb": 0.0, "grew_mb": 0.0})
            entry["wall_s"] += t1 - t0
            entry["user_s"] += cpu1.user - cpu0.user
            entry["system_s"] += cpu1.system - cpu0.system
            entry["calls"] += 1
            entry["rss_mb"] = _larger(entry["rss_mb"], after)
            entry["peak_mb"] = _larger(entry["peak_mb"], peak)
            entry["grew_mb"] = _larger(entry["grew_mb"], after - before)

    def merge(self, other: "StageClock | dict") -> None:
        """Add another clock's stages (a sub-solver's) under their names."""
        stages = other.stages if isinstance(other, StageClock) else other
        for name, figures in stages.items():
            mine = self.stages.setdefault(name, {k: 0.0 for k in figures})
            for key, value in figures.items():
                if key in ("rss_mb", "peak_mb", "grew_mb"):
                    mine[key] = max(mine[key], value)
                else:
                    mine[key] = mine[key] + value

    def as_dict(self) -> dict:
        return {name: dict(figures) for name, figures in self.stages.items()}


def format_stages(stages: dict) -> str:
    """A fixed-width table of a StageClock's ``as_dict()`` (for logs and benchmarks)."""
    lines = [f"{'stage':<22}{'wall s':>9}{'user s':>9}{'sys s':>8}{'RSS MB':>9}{'peak MB':>9}{'grew MB':>9}"]
    for name, f in stages.items():
        lines.append(f"{name:<22}{f['wall_s']:>9.1f}{f['user_s']:>9.1f}{f['system_s']:>8.1f}{f['rss_mb']:>9.0f}"
                     f"{f['peak_mb']:>9.0f}{f['grew_mb']:>9.0f}")
    return "\n".join(lines)
