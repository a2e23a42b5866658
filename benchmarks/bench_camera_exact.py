"""Camera measurement vs the exact z3 oracle by bearing spread (issue #14).

Random triples whose three bearings lie in a sector of width ``spread`` (uniform in the
sector, random sector, slots = range order near, mid, far); for each spread bucket the mean
number of states kept per cyclic relation by :func:`pqrm_jax.qrm.camera.measure_triples`
beside the exact count of :func:`pqrm_jax.qrm.camera_oracle.oracle_sets`, the share of
relations whose measured set equals the exact set, the share of triples keeping all 20, the
share of relations whose first measurement removes at least half the states (≤ 10 kept), and
the exact path (``measure_triples(exact=True)``: sweep-seeded kernel + z3) against the oracle.

    .venv/bin/python benchmarks/bench_camera_exact.py [--per-bucket 40] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from pqrm_jax.qrm import camera as C
from pqrm_jax.qrm.camera_oracle import oracle_sets
from pqrm_jax.qrm.spec import popcount, qrm_spec

SPREADS = (0.3, 1.0, 2.0, 2 * np.pi)


def triples(spread: float, count: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    c = rng.uniform(-np.pi, np.pi, (count, 1))
    return (c + rng.uniform(0, spread, (count, 3))).astype(np.float64)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--per-bucket", type=int, default=40)
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "camera_exact.json"))
    a = ap.parse_args()
    spec = qrm_spec("edc")
    res = {"per_bucket": a.per_bucket, "buckets": {}}
    for i, s in enumerate(SPREADS):
        b = triples(s, a.per_bucket, 100 + i).astype(np.float32)
        t0 = time.perf_counter()
        exact = np.stack([oracle_sets(row, spec) for row in b])
        t_or = time.perf_counter() - t0
        t0 = time.perf_counter()
        kern = C.measure_triples(b, spec, exact=False)
        meas, und = np.asarray(kern.sets), np.asarray(kern.undecided)
        t_k = time.perf_counter() - t0
        kept, ex = popcount(meas), popcount(exact)
        out = {"spread": s, "mean_kept": float(kept.mean()), "mean_exact": float(ex.mean()),
               "mean_undecided": float(popcount(und).mean()),
               "equal_share": float((meas == exact).mean()),
               "all20_triple_share": float((kept == 20).all(-1).mean()),
               "sound": bool(np.all((exact & ~meas) == 0)),
               "first_half_removed_share_kernel": float((kept <= 10).mean()),
               "first_half_removed_share_exact": float((ex <= 10).mean()),
               "oracle_s": t_or, "kernel_s_incl_compile": t_k}
        if hasattr(kern, "exact_decisions"):
            t0 = time.perf_counter()
            em = C.measure_triples(b, spec, exact=True)
            out["exact_path_s"] = time.perf_counter() - t0
            out["exact_path_equal_share"] = float((np.asarray(em.sets) == exact).mean())
            out["exact_path_z3_decisions_per_relation"] = em.exact_decisions / exact.size
        res["buckets"][f"{s:.3f}"] = out
        print(f"spread {s:5.3f}: kept {out['mean_kept']:5.2f} vs exact {out['mean_exact']:5.2f}"
              f" per relation, equal {out['equal_share']:.1%}, all-20 triples "
              f"{out['all20_triple_share']:.1%}, sound {out['sound']}, first >= half removed "
              f"{out['first_half_removed_share_kernel']:.1%} (exact "
              f"{out['first_half_removed_share_exact']:.1%})"
              + (f"; exact path equal {out['exact_path_equal_share']:.1%}, "
                 f"{out['exact_path_z3_decisions_per_relation']:.2f} z3 decisions/relation, "
                 f"{out['exact_path_s']:.1f} s" if "exact_path_s" in out else ""))
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
