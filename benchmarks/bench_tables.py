"""Batched vs per-problem branch-and-bound for the EDC composition problems (issue #2).

Same solver code, same problems, same process: the batched run solves all problems in one
jit-compiled work-queue program (64 problems in flight); the reference solves them one at a
time (one call per problem, the same compiled step with one slot). ``--full`` also times full
EDC table builds (witness pre-pass + B&B + z3 for what the B&B leaves undecided), with and
without z3 confirmation of every B&B refutation.

    .venv/bin/python benchmarks/bench_tables.py [--problems 384] [--full]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from pqrm_jax import calculi
from pqrm_jax.tables import build
from pqrm_jax.tables import problems as pb
from pqrm_jax.tables.feasibility import solve


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--problems", type=int, default=384)
    ap.add_argument("--full", action="store_true", help="also time full table builds")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "tables.json"))
    args = ap.parse_args()
    edc = calculi.get("edc")
    atoms, _ = pb.atoms(edc)
    rng = np.random.default_rng(0)
    probs = []
    while len(probs) < args.problems:
        i, j, k = rng.integers(0, len(atoms), 3)
        pr = pb.compose_problem(edc, atoms[i], atoms[j], atoms[k])
        if not pr.trivially_infeasible:
            probs.append(pr)
    batch = pb.to_batch(probs, 8.0)
    kw = {"pool": 32, "max_iters": 120}
    solve(batch, **kw)  # compile (same shapes as the timed call)
    t0 = time.perf_counter()
    batched = solve(batch, **kw)
    t_batched = time.perf_counter() - t0
    solve(batch.take(slice(0, 1)), **kw)  # compile the one-slot program
    t0 = time.perf_counter()
    single = [solve(batch.take(slice(i, i + 1)), **kw).status[0]
              for i in range(batch.size)]
    t_single = time.perf_counter() - t0
    agree = float(np.mean(np.asarray(single) == batched.status))
    res = {"problems": batch.size, "batched_s": t_batched, "per_problem_s": t_single,
           "ratio": t_single / t_batched, "status_agreement": agree,
           "batched_problems_per_s": batch.size / t_batched}
    print(f"{batch.size} EDC compose problems: batched {t_batched:.2f} s, one at a time "
          f"{t_single:.2f} s -> ratio {res['ratio']:.1f}x (agreement {agree:.3f})")
    if args.full:
        for certify_all in (False, True):
            t0 = time.perf_counter()
            raw = build.build_base(edc, certify_all=certify_all)
            dt = time.perf_counter() - t0
            res[f"edc_build_s_certify_{certify_all}"] = dt
            res[f"edc_build_stats_certify_{certify_all}"] = raw["stats"]
            print(f"full EDC build (certify_all={certify_all}): {dt:.1f} s; stats {raw['stats']}")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(res, indent=1, default=float))


if __name__ == "__main__":
    main()
