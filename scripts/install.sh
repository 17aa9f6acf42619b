#!/usr/bin/env bash
# Installs vgpl and its test dependencies, with every package pinned by constraints.txt.
#
#   bash scripts/install.sh DIR   a new virtualenv at DIR (one already there is replaced), then install into it
#   bash scripts/install.sh       install into the current Python environment (a conda env, a CUDA build of torch)
#
# torch is the one package constraints.txt does not pin: where no torch is present, the CPU build of
# 2.13.0 is installed first (an unpinned `torch` would pull several GB of CUDA packages); a torch that
# is present, such as a CUDA build on a GPU machine, is left in place.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ $# -gt 1 ]; then
    echo "usage: bash scripts/install.sh [VENV_DIR]" >&2
    exit 2
fi
if [ $# -eq 1 ]; then
    "$PY" -m venv --clear "$1"
    PY="$1/bin/python"
fi
if ! "$PY" -c "import torch" >/dev/null 2>&1; then
    "$PY" -m pip install --quiet "torch==2.13.0" \
        || "$PY" -m pip install --quiet "torch>=2.4"
fi
"$PY" -m pip install --quiet -c constraints.txt -e ".[test]"
"$PY" - <<'PYEOF'
import importlib.metadata as md
import sys

names = ["torch", "lightning", "torch-geometric", "hydra-core", "h5py", "numpy", "pytest"]
print(f"vgpl installed into {sys.prefix} (Python {sys.version.split()[0]}, {len(list(md.distributions()))} packages): "
      + ", ".join(f"{n} {md.version(n)}" for n in names))
PYEOF
