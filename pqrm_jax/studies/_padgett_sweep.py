"""Headline numbers of one padgett-mc cell for a sweep (P §2.3.1; :mod:`.sweep`).

The two quantities behind the report's two open mismatches, plus what explains them:

* the EDC mean conceptual-neighbour distance near σ_N = 0.87 (P Fig. 2.6 claims < 1 for every
  σ_N < 1), with the EDC error rate and the number of updates each mapped triplet received;
* the normalised entropy H / ln Q of every representation averaged over σ_N > 0 (P Fig. 2.10b:
  LR worst, EDC-lune-merged best), the LR − Triple-Cross difference and the fraction of noise
  levels at which LR is the worst;
* every claim's verdict from the cell's own report (``claims``: claim → verdict).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ._padgett_report import claim_rows
from .padgett_common import load_results

__all__ = ["sweep_summary"]

SIGMA_N_PROBE = 0.866  # σ_R = 25 m: the level of the report's neighbour-distance mismatch


def sweep_summary(out: Path) -> dict:
    """Headline numbers, the worst/best representation and claim verdicts of ``out``."""
    cfg, lines, arrays = load_results(Path(out))
    main = [ln for ln in lines if ln["tag"] == "main"]
    below = [ln for ln in main if ln["sigma_n"] < 1]  # as the report's claim
    probe = min(main, key=lambda ln: abs(ln["sigma_n"] - SIGMA_N_PROBE))
    noisy = [ln for ln in main if ln["sigma_n"] > 0]
    reps = cfg["representations"]
    norm = {r: float(np.mean([ln["reps"][r]["norm_entropy_mean"] for ln in noisy]))
            for r in reps}
    worst_at = [max(reps, key=lambda r, ln=ln: ln["reps"][r]["norm_entropy_mean"])
                for ln in noisy]
    out_d = {
        "probe_sigma_n": float(probe["sigma_n"]),
        "nd_at_probe": float(probe["reps"]["edc"]["neighbor_mean"]),
        "nd_max_below_sn1": (float(max(ln["reps"]["edc"]["neighbor_mean"] for ln in below))
                             if below else math.nan),
        "edc_error_at_probe": float(probe["reps"]["edc"]["error_mean"]),
        "updates_per_triplet": float(probe["mean_updates_per_triplet"]),
        "mapped_per_run": float(probe["mean_mapped"]),
        "edc_H_high_noise": float(np.mean([ln["reps"]["edc"]["entropy_mean"] for ln in main
                                           if ln["sigma_n"] >= 3.0] or [math.nan])),
    }
    for r in ("lr", "triple_cross", "edc_lune"):
        if r in norm:
            out_d[f"normH_{r}"] = norm[r]
    if "lr" in norm and "triple_cross" in norm:
        out_d["normH_lr_minus_tc"] = norm["lr"] - norm["triple_cross"]
        out_d["lr_worst_fraction"] = float(np.mean([w == "lr" for w in worst_at]))
    out_d["worst_normH"] = max(norm, key=norm.get)
    out_d["best_normH"] = min(norm, key=norm.get)
    out_d["claims"] = {row[0]: row[4] for row in claim_rows(cfg, lines, arrays)}
    return out_d
