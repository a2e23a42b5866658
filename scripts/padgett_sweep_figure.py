"""One figure of the padgett-mc sweeps for docs/studies.md §padgett-sweep.

Reads the ``sweep.csv`` of one or more ``pqrm-jax study padgett-mc --sweep ...`` directories
and plots, over every cell of all of them, (a) the EDC mean neighbour distance (max over
σ_N < 1) against the updates each mapped triplet received, and (b) the normalised-entropy
difference LR − Triple Cross against the samples per update, with the published claims'
thresholds (< 1; > 0 for "LR worst").

    python scripts/padgett_sweep_figure.py OUT.png SWEEP_DIR [SWEEP_DIR ...]
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path


def main(argv: list[str]) -> int:
    if len(argv) < 2:
        print(__doc__, file=sys.stderr)
        return 2
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out, dirs = Path(argv[0]), [Path(a) for a in argv[1:]]
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    markers = "osD^v"
    colour = {32.0: "C2", 16.0: "C0", 8.0: "C1", 4.0: "C3"}  # by measurement spacing
    for n, d in enumerate(dirs):
        rows = list(csv.DictReader((d / "sweep.csv").open()))
        m = markers[n % len(markers)]
        for r in rows:
            c = colour.get(float(r.get("dtheta_deg") or 16.0), "k")
            a.scatter(float(r["updates_per_triplet"]), float(r["nd_max_below_sn1"]), marker=m,
                      c=c, s=28, alpha=0.8)
            b.scatter(float(r.get("num_samples") or 256), float(r["normH_lr_minus_tc"]),
                      marker=m, c=c, s=28, alpha=0.8)
        a.scatter([], [], marker=m, c="gray", label=d.name)
    a.axhline(1.0, color="k", lw=0.8, ls="--", label="P: < 1 for σ_N < 1")
    a.set_xlabel("updates per mapped triplet (at σ_N = 0.87)")
    a.set_ylabel("EDC mean neighbour distance, max over σ_N < 1")
    a.legend(fontsize=7)
    b.axhline(0.0, color="k", lw=0.8, ls="--", label="> 0: LR worst (P)")
    b.set_xscale("log", base=2)
    b.set_xlabel("samples per update (num_samples)")
    b.set_ylabel("H/ln Q: LR − Triple Cross (mean, σ_N > 0)")
    for ds, c in colour.items():
        b.scatter([], [], c=c, label=f"dtheta_deg = {ds:g}")
    b.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=90)
    print(out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
