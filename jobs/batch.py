"""What ``run`` and ``plan`` decide before any work: shards, "up to date", workers per node,
a clean stop on SIGTERM (a batch system's time limit)."""

from __future__ import annotations

import signal
import sys
from wavebrdf.jobs.node import allowed_cpus

__all__ = ["RunScope", "run_scope", "stop_on_sigterm", "workers_per_node"]


class RunScope:
    """The config a run works on (a shard's output for ``--shard``) and the shard's task ids."""

    def __init__(self, config, only=None, shard=None):
        self.config, self.only, self.shard = config, only, shard


def run_scope(args, config) -> RunScope | None:
    """The run's scope, or None (after printing "up to date") when there is nothing to do: the
    output already holds this plan's complete results (jobs/finished.py; ``--force`` recomputes).
    A changed config is refused (ResumeError naming what changed)."""
    from wavebrdf.jobs.finished import up_to_date
    from wavebrdf.jobs.plan import plan_study
    from wavebrdf.jobs.shards import parse_shard, shard_output, shard_tasks, with_output

    force = getattr(args, "force", False)
    plan = plan_study(config)
    if up_to_date(plan, force):
        print(f"{config.output} is up to date ({len(plan.tasks)} tasks done; --force recomputes it)",
              file=sys.stderr)
        return None
    if not getattr(args, "shard", None):
        return RunScope(config)
    index, shards = parse_shard(args.shard)
    config = with_output(config, shard_output(config.output, index, shards))
    return RunScope(config, shard_tasks(plan, index, shards), (index, shards))


def workers_per_node(executor: str, requested: int | None, study, launch=None) -> int:
    """Tasks at once on this node, the same for ``plan`` and ``run``: MPI ranks on the node;
    ``processes``: ``--workers``, ``[run] workers``, else the CPUs this process may use; serial 1."""
    if executor == "mpi":
        return launch.local_size if launch else (requested or study.run.workers or 1)
    if executor == "processes":
        return requested or study.run.workers or allowed_cpus()
    return 1


def stop_on_sigterm() -> None:
    """SIGTERM (a batch system stopping the job) ends the run like Ctrl-C: finished tasks are
    kept, the lock is released, exit status 130, and the next run resumes."""
    def stop(signum, frame):
        raise KeyboardInterrupt

    try:
        signal.signal(signal.SIGTERM, stop)
    except ValueError:  # not the main thread (the CLI called from a library)
        pass
