"""Warm starts: first call, second process (persistent compilation cache) and warm call.

    .venv/bin/python benchmarks/bench_warm.py [--what traverse tables study:padgett-mc ...]
                                              [--out benchmarks/results/warm.json]

For each workload, in fresh processes with an empty cache directory of their own:

* **first call** — a process with the cache on but empty: compiles everything (and fills it);
* **second process** — the same workload again in a new process on that cache: nothing to
  compile when every program was cached (``cache_misses`` 0);
* **warm** — the second call inside the first process (in-memory compiled programs), for the
  workloads that are one function call (``traverse``, ``tables``); a study is one process.

Workloads: ``traverse`` — the Mars-Yard-like traverse of ``benchmarks/bench_qrm.py``
(``qrm.pipeline.run_sequence``, 30 landmarks, 50 images, 18 candidates);
``tables`` — the EDC table build (``tables.build.build_base``); ``study:NAME[:ARGS]`` —
``pqrm-jax study NAME --reduced`` (ARGS replaces ``--reduced``, ``+`` for spaces), timed as a
whole process. Wall and CPU seconds (every thread) of each, the cache's hits and misses
(``jax.monitoring``), and where it ran (``env``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

WORKER = r"""
import json, sys, time
from jax import monitoring
ev = {"hit": 0, "miss": 0}
def listen(name, **kw):
    if name.endswith("/cache_hits"): ev["hit"] += 1
    elif name.endswith("/cache_misses"): ev["miss"] += 1
monitoring.register_event_listener(listen)
what, cache = sys.argv[1], sys.argv[2]
t0, c0 = time.perf_counter(), time.process_time()
from pqrm_jax import compile_cache
compile_cache.enable(cache)
import jax
out = {}
def timed(f):
    a, b = time.perf_counter(), time.process_time()
    jax.block_until_ready(f())
    return time.perf_counter() - a, time.process_time() - b
if what == "traverse":
    from pqrm_jax import sim
    from pqrm_jax.qrm import pipeline as P
    lm = sim.uniform_landmarks(jax.random.key(1), 30, (30.0, 30.0))
    poses = sim.traverse(jax.random.key(2), 50, size=(30.0, 30.0))
    f = lambda: P.run_sequence(lm, poses, 18)[0].rel
elif what == "tables":
    from pqrm_jax import calculi
    from pqrm_jax.tables import build
    calc = calculi.get("edc")
    def f():
        r = build.build_base(calc)
        f.same = all((r[k] == getattr(calc.tables, k)).all()
                     for k in ("left", "right", "inverse", "compose", "adjacency"))
        return 0
else:
    f = None
out["import_s"] = time.perf_counter() - t0
if f is not None:
    out["first_s"], out["first_cpu_s"] = timed(f)
    ev_first = dict(ev)
    out["warm_s"], out["warm_cpu_s"] = timed(f)
    out["warm_s2"], out["warm_cpu_s2"] = timed(f)
    if hasattr(f, "same"):
        out["tables_equal_shipped"] = bool(f.same)
    out["cache_hits"], out["cache_misses"] = ev_first["hit"], ev_first["miss"]
else:
    from pqrm_jax import cli
    name, _, args = what.partition(":")[2].partition(":")
    argv = ["study", name, *(args.split("+") if args else ["--reduced"]), "--out",
            sys.argv[3]]
    if name != "mars-yard":
        argv.append("--quiet")
    rc = cli.main(argv)
    out["rc"] = rc
    out["cache_hits"], out["cache_misses"] = ev["hit"], ev["miss"]
out["process_s"], out["process_cpu_s"] = time.perf_counter() - t0, time.process_time() - c0
print("RESULT " + json.dumps(out))
"""


def _worker(what: str, cache: str, tmp: str) -> dict:
    env = dict(os.environ)
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", WORKER, what, cache,
                           str(Path(tmp) / f"out{time.monotonic_ns()}")], env=env,
                          capture_output=True, text=True)
    wall = time.perf_counter() - t0
    lines = [x for x in proc.stdout.splitlines() if x.startswith("RESULT ")]
    if proc.returncode or not lines:
        return {"rc": proc.returncode, "log_tail": (proc.stdout + proc.stderr)[-1500:]}
    res = json.loads(lines[-1][7:])
    res["process_wall_with_startup_s"] = wall
    return res


def main(argv=None) -> int:
    from _env import write_result

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--what", nargs="+", default=["traverse", "tables", "study:padgett-mc"])
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "warm.json"))
    args = ap.parse_args(argv)
    rows = {}
    for what in args.what:
        with tempfile.TemporaryDirectory() as tmp:
            cache = str(Path(tmp) / "cache")
            first = _worker(what, cache, tmp)
            second = _worker(what, cache, tmp)
        rows[what] = {"first_process": first, "second_process": second}
        print(what, json.dumps(rows[what]), flush=True)
    write_result({"benchmark": "warm starts", "rows": rows}, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
