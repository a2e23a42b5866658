"""Re-localisation at revisits batched over pairs vs one pair at a time (B §9.2).

:func:`pqrm_jax.hssh_global.relocalize.match_pairs` (all pairs in one jitted call: ``lax.map``
over the pairs, ``vmap`` over the candidates of the coarse-to-fine search over a small pose
window) against the same jitted function called once per pair (compiled once). The snapshots
are synthetic LPMs of T junctions (45 × 45 cells, 14 per corridor width, as in the simulator),
each current snapshot the stored one seen from a known offset; the recovered offsets are
checked against it and the batched and looped results against each other. Compile time is
excluded (one warm-up call each). Writes ``benchmarks/results/hssh_reloc.json``.

    .venv/bin/python benchmarks/bench_hssh_reloc.py [--quick]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from _env import write_result  # benchmarks/_env.py
from _timing import best_of_cpu

from pqrm_jax.hssh_global import relocalize as rl


def t_junction(n: int = 45, cells: int = 14) -> np.ndarray:
    """Log-odds ``[n, n]`` of a T junction: walls 3.0, free -3.0 (rows along y)."""
    g = np.full((n, n), 3.0)
    c, h = n // 2, cells // 2
    g[c - h:c + h + 1, :] = -3.0           # east-west corridor
    g[:c, c - h:c + h + 1] = -3.0          # south arm
    inner = np.zeros_like(g, bool)
    inner[1:-1, 1:-1] = True
    edge = (g > 0) & ~(np.roll(g > 0, 1, 0) & np.roll(g > 0, -1, 0) & np.roll(g > 0, 1, 1)
                       & np.roll(g > 0, -1, 1))
    return np.where(edge & inner, 3.0, np.where(g > 0, 0.0, -3.0))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--repeat", type=int, default=5, help="best of this many runs")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "hssh_reloc.json"))
    a = ap.parse_args()
    width, cells = 1.0, 14
    res = width / cells
    grid = t_junction(45, cells)
    fld = rl.field(grid[None])
    rng = np.random.default_rng(0)
    rows = []
    for k in ([8, 64] if a.quick else [8, 64, 256]):
        offs = np.column_stack([rng.uniform(-0.3, 0.3, (k, 2)) * width,
                                rng.uniform(-0.08, 0.08, k)])
        pts, mask = rl.occupied_points(np.repeat(grid[None], k, 0), np.zeros((k, 2)), offs, res)
        args = (pts, mask, np.repeat(fld, k, 0), np.zeros((k, 2)), np.zeros((k, 3)),
                np.zeros((k, 3)), res, width)
        rl.match_pairs(*args)                                   # compile
        one = [tuple(x[i:i + 1] if isinstance(x, np.ndarray) else x for x in args)
               for i in range(k)]
        rl.match_pairs(*one[0])                                 # compile the K = 1 shape
        t_b, cpu_b, (c_b, _) = best_of_cpu(lambda args=args: rl.match_pairs(*args), a.repeat)
        t_l, cpu_l, outs = best_of_cpu(lambda one=one: [rl.match_pairs(*o) for o in one],
                                       a.repeat)
        c_l = np.concatenate([np.asarray(o[0]) for o in outs])
        err = np.abs(np.asarray(c_b) - offs)
        rows.append({"pairs": k, "batched_s": t_b, "loop_s": t_l, "loop_over_batched": t_l / t_b,
                     "batched_cpu_s": cpu_b, "loop_cpu_s": cpu_l,
                     "loop_over_batched_cpu": cpu_l / cpu_b,
                     "max_err_xy_widths": float(err[:, :2].max() / width),
                     "max_err_theta": float(err[:, 2].max()),
                     "batched_equals_loop": bool(np.allclose(c_b, c_l, atol=1e-4))})
        print(rows[-1])
    write_result({"benchmark": "hssh_reloc", "rows": rows}, a.out)  # + env (where it ran)


if __name__ == "__main__":
    main()
