#!/usr/bin/env bash
# One-command set-up on a fresh Debian/Ubuntu machine: system OpenCL (PoCL) + a virtual
# environment in .venv with wavebrdf and its test/MPI dependencies.
#
#   bash tools/setup.sh            # system PoCL via apt (needs root or sudo), then .venv
#   WAVEBRDF_POCL=pip bash tools/setup.sh   # no root: PoCL from the pocl-binary-distribution wheel
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
    echo "[setup] installing PoCL (CPU OpenCL) and OpenCL headers with apt"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends \
        pocl-opencl-icd ocl-icd-opencl-dev binutils >/dev/null
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
echo "[setup] done: activate with 'source $VENV/bin/activate'"
