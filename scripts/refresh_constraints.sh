#!/usr/bin/env bash
# Rewrites constraints.txt with the newest releases that pyproject.toml's ranges allow: a new
# virtualenv, an install without constraints, then pip freeze. Run it on purpose, then run the
# tests (bash scripts/test.sh) before committing the new pins.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
VENV=$(mktemp -d)/venv
trap 'rm -rf "$(dirname "$VENV")"' EXIT
"$PY" -m venv "$VENV"
"$VENV/bin/python" -m pip install --quiet "torch==2.13.0"
"$VENV/bin/python" -m pip install --quiet -e ".[test]"
{
    echo "# Every package vgpl installs, pinned: scripts/install.sh passes this file to pip as -c."
    echo "# Rewritten by scripts/refresh_constraints.sh (the newest releases pyproject.toml allows), never by hand."
    echo "# torch is not pinned here: scripts/install.sh installs 2.13.0 (CPU) where none is present."
    "$VENV/bin/python" -m pip freeze --exclude-editable | grep -viE '^(torch|nvidia-[a-z0-9-]+|triton)==' | LC_ALL=C sort -f
} > constraints.txt
echo "constraints.txt: $(grep -vc '^#' constraints.txt) pins"
