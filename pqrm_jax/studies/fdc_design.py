"""The FDC mapper's 4-landmark / 7-image design (MT ch. 1, Figs. 1.5–1.6a).

MT chose seven imaging points for four landmarks "using the measurement regions of Fig. 1.4"
so that the Freksa Double Cross map is fully constrained at the end, and observed that no
edge is fully constrained before the fourth image. We do not have MT's coordinates, so the
design is searched for: a greedy choice among random candidate poses (each candidate scored
by one batched, ``vmap``-ed map update), with the rule that images 1–3 may not fully
constrain an edge. The same QRM pipeline runs with the FDC calculus (``double_cross``, the
open 6-state FDC; ``--calc dcc`` for the boundary-inclusive version when its tables exist).
Outputs: ``fdc_design.png`` (layout + curves of % open states and % constrained edges, like
MT Fig. 1.6a), ``design.json`` and ``report.md``. As N processes on ``jax.distributed``
(``--coordinator/--processes/--process-id``; :mod:`pqrm_jax.studies.distributed`) the searches
are split over the processes and process 0 writes them.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

NAME = "fdc-design"
HELP = "FDC mapper 4-landmark / 7-image design (MT ch. 1): fully constrained at the end"

LANDMARKS = np.array([[0.0, 0.0], [4.0, 1.0], [1.5, 3.5], [5.0, 4.5]], np.float32)


def search(calc: str = "double_cross", images: int = 7, candidates: int = 256,
           seed: int = 0, min_free: int = 3):
    """Greedy design: returns poses (images, 3) and the per-image metrics."""
    from pqrm_jax.qrm import hypergraph as H
    from pqrm_jax.qrm import pipeline as P
    from pqrm_jax.qrm.spec import qrm_spec

    spec = qrm_spec(calc)
    lm = jnp.asarray(LANDMARKS)
    truth = H.true_relations(lm, spec)
    sensor = P.resolve_sensor(None)
    step = jax.jit(jax.vmap(
        lambda m, p: P.map_step_kernel(spec, m, p, lm, truth, sensor, 4),
        in_axes=(None, 0)))
    m = H.empty_map(4, spec)
    key = jax.random.key(seed)
    chosen, rows = [], []
    lo, hi = LANDMARKS.min(0) - 4.0, LANDMARKS.max(0) + 4.0
    for t in range(images):
        key, k = jax.random.split(key)
        cand = jnp.concatenate([lo + (hi - lo) * jax.random.uniform(k, (candidates, 2)),
                                jnp.zeros((candidates, 1))], 1)
        ms, met = step(m, cand)
        removed = np.asarray(met.removed_pct)
        constrained = np.asarray(met.constrained_pct)
        score = removed.copy()
        if t < min_free:  # MT: no edge fully constrained before the fourth image
            score[constrained > 0] = -1.0
        if t == images - 1:  # prefer finishing fully constrained
            score = score + 1000.0 * (constrained >= 100.0)
        best = int(np.argmax(score))
        m = jax.tree_util.tree_map(lambda x, b=best: x[b], ms)
        chosen.append(np.asarray(cand[best]))
        rows.append({f: float(np.asarray(getattr(met, f))[best]) for f in
                     ("removed_pct", "constrained_pct", "not_adjacent_pct")})
    open_states = [100.0 - r["removed_pct"] * (spec.num_states - 1) / spec.num_states
                   for r in rows]
    return np.stack(chosen), rows, open_states, m


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog=f"pqrm-jax study {NAME}", description=HELP)
    p.add_argument("--out", default="out/fdc-design")
    p.add_argument("--calc", default="double_cross")
    p.add_argument("--runs", type=int, default=8, help="independent searches (seeds)")
    p.add_argument("--reduced", action="store_true", help="2 searches")
    p.add_argument("--no-progress", action="store_true")
    from . import distributed

    distributed.add_arguments(p)
    a = p.parse_args(argv)

    from . import distributed
    from .store import Store, tidy_rows

    runs = 2 if a.reduced else a.runs
    if runs < 1:
        p.error(f"--runs must be ≥ 1, got {runs}")
    out = Path(a.out)
    cluster = distributed.initialize_from(a)  # before any JAX computation
    distributed.agree(cluster, {"calc": a.calc, "runs": runs}, f"{NAME} config")
    st = None

    def open_store():
        nonlocal st
        st = Store.open(out, NAME, {"calc": a.calc}, legacy=(
            "design.json", "report.md", "fdc_design.png", "config.json", "study.json",
            "results.csv"))
        return []

    try:
        distributed.decide(cluster, 0, open_store)  # process 0 opens the store (or all fail)
        results = _searches(a.calc, runs, a.no_progress, st, cluster)
        if st is None:  # other processes: the same verdict as process 0's
            return 0 if any(r["fully_constrained_end"] and r["none_before_fourth"]
                            for r in results) else 1
        code = _write(out, a.calc, runs, results, st)
        st.write_results_csv(tidy_rows(results, unit=lambda r: f"seed_{r['seed']}",
                                       skip=("seed", "poses")))
    finally:
        if st is not None:
            st.close()
    return code


def _search_record(calc: str, s: int) -> dict:
    """The stored record of the greedy search with seed ``s``."""
    poses, rows, open_states, _ = search(calc, seed=s)
    c = [r["constrained_pct"] for r in rows]
    return {"seed": s, "poses": poses.tolist(), "rows": rows,
            "open_pct_of_all_states": [float(x) for x in open_states],
            "fully_constrained_end": c[-1] >= 100.0,
            "none_before_fourth": all(x == 0 for x in c[:3]),
            "first_constrained_image": next((i + 1 for i, x in enumerate(c) if x > 0), None)}


def _searches(calc: str, runs: int, no_progress: bool, st, cluster=None) -> list[dict]:
    """Every search's record (split over the processes of ``cluster``); process 0 stores."""
    from tqdm.auto import tqdm

    from . import distributed

    cluster = cluster or distributed.current()
    done = distributed.map_units(lambda s: _search_record(calc, s), list(range(runs)),
                                 cluster, codec="json")
    results = [r for _, r in tqdm(done, total=runs, desc=NAME,
                                  disable=no_progress or not cluster.is_main)]
    if st is not None:
        st.write_json("design.json", results)
    return results


def _write(out: Path, calc: str, runs: int, results: list[dict], st) -> int:
    """Figure and ``report.md`` of the searches; 0 when one design has both MT properties."""
    ok = [r for r in results if r["fully_constrained_end"] and r["none_before_fourth"]]
    best = ok[0] if ok else results[0]
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(11, 4.5))
    P = np.asarray(best["poses"])
    ax[0].plot(LANDMARKS[:, 0], LANDMARKS[:, 1], "ko", ms=10)
    for i, (x, y, _) in enumerate(P):
        ax[0].plot(x, y, "g^")
        ax[0].annotate(str(i + 1), (x, y), textcoords="offset points", xytext=(4, 4))
    ax[0].set_aspect("equal")
    ax[0].set_title(f"4 landmarks, 7 imaging points (seed {best['seed']})")
    x = np.arange(1, len(P) + 1)
    ax[1].plot(x, best["open_pct_of_all_states"], "b-o", label="open FDC states [%]")
    ax[1].plot(x, [r["constrained_pct"] for r in best["rows"]], "r-s",
               label="fully constrained edges [%]")
    ax[1].axhline(100.0 / 6, color="b", ls="--", label="fully converged map")
    ax[1].set_xlabel("image")
    ax[1].legend()
    ax[1].set_title("MT Fig. 1.6a analogue")
    fig.tight_layout()
    fig.savefig(st.path("fdc_design.png"), dpi=110)
    plt.close(fig)
    lines = [f"# {NAME}: FDC 4-landmark / 7-image design (MT ch. 1)", "",
             f"Calculus `{calc}`; {runs} greedy searches, {len(ok)} satisfy both MT "
             "properties (fully constrained after image 7; no edge fully constrained before "
             "image 4).", "", "![design](fdc_design.png)", "",
             "| seed | constrained % per image | open % per image | ok |", "|---|---|---|---|"]
    for r in results:
        cons = ", ".join(f"{x['constrained_pct']:.0f}" for x in r["rows"])
        opn = ", ".join(f"{x:.0f}" for x in r["open_pct_of_all_states"])
        good = r["fully_constrained_end"] and r["none_before_fourth"]
        lines.append(f"| {r['seed']} | {cons} | {opn} | {good} |")
    st.write_text("report.md", "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0 if ok else 1
