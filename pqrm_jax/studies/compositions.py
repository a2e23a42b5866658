"""Held-out study: PQRM maps with vs without composition propagation (Z eq. 2.4; issue #6).

``pqrm-jax study compositions-heldout [--tiny|--reduced] [--landmarks 20 --runs 5
--fractions 0.1 0.25 0.5 --sigmas 2 5 10 --calculus edc] [--out DIR] [--json out.json]``

The study protocol of :mod:`pqrm_jax.studies.protocol` (``Config``, ``PRESETS``,
``configure``, ``run_study``, ``report``, ``claims``; the common flags; ``--sweep``). Each
(fraction, σ) cell is one unit: it is appended to ``cells.jsonl`` in the store as soon as it is
computed, so a killed run keeps its finished cells and a re-run computes only the others. At
the end ``results.json`` (every cell), the tidy ``results.csv``, ``heldout.png`` and
``report.md`` (the claims table and the captioned figure) are written; ``--json`` also
writes ``results.json``'s content to another path. As N processes on ``jax.distributed``
(the cluster flags; :mod:`pqrm_jax.studies.distributed`) the cells are split over the
processes and process 0 writes them.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any

from . import protocol

NAME = "compositions-heldout"
HELP = "held-out triplet prediction with vs without composition propagation (Z eq. 2.4)"


@dataclasses.dataclass(frozen=True)
class Config(protocol.StudyConfig):
    """Every result-changing setting of the study (each knob's reason in :data:`REASONS`)."""

    calculus: str = "edc"
    landmarks: int = 20
    runs: int = 5
    samples: int = 256
    fractions: tuple[float, ...] = (0.1, 0.25, 0.5)
    sigmas: tuple[float, ...] = (2.0, 5.0, 10.0)
    rounds: int = 2
    seed: int = 2024



REASONS = {
    "calculus": "EDC: the calculus of the composition tables the maps use (Z eq. 2.4)",
    "landmarks": "20 landmarks: 1140 triplets, enough held-out ones at every fraction",
    "runs": "5 worlds per cell: the error rate's standard error is about 1 %",
    "samples": "256 inverse-sensor samples per triplet, as the PQRM mapper",
    "fractions": "observed fractions 0.1–0.5: from sparse to half-observed maps",
    "sigmas": "position noise 2–10 m in a 100 m square: from clean to ambiguous measurements",
    "rounds": "2 propagation rounds: the second adds paths through filled triplets",
    "seed": "the root seed; every cell uses it, so cells differ only by their setting",
}

PRESETS: dict[str, dict[str, Any]] = {
    "tiny": {"landmarks": 6, "runs": 1, "samples": 32, "fractions": (0.5,), "sigmas": (5.0,),
             "rounds": 1},
    "reduced": {"landmarks": 10, "runs": 2, "samples": 64, "fractions": (0.25, 0.5),
                "sigmas": (2.0, 10.0)},
    "full": {},
}

_FLAGS = {"calculus": "calculus", "landmarks": "landmarks", "runs": "runs",
          "samples": "samples", "fractions": "fractions", "sigmas": "sigmas",
          "rounds": "rounds"}


def configure(argv: list[str], overrides: dict | None = None
              ) -> tuple[Config, argparse.Namespace]:
    """The study's Config and parsed flags (every number checked before any work)."""
    ap = protocol.parser(NAME, HELP, seed=Config.seed)
    ap.add_argument("--calculus", default=None, help="calculus (default edc)")
    ap.add_argument("--landmarks", type=protocol.positive_int, default=None,
                    help="landmarks per world (≥ 3; default 20)")
    ap.add_argument("--runs", type=protocol.positive_int, default=None,
                    help="worlds per cell (default 5)")
    ap.add_argument("--samples", type=protocol.positive_int, default=None,
                    help="inverse-sensor samples (default 256)")
    ap.add_argument("--fractions", type=protocol.fraction, nargs="+", default=None,
                    help="observed fractions, each in (0, 1) (default 0.1 0.25 0.5)")
    ap.add_argument("--sigmas", type=protocol.positive_float, nargs="+", default=None,
                    help="position noise std, m (default 2 5 10)")
    ap.add_argument("--rounds", type=protocol.nonneg_int, default=None,
                    help="propagation rounds (default 2)")
    ap.add_argument("--json", help="also write the results to this file")
    a = ap.parse_args(argv)
    for f in ("fractions", "sigmas"):
        if getattr(a, f) is not None:
            setattr(a, f, tuple(getattr(a, f)))
    cfg = protocol.apply_preset(Config, PRESETS, a.preset, a, _FLAGS, overrides)
    cfg = dataclasses.replace(cfg, seed=a.seed if "seed" not in (overrides or {}) else cfg.seed)
    if cfg.landmarks < 3:
        ap.error(f"argument --landmarks: must be an integer ≥ 3, got {cfg.landmarks}")
    if not cfg.fractions or not all(0.0 < f < 1.0 for f in cfg.fractions):
        ap.error(f"argument --fractions: each must lie in (0, 1), got {cfg.fractions}")
    if not cfg.sigmas or not all(0.0 < s < float("inf") for s in cfg.sigmas):
        ap.error(f"argument --sigmas: each must be positive and finite, got {cfg.sigmas}")
    if min(cfg.runs, cfg.samples) < 1 or cfg.rounds < 0:
        ap.error(f"--runs and --samples must be ≥ 1 and --rounds ≥ 0, got {cfg.runs}, "
                 f"{cfg.samples}, {cfg.rounds}")
    return cfg, a


def _cell_key(r: dict) -> tuple[float, float]:
    return (float(r["fraction"]), float(r["sigma"]))


def _open(out: Path, cfg: Config | None, fresh: bool = False):
    from .store import Store

    stored = None if cfg is None else dict(cfg.to_json(), reasons=REASONS)
    return Store.open(out, NAME, stored, fresh=fresh,
                      legacy=("results.json", "results.csv", "config.json", "study.json"))


def _tensor(cfg: Config):
    import jax
    import numpy as np

    from .. import calculi
    from ..compositions.simulation import sample_compose_tensor

    calc = calculi.get(cfg.calculus)
    try:
        return calc, np.asarray(calc.tables.prob_compose, np.float32), "prob_compose"
    except ValueError:  # no probabilistic table (e.g. boundary-inclusive calculi)
        tensor, _ = sample_compose_tensor(calc, jax.random.key(cfg.seed + 1), 4_000_000)
        return calc, tensor, "sampled"


def run_study(cfg: Config, out: Path, *, quiet: bool = False, cluster=None,
              fresh: bool = False, json_path: str | None = None) -> None:
    """Compute every (fraction, σ) cell not yet stored in ``out``; process 0 writes each one
    as it arrives (``cells.jsonl``), then ``results.json`` and ``results.csv``."""
    import jax

    from ..compositions.simulation import heldout_study
    from . import distributed
    from .store import atomic_write_json, tidy_rows

    cluster = cluster or distributed.current()
    distributed.agree(cluster, cfg.to_json(), f"{NAME} config")
    cells = [(float(f), float(s)) for f in cfg.fractions for s in cfg.sigmas]
    st = log = None

    def left():  # process 0: open the store, the cells not stored yet
        nonlocal st, log
        st = _open(Path(out), cfg, fresh)
        log = st.records("cells.jsonl", key=_cell_key, required=("fraction", "sigma"))
        return [c not in log for c in cells]

    try:
        todo = [c for c, m in zip(cells, distributed.decide(cluster, len(cells), left),
                                  strict=True) if m]
        calc, tensor, source = _tensor(cfg)
        if cluster.is_main and not quiet:
            print(f"calculus {calc.name}, tensor {source}, {cfg.landmarks} landmarks, "
                  f"{cfg.runs} runs per cell; {len(cells) - len(todo)} of {len(cells)} "
                  "cells stored")

        def cell(fs):
            r = heldout_study(calc, tensor, jax.random.key(cfg.seed),
                              num_landmarks=cfg.landmarks, fraction=fs[0], sigma=fs[1],
                              runs=cfg.runs, samples=cfg.samples, rounds=cfg.rounds)
            return {"fraction": fs[0], "sigma": fs[1], **r}

        for _, rec in distributed.map_units(cell, todo, cluster, codec="json"):
            if log is not None:
                log.add(rec)
            if cluster.is_main and not quiet:
                for k, v in rec.items():
                    if isinstance(v, dict):
                        extra = f" coverage {v['coverage']:.2f}" if "coverage" in v else ""
                        print(f"f={rec['fraction']:.2f} σ={rec['sigma']:5.1f} {k:20s} error "
                              f"{v['error']:.3f} entropy {v['entropy']:.2f} NLL "
                              f"{v['nll']:.2f}{extra}", flush=True)
        if st is None:
            return
        recs = [log.get(c) for c in cells]
        doc = {"calculus": calc.name, "tensor": source, "results": recs}
        st.write_json("results.json", doc)
        st.write_results_csv(tidy_rows(recs, unit=lambda r: f"f={r['fraction']:g}/"
                                       f"σ={r['sigma']:g}", skip=("fraction", "sigma")))
        if json_path:
            atomic_write_json(Path(json_path), doc)
    finally:
        if st is not None:
            st.close()


def _results(out: Path) -> list[dict]:
    from .store import StudyError, read_json

    doc = read_json(Path(out) / "results.json", ("results",), quarantine=False)
    if doc is None:
        raise StudyError(f"{out} holds no finished {NAME} results (no results.json); run the "
                         "study first")
    return doc["results"]


def claims(out: Path) -> list[protocol.Claim]:
    """Z eq. 2.4's claim: propagation predicts held-out triplets better than no propagation
    (the uniform row) and than the best prior-only guess (observed state frequencies), in
    every cell."""
    recs = _results(out)
    n = len(recs)
    cs = []
    for other, what in (("uniform", "no propagation (uniform rows)"),
                        ("marginal", "the prior-only guess (observed frequencies)")):
        better = sum(r["heldout/propagated"]["error"] < r[f"heldout/{other}"]["error"]
                     for r in recs)
        cs.append(protocol.Claim(
            f"propagated held-out error < {other}", f"lower error than {what} (Z eq. 2.4)",
            better, (n, n), protocol.verdict_in(better, n, n)))
    gain = [r["heldout/marginal"]["error"] - r["heldout/propagated"]["error"] for r in recs]
    cs.append(protocol.Claim("mean error gain over the prior-only guess", "positive",
                             float(sum(gain) / max(len(gain), 1)), (0.0, 1.0),
                             protocol.verdict_in(float(sum(gain) / max(len(gain), 1)),
                                                 1e-12, 1.0)))
    return cs


_SCORES = (("heldout/uniform", "no propagation (uniform rows)"),
           ("heldout/marginal", "prior-only guess (observed frequencies)"),
           ("heldout/propagated", "propagated (Z eq. 2.4)"))


def _figure(out: Path, recs: list[dict]) -> str:
    """``heldout.png``: held-out error and NLL against the held-out fraction, one colour per
    score, one line style per σ; returns its file name."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .store import atomic_savefig

    sigmas = sorted({float(r["sigma"]) for r in recs})
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for ax, metric, label in zip(axes, ("error", "nll"),
                                 ("held-out ML error rate", "held-out NLL (nats)"), strict=True):
        for c, (key, what) in enumerate(_SCORES):
            for si, sigma in enumerate(sigmas):
                pts = sorted((float(r["fraction"]), r[key][metric]) for r in recs
                             if float(r["sigma"]) == sigma)
                x, y = zip(*pts, strict=True)
                ax.plot(x, y, marker="osD^"[si % 4], ls=("-", "--", ":", "-.")[si % 4],
                        color=f"C{c}", mfc="none", ms=6,
                        label=f"{what}, σ = {sigma:g}" if len(sigmas) > 1 else what)
        ax.set_xlabel("fraction of triplets held out")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 3), fontsize=8,
               frameon=False)
    fig.tight_layout(rect=(0, 0.06 + 0.05 * ((len(labels) - 1) // 3), 1, 1))
    atomic_savefig(fig, Path(out) / "heldout.png", dpi=100)
    plt.close(fig)
    return "heldout.png"


def report(out: Path) -> Path:
    """``report.md`` (the claims table, a figure and every cell's scores) and ``heldout.png``."""
    from .store import atomic_write_text

    recs = _results(out)
    fig = _figure(Path(out), recs)
    lines = [f"# {NAME}: held-out triplets with vs without propagation (Z eq. 2.4)", "",
             "## Claims", "", *protocol.claims_table(claims(out)), "",
             *protocol.figure(fig, (
                 "Held-out triplets' ML error rate (left) and negative log-likelihood of the "
                 "true state (right, nats) against the fraction of triplets held out, for the "
                 "three predictions of a held-out row (colours; line style and marker: noise σ "
                 "of the cell): the uniform row, the observed state frequencies and the "
                 "propagated row; lower is better.")),
             "## Cells", "",
             "| fraction | σ | score | error | entropy | NLL | coverage |",
             "|---|---|---|---|---|---|---|"]
    for r in recs:
        for k, v in r.items():
            if isinstance(v, dict):
                lines.append(f"| {r['fraction']:g} | {r['sigma']:g} | {k} | {v['error']:.3f} | "
                             f"{v['entropy']:.2f} | {v['nll']:.2f} | "
                             f"{v.get('coverage', float('nan')):.2f} |")
    return atomic_write_text(Path(out) / "report.md", "\n".join(lines) + "\n")


sweep_summary = protocol.summary_for(sys.modules[__name__])


def main(argv: list[str] | None = None) -> int:
    """``pqrm-jax study compositions-heldout`` (the protocol's driver, plus ``--json``)."""
    cfg, args = configure(list(argv or []))
    out = Path(args.out)
    if not args.report_only:
        from . import distributed

        cluster = distributed.initialize_from(args)  # before any JAX computation
        run_study(cfg, out, quiet=args.no_progress, cluster=cluster, fresh=args.fresh,
                  json_path=args.json)
        if not cluster.is_main:
            return 0
    print(f"wrote {report(out)}")
    return 0
