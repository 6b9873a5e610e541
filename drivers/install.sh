#!/usr/bin/env bash
# Install the system side of polcam on Debian bookworm (idempotent).
#
#   Aravis 0.8 and its GObject-introspection typelib (the camera layer),
#   aravis-tools-cli (arv-tool-0.8) and aravis-tools (arv-fake-gv-camera-0.8, the
#   GigE Vision emulator the tests use), the PyGObject build dependencies, and
#   Python's venv/headers where the interpreter lacks them, and Chromium (headless,
#   for the tests that look at the Rerun web viewer).
#
# Usage: drivers/install.sh [--check]
#   --check  exit 0 if everything is installed, 1 otherwise; install nothing.
set -euo pipefail

PKGS=(gir1.2-aravis-0.8 aravis-tools-cli aravis-tools
      libgirepository1.0-dev libcairo2-dev pkg-config gcc chromium)

PY=${PYTHON:-python3}
if ! "$PY" -c 'import venv, ensurepip' >/dev/null 2>&1; then PKGS+=(python3-venv); fi
if ! "$PY" -c 'import os, sysconfig, sys; sys.exit(not os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")))' >/dev/null 2>&1; then
    PKGS+=(python3-dev)
fi

missing=()
for p in "${PKGS[@]}"; do
    if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
        missing+=("$p")
    fi
done

if [ "${1:-}" = "--check" ]; then
    [ ${#missing[@]} -eq 0 ]
    exit $?
fi
if [ ${#missing[@]} -eq 0 ]; then
    echo "drivers/install.sh: system packages already installed"
    exit 0
fi

SUDO=""
if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else
        echo "drivers/install.sh: need root or sudo to install: ${missing[*]}" >&2
        exit 1
    fi
fi
echo "drivers/install.sh: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
