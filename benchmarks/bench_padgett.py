"""Benchmark: the padgett-mc runner on a fixed slice vs the runner of session 2 (issue 31).

    .venv/bin/python benchmarks/bench_padgett.py [--runs 200] [--sigma 50] [--repeat 3]
                                                 [--out benchmarks/results/padgett.json]

Slice: one noise level (σ_R = ``--sigma`` m) of the study's configuration (10 landmarks,
256 samples, the six representations, 23 poses), ``--runs`` runs in one call. In one process,
on the same keys:

* **reference** — the runner as merged before this change (main ``45bfc0d``), patched in
  with :class:`legacy`: the bank of draws by ``jax.random.normal`` (on the CPU JAX lowers its
  threefry hash as a rolled loop), the compact buffer chosen by a ``lax.cond`` (small or
  full), and the observation arithmetic fused into the per-triplet gathers (since session 9
  it shares the current code's row update, ``map._merge_counts`` included);
* **current** — ``padgett_mc.run_level`` as shipped: the same draws by the unrolled
  ``measurement.threefry2x32`` (bit-identical), each piece of seen rows scattered into the
  map the piece loop carries (``map.BUFFER_MODE = "direct"``), the per-landmark inputs
  computed once (``map.PREPARE_BARRIER``).

Every result leaf must be identical (``identical``: the changes move no bit;
``differing_leaves`` lists any that differ).

``layout`` (issue 31, numerics version 4): the same runs as the study now computes them on a
CPU — in chunks of ``padgett_mc.CPU_CHUNK_RUNS`` runs (evened out), compiled with
``padgett_mc.chunk_compiler_options()`` (no YNNPACK fusions) — against the layout before
that change: all runs in one call, compiled with the kernel's options only (YNNPACK's
reductions); warm times interleaved, the leaves that differ (only the declared float
metrics may) and the largest relative difference of each.

Times: the first call (compilation included) and the best of ``--repeat`` warm calls
(interleaved reference/current, so that a change of load hits both), wall and CPU seconds of
the process, per run and the ratio. The full study's time is measured with
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
from pqrm_jax.studies import padgett_mc  # noqa: E402


def LEGACY_sample_bank(key, num_samples: int, dtype, *, sample_major=False):  # noqa: N802
    """The bank of main ``45bfc0d`` (by ``jax.random.normal``), in the layout asked for."""
    nchunks = -(-num_samples // 255)
    size = -(-num_samples // nchunks)
    z = jax.random.normal(key, (num_samples, 6), dtype)
    pad = nchunks * size - num_samples
    if pad:
        z = jnp.concatenate([z, jnp.full((pad, 6), jnp.nan, dtype)])
    z = z.reshape(nchunks, size, 6)
    return jnp.swapaxes(z, 1, 2) if sample_major else z


class legacy:  # noqa: N801
    """Context: the runner of main ``45bfc0d`` (patched module settings, fresh programs)."""

    def __enter__(self):
        self.saved = (pqrm_map.sample_bank, pqrm_map.BUFFER_MODE, pqrm_map.PREPARE_BARRIER)
        pqrm_map.sample_bank = LEGACY_sample_bank
        pqrm_map.BUFFER_MODE, pqrm_map.PREPARE_BARRIER = "cond", False
        _forget()

    def __exit__(self, *exc):
        pqrm_map.sample_bank, pqrm_map.BUFFER_MODE, pqrm_map.PREPARE_BARRIER = self.saved
        _forget()


def _forget():
    padgett_mc._COMPILED.clear()
    padgett_mc._AOT.clear()


def _program(cfg):
    """(compiled chunk program, keys, first-call wall, first-call CPU) of ``cfg``'s runner."""
    keys = padgett_mc.run_keys(cfg, 0, np.arange(cfg.runs))  # level 0's runs
    wall, cpu, (prog, _) = timed(lambda: padgett_mc.chunk_program(cfg, cfg.runs))
    return prog, keys, wall, cpu


def _layout(cfg, sigma: float, repeat: int) -> dict:
    """The study's layout on this device (``padgett_mc.auto_chunk``: chunks of
    ``CPU_CHUNK_RUNS`` on a CPU; ``chunk_compiler_options()``) against one call of every run
    compiled with the kernel's options only (YNNPACK on); both through ``run_level``."""
    from pqrm_jax.pqrm.measurement import KERNEL_COMPILER_OPTIONS

    chunk = padgett_mc.auto_chunk(dataclasses.replace(cfg, chunk_runs=None))
    now = dataclasses.replace(cfg, chunk_runs=chunk)

    def before():
        saved = padgett_mc.CHUNK_COMPILER_OPTIONS
        padgett_mc.CHUNK_COMPILER_OPTIONS = dict(KERNEL_COMPILER_OPTIONS)
        try:
            return padgett_mc.run_level(cfg, 0, sigma)  # cfg: every run in one call
        finally:
            padgett_mc.CHUNK_COMPILER_OPTIONS = saved

    calls = {"one_call_ynn": before, "chunked": lambda: padgett_mc.run_level(now, 0, sigma)}
    times = {k: [] for k in calls}
    res = {}
    for _ in range(repeat + 1):  # the first pass warms up, interleaved
        for name, f in calls.items():
            wall, cpu, res[name] = timed(f)
            times[name].append((wall, cpu))
    out = {"chunk": chunk, "options": padgett_mc.chunk_compiler_options()}
    for name in calls:
        out[name] = {"warm_s": min(w for w, _ in times[name][1:]),
                     "warm_cpu_s": min(c for _, c in times[name][1:]),
                     "all_warm_s": [w for w, _ in times[name][1:]],
                     "all_warm_cpu_s": [c for _, c in times[name][1:]]}
    out["warm_ratio"] = out["one_call_ynn"]["warm_s"] / out["chunked"]["warm_s"]
    out["warm_cpu_ratio"] = out["one_call_ynn"]["warm_cpu_s"] / out["chunked"]["warm_cpu_s"]
    differ = {}
    for (p, a), b in zip(jax.tree_util.tree_leaves_with_path(res["one_call_ynn"]),
                         jax.tree_util.tree_leaves(res["chunked"]), strict=True):
        a, b = np.asarray(a), np.asarray(b)
        if not np.array_equal(a, b, equal_nan=True):
            rel = np.abs(a.astype(float) - b) / np.maximum(np.abs(a.astype(float)), 1e-30)
            differ[jax.tree_util.keystr(p)] = float(np.nanmax(rel))
    out["differing_leaves_max_rel"] = differ
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--sigma", type=float, default=50.0, help="σ_R of the slice (m)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "padgett.json"))
    args = ap.parse_args(argv)
    cfg = padgett_mc.Config(runs=args.runs, levels=1, chunk_runs=args.runs)
    out = {
        "config": {
            "runs": cfg.runs,
            "sigma_r": args.sigma,
            "landmarks": cfg.num_landmarks,
            "samples": cfg.num_samples,
            "representations": list(cfg.representations),
            "poses": 23,
            "sparse_block": padgett_mc.SPARSE_BLOCK,
        }
    }
    with legacy():
        ref_prog, keys, rw, rc = _program(cfg)
    cur_prog, _, cw, cc = _program(cfg)
    sigma = jnp.float32(args.sigma)
    runs = {"reference": ref_prog, "current": cur_prog}
    times = {k: [] for k in runs}
    res = {}
    for _ in range(args.repeat + 1):  # the first pass warms up, interleaved
        for name, prog in runs.items():
            wall, cpu, r = timed(lambda prog=prog: jax.device_get(prog(keys, sigma)))
            times[name].append((wall, cpu))
            res[name] = r
    stats = {}
    for name, first in (("reference", (rw, rc)), ("current", (cw, cc))):
        wall = min(w for w, _ in times[name][1:])
        cpu = min(c for _, c in times[name][1:])
        stats[name] = {
            "compile_s": first[0],
            "compile_cpu_s": first[1],
            "warm_s": wall,
            "warm_cpu_s": cpu,
            "per_run_ms": 1e3 * wall / cfg.runs,
            "per_run_cpu_ms": 1e3 * cpu / cfg.runs,
            "all_warm_s": [w for w, _ in times[name][1:]],
            "all_warm_cpu_s": [c for _, c in times[name][1:]],
        }
    ref, cur = stats["reference"], stats["current"]
    leaves_r = jax.tree_util.tree_leaves_with_path(res["reference"])
    leaves_c = jax.tree_util.tree_leaves(res["current"])
    differ = [
        jax.tree_util.keystr(p)
        for (p, a), b in zip(leaves_r, leaves_c, strict=True)
        if not np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True)
    ]
    out.update(
        {
            "reference": ref,
            "current": cur,
            "warm_ratio": ref["warm_s"] / cur["warm_s"],
            "warm_cpu_ratio": ref["warm_cpu_s"] / cur["warm_cpu_s"],
            "compile_cpu_ratio": ref["compile_cpu_s"] / cur["compile_cpu_s"],
            "identical": not differ,
            "differing_leaves": differ,
            "num_leaves": len(leaves_c),
        }
    )
    out["layout"] = lay = _layout(cfg, args.sigma, args.repeat)
    path = write_result(out, args.out)
    print(
        f"reference {ref['per_run_ms']:.2f} ms/run ({ref['per_run_cpu_ms']:.2f} CPU), "
        f"current {cur['per_run_ms']:.2f} ms/run ({cur['per_run_cpu_ms']:.2f} CPU): "
        f"{out['warm_ratio']:.2f}x wall, {out['warm_cpu_ratio']:.2f}x CPU; compile "
        f"{ref['compile_cpu_s']:.1f} -> {cur['compile_cpu_s']:.1f} CPU-s; identical: "
        f"{out['identical']} ({len(leaves_c)} leaves) -> {path}"
    )
    print(
        f"layout: one call (YNNPACK) {lay['one_call_ynn']['warm_cpu_s']:.2f} CPU-s, chunks of "
        f"{lay['chunk']} without {lay['chunked']['warm_cpu_s']:.2f} CPU-s "
        f"({lay['warm_cpu_ratio']:.2f}x CPU, {lay['warm_ratio']:.2f}x wall); differing leaves: "
        f"{sorted(lay['differing_leaves_max_rel'])}"
    )
    return 0


if __name__ == "__main__":
    t0 = time.perf_counter()
    raise SystemExit(main())
