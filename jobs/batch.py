"""What ``run`` decides before any work: shards, "up to date", a clean stop on SIGTERM (a batch
system's time limit). Workers per node are the executor's (jobs/executors.py)."""

from __future__ import annotations

import signal
import sys

from wavebrdf.jobs.finished import up_to_date
from wavebrdf.jobs.plan import plan_study
from wavebrdf.jobs.shards import parse_shard, shard_output, shard_tasks, with_output

__all__ = ["STOPPED_STATUS", "RunScope", "Stopped", "run_scope", "stop_on_sigterm"]


class RunScope:
    """The config a run works on (a shard's output for ``--shard``) and the shard's task ids."""

    def __init__(self, config, only=None, shard=None):
        self.config, self.only, self.shard = config, only, shard


def run_scope(args, config) -> RunScope | None:
    """The run's scope, or None (after printing "up to date") when there is nothing to do: the
    output already holds this plan's complete results (jobs/finished.py; ``--force`` recomputes).
    A changed config is refused (ResumeError naming what changed and ``args.force_flag``, how this
    caller forces a run: "--force" unless set)."""
    force, flag = getattr(args, "force", False), getattr(args, "force_flag", "--force")
    plan = plan_study(config)
    if up_to_date(plan, force, flag):
        print(f"{config.output} is up to date ({len(plan.tasks)} tasks done; {flag} recomputes it)",
              file=sys.stderr)
        return None
    if not getattr(args, "shard", None):
        return RunScope(config)
    index, shards = parse_shard(args.shard)
    config = with_output(config, shard_output(config.output, index, shards))
    return RunScope(config, shard_tasks(plan, index, shards), (index, shards))


class Stopped(KeyboardInterrupt):
    """SIGTERM: a batch system (or the batch script at its time limit) stopping the run."""


STOPPED_STATUS = 128 + signal.SIGTERM  # the exit status of a run stopped by SIGTERM (143)


def stop_on_sigterm() -> None:
    """SIGTERM (a batch system stopping the job) ends the run like Ctrl-C — finished tasks are
    kept, the lock is released, and the next run resumes — with exit status
    :data:`STOPPED_STATUS`; under MPI every rank stops so, without aborting the others."""
    def stop(signum, frame):
        raise Stopped

    try:
        signal.signal(signal.SIGTERM, stop)
    except ValueError:  # not the main thread (the CLI called from a library)
        pass
