"""Held-out study: PQRM maps with vs without composition propagation (Z eq. 2.4; issue #6).

``pqrm-jax study compositions-heldout [--landmarks 20 --runs 5 --fractions 0.1 0.25 0.5
--sigmas 2 5 10 --calculus edc --out DIR --json out.json]``

Results go to the study store in ``--out`` (``results.json``, tidy ``results.csv``; lock,
study marker and config guard of :mod:`pqrm_jax.studies.store`); ``--json`` also writes
``results.json``'s content to another path.
"""

from __future__ import annotations

import argparse
from pathlib import Path

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
    ap.add_argument("--json", help="also write the results to this file")
    ap.add_argument("--out", default="out/compositions-heldout", help="study directory")
    args = ap.parse_args(argv)
    for flag, val, lo in (("--landmarks", args.landmarks, 3), ("--runs", args.runs, 1),
                          ("--samples", args.samples, 1), ("--rounds", args.rounds, 0)):
        if val < lo:
            ap.error(f"{flag} must be ≥ {lo}, got {val}")
    if not all(0.0 < f < 1.0 for f in args.fractions):
        ap.error(f"--fractions must lie in (0, 1), got {args.fractions}")
    if not all(s > 0 and s < float("inf") for s in args.sigmas):
        ap.error(f"--sigmas must be positive and finite, got {args.sigmas}")

    from .store import Store

    cfg = {k: v for k, v in vars(args).items() if k not in ("json", "out")}
    with Store.open(args.out, NAME, cfg) as st:
        return _run(args, st)


def _run(args: argparse.Namespace, st) -> int:
    """The study body (under the store's lock)."""
    import jax
    import numpy as np

    from .. import calculi
    from ..compositions.simulation import heldout_study, sample_compose_tensor
    from .store import atomic_write_json, tidy_rows

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
    doc = {"calculus": calc.name, "tensor": source, "results": out}
    st.write_json("results.json", doc)
    st.write_results_csv(tidy_rows(out, unit=lambda r: f"f={r['fraction']:g}/σ={r['sigma']:g}",
                                   skip=("fraction", "sigma")))
    if args.json:
        atomic_write_json(Path(args.json), doc)
    return 0
