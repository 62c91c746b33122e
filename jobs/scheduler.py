"""Execution: run a plan's tasks (in-process, local processes or MPI ranks), keep every finished
task on disk, and assemble the dataset with one writer.

Finished tasks are saved atomically in ``<output>.parts/`` (jobs/parts.py); a run that dies loses
only the tasks in flight; re-running the same command runs only what is missing. A changed config
is refused (the folder records the plan's fingerprint); every part is verified (identity and
checksum) before any new work starts, and a bad one is recomputed. The caller holds the output's
lock (:class:`~wavebrdf.jobs.parts.OutputLock`) for the whole run. A write that fails (disk
full) stops the run with :class:`~wavebrdf.jobs.parts.StorageError`; finished parts are kept.
What a task runs and saves is its kind's entry in jobs/tasks.py; every worker process keeps its own :class:`~wavebrdf.jobs.tasks.ModelPool`. A task that raises is recorded with its
diagnostics and retried ``[run] retries`` times; if it still fails, its slot stays NaN, the
dataset is written with ``status = "failed"`` for it, the parts folder is kept (a re-run retries
it) and the command exits non-zero.

Executors (jobs/executors.py: serial, local processes, MPI ranks) share one :class:`TaskBoard`
(dependencies, retries, progress), reached through a :class:`Work`. It hands out ready tasks in
plan order, except that a steered sub-area stays with the worker that ran its last task (its
wavelengths in order, one operator for its basic directions and each solve warm-started from
the previous wavelength, solver/bem3d/warm_start.py), and a worker done with its sub-area takes
one no other worker holds while there is one.
"""

from __future__ import annotations

import logging
import os
import time
import traceback
from dataclasses import dataclass
from functools import partial
from pathlib import Path

from wavebrdf.jobs.config import parse_config
from wavebrdf.jobs.executors import Executor, die_with_parent, resolve_executor
from wavebrdf.jobs.node import threads_per_rank
from wavebrdf.jobs.parts import PartsFolder, ResumeError, StorageError, remove_leftovers
from wavebrdf.jobs.plan import Plan, Task, plan_study
from wavebrdf.jobs.progress import RunLog
from wavebrdf.jobs.store import write_dataset
from wavebrdf.jobs.tasks import ModelPool, execute_task, plain
from wavebrdf.solver.opencl import create_context
from wavebrdf.solver.progress import silent

logger = logging.getLogger(__name__)

__all__ = [
    "ResumeError",
    "RunSummary",
    "TaskBoard",
    "Work",
    "die_with_parent",  # the measuring processes of jobs/compare.py die with their parent too
    "prepare_output",
    "run_plan",
    "sub_area",
]


@dataclass
class RunSummary:
    path: Path
    done: int
    failed: int
    tasks: int


# ---------------------------------------------------------------------------------------------
# Coordination


def sub_area(task: Task) -> tuple | None:
    """(case, sub-area) of a task that simulates a steering sub-area, else None."""
    return (task.case, task.patch) if task.on_patch else None


class TaskBoard:
    """Which tasks are ready, running, done or failed; retries; the progress bar."""

    def __init__(self, plan: Plan, parts: PartsFolder, retries: int, progress: bool, quiet: bool = False,
                 only: set[int] | None = None):
        self.plan = plan
        self.parts = parts
        self.retries = retries
        self.done = parts.verify()  # every part checked before any new work starts
        self.failed: dict[int, dict] = {}
        self.run_info: dict[int, dict] = {}  # per-task scheduling facts (rank, dispatch wait) for the table
        self.attempts: dict[int, int] = {}
        self.running: set[int] = set()
        self.held: dict = {}  # worker → the sub-area of its last task (next_task)
        self.waiting = [t for t in plan.tasks if t.id not in self.done and (only is None or t.id in only)]
        for task in self.waiting:
            parts.clear_failure(task)
        self.started = time.perf_counter()
        self.dispatch_seconds = 0.0
        ours = len(plan.tasks) if only is None else len(only)  # a shard runs only its tasks (jobs/shards.py)
        self.log = RunLog(plan, ours - len(self.waiting), quiet=quiet, show=progress, total=ours)
        if self.done:
            logger.info("resuming: %d of %d tasks already done", len(self.done), len(plan.tasks))

    def next_task(self, worker=None) -> Task | None:
        """A task whose dependencies are done (None if nothing is ready now). A spot check
        (``Task.checks``) is a soft dependency: done or failed, the task may run (without it).
        ``worker`` (any hashable, e.g. a rank) names the asking worker: it gets the next ready
        task of the sub-area it holds, else of a sub-area no other worker holds, else the first
        ready one (module docstring); None: the first ready one."""
        t0 = time.perf_counter()
        blocked = set(self.failed)
        held = {a for w, a in self.held.items() if w != worker}
        mine = self.held.get(worker)
        chosen = free = first = None
        for i, task in enumerate(self.waiting):
            hard = [d for d in task.depends if d not in task.checks]
            if any(d in blocked for d in hard):
                self.waiting.pop(i)
                self.fail(task, {"error": "a task it depends on failed", "depends": hard}, final=True)
                self.dispatch_seconds += time.perf_counter() - t0
                return self.next_task(worker)
            if not (all(d in self.done for d in hard) and all(d in self.done or d in blocked for d in task.checks)):
                continue
            area = sub_area(task)
            if worker is None or (mine is not None and area == mine):
                chosen = i
                break
            if first is None:
                first = i
            if free is None and (area is None or area not in held):
                free = i
        if chosen is None:
            chosen = free if free is not None else first
        if chosen is None:
            self.dispatch_seconds += time.perf_counter() - t0
            return None
        task = self.waiting.pop(chosen)
        self.running.add(task.id)
        self.attempts[task.id] = self.attempts.get(task.id, 0) + 1
        if worker is not None and sub_area(task) is not None:
            self.held[worker] = sub_area(task)
        self.dispatch_seconds += time.perf_counter() - t0
        return task

    def finish(self, task: Task, diagnostics: dict) -> None:
        self.running.discard(task.id)
        self.done.add(task.id)
        self.run_info[task.id] = {k: diagnostics[k] for k in ("rank", "dispatch_wait_s", "threads", "kernel_build_s")
                                  if k in diagnostics}
        self.parts.save_run_info(task, self.run_info[task.id])
        self.log.task_done(task, diagnostics)

    def fail(self, task: Task, diagnostics: dict, final: bool = False) -> None:
        self.running.discard(task.id)
        if not final and self.attempts.get(task.id, 0) <= self.retries:
            logger.warning("%s failed (attempt %d), retrying: %s", task.label, self.attempts[task.id],
                           diagnostics.get("error"))
            self.waiting.insert(0, task)
            return
        logger.error("%s failed: %s", task.label, diagnostics.get("error"))
        diagnostics = {**diagnostics, "attempts": self.attempts.get(task.id, 0)}
        self.failed[task.id] = diagnostics
        self.parts.save_failure(task, diagnostics)
        self.log.task_failed()

    @property
    def finished(self) -> bool:
        return not self.waiting and not self.running

    def close(self) -> None:
        self.log.close()


def _run_guarded(ctx, plan: Plan, task: Task, parts: PartsFolder, pool: ModelPool,
                 stages=None) -> tuple[bool, dict]:
    """Execute a task, turning any exception into failure diagnostics (except a failed write of
    the parts folder: a full disk is not the task's failure, it stops the run). ``stages``: the
    task's in-task progress reporter (jobs/progress.py), set as ``ctx.progress`` while it runs.
    Adds the threads this process runs and its kernel build time to the diagnostics."""
    build = getattr(ctx, "build_seconds", 0.0)
    if ctx is not None and stages is not None:
        ctx.progress = stages
    try:
        diag = execute_task(ctx, plan, task, parts, pool)
        diag.update(threads=int(os.environ.get("POCL_MAX_PTHREAD_COUNT", 0)) or threads_per_rank(1),
                    kernel_build_s=getattr(ctx, "build_seconds", 0.0) - build)
        return True, diag
    except StorageError:
        raise
    except Exception as exc:  # a task failure is data, not a crash of the run
        diag = {"error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc(limit=8)}
        diag.update(plain(getattr(exc, "diagnostics", {}) or {}))
        return False, diag
    finally:
        if ctx is not None and stages is not None:
            ctx.progress = silent


@dataclass
class Work:
    """What an executor (jobs/executors.py) runs: the plan's tasks, saved to ``parts``, handed out
    by ``board`` where this process coordinates (None on MPI ranks other than 0)."""

    plan: Plan
    parts: PartsFolder
    board: TaskBoard | None = None

    def execute(self, ctx, task: Task, pool: ModelPool, stages=None) -> tuple[bool, dict]:
        """Run ``task`` here: (True, diagnostics), or (False, its failure's diagnostics)."""
        return _run_guarded(ctx, self.plan, task, self.parts, pool, stages)

    def worker_setup(self):
        """A picklable recipe a spawned worker process calls for its own (Work, context): the
        plan rebuilt from the config text this run read."""
        config = self.plan.config
        return partial(_worker_work, config.text, str(config.path), str(config.output))


def _worker_work(config_text: str, config_path: str, output: str) -> tuple[Work, object]:
    plan = plan_study(parse_config(config_text, Path(config_path), output=output))
    ctx = create_context(require_fp64=plan.needs_fp64)
    return Work(plan, PartsFolder(plan)), ctx


# ---------------------------------------------------------------------------------------------
# Entry point


def prepare_output(plan: Plan) -> PartsFolder:
    """Remove what killed runs on the output left behind, then open (or create) the parts folder;
    :class:`ResumeError` if it cannot be used. The caller holds the output's lock."""
    for path in remove_leftovers(plan.config.output):
        logger.info("removed %s (left by a run that was killed)", path)
    parts = PartsFolder(plan)
    parts.open()
    return parts


def run_plan(plan: Plan, ctx, *, executor: str | Executor = "serial", workers: int | None = None, comm=None,
             progress: bool = True, quiet: bool = False, only: set[int] | None = None) -> RunSummary | None:
    """Run every missing task of ``plan`` and write the dataset (rank 0 only under MPI). The caller
    holds the output's lock (rank 0 under MPI). ``executor``: an entry of
    :data:`~wavebrdf.jobs.executors.EXECUTORS` or its name. ``only``: the task ids of a shard (jobs/shards.py):
    just those run, and the parts folder is kept for ``wavebrdf merge`` instead of a dataset.

    Returns the summary on the writing process, None on other MPI ranks.
    """
    study = plan.study
    rank = comm.Get_rank() if comm is not None else 0
    parts = prepare_output(plan) if rank == 0 else PartsFolder(plan)
    if comm is not None:
        comm.Barrier()
    board = TaskBoard(plan, parts, study.run.retries, progress, quiet, only) if rank == 0 else None
    if isinstance(executor, str):
        executor = resolve_executor(executor)
    try:
        executor.run(Work(plan, parts, board), ctx, workers=workers, comm=comm)
    finally:
        if board is not None:
            board.close()
    if rank != 0:
        return None
    elapsed = time.perf_counter() - board.started
    logger.info("coordinator dispatch time %.3g s for %d tasks (%.2f%% of the run)", board.dispatch_seconds,
                len(plan.tasks), 100 * board.dispatch_seconds / max(elapsed, 1e-9))
    if only is not None:
        return RunSummary(parts.path, len(board.done & only), len(board.failed), len(only))
    path = write_dataset(plan, parts, device=ctx.describe() if ctx is not None else "", run_info=board.run_info)
    if not board.failed:
        parts.remove()
    return RunSummary(path, len(board.done), len(board.failed), len(plan.tasks))
