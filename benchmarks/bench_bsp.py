"""Benchmark: batched belief-tree planning vs a one-environment-at-a-time loop (issue #16).

Usage::

    .venv/bin/python benchmarks/bench_bsp.py            # 256 environments, depth 2
    .venv/bin/python benchmarks/bench_bsp.py --quick    # smoke run (32 environments)

Both sides run the same jitted planner (:func:`pqrm_jax.bsp.plan`) on the same frozen beliefs
of random study environments (with compositions, cost 1): the batched side ``vmap``s it over
all environments in one call; the reference loops over the environments calling the jitted
single-environment planner. Both are compiled before timing; the plans must agree exactly.
Writes ``benchmarks/results/bsp.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _env import device_info  # benchmarks/_env.py

from pqrm_jax import calculi
from pqrm_jax.bsp import env as E
from pqrm_jax.bsp import graph as G
from pqrm_jax.bsp import models as M
from pqrm_jax.bsp import planner as P


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--envs", type=int)
    ap.add_argument("--depth", type=int, default=2)
    ap.add_argument("--samples", type=int, default=600, help="model samples per cell")
    ap.add_argument("--json", default=str(Path(__file__).parent / "results" / "bsp.json"))
    a = ap.parse_args()
    n_env = a.envs or (32 if a.quick else 256)
    models = M.load_models(M.ModelParams(samples=a.samples, pool=1 << 18, seed=3))
    D1 = jnp.asarray(calculi.get("edc").tables.neighbor_distance, jnp.float32)
    bels, fgs, goals = [], [], []
    for e in range(n_env):
        rng = np.random.default_rng([1, e])
        env = E.generate(rng, int(rng.integers(8, 13)), 2.5)
        b = E.initial_belief(models, env, jax.random.key(e), compositions=True)
        goal = jnp.asarray(env.goal, jnp.int32)
        fgs.append(G.frame_graph(models, b.trip, b.trip_src, b.scale, b.lm_mask, goal, 0.2))
        bels.append(b)
        goals.append(goal)
    stack = lambda xs: jax.tree.map(lambda *x: jnp.stack(x), *xs)  # noqa: E731
    B, F, Gl = stack(bels), stack(fgs), jnp.stack(goals)
    keys = jax.random.split(jax.random.key(0), n_env)
    pp = P.PlannerParams(depth=a.depth)

    batched = jax.jit(jax.vmap(lambda t, s, f, g, fr, r, k: P.plan(models, D1, t, s, f, g, fr,
                                                                     r, k, pp)))

    def run_batched():
        out = batched(B.trip, B.scale, F, Gl, B.frame, B.robot, keys)
        return jax.block_until_ready(out)

    def run_loop():
        outs = []
        for e in range(n_env):
            outs.append(P.plan(models, D1, bels[e].trip, bels[e].scale, fgs[e], goals[e],
                               bels[e].frame, bels[e].robot, keys[e], pp))
        return jax.block_until_ready(outs)

    ob = run_batched()
    ol = run_loop()  # compile both
    same = all(int(ob.action[e]) == int(ol[e].action) for e in range(n_env))
    close = float(np.max(np.abs(np.asarray(ob.value) - np.array([float(o.value) for o in ol]))))
    tb = min(_time(run_batched) for _ in range(3))
    tl = min(_time(run_loop) for _ in range(2))
    res = {"envs": n_env, "depth": a.depth, "n_actions": pp.n_actions, "n_beta": pp.n_beta,
           "batched_s": tb, "loop_s": tl, "ratio": tl / tb, "ms_per_plan_batched": 1e3 * tb / n_env,
           "ms_per_plan_loop": 1e3 * tl / n_env, "same_actions": same, "max_value_diff": close,
           "devices": [str(d) for d in jax.devices()], "cpu_threads_note": "shared 2-core host"}
    res["env"] = device_info()  # backend, device kind (benchmarks/_env.py)
    print(json.dumps(res, indent=1))
    Path(a.json).parent.mkdir(parents=True, exist_ok=True)
    Path(a.json).write_text(json.dumps(res, indent=1))
    return 0


def _time(f) -> float:
    t = time.perf_counter()
    f()
    return time.perf_counter() - t


if __name__ == "__main__":
    raise SystemExit(main())
