#!/usr/bin/env bash
# Set up the project from scratch: system packages (Debian, when root), a virtualenv in
# .venv, a torch build that fits the machine, and the project itself (editable, with test deps).
# Idempotent: a second run only checks what is there.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}

# System packages: none are needed by the model package yet beyond a Python with venv;
# the explorer's GUI packages are added here when it lands.
SYSTEM_PACKAGES=(python3-venv)
if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
  missing=()
  for p in "${SYSTEM_PACKAGES[@]}"; do dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p"); done
  if ! "$PY" -m venv --help >/dev/null 2>&1 && [ ${#missing[@]} -gt 0 ]; then
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
.venv/bin/pip install -q -e ".[test]"
echo "setup done: $(.venv/bin/python -c 'import torch, anny; print("torch", torch.__version__, "| anny", anny.__version__ if hasattr(anny, "__version__") else "0.6.2")')"
