#!/bin/bash
# SLURM batch script written by `wavebrdf submit` for study 'gsbig'.
# Submit with: sbatch gsbig.slurm.sh
#SBATCH --job-name=gsbig
#SBATCH --nodes=1
#SBATCH --ntasks-per-node=2
#SBATCH --cpus-per-task=1
#SBATCH --mem=1500M
#SBATCH --time=0-00:10:00
#SBATCH --signal=B:USR1@120
#SBATCH --open-mode=append
#SBATCH --requeue
#SBATCH --output=gsbig-%j.log
#SBATCH --partition=a
# (SLURM reads #SBATCH lines only above the first command.)
# Plan: 40 task(s), largest 0.14 GiB, about 1 min 9 s on 1 node(s) x 2 rank(s) x 1 thread(s)
# Finished tasks are kept in out/probe_batch/gsbig.h5.parts/: a job stopped at its time limit resumes when requeued
# or submitted again; submitting this script after the study finished only prints "up to date"
# (and makes the pictures if a stop left them unmade).
set -uo pipefail
cd /work/main
# --- prologue ([run] prologue / --prologue: module loads, venv activation) ---
:
# ---
export PATH=/work/main/.venv/bin:$PATH
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 

mpi_plugin=auto
if [ "$mpi_plugin" = auto ]; then  # the MPI plugin of this cluster's srun
  case "$(srun --mpi=list 2>&1 || true)" in
    *pmi2*) mpi_plugin=pmi2 ;;  # MPICH, including the PyPI mpich wheel
    *pmix*) mpi_plugin=pmix ;;
    *) mpi_plugin=none ;;
  esac
fi
launcher=srun
if [ "$launcher" = srun ]; then  # an array, so the launcher itself is the background job below
  launch=(srun --mpi="$mpi_plugin" --cpus-per-task=1)
else
  launch=(mpiexec -n "$((SLURM_NNODES * 2))")
fi

# SLURM sends USR1 to this shell 120 s before the time limit (--signal=B:USR1@120; it may
# come up to 60 s earlier): every rank gets SIGTERM (under srun from `scancel --signal=TERM`, which
# signals the job's steps, not this shell; a SIGTERM to srun itself would kill them), stops after
# the step it is on (finished tasks are kept) and exits with status 143; then the job is requeued (--requeue) and resumes.
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

"${launch[@]}" /work/main/.venv/bin/wavebrdf run /work/main/out/probe_batch/gsbig.toml --quiet  &
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
  echo "wavebrdf: requeueing job ${SLURM_JOB_ID}: it resumes from the finished tasks" >&2
  scontrol requeue "${SLURM_JOB_ID}"
  exit 0
fi
:
exit "$status"
