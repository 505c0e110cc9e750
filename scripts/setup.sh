#!/usr/bin/env bash
# Sets up everything the project needs on a fresh Debian machine: apt packages (libllvm19 for Mitsuba's
# llvm variants), the virtual environment at .venv, torch (CPU wheel, pinned), mitsuba, drjit and the
# project itself (with its `holo` command in .venv/bin). Safe to run again: it skips what is done.
set -euo pipefail
cd "$(dirname "$0")/.."

SUDO=""
if [ "$(id -u)" != "0" ] && command -v sudo >/dev/null 2>&1; then SUDO="sudo"; fi

if ! ls /usr/lib/llvm-19/lib/libLLVM.so.19* >/dev/null 2>&1 && ! dpkg -s libllvm19 >/dev/null 2>&1; then
  echo "[setup] installing libllvm19 (Mitsuba llvm variants need LLVM >= 16)"
  $SUDO apt-get update -qq || true
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libllvm19 >/dev/null
fi

if ! command -v strace >/dev/null 2>&1; then
  echo "[setup] installing strace (the bundle tests trace which files Mitsuba opens)"
  $SUDO apt-get update -qq || true
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq strace >/dev/null || echo "[setup] strace not installed"
fi

if ! command -v chromium >/dev/null 2>&1 || ! command -v chromedriver >/dev/null 2>&1; then
  echo "[setup] installing chromium and chromium-driver (tests/service/test_web.py drives the web page in them)"
  $SUDO apt-get update -qq || true
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq chromium chromium-driver >/dev/null \
    || echo "[setup] chromium not installed: the browser test will be skipped"
fi

PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  echo "[setup] creating .venv"
  $PY -m venv .venv
fi
VPY=.venv/bin/python
$VPY -m pip install -q --upgrade pip >/dev/null
# torch first and pinned: the CPU wheel on this machine; an unpinned torch would pull a CUDA build.
if ! $VPY -c "import torch" >/dev/null 2>&1; then
  echo "[setup] installing torch==2.13.0"
  $VPY -m pip install -q "torch==2.13.0"
fi
echo "[setup] installing holocore and its dependencies"
$VPY -m pip install -q -e ".[all]"
echo "[setup] done: $($VPY -c 'import torch, mitsuba, drjit; print("torch", torch.__version__, "mitsuba", mitsuba.__version__, "drjit", drjit.__version__)')"
