"""Benchmark: batched SERGE trials vs a plain NumPy reference and a loop of jitted trials.

The batched program runs all trials in one program; the sequential loop runs the same jitted
trials one at a time.

    .venv/bin/python benchmarks/bench_serge.py [--trials T] [--seq-trials S] [--ref-trials R]
                                               [--json PATH] [--one-core]

What each reported ratio compares and how the reference is timed: docs/benchmarks.md §bench_serge.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

if "--one-core" in sys.argv:  # before JAX starts its thread pool (threads inherit this)
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})

import jax
import numpy as np
from _env import write_result  # benchmarks/_env.py
from _timing import best_of  # benchmarks/_timing.py

from pqrm_jax._parallel import default_queues
from pqrm_jax.serge import Grid, initial_cells, scenes, serge, serge_sequential
from pqrm_jax.serge.reference import serge_reference
from pqrm_jax.serge.relaxed import relaxed_serge


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=None, help="batched trials (default 100·K)")
    ap.add_argument("--seq-trials", type=int, default=None, help="sequential trials measured")
    ap.add_argument("--ref-trials", type=int, default=50,
                    help="trials of the NumPy reference measured (scaled to T)")
    ap.add_argument("--mu", type=int, default=20)
    ap.add_argument("--sigma", type=float, default=2.0)
    ap.add_argument("--out", "--json", dest="json", default=None)
    ap.add_argument("--one-core", action="store_true",
                    help="run the whole process on one core (the NumPy reference's resources)")
    args = ap.parse_args(argv)

    sc = scenes.lab()
    grid = Grid.covering(np.concatenate(sc.points), (96, 96))
    t0 = time.perf_counter()
    prob = initial_cells(jax.random.PRNGKey(0), sc.beliefs(), grid)
    t_init = time.perf_counter() - t0
    t_trials = args.trials or 100 * sc.k + 1
    s_trials = min(args.seq_trials or t_trials, t_trials)
    key = jax.random.PRNGKey(0)

    # warm-up (compilation) of both programs
    serge(key, prob, args.mu, args.sigma, trials=t_trials)
    serge_sequential(key, prob, args.mu, args.sigma, trials=2)
    serge_sequential(key, prob, args.mu, args.sigma, trials=2, branch=True)
    t_batched, rb = best_of(lambda: serge(key, prob, args.mu, args.sigma, trials=t_trials))
    t0 = time.perf_counter()
    rs = serge_sequential(key, prob, args.mu, args.sigma, trials=s_trials)
    t_seq = (time.perf_counter() - t0) * t_trials / s_trials
    t0 = time.perf_counter()
    serge_sequential(key, prob, args.mu, args.sigma, trials=s_trials, branch=True)
    t_seq_cond = (time.perf_counter() - t0) * t_trials / s_trials
    steps = float(np.sum(rb.iterations))
    # same keys ⇒ same trials: check the measured ones agree (chunking changes the keys
    # only when T exceeds the chunk size, so compare on a small batched run)
    small = serge(key, prob, args.mu, args.sigma, trials=min(s_trials, 256))
    small_seq = serge_sequential(key, prob, args.mu, args.sigma, trials=min(s_trials, 256))
    agree = bool(np.allclose(small.trial_log_psi, small_seq.trial_log_psi, atol=1e-4))
    # the plain NumPy reference (the team's usual reference), on R trials scaled to T, and
    # the same R trials batched (same keys) to check it reproduces them
    r_trials = min(args.ref_trials, t_trials)
    # warm-up: the seeds are derived with jax.random (split + bits), compiled per shape
    serge_reference(key, prob, args.mu, args.sigma, trials=r_trials)
    t_ref_meas, rn = best_of(
        lambda: serge_reference(key, prob, args.mu, args.sigma, trials=r_trials))
    t_ref = t_ref_meas * t_trials / r_trials
    rb_r = serge(key, prob, args.mu, args.sigma, trials=r_trials)
    ref_dlp = float(np.max(np.abs(rn.trial_log_psi - rb_r.trial_log_psi)))
    ref_agree = bool(np.array_equal(rn.iterations, rb_r.iterations) and ref_dlp <= 1e-5
                     and np.array_equal(rn.cell_labels, rb_r.cell_labels))
    relaxed_serge(key, prob, args.mu, args.sigma)          # warm-up
    t_rel, rr = best_of(lambda: relaxed_serge(key, prob, args.mu, args.sigma), 2)
    out = {
        "scene": "lab (55 objects)", "grid": list(grid.shape), "mu": args.mu,
        "sigma": args.sigma, "trials": t_trials, "seq_trials_measured": s_trials,
        "initial_cells_s": t_init, "batched_s": t_batched, "sequential_s": t_seq,
        "speedup": t_seq / t_batched, "batched_equals_sequential": agree,
        "sequential_cond_s": t_seq_cond, "speedup_vs_cond": t_seq_cond / t_batched,
        "batched_us_per_trial_step": t_batched / steps * 1e6,
        "sequential_us_per_step": t_seq / steps * 1e6,
        "sequential_cond_us_per_step": t_seq_cond / steps * 1e6,
        "time_per_solve_s": t_batched, "n_regions": rb.n_regions, "log_psi": rb.log_psi,
        "sequential_best_log_psi": rs.log_psi,
        "numpy_reference_s": t_ref, "numpy_reference_measured_s": t_ref_meas,
        "numpy_reference_trials": r_trials, "speedup_vs_numpy": t_ref / t_batched,
        "numpy_reference_us_per_step": t_ref_meas / float(np.sum(rn.iterations)) * 1e6,
        "numpy_reference_equals_batched": ref_agree,
        "numpy_reference_max_abs_dlogpsi": ref_dlp,
        "numpy_reference_best_log_psi": rn.log_psi,
        "relaxed_s": t_rel, "relaxed_log_psi": rr.result.log_psi,
        "relaxed_n_regions": rr.result.n_regions, "devices": str(jax.devices()),
        "cores": len(os.sched_getaffinity(0)), "queues": default_queues(),
    }
    for k, v in out.items():
        print(f"{k:32s} {v:.4g}" if isinstance(v, float) else f"{k:32s} {v}")
    if args.json:
        write_result(out, args.json)  # + env: where it ran; timings with CPU time
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
