#!/bin/bash
# SLURM batch script written by `wavebrdf submit` for study @STUDY@.
# Submit with: sbatch @SCRIPT@
@DIRECTIVES@
# (SLURM reads #SBATCH lines only above the first command.)
# Plan: @PLAN@
# Finished tasks are kept in @PARTS@/: a job stopped at its time limit resumes when requeued
# or submitted again; submitting this script after the study finished only prints "up to date"
# (and makes the pictures if a stop left them unmade).
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
if [ "$launcher" = srun ]; then  # an array, so the launcher itself is the background job below
  launch=(srun --mpi="$mpi_plugin" --cpus-per-task=@THREADS@)
else
  launch=(mpiexec -n "$((SLURM_NNODES * @RANKS@))")
fi

# SLURM sends USR1 to this shell @LEAD@ s before the time limit (--signal=B:USR1@@LEAD@; it may
# come up to 60 s earlier): every rank gets SIGTERM (under srun from `scancel --signal=TERM`, which
# signals the job's steps, not this shell; a SIGTERM to srun itself would kill them), stops after
# the step it is on (finished tasks are kept) and exits with status 143; then @STOP_WORD@.
stop_at_time_limit() {
  echo "wavebrdf: time limit near: stopping the ranks of job ${SLURM_JOB_ID}" >&2
  stopping=1
  if [ "$launcher" = srun ]; then
    scancel --signal=TERM "${SLURM_JOB_ID}"
  else
    kill -TERM "$run_pid" 2>/dev/null || true
  fi
}
stopping=0
trap stop_at_time_limit USR1

"${launch[@]}" @WAVEBRDF@ run @CONFIG@ --quiet @RUN_ARGS@ &
run_pid=$!
status=0
wait "$run_pid" || status=$?
while [ "$stopping" = 1 ]; do  # USR1 interrupted the wait: wait for the ranks to stop
  stopping=2
  again=0
  wait "$run_pid" || again=$?
  [ "$again" -eq 127 ] || status=$again  # 127: it had already been waited for
done
if [ "$stopping" != 0 ] && [ "$status" -ne 0 ]; then
  echo "wavebrdf: the ranks stopped (exit status ${status})" >&2
@STOPPED@
fi
@AFTER@
exit "$status"
