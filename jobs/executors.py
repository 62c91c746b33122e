"""Executors: where a run's tasks run. One table, :data:`EXECUTORS`, that the config (``[run]
executor``), the CLI (``--executor``), ``plan`` and ``run`` (tasks at once per node, so each task's
memory budget) and the scheduler read; ``"auto"`` is resolved here alone (:func:`resolve_executor`).

Every executor takes tasks from the scheduler's :class:`~wavebrdf.jobs.scheduler.TaskBoard`
(dependencies, retries, progress) through a :class:`~wavebrdf.jobs.scheduler.Work` (the plan,
its parts folder, the board where this process coordinates) and runs each with
``work.execute`` (a task's failure is data, a failed write stops the run):

- ``serial``: tasks run in this process.
- ``processes``: a pool of local worker processes (spawned; PoCL threads and FFT workers bounded
  to cores / workers each, :func:`~wavebrdf.jobs.node.worker_environment`); they die with their
  parent (``PR_SET_PDEATHSIG`` on Linux, a watchdog thread elsewhere).
- ``mpi``: under ``mpiexec``/``srun`` every rank works; rank 0 also runs the coordinator in a
  thread that hands out tasks on request (so slow tasks never idle the other ranks), shows the
  progress bar and writes the dataset. Waiting uses polling with sleeps, not busy MPI receives,
  so oversubscribed ranks do not steal CPU. mpi4py is imported here only, when MPI starts.

A new executor is a subclass of :class:`Executor` in :data:`EXECUTORS`; the config, the CLI and
the plan offer it with no other change.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from enum import IntEnum

from wavebrdf.jobs.errors import ConfigError
from wavebrdf.jobs.node import allowed_cpus, apply_worker_environment, worker_environment
from wavebrdf.jobs.progress import worker_stages
from wavebrdf.jobs.tasks import ModelPool

__all__ = ["AUTO", "EXECUTORS", "Executor", "Tag", "die_with_parent", "executor_names", "resolve_executor",
           "share_from_root"]

AUTO = "auto"  # MPI under a launcher (mpiexec/srun), else serial


class Executor:
    """How a run's tasks are spread over workers (the protocol every entry of :data:`EXECUTORS`
    follows). ``launch``: what the launcher says (:class:`~wavebrdf.jobs.cli.MpiLaunch`), or None."""

    name: str = ""

    def check(self, launch) -> None:
        """Refuse (:class:`ConfigError`) to run under ``launch`` before anything starts."""

    def tasks_per_node(self, study, requested: int | None = None, launch=None) -> int:
        """Tasks at once on this node, the same for ``plan`` and ``run`` (their memory budget):
        ``requested`` is ``--workers``."""
        return 1

    def start(self, launch):
        """Set up the workers' world before the plan is built; the MPI communicator or None."""
        return None

    def describe(self, workers: int, comm) -> str:
        """Where the tasks run, for the run's first line."""
        raise NotImplementedError

    def run(self, work, ctx, *, workers: int | None, comm) -> None:
        """Run the board's tasks until it is finished (``work.board``; None on MPI ranks other
        than 0)."""
        raise NotImplementedError


class Serial(Executor):
    name = "serial"

    def describe(self, workers, comm) -> str:
        return "this process"

    def run(self, work, ctx, *, workers, comm) -> None:
        board, pool = work.board, ModelPool()
        while not board.finished:
            task = board.next_task()
            if task is None:
                raise RuntimeError("internal error: tasks are waiting on dependencies that can never finish")
            ok, diag = work.execute(ctx, task, pool, board.log.stages(task))
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


def _process_init(setup, env, parent_pid):
    """A worker: dies with its parent, bounded threads, then ``setup()`` (the scheduler's recipe:
    the parent's config text, not the file, which may have been edited since) gives its work and
    context; its own model pool."""
    die_with_parent(parent_pid)
    apply_worker_environment(env)
    work, ctx = setup()
    _WORKER.update(work=work, ctx=ctx, pool=ModelPool(), pid=os.getpid())


def _process_run(task_id: int):
    work = _WORKER["work"]
    task = work.plan.tasks[task_id]
    stages = worker_stages(work.plan, task, f"worker {_WORKER['pid']}")
    return work.execute(_WORKER["ctx"], task, _WORKER["pool"], stages)


class Processes(Executor):
    name = "processes"

    def tasks_per_node(self, study, requested=None, launch=None) -> int:
        return requested or study.run.workers or allowed_cpus()

    def describe(self, workers, comm) -> str:
        return f"{workers} worker processes"

    def run(self, work, ctx, *, workers, comm) -> None:
        import multiprocessing
        from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

        board = work.board
        workers = workers or os.cpu_count() or 1
        envs = [worker_environment(workers, r) for r in range(workers)]
        # one pool per worker keeps each worker's environment (threads, cache folder) its own
        pools = [ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"), initializer=_process_init,
                                     initargs=(work.worker_setup(), envs[r], os.getpid()))
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


def _mpi_coordinator(board, comm, size: int, error: list) -> None:
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


def _mpi_worker(comm, ctx, work) -> None:
    """Ask rank 0 for tasks and run them until told to stop (``work.board``: rank 0's, for its bar)."""
    rank, plan, board = comm.Get_rank(), work.plan, work.board
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
        ok, diag = work.execute(ctx, task, pool, stages)
        diag["dispatch_wait_s"] = waited
        diag["rank"] = rank
        previous = (task_id, ok, diag)


class Mpi(Executor):
    name = "mpi"

    def check(self, launch) -> None:
        if launch is None:
            raise ConfigError("[run] executor = \"mpi\": start the run with mpiexec -n N (or srun) to use MPI")

    def tasks_per_node(self, study, requested=None, launch=None) -> int:
        return launch.local_size if launch else (requested or study.run.workers or 1)

    def start(self, launch):
        apply_worker_environment(worker_environment(launch.local_size, launch.rank))
        from mpi4py import MPI

        return MPI.COMM_WORLD

    def describe(self, workers, comm) -> str:
        return f"{comm.Get_size() if comm else 1} MPI ranks"

    def run(self, work, ctx, *, workers, comm) -> None:
        """Every rank works; rank 0 also coordinates in a thread."""
        if comm.Get_rank() != 0:
            _mpi_worker(comm, ctx, work)
            return
        error: list = []
        thread = threading.Thread(target=_mpi_coordinator, args=(work.board, comm, comm.Get_size(), error),
                                  daemon=True)
        thread.start()
        _mpi_worker(comm, ctx, work)
        thread.join()
        if error:
            raise error[0]


# ---------------------------------------------------------------------------------------------
# The table

EXECUTORS: dict[str, Executor] = {e.name: e for e in (Serial(), Processes(), Mpi())}


def executor_names() -> tuple[str, ...]:
    """What ``[run] executor`` and ``--executor`` accept: "auto", then every executor."""
    return (AUTO, *EXECUTORS)


def resolve_executor(name: str, launch=None) -> Executor:
    """The executor ``name`` stands for: "auto" is MPI under a launcher (``launch``), else serial."""
    if name == AUTO:
        name = "mpi" if launch else "serial"
    return EXECUTORS[name]
