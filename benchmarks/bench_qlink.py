"""Q-Link batched navigation vs one pair at a time (issue 15, docs/decisions.md §10).

The same executive (:func:`pqrm_jax.qlink.navigate_pairs`: localise, plan, drive) on the
same trials of one world: all B trials queued on a pool of 128 ``vmap``-ped lanes (a lane takes
the next trial as soon as its own ends) against a Python loop that drives one trial per call
(``chunk = 1``: one lane, compiled once). Compile time is excluded (one warm-up call
each). Both give identical outcomes (checked). Wall and process CPU time are both reported (the
CPU ratio is the one to read on a shared, loaded machine), with the load average. Writes
``benchmarks/results/qlink.json``.

    .venv/bin/python benchmarks/bench_qlink.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _env import write_result  # benchmarks/_env.py

from pqrm_jax import sim
from pqrm_jax.qlink import elements as qel
from pqrm_jax.qlink import linkgraph as lg
from pqrm_jax.qlink import navigate as nav
from pqrm_jax.qlink import pomdp

CHUNK = 128


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "qlink.json"))
    a = ap.parse_args()
    n_batch, n_loop = (128, 8) if a.quick else (512, 24)
    r = 20.0
    size = (100.0, 100.0)
    lm = sim.uniform_landmarks(jax.random.key(0), 50, size=size)
    el, _ = qel.from_mapping_run(jax.random.key(1), lm, sim.lawnmower(size, r, 1.0),
                                 sim.SensorParams(max_range=r, sigma=0.3))
    g = lg.link_graph(el, 2)
    lms = np.flatnonzero(qel.incidence(el).any(1))
    goal_row = np.full(el.num_landmarks, -1)
    goal_row[lms] = np.arange(len(lms))
    to_go = lg.goal_distances(g, el, lms)
    tables = nav.start_tables(el)
    rng = np.random.default_rng(0)
    pairs = np.array([(s, t) for s in lms for t in lms if s != t])
    pairs = pairs[rng.choice(len(pairs), n_batch, replace=False)]
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(2), i))(jnp.arange(n_batch))
    p = nav.NavParams(map_range=r, nav_range=0.8 * r, sigma=0.3, ds=r / 40, start_offset=r / 20)
    args = (lm, el, g, to_go, goal_row, tables)
    plans = nav.qsr_plans(el, pomdp.search_model(horizon=4))   # QSR plans, shared by both

    def batched():
        return nav.navigate_pairs(keys, *args, pairs[:, 0], pairs[:, 1], p, chunk=CHUNK,
                                  plans=plans)

    def one_at_a_time():
        return [nav.navigate_pairs(keys[i:i + 1], *args, pairs[i:i + 1, 0], pairs[i:i + 1, 1],
                                   p, chunk=1, plans=plans) for i in range(n_loop)]

    nav.navigate_pairs(keys[:1], *args, pairs[:1, 0], pairs[:1, 1], p, chunk=1,
                       plans=plans)                                                  # compile
    batched()                                                                        # compile
    t0, c0 = time.perf_counter(), time.process_time()
    res_b = batched()
    t_b, c_b = time.perf_counter() - t0, time.process_time() - c0
    t0, c0 = time.perf_counter(), time.process_time()
    res_l = one_at_a_time()
    t_l, c_l = time.perf_counter() - t0, time.process_time() - c0
    same = all(int(res_l[i].status[0]) == int(res_b.status[i]) and
               abs(float(res_l[i].length[0]) - float(res_b.length[i])) < 1e-3 * (
                   1 + float(res_b.length[i])) for i in range(n_loop))
    per_b, per_l = t_b / n_batch, t_l / n_loop
    # the drive alone (nav.navigate on planned paths), without the per-call host work
    plan = lg.plan_pairs(g, el, pairs[:, 0], pairs[:, 1])
    drv = (lm, el, pairs[:, 0], pairs[:, 1], plan.path, plan.n_elements, p)

    def drive_batched():
        return nav.navigate(keys, *drv, chunk=CHUNK, plans=plans)

    def drive_loop():
        return [nav.navigate(keys[i:i + 1], lm, el, pairs[i:i + 1, 0], pairs[i:i + 1, 1],
                             plan.path[i:i + 1], plan.n_elements[i:i + 1], p, chunk=1,
                             plans=plans) for i in range(n_loop)]

    drive_batched()
    drive_loop()
    t0 = time.perf_counter()
    jax.block_until_ready(drive_batched())
    td_b = (time.perf_counter() - t0) / n_batch
    t0 = time.perf_counter()
    jax.block_until_ready(drive_loop())
    td_l = (time.perf_counter() - t0) / n_loop
    out = {"trials_batched": n_batch, "chunk": CHUNK, "trials_loop": n_loop,
           "batched_s": round(t_b, 3),
           "loop_s": round(t_l, 3), "per_trial_batched_ms": round(1e3 * per_b, 2),
           "per_trial_loop_ms": round(1e3 * per_l, 2), "ratio": round(per_l / per_b, 1),
           "outcomes_identical": bool(same),
           "per_trial_batched_cpu_ms": round(1e3 * c_b / n_batch, 2),
           "per_trial_loop_cpu_ms": round(1e3 * c_l / n_loop, 2),
           "cpu_ratio": round((c_l / n_loop) / (c_b / n_batch), 1),
           "load_average": [round(x, 2) for x in os.getloadavg()],
           "drive_only_per_trial_batched_ms": round(1e3 * td_b, 2),
           "drive_only_per_trial_loop_ms": round(1e3 * td_l, 2),
           "drive_only_ratio": round(td_l / td_b, 1), "cpu_count": os.cpu_count(),
           "device": str(jax.devices()[0]), "setting": "50 landmarks, 100 m x 100 m, R = 20 m, "
           "R' = 0.8R, beta = 2, sigma = 0.3"}
    print(json.dumps(out, indent=1))
    write_result(out, a.out)  # + env: where it ran, load at the end; process CPU time


if __name__ == "__main__":
    main()
