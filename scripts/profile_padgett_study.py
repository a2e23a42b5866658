"""Where the time of a padgett-mc study goes: one run of the study, instrumented.

    .venv/bin/python scripts/profile_padgett_study.py [--runs 1000] [--out DIR]
        [--workers N] [--json PATH]

Runs ``padgett_mc.run_study`` then ``padgett_mc.report`` exactly as
``pqrm-jax study padgett-mc --runs R --fresh`` does (no compilation cache), with the study's
functions wrapped to record wall seconds (and the calling thread's CPU seconds for host-side
work): the compilation of the chunk program, each level's device computation
(``run_level``), each level's host-side summary (``summarise_level``), the writes, and the
report with its figures; plus the process CPU seconds of each phase (``time.process_time``,
every thread), so that ``cpu / wall`` says how many cores were busy.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time
from pathlib import Path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--levels", type=int, default=21)
    ap.add_argument("--out", default="/tmp/padgett_profile")
    ap.add_argument("--workers", type=int, default=0, help="levels side by side (0: study's)")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    os.environ.setdefault("PQRM_JAX_COMPILE_CACHE", "off")
    t_start, c_start = time.perf_counter(), time.process_time()
    import jax  # noqa: F401

    from pqrm_jax.studies import padgett_mc as P
    from pqrm_jax.studies import store as S

    t_import = time.perf_counter() - t_start
    lock = threading.Lock()
    events: list[dict] = []

    def wrap(owner, name, label, key=None):
        f = getattr(owner, name)

        def g(*a, **k):
            t0, c0, tc0 = time.perf_counter(), time.process_time(), time.thread_time()
            try:
                return f(*a, **k)
            finally:
                ev = {
                    "what": label,
                    "t0": t0 - t_start,
                    "wall": time.perf_counter() - t0,
                    "cpu": time.process_time() - c0,
                    "thread_cpu": time.thread_time() - tc0,
                }
                if key is not None:
                    ev["key"] = key(a, k)
                with lock:
                    events.append(ev)

        setattr(owner, name, g)

    wrap(P, "_compiled_chunk", "compile (lower + compile, cached)")
    wrap(P, "run_level", "level compute", key=lambda a, k: a[1])
    wrap(P, "summarise_level", "level summary (host)", key=lambda a, k: a[3])
    wrap(S.Store, "write_npz", "write npz")
    if args.workers:
        P.level_workers = lambda cluster=None: args.workers
    cfg, _ = P.configure(
        ["--runs", str(args.runs), "--levels", str(args.levels), "--fresh", "--out", args.out]
    )
    t0, c0 = time.perf_counter(), time.process_time()
    P.run_study(cfg, Path(args.out), quiet=True, fresh=True)
    study = (time.perf_counter() - t0, time.process_time() - c0)
    t0, c0 = time.perf_counter(), time.process_time()
    P.report(Path(args.out))
    rep = (time.perf_counter() - t0, time.process_time() - c0)
    total = (time.perf_counter() - t_start, time.process_time() - c_start)

    def agg(label):
        evs = [e for e in events if e["what"] == label]
        return {
            "n": len(evs),
            "wall_sum": sum(e["wall"] for e in evs),
            "cpu_sum_process": sum(e["cpu"] for e in evs),
            "thread_cpu_sum": sum(e["thread_cpu"] for e in evs),
        }

    out = {
        "runs": args.runs,
        "levels": len(cfg.sigma_levels()),
        "chunk": None,
        "import_s": t_import,
        "run_study_wall": study[0],
        "run_study_cpu": study[1],
        "report_wall": rep[0],
        "report_cpu": rep[1],
        "total_wall": total[0],
        "total_cpu": total[1],
        "load": os.getloadavg(),
        "phases": {lb: agg(lb) for lb in sorted({e["what"] for e in events})},
        "events": events,
    }
    levels = sorted((e for e in events if e["what"] == "level compute"), key=lambda e: e["key"])
    print(
        f"import {t_import:.1f}s; run_study {study[0]:.1f}s wall {study[1]:.1f} CPU; "
        f"report {rep[0]:.1f}s wall {rep[1]:.1f} CPU; total {total[0]:.1f}s wall "
        f"{total[1]:.1f} CPU; load {os.getloadavg()}"
    )
    for lb, a in out["phases"].items():
        print(
            f"  {lb:40s} n={a['n']:3d} wall_sum {a['wall_sum']:7.1f}s  process-CPU "
            f"{a['cpu_sum_process']:7.1f}s  thread-CPU {a['thread_cpu_sum']:6.1f}s"
        )
    for e in levels:
        print(f"  level {e['key']:2d} start {e['t0']:6.1f}s wall {e['wall']:5.2f}s")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
