#!/usr/bin/env bash
# Installs vgpl and its test dependencies into the current Python environment.
# A CPU build of PyTorch is installed first where no torch is present: an unpinned
# `torch` would pull several GB of CUDA packages.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if ! "$PY" -c "import torch" >/dev/null 2>&1; then
    "$PY" -m pip install --quiet "torch==2.13.0" \
        || "$PY" -m pip install --quiet "torch>=2.4"
fi
"$PY" -m pip install --quiet -e ".[test]"
