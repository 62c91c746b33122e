#!/usr/bin/env bash
# One-command set-up on a fresh Debian/Ubuntu machine: system OpenCL (PoCL) + a virtual
# environment in .venv with wavebrdf and its test/MPI dependencies.
#
#   bash tools/setup.sh            # system PoCL via apt (needs root or sudo), then .venv
#   WAVEBRDF_POCL=pip bash tools/setup.sh   # no root: PoCL from the pocl-binary-distribution wheel
#   WAVEBRDF_INTEL=1 bash tools/setup.sh    # also Intel's CPU OpenCL runtime (tools/intel-opencl.sh)
#
# Environment knobs: PYTHON (interpreter, default python3), VENV (default .venv),
# WAVEBRDF_EXTRAS (pip extras, default dev).
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
VENV=${VENV:-.venv}
EXTRAS=${WAVEBRDF_EXTRAS:-dev}
POCL=${WAVEBRDF_POCL:-auto}

have_apt_root() {
    command -v apt-get >/dev/null 2>&1 || return 1
    [ "$(id -u)" = 0 ] && return 0
    command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null
}

if [ "$POCL" = auto ]; then
    if [ -e /etc/OpenCL/vendors/pocl.icd ]; then POCL=present
    elif have_apt_root; then POCL=apt
    else POCL=pip
    fi
fi

if [ "$POCL" = apt ]; then
    SUDO=""; [ "$(id -u)" = 0 ] || SUDO=sudo
    echo "[setup] installing PoCL (CPU OpenCL), OpenCL headers and Oclgrind (the kernel checker) with apt"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends \
        pocl-opencl-icd ocl-icd-opencl-dev binutils oclgrind >/dev/null
fi

# Mitsuba 3's llvm variants (the JIT backend of wavebrdf.mitsuba) need libLLVM >= 17; without it
# the plugin uses the scalar variants (tests/test_mitsuba*.py say so)
if ! compgen -G "/usr/lib/*/libLLVM.so.1[7-9]*" >/dev/null && ! compgen -G "/usr/lib/*/libLLVM-1[7-9]*.so*" >/dev/null \
        && have_apt_root; then
    SUDO=""; [ "$(id -u)" = 0 ] || SUDO=sudo
    echo "[setup] installing libLLVM 19 with apt (Mitsuba's llvm variants)"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends libllvm19 >/dev/null \
        || echo "[setup] libllvm19 is not available here: Mitsuba will use its scalar variants"
fi

if [ "$POCL" = pip ]; then
    echo "[setup] no root/apt: PoCL comes from the pocl-binary-distribution wheel"
    EXTRAS="$EXTRAS,pocl"
fi

echo "[setup] creating $VENV and installing wavebrdf[$EXTRAS]"
"$PYTHON" -m venv "$VENV"
"$VENV/bin/python" -m pip install -q --upgrade pip
"$VENV/bin/python" -m pip install -q -e ".[$EXTRAS]"
"$VENV/bin/wavebrdf" devices
if [ "$EXTRAS" != "${EXTRAS#dev}" ]; then
    # xarray at the minimum versions pyproject allows, beside the main one: tests/test_conventions.py
    # opens every example dataset with it (no wavebrdf inside; it only reads the files)
    echo "[setup] creating $VENV/xarray-min (xarray and h5netcdf at their pinned minimum versions)"
    "$PYTHON" -m venv "$VENV/xarray-min"
    "$VENV/xarray-min/bin/python" -m pip install -q -r tools/xarray-min.txt
fi
if [ "${WAVEBRDF_INTEL:-0}" = 1 ]; then
    VENV="$VENV" bash tools/intel-opencl.sh
fi
echo "[setup] done: activate with 'source $VENV/bin/activate'"
