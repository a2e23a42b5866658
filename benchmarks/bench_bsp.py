"""Benchmark: batched belief-tree planning vs a one-environment-at-a-time loop (issue #16).

Usage::

    .venv/bin/python benchmarks/bench_bsp.py                  # 128 and 1024 environments
    .venv/bin/python benchmarks/bench_bsp.py --envs 128 1024  # the same, explicit
    .venv/bin/python benchmarks/bench_bsp.py --quick          # smoke run (32 environments)

Both sides run the same planner (:func:`pqrm_jax.bsp.plan`, depth 2, cost 1) on the same
frozen beliefs of distinct random study environments (with compositions). The reference calls
the jitted single-environment planner once per environment in a Python loop (arguments sliced
before timing, so the loop pays only the planner's own dispatch). The batched side is one
jitted call over all environments: ``lax.map`` over chunks of ``chunk`` environments, each
chunk ``vmap``-ed; several chunk widths are timed. Both are compiled before timing and the
plans must agree (same first actions; values to float32 rounding).

To explain the ratio it also records, per plan, XLA's cost analysis of the compiled
single-environment planner (flops, bytes accessed) and the dispatch cost of a jitted function
that takes the same arguments and does nothing: the loop can lose to batching at most that
overhead, unless batching makes each plan's own arithmetic cheaper. Writes
``benchmarks/results/bsp.json`` (docs/bsp.md §benchmark).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _env import write_result  # benchmarks/_env.py
from _timing import best_of  # benchmarks/_timing.py

from pqrm_jax import calculi
from pqrm_jax.bsp import env as E
from pqrm_jax.bsp import graph as G
from pqrm_jax.bsp import models as M
from pqrm_jax.bsp import planner as P


def _instances(models, n_env: int):
    bels, fgs, goals = [], [], []
    for e in range(n_env):
        rng = np.random.default_rng([1, e])
        env = E.generate(rng, int(rng.integers(8, 13)), 2.5)
        b = E.initial_belief(models, env, jax.random.key(e), compositions=True, samples=64)
        goal = jnp.asarray(env.goal, jnp.int32)
        fgs.append(G.frame_graph(models, b.trip, b.trip_src, b.scale, b.lm_mask, goal, 0.2))
        bels.append(b)
        goals.append(goal)
    return bels, fgs, goals


def bench(models, D1, bels, fgs, goals, pp, chunks, reps: int = 3) -> dict:
    """Loop vs batched (one ``lax.map`` over ``vmap``-ed chunks) on these instances."""
    n_env = len(bels)
    keys = jax.random.split(jax.random.key(0), n_env)
    key_list = [keys[e] for e in range(n_env)]
    args = [(bels[e].trip, bels[e].scale, fgs[e], goals[e], bels[e].frame, bels[e].robot,
             key_list[e]) for e in range(n_env)]
    stack = lambda xs: jax.tree.map(lambda *x: jnp.stack(x), *xs)  # noqa: E731
    xs = stack(args)

    def one(a):
        return P.plan(models, D1, *a, pp)

    def run_loop():
        return [one(a) for a in args]

    t_loop, ol = best_of(run_loop, reps)
    ref_act = np.array([int(o.action) for o in ol])
    ref_val = np.array([float(o.value) for o in ol])
    out = {"envs": n_env, "loop_s": t_loop, "ms_per_plan_loop": 1e3 * t_loop / n_env,
           "batched": {}}
    for c in chunks:
        if c > n_env or n_env % c:
            continue
        f = jax.jit(lambda xs, c=c: jax.lax.map(one, xs, batch_size=c))
        jax.block_until_ready(f(xs))  # compile
        t_b, ob = best_of(lambda f=f: f(xs), reps)
        out["batched"][str(c)] = {
            "batched_s": t_b, "ms_per_plan": 1e3 * t_b / n_env, "ratio": t_loop / t_b,
            "same_actions": bool(np.array_equal(np.asarray(ob.action), ref_act)),
            "max_value_diff": float(np.max(np.abs(np.asarray(ob.value) - ref_val)))}
    best = max(out["batched"].items(), key=lambda kv: kv[1]["ratio"])
    out["best_chunk"], out["best_ratio"] = int(best[0]), best[1]["ratio"]
    return out


def overheads(models, D1, bels, fgs, goals, pp, reps: int = 3) -> dict:
    """Per-call dispatch cost of a do-nothing jit with the planner's arguments, and XLA's
    cost analysis of one compiled plan."""
    n = len(bels)
    key = jax.random.key(0)
    args = [(models, D1, bels[e].trip, bels[e].scale, fgs[e], goals[e], bels[e].frame,
             bels[e].robot, key) for e in range(n)]
    nothing = jax.jit(lambda *a: a[6].sum())
    jax.block_until_ready(nothing(*args[0]))
    t, _ = best_of(lambda: [nothing(*a) for a in args], reps)
    ca = P.plan.lower(*args[0], pp).compile().cost_analysis()
    ca = ca[0] if isinstance(ca, list) else (ca or {})
    return {"dispatch_ms_per_call": 1e3 * t / n, "flops_per_plan": ca.get("flops"),
            "bytes_accessed_per_plan": ca.get("bytes accessed")}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--envs", type=int, nargs="+")
    ap.add_argument("--chunks", type=int, nargs="+", default=[1, 4, 16, 64, 128])
    ap.add_argument("--depth", type=int, default=2)
    ap.add_argument("--samples", type=int, default=600, help="model samples per cell")
    ap.add_argument("--out", "--json", dest="out",
                    default=str(Path(__file__).parent / "results" / "bsp.json"))
    a = ap.parse_args()
    sizes = a.envs or ([32] if a.quick else [128, 1024])
    models = M.load_models(M.ModelParams(samples=a.samples, pool=1 << 18, seed=3))
    D1 = jnp.asarray(calculi.get("edc").tables.neighbor_distance, jnp.float32)
    pp = P.PlannerParams(depth=a.depth)
    bels, fgs, goals = _instances(models, max(sizes))
    res = {"depth": a.depth, "n_actions": pp.n_actions, "n_beta": pp.n_beta,
           "overheads": overheads(models, D1, bels[:64], fgs[:64], goals[:64], pp),
           "runs": [bench(models, D1, bels[:n], fgs[:n], goals[:n], pp, a.chunks)
                    for n in sizes]}
    print(json.dumps(res, indent=1))
    write_result(res, a.out)  # + env: where it ran, load; timings with CPU time
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
