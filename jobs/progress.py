"""What a run shows while it works: the progress bar on a terminal, timestamped lines in logs.

- **Terminal** (stderr is a TTY): a progress bar with ETA; one line per finished task printed
  above it; the running task's stage (solver/progress.py) in the bar's postfix; log records are
  printed above the bar, never onto it. ``--quiet`` hides the bar and the task lines.
- **Log file** (stderr is not a TTY, e.g. ``2>log`` or a batch system): no bar and no ``\\r``;
  one timestamped line per finished task (λ, θ_i, φ_i, patch, model, wall time, peak memory,
  iterations), kept under ``--quiet``; a progress/ETA line every :data:`HEARTBEAT_S` seconds
  when no task finished meanwhile; inside a long task (after :data:`STAGE_QUIET_S` s) a line
  per stage change and at most one every :data:`STAGE_INTERVAL_S` s with the stage, elapsed
  time, the plan's estimate for the task, memory and the Krylov products/residual.

``-v``/``-q`` are accepted before and after the subcommand (:func:`add_verbosity_flags`).
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import threading
import time
from datetime import datetime

import numpy as np

from wavebrdf.solver.resources import peak_memory_mb, resident_memory_mb

__all__ = ["RunLog", "StageReporter", "add_verbosity_flags", "configure_logging", "emit", "task_where"]

HEARTBEAT_S = float(os.environ.get("WAVEBRDF_HEARTBEAT_S", 300))  # logs: progress line when nothing else
STAGE_QUIET_S = 10.0  # logs: no stage lines in a task's first seconds (most tasks are short)
STAGE_INTERVAL_S = float(os.environ.get("WAVEBRDF_STAGE_INTERVAL_S", 60))  # logs: stage line period
TIME_FORMAT = "%Y-%m-%d %H:%M:%S"

_BAR = None  # the tqdm bar being shown in this process (log lines are printed above it)
_WRITE_LOCK = threading.Lock()


def stamp() -> str:
    return datetime.now().strftime(TIME_FORMAT)


def emit(text: str) -> None:
    """One timestamped line on stderr, above the progress bar if one is shown."""
    line = f"{stamp()} {text}"
    with _WRITE_LOCK:
        if _BAR is not None:
            _BAR.write(line, file=sys.stderr)
        else:
            print(line, file=sys.stderr, flush=True)


class _Handler(logging.Handler):
    def emit(self, record: logging.LogRecord) -> None:
        try:
            emit(self.format(record))
        except Exception:  # noqa: BLE001 - logging must never break the run
            self.handleError(record)


def configure_logging(verbose: bool) -> None:
    """Timestamped log records on stderr (INFO with ``-v``, else WARNING), printed above any bar."""
    handler = _Handler()
    handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    for old in [h for h in root.handlers if isinstance(h, _Handler)]:
        root.removeHandler(old)
    root.addHandler(handler)
    root.setLevel(logging.INFO if verbose else logging.WARNING)


def add_verbosity_flags(parser: argparse.ArgumentParser, subcommands: argparse._SubParsersAction) -> None:
    """``-v/--verbose`` and ``-q/--quiet`` on ``parser`` and on every subcommand, so either place
    works (a subcommand's flag only sets the value when given)."""
    flags = (("-v", "--verbose", "log more (every record at level INFO)"),
             ("-q", "--quiet", "no progress bar on a terminal (logs keep one line per task)"))
    for short, long, text in flags:
        if long not in parser._option_string_actions:
            parser.add_argument(short, long, action="store_true", help=text)
    for sub in subcommands.choices.values():
        for short, long, text in flags:
            names = [n for n in (short, long) if n not in sub._option_string_actions]
            if len(names) == 2:
                sub.add_argument(*names, action="store_true", default=argparse.SUPPRESS, help=text)
        for action in sub._actions:  # a subcommand's own -q/--quiet must not reset a -q given before it
            if action.dest in ("verbose", "quiet"):
                action.default = argparse.SUPPRESS


def _is_tty() -> bool:
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False


def task_where(plan, task) -> str:
    """λ, θ_i, φ_i and patch of ``task`` (fiber tasks solve every φ_i: their count)."""
    theta, phi = np.rad2deg(plan.direction_rad(task))
    lam = plan.wavelengths_um[task.wavelength]
    text = f"λ {lam:.4g} µm, θ_i {degrees_text(theta, 1)}°, φ_i {phi_text(plan, task)}"
    if task.patch:
        text += f", patch {'x'.join(map(str, task.patch))}"
    return text


def degrees_text(value: float, decimals: int) -> str:
    """``value`` (degrees) with ``decimals`` decimals, or more (up to 6) where fewer would round it
    by more than 10⁻⁶° — 89.9999° is not 90.0°."""
    for places in range(decimals, max(decimals, 6) + 1):
        text = f"{value:.{places}f}"
        if abs(float(text) - value) <= 1e-6:
            break
    return text


def phi_text(plan, task) -> str:
    """φ_i of ``task`` in degrees, as its study kind says it (fiber tasks: every φ_i of the table,
    "all 36", or the one value)."""
    return plan.study.kind.phi_text(plan, task)


def _duration(seconds: float) -> str:
    seconds = max(0, int(round(seconds)))
    h, rest = divmod(seconds, 3600)
    return f"{h}:{rest // 60:02d}:{rest % 60:02d}" if h else f"{rest // 60}:{rest % 60:02d}"


def _figures(diagnostics: dict) -> str:
    text = ""
    for key in ("iterations", "residual"):
        value = diagnostics.get(key)
        if value is None:
            continue
        if isinstance(value, list):
            value = max(value) if value else None
        if value is not None:
            text += f", {key} {value:.3g}" if isinstance(value, float) else f", {key} {value}"
    return text


class StageReporter:
    """``ctx.progress`` during one task (solver/progress.py): the stage in the bar's postfix
    (``bar``), or timestamped lines at a bounded rate (``lines``)."""

    def __init__(self, plan, task, *, bar=None, lines: bool = True, prefix: str = ""):
        self.plan, self.task, self.bar, self.lines, self.prefix = plan, task, bar, lines, prefix
        self.started = time.monotonic()
        self.stage = None
        self._last_line = -float("inf")
        self._estimate: float | None = None

    def estimate_s(self) -> float | None:
        if self._estimate is None:
            try:
                self._estimate = float(self.plan.estimate(self.task).seconds)
            except Exception:  # noqa: BLE001 - the estimate is shown beside progress, never needed
                self._estimate = float("nan")
        return self._estimate

    def text(self, stage: str, fraction, figures: dict) -> str:
        out = stage + (f" {100 * fraction:.0f}%" if fraction is not None else "")
        if "products" in figures:
            out += f", {figures['products']} products"
        if "residual" in figures:
            out += f", residual {figures['residual']:.2e}"
        estimate = self.estimate_s()
        est = f" (plan ~{_duration(estimate)})" if estimate == estimate else ""
        return (f"{out}; {_duration(time.monotonic() - self.started)}{est}, "
                f"{resident_memory_mb() / 1024:.2f} GiB")

    def __call__(self, stage: str, fraction=None, **figures) -> None:
        changed = stage != self.stage
        self.stage = stage
        if self.bar is not None:
            self.bar.set_postfix_str(f"task {self.task.id}: {self.text(stage, fraction, figures)}", refresh=True)
            return
        if not self.lines:
            return
        now = time.monotonic()
        if now - self.started < STAGE_QUIET_S:
            return
        if changed or now - self._last_line >= STAGE_INTERVAL_S:
            self._last_line = now
            emit(f"{self.prefix}task {self.task.id} running: {self.text(stage, fraction, figures)}")


class RunLog:
    """The coordinator's view of a run (see the module docstring)."""

    def __init__(self, plan, done_before: int, quiet: bool, show: bool = True, total: int | None = None):
        global _BAR
        self.plan = plan
        self.total = len(plan.tasks) if total is None else total
        self.done_before = done_before
        self.finished = done_before
        self.tty = _is_tty()
        self.bar_shown = show and self.tty and not quiet
        self.lines = show and (not self.tty or not quiet)
        self.started = time.monotonic()
        self._last_line = self.started
        from tqdm import tqdm

        self.bar = tqdm(total=self.total, initial=done_before, unit="task", disable=not self.bar_shown,
                        file=sys.stderr, dynamic_ncols=True, desc="simulating")
        if self.bar_shown:
            _BAR = self.bar
        self._stop = threading.Event()
        self._heartbeat = None
        if self.lines and not self.tty:
            self._heartbeat = threading.Thread(target=self._beat, daemon=True, name="progress-heartbeat")
            self._heartbeat.start()

    def eta(self) -> str:
        ran = self.finished - self.done_before
        if ran <= 0:
            return "ETA unknown"
        left = (time.monotonic() - self.started) / ran * (self.total - self.finished)
        return f"ETA {_duration(left)}"

    def line(self, text: str) -> None:
        self._last_line = time.monotonic()
        emit(text)

    def task_done(self, task, diagnostics: dict) -> None:
        self.finished += 1
        if self.lines:
            memory = diagnostics.get("peak_memory_mb", peak_memory_mb())
            text = (f"[{self.finished}/{self.total}] task {task.id} {task.kind}: {task_where(self.plan, task)}; "
                    f"{diagnostics.get('model', '')}, {diagnostics.get('wall_time_s', 0.0):.2f} s, "
                    f"peak {memory:.0f} MB{_figures(diagnostics)}")
            if "rank" in diagnostics:
                text += f", rank {diagnostics['rank']}"
            if diagnostics.get("warnings"):
                text += f" [warning: {diagnostics['warnings']}]"
            self.line(text + ("" if self.tty else f"; {self.eta()}"))
        self.bar.update(1)

    def task_failed(self) -> None:
        self.finished += 1
        self.bar.update(1)

    def stages(self, task, prefix: str = "") -> StageReporter:
        """The reporter of ``task`` run in this process."""
        return StageReporter(self.plan, task, bar=self.bar if self.bar_shown else None, lines=self.lines,
                             prefix=prefix)

    def _beat(self) -> None:
        while not self._stop.wait(min(HEARTBEAT_S, 30.0)):
            if time.monotonic() - self._last_line >= HEARTBEAT_S:
                self.line(f"progress: {self.finished}/{self.total} tasks, elapsed "
                          f"{_duration(time.monotonic() - self.started)}, {self.eta()}")

    def close(self) -> None:
        global _BAR
        self._stop.set()
        if _BAR is self.bar:
            _BAR = None
        self.bar.close()


def worker_stages(plan, task, rank: int) -> StageReporter:
    """The reporter of a task run in a worker process or MPI rank without the bar: lines in logs
    only (on a terminal they would break the coordinator's bar)."""
    return StageReporter(plan, task, bar=None, lines=not _is_tty(), prefix=f"rank {rank}: ")
