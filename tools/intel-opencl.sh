#!/usr/bin/env bash
# Intel's CPU OpenCL runtime from PyPI (no root) as a second OpenCL implementation beside PoCL.
#
#   bash tools/intel-opencl.sh            # pip install wavebrdf's [test-opencl] extra into .venv
#                                         # and write .venv/etc/OpenCL/intel/intel-cpu.icd
#   OCL_ICD_VENDORS=$PWD/.venv/etc/OpenCL/intel .venv/bin/python -m pytest tests/test_models.py
#
# The wheel's own ICD file names a placeholder path (/opt/anaconda1anaconda2anaconda3/...), so
# the loader is pointed at a folder holding one that names the installed libintelocl.so.
# Environment knobs: VENV (default .venv); WAVEBRDF_INTEL_INSTALL=0 only writes the ICD file.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
if [ "${WAVEBRDF_INTEL_INSTALL:-1}" != 0 ]; then
    echo "[intel-opencl] installing intel-opencl-rt and intel-cmplr-lib-rt into $VENV"
    "$VENV/bin/python" -m pip install -q -e ".[test-opencl]"
fi
prefix=$(cd "$VENV" && pwd)
library="$prefix/lib/libintelocl.so"
[ -e "$library" ] || { echo "[intel-opencl] $library is missing: install the [test-opencl] extra" >&2; exit 1; }
mkdir -p "$prefix/etc/OpenCL/intel"
echo "$library" > "$prefix/etc/OpenCL/intel/intel-cpu.icd"
OCL_ICD_VENDORS="$prefix/etc/OpenCL/intel" "$VENV/bin/wavebrdf" devices
echo "[intel-opencl] select it with: export OCL_ICD_VENDORS=$prefix/etc/OpenCL/intel"
