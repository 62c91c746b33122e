"""What this process may use on its node: CPUs (affinity, ``SLURM_CPUS_PER_TASK``, a user's
``OMP_NUM_THREADS``), its local rank among the node's ranks (from the launcher's environment) and
so its GPU, and the environment that bounds a worker's threads to its share
(:func:`worker_environment`). Read before MPI or OpenCL start; nothing here imports them."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["LOCAL_RANK_VARIABLES", "allowed_cpus", "apply_worker_environment", "local_rank", "threads_per_rank",
           "worker_environment"]

# launcher variables naming this process's rank among the ranks of its node, in order of trust
LOCAL_RANK_VARIABLES = ("SLURM_LOCALID", "OMPI_COMM_WORLD_LOCAL_RANK", "MPI_LOCALRANKID", "PMI_LOCAL_RANK",
                        "PMIX_LOCAL_RANK", "MV2_COMM_WORLD_LOCAL_RANK", "PALS_LOCAL_RANKID", "WAVEBRDF_LOCAL_RANK")


def allowed_cpus() -> int:
    """CPUs this process may run on (its affinity mask; the CPU count where there is none)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - non-Linux
        return max(1, os.cpu_count() or 1)


def threads_per_rank(ranks_on_node: int, environ: dict | None = None, cpus: int | None = None) -> int:
    """Threads for one of ``ranks_on_node`` ranks (or worker processes) of a node.

    ``SLURM_CPUS_PER_TASK`` when set (SLURM gave each task that many CPUs), else the affinity
    mask shared by the node's ranks; a user's ``OMP_NUM_THREADS`` lowers it; never more than
    the CPUs this process may run on, never less than 1."""
    env = os.environ if environ is None else environ
    cpus = cpus or allowed_cpus()
    slurm = _positive_int_from(env, "SLURM_CPUS_PER_TASK")
    threads = slurm if slurm is not None else cpus // max(1, ranks_on_node)
    user = _positive_int_from(env, "OMP_NUM_THREADS")
    if user is not None:
        threads = min(threads, user)
    return max(1, min(threads, cpus))


def _positive_int_from(env, name: str) -> int | None:
    text = str(env.get(name, "")).strip()
    try:
        value = int(text.split("(")[0])
    except ValueError:
        return None
    return value if value >= 1 else None


def local_rank(environ: dict | None = None) -> int:
    """This process's rank among the ranks of its node (0 without a launcher)."""
    env = os.environ if environ is None else environ
    for name in LOCAL_RANK_VARIABLES:
        value = _positive_int_from(env, name)
        if value is not None or str(env.get(name, "")).strip() == "0":
            return value or 0
    return 0


def worker_environment(workers_on_node: int, rank: int, cores: int | None = None) -> dict[str, str]:
    """Environment for one of ``workers_on_node`` workers of a node: bounded threads
    (:func:`threads_per_rank`: the CPU affinity or ``SLURM_CPUS_PER_TASK``, a user's
    ``OMP_NUM_THREADS``) and the node's shared kernel cache (``POCL_CACHE_DIR``, built once, see
    :meth:`~wavebrdf.solver.opencl.ComputeContext.program`). ``rank`` is kept for callers.

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
