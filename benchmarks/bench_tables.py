"""Batched branch-and-bound vs per-problem references on the table builds (issue #2, item 7).

    .venv/bin/python benchmarks/bench_tables.py [--repeat 3] [--random 384] [--certify]
                                                [--one-core] [--out PATH]

The workload, the three references and the JSON fields: docs/benchmarks.md §bench_tables.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

if "--one-core" in sys.argv:  # before JAX starts its thread pool (threads inherit this)
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
from pathlib import Path

import numpy as np
from _env import write_result  # benchmarks/_env.py
from _timing import best_of  # benchmarks/_timing.py

from pqrm_jax import calculi
from pqrm_jax._parallel import default_queues
from pqrm_jax.tables import build
from pqrm_jax.tables import problems as pb
from pqrm_jax.tables.feasibility import ProblemBatch, solve, support_classes
from pqrm_jax.tables.reference import solve_reference

OPS = ("left", "right", "inverse", "compose", "adjacency")


def _compare(batches: list[tuple[str, ProblemBatch, dict]], repeat: int,
             single: int) -> dict:
    """Time the batched solver, the NumPy reference and one-problem calls on the batches."""
    out = {"batches": [], "problems": 0, "batched_s": 0.0, "numpy_reference_s": 0.0,
           "one_per_call_s": 0.0, "batched_one_queue_s": 0.0, "queues": default_queues()}
    agree_np, agree_one, agree_q, n_one = 0, 0, 0, 0
    for name, batch, kw in batches:
        solve(batch, **kw)  # warm (compiled already when recorded from a build)
        t_b, sol = best_of(lambda batch=batch, kw=kw: solve(batch, **kw), repeat)
        t_q, one_q = best_of(lambda batch=batch, kw=kw: solve(batch, **{**kw, "parts": 1}),
                             repeat)
        t_r, ref = best_of(lambda batch=batch, kw=kw: solve_reference(
            batch, pool=kw["pool"], max_iters=kw["max_iters"]), repeat)
        m = batch.size if single <= 0 else min(single, batch.size)
        sub, cls = support_classes(batch)  # one compiled program for every single problem
        solve(sub.take(slice(0, 1)), classes=cls, **kw)  # compile it
        t_1, one = best_of(lambda sub=sub, cls=cls, kw=kw, m=m: [
            solve(sub.take(slice(i, i + 1)), classes=cls, ids=[i], **{**kw, "parts": 1}
                  ).status[0] for i in range(m)], 1)
        t_1s = t_1 * batch.size / m
        agree_np += int((ref.status == sol.status).sum())
        agree_q += int((one_q.status == sol.status).sum())
        agree_one += int((np.asarray(one) == sol.status[:m]).sum())
        n_one += m
        out["batches"].append({"batch": name, "problems": batch.size,
                               "constraints": int(batch.A.shape[1]), "batched_s": t_b,
                               "batched_one_queue_s": t_q,
                               "numpy_reference_s": t_r, "one_per_call_s": t_1s,
                               "one_per_call_measured": m, "rounds": sol.iterations})
        out["problems"] += batch.size
        out["batched_s"] += t_b
        out["batched_one_queue_s"] += t_q
        out["numpy_reference_s"] += t_r
        out["one_per_call_s"] += t_1s
        print(f"  {name}: {batch.size} problems, K={batch.A.shape[1]}: batched {t_b:.3f} s "
              f"(one queue {t_q:.3f} s), "
              f"NumPy {t_r:.2f} s ({t_r / t_b:.1f}x), one per call {t_1s:.2f} s"
              f"{'' if m == batch.size else f' (scaled from {m})'} ({t_1s / t_b:.1f}x)",
              flush=True)
    out["ratio_vs_numpy"] = out["numpy_reference_s"] / out["batched_s"]
    out["ratio_vs_one_per_call"] = out["one_per_call_s"] / out["batched_s"]
    out["ratio_vs_numpy_one_queue"] = out["numpy_reference_s"] / out["batched_one_queue_s"]
    out["status_agreement_numpy"] = agree_np / out["problems"]
    out["status_agreement_one_queue"] = agree_q / out["problems"]
    out["status_agreement_one_per_call"] = agree_one / n_one
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=3, help="batched runs: best of this many")
    ap.add_argument("--single-problems", type=int, default=300,
                    help="one-problem calls timed per batch, scaled linearly (0: all)")
    ap.add_argument("--random", type=int, default=384,
                    help="also time this many random EDC compose problems (0: skip)")
    ap.add_argument("--certify", action="store_true",
                    help="also time an EDC build with z3 confirmation of every refutation")
    ap.add_argument("--one-core", action="store_true",
                    help="run the whole process on one core (the NumPy reference's resources)")
    ap.add_argument("--random-only", action="store_true",
                    help="skip the two table builds, time only the --random problems (quick "
                         "check, e.g. scripts/accelerator_check.sh)")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "tables.json"))
    args = ap.parse_args()
    res: dict = {"cores": len(os.sched_getaffinity(0))}
    batches: list[tuple[str, ProblemBatch, dict]] = []
    first_call = 0.0
    for cname in () if args.random_only else ("edc", "dcc"):
        calc = calculi.get(cname)
        calls: list[float] = []

        def recording(batch, *, desc="", cname=cname, calls=calls, **kw):
            t0 = time.perf_counter()
            sol = solve(batch, desc=desc, **kw)
            calls.append(time.perf_counter() - t0)
            batches.append((f"{cname}/{desc}", batch, kw))
            return sol

        t0 = time.perf_counter()
        raw = build.build_base(calc, solver=recording)
        dt = time.perf_counter() - t0
        same = all(np.array_equal(raw[op], getattr(calc.tables, op)) for op in OPS)
        first_call += sum(calls)
        res[f"{cname}_build_s"] = dt
        res[f"{cname}_build_stats"] = raw["stats"]
        res[f"{cname}_build_identical_to_shipped"] = same
        print(f"{cname} build: {dt:.1f} s, tables identical to the shipped ones: {same}; "
              f"branch-and-bound calls {sum(calls):.1f} s (compilation included); "
              f"stats {raw['stats']}", flush=True)
    if batches:
        print("branch-and-bound batches of the builds:")
        res["build_workload"] = _compare(batches, args.repeat, args.single_problems)
        res["build_workload"]["batched_first_call_s"] = first_call
        w = res["build_workload"]
    if batches:
        print(f"all {w['problems']} problems: batched {w['batched_s']:.2f} s on {w['queues']} "
              f"queue(s) (first calls, compilation included: {first_call:.1f} s), one queue "
              f"{w['batched_one_queue_s']:.2f} s; NumPy reference {w['numpy_reference_s']:.1f} s "
              f"-> {w['ratio_vs_numpy']:.1f}x ({w['ratio_vs_numpy_one_queue']:.1f}x on one queue); "
              f"one problem per call {w['one_per_call_s']:.1f} s -> "
              f"{w['ratio_vs_one_per_call']:.1f}x")
    if args.random:
        print(f"{args.random} random EDC compose problems:")
        kw = {"pool": 32, "max_iters": 120}
        batch = pb.to_batch(pb.random_compose_problems(calculi.get("edc"), args.random), 8.0)
        res["random_workload"] = _compare([("edc/random compose", batch, kw)], args.repeat,
                                          args.single_problems)
    if args.certify:
        t0 = time.perf_counter()
        raw = build.build_base(calculi.get("edc"), certify_all=True)
        res["edc_build_certified_s"] = time.perf_counter() - t0
        res["edc_build_certified_stats"] = raw["stats"]
        print(f"edc build with z3 confirmation: {res['edc_build_certified_s']:.1f} s")
    res["notes"] = ("ratio_vs_numpy = NumPy per-problem reference / batched (warm, best of "
                    "repeat); ratio_vs_one_per_call = same JAX program one problem per call / "
                    "batched (scaled from one_per_call_measured problems per batch); "
                    "batched_first_call_s = the builds' own solver calls, compilation "
                    "included; build times include the witness pre-pass, problem "
                    "construction, path-consistency refutation and z3")
    write_result(json.loads(json.dumps(res, default=float)), args.out)  # + env, CPU times


if __name__ == "__main__":
    main()
