"""Benchmark: the PQRM measurement kernel (P eq. 2.9) vs a straightforward NumPy estimator.

    .venv/bin/python benchmarks/bench_pqrm.py [--triplets N] [--samples S] [--json PATH]

Writes ``benchmarks/results/pqrm.json``. Inputs, references and targets
(docs/decisions.md §10): docs/benchmarks.md §bench_pqrm.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _env import write_result  # benchmarks/_env.py
from _timing import best_of, timed  # benchmarks/_timing.py

from pqrm_jax import calculi, pqrm
from pqrm_jax.pqrm import measurement
from pqrm_jax.pqrm.reference import (
    numpy_counts,
    numpy_fused_counts,
    numpy_state_probabilities,
)


def _study_step(runs: int) -> dict:
    """padgett-mc per-run time: dense reference runner vs sparse batched runner, same process.

    One chunk of ``runs`` runs at σ_R = 40 m (compiled and warmed up first, best of 3); the
    results of the two runners are compared for bit-identity.
    """
    from pqrm_jax.studies import padgett_mc as P

    cfg = P.Config(runs=runs, levels=1, chunk_runs=runs)
    out, times = {}, {}
    for name, dense in (("dense", True), ("sparse", False)):
        P.run_level(cfg, 0, 40.0, dense=dense)  # compile + warm up
        ts = []
        for _ in range(3):
            t0 = time.perf_counter()
            out[name] = P.run_level(cfg, 0, 40.0, dense=dense)
            ts.append(time.perf_counter() - t0)
        times[name] = min(ts) / runs
    same = all(np.array_equal(a, b, equal_nan=True) for a, b in zip(
        jax.tree_util.tree_leaves(out["dense"]), jax.tree_util.tree_leaves(out["sparse"]),
        strict=True))
    return {"what": "padgett-mc per-run time, sigma_r = 40 m, all six representations",
            "runs": runs, "dense_s_per_run": times["dense"],
            "sparse_s_per_run": times["sparse"],
            "speedup": times["dense"] / times["sparse"], "bit_identical": bool(same)}


def _kernel_vs_previous(means, sigma, key, s: int) -> dict:
    """The kernel alone on a given bank, this formulation against the previous one, in one
    process, interleaved (best of 7 each, CPU time beside wall): the same arithmetic and
    blocks. Current: ``measurement._counts_all_blocks`` as ``fine_counts`` runs it (bank
    sample-major, [c, 6, C], ``KERNEL_COMPILER_OPTIONS``). Previous: the block loop as it was
    (each block's counts unpacked inside the loop) reading the bank row-major, [c, C, 6] —
    six values of a sample 6 floats apart, gathered by XLA's loop along the samples with
    shuffles — under XLA's default options."""
    n = means.shape[0]
    blk = measurement._balanced_block(n, 4096)  # noqa: SLF001  (the blocks fine_counts uses)
    mT, sT = measurement._prepare_edc(jnp.asarray(means), jnp.asarray(sigma),  # noqa: SLF001
                                      chunk_triplets=4096)
    nblk = mT.shape[1] // blk
    z_rows = measurement.sample_bank(key, s, jnp.float32)  # [c, C, 6]
    z_major = measurement.sample_bank(key, s, jnp.float32, sample_major=True)  # [c, 6, C]

    def previous_blocks(z):
        mB = mT.reshape(6, nblk, blk).transpose(1, 0, 2)
        sB = sT.reshape(3, nblk, blk).transpose(1, 0, 2)
        zc = jnp.swapaxes(z, 1, 2)  # fused into the loop by XLA: strided reads, as before
        out = jax.lax.map(lambda a: measurement.edc_block_counts(a[0], a[1], zc), (mB, sB))
        return out.reshape(nblk * blk, -1)

    previous = jax.jit(previous_blocks)
    current = jax.jit(lambda z: measurement._counts_all_blocks(mT, sT, z, nblk, blk),  # noqa: SLF001
                      compiler_options=measurement.KERNEL_COMPILER_OPTIONS)
    same = bool(np.array_equal(np.asarray(previous(z_rows)), np.asarray(current(z_major))))
    runs = {"previous": [], "current": []}
    for _ in range(7):
        for name, f, z in (("previous", previous, z_rows), ("current", current, z_major)):
            wall, cpu, _ = timed(lambda f=f, z=z: f(z))
            runs[name].append((wall, cpu))
    best = {k: min(v) for k, v in runs.items()}  # (wall, CPU of that run)
    return {"what": "EDC kernel on a given bank, previous (row-major bank, default XLA "
                    "options) vs current (sample-major bank, KERNEL_COMPILER_OPTIONS)",
            "previous_s": best["previous"][0], "previous_cpu_s": best["previous"][1],
            "current_s": best["current"][0], "current_cpu_s": best["current"][1],
            "previous_triplet_samples_per_s": n * s / best["previous"][0],
            "current_triplet_samples_per_s": n * s / best["current"][0],
            "ratio": best["previous"][0] / best["current"][0], "counts_identical": same,
            "all_wall_cpu_s": runs}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--triplets", type=int, default=7200, help="N (10 maps of 10 landmarks)")
    ap.add_argument("--samples", type=int, default=1024, help="S per triplet")
    ap.add_argument("--out", "--json", dest="json",
                    default=str(Path(__file__).parent / "results" / "pqrm.json"))
    ap.add_argument("--study-runs", type=int, default=50,
                    help="runs for the padgett-mc per-run comparison (0: skip)")
    args = ap.parse_args(argv)
    n, s = args.triplets, args.samples
    key = jax.random.key(0)
    rng = np.random.default_rng(0)
    means = rng.uniform(0, 100, (n, 3, 2)).astype(np.float32)
    sigma = rng.uniform(0, 20, (n, 3)).astype(np.float32)
    work = n * s

    means_j, sigma_j = jax.device_put(means), jax.device_put(sigma)
    pqrm.fine_counts(key, "edc", means_j, sigma_j, s)  # compile
    t_jax, counts = best_of(lambda: pqrm.fine_counts(key, "edc", means_j, sigma_j, s), 5)
    reps = calculi.PADGETT_REPRESENTATIONS
    pqrm.multi_state_probabilities(key, reps, means_j, sigma_j, s)
    t_multi, _ = best_of(lambda: pqrm.multi_state_probabilities(key, reps, means_j, sigma_j, s),
                       5)

    z = np.asarray(measurement.sample_bank(key, s, np.float32)).reshape(-1, 3, 2)[:s]
    t_np, p_np = best_of(lambda: numpy_state_probabilities(rng, "edc", means, sigma, s, z=z), 3)
    t_np_ind, _ = best_of(lambda: numpy_state_probabilities(rng, "edc", means, sigma, s), 1)
    ref = numpy_counts("edc", means[:, None] + sigma[:, None, :, None] * z[None])
    mismatch = int(np.abs(np.asarray(counts) - ref).sum())
    t_fused, fused = best_of(lambda: numpy_fused_counts(means, sigma, z), 3)
    fused_mismatch = int(np.abs(np.asarray(counts) - fused).sum())

    res = {
        "what": "PQRM eq. 2.9 EDC state counts, shared Gaussian bank, same inputs",
        "triplets": n, "samples": s, "triplet_samples": work,
        "jax_s": t_jax, "jax_triplet_samples_per_s": work / t_jax,
        "jax_six_representations_s": t_multi,
        "numpy_s": t_np, "numpy_triplet_samples_per_s": work / t_np,
        "numpy_independent_draws_s": t_np_ind,
        "speedup_vs_numpy": t_np / t_jax,
        "speedup_vs_numpy_independent_draws": t_np_ind / t_jax,
        "count_mismatch_vs_numpy_same_draws": mismatch,
        "numpy_fused_s": t_fused, "speedup_vs_numpy_fused": t_fused / t_jax,
        "count_mismatch_vs_numpy_fused": fused_mismatch,
        "targets": {"speedup": 50, "triplet_samples_per_s": 1e9},
        "meets_speedup_target": t_np / t_jax >= 50,
        "meets_throughput_target": work / t_jax >= 1e9,
        "devices": [str(d) for d in jax.devices()], "cpu_count": os.cpu_count(),
        "load_average": os.getloadavg(), "machine": platform.processor() or platform.machine(),
        "jax": jax.__version__, "numpy": np.__version__,
    }
    res["kernel_vs_previous"] = _kernel_vs_previous(means, sigma, key, s)
    if args.study_runs:
        res["study_step"] = _study_step(args.study_runs)
    print(json.dumps(res, indent=2))
    if args.json:
        write_result(res, args.json)  # + env: where it ran; timings with CPU time
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
