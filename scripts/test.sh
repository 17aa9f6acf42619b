#!/usr/bin/env bash
# The test command: a new virtualenv (.venv-test) with the pinned packages, ruff, then pytest.
# Arguments go to pytest: bash scripts/test.sh -m "not slow" for the fast tier.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh .venv-test
.venv-test/bin/python -m ruff check .
exec .venv-test/bin/python -m pytest -q "$@"
