"""Execution: run a plan's tasks (in-process, local processes or MPI ranks), keep every finished
task on disk, and assemble the dataset with one writer.

Finished tasks are saved atomically in ``<output>.parts/`` (written under a temporary name, then
renamed): ``task-<id>.npz`` for result tasks, ``patch-<id>.npz`` for sub-area far fields (kept
until the dataset is written, so no wavelength overwrites another's). A run that dies loses only
the tasks in flight; re-running the same command runs only what is missing. A changed config is
refused (the folder records the plan's fingerprint). A task that raises is recorded with its
diagnostics and retried ``[run] retries`` times; if it still fails, its slot stays NaN, the
dataset is written with ``status = "failed"`` for it, the parts folder is kept (a re-run retries
it) and the command exits non-zero.

Executors share one :class:`TaskBoard` (dependencies, retries, progress):

- ``serial``: tasks run in this process.
- ``processes``: a pool of local worker processes (spawned; PoCL threads and FFT workers bounded
  to cores / workers each, one kernel cache folder per worker).
- ``mpi``: under ``mpiexec``/``srun`` every rank works; rank 0 also runs the coordinator in a
  thread that hands out tasks on request (so slow tasks never idle the other ranks), shows the
  progress bar and writes the dataset. Waiting uses polling with sleeps, not busy MPI receives,
  so oversubscribed ranks do not steal CPU.
"""

from __future__ import annotations

import json
import logging
import os
import queue
import shutil
import sys
import threading
import time
import traceback
import warnings
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path

import numpy as np

from wavebrdf import __version__
from wavebrdf.jobs.plan import Plan, Task
from wavebrdf.jobs.steering import synthesize, synthesized_incident_power
from wavebrdf.jobs.store import SurfaceDatasetWriter, atomic_h5
from wavebrdf.solver.farfield import FarField, albedo, combine_polarizations
from wavebrdf.solver.models import get_model
from wavebrdf.solver.resources import peak_memory_mb

logger = logging.getLogger(__name__)

__all__ = [
    "PartsFolder",
    "ResumeError",
    "RunSummary",
    "TaskBoard",
    "TaskResult",
    "execute_task",
    "run_plan",
    "worker_environment",
]


class ResumeError(RuntimeError):
    """Existing partial results belong to a different configuration."""


@dataclass
class TaskResult:
    brdf_sp: np.ndarray  # (2, res, res) float32, s and p
    albedo_sp: np.ndarray  # (2,)
    diagnostics: dict

    def brdf(self, polarization: str) -> np.ndarray:
        return combine_polarizations(self.brdf_sp, polarization)


@dataclass
class RunSummary:
    path: Path
    done: int
    failed: int
    tasks: int


def worker_environment(workers_on_node: int, rank: int, cores: int | None = None) -> dict[str, str]:
    """Environment for one of ``workers_on_node`` workers: bounded threads, own kernel cache.

    Must be applied before the worker first touches OpenCL (PoCL reads it at platform load).
    """
    cores = cores or os.cpu_count() or 1
    threads = str(max(1, cores // max(1, workers_on_node)))
    base = Path(os.environ.get("POCL_CACHE_DIR", Path.home() / ".cache" / "pocl")).expanduser()
    return {
        "POCL_MAX_PTHREAD_COUNT": threads,
        "POCL_CPU_MAX_CU_COUNT": threads,
        "WAVEBRDF_FFT_WORKERS": threads,
        "OMP_NUM_THREADS": threads,
        "OPENBLAS_NUM_THREADS": threads,
        "MKL_NUM_THREADS": threads,
        "POCL_CACHE_DIR": str(base / f"rank-{rank}"),
    }


# ---------------------------------------------------------------------------------------------
# Task execution (any process)


def _plain(diagnostics: dict) -> dict:
    """Diagnostics with JSON-ready values (numbers, strings, lists of numbers; anything else as repr)."""
    def value(v):
        if isinstance(v, (bool, int, float, str)):
            return v
        if isinstance(v, (list, tuple)) and all(isinstance(x, (bool, int, float, str)) for x in v):
            return list(v)
        return repr(v)

    return {k: value(v) for k, v in diagnostics.items()}


def _farfield_diagnostics(ff: FarField) -> dict:
    return _plain(ff.diagnostics)


def _reduce(plan: Plan, task: Task, ff: FarField) -> TaskResult:
    brdf_sp = ff.brdf()
    if not np.all(np.isfinite(brdf_sp[:, plan.grid.inside])):
        raise FloatingPointError(f"{task.label}: NaN/inf inside the unit disk")
    return TaskResult(brdf_sp.astype(np.float32), albedo(brdf_sp, plan.grid), _farfield_diagnostics(ff))


def execute_task(ctx, plan: Plan, task: Task, parts: "PartsFolder") -> dict:
    """Run ``task`` and save its output in ``parts``; return its diagnostics."""
    if task.kind == "fiber":
        from wavebrdf.jobs.fibers import run_fiber_task

        return run_fiber_task(ctx, plan, task, parts)
    t0 = time.perf_counter()
    model = get_model(plan.model_name(task))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if task.kind == "synth":
            st = plan.steering[task.case]
            fields = {tuple(p.patch): parts.load_patch(p) for p in (plan.tasks[i] for i in task.depends)}
            basic_scene = plan.scene(task, basic=task.basic)
            theta, phi = plan.direction_rad(task)
            power = synthesized_incident_power(
                lambda pts: model.incident_fields(basic_scene, pts), st.layout, basic_scene.surface.spacing_um,
                basic_scene.wavelength_um, basic_scene.exterior_index, theta, phi,
            )
            ff = synthesize(fields, st.layout, theta, phi, power)
            ff.diagnostics["steering_offset"] = float(np.hypot(
                *(np.sin(theta) * np.array([np.cos(phi), np.sin(phi)])
                  - np.sin(basic_scene.theta_i) * np.array([np.cos(basic_scene.phi_i), np.sin(basic_scene.phi_i)]))))
        else:
            ff = model.farfield(ctx, plan.scene(task))
    messages = sorted({f"{w.category.__name__}: {w.message}" for w in caught})
    extra = {
        "kind": task.kind,
        "model": model.name,
        "wall_time_s": time.perf_counter() - t0,
        "peak_memory_mb": peak_memory_mb(),
        "device": ctx.describe() if ctx is not None else "",
        "warnings": "; ".join(messages),
    }
    if task.kind == "patch":
        centre = plan.steering[task.case].layout.centre(task.patch)
        ff = ff.translated(centre)
        ff.diagnostics.update(extra)
        parts.save_patch(task, ff)
        return {**_farfield_diagnostics(ff), **extra}
    result = _reduce(plan, task, ff)
    result.diagnostics.update(extra)
    parts.save_result(task, result)
    return result.diagnostics


# ---------------------------------------------------------------------------------------------
# On-disk parts


def _atomic_write(path: Path, write) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    with open(tmp, "wb") as fh:
        write(fh)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


class PartsFolder:
    """Finished task outputs next to the dataset, for resume and for the final assembly."""

    def __init__(self, plan: Plan):
        self.plan = plan
        output = Path(plan.config.output)
        self.path = output.with_name(output.name + ".parts")
        self.manifest = self.path / "manifest.json"

    def open(self) -> None:
        """Create the folder, or check that an existing one belongs to this plan."""
        expected = {"fingerprint": self.plan.fingerprint, "tasks": len(self.plan.tasks)}
        if self.manifest.exists():
            found = json.loads(self.manifest.read_text())
            if {k: found.get(k) for k in expected} != expected:
                raise ResumeError(
                    f"{self.path} holds partial results of a different configuration "
                    f"(fingerprint {found.get('fingerprint')} vs {expected['fingerprint']}); "
                    "delete that folder to start over, or restore the original config to resume"
                )
            return
        self.path.mkdir(parents=True, exist_ok=True)
        payload = json.dumps({**expected, "software_version": __version__}).encode()
        _atomic_write(self.manifest, lambda fh: fh.write(payload))

    def _file(self, task: Task) -> Path:
        prefix = "patch" if task.kind == "patch" else "task"
        return self.path / f"{prefix}-{task.id:06d}.npz"

    def done(self, task: Task) -> bool:
        return self._file(task).exists()

    def save_arrays(self, task: Task, diagnostics: dict, **arrays: np.ndarray) -> None:
        """Store a task's arrays and diagnostics (atomic)."""
        payload = {**arrays, "diagnostics": np.array(json.dumps(diagnostics))}
        _atomic_write(self._file(task), lambda fh: np.savez(fh, **payload))

    def load_arrays(self, task: Task) -> tuple[dict, dict]:
        with np.load(self._file(task)) as data:
            arrays = {k: data[k] for k in data.files if k != "diagnostics"}
            return arrays, json.loads(str(data["diagnostics"]))

    def save_result(self, task: Task, result: TaskResult) -> None:
        self.save_arrays(task, result.diagnostics, brdf_sp=result.brdf_sp, albedo_sp=result.albedo_sp)

    def load_result(self, task: Task) -> TaskResult:
        arrays, diagnostics = self.load_arrays(task)
        return TaskResult(arrays["brdf_sp"], arrays["albedo_sp"], diagnostics)

    def save_patch(self, task: Task, ff: FarField) -> None:
        arrays = {"E": ff.E, "incident_power": ff.incident_power,
                  "scalars": np.array([ff.wavelength_um, ff.exterior_index, ff.theta_i, ff.phi_i])}
        if ff.H is not None:
            arrays["H"] = ff.H
        self.save_arrays(task, _farfield_diagnostics(ff), **arrays)

    def load_patch(self, task: Task) -> FarField:
        arrays, diagnostics = self.load_arrays(task)
        lam, n1, theta, phi = arrays["scalars"]
        return FarField(grid=self.plan.grid, wavelength_um=float(lam), exterior_index=float(n1),
                        theta_i=float(theta), phi_i=float(phi), E=arrays["E"], H=arrays.get("H"),
                        incident_power=arrays["incident_power"], diagnostics=diagnostics)

    def load_diagnostics(self, task: Task) -> dict:
        return self.load_arrays(task)[1]

    def save_failure(self, task: Task, diagnostics: dict) -> None:
        payload = json.dumps(diagnostics).encode()
        _atomic_write(self.path / f"failed-{task.id:06d}.json", lambda fh: fh.write(payload))

    def failure(self, task: Task) -> dict | None:
        path = self.path / f"failed-{task.id:06d}.json"
        return json.loads(path.read_text()) if path.exists() else None

    def clear_failure(self, task: Task) -> None:
        (self.path / f"failed-{task.id:06d}.json").unlink(missing_ok=True)

    def remove(self) -> None:
        shutil.rmtree(self.path, ignore_errors=True)


# ---------------------------------------------------------------------------------------------
# Coordination


class TaskBoard:
    """Which tasks are ready, running, done or failed; retries; the progress bar."""

    def __init__(self, plan: Plan, parts: PartsFolder, retries: int, progress: bool):
        self.plan = plan
        self.parts = parts
        self.retries = retries
        self.done = {t.id for t in plan.tasks if parts.done(t)}
        self.failed: dict[int, dict] = {}
        self.run_info: dict[int, dict] = {}  # per-task scheduling facts (rank, dispatch wait) for the table
        self.attempts: dict[int, int] = {}
        self.running: set[int] = set()
        self.waiting = [t for t in plan.tasks if t.id not in self.done]
        for task in self.waiting:
            parts.clear_failure(task)
        self.started = time.perf_counter()
        self.dispatch_seconds = 0.0
        from tqdm import tqdm

        self.bar = tqdm(total=len(plan.tasks), initial=len(self.done), unit="task", disable=not progress,
                        file=sys.stderr, dynamic_ncols=True, desc="simulating")
        if self.done:
            logger.info("resuming: %d of %d tasks already done", len(self.done), len(plan.tasks))

    def next_task(self) -> Task | None:
        """A task whose dependencies are done (None if nothing is ready now)."""
        t0 = time.perf_counter()
        blocked = set(self.failed)
        for i, task in enumerate(self.waiting):
            if any(d in blocked for d in task.depends):
                self.waiting.pop(i)
                self.fail(task, {"error": "a task it depends on failed", "depends": list(task.depends)}, final=True)
                return self.next_task()
            if all(d in self.done for d in task.depends):
                self.waiting.pop(i)
                self.running.add(task.id)
                self.attempts[task.id] = self.attempts.get(task.id, 0) + 1
                self.dispatch_seconds += time.perf_counter() - t0
                return task
        self.dispatch_seconds += time.perf_counter() - t0
        return None

    def finish(self, task: Task, diagnostics: dict) -> None:
        self.running.discard(task.id)
        self.done.add(task.id)
        self.run_info[task.id] = {k: diagnostics[k] for k in ("rank", "dispatch_wait_s") if k in diagnostics}
        line = (f"[{len(self.done)}/{len(self.plan.tasks)}] {task.label}: {diagnostics.get('model', '')} "
                f"{diagnostics.get('wall_time_s', 0.0):.2f} s, peak {diagnostics.get('peak_memory_mb', 0):.0f} MB")
        for key in ("iterations", "residual"):
            if key in diagnostics:
                line += f", {key} {diagnostics[key]}"
        if diagnostics.get("warnings"):
            line += f" [warning: {diagnostics['warnings']}]"
        if self.bar.disable:
            logger.info("%s", line)
        else:
            self.bar.write(line, file=sys.stderr)
        self.bar.update(1)

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
        self.bar.update(1)

    @property
    def finished(self) -> bool:
        return not self.waiting and not self.running

    def close(self) -> None:
        self.bar.close()


def _run_guarded(ctx, plan: Plan, task: Task, parts: PartsFolder) -> tuple[bool, dict]:
    """Execute a task, turning any exception into failure diagnostics."""
    try:
        return True, execute_task(ctx, plan, task, parts)
    except Exception as exc:  # a task failure is data, not a crash of the run
        diag = {"error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc(limit=8)}
        diag.update(_plain(getattr(exc, "diagnostics", {}) or {}))
        return False, diag


def _run_serial(board: TaskBoard, ctx) -> None:
    while not board.finished:
        task = board.next_task()
        if task is None:
            raise RuntimeError("internal error: tasks are waiting on dependencies that can never finish")
        ok, diag = _run_guarded(ctx, board.plan, task, board.parts)
        board.finish(task, diag) if ok else board.fail(task, diag)


# --- local processes ---------------------------------------------------------------------------

_WORKER: dict = {}


def _process_init(config_path, output, env):
    os.environ.update(env)
    from wavebrdf.jobs.config import load_config
    from wavebrdf.jobs.plan import plan_study
    from wavebrdf.solver.opencl import create_context

    plan = plan_study(load_config(config_path, output=output))
    _WORKER.update(plan=plan, parts=PartsFolder(plan), ctx=create_context())


def _process_run(task_id: int):
    plan = _WORKER["plan"]
    return _run_guarded(_WORKER["ctx"], plan, plan.tasks[task_id], _WORKER["parts"])


def _run_processes(board: TaskBoard, workers: int) -> None:
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    config = board.plan.config
    envs = [worker_environment(workers, r) for r in range(workers)]
    # one pool per worker keeps each worker's environment (threads, cache folder) its own
    pools = [ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"), initializer=_process_init,
                                 initargs=(str(config.path), str(config.output), envs[r])) for r in range(workers)]
    running: dict = {}
    try:
        while not board.finished:
            idle = [p for p in pools if p not in {pool for pool, _ in running.values()}]
            for pool in idle:
                task = board.next_task()
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


def _poll_recv(comm, source: int, tag: int, stop: threading.Event | None = None):
    """Receive without MPI busy-waiting (MPICH spins in blocking receives)."""
    delay = 0.0001
    while not comm.Iprobe(source=source, tag=tag):
        if stop is not None and stop.is_set():
            return None
        time.sleep(delay)
        delay = min(delay * 2, 0.002)
    return comm.recv(source=source, tag=tag)


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
                task = board.next_task()
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


def _mpi_worker(comm, ctx, plan: Plan, parts: PartsFolder) -> None:
    rank = comm.Get_rank()
    previous = (None, True, {})
    while True:
        asked = time.perf_counter()
        comm.send((rank,) + previous, dest=0, tag=Tag.REQUEST)
        task_id = _poll_recv(comm, source=0, tag=Tag.TASK)
        if task_id is None:
            return
        waited = time.perf_counter() - asked  # coordinator round trip: the scheduling overhead
        ok, diag = _run_guarded(ctx, plan, plan.tasks[task_id], parts)
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
    _mpi_worker(comm, ctx, plan, parts)
    thread.join()
    if error:
        raise error[0]


# ---------------------------------------------------------------------------------------------
# Entry point


def run_plan(plan: Plan, ctx, *, executor: str = "serial", workers: int | None = None, comm=None,
             progress: bool = True) -> RunSummary | None:
    """Run every missing task of ``plan`` and write the dataset (rank 0 only under MPI).

    Returns the summary on the writing process, None on other MPI ranks.
    """
    study = plan.study
    parts = PartsFolder(plan)
    rank = comm.Get_rank() if comm is not None else 0
    if rank == 0:
        parts.open()
    if comm is not None:
        comm.Barrier()
    board = TaskBoard(plan, parts, study.run.retries, progress) if rank == 0 else None
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
    path = write_dataset(plan, parts, device=ctx.describe() if ctx is not None else "", run_info=board.run_info)
    if not board.failed:
        parts.remove()
    return RunSummary(path, len(board.done), len(board.failed), len(plan.tasks))


def write_dataset(plan: Plan, parts: PartsFolder, device: str, run_info: dict | None = None) -> Path:
    """Assemble the HDF5 dataset from the finished parts (one writer, atomic rename)."""
    if plan.is_fiber:
        from wavebrdf.jobs.fibers import write_fiber_dataset

        return write_fiber_dataset(plan, parts, device, run_info)
    study = plan.study
    output = Path(plan.config.output)
    with atomic_h5(output) as h5:
        writer = SurfaceDatasetWriter(
            h5, plan.config.sweep_axes, plan.wavelengths_um, plan.directions_deg, plan.grid.resolution,
            study.illumination.polarization, study.output_options.per_polarization,
        )
        writer.create(config_text=plan.config.text, study=study.name, software_version=__version__, device=device)
        shape = plan.config.case_shape
        for case, case_index in enumerate(np.ndindex(*shape) if shape else [()]):
            surface = plan.surface(case)
            writer.write_case(tuple(case_index), str(case), surface.z, surface.size_um, surface.statistics(),
                              plan.index(case))
            if case in plan.steering:
                writer.write_steering(tuple(case_index), plan.steering[case])
        rows = []
        for task in plan.tasks:
            row = {"id": task.id, "kind": task.kind, "case": task.case, "wavelength_index": task.wavelength,
                   "incidence_index": task.incidence, "basic_index": task.basic,
                   "patch": "x".join(map(str, task.patch)), **(run_info or {}).get(task.id, {})}
            failure = parts.failure(task)
            if failure is not None or not parts.done(task):
                rows.append({**row, "status": "failed", **(failure or {"error": "not run"})})
                continue
            if task.kind == "patch":
                rows.append({**row, "status": "done", **parts.load_diagnostics(task)})
                continue
            result = parts.load_result(task)
            pol = plan.config.cases[task.case].illumination.polarization
            brdf = result.brdf(pol)
            writer.write_result(task.case_index, task.wavelength, task.incidence, result.brdf_sp, brdf,
                                result.albedo_sp, float(albedo(brdf, plan.grid)))
            rows.append({**row, "status": "done", **result.diagnostics})
        writer.write_tasks(rows)
    return output
