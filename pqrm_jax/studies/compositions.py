"""Held-out study: PQRM maps with vs without composition propagation (Z eq. 2.4; issue #6).

``pqrm-jax study compositions-heldout [--landmarks 20 --runs 5 --fractions 0.1 0.25 0.5
--sigmas 2 5 10 --calculus edc --out DIR --json out.json]``

Results go to the study store in ``--out`` (``results.json``, tidy ``results.csv``; lock,
study marker and config guard of :mod:`pqrm_jax.studies.store`); ``--json`` also writes
``results.json``'s content to another path. As N processes on ``jax.distributed``
(``--coordinator/--processes/--process-id``; :mod:`pqrm_jax.studies.distributed`) the
(fraction, σ) cells are split over the processes and process 0 writes them.
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
    from . import distributed

    distributed.add_arguments(ap)
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

    skip = ("json", "out", "coordinator", "num_processes", "process_id", "init_timeout")
    cfg = {k: v for k, v in vars(args).items() if k not in skip}
    cluster = distributed.initialize_from(args)  # before any JAX computation
    distributed.agree(cluster, cfg, f"{NAME} config")
    st = None

    def open_store():
        nonlocal st
        st = Store.open(args.out, NAME, cfg)
        return []

    try:
        distributed.decide(cluster, 0, open_store)  # process 0 opens the store (or all fail)
        return _run(args, st, cluster)
    finally:
        if st is not None:
            st.close()


def _run(args: argparse.Namespace, st, cluster) -> int:
    """The study body: the (fraction, σ) cells split over the processes; process 0 writes."""
    import jax
    import numpy as np

    from .. import calculi
    from ..compositions.simulation import heldout_study, sample_compose_tensor
    from . import distributed
    from .store import atomic_write_json, tidy_rows

    calc = calculi.get(args.calculus)
    try:
        tensor, source = np.asarray(calc.tables.prob_compose, np.float32), "prob_compose"
    except ValueError:  # no probabilistic table (e.g. boundary-inclusive calculi)
        tensor, _ = sample_compose_tensor(calc, jax.random.key(args.seed + 1), 4_000_000)
        source = "sampled"
    if cluster.is_main:
        print(f"calculus {calc.name}, tensor {source}, {args.landmarks} landmarks, "
              f"{args.runs} runs per cell")
    cells = [(frac, sigma) for frac in args.fractions for sigma in args.sigmas]

    def cell(fs):
        r = heldout_study(calc, tensor, jax.random.key(args.seed),
                          num_landmarks=args.landmarks, fraction=fs[0], sigma=fs[1],
                          runs=args.runs, samples=args.samples, rounds=args.rounds)
        return {"fraction": fs[0], "sigma": fs[1], **r}

    out = []
    for _, rec in distributed.map_units(cell, cells, cluster, codec="json"):
        out.append(rec)
        frac, sigma = rec["fraction"], rec["sigma"]
        r = {k: v for k, v in rec.items() if k not in ("fraction", "sigma")}
        if cluster.is_main:
            for k, v in r.items():
                extra = f" coverage {v['coverage']:.2f}" if "coverage" in v else ""
                print(f"f={frac:.2f} σ={sigma:5.1f} {k:20s} error {v['error']:.3f} "
                      f"entropy {v['entropy']:.2f} NLL {v['nll']:.2f}{extra}", flush=True)
    if st is None:
        return 0
    doc = {"calculus": calc.name, "tensor": source, "results": out}
    st.write_json("results.json", doc)
    st.write_results_csv(tidy_rows(out, unit=lambda r: f"f={r['fraction']:g}/σ={r['sigma']:g}",
                                   skip=("fraction", "sigma")))
    if args.json:
        atomic_write_json(Path(args.json), doc)
    return 0
