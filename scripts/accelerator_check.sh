#!/usr/bin/env bash
# Accelerator readiness check (issue 19 item 2): the PQRM, tables, QRM, SERGE and compositions
# benchmarks in reduced form and one reduced padgett-mc study, on whatever device JAX finds
# (set JAX_PLATFORMS=cpu to force the CPU), all written into ONE JSON.
#
#   bash scripts/accelerator_check.sh [OUT.json]     # default benchmarks/results/accelerator_check_<backend>.json
#
# Each step has its own time limit (STEP_S, default 60 s; QRM_S 150 s; SERGE_S 75 s; the study
# STUDY_S 60 s: at most 465 s in all) so the whole check stays under 8 minutes; a step that fails or times out is recorded as such
# (rc, timed_out, the tail of its log) and the check goes on. Every step's JSON carries
# "env" (backend, device kind; benchmarks/_env.py).
set -uo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-.venv/bin/python}
[ -x "$PY" ] || PY=python3
STEP_S=${STEP_S:-60}
QRM_S=${QRM_S:-150}
SERGE_S=${SERGE_S:-75}
STUDY_S=${STUDY_S:-60}
WORK=$(mktemp -d "${TMPDIR:-/tmp}/pqrm-accel.XXXXXX")
trap 'rm -rf "$WORK"' EXIT
T0=$(date +%s)

step() {  # step NAME LIMIT_S command...
  local name=$1 limit=$2; shift 2
  local t0 rc
  t0=$(date +%s%N)
  timeout --kill-after=5 "$limit" "$@" >"$WORK/$name.log" 2>&1
  rc=$?
  echo "$name $rc $(awk -v a="$(date +%s%N)" -v b="$t0" 'BEGIN{print (a-b)/1e9}')" >>"$WORK/steps.txt"
  printf '%-14s rc=%s\n' "$name" "$rc"
}

step pqrm "$STEP_S" "$PY" benchmarks/bench_pqrm.py --triplets 720 --samples 256 --study-runs 0 \
  --json "$WORK/pqrm.json"
step tables "$STEP_S" "$PY" benchmarks/bench_tables.py --repeat 1 --single-problems 10 \
  --random 48 --random-only --out "$WORK/tables.json"
step qrm "$QRM_S" "$PY" benchmarks/bench_qrm.py --quick --out "$WORK/qrm.json"
step serge "$SERGE_S" "$PY" benchmarks/bench_serge.py --trials 64 --seq-trials 4 --ref-trials 4 \
  --json "$WORK/serge.json"
step bsp "$STEP_S" "$PY" benchmarks/bench_bsp.py --quick --json "$WORK/bsp.json"
step compositions "$STEP_S" "$PY" benchmarks/bench_compositions.py --quick \
  --json "$WORK/compositions.json"
step study "$STUDY_S" "$PY" -m pqrm_jax.cli study padgett-mc --runs 20 --levels 2 \
  --quiet --out "$WORK/study"

"$PY" - "$WORK" "${1:-}" "$T0" <<'EOF'
import json, sys, time
from pathlib import Path

sys.path.insert(0, "benchmarks")
from _env import device_info  # noqa: E402

work, out, t0 = Path(sys.argv[1]), sys.argv[2], float(sys.argv[3])
env = device_info()
res = {"env": env, "steps": {}}
for line in (work / "steps.txt").read_text().split("\n"):
    if not line.strip():
        continue
    name, rc, secs = line.split()
    rc = int(rc)
    entry = {"rc": rc, "timed_out": rc in (124, 137), "wall_s": round(float(secs), 2)}
    src = work / ("study/timing.json" if name == "study" else f"{name}.json")
    if src.exists():
        entry["result"] = json.loads(src.read_text())
    if name == "study" and (work / "study/levels.jsonl").exists():
        lines = [json.loads(x) for x in (work / "study/levels.jsonl").read_text().split("\n") if x]
        entry["levels"] = [{"sigma_r": r["sigma_r"],
                            "edc_error": r["reps"]["edc"]["error_mean"],
                            "edc_entropy": r["reps"]["edc"]["entropy_mean"]} for r in lines]
    if rc != 0:
        entry["log_tail"] = (work / f"{name}.log").read_text()[-1500:]
    res["steps"][name] = entry
res["total_s"] = round(time.time() - t0, 1)
res["all_ok"] = all(s["rc"] == 0 for s in res["steps"].values())
path = Path(out or f"benchmarks/results/accelerator_check_{env['backend']}.json")
path.parent.mkdir(parents=True, exist_ok=True)
path.write_text(json.dumps(res, indent=1, default=float) + "\n")
print(f"{env['backend']} / {env['device_kind']}: all_ok={res['all_ok']} "
      f"total {res['total_s']} s -> {path}")
EOF
