#!/usr/bin/env bash
# Accelerator readiness check (issue 19 item 2, issue 31 item 7): every benchmark in reduced
# form (PQRM, padgett runner, tables, QRM, SERGE, compositions, BSP, Q-Link, HSSH cellular,
# HSSH global layout and re-localisation), one reduced padgett-mc study and the FULL padgett-mc
# study (--runs 1000, 24 levels), on whatever device JAX finds (set JAX_PLATFORMS=cpu to force
# the CPU), all written into ONE JSON.
#
#   bash scripts/accelerator_check.sh [OUT.json]     # default benchmarks/results/accelerator_check_<backend>.json
#
# Each step has its own time limit (STEP_S, default 90 s; QRM_S 150 s; SERGE_S 75 s; BSP_S 180 s;
# the reduced study STUDY_S 60 s; the full study FULL_S 300 s), and TOTAL_S (default 1200 s)
# bounds the whole check: a step gets at most what is left of it (less 15 s to write the JSON)
# and is recorded as skipped when under 10 s is left, so a check on a time-limited machine
# always writes its JSON. The steps the accelerator targets name come first (PQRM kernel,
# padgett runner, BSP batched vs loop at 256 environments — BSP_ARGS; 1 024 ran past 90 s on an
# H200 —, Q-Link, HSSH, the full study). Each step's wall time, user+system CPU seconds and peak
# memory are recorded (/usr/bin/time); a step that fails or times out is recorded as such (rc,
# timed_out, the tail of its log) and the check goes on. Every step's JSON carries "env" (where it ran:
# backend, device kind, host, load; benchmarks/_env.py). SKIP="bsp hssh ..." leaves steps out.
# The compilation cache is off (PQRM_JAX_COMPILE_CACHE=off): every step compiles cold.
# LOGS_TGZ=path.tgz keeps every step's log (and the studies' outputs) as one archive.
set -uo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-.venv/bin/python}
[ -x "$PY" ] || PY=python3
STEP_S=${STEP_S:-90}
QRM_S=${QRM_S:-150}
SERGE_S=${SERGE_S:-75}
STUDY_S=${STUDY_S:-60}
FULL_S=${FULL_S:-300}
TOTAL_S=${TOTAL_S:-1200}
BSP_S=${BSP_S:-180}
BSP_ARGS=${BSP_ARGS:---envs 256 --chunks 16 256}
SKIP=${SKIP:-}
export PQRM_JAX_COMPILE_CACHE=off
WORK=$(mktemp -d "${TMPDIR:-/tmp}/pqrm-accel.XXXXXX")
trap '[ -n "${LOGS_TGZ:-}" ] && tar czf "$LOGS_TGZ" -C "$WORK" .; rm -rf "$WORK"' EXIT
T0=$(date +%s)

step() {  # step NAME LIMIT_S command...
  local name=$1 limit=$2; shift 2
  local t0 rc left
  case " $SKIP " in *" $name "*) printf '%-14s skipped\n' "$name"; return;; esac
  left=$(( TOTAL_S - 15 - $(date +%s) + T0 ))
  if [ "$left" -lt 10 ]; then
    echo "$name skipped 0" >>"$WORK/steps.txt"; printf '%-14s skipped (TOTAL_S)\n' "$name"; return
  fi
  [ "$left" -lt "$limit" ] && limit=$left
  t0=$(date +%s%N)
  if [ -x /usr/bin/time ]; then
    /usr/bin/time -f "%e %U %S %M" -o "$WORK/$name.time" \
      timeout --kill-after=5 "$limit" "$@" >"$WORK/$name.log" 2>&1
  else
    timeout --kill-after=5 "$limit" "$@" >"$WORK/$name.log" 2>&1
  fi
  rc=$?
  echo "$name $rc $(awk -v a="$(date +%s%N)" -v b="$t0" 'BEGIN{print (a-b)/1e9}')" >>"$WORK/steps.txt"
  printf '%-14s rc=%s\n' "$name" "$rc"
}

step pqrm "$STEP_S" "$PY" benchmarks/bench_pqrm.py --triplets 7200 --samples 1024 \
  --study-runs 0 --out "$WORK/pqrm.json"
step padgett "$STEP_S" "$PY" benchmarks/bench_padgett.py --runs 100 --repeat 2 \
  --out "$WORK/padgett.json"
# shellcheck disable=SC2086
step bsp "$BSP_S" "$PY" benchmarks/bench_bsp.py $BSP_ARGS --out "$WORK/bsp.json"
step qlink "$STEP_S" "$PY" benchmarks/bench_qlink.py --quick --out "$WORK/qlink.json"
step hssh "$STEP_S" "$PY" benchmarks/bench_hssh.py --batch 16 --repeats 2 --out "$WORK/hssh.json"
step hssh_global "$STEP_S" "$PY" benchmarks/bench_hssh_global.py --quick \
  --out "$WORK/hssh_global.json"
step hssh_reloc "$STEP_S" "$PY" benchmarks/bench_hssh_reloc.py --quick --repeat 2 \
  --out "$WORK/hssh_reloc.json"
step study_full "$FULL_S" "$PY" -m pqrm_jax.cli study padgett-mc --runs 1000 \
  --quiet --out "$WORK/study_full"
step study "$STUDY_S" "$PY" -m pqrm_jax.cli study padgett-mc --runs 20 --levels 2 \
  --quiet --out "$WORK/study"
step compositions "$STEP_S" "$PY" benchmarks/bench_compositions.py --quick \
  --out "$WORK/compositions.json"
step tables "$STEP_S" "$PY" benchmarks/bench_tables.py --repeat 1 --single-problems 10 \
  --random 48 --random-only --out "$WORK/tables.json"
step serge "$SERGE_S" "$PY" benchmarks/bench_serge.py --trials 64 --seq-trials 4 --ref-trials 4 \
  --out "$WORK/serge.json"
step qrm "$QRM_S" "$PY" benchmarks/bench_qrm.py --quick --out "$WORK/qrm.json"

"$PY" - "$WORK" "${1:-}" "$T0" "$TOTAL_S" <<'EOF'
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
    if rc == "skipped":
        res["steps"][name] = {"skipped": "TOTAL_S exhausted"}
        continue
    rc = int(rc)
    entry = {"rc": rc, "timed_out": rc in (124, 137), "wall_s": round(float(secs), 2)}
    tfile = work / f"{name}.time"
    if tfile.exists() and len(tfile.read_text().split()) >= 4:
        wall, user, system, kb = tfile.read_text().split()[-4:]
        entry.update({"time_wall_s": float(wall), "cpu_s": round(float(user) + float(system), 2),
                      "max_rss_mb": round(int(kb) / 1024, 1)})
    study = name.startswith("study")
    src = work / (f"{name}/timing.json" if study else f"{name}.json")
    if src.exists():
        entry["result"] = json.loads(src.read_text())
    if study and (work / f"{name}/levels.jsonl").exists():
        lines = [json.loads(x) for x in (work / f"{name}/levels.jsonl").read_text().split("\n")
                 if x]
        entry["levels"] = [{"sigma_r": r["sigma_r"],
                            "edc_error": r["reps"]["edc"]["error_mean"],
                            "edc_entropy": r["reps"]["edc"]["entropy_mean"]} for r in lines]
    if rc != 0:
        entry["log_tail"] = (work / f"{name}.log").read_text()[-1500:]
    res["steps"][name] = entry
res["total_s"] = round(time.time() - t0, 1)
res["all_ok"] = all(s.get("rc") == 0 for s in res["steps"].values())
res["total_budget_s"] = float(sys.argv[4])
path = Path(out or f"benchmarks/results/accelerator_check_{env['backend']}.json")
path.parent.mkdir(parents=True, exist_ok=True)
path.write_text(json.dumps(res, indent=1, default=float) + "\n")
print(f"{env['backend']} / {env['device_kind']}: all_ok={res['all_ok']} "
      f"total {res['total_s']} s -> {path}")
EOF
