"""Benchmark and evidence for composition propagation (issue #6 items 4 and 5).

Usage::

    .venv/bin/python benchmarks/bench_compositions.py            # full run (a few minutes)
    .venv/bin/python benchmarks/bench_compositions.py --quick    # smoke run
    .venv/bin/python benchmarks/bench_compositions.py --json out.json

The two parts and the composition tensor used: docs/benchmarks.md §bench_compositions.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import jax
import numpy as np
from _env import device_info, write_result  # benchmarks/_env.py

from pqrm_jax import calculi
from pqrm_jax.compositions.propagation import propagate, propagate_loop
from pqrm_jax.compositions.simulation import heldout_study, sample_compose_tensor


def get_tensor(calc, samples: int = 4_000_000):
    """The exact-core tensor if available, else a sampled one; returns (tensor, source)."""
    try:
        t = np.asarray(calc.tables.prob_compose, np.float32)
        return t, "calc.tables.prob_compose"
    except Exception:  # noqa: BLE001 - tables not built in this checkout
        t, _ = sample_compose_tensor(calc, jax.random.key(7), samples)
        return t, f"sample_compose_tensor({samples} samples)"


def random_map(n: int, q: int, seed: int = 0, fraction: float = 1.0):
    rng = np.random.default_rng(seed)
    p = rng.dirichlet(np.full(q, 0.3), size=(n, n, n)).astype(np.float32)
    i, j, k = np.ogrid[:n, :n, :n]
    obs = (i != j) & (j != k) & (i != k) & (rng.random((n, n, n)) < fraction)
    return p, obs


def best_of(fn, repeats: int) -> float:
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        best = min(best, time.perf_counter() - t0)
    return best


def bench_speed(tensor, n: int = 30, repeats: int = 3):
    q = tensor.shape[0]
    p, obs = random_map(n, q)
    t0 = time.perf_counter()
    res = propagate(p, obs, tensor, mode="fuse")
    jax.block_until_ready(res.probs)
    first = time.perf_counter() - t0
    batched = best_of(lambda: propagate(p, obs, tensor, mode="fuse").probs, repeats)
    out = {"landmarks": n, "states": q, "targets": int(obs.sum()),
           "pairs": int(np.asarray(res.n_paths).sum()), "batched_s": batched,
           "batched_first_call_s": first}
    for backend in ("numpy", "jax"):
        t0 = time.perf_counter()
        lp, _ = propagate_loop(p, obs, tensor, mode="fuse", backend=backend)
        dt = time.perf_counter() - t0
        out[f"loop_{backend}_s"] = dt
        out[f"speedup_vs_{backend}_loop"] = dt / batched
        out[f"max_abs_diff_vs_{backend}_loop"] = float(np.abs(lp - np.asarray(res.probs)).max())
    return out


def bench_scaling(tensor, sizes, repeats: int = 2):
    rows = []
    for n in sizes:
        p, obs = random_map(n, tensor.shape[0], seed=n)
        propagate(p, obs, tensor, mode="fuse").probs.block_until_ready()
        rows.append({"landmarks": n, "batched_s": best_of(
            lambda p=p, obs=obs: propagate(p, obs, tensor, mode="fuse").probs, repeats)})
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes (smoke test)")
    ap.add_argument("--out", "--json", dest="out", help="also write the results to this file")
    ap.add_argument("--calculus", default="edc")
    args = ap.parse_args(argv)
    calc = calculi.get(args.calculus)
    tensor, source = get_tensor(calc, 400_000 if args.quick else 4_000_000)
    results: dict = {"calculus": calc.name, "tensor": source, "jax_backend": jax.default_backend(),
                     "devices": len(jax.devices())}
    n = 10 if args.quick else 30
    results["speed"] = bench_speed(tensor, n=n, repeats=2 if args.quick else 3)
    results["env"] = device_info()  # backend, device kind (benchmarks/_env.py)
    print(json.dumps(results["speed"], indent=1), flush=True)
    sizes = (6, 8, 10) if args.quick else (10, 15, 20, 30, 40, 50)
    results["scaling"] = bench_scaling(tensor, sizes)
    for r in results["scaling"]:
        print(f"L={r['landmarks']:3d}  batched {r['batched_s'] * 1e3:9.1f} ms", flush=True)
    study = []
    grid = [(0.5, 5.0)] if args.quick else [(f, s) for f in (0.1, 0.25, 0.5)
                                            for s in (2.0, 5.0, 10.0)]
    for frac, sigma in grid:
        r = heldout_study(calc, tensor, jax.random.key(2024), num_landmarks=8 if args.quick
                          else 20, fraction=frac, sigma=sigma, runs=1 if args.quick else 5,
                          samples=128 if args.quick else 256, rounds=2)
        study.append({"fraction": frac, "sigma": sigma, **r})
        h0, hm, hp = r["heldout/uniform"], r["heldout/marginal"], r["heldout/propagated"]
        om, of = r["observed/measured"], r["observed/fused"]
        print(f"f={frac:.2f} σ={sigma:4.1f} held-out error/entropy/NLL: "
              f"uniform {h0['error']:.3f}/{h0['entropy']:.2f}/{h0['nll']:.2f}  "
              f"marginal {hm['error']:.3f}/{hm['entropy']:.2f}/{hm['nll']:.2f}  "
              f"propagated {hp['error']:.3f}/{hp['entropy']:.2f}/{hp['nll']:.2f} "
              f"(coverage {hp['coverage']:.2f}) | observed: measured "
              f"{om['error']:.3f}/{om['entropy']:.2f}/{om['nll']:.2f} fused "
              f"{of['error']:.3f}/{of['entropy']:.2f}/{of['nll']:.2f}", flush=True)
    results["heldout"] = study
    if args.out:
        write_result(results, args.out)  # + env and timings with CPU time
    return 0


if __name__ == "__main__":
    sys.exit(main())
