"""Benchmark: the padgett-mc runner on a fixed slice vs the runner of before issue 31.

    .venv/bin/python benchmarks/bench_padgett.py [--runs 200] [--sigma 50] [--repeat 3]
                                                 [--out benchmarks/results/padgett.json]

Slice: one noise level (σ_R = ``--sigma`` m) of the study's configuration (10 landmarks,
256 samples, the six representations, 23 poses), ``--runs`` runs in one call. In one process:

* **reference** — the runner as it was before issue 31 (the ``LEGACY_*`` functions below:
  the rank of the truth by a stable ``argsort`` of every row, and the eq. 2.10 normaliser of
  numerics version 2), patched in;
* **current** — ``padgett_mc.run_level`` as shipped.

Both run the same keys. The discrete result leaves (counts, error and top-n rates, confusion,
neighbour distance, error locations) are identical (``identical_discrete``) except where the
declared numerics change 2 → 3 flips an ML state between two states within an ulp (listed in
``differing_discrete_leaves`` with the share of elements); the float leaves move by
``max_float_diff``. Times: the
first call (compilation included) and the best of ``--repeat`` warm calls, wall and CPU
seconds of the process, per run and the ratio; plus the compile of the one-run probe program
the former automatic chunk size compiled before the real one (``probe_compile_*``, now only
compiled when the whole level does not fit in memory). The full study's time is measured with
``/usr/bin/time -v`` (docs/benchmarks.md §bench_padgett).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _env import write_result  # noqa: E402
from _timing import timed  # noqa: E402

from pqrm_jax.pqrm import map as pqrm_map  # noqa: E402
from pqrm_jax.pqrm import metrics  # noqa: E402
from pqrm_jax.studies import padgett_mc  # noqa: E402


def LEGACY_topn_error_rates(probs, truth, mask):  # noqa: N802  (the pre-issue-31 code)
    order = jnp.argsort(-probs, axis=-1, stable=True)  # (T, Q) most likely first
    rank = jnp.argmax(order == truth[:, None], axis=-1)  # position of the truth
    q = probs.shape[-1]
    wrong = rank[:, None] >= jnp.arange(1, q + 1)[None, :]  # (T, Q)
    m = metrics.defined_mask(truth, mask, q)
    return jnp.sum(jnp.where(m[:, None], wrong, False), axis=0) / jnp.maximum(jnp.sum(m), 1)


def LEGACY_bayes(prior, meas, mapped, seen):  # noqa: N802  (numerics version 2)
    post = meas * prior  # LLVM may contract this product into the sum below (an FMA)
    z = post[:, :1]
    for q in range(1, post.shape[-1]):
        z = z + post[:, q:q + 1]
    conflict = seen & mapped & (z[:, 0] <= 0)
    post = post / jnp.where(z > 0, z, 1.0)
    new = jnp.where((seen & ~mapped)[:, None], meas, prior)
    new = jnp.where((seen & mapped & ~conflict)[:, None], post, new)
    return new, conflict


class legacy:  # noqa: N801
    """Context: the pre-issue-31 runner (patched module functions, fresh compiled programs)."""

    def __enter__(self):
        self.saved = (metrics.topn_error_rates, pqrm_map._bayes)
        metrics.topn_error_rates = LEGACY_topn_error_rates
        pqrm_map._bayes = LEGACY_bayes
        _forget()

    def __exit__(self, *exc):
        metrics.topn_error_rates, pqrm_map._bayes = self.saved
        _forget()


def _forget():
    padgett_mc._COMPILED.clear()
    padgett_mc._AOT.clear()


def _measure(cfg, sigma: float, repeat: int) -> dict:
    first_wall, first_cpu, res = timed(lambda: padgett_mc.run_level(cfg, 0, sigma))
    warm = [timed(lambda: padgett_mc.run_level(cfg, 0, sigma))[:2] for _ in range(repeat)]
    wall, cpu = min(warm)
    return {"first_call_s": first_wall, "first_call_cpu_s": first_cpu, "warm_s": wall,
            "warm_cpu_s": cpu, "per_run_ms": 1e3 * wall / cfg.runs,
            "per_run_cpu_ms": 1e3 * cpu / cfg.runs}, res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--sigma", type=float, default=50.0, help="σ_R of the slice (m)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "padgett.json"))
    args = ap.parse_args(argv)
    cfg = padgett_mc.Config(runs=args.runs, levels=1, chunk_runs=args.runs)
    out = {"config": {"runs": cfg.runs, "sigma_r": args.sigma, "landmarks": cfg.num_landmarks,
                      "samples": cfg.num_samples, "representations": list(cfg.representations),
                      "poses": 23}}
    with legacy():
        ref, ref_res = _measure(cfg, args.sigma, args.repeat)
        probe = dataclasses.replace(cfg, runs=1, chunk_runs=1)
        _forget()
        pw, pc, _ = timed(lambda: padgett_mc.chunk_program(probe, 1))
    cur, cur_res = _measure(cfg, args.sigma, args.repeat)
    leaves_r = jax.tree_util.tree_leaves_with_path(ref_res)
    leaves_c = jax.tree_util.tree_leaves(cur_res)
    differ, max_float = [], 0.0
    for (p, a), b in zip(leaves_r, leaves_c, strict=True):
        a, b = np.asarray(a), np.asarray(b)
        name = jax.tree_util.keystr(p)
        if name.endswith(("['entropy']", "['p_ml']", "['xy']", "['dab']")):
            max_float = max(max_float, float(np.nanmax(np.abs(a - b), initial=0.0)))
        elif not np.array_equal(a, b, equal_nan=True):
            differ.append(f"{name}: {float(np.mean(a != b)):.2g} of elements, max "
                          f"{float(np.max(np.abs(a.astype(float) - b))):.2g}")
    out.update({
        "reference": ref, "current": cur,
        "warm_ratio": ref["warm_s"] / cur["warm_s"],
        "warm_cpu_ratio": ref["warm_cpu_s"] / cur["warm_cpu_s"],
        "probe_compile_s": pw, "probe_compile_cpu_s": pc,
        "identical_discrete": not differ, "differing_discrete_leaves": differ,
        "max_float_diff": max_float, "num_leaves": len(leaves_c),
    })
    path = write_result(out, args.out)
    print(f"reference {ref['per_run_ms']:.2f} ms/run ({ref['per_run_cpu_ms']:.2f} CPU), "
          f"current {cur['per_run_ms']:.2f} ms/run ({cur['per_run_cpu_ms']:.2f} CPU): "
          f"{out['warm_ratio']:.2f}x wall, {out['warm_cpu_ratio']:.2f}x CPU; first call "
          f"{ref['first_call_s']:.1f} -> {cur['first_call_s']:.1f} s; probe compile "
          f"{pw:.1f} s; discrete identical: {out['identical_discrete']}, float leaves within "
          f"{max_float:.1e} -> {path}")
    return 0


if __name__ == "__main__":
    t0 = time.perf_counter()
    raise SystemExit(main())
