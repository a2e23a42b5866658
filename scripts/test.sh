#!/usr/bin/env bash
# Set up from nothing and run the default test suite (slow studies excluded; -m slow runs them).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/ruff check .
.venv/bin/python -m pytest -n 2 -q "$@"
