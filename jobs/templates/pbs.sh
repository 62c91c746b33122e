#!/bin/bash
# PBS (PBS Pro / OpenPBS / Torque) batch script written by `wavebrdf submit --scheduler pbs` for
# study @STUDY@. Submit with: qsub @SCRIPT@
@DIRECTIVES@
# (PBS reads #PBS lines only above the first command.)
# Plan: @PLAN@
# Finished tasks are kept in @PARTS@/: a job stopped at its walltime (PBS sends SIGTERM, then
# SIGKILL after its kill_delay) resumes when rerun (#PBS -r y) or submitted again.
@PRELUDE@
export SLURM_CPUS_PER_TASK=@THREADS@  # threads per rank for wavebrdf (PBS has no per-rank variable)

stop() {
  echo "wavebrdf: walltime reached: stopping the run (finished tasks are kept)" >&2
  kill -TERM "$run_pid" 2>/dev/null || true
}
trap stop TERM

mpiexec -n @TOTAL_RANKS@ @WAVEBRDF@ run @CONFIG@ --quiet @RUN_ARGS@ &
run_pid=$!
status=0
wait "$run_pid" || status=$?
if kill -0 "$run_pid" 2>/dev/null; then wait "$run_pid" || true; fi
@AFTER@
exit "$status"
