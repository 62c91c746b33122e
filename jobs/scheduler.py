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

Executors share one :class:`TaskBoard` (dependencies, retries, progress). It hands out ready
tasks in plan order, except that a steered sub-area stays with the worker that ran its last task
(its wavelengths in order, one operator for its basic directions and each solve warm-started
from the previous wavelength, solver/bem3d/warm_start.py), and a worker done with its sub-area
takes one no other worker holds while there is one:

- ``serial``: tasks run in this process.
- ``processes``: a pool of local worker processes (spawned; PoCL threads and FFT workers bounded
  to cores / workers each, one kernel cache folder per worker); they die with their parent
  (``PR_SET_PDEATHSIG`` on Linux, a watchdog thread elsewhere).
- ``mpi``: under ``mpiexec``/``srun`` every rank works; rank 0 also runs the coordinator in a
  thread that hands out tasks on request (so slow tasks never idle the other ranks), shows the
  progress bar and writes the dataset. Waiting uses polling with sleeps, not busy MPI receives,
  so oversubscribed ranks do not steal CPU.
"""

from __future__ import annotations

import logging
import os
import signal
import sys
import threading
import time
import traceback
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path

from wavebrdf.jobs.node import threads_per_rank
from wavebrdf.jobs.parts import PartsFolder, ResumeError, StorageError, remove_leftovers
from wavebrdf.jobs.plan import Plan, Task
from wavebrdf.jobs.progress import RunLog, worker_stages
from wavebrdf.jobs.store import write_dataset
from wavebrdf.jobs.tasks import ModelPool, execute_task, plain
from wavebrdf.solver.progress import silent

logger = logging.getLogger(__name__)

__all__ = [
    "ResumeError",
    "RunSummary",
    "TaskBoard",
    "apply_worker_environment",
    "die_with_parent",
    "prepare_output",
    "run_plan",
    "share_from_root",
    "sub_area",
    "worker_environment",
]


@dataclass
class RunSummary:
    path: Path
    done: int
    failed: int
    tasks: int


def worker_environment(workers_on_node: int, rank: int, cores: int | None = None) -> dict[str, str]:
    """Environment for one of ``workers_on_node`` workers of a node: bounded threads
    (:func:`~wavebrdf.jobs.node.threads_per_rank`: the CPU affinity or ``SLURM_CPUS_PER_TASK``,
    a user's ``OMP_NUM_THREADS``) and the node's shared kernel cache (``POCL_CACHE_DIR``, built
    once, see :meth:`~wavebrdf.solver.opencl.ComputeContext.program`). ``rank`` is kept for callers.

    Must be applied before the worker first touches OpenCL (PoCL reads it at platform load).
    """
    threads = str(threads_per_rank(workers_on_node, cpus=cores))
    base = Path(os.environ.get("POCL_CACHE_DIR", Path.home() / ".cache" / "pocl")).expanduser()
    return {
        "POCL_MAX_PTHREAD_COUNT": threads,
        "POCL_CPU_MAX_CU_COUNT": threads,
        "WAVEBRDF_FFT_WORKERS": threads,
        "OMP_NUM_THREADS": threads,
        "OPENBLAS_NUM_THREADS": threads,
        "MKL_NUM_THREADS": threads,
        "POCL_CACHE_DIR": str(base),
    }


def apply_worker_environment(env: dict[str, str]) -> None:
    """Apply :func:`worker_environment` to this process: the variables for what starts later
    (PoCL, host FFTs, libraries not loaded yet), and the same thread cap on the BLAS/OpenMP
    pools already loaded (numpy's and scipy's OpenBLAS start their threads at import, before any
    variable set here is read; an uncapped pool spins on the other workers' cores)."""
    os.environ.update(env)
    from threadpoolctl import threadpool_limits

    threadpool_limits(int(env["OMP_NUM_THREADS"]))


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


def _run_serial(board: TaskBoard, ctx) -> None:
    pool = ModelPool()
    while not board.finished:
        task = board.next_task()
        if task is None:
            raise RuntimeError("internal error: tasks are waiting on dependencies that can never finish")
        ok, diag = _run_guarded(ctx, board.plan, task, board.parts, pool, board.log.stages(task))
        board.finish(task, diag) if ok else board.fail(task, diag)


# --- local processes ---------------------------------------------------------------------------

_WORKER: dict = {}
PR_SET_PDEATHSIG = 1  # linux/prctl.h


def die_with_parent(parent_pid: int) -> None:
    """End this process when its parent dies: ``PR_SET_PDEATHSIG`` (SIGKILL) on Linux, a watchdog
    thread polling the parent elsewhere. A worker killed so loses only its task in flight."""
    if sys.platform.startswith("linux"):
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0:
            if os.getppid() != parent_pid:  # the parent died before the request
                os._exit(1)
            return

    def watch():
        while os.getppid() == parent_pid:
            time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=watch, daemon=True, name="parent-watchdog").start()


def _process_init(config_text, config_path, output, env, parent_pid):
    """A worker: dies with its parent, bounded threads, the parent's config text (not the file,
    which may have been edited since), its own context and model pool."""
    die_with_parent(parent_pid)
    apply_worker_environment(env)
    from wavebrdf.jobs.config import parse_config
    from wavebrdf.jobs.plan import plan_study
    from wavebrdf.solver.opencl import create_context

    plan = plan_study(parse_config(config_text, Path(config_path), output=output))
    ctx = create_context(require_fp64=plan.needs_fp64)
    _WORKER.update(plan=plan, parts=PartsFolder(plan), ctx=ctx, pool=ModelPool(), pid=os.getpid())


def _process_run(task_id: int):
    plan = _WORKER["plan"]
    task = plan.tasks[task_id]
    return _run_guarded(_WORKER["ctx"], plan, task, _WORKER["parts"], _WORKER["pool"],
                        worker_stages(plan, task, f"worker {_WORKER['pid']}"))


def _run_processes(board: TaskBoard, workers: int) -> None:
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    config = board.plan.config
    envs = [worker_environment(workers, r) for r in range(workers)]
    # one pool per worker keeps each worker's environment (threads, cache folder) its own
    pools = [ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"), initializer=_process_init,
                                 initargs=(config.text, str(config.path), str(config.output), envs[r], os.getpid()))
             for r in range(workers)]
    running: dict = {}
    try:
        while not board.finished:
            busy = {pool for pool, _ in running.values()}
            for worker, pool in enumerate(pools):
                if pool in busy:
                    continue
                task = board.next_task(worker)
                if task is None:
                    break
                running[pool.submit(_process_run, task.id)] = (pool, task)
            if not running:
                raise RuntimeError("internal error: no runnable task and none running")
            finished, _ = wait(list(running), return_when=FIRST_COMPLETED)
            for future in finished:
                _, task = running.pop(future)
                ok, diag = future.result()
                board.finish(task, diag) if ok else board.fail(task, diag)
    finally:
        for pool in pools:
            pool.shutdown(cancel_futures=True)


# --- MPI ---------------------------------------------------------------------------------------


class Tag(IntEnum):
    REQUEST = 1  # worker -> coordinator: (rank, finished task id or None, ok, diagnostics)
    TASK = 2  # coordinator -> worker: task id, or None = stop
    SHARE = 3  # rank 0 -> every rank: a value decided by rank 0 (share_from_root)


def _poll_recv(comm, source: int, tag: int, stop: threading.Event | None = None):
    """Receive without MPI busy-waiting (MPICH spins in blocking receives)."""
    delay = 0.0001
    while not comm.Iprobe(source=source, tag=tag):
        if stop is not None and stop.is_set():
            return None
        time.sleep(delay)
        delay = min(delay * 2, 0.002)
    return comm.recv(source=source, tag=tag)


def share_from_root(comm, value):
    """Rank 0's ``value`` on every rank (a broadcast that waits by polling, so ranks waiting while
    rank 0 blocks, e.g. on the output's lock, do not spin)."""
    if comm.Get_rank() == 0:
        for rank in range(1, comm.Get_size()):
            comm.send(value, dest=rank, tag=Tag.SHARE)
        return value
    return _poll_recv(comm, source=0, tag=Tag.SHARE)


def _mpi_coordinator(board: TaskBoard, comm, size: int, error: list) -> None:
    """Hand out tasks on request until all are done, then tell every worker to stop."""
    from mpi4py import MPI

    try:
        waiting_ranks: list[int] = []
        stopped = 0
        while stopped < size:
            message = _poll_recv(comm, source=MPI.ANY_SOURCE, tag=Tag.REQUEST)
            rank, task_id, ok, diag = message
            if task_id is not None:
                task = board.plan.tasks[task_id]
                board.finish(task, diag) if ok else board.fail(task, diag)
            waiting_ranks.append(rank)
            still = []
            for r in waiting_ranks:
                task = board.next_task(r)
                if task is not None:
                    comm.send(task.id, dest=r, tag=Tag.TASK)
                elif board.finished:
                    comm.send(None, dest=r, tag=Tag.TASK)
                    stopped += 1
                else:
                    still.append(r)
            waiting_ranks = still
    except BaseException as exc:  # pragma: no cover - reported, then the run aborts
        error.append(exc)
        comm.Abort(1)


def _mpi_worker(comm, ctx, plan: Plan, parts: PartsFolder, board: TaskBoard | None = None) -> None:
    """Ask rank 0 for tasks and run them until told to stop (``board``: rank 0's, for its bar)."""
    rank = comm.Get_rank()
    pool = ModelPool()
    previous = (None, True, {})
    while True:
        asked = time.perf_counter()
        comm.send((rank,) + previous, dest=0, tag=Tag.REQUEST)
        task_id = _poll_recv(comm, source=0, tag=Tag.TASK)
        if task_id is None:
            return
        waited = time.perf_counter() - asked  # coordinator round trip: the scheduling overhead
        task = plan.tasks[task_id]
        stages = board.log.stages(task, f"rank {rank}: ") if board is not None else worker_stages(plan, task, rank)
        ok, diag = _run_guarded(ctx, plan, task, parts, pool, stages)
        diag["dispatch_wait_s"] = waited
        diag["rank"] = rank
        previous = (task_id, ok, diag)


def _run_mpi(board: TaskBoard | None, comm, ctx, plan: Plan, parts: PartsFolder) -> None:
    """Every rank works; rank 0 also coordinates in a thread."""
    if comm.Get_rank() != 0:
        _mpi_worker(comm, ctx, plan, parts)
        return
    error: list = []
    thread = threading.Thread(target=_mpi_coordinator, args=(board, comm, comm.Get_size(), error), daemon=True)
    thread.start()
    _mpi_worker(comm, ctx, plan, parts, board)
    thread.join()
    if error:
        raise error[0]


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


def run_plan(plan: Plan, ctx, *, executor: str = "serial", workers: int | None = None, comm=None,
             progress: bool = True, quiet: bool = False, only: set[int] | None = None) -> RunSummary | None:
    """Run every missing task of ``plan`` and write the dataset (rank 0 only under MPI). The caller
    holds the output's lock (rank 0 under MPI). ``only``: the task ids of a shard (jobs/shards.py):
    just those run, and the parts folder is kept for ``wavebrdf merge`` instead of a dataset.

    Returns the summary on the writing process, None on other MPI ranks.
    """
    study = plan.study
    rank = comm.Get_rank() if comm is not None else 0
    parts = prepare_output(plan) if rank == 0 else PartsFolder(plan)
    if comm is not None:
        comm.Barrier()
    board = TaskBoard(plan, parts, study.run.retries, progress, quiet, only) if rank == 0 else None
    try:
        if executor == "mpi":
            _run_mpi(board, comm, ctx, plan, parts)
        elif executor == "processes":
            _run_processes(board, workers or os.cpu_count() or 1)
        else:
            _run_serial(board, ctx)
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
