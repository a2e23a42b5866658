"""Benchmark: the belief-tree planner against its previous version, and batched planning vs a
one-environment-at-a-time loop (issues #16, #25).

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

``per_plan`` times this planner against the previous one in the same process (the reference,
``reference_plan`` below: main's planner before issue #25, verbatim; the one reference of the
previous planner and its joint sampler) on the same instances, one jitted plan at a time and
``vmap``-ed over the instances, the repetitions interleaved, and compares the plans: at depth 1
(no measurement drawn) one for one, at the benchmark's depth in distribution (this planner
draws (b, s_x, s_τ) one after the other, the reference from the Q²·nb-cell joint).

To explain the batched ratio it also records, per plan, XLA's cost analysis of the compiled
single-environment planner (flops, bytes accessed) and the dispatch cost of a jitted function
that takes the same arguments and does nothing: the loop can lose to batching at most that
overhead, unless batching makes each plan's own arithmetic cheaper. Writes
``benchmarks/results/bsp.json`` (docs/bsp.md §benchmark).
"""

from __future__ import annotations

import argparse
import json
from functools import partial
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from _env import write_result  # benchmarks/_env.py
from _timing import best_of, timed  # benchmarks/_timing.py

from pqrm_jax import calculi
from pqrm_jax.bsp import env as E
from pqrm_jax.bsp import graph as G
from pqrm_jax.bsp import models as M
from pqrm_jax.bsp import planner as P
from pqrm_jax.bsp.belief import LINK_K


# ------------------------------------------------------------------------------------------
# The previous planner (main before issue #25), kept verbatim as the in-process reference: one
# expansion per node (frame-only quantities recomputed for every node of a frame) and one
# cumsum over the Q²·nb-cell joint per branch.
class _RefLevel(NamedTuple):
    cost: jax.Array  # [N, na]
    acts: jax.Array  # [N, na]
    ks: jax.Array  # [N, na, nb]
    w: jax.Array  # [N, na, nb]
    goal: jax.Array  # [N, na, nb]
    anyobs: jax.Array  # [N, na]
    seen: jax.Array  # [N, na] P(some observable candidate seen | a): 1 without nothing_seen
    frames: jax.Array  # [N, na, nb, 3, 2]
    robots: jax.Array  # [N, na, nb, 3, Q]


def _ref_expand_one(models, D1, trip, scale, fg: G.FrameGraph, goal, key, level, frame, p,
                    pp: P.PlannerParams, cost):
    L = trip.shape[0]
    Q = models.num_states
    i, j = frame[0], frame[1]
    sf = scale[i, j]
    costs = P.step_costs(models, D1, sf, p, cost)
    wt = jnp.einsum("b,bax,kxb->ak", sf, models.T, fg.Ab[i, j]) * fg.obs[i, j][None]
    idx = jnp.arange(L)
    third = goal.sum() - i - j
    isg = fg.goal_obs[i, j] & (idx == third)
    cb = P.cbar(models, D1, cost)
    lam = jnp.asarray(pp.lam, jnp.float32)
    # one-step proxy for every action: c + E_β[min over links of h(F')] (h needs no ẑ)
    h_f = P.leaf_values(fg, frame, cb, lam, pp.rho)
    h_ik = P.leaf_values(fg, jnp.stack([jnp.full(L, i), idx], -1), cb, lam, pp.rho)
    h_jk = P.leaf_values(fg, jnp.stack([jnp.full(L, j), idx], -1), cb, lam, pp.rho)
    hk = jnp.where(isg, 0.0, jnp.minimum(h_f, jnp.minimum(h_ik, h_jk)))
    wsum = wt.sum(1)
    # P(some candidate seen | a): 1 in the thesis model (the candidate weights renormalised,
    # §Z-24); the nothing-seen EXTENSION clips the sum at 1 (the events may overlap)
    ps = jnp.clip(wsum, 0.0, 1.0) if pp.nothing_seen else jnp.ones_like(wsum)
    proxy = costs + jnp.where(wsum > 0, ps * (wt @ hk) / jnp.where(wsum > 0, wsum, 1.0)
                              + (1.0 - ps) * (h_f + cb), h_f + cb)
    score = -proxy
    _, acts = jax.lax.top_k(score, pp.n_actions)
    wa = wt[acts]  # [na, L]
    wk, ks = jax.lax.top_k(wa, pp.n_beta)  # [na, nb]
    tot = wk.sum(-1, keepdims=True)
    anyobs = tot[:, 0] > 0
    w = wk / jnp.where(tot > 0, tot, 1.0)
    base = jax.random.fold_in(jax.random.fold_in(key, level), i * L + j)

    def branch(a, k):
        kk = jax.random.fold_in(jax.random.fold_in(base, a), k)
        k1, k2 = jax.random.split(kk)
        jw = jnp.einsum("b,bx,t,xtb->xtb", sf, models.T[:, a], trip[i, j, k], models.A)
        cell = P.sample_index(k1, jw.reshape(-1))
        x, t, b = cell // (Q * models.num_bins), (cell // models.num_bins) % Q, \
            cell % models.num_bins
        z = P.sample_index(k2, models.AZ[x, t, b])
        J = jnp.einsum("b,bx,t,xtb->xt", sf, models.T[:, a], trip[i, j, k], models.AZ_by_z[z])
        s = J.sum()
        J = J / jnp.where(s > 0, s, 1.0)
        stay = J.sum(1)
        ac = jnp.einsum("xt,xts->s", J, models.K[LINK_K[0]])
        bc = jnp.einsum("xt,xts->s", J, models.K[LINK_K[1]])
        frames = jnp.stack([jnp.stack([i, j]), jnp.stack([i, k]), jnp.stack([j, k])])
        return frames, jnp.stack([stay, ac, bc])

    fr, rb = jax.vmap(jax.vmap(branch, (None, 0)), (0, 0))(acts, ks)
    return _RefLevel(cost=costs[acts], acts=acts, ks=ks, w=w,
                  goal=fg.goal_obs[i, j] & (ks == third), anyobs=anyobs,
                  seen=ps[acts], frames=fr, robots=rb)


@partial(jax.jit, static_argnames=("pp",))
def reference_plan(key, models, D1, trip, scale, fg: G.FrameGraph, goal, frame, robot,
                   pp: P.PlannerParams = P.DEFAULT, cost=None) -> P.Plan:
    """Plan from ``frame`` with robot belief ``robot`` (module docstring); jit, vmap-able.

    Args:
        key: PRNG key of the session.
        models: offline tables. D1: (Q, Q) neighbour distance (eq. 4.29).
        trip: (L, L, L, Q) frozen triplet beliefs. scale: (L, L, nb) frame scales.
        fg: the session's :func:`~pqrm_jax.bsp.graph.frame_graph`. goal: (3,) landmark ids.
        frame: (2,) current frame. robot: (Q,) robot belief.
        pp: static settings. cost: optional traced 1 or 2 overriding ``pp.cost``.
    """
    if pp.depth < 1:
        raise ValueError(f"planner depth must be >= 1, got {pp.depth}")
    cost = pp.cost if cost is None else cost
    cb = P.cbar(models, D1, cost)
    lam = jnp.asarray(pp.lam, jnp.float32)
    expand = jax.vmap(lambda f, p, lv: _ref_expand_one(models, D1, trip, scale, fg, goal, key, lv,
                                                   f, p, pp, cost), (0, 0, None))
    frames, robots = frame[None], robot[None]
    levels = []
    for lv in range(pp.depth):
        out = expand(frames, robots, lv)
        levels.append((frames, out))
        frames = out.frames.reshape(-1, 2)
        robots = out.robots.reshape(-1, robot.shape[-1])
    values = P.leaf_values(fg, frames, cb, lam, pp.rho)
    q = None
    for parent_frames, out in reversed(levels):
        n = parent_frames.shape[0]
        v = values.reshape(n, pp.n_actions, pp.n_beta, 3)
        vb = jnp.where(out.goal, 0.0, v.min(-1))
        stuck = P.leaf_values(fg, parent_frames, cb, lam, pp.rho)[:, None] + cb
        # seen = 1 unless the nothing-seen EXTENSION is on (docs/bsp.md §nothing-seen)
        q = out.cost + jnp.where(out.anyobs, out.seen * (out.w * vb).sum(-1)
                                 + (1.0 - out.seen) * stuck, stuck)
        values = q.min(-1)
        links = v.argmin(-1)
    root = levels[0][1]
    best = jnp.argmin(q[0])
    value = values[0]
    return P.Plan(value=value, action=root.acts[0, best], exists=value < 0.5 * lam * cb,
                actions=root.acts[0], ks=root.ks[0], links=links[0], q=q[0])


def _instances(models, n_env: int):
    bels, fgs, goals = [], [], []
    for e in range(n_env):
        rng = np.random.default_rng([1, e])
        env = E.generate(rng, int(rng.integers(8, 13)), 2.5)
        b = E.initial_belief(jax.random.key(e), models, env, compositions=True, samples=64)
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
    args = [(key_list[e], bels[e].trip, bels[e].scale, fgs[e], goals[e], bels[e].frame,
             bels[e].robot) for e in range(n_env)]
    stack = lambda xs: jax.tree.map(lambda *x: jnp.stack(x), *xs)  # noqa: E731
    xs = stack(args)

    def one(a):
        return P.plan(a[0], models, D1, *a[1:], pp)

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


def per_plan(models, D1, bels, fgs, goals, pp, reps: int = 7) -> dict:
    """This planner against the previous one (``reference_plan``, kept verbatim above) on the
    same instances: per-plan time one jitted plan at a time (``loop``) and ``vmap``-ed over all
    instances in one jitted call (``batched``, how the study runs its lanes), the repetitions
    interleaved (reference, new, reference, …; best of ``reps``) so that load hits both alike.
    The plans are compared where the draws are comparable (depth 1: no ẑ is drawn, so first
    actions and values must agree to float rounding) and in distribution at ``pp.depth`` (the
    new sampler draws (b, s_x, s_τ) one after the other: the share of equal first actions and
    the relative value differences are recorded)."""
    n = len(bels)
    keys = jax.random.split(jax.random.key(0), n)
    args = [(keys[e], bels[e].trip, bels[e].scale, fgs[e], goals[e], bels[e].frame,
             bels[e].robot) for e in range(n)]
    xs = jax.tree.map(lambda *x: jnp.stack(x), *args)
    planners = {"reference": reference_plan, "new": P.plan}
    # the reference reads AZ_by_z in the layout it was written for, [Q², Q, Q, nb]
    mods = {"reference": models._replace(AZ_by_z=jnp.moveaxis(models.AZ, -1, 0)),
            "new": models}
    fns = {}
    for name, f in planners.items():
        m = mods[name]
        one = jax.jit(lambda a, f=f, m=m: f(a[0], m, D1, *a[1:], pp))
        vb = jax.jit(jax.vmap(lambda a, f=f, m=m: f(a[0], m, D1, *a[1:], pp)))
        jax.block_until_ready(one(args[0]))  # compile
        jax.block_until_ready(vb(xs))
        fns[name] = (one, vb)
    runs = {name: {"loop": [], "batched": []} for name in planners}
    outs = {}
    for _ in range(reps):
        for name, (one, vb) in fns.items():
            w, c, o = timed(lambda one=one: [one(a) for a in args])
            runs[name]["loop"].append((w, c))
            outs[name] = o
            w, c, _ = timed(lambda vb=vb: vb(xs))
            runs[name]["batched"].append((w, c))
    best = {name: {k: min(v) for k, v in r.items()} for name, r in runs.items()}
    ms = {name: {k: 1e3 * v[0] / n for k, v in b.items()} for name, b in best.items()}
    cpu_ms = {name: {k: 1e3 * v[1] / n for k, v in b.items()} for name, b in best.items()}
    ra = np.array([int(x.action) for x in outs["reference"]])
    na = np.array([int(x.action) for x in outs["new"]])
    rv = np.array([float(x.value) for x in outs["reference"]])
    nv = np.array([float(x.value) for x in outs["new"]])
    rel = np.abs(nv - rv) / np.maximum(np.abs(rv), 1e-9)
    # depth 1: no measurement is drawn, the plans are comparable one for one
    p1 = pp._replace(depth=1)
    o1 = {name: [f(a[0], mods[name], D1, *a[1:], p1) for a in args]
          for name, f in planners.items()}
    same1 = float(np.mean([int(r.action) == int(m.action)
                           for r, m in zip(o1["reference"], o1["new"], strict=True)]))
    diff1 = float(np.max([abs(float(r.value) - float(m.value)) / max(abs(float(r.value)), 1e-9)
                          for r, m in zip(o1["reference"], o1["new"], strict=True)]))
    ca = {}
    for name, f in planners.items():
        c = f.lower(args[0][0], mods[name], D1, *args[0][1:], pp).compile().cost_analysis()
        c = c[0] if isinstance(c, list) else (c or {})
        ca[name] = {"flops": c.get("flops"), "bytes_accessed": c.get("bytes accessed")}
    return {"envs": n, "reps": reps,
            "ms_per_plan": ms, "cpu_ms_per_plan": cpu_ms,
            "ratio_loop": ms["reference"]["loop"] / ms["new"]["loop"],
            "ratio_batched": ms["reference"]["batched"] / ms["new"]["batched"],
            "depth1_same_first_action": same1, "depth1_value_rel_diff_max": diff1,
            "same_first_action": float(np.mean(ra == na)),
            "value_rel_diff_median": float(np.median(rel)),
            "value_rel_diff_p90": float(np.quantile(rel, 0.9)),
            "value_rel_diff_max": float(np.max(rel)),
            "same_plan_exists": bool(np.array_equal(rv < 0.5 * pp.lam, nv < 0.5 * pp.lam)),
            "cost_analysis": ca}


def overheads(models, D1, bels, fgs, goals, pp, reps: int = 3) -> dict:
    """Per-call dispatch cost of a do-nothing jit with the planner's arguments, and XLA's
    cost analysis of one compiled plan."""
    n = len(bels)
    key = jax.random.key(0)
    args = [(key, models, D1, bels[e].trip, bels[e].scale, fgs[e], goals[e], bels[e].frame,
             bels[e].robot) for e in range(n)]
    nothing = jax.jit(lambda *a: a[7].sum())
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
    n_pp = min(max(sizes), 64)
    res = {"depth": a.depth, "n_actions": pp.n_actions, "n_beta": pp.n_beta,
           "per_plan": per_plan(models, D1, bels[:n_pp], fgs[:n_pp], goals[:n_pp], pp),
           "overheads": overheads(models, D1, bels[:64], fgs[:64], goals[:64], pp),
           "runs": [bench(models, D1, bels[:n], fgs[:n], goals[:n], pp, a.chunks)
                    for n in sizes]}
    print(json.dumps(res, indent=1))
    write_result(res, a.out)  # + env: where it ran, load; timings with CPU time
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
