"""Held-out study: PQRM maps with vs without composition propagation (Z eq. 2.4; issue #6).

``pqrm-jax study compositions-heldout [--landmarks 20 --runs 5 --fractions 0.1 0.25 0.5
--sigmas 2 5 10 --calculus edc --json out.json]``
"""

from __future__ import annotations

import argparse
import json

NAME = "compositions-heldout"
HELP = "held-out triplet prediction with vs without composition propagation (Z eq. 2.4)"


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog=f"pqrm-jax study {NAME}", description=HELP)
    ap.add_argument("--calculus", default="edc")
    ap.add_argument("--landmarks", type=int, default=20)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--samples", type=int, default=256, help="inverse-sensor samples")
    ap.add_argument("--fractions", type=float, nargs="+", default=[0.1, 0.25, 0.5])
    ap.add_argument("--sigmas", type=float, nargs="+", default=[2.0, 5.0, 10.0])
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--seed", type=int, default=2024)
    ap.add_argument("--json", help="write the results to this file")
    args = ap.parse_args(argv)

    import jax
    import numpy as np

    from .. import calculi
    from ..compositions.simulation import heldout_study, sample_compose_tensor

    calc = calculi.get(args.calculus)
    try:
        tensor, source = np.asarray(calc.tables.prob_compose, np.float32), "prob_compose"
    except ValueError:  # no probabilistic table (e.g. boundary-inclusive calculi)
        tensor, _ = sample_compose_tensor(calc, jax.random.key(args.seed + 1), 4_000_000)
        source = "sampled"
    print(f"calculus {calc.name}, tensor {source}, {args.landmarks} landmarks, "
          f"{args.runs} runs per cell")
    out = []
    for frac in args.fractions:
        for sigma in args.sigmas:
            r = heldout_study(calc, tensor, jax.random.key(args.seed),
                              num_landmarks=args.landmarks, fraction=frac, sigma=sigma,
                              runs=args.runs, samples=args.samples, rounds=args.rounds)
            out.append({"fraction": frac, "sigma": sigma, **r})
            for k, v in r.items():
                extra = f" coverage {v['coverage']:.2f}" if "coverage" in v else ""
                print(f"f={frac:.2f} σ={sigma:5.1f} {k:20s} error {v['error']:.3f} "
                      f"entropy {v['entropy']:.2f} NLL {v['nll']:.2f}{extra}", flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"calculus": calc.name, "tensor": source, "results": out}, fh, indent=1)
    return 0
