#!/bin/bash
# SLURM batch script written by `wavebrdf submit` for study @STUDY@.
# Submit with: sbatch @SCRIPT@
@DIRECTIVES@
# (SLURM reads #SBATCH lines only above the first command.)
# Plan: @PLAN@
# Finished tasks are kept in @PARTS@/: a job stopped at its time limit is requeued and resumes;
# submitting this script again after the study finished only prints "up to date".
@PRELUDE@

mpi_plugin=@MPI@
if [ "$mpi_plugin" = auto ]; then  # the MPI plugin of this cluster's srun
  case "$(srun --mpi=list 2>&1 || true)" in
    *pmi2*) mpi_plugin=pmi2 ;;  # MPICH, including the PyPI mpich wheel
    *pmix*) mpi_plugin=pmix ;;
    *) mpi_plugin=none ;;
  esac
fi
launcher=@LAUNCHER@
launch() {
  if [ "$launcher" = srun ]; then
    srun --mpi="$mpi_plugin" --cpus-per-task=@THREADS@ "$@"
  else
    mpiexec -n "$((SLURM_NNODES * @RANKS@))" "$@"
  fi
}

# SLURM sends USR1 to this shell @LEAD@ s before the time limit (--signal=B:USR1@@LEAD@): the run
# stops (finished tasks are kept) and the job is requeued (--requeue), so it resumes.
stop_and_requeue() {
  echo "wavebrdf: time limit near: stopping the run, requeueing job ${SLURM_JOB_ID}" >&2
  kill -TERM "$run_pid" 2>/dev/null || true
  wait "$run_pid" 2>/dev/null || true
  @REQUEUE@
  exit 0
}
trap stop_and_requeue USR1

launch @WAVEBRDF@ run @CONFIG@ --quiet @RUN_ARGS@ &
run_pid=$!
status=0
wait "$run_pid" || status=$?
@AFTER@
exit "$status"
