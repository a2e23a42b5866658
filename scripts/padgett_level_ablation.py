"""Where a padgett-mc level's CPU goes, by ablation (issue 31, docs/benchmarks.md §bench_padgett).

    .venv/bin/python scripts/padgett_level_ablation.py [--runs 1000] [--sigma 20]
                                                       [--repeat 5] [--out F.json]

One noise level of the study's configuration (``--runs`` runs in one chunk), compiled as
the study compiles it (``padgett_mc.chunk_program``), against the same program with
parts of the sparse update's piece loop (``pqrm.map``'s per-group update) taken out, one
more each variant:

* ``study`` — the study's program;
* ``no_row_update`` — each piece samples its rows (bank gather, kernel) but reads and writes
  no map row: no row gathers, no eq. 2.10, no counters, no scatters (a sum of the counts
  keeps the kernel alive);
* ``no_bank_draws`` — also the per-step bank of normal draws replaced by a constant table of
  normals (one bank per map, gathered per row as before; a constant *value* would let XLA
  fold the kernel away);
* ``no_kernel`` — also no sampling kernel: the pieces only gather their rows' inputs;
* ``no_piece_loop`` — no pieces at all: what is left is the observations, the metrics at
  the end and the scan.

The variants' results are not the study's (they are ablations); each program is compiled
once and the programs are called in turn, ``--repeat`` times (best and median wall and
process CPU seconds). The differences between neighbours are what each part costs.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from pqrm_jax.pqrm import map as pqrm_map
from pqrm_jax.pqrm.measurement import edc_block_counts, key_to_edc_state
from pqrm_jax.studies import padgett_mc as P

VARIANTS = ("study", "no_row_update", "no_bank_draws", "no_kernel", "no_piece_loop")


def ablated_update(variant: str):
    """A stand-in for the per-group sparse update with the parts of ``variant`` taken out."""
    def update(z, m, s, mask, rows, *, most_seen, n, block, cals, mode):
        total = mask.shape[0]
        order, num_seen, blk, _ = pqrm_map._seen_order(mask, block)  # as the study compacts
        bank = z
        if variant != "no_row_update":  # a constant table of normals instead of the draws
            bank = jnp.asarray(np.random.default_rng(0).standard_normal(z.shape), z.dtype)
        inv = np.argsort(key_to_edc_state())

        def piece(c):
            p, acc = c
            idx = jax.lax.dynamic_slice(order, (p * blk,), (blk,))
            valid = idx < total
            safe = jnp.where(valid, idx, 0)
            zc = jnp.transpose(bank[safe // n], (1, 2, 3, 0))
            if variant == "no_kernel":
                kept = (jnp.sum(jnp.where(valid[:, None], m[safe], 0)) + jnp.sum(s[safe])
                        + jnp.sum(zc[0, 0, 0]))
                return p + 1, acc + kept.astype(jnp.int32)
            counts = edc_block_counts(m[safe].T, s[safe].T, zc)[:, inv]
            return p + 1, acc + jnp.sum(jnp.where(valid[:, None], counts, 0))

        if variant == "no_piece_loop":
            acc = num_seen
        else:
            acc = jax.lax.while_loop(lambda c: c[0] * blk < num_seen, piece,
                                     (jnp.int32(0), jnp.int32(0)))[1]
        probs, mapped, num_updates, num_conflicts, num_rejected = rows
        mapped = mapped.at[0].set(mapped[0] | (acc < 0))  # never true: keeps acc alive
        return probs, mapped, num_updates, num_conflicts, num_rejected

    return update


def ablate(runs: int, sigma: float, repeat: int) -> dict:
    cfg, _ = P.configure(["--runs", str(runs), "--fresh", "--out", "/dev/null"])
    cfg = dataclasses.replace(cfg, chunk_runs=runs)
    study_update = pqrm_map._sparse_group_update
    progs = {}
    try:
        for v in VARIANTS:
            pqrm_map._sparse_group_update = study_update if v == "study" else ablated_update(v)
            P._COMPILED.clear()
            progs[v], sharding = P.chunk_program(cfg, runs)  # as the study compiles it
    finally:
        pqrm_map._sparse_group_update = study_update
        P._COMPILED.clear()
    keys = jax.device_put(P.run_keys(cfg, 0, np.arange(runs)), sharding)  # level 0's runs
    times = {v: [] for v in VARIANTS}
    for _ in range(repeat):
        for v, prog in progs.items():
            t0, c0 = time.perf_counter(), time.process_time()
            out = jax.device_get(prog(keys, jnp.float32(sigma)))
            times[v].append((time.perf_counter() - t0, time.process_time() - c0))
            if v == "study" and not np.asarray(out["n_updates"]).sum() > 0:
                raise SystemExit("the study's program updated no row")
    res = {"runs": runs, "sigma_r": sigma, "repeat": repeat, "variants": {}}
    for v in VARIANTS:
        w = sorted(t[0] for t in times[v])
        c = sorted(t[1] for t in times[v])
        res["variants"][v] = {"wall_best_s": w[0], "wall_median_s": w[len(w) // 2],
                              "cpu_best_s": c[0], "cpu_median_s": c[len(c) // 2],
                              "all": times[v]}
        print(f"{v:14s} wall best {w[0]:.3f} s (median {w[len(w) // 2]:.3f}), "
              f"CPU best {c[0]:.3f} s (median {c[len(c) // 2]:.3f})", flush=True)
    cpu = [res["variants"][v]["cpu_best_s"] for v in VARIANTS]
    res["cpu_parts_s"] = {"row update": cpu[0] - cpu[1], "bank draws": cpu[1] - cpu[2],
                          "kernel": cpu[2] - cpu[3], "piece inputs and compaction":
                          cpu[3] - cpu[4], "rest (observations, metrics)": cpu[4]}
    for k, v in res["cpu_parts_s"].items():
        print(f"  {k:30s} {v:6.3f} CPU-s ({v / cpu[0]:5.1%})")
    res["load_average"] = os.getloadavg()
    res["date"] = time.strftime("%Y-%m-%d %H:%M:%S")
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--sigma", type=float, default=20.0, help="σ_R of the level (m)")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--out", default=None, help="also write the figures as JSON")
    args = ap.parse_args(argv)
    if args.runs < 1 or args.repeat < 1:
        ap.error("--runs and --repeat must be ≥ 1")
    os.environ.setdefault("PQRM_JAX_COMPILE_CACHE", "off")
    res = ablate(args.runs, args.sigma, args.repeat)
    if args.out:
        with open(args.out, "w") as f:
            json.dump(res, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
