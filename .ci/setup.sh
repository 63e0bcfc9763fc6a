#!/usr/bin/env bash
# Set up the project from scratch: system packages (Debian, when root), a virtualenv in
# .venv, a torch build that fits the machine, and the project itself (editable, with test deps).
# Idempotent: a second run only checks what is there.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}

# System packages (Debian, when root and missing): venv support if the Python lacks it, and what the explorer's
# Qt/VTK stack needs to draw under an X server (Xvfb for CI and screenshots; each one was needed).
SYSTEM_PACKAGES=(xvfb xauth libegl1 libglib2.0-0 libdbus-1-3 libfontconfig1 libxkbcommon-x11-0
                 libxcb-cursor0 libxcb-icccm4 libxcb-image0 libxcb-keysyms1 libxcb-render-util0 libxcb-shape0)
if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
  missing=()
  for p in "${SYSTEM_PACKAGES[@]}"; do dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p"); done
  # python3-venv only where this Python has no venv module (a non-Debian Python brings its own)
  "$PY" -m venv --help >/dev/null 2>&1 || missing+=(python3-venv)
  if [ ${#missing[@]} -gt 0 ]; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}"
  fi
fi

[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip >/dev/null 2>&1 || true

# torch: the pinned release. Where it lies on disk as a CPU build (these machines) pip takes
# that file; elsewhere set LRR_TORCH_INDEX (e.g. PyTorch's CPU wheel index) to avoid a CUDA download.
if ! .venv/bin/python -c "import torch" >/dev/null 2>&1; then
  if [ -n "${LRR_TORCH_INDEX:-}" ]; then
    .venv/bin/pip install -q "torch==2.13.0" --index-url "$LRR_TORCH_INDEX"
  else
    .venv/bin/pip install -q "torch==2.13.0"
  fi
fi
.venv/bin/pip install -q -e ".[test,gui]"
echo "setup done: $(.venv/bin/python -c 'import torch, anny; print("torch", torch.__version__, "| anny", anny.__version__ if hasattr(anny, "__version__") else "0.6.2")')"
