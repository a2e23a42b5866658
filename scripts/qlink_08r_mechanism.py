"""Where the Table 4.1 sensor-range failures come from, by experiment (issue 24, item 4).

The study (`pqrm-jax study qlink`) fails 16 % of the paths at R′ = 0.8R, the thesis 31.9 %
(P Table 4.1). This script runs the study's own executive on one world (the study's seeded
``--max-pairs`` sample, β = 2, the study's per-trial keys) and measures

1. **where** every failed transition fails, by the geometry of the executive's own search
   pattern (true positions): a link (or the goal) searched for on the quarter arcs of radius
   R about the references' midpoint M is in the arcs' reach only if
   ``R − R′ ≤ |e − M| ≤ R + R′``; the circle of radius R′ about the link e sees a second
   member m of the next element only if ``|m − e| ≤ 2R′``;
2. a fine R′ sweep (how steep the failure rate is around 0.8R);
3. **what moves the rate**, side by side on the same pairs and keys: navigation noise off,
   the noise-free map, the rover step, the circle radius R (the thesis's words, "a circle of
   radius R"), the ``epoch`` sensing model, and the mapping trajectory (lawnmower lanes
   f·R apart instead of R: P §4.4.1 says only "driving the environment").

Nothing here is tuned: every variant is a reading of the text or an idealisation, reported
beside the baseline. Results: one JSON per variant in OUT and a table on stdout.

Usage (CPU: about 5 min on one core for the default parts)::

    python scripts/qlink_08r_mechanism.py OUT [--world 0] [--max-pairs 4000] [--lanes 0.5]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from collections import Counter
from pathlib import Path

import numpy as np

from pqrm_jax import sim
from pqrm_jax.qlink import elements as qel
from pqrm_jax.qlink import linkgraph as lg
from pqrm_jax.qlink import navigate as nav
from pqrm_jax.qlink import pomdp
from pqrm_jax.studies import qlink as Q

SWEEP = (1.0, 0.9, 0.85, 0.82, 0.8, 0.78, 0.75, 0.7)
SETTINGS = (1.0, 0.9, 0.8, 0.7)


def build(cfg: Q.Config, w: int, lanes: float = 1.0, exact: bool = False):
    """The study's world ``w`` (lawnmower lanes ``lanes``·R apart; ``exact``: the noise-free
    relations of the same elements) and everything ``Q.run_setting`` needs."""
    orig = sim.lawnmower
    if lanes != 1.0:
        sim.lawnmower = lambda size, spacing, step: orig(size, spacing=spacing * lanes,
                                                         step=step)
    try:
        lm, el, detect = Q._build(cfg, w)
    finally:
        sim.lawnmower = orig
    if exact:
        el = qel.exact_elements(lm, np.asarray(el.ids))
    lms = np.flatnonzero(qel.incidence(el).any(1))
    goal_row = np.full(el.num_landmarks, -1, np.int64)
    goal_row[lms] = np.arange(len(lms))
    pairs = Q._pairs(cfg, lms, w)
    g = lg.link_graph(el, 2)
    to_go = lg.goal_distances(g, el, lms)
    plans = nav.qsr_plans(el, pomdp.search_model("quadrant", horizon=cfg.horizon,
                                                 detect=detect))
    return (lm, el, g, to_go, goal_row, nav.start_tables(el), pairs, detect, plans)


def _link_of(ids, cur, nxt, refs):
    """The link the executive's PLAN step searches for (navigate._plan_step's rule)."""
    lc, ln = ids[cur], ids[nxt]
    cand = [x for x in lc if x in ln and x not in refs]
    return cand[0] if cand else [x for x in lc if x in ln][0]


def run(cfg: Q.Config, w: int, frac: float, world, circle_r: bool = False) -> dict:
    """One setting R′ = frac·R: failure %, reasons, mean |P| and the reach class of every
    failed transition."""
    lm, el = world[0], world[1]
    ids, pos = np.asarray(el.ids), np.asarray(lm, np.float64)
    r_map, r_nav = cfg.map_range, frac * cfg.map_range
    if circle_r:          # every circle of radius 0.999 R instead of 0.999 R′
        cfg = dataclasses.replace(cfg, circle_margin=cfg.circle_margin / frac)
    got = []
    orig = nav.navigate

    def spy(trials, *a, **k):
        r = orig(trials, *a, **k)
        got.append((np.asarray(trials.paths), np.asarray(trials.n_elements),
                    np.asarray(trials.goals), r))
        return r

    nav.navigate = spy
    t0 = time.process_time()
    try:
        name = "R" if frac == 1.0 else f"{frac:g}R"
        rows = Q.run_setting(cfg, w, 2, name, frac, 0.0, world, progress=False)
    finally:
        nav.navigate = orig
    cpu = time.process_time() - t0
    reach = [r for r in rows if r["reachable"]]
    fails = Counter(r["reason"] for r in reach if not r["success"])
    cls = Counter()
    for paths, n, goals, res in got:
        st, k, refs = np.asarray(res.status), np.asarray(res.k), np.asarray(res.refs)
        for i in np.flatnonzero(st != nav.SUCCESS):
            s, rf = int(st[i]), refs[i]
            if s in (nav.LINK_NOT_FOUND, nav.GOAL_NOT_FOUND):
                e = goals[i] if s == nav.GOAL_NOT_FOUND else _link_of(
                    ids, paths[i, k[i]], paths[i, k[i] + 1], list(rf))
                d = np.linalg.norm(pos[e] - pos[rf].mean(0))
                inside = r_map - r_nav <= d <= r_map + r_nav
                cls[f"{nav.FAILURE_REASONS[s]}: {'in' if inside else 'out of'} the arcs' "
                    "reach"] += 1
            elif s == nav.REFS_NOT_FOUND and 0 <= k[i] < n[i] - 1:
                nxt = paths[i, k[i] + 1]
                e = _link_of(ids, paths[i, k[i]], nxt, list(rf))
                d = min(np.linalg.norm(pos[m] - pos[e]) for m in ids[nxt] if m != e)
                cls[f"refs_not_found: 2nd member {'within' if d <= 2 * r_nav else 'beyond'}"
                    " 2R' of the link"] += 1
            else:
                cls[nav.FAILURE_REASONS[s]] += 1
    return dict(setting=f"{frac:g}R", trials=len(rows), reachable=len(reach),
                failures=sum(fails.values()),
                failure_pct=round(100.0 * sum(fails.values()) / max(len(reach), 1), 2),
                reasons=dict(sorted(fails.items())), reach_classes=dict(sorted(cls.items())),
                mean_elements=round(float(np.mean([r["n_elements"] for r in reach])), 2),
                cpu_s=round(cpu, 1))


def element_spread(world) -> dict:
    """How wide the map's elements are: quantiles of each element's widest pair (m)."""
    lm, el = world[0], world[1]
    p = np.asarray(lm, np.float64)[np.asarray(el.ids)]
    d = np.linalg.norm(p[:, :, None] - p[:, None, :], axis=-1).max((1, 2))
    return dict(elements=int(len(d)),
                widest_pair_quantiles_10_50_90=np.round(np.quantile(d, [.1, .5, .9]), 1)
                .tolist(),
                share_wider_than_32m=round(float((d > 32).mean()), 3))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out")
    ap.add_argument("--world", type=int, default=0)
    ap.add_argument("--max-pairs", type=int, default=4000)
    ap.add_argument("--lanes", type=float, nargs="*", default=[0.5],
                    help="lawnmower lane spacings (× R) of the mapping variants")
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    cfg = dataclasses.replace(Q.Config(), worlds=(a.world,), max_pairs=a.max_pairs,
                              chunk=Q.CPU_CHUNK)
    base = build(cfg, a.world)
    variants = [
        ("baseline", cfg, base, SWEEP, False),
        ("nav_sigma 0", dataclasses.replace(cfg, nav_sigma=0.0), base, SETTINGS, False),
        ("nav_sigma 0 + exact map", dataclasses.replace(cfg, nav_sigma=0.0), None, SETTINGS,
         False),
        ("ds 0.25 m", dataclasses.replace(cfg, ds=0.25), base, SETTINGS, False),
        ("ds 1 m", dataclasses.replace(cfg, ds=1.0), base, SETTINGS, False),
        ("circle radius R", cfg, base, SETTINGS, True),
        ("epoch sensing", dataclasses.replace(cfg, sensing="epoch"), base, SETTINGS, False),
    ] + [(f"lanes {f:g}R", cfg, f, SETTINGS, False) for f in a.lanes]
    for name, c, world, fracs, circle_r in variants:
        if world is None:
            world = build(cfg, a.world, exact=True)
        elif isinstance(world, float):
            world = build(cfg, a.world, lanes=world)
        rec = dict(variant=name, world=a.world, max_pairs=a.max_pairs,
                   map=element_spread(world), rows=[])
        for f in fracs:
            rec["rows"].append(run(c, a.world, f, world, circle_r))
            r = rec["rows"][-1]
            print(f"{name:26s} {r['setting']:6s} {r['failure_pct']:6.2f} % "
                  f"|P| {r['mean_elements']:5.2f}  {r['reach_classes']}", flush=True)
        (out / f"{name.replace(' ', '_')}.json").write_text(json.dumps(rec, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
