#!/usr/bin/env bash
# The CUDA path end to end: set up, then render the demo scene at 1080x1920 x 3 x 24 to 80%
# convergence, encode and view it on the GPU, printing times, GPU memory and the ratio to the CPU figures
# (bench/results/cpu_fullscale.json). One prepared script for a bare GPU machine with Python 3.12.
#
#   bash bench/device_check.sh --dry-run          # here, on the CPU, at 96x128 x 2 frames, with .venv
#   bash bench/device_check.sh                    # a GPU machine with network: venv, torch (CUDA), mitsuba, ...
#   bash bench/device_check.sh --wheelhouse DIR   # a GPU machine without network: install from wheels in DIR
#   bash bench/device_check.sh --python python3   # use an interpreter that already has CUDA torch
#   bash bench/device_check.sh --fetch-wheels DIR # on a connected machine: download those wheels (cp312)
# Anything after -- goes to bench/device_check.py (e.g. -- --iterations 100 --convergence 0.5).
# Environment: TORCH_INDEX (default https://download.pytorch.org/whl/cu128), VENV (default .venv-gpu).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
DRY=0; PY=""; WHEELS=""; FETCH=""; EXTRA=()
while [[ $# -gt 0 ]]; do
  case "$1" in
    --dry-run) DRY=1 ;;
    --python) PY="$2"; shift ;;
    --wheelhouse) WHEELS="$2"; shift ;;
    --fetch-wheels) FETCH="$2"; shift ;;
    --) shift; EXTRA=("$@"); break ;;
    *) echo "device_check.sh: unknown option $1" >&2; exit 2 ;;
  esac
  shift
done
# What the project needs beside torch (pyproject's core extra and base dependencies).
PKGS=("mitsuba>=3.6,<4" "drjit>=1.0,<2" "numpy>=1.24" "pydantic>=2.5" "typer>=0.12" "rich>=13" "pillow>=10" "scipy>=1.10")

if [[ -n "$FETCH" ]]; then
  mkdir -p "$FETCH"
  python3 -m pip download --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
    -d "$FETCH" "${PKGS[@]}"
  echo "wheels in $FETCH (torch not included: use the GPU machine's own or add its CUDA wheel)"
  exit 0
fi

if [[ $DRY == 1 ]]; then
  PY="${PY:-$ROOT/.venv/bin/python}"
  exec env HOLO_DEVICE=cpu "$PY" "$ROOT/bench/device_check.py" --dry-run "${EXTRA[@]}"
fi

t0=$(date +%s)
if [[ -z "$PY" ]]; then
  if python3 -c 'import torch, sys; sys.exit(0 if torch.cuda.is_available() else 1)' 2>/dev/null; then
    PY="$(command -v python3)"      # an image with CUDA torch already (the lab's GPU box, the lent machine)
  else
    VENV="${VENV:-$ROOT/.venv-gpu}"
    [[ -x "$VENV/bin/python" ]] || python3.12 -m venv "$VENV"
    PY="$VENV/bin/python"
    "$PY" -m pip install -q --upgrade pip
    "$PY" -m pip install -q torch --index-url "${TORCH_INDEX:-https://download.pytorch.org/whl/cu128}"
  fi
fi
if ! "$PY" -c 'import mitsuba, drjit, pydantic, typer, rich, PIL, scipy' 2>/dev/null; then
  if [[ -n "$WHEELS" ]]; then
    "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/holo-site "$WHEELS"/*.whl
    export PYTHONPATH="/tmp/holo-site${PYTHONPATH:+:$PYTHONPATH}"
  else
    "$PY" -m pip install -q "${PKGS[@]}"
  fi
fi
export PYTHONPATH="$ROOT${PYTHONPATH:+:$PYTHONPATH}"   # the project itself, from this checkout
echo "set-up: $(( $(date +%s) - t0 )) s"
command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
"$PY" -c 'import torch, mitsuba as mi; print("torch", torch.__version__, "cuda", torch.cuda.is_available(), "| mitsuba", mi.__version__, [v for v in mi.variants() if "cuda" in v])'
exec env HOLO_DEVICE=cuda PYTHONUNBUFFERED=1 "$PY" "$ROOT/bench/device_check.py" --device cuda "${EXTRA[@]}"
