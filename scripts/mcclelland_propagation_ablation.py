"""Why n = 9 leaves Fig. 7b's 'uniform' band in mcclelland-mc (docs/studies.md §mcclelland-mc).

    .venv/bin/python scripts/mcclelland_propagation_ablation.py [--runs 20] [--ns 6 9]
                                                                [--sweeps 64 1 0] [--out F.json]

The study's own layouts and poses (runs 0..R-1 of the full preset, seed 0) mapped with the
path-consistency propagation of each update capped at ``--sweeps`` (64: the study, the fixed
point; 1: one sweep per image; 0: none, the map is the intersection of the measured sets),
everything else the study's. Prints, per (n, sweeps), the final removed % and the final
"open states not adjacent to the truth" % (mean and standard deviation over the runs), the
same at image 10, and whether the truth was kept. About 4 minutes on 2 cores at 20 runs.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from pqrm_jax.qrm import run_sequence
from pqrm_jax.studies import mcclelland_mc as M


def ablate(runs: int, ns: list[int], sweeps: list[int]) -> dict:
    cfg = M.Config()
    out = {}
    for n in ns:
        for k in sweeps:
            t0 = time.perf_counter()
            mets = [run_sequence(*M.layout(cfg, r), n, "edc", tol=cfg.bearing_tol,
                                 max_sweeps=k)[1] for r in range(runs)]
            rm = np.stack([np.asarray(m.removed_pct) for m in mets])
            na = np.stack([np.asarray(m.not_adjacent_pct) for m in mets])
            out[f"n{n}_sweeps{k}"] = {
                "n": n, "max_sweeps": k, "runs": runs,
                "removed_final": float(rm[:, -1].mean()),
                "not_adjacent_final": float(na[:, -1].mean()),
                "not_adjacent_final_sd": float(na[:, -1].std()),
                "removed_img10": float(rm[:, min(9, rm.shape[1] - 1)].mean()),
                "not_adjacent_img10": float(na[:, min(9, na.shape[1] - 1)].mean()),
                "truth_kept": bool(all(np.asarray(m.truth_kept).all() for m in mets)),
                "seconds": time.perf_counter() - t0}
            r = out[f"n{n}_sweeps{k}"]
            print(f"n = {n:2d}, max_sweeps = {k:2d}: removed {r['removed_final']:5.1f} %, not "
                  f"adjacent {r['not_adjacent_final']:5.1f} ± {r['not_adjacent_final_sd']:.1f} % "
                  f"(image 10: {r['removed_img10']:.1f} / {r['not_adjacent_img10']:.1f} %), "
                  f"truth kept {r['truth_kept']}", flush=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--ns", type=int, nargs="+", default=[6, 9])
    ap.add_argument("--sweeps", type=int, nargs="+", default=[64, 1, 0])
    ap.add_argument("--out", default=None, help="also write the figures as JSON")
    args = ap.parse_args(argv)
    if args.runs < 1:
        ap.error("--runs must be ≥ 1")
    res = ablate(args.runs, args.ns, args.sweeps)
    if args.out:
        with open(args.out, "w") as f:
            json.dump(res, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
