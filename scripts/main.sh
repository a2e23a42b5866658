#!/usr/bin/env bash
# Set up from nothing and run the main job: the reduced Padgett PQRM Monte Carlo study
# (P §2.3.1; report.md + figures) and the operator-table report, under out/main/.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
OUT=${OUT:-out/main}
.venv/bin/pqrm-jax study padgett-mc --reduced --out "$OUT/padgett-mc"
.venv/bin/pqrm-jax tables --plot "$OUT/tables"
echo "reports: $OUT/padgett-mc/report.md $OUT/tables/report.md"
