"""In-vivo-like synthetic Q-Link study (P §4.4.2, Table 4.2): hybrid map, −log p, re-planning.

A synthetic stand-in for Padgett's Jackal experiment: 25 point landmarks and two facing walls,
range 60 m, noise σ = 0.7 m, a hybrid map (LR on point triplets, front/between/behind bands on
wall–wall–point triplets, :mod:`pqrm_jax.qlink.hybrid`), β = 2, −log p edge costs, a search
POMDP with τ = 4 and direct transitions, drives to the reference-segment centre with a sensor
sweep, contingency re-planning (at most ``max_replans``), a drive to the centroid of the goal
element. 18 start/goal element pairs are driven once per injected per-scan miss probability
``p_miss``. Every knob is in ``config.json`` with its reason (``REASONS``).

What is checked (``report.md``, match/mismatch):

* p_miss = 0: all trials succeed with 0 re-plans;
* p_miss > 0: at least one re-plan, and every success is correctly attributed — the robot
  ends within ``attrib_radius`` of the true centroid of the goal element with all its
  landmarks truly in range (no success claimed from a wrong place);
* Table 4.2: mean length non-decreasing in |P| and every trial below (2π+1)R|P| (Prop. 2) and
  R|P| (Prop. 4), with |P| the elements entered over all re-plans;
* the published 72 % success (13 / 18) beside ours — not a target: terrain pitch and
  recognition errors are not simulated.

Results are kept in the shared :class:`~pqrm_jax.studies.store.Store` (one record per
``p_miss``; a re-run resumes and refuses a different configuration); ``trials.csv`` has one row
per trial, ``world.npz`` the world and the map, ``invivo_world.png`` the world and trajectories.

The study follows :mod:`pqrm_jax.studies.protocol` (``Config``, ``PRESETS`` tiny / reduced /
full, ``configure``, ``run_study``, ``report``, ``claims``, ``--sweep``). As N processes
(``--coordinator/--processes/--process-id``) the ``p_miss`` settings are split over the
processes (:func:`.distributed.map_units`) and process 0 writes them; each setting's trials
draw from their own keys, so the records equal a one-process run's.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import sys
from pathlib import Path

import numpy as np

from . import protocol
from .store import Store, atomic_savefig, atomic_write_npz, atomic_write_text, csv_text

NAME = "qlink-invivo"
HELP = "in-vivo-like Q-Link study (P §4.4.2): hybrid LR + bands map, −log p, re-planning"

PUBLISHED = {"trials": 18, "successes": 13, "success_rate": 0.72, "replanned_successes": 5,
             "elements": 44,
             "table_4_2": {1: (2, 2.5), 2: (3, 6.5), 3: (2, 12.7), 4: (3, 14.3), 6: (2, 32.9),
                           8: (1, 38.4)}}
"""P §4.4.2 and Table 4.2 (|P| → (paths, mean length m)); fixtures, never outputs."""

REASONS = {
    "points": "P §4.4.2: 25 point landmark features",
    "size": "world W x H (m): not in P; larger than R so paths need several elements, small "
            "enough that some points see both walls (bands elements); not tuned to any result",
    "wall_gap": "distance between the wall midpoints A, B (m); walls perpendicular to AB "
                "(two facing buildings; bands = Double Cross bands, docs/qlink.md §invivo)",
    "wall_length": "wall segment length (m)",
    "map_range": "P §4.4.2: sensor range 60 m (Q28: as stated)",
    "sigma": "P §4.4.2: noise N(0, 0.7), std 0.7 m per coordinate",
    "max_side": "elements are triplets with all measured sides <= R (Assumption 3, P §4.3.4): "
                "the triangle-based recognition of P §4.4.2 needs the whole triangle in view",
    "sweep_step": "mapping lawnmower pose spacing (m); lanes R apart (P: teleoperated, unknown)",
    "num_samples": "eq. 2.9 samples per mapped row",
    "max_obs": "co-observations fused per element (eq. 2.10)",
    "floor": "likelihood floor in the Bayes fusion",
    "beta": "P §4.4.2: |L_i ∩ L_j| = 2",
    "horizon": "P §4.4.2: POMDP horizon 4, direct transitions",
    "detect_same": "sweep detection probability the robot assumes in the swept state, the same "
                   "for all elements (P L1165); < 1 so the plan may sweep a state twice; the "
                   "robot does not know p_miss",
    "p_miss": "injected per-scan, per-landmark miss probability (0 and 0.3, docs/qlink.md §invivo)",
    "trials": "P §4.4.2: 18 trials",
    "max_replans": "contingency re-plans per trial (decision Q30: at most 3)",
    "attrib_radius": "a success is attributed correctly when the robot ends within this of the "
                     "true goal centroid (3σ) with every goal landmark truly in range",
    "min_bin_trials": "the length-vs-|P| check orders the mean lengths of |P| bins with at least "
                      "this many successful trials: one trial has no spread of its own, and the "
                      "pooled within-bin std (14 m at p_miss 0, 21 m at 0.3) exceeds the steps "
                      "between bin means (docs/qlink.md §invivo); the other bins are shown",
    "seed": "world, map and trial seed",
}


@dataclasses.dataclass(frozen=True)
class Config:
    """Every result-changing setting (reasons in :data:`REASONS`)."""

    points: int = 25
    size: tuple[float, float] = (200.0, 120.0)
    wall_gap: float = 30.0
    wall_length: float = 20.0
    map_range: float = 60.0
    sigma: float = 0.7
    max_side: float = 60.0
    sweep_step: float = 2.0
    num_samples: int = 64
    max_obs: int = 6
    floor: float = 1e-3
    beta: int = 2
    horizon: int = 4
    detect_same: float = 0.9
    p_miss: tuple[float, ...] = (0.0, 0.3)
    trials: int = 18
    max_replans: int = 3
    attrib_radius: float = 2.1
    min_bin_trials: int = 2
    seed: int = 0


REDUCED = dict(points=12, size=(120.0, 80.0), num_samples=16, max_obs=2, sweep_step=6.0,
               trials=6)

PRESETS: dict[str, dict] = {
    "tiny": dict(REDUCED, num_samples=8, trials=4),
    "reduced": REDUCED,
    "full": {},
}
"""Field overrides of :class:`Config` per preset (``--tiny``: a few seconds, for tests;
``--reduced``: 12 points, 6 trials, seconds)."""

FIELDS = ("p_miss", "trial", "start_element", "goal_element", "n_planned", "n_entered",
          "replans", "success", "reason", "attributed", "length_m", "final_x", "final_y")


def make_world(cfg: Config):
    """``(points [N, 2], walls [2, 2, 2])``: uniform points
    (:func:`pqrm_jax.sim.uniform_landmarks`), two walls facing across the centre
    (perpendicular to the line of their midpoints)."""
    import jax
    import jax.numpy as jnp

    from .. import sim

    w, h = cfg.size
    pts = sim.uniform_landmarks(jax.random.fold_in(jax.random.key(cfg.seed), 1), cfg.points,
                                (w, h))
    half = cfg.wall_length / 2
    a = np.array([w / 2 - cfg.wall_gap / 2, h / 2])
    b = np.array([w / 2 + cfg.wall_gap / 2, h / 2])
    walls = np.array([[a + [0, -half], a + [0, half]], [b + [0, -half], b + [0, half]]],
                     np.float32)
    return pts, jnp.asarray(walls, pts.dtype)


# fields build() does not read
_NOT_BUILD = ("p_miss", "max_replans", "attrib_radius", "min_bin_trials")


def build(cfg: Config):
    """World, hybrid map, −log p Link Graph (networkx), QSR tables, trial pairs and paths.

    A pure function of the config; the last two results are kept in the process (a resumed
    run, or a second setting, does not map the world again). Treat the result as read-only.
    """
    key = json.dumps({k: v for k, v in dataclasses.asdict(cfg).items()
                      if k not in _NOT_BUILD}, sort_keys=True)
    return _build(key)


@functools.lru_cache(maxsize=2)
def _build(key: str):
    import jax
    import networkx as nx

    from .. import qlink, sim
    from ..qlink import hybrid as hy

    cfg = Config(**json.loads(key))
    pts, walls = make_world(cfg)
    poses = sim.lawnmower(cfg.size, spacing=cfg.map_range, step=cfg.sweep_step)
    hmap, lm, _ = hy.hybrid_elements(jax.random.fold_in(jax.random.key(cfg.seed), 2), pts, walls,
                                     poses, cfg.map_range, cfg.sigma, cfg.num_samples,
                                     cfg.max_obs, cfg.floor, max_side=cfg.max_side)
    models = hy.search_models(cfg.horizon, cfg.detect_same)
    tables = hy.qsr_tables(hmap, models)
    cost = hy.hybrid_costs(hmap, cfg.beta, models, tables)
    graph = qlink.link_graph(hmap.elements, cfg.beta, cost=np.where(np.isfinite(cost), cost, 1.0))
    g = qlink.to_networkx(graph, hmap.elements)
    rng = np.random.default_rng(cfg.seed)
    e = len(hmap.kind)
    pairs, paths, tries = [], [], 0
    while len(pairs) < cfg.trials and tries < 100 * cfg.trials:
        tries += 1
        s, t = (int(x) for x in rng.integers(e, size=2))
        if s == t or (s, t) in pairs:
            continue
        try:
            paths.append(nx.dijkstra_path(g, s, t))
        except nx.NetworkXNoPath:
            continue
        pairs.append((s, t))
    if len(pairs) < cfg.trials:
        raise ValueError(f"only {len(pairs)} connected start/goal pairs in this map")
    return dict(points=pts, walls=walls, hmap=hmap, landmarks=lm, models=models, graph=g,
                tables=tables, pairs=pairs, paths=paths)


def _pad(paths):
    width = max(len(p) for p in paths)
    out = np.full((len(paths), width), -1, np.int32)
    for i, p in enumerate(paths):
        out[i, :len(p)] = p
    return out


def run_setting(cfg: Config, world: dict, p_miss: float) -> list[dict]:
    """Drive every trial at ``p_miss`` with up to ``max_replans`` contingency re-plans."""
    import jax
    import jax.numpy as jnp
    import networkx as nx

    from ..qlink import FAILURE_REASONS
    from ..qlink import hybrid as hy

    hmap, lm, walls, g = world["hmap"], world["landmarks"], world["walls"], world["graph"]
    ids = np.asarray(hmap.elements.ids)
    pairs, paths = world["pairs"], [list(p) for p in world["paths"]]
    b = len(pairs)
    key = jax.random.fold_in(jax.random.key(cfg.seed), int(round(p_miss * 1e6)) + 7)
    first = [p[0] for p in paths]
    pos = np.asarray(lm)[ids[first]].mean(1)
    nxt = [p[1] if len(p) > 1 else p[0] for p in paths]
    refs = hy.reference_rule(ids[first], hmap.kind[first], ids[nxt], hmap.walls)[0]
    params = hy.HybridParams(cfg.map_range, cfg.sigma, p_miss)
    length = np.zeros(b)
    entered = np.zeros(b, np.int64)
    replans = np.zeros(b, np.int64)
    status = np.zeros(b, np.int64)
    final = np.zeros((b, 2))
    traces = [[] for _ in range(b)]
    removed = [set() for _ in range(b)]
    active = np.arange(b)
    cur_paths = list(paths)     # the planned paths stay for the rows (n_planned)
    for rnd in range(cfg.max_replans + 1):
        keys = jax.vmap(lambda t, r=rnd: jax.random.fold_in(jax.random.fold_in(key, t), r))(
            np.asarray(active))
        res = hy.drive(keys, hmap, lm, walls, _pad([cur_paths[t] for t in active]),
                       [len(cur_paths[t]) for t in active], refs[active], pos[active], params,
                       world["tables"])
        st, ln = np.asarray(res.status), np.asarray(res.length)
        hops, fpos, tr = np.asarray(res.hops), np.asarray(res.pose), np.asarray(res.trace)
        failed = np.asarray(res.failed)
        nxt_active, nxt_paths, nxt_refs = [], {}, {}
        for i, t in enumerate(active):
            length[t] += ln[i]
            entered[t] += hops[i]
            final[t] = fpos[i]
            traces[t].append(tr[i][np.isfinite(tr[i, :, 0])])
            status[t] = st[i]
            if st[i] == hy.SUCCESS or rnd == cfg.max_replans:
                continue
            # contingency (P §4.4.2, Q30): drop the failed edge, re-plan from what is in view
            removed[t].add(tuple(int(x) for x in failed[i]))
            gg = g.copy()
            gg.remove_edges_from([e for e in removed[t] if gg.has_edge(*e)])
            ok_el, refs_el = hy.visible_references(hmap, lm, walls, fpos[i], cfg.map_range)
            srcs = {int(el): refs_el[el] for el in np.flatnonzero(ok_el)}
            goal = pairs[t][1]
            best = None
            for s_el in srcs:
                try:
                    c, p = nx.single_source_dijkstra(gg, s_el, goal)
                except nx.NetworkXNoPath:
                    continue
                if best is None or c < best[0]:
                    best = (c, p)
            if best is None:
                continue   # "cannot re-plan ... insufficient environmental features in view"
            replans[t] += 1
            nxt_active.append(t)
            nxt_paths[t] = best[1]
            nxt_refs[t] = srcs[best[1][0]]
        if not nxt_active:
            break
        for t in nxt_active:
            cur_paths[t] = nxt_paths[t]
            refs[t] = nxt_refs[t]
            pos[t] = final[t]
        active = np.array(nxt_active)
    true_lm = np.asarray(lm)
    rows = []
    for t in range(b):
        gid = ids[pairs[t][1]]
        cen = true_lm[gid].mean(0)
        dist = np.asarray(hy.landmark_distances(jnp.asarray(final[t], lm.dtype), lm, walls))
        in_range = bool((dist[gid] <= cfg.map_range).all())
        ok = status[t] == hy.SUCCESS
        attributed = bool(ok and np.linalg.norm(final[t] - cen) <= cfg.attrib_radius
                          and in_range)
        rows.append(dict(p_miss=p_miss, trial=t, start_element=pairs[t][0],
                         goal_element=pairs[t][1], n_planned=len(paths[t]),
                         n_entered=int(entered[t]), replans=int(replans[t]), success=int(ok),
                         reason=FAILURE_REASONS.get(int(status[t]), "unknown"),
                         attributed=int(attributed), length_m=float(length[t]),
                         final_x=float(final[t, 0]), final_y=float(final[t, 1]),
                         trace=[x.tolist() for x in traces[t]]))
    return rows


def checks(cfg: Config, rows: list[dict]) -> list[tuple[str, str, str, bool]]:
    """``(check, published/target, ours, match)`` rows of the acceptance list."""
    out = []
    r_ = cfg.map_range
    for pm in cfg.p_miss:
        rs = [r for r in rows if r["p_miss"] == pm]
        succ = sum(r["success"] for r in rs)
        rep = sum(r["replans"] for r in rs)
        if pm == 0:
            out.append(("p_miss = 0: all succeed, 0 re-plans", f"{len(rs)}/{len(rs)}, 0",
                        f"{succ}/{len(rs)}, {rep}", succ == len(rs) and rep == 0))
        else:
            att = all(r["attributed"] for r in rs if r["success"])
            out.append((f"p_miss = {pm}: ≥ 1 re-plan", "≥ 1", str(rep), rep >= 1))
            out.append((f"p_miss = {pm}: every success correctly attributed", "all",
                        f"{sum(r['attributed'] for r in rs)}/{succ}", att))
        ok = [r for r in rs if r["success"]]
        by = {}
        for r in ok:
            by.setdefault(r["n_planned"], []).append(r["length_m"])
        kept = [k for k in sorted(by) if len(by[k]) >= cfg.min_bin_trials]
        means = [np.mean(by[k]) for k in kept]
        mono = all(b >= a for a, b in zip(means, means[1:], strict=False))
        out.append((f"p_miss = {pm}: mean length non-decreasing in |P| (bins of ≥ "
                    f"{cfg.min_bin_trials} trials)", "monotone",
                    ", ".join(f"{k}: {np.mean(by[k]):.1f}" + ("" if k in kept else
                                                            f" (n = {len(by[k])}, not ordered)")
                              for k in sorted(by)), mono))
        b2 = all(r["length_m"] <= (2 * np.pi + 1) * r_ * max(r["n_entered"], 1) for r in ok)
        b4 = all(r["length_m"] <= r_ * max(r["n_entered"], 1) for r in ok)
        out.append((f"p_miss = {pm}: lengths ≤ (2π+1)R|P| (Prop. 2)", "all", str(b2), b2))
        out.append((f"p_miss = {pm}: lengths ≤ R|P| (Prop. 4)", "all", str(b4), b4))
    return out


def _claims(cfg: Config, rows: list[dict]) -> list[protocol.Claim]:
    """The acceptance checks (:func:`checks`) as claims, and P's success rate beside ours
    (not a target: terrain pitch and recognition errors are not simulated)."""
    def cell(text: str) -> str:  # "|P|" inside a markdown table cell
        return text.replace("|", "\\|")

    out = [protocol.Claim(cell(name), tgt, cell(ours), None,
                          protocol.MATCH if ok else protocol.MISMATCH)
           for name, tgt, ours, ok in checks(cfg, rows)]
    for pm in cfg.p_miss:
        rs = [r for r in rows if r["p_miss"] == pm]
        if rs:
            rate = sum(r["success"] for r in rs) / len(rs)
            out.append(protocol.Claim(
                f"success rate, p_miss = {pm} (beside P, not a target)",
                f"{PUBLISHED['success_rate']:.0%} in vivo", round(rate, 4), None,
                protocol.NOT_CHECKED))
    return out


def report_text(cfg: Config, world: dict, rows: list[dict], out) -> str:
    """``report.md`` text (and the figure); ``world`` holds ``points``, ``walls`` and
    ``element_kind`` (as stored in ``world.npz``)."""
    kind = np.asarray(world["element_kind"])
    lines = ["# In-vivo-like Q-Link study (P §4.4.2)", "",
             f"World: {cfg.points} points + 2 walls in {cfg.size[0]:g} m × {cfg.size[1]:g} m, "
             f"R = {cfg.map_range:g} m, σ = {cfg.sigma:g} m; map: {len(kind)} elements "
             f"({int((kind == 1).sum())} bands, {int((kind == 0).sum())} LR) "
             f"(P: {PUBLISHED['elements']}); β = {cfg.beta}, −log p costs, τ = {cfg.horizon}, "
             f"direct transitions, ≤ {cfg.max_replans} re-plans. Config and reasons: "
             "`config.json`.", "",
             "## Acceptance checks", "", *protocol.claims_table(_claims(cfg, rows))]
    lines += ["", "## Success beside P (not a target)", "",
              "| | trials | successes | rate | successes after a re-plan |",
              "|---|---|---|---|---|",
              f"| P (in vivo) | {PUBLISHED['trials']} | {PUBLISHED['successes']} | "
              f"{PUBLISHED['success_rate']:.0%} | {PUBLISHED['replanned_successes']} |"]
    for pm in cfg.p_miss:
        rs = [r for r in rows if r["p_miss"] == pm]
        s = sum(r["success"] for r in rs)
        lines.append(f"| ours, p_miss = {pm} | {len(rs)} | {s} | {s / len(rs):.0%} | "
                     f"{sum(1 for r in rs if r['success'] and r['replans'])} |")
    lines += ["", "P's 72 % comes from terrain-pitch occlusion and lidar recognition errors "
              "(P §4.4.2), which are not simulated; the injected misses stand in for them.", "",
              "## Table 4.2 — mean length (m) of successful trials by planned |P|", "",
              "| |P| | P paths | P mean | " + " | ".join(f"ours p_miss={pm} (n, mean)"
                                                    for pm in cfg.p_miss) + " |",
              "|---|---|---|" + "---|" * len(cfg.p_miss)]
    ks = sorted({r["n_planned"] for r in rows} | set(PUBLISHED["table_4_2"]))
    for k in ks:
        pub = PUBLISHED["table_4_2"].get(k)
        cells = []
        for pm in cfg.p_miss:
            v = [r["length_m"] for r in rows if r["p_miss"] == pm and r["success"]
                 and r["n_planned"] == k]
            cells.append(f"{len(v)}, {np.mean(v):.1f}" if v else "—")
        lines.append(f"| {k} | {pub[0] if pub else '—'} | {pub[1] if pub else '—'} | "
                     + " | ".join(cells) + " |")
    lines += ["", "Lengths are not expected to match P: the synthetic world's size and layout "
              "are ours (config `size`).", "",
              *protocol.figure("invivo_world.png", "The synthetic world (black: point "
                               "landmarks, blue: the two walls; axes in metres) with up to six "
                               "driven trials per p_miss, re-planned and failed ones first: "
                               "triangle = start, star = end, dots = stops, dashed = failed.")]
    _figure(cfg, world, rows, out)
    return "\n".join(lines)


def _figure(cfg, world, rows, out):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pts, walls = np.asarray(world["points"]), np.asarray(world["walls"])
    fig, axes = plt.subplots(1, len(cfg.p_miss), figsize=(6 * len(cfg.p_miss), 4.5),
                             squeeze=False)
    for ax, pm in zip(axes[0], cfg.p_miss, strict=True):
        ax.scatter(pts[:, 0], pts[:, 1], c="k", s=12, label="point landmarks")
        for i, w in enumerate(walls):
            ax.plot(w[:, 0], w[:, 1], "b-", lw=4, label="walls" if i == 0 else None)
        rs = sorted((r for r in rows if r["p_miss"] == pm),     # re-planned/failed first
                    key=lambda r: (-(r["replans"] > 0 or not r["success"]), r["trial"]))[:6]
        for k, r in enumerate(rs):
            # the driven trajectory: every stop (straight drives between them; a drive that
            # meets a wall stops there, docs/qlink.md §invivo) and the final position
            xy = np.concatenate([np.asarray(t).reshape(-1, 2) for t in r["trace"]] +
                                [np.array([[r["final_x"], r["final_y"]]])])
            line, = ax.plot(xy[:, 0], xy[:, 1], marker="o", ms=3, lw=1,
                            ls="-" if r["success"] else "--",
                            label=f"trial {r['trial']}: |P|={r['n_planned']}, re-plans "
                                  f"{r['replans']}"
                                  f"{'' if r['success'] else ', ' + r['reason']}")
            ax.plot(*xy[0], "^", color=line.get_color(), ms=8, mec="k",
                    label="start" if k == 0 else None)
            ax.plot(*xy[-1], "*", color=line.get_color(), ms=11, mec="k",
                    label="end (goal)" if k == 0 else None)
        ax.set_title(f"p_miss = {pm}")
        ax.set(xlabel="x (m)", ylabel="y (m)")
        ax.set_aspect("equal")
        ax.legend(fontsize=6, loc="upper right")
    atomic_savefig(fig, out / "invivo_world.png", dpi=110)
    plt.close(fig)




def configure(argv: list[str], overrides: dict | None = None
              ) -> tuple[Config, argparse.Namespace]:
    """The study's Config and parsed flags (every number checked before any work)."""
    p = protocol.parser(NAME, HELP, seed=Config.seed)
    a = p.parse_args(argv)
    cfg = protocol.apply_preset(Config, PRESETS, a.preset, a, {}, overrides)
    if "seed" not in (overrides or {}):
        cfg = dataclasses.replace(cfg, seed=a.seed)
    cfg = dataclasses.replace(cfg, size=tuple(float(x) for x in cfg.size),
                              p_miss=tuple(float(x) for x in cfg.p_miss))
    if len(cfg.size) != 2 or min(cfg.size) <= 0:
        p.error(f"size must be two lengths > 0, got {cfg.size}")
    if not all(0.0 <= x < 1.0 for x in cfg.p_miss) or not cfg.p_miss:
        p.error(f"p_miss must be probabilities in [0, 1), got {cfg.p_miss}")
    if min(cfg.points, cfg.trials, cfg.num_samples, cfg.max_obs, cfg.beta) < 1 \
            or cfg.max_replans < 0:
        p.error("points, trials, num_samples, max_obs and beta must be ≥ 1 and max_replans "
                "≥ 0")
    return cfg, a


def _stored(cfg: Config) -> dict:
    return json.loads(json.dumps(dict(dataclasses.asdict(cfg), reasons=REASONS)))


def _open(out: Path, cfg: Config | None, fresh: bool = False) -> Store:
    return Store.open(out, NAME, None if cfg is None else _stored(cfg), fresh=fresh)


def _records(st: Store):
    return st.records("settings.jsonl", key=lambda r: r["p_miss"], required=("p_miss", "rows"))


def run_study(cfg: Config, out: Path, *, quiet: bool = False, cluster=None,
              fresh: bool = False) -> None:
    """Every ``p_miss`` setting not yet stored (``settings.jsonl``, one record each), split
    over the processes; process 0 writes them, ``trials.csv``, ``world.npz`` and
    ``results.csv``."""
    from . import distributed

    cluster = cluster or distributed.current()
    distributed.agree(cluster, _stored(cfg), f"{NAME} config")
    st = log = None

    def left():  # process 0: open the store, the settings not stored yet
        nonlocal st, log
        st = _open(out, cfg, fresh)
        log = _records(st)
        return [pm not in log for pm in cfg.p_miss]

    try:
        todo = [pm for pm, m in zip(cfg.p_miss, distributed.decide(cluster, len(cfg.p_miss),
                                                                     left), strict=True) if m]
        world = build(cfg)
        for j, rows in distributed.map_units(lambda pm: run_setting(cfg, world, pm), todo,
                                             cluster, codec="json"):
            if log is not None:
                log.add({"p_miss": todo[j], "rows": rows})
        if st is None:
            return
        rows = [r for pm in cfg.p_miss for r in log.get(pm)["rows"]]
        atomic_write_text(st.path("trials.csv"), csv_text(FIELDS, rows))
        hm = world["hmap"]
        atomic_write_npz(st.path("world.npz"), {
            "points": np.asarray(world["points"]), "walls": np.asarray(world["walls"]),
            "element_ids": np.asarray(hm.elements.ids), "element_kind": hm.kind,
            "beta": np.int32(cfg.beta)})
        st.write_results_csv([
            (f"p_miss={pm}", m, v)
            for pm in cfg.p_miss
            for m, v in (("success_rate", np.mean([r["success"] for r in rows
                                                   if r["p_miss"] == pm])),
                         ("replans", sum(r["replans"] for r in rows if r["p_miss"] == pm)))])
    finally:
        if st is not None:
            st.close()


def _load(out: Path) -> tuple[Config, list[dict], dict]:
    """(Config, trial rows, world arrays) of a finished study in ``out``."""
    from .store import StudyError

    with _open(Path(out), None) as st:
        fields = {f.name for f in dataclasses.fields(Config)}
        stored = {k: v for k, v in st.config.items() if k in fields}
        cfg = Config(**{k: tuple(v) if isinstance(v, list) else v for k, v in stored.items()})
        log = _records(st)
        world = st.read_npz("world.npz", ("points", "walls", "element_kind"))
        if world is None or any(pm not in log for pm in cfg.p_miss):
            raise StudyError(f"{out} holds no finished {NAME} results; run the study first")
        rows = [r for pm in cfg.p_miss for r in log.get(pm)["rows"]]
    return cfg, rows, world


def claims(out: Path) -> list[protocol.Claim]:
    """The acceptance checks of P §4.4.2 and P's success rate beside ours."""
    cfg, rows, _ = _load(out)
    return _claims(cfg, rows)


def report(out: Path) -> Path:
    """``report.md`` and ``invivo_world.png`` from the stored results."""
    out = Path(out)
    cfg, rows, world = _load(out)
    atomic_write_text(out / "report.md", report_text(cfg, world, rows, out))
    return out / "report.md"


sweep_summary = protocol.summary_for(sys.modules[__name__])
main = protocol.main_for(sys.modules[__name__])
