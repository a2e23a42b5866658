"""Batched branch-and-bound vs per-problem references for the EDC composition problems (issue #2).

Same problems, same process, two references for the batched JAX run (all problems in one
jit-compiled work-queue program, 64 problems in flight):

* **NumPy reference** (the team's usual reference, ``ratio_vs_numpy``):
  ``tables.reference.solve_reference``, the same algorithm in plain NumPy, one problem at a
  time, each round vectorised over that problem's boxes. ``--ref-problems N`` times it on the
  first N problems only and scales linearly to the batch (``numpy_reference_s`` is the scaled
  figure, ``numpy_reference_measured_s`` the time on ``numpy_reference_problems`` problems);
  the default times it on every problem (no scaling).
* **one-slot JAX** (``ratio``): the same compiled JAX step with one slot, one call per
  problem. It shows what batching alone buys on this CPU (same kernels, no batching), not a
  speed-up over a plain implementation.

Statuses are compared with the batched run (``status_agreement``,
``status_agreement_numpy``); they can differ only where a random witness probe found a
solution in one run and not the other (the probe streams differ).

``--full`` also times full EDC table builds (witness pre-pass + B&B + z3 for what the B&B
leaves undecided), with and without z3 confirmation of every B&B refutation.

    .venv/bin/python benchmarks/bench_tables.py [--problems 384] [--ref-problems N] [--full]
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
from pqrm_jax.tables.reference import solve_reference


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--problems", type=int, default=384)
    ap.add_argument("--ref-problems", type=int, default=0,
                    help="time the NumPy reference on the first N problems only and scale "
                         "linearly to the batch (0: all problems)")
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
    n_ref = batch.size if args.ref_problems <= 0 else min(args.ref_problems, batch.size)
    ref_kw = {k: kw[k] for k in ("pool", "max_iters")}
    solve_reference(batch.take(slice(0, 1)), **ref_kw)  # warm-up (first-call overheads)
    t0 = time.perf_counter()
    ref = solve_reference(batch.take(slice(0, n_ref)), **ref_kw)
    t_ref_measured = time.perf_counter() - t0
    t_ref = t_ref_measured * batch.size / n_ref
    agree_np = float(np.mean(ref.status == batched.status[:n_ref]))
    res = {"problems": batch.size, "batched_s": t_batched, "per_problem_s": t_single,
           "ratio": t_single / t_batched, "status_agreement": agree,
           "batched_problems_per_s": batch.size / t_batched,
           "numpy_reference_s": t_ref, "numpy_reference_measured_s": t_ref_measured,
           "numpy_reference_problems": n_ref, "numpy_reference_scaled": n_ref < batch.size,
           "ratio_vs_numpy": t_ref / t_batched, "status_agreement_numpy": agree_np,
           "notes": "ratio_vs_numpy = NumPy per-problem reference (team standard) / batched; "
                    "numpy_reference_s is scaled linearly from numpy_reference_problems "
                    "problems when numpy_reference_scaled; ratio = one-slot JAX / batched "
                    "(what batching alone buys); status_agreement* are against the batched "
                    "statuses"}
    scaled = (f" (measured {t_ref_measured:.2f} s on {n_ref} problems, scaled linearly)"
              if n_ref < batch.size else "")
    print(f"{batch.size} EDC compose problems: batched JAX {t_batched:.2f} s")
    print(f"  NumPy per-problem reference {t_ref:.2f} s{scaled} -> ratio "
          f"{res['ratio_vs_numpy']:.1f}x (agreement {agree_np:.3f})")
    print(f"  one-slot JAX, one call per problem {t_single:.2f} s -> ratio "
          f"{res['ratio']:.1f}x (agreement {agree:.3f})")
    if args.full:
        for certify_all in (False, True):
            t0 = time.perf_counter()
            raw = build.build_base(edc, certify_all=certify_all)
            dt = time.perf_counter() - t0
            res[f"edc_build_s_certify_{certify_all}"] = dt
            res[f"edc_build_stats_certify_{certify_all}"] = raw["stats"]
            same = all(np.array_equal(raw[op], getattr(edc.tables, op))
                       for op in ("left", "right", "inverse", "compose", "adjacency"))
            res[f"edc_build_identical_to_shipped_certify_{certify_all}"] = same
            print(f"full EDC build (certify_all={certify_all}): {dt:.1f} s, tables identical "
                  f"to the shipped ones: {same}; stats {raw['stats']}")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(res, indent=1, default=float))


if __name__ == "__main__":
    main()
