# The part every batch script shares: strict mode, working folder, prologue, environment.
set -uo pipefail
cd @CWD@
# --- prologue ([run] prologue / --prologue: module loads, venv activation) ---
@PROLOGUE@
# ---
export PATH=@BINDIR@:$PATH
export OMP_NUM_THREADS=@THREADS@ OPENBLAS_NUM_THREADS=@THREADS@ @EXPORTS@
