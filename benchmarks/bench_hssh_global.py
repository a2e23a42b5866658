"""HSSH global layout relaxation batched over map hypotheses vs one hypothesis at a time.

The same Levenberg–Marquardt spring relaxation (:func:`pqrm_jax.hssh_global.relax`, ``vmap``
over the leaves of the tree of maps) against :func:`pqrm_jax.hssh_global.relax_loop` (the same
jitted function called once per hypothesis, compiled once), for the block-sparse Jacobian (the
default) and the dense ``jacfwd`` one (``jacobian="dense"``, the earlier implementation); also
dense over sparse, both batched. Compile time is excluded (one warm-up call each). Costs agree
(checked, also sparse against dense). Writes ``benchmarks/results/hssh_global.json``.

    .venv/bin/python benchmarks/bench_hssh_global.py [--quick]
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import jax
import numpy as np
from _env import write_result  # benchmarks/_env.py
from _timing import best_of

from pqrm_jax import hssh_global as hg


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "hssh_global.json"))
    a = ap.parse_args()
    cases = [(3, 3, 16, 5, 1), (4, 3, 24, 5, 1)] if a.quick else [(3, 3, 16, 5, 1),
                                                                  (4, 3, 24, 5, 1),
                                                                  (4, 4, 30, 3, 2)]
    rows = []
    for nx_, ny, n, ws, es in cases:
        w = hg.grid_world(nx_, ny, loop_prob=0.6, seed=ws)
        e = hg.explore(w, n, seed=es)
        leaves = hg.build_tree(e).leaves
        prob = hg.pack(leaves, e.odometry)
        row = {"world": f"{nx_}x{ny}", "travels": n, "hypotheses": len(leaves),
               "places_max": int(prob.init.shape[1])}
        costs = {}
        for jac in ("sparse", "dense"):
            hg.relax(prob, jacobian=jac)
            hg.relax_loop(LayoutSlice(prob, 1), jacobian=jac)
            tb, (_, cb) = best_of(lambda prob=prob, jac=jac: hg.relax(prob, jacobian=jac))
            tl, (_, cl) = best_of(lambda prob=prob, jac=jac: hg.relax_loop(prob, jacobian=jac),
                                  n=2)
            np.testing.assert_allclose(np.asarray(cb), np.asarray(cl), rtol=1e-3, atol=1e-3)
            costs[jac] = np.asarray(cb)
            row.update({f"{jac}_batched_s": tb, f"{jac}_loop_s": tl,
                        f"{jac}_loop_over_batched": tl / tb})
        np.testing.assert_allclose(costs["sparse"], costs["dense"], rtol=1e-3, atol=1e-3)
        row["dense_over_sparse_batched"] = row["dense_batched_s"] / row["sparse_batched_s"]
        rows.append(row)
        print(rows[-1])
    out = {"benchmark": "hssh_global layout relaxation", "backend": jax.default_backend(),
           "devices": str(jax.devices()), "cpu_count": os.cpu_count(), "rows": rows}
    path = write_result(out, a.out)  # + env and timings with CPU time
    print("wrote", path)


def LayoutSlice(prob, k):  # noqa: N802 - a small view of the first k hypotheses (warm-up)
    return hg.LayoutProblem(*(x[:k] for x in prob))


if __name__ == "__main__":
    main()
