#!/usr/bin/env bash
# Every kernel of kernels/*.cl once on small inputs under Oclgrind (a simulated OpenCL device):
# invalid memory accesses, data races and API misuse, with a GPU's limits (work-groups <= 256,
# 48 KiB local memory); then the kernels launched with explicit work-groups at <= 4.
# Exit status 1 on any report. Needs `apt-get install oclgrind`.
#
#   bash tools/oclgrind-check.sh            # about 5 min on 2 cores
#   PYTHON=python3 bash tools/oclgrind-check.sh
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-.venv/bin/python}
command -v oclgrind >/dev/null || { echo "oclgrind is not installed (apt-get install oclgrind)" >&2; exit 2; }
"$PYTHON" tools/kernel_check.py --oclgrind
"$PYTHON" tools/kernel_check.py --oclgrind --max-wgsize 4 --cases bem-dense,bem-aim
