#!/bin/sh
# Install everything ns2codegen needs (every extra, editable) on a fresh Debian-like machine:
# Python packages (torch pinned to the local CPU wheel first) and, when
# missing, the ARM cross toolchain and QEMU (apt-get, needs root).
set -eu
PYTHON=${PYTHON:-python3}
if ! "$PYTHON" -c "import torch" 2>/dev/null; then
    "$PYTHON" -m pip install "torch==2.13.0"
fi
"$PYTHON" -m pip install -e ".[all,test,bench]"
if ! command -v arm-none-eabi-gcc >/dev/null 2>&1 || ! command -v qemu-system-arm >/dev/null 2>&1; then
    SUDO=""
    [ "$(id -u)" -eq 0 ] || SUDO="sudo"
    $SUDO apt-get update
    $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y \
        gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm
fi
