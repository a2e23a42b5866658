#!/usr/bin/env bash
# Set up from nothing and run the main job: the default study, writing a report with plots.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
OUT=${OUT:-out/main}
.venv/bin/pqrm-jax tables --plot "$OUT/tables"
echo "report: $OUT/tables/report.md"
