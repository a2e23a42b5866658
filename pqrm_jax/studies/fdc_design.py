"""The FDC mapper's 4-landmark / 7-image design (MT ch. 1, Figs. 1.5–1.6a).

MT chose seven imaging points for four landmarks "using the measurement regions of Fig. 1.4"
so that the Freksa Double Cross map is fully constrained at the end, and observed that no
edge is fully constrained before the fourth image. We do not have MT's coordinates, so the
design is searched for: a greedy choice among random candidate poses (each candidate scored
by one batched, ``vmap``-ed map update), with the rule that images 1–3 may not fully
constrain an edge. The same QRM pipeline runs with the FDC calculus (``double_cross``, the
open 6-state FDC; ``--calc dcc`` for the boundary-inclusive version when its tables exist).
Outputs: ``searches.jsonl`` (one record per search, appended as it ends: a killed run
keeps it), ``design.json``, ``fdc_design.png`` (layout + curves of % open states and %
constrained edges, like MT Fig. 1.6a) and ``report.md`` with the claims table. As N
processes on ``jax.distributed`` (``--coordinator/--processes/--process-id``;
:mod:`pqrm_jax.studies.distributed`) the searches are split over the processes and process 0
writes them.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from . import protocol

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


@dataclasses.dataclass(frozen=True)
class Config(protocol.StudyConfig):
    """Every setting of the design search (each knob's reason in :data:`REASONS`)."""

    calc: str = "double_cross"
    runs: int = 8
    images: int = 7
    candidates: int = 256
    min_free: int = 3
    seed: int = 0



REASONS = {
    "calc": "the open 6-state FDC of MT ch. 1 (dcc: the boundary-inclusive version)",
    "runs": "independent greedy searches, seeds seed..seed+runs-1 (only selects units)",
    "images": "MT's 7 imaging points",
    "candidates": "random candidate poses per image, each scored by one vmap-ed map update",
    "min_free": "MT: no edge fully constrained before the fourth image (images 1-3 free)",
    "seed": "the first search's seed",
}

PRESETS: dict[str, dict] = {"tiny": {"runs": 1, "candidates": 64},
                            "reduced": {"runs": 2}, "full": {}}


def configure(argv: list[str], overrides: dict | None = None
              ) -> tuple[Config, argparse.Namespace]:
    """The study's Config and parsed flags (every number checked before any work)."""
    p = protocol.parser(NAME, HELP, seed=Config.seed)
    p.add_argument("--calc", default=None, help="calculus (default double_cross)")
    p.add_argument("--runs", type=protocol.positive_int, default=None,
                   help="independent searches (seeds; default 8, reduced 2)")
    p.add_argument("--candidates", type=protocol.positive_int, default=None,
                   help="candidate poses per image (default 256)")
    a = p.parse_args(argv)
    cfg = protocol.apply_preset(Config, PRESETS, a.preset, a,
                                {"calc": "calc", "runs": "runs", "candidates": "candidates"},
                                overrides)
    if "seed" not in (overrides or {}):
        cfg = dataclasses.replace(cfg, seed=a.seed)
    if cfg.images < 1 or not 0 <= cfg.min_free < cfg.images:
        p.error(f"images must be ≥ 1 and 0 ≤ min_free < images, got {cfg.images}, "
                f"{cfg.min_free}")
    return cfg, a


def run_study(cfg: Config, out: Path, *, quiet: bool = False, cluster=None,
              fresh: bool = False) -> None:
    """Every search not yet stored (``searches.jsonl``, one record per seed, appended as it
    arrives), split over the processes; then ``design.json`` and ``results.csv``."""
    from . import distributed
    from .store import Store, tidy_rows

    cluster = cluster or distributed.current()
    distributed.agree(cluster, cfg.to_json(), f"{NAME} config")
    seeds = list(range(cfg.seed, cfg.seed + cfg.runs))
    st = log = None

    def left():  # process 0: open the store, the seeds not stored yet
        nonlocal st, log
        st = Store.open(out, NAME, dict(cfg.to_json(), reasons=REASONS), fresh=fresh,
                        selection=("runs",), legacy=(
                            "design.json", "report.md", "fdc_design.png", "config.json",
                            "study.json", "results.csv"))
        log = st.records("searches.jsonl", key=lambda r: r["seed"],
                         required=("seed", "rows", "fully_constrained_end"))
        return [s not in log for s in seeds]

    try:
        todo = [s for s, m in zip(seeds, distributed.decide(cluster, len(seeds), left),
                                  strict=True) if m]
        from tqdm.auto import tqdm

        done = distributed.map_units(lambda s: _search_record(cfg, s), todo, cluster,
                                     codec="json")
        for _, r in tqdm(done, total=len(todo), desc=NAME,
                         disable=quiet or not cluster.is_main):
            if log is not None:
                log.add(r)
        if st is None:
            return
        results = [log.get(s) for s in seeds]
        st.write_json("design.json", results)
        st.write_results_csv(tidy_rows(results, unit=lambda r: f"seed_{r['seed']}",
                                       skip=("seed", "poses")))
    finally:
        if st is not None:
            st.close()


def _search_record(cfg: Config, s: int) -> dict:
    """The stored record of the greedy search with seed ``s``."""
    poses, rows, open_states, _ = search(cfg.calc, cfg.images, cfg.candidates, seed=s,
                                         min_free=cfg.min_free)
    c = [r["constrained_pct"] for r in rows]
    return {"seed": s, "poses": poses.tolist(), "rows": rows,
            "open_pct_of_all_states": [float(x) for x in open_states],
            "fully_constrained_end": c[-1] >= 100.0,
            "none_before_fourth": all(x == 0 for x in c[:cfg.min_free]),
            "first_constrained_image": next((i + 1 for i, x in enumerate(c) if x > 0), None)}


def _design(out: Path) -> list[dict]:
    from .store import StudyError

    path = Path(out) / "design.json"
    try:
        return json.loads(path.read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        raise StudyError(f"{out} holds no finished {NAME} results (design.json); run the "
                         "study first") from None


def claims(out: Path) -> list[protocol.Claim]:
    """MT ch. 1: the 7-image design fully constrains the map, and no edge is fully
    constrained before the fourth image."""
    results = _design(out)
    n = len(results)
    both = sum(r["fully_constrained_end"] and r["none_before_fourth"] for r in results)
    end = sum(r["fully_constrained_end"] for r in results)
    return [
        protocol.Claim("a design with both MT properties exists",
                       "fully constrained after image 7, none before image 4 (MT Fig. 1.6a)",
                       both, (1, n), protocol.verdict_in(both, 1, n)),
        protocol.Claim("searches ending fully constrained", "the 7-image map is fully "
                       "constrained", end, (1, n), protocol.verdict_in(end, 1, n)),
    ]


def report(out: Path) -> Path:
    """``fdc_design.png`` and ``report.md`` from ``design.json``."""
    results = _design(out)
    _write(Path(out), results, claims(out))
    return Path(out) / "report.md"


sweep_summary = protocol.summary_for(sys.modules[__name__])
main = protocol.main_for(sys.modules[__name__])


def _write(out: Path, results: list[dict], cs: list) -> None:
    """Figure and ``report.md`` of the searches (and the claims table)."""
    from .store import atomic_savefig, atomic_write_text

    cfg = json.loads((out / "config.json").read_text())
    calc, runs = cfg["calc"], len(results)
    ok = [r for r in results if r["fully_constrained_end"] and r["none_before_fourth"]]
    best = ok[0] if ok else results[0]
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(11, 4.5))
    P = np.asarray(best["poses"])
    ax[0].plot(LANDMARKS[:, 0], LANDMARKS[:, 1], "ko", ms=10)
    ax[0].plot(P[:, 0], P[:, 1], "g^")
    for i, (x, y, _) in enumerate(P):
        ax[0].annotate(str(i + 1), (x, y), textcoords="offset points", xytext=(4, 4))
    ax[0].set_aspect("equal")
    ax[0].set_xlabel("x")
    ax[0].set_ylabel("y")
    # no legend box (it would cover a landmark or a pose): the title names the marks
    ax[0].set_title(f"4 landmarks (●), 7 imaging points (▲, in order; seed {best['seed']})")
    x = np.arange(1, len(P) + 1)
    ax[1].plot(x, best["open_pct_of_all_states"], "b-o", label="open FDC states [%]")
    ax[1].plot(x, [r["constrained_pct"] for r in best["rows"]], "r-s",
               label="fully constrained edges [%]")
    # drawn over the curves (the open-states curve ends on it) in another colour
    ax[1].axhline(100.0 / 6, color="0.3", ls=":", lw=1.5, zorder=3,
                  label="fully converged map (1 of 6 states open)")
    ax[1].set_xlabel("image")
    ax[1].set_ylabel("%")
    ax[1].legend()
    ax[1].set_title("MT Fig. 1.6a analogue")
    fig.tight_layout()
    atomic_savefig(fig, out / "fdc_design.png", dpi=110)
    plt.close(fig)
    lines = [f"# {NAME}: FDC 4-landmark / 7-image design (MT ch. 1)", "",
             f"Calculus `{calc}`; {runs} greedy searches, {len(ok)} satisfy both MT "
             "properties (fully constrained after image 7; no edge fully constrained before "
             "image 4).", "", "## Claims", "", *protocol.claims_table(cs), "",
             *protocol.figure("fdc_design.png", (
                 f"Left: the 4 landmarks (black circles) and the 7 imaging points (green, "
                 f"numbered in imaging order) of the search with seed {best['seed']} "
                 + ("(the first that satisfies both MT properties). " if ok else
                    "(no search satisfies both MT properties; the first is shown). ")
                 + "Right: after each image, the open FDC states as a percentage of all "
                 "states (blue; grey dotted: a fully converged map, one state of six open per "
                 "relation) and the fully constrained edges (red) (cf. MT Fig. 1.6a).")),
             "| seed | constrained % per image | open % per image | ok |", "|---|---|---|---|"]
    for r in results:
        cons = ", ".join(f"{x['constrained_pct']:.0f}" for x in r["rows"])
        opn = ", ".join(f"{x:.0f}" for x in r["open_pct_of_all_states"])
        good = r["fully_constrained_end"] and r["none_before_fourth"]
        lines.append(f"| {r['seed']} | {cons} | {opn} | {good} |")
    atomic_write_text(out / "report.md", "\n".join(lines) + "\n")
