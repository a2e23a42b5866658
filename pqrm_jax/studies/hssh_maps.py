"""HSSH global levels on random corridor worlds and a §8.3-like office (B §8.3, ch. 9).

For each random lattice corridor world (nested loops, aliased intersections) one exploration is
run and the tree of maps (B Alg. 8.1, star views) is built; per world: leaves after each travel,
inconsistent leaves, branching events and ``k`` against the §8.3 bounds (branching ≤ k+1, ≤ m·l/2
branching travels), whether the true map is among the leaves (it must always be) and whether the
preferred leaf (fewest places, then layout cost) is the true one, the layout error before/after the
spring relaxation (relative to the lattice spacing) and navigation success with the preferred map.
The basic-SSH tree (symbol views, branching on turns) is built on a short prefix for the
leaf-count comparison. The office world (6 paths, 9 places, 4 distinct local topologies) is
explored with 14 travels from several seeds: leaves and minimal models beside the published
83 → 4 (46 → 1 with planarity). The thesis's exploration trace is not published, so only the
order of magnitude can be compared.

Simulator-driven worlds (:mod:`pqrm_jax.hssh_global.simulation`): random lattice worlds rendered
into occupancy grids and explored by the simulated rover with the real local levels (lidar →
scrolling LPM → gateways → local topology → star views, dead-reckoning odometry); per world:
whether every view matched its true place, the tree of maps, layout error, the global occupancy
map's agreement with the walls (odometry vs relaxed poses, and relaxed with re-localisation of
each revisit in the place's stored LPM, :mod:`pqrm_jax.hssh_global.relocalize`) and navigation
executed in the simulator; a lost exploration or navigation run is recorded with its reason.

Writes ``worlds.jsonl`` / ``office.jsonl`` / ``sim.jsonl`` (records, resumable), ``results.csv``,
``report.md`` and figures ``tree_size.png``, ``layout.png``, ``navigation.png``, ``sim_map.png``.

    pqrm-jax study hssh-maps --out DIR [--reduced]

As N processes on ``jax.distributed`` (README "Running on a cluster"; the flags of
:func:`.distributed.add_arguments`) process 0 lists the world, office and simulator units left,
the processes compute them in rounds of N (:func:`.distributed.map_units`) and process 0
writes each record as it arrives; the records equal a one-process run's except the measured
``explore_s``. Simulator world 0, which also draws ``sim_map.png``, is listed first, so it
always falls to process 0.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

from . import protocol

NAME = "hssh-maps"
HELP = "HSSH global levels: tree of maps, layout, navigation (B §8.3, ch. 9)"

PUBLISHED = {"office_travels": 14, "office_leaves": 83, "office_minimal": 4,
             "office_leaves_planar": 46, "office_minimal_planar": 1}

REASONS = {
    "worlds": "number of random worlds (reduced: enough for a CI smoke run)",
    "sizes": "lattice sizes cycled over worlds; small enough that full trees stay enumerable",
    "loop_prob": "probability of each extra lattice corridor (controls nested loops)",
    "travels": "travel actions per exploration",
    "basic_travels": "prefix length for the basic-SSH tree (it grows much faster)",
    "sigma_xy": "odometry sd per unit travelled (x, y)",
    "sigma_theta": "odometry heading sd per shortest corridor",
    "nav_pairs": "random start/goal pairs per world",
    "office_seeds": "exploration seeds of the office world (trace of the thesis not published)",
    "max_leaves": "the tree is never truncated: beyond this the world is recorded as too large",
    "seed": "base seed of worlds and explorations",
    "sim_worlds": "simulator-driven worlds (each exploration drives the rover: seconds per travel)",
    "sim_sizes": "lattice sizes of the simulator-driven worlds",
    "sim_travels": "travel actions per simulator-driven exploration",
    "sim_nav_pairs": "start/goal pairs driven in the simulator per world",
    "sim_width": "corridor width / shortest corridor (LPM of 3.2 widths fits one intersection)",
    "sim_sigma_v": "executed-speed sd, relative (dead-reckoning error source)",
    "sim_sigma_w": "heading-rate sd per corridor width travelled (rad)",
    "sim_reloc": "re-localisation at revisits (RelocParams): search window half-widths in "
                 "corridor widths / rad (the mean revisit jitter without it is 0.11 w and "
                 "0.024 rad, single revisits stray up to 0.8 w: a ±0.3 w window clamped one in "
                 "world 0), candidates per axis, coarse-to-fine levels, likelihood-field sd in "
                 "LPM cells, least match score to apply a correction; window shrink per "
                 "level, the LPM's occupied log-odds threshold and the obstacle points kept "
                 "per snapshot (padding) are RelocParams' defaults",
    "geo_alpha": "declared geometric test beyond B (issue 26): a map whose relaxed layout cost "
                 "2·cost exceeds the 1 − geo_alpha χ² quantile (dof 3N − 3(M − 1)) is demoted "
                 "behind every supported map; reported on and off (B's ordering is off)",
    "sim_layout_sigma": "odometry sd assumed by the relaxation of simulator runs (x, y per unit, "
                        "θ per corridor); above the dead-reckoning noise because entry bearings "
                        "from tilted gateways carry a few degrees of error",
}


def _reloc_default() -> dict:
    return {"window_xy": 0.8, "window_theta": 0.12, "steps": 9, "levels": 4, "zoom": 3.0,
            "sigma_cells": 1.0, "threshold": 0.4, "min_score": 0.3, "max_points": 512}


@dataclasses.dataclass(frozen=True)
class Config:
    """Every setting of the study (each knob's reason in :data:`REASONS`); stored in
    ``config.json`` by :meth:`to_json` (with the reasons). ``worlds`` only selects units
    (``--worlds N``: the first N random worlds)."""

    worlds: int = 30
    sizes: tuple[tuple[int, int], ...] = ((3, 3), (4, 3), (4, 4))
    travels: int = 24
    basic_travels: int = 10
    nav_pairs: int = 30
    office_seeds: int = 10
    sim_worlds: int = 8
    sim_sizes: tuple[tuple[int, int], ...] = ((3, 3), (4, 3))
    sim_travels: int = 20
    sim_nav_pairs: int = 6
    loop_prob: float = 0.5
    sigma_xy: float = 0.03
    sigma_theta: float = 0.02
    max_leaves: int = 20000
    sim_width: float = 0.2
    sim_sigma_v: float = 0.02
    sim_sigma_w: float = 0.02
    geo_alpha: float = 1e-3
    sim_layout_sigma: tuple[float, float] = (0.02, 0.02)
    sim_reloc: dict = dataclasses.field(default_factory=_reloc_default)
    seed: int = 18

    def to_json(self) -> dict:
        """The stored config (the dict every function of this module reads)."""
        return json.loads(json.dumps(dict(protocol.config_json(self), reasons=REASONS)))


PRESETS: dict[str, dict] = {
    "tiny": {"worlds": 2, "sizes": ((3, 3),), "travels": 12, "basic_travels": 6,
             "nav_pairs": 4, "office_seeds": 1, "sim_worlds": 1, "sim_sizes": ((3, 3),),
             "sim_travels": 6, "sim_nav_pairs": 1},
    "reduced": {"worlds": 4, "sizes": ((3, 3), (4, 3)), "travels": 16, "basic_travels": 8,
                "nav_pairs": 10, "office_seeds": 2, "sim_worlds": 1, "sim_sizes": ((3, 3),),
                "sim_travels": 10, "sim_nav_pairs": 2},
    "full": {},
}
"""Field overrides of :class:`Config` per preset (``--reduced``: 4 small worlds, one simulator
world, CI; ``--tiny``: 2 worlds, short explorations, for tests)."""


def configure(argv: list[str], overrides: dict | None = None
              ) -> tuple[Config, argparse.Namespace]:
    """The study's Config and parsed flags (every number checked before any work)."""
    p = protocol.parser(NAME, HELP, seed=Config.seed)
    p.add_argument("--worlds", type=protocol.positive_int, default=None,
                   help="run/report only the first N random worlds (resumable)")
    a = p.parse_args(argv)
    cfg = protocol.apply_preset(Config, PRESETS, a.preset, a, {"worlds": "worlds"}, overrides)
    if "seed" not in (overrides or {}):
        cfg = dataclasses.replace(cfg, seed=a.seed)
    ints = ("worlds", "travels", "basic_travels", "nav_pairs", "office_seeds", "sim_worlds",
            "sim_travels", "sim_nav_pairs", "max_leaves")
    bad = [k for k in ints if getattr(cfg, k) < 1]
    if bad:
        p.error(f"{', '.join(bad)} must be ≥ 1, got {[getattr(cfg, k) for k in bad]}")
    if not cfg.sizes or not cfg.sim_sizes or min(min(s) for s in (*cfg.sizes,
                                                                  *cfg.sim_sizes)) < 2:
        p.error(f"sizes and sim_sizes must be lattices of at least 2 x 2, got {cfg.sizes}, "
                f"{cfg.sim_sizes}")
    if not 0 <= cfg.loop_prob <= 1 or not 0 < cfg.geo_alpha < 1:
        p.error(f"loop_prob must be in [0, 1] and geo_alpha in (0, 1), got {cfg.loop_prob}, "
                f"{cfg.geo_alpha}")
    return cfg, a


def run_world(cfg: dict, i: int) -> dict:
    from .. import hssh_global as hg

    nx_, ny = cfg["sizes"][i % len(cfg["sizes"])]
    w = hg.grid_world(nx_, ny, loop_prob=cfg["loop_prob"], seed=cfg["seed"] + i)
    e = hg.explore(w, cfg["travels"], seed=cfg["seed"] + 1000 + i, sigma_xy=cfg["sigma_xy"],
                   sigma_theta=cfg["sigma_theta"])
    rec = {"world": i, "lattice": f"{nx_}x{ny}", "places": w.n_places,
           "seen_places": len(set(e.true_places.tolist()))}
    try:
        log = hg.build_tree(e, max_leaves=cfg["max_leaves"])
    except hg.TreeTooLarge:
        return {**rec, "too_large": 1}
    leaves = log.leaves
    lmax = max(len(s) for s in w.stars)
    truth = [k for k, h in enumerate(leaves) if hg.is_true_map(h, e)]
    prob, chi, cost = hg.relax_many(leaves, e.odometry, cfg["sigma_xy"], cfg["sigma_theta"])
    order = hg.preference_order(leaves, np.asarray(cost))
    best = leaves[order[0]]
    minimal = hg.minimal_models(leaves)
    sup = hg.layout_supported(cost, leaves, len(e.odometry), cfg["geo_alpha"])
    best_geo = hg.preference_order(leaves, np.asarray(cost), sup)[0]
    rec.update({"too_large": 0, "leaves": log.n_leaves.tolist(), "final_leaves": len(leaves),
                "inconsistent": int(log.n_inconsistent.sum()), "branch_events": log.branch_events,
                "k": log.k_max, "max_branching": int(log.branching.max()),
                "bound_branching_ok": int(log.branching.max() <= log.k_max + 1),
                "bound_events": w.n_places * lmax / 2,
                "bound_events_ok": int(log.branch_events <= w.n_places * lmax / 2),
                "true_in_leaves": int(len(truth) == 1), "minimal_models": len(minimal),
                "true_minimal": int(bool(truth) and truth[0] in minimal),
                "preferred_true": int(hg.is_true_map(best, e)),
                "preferred_true_geo": int(bool(truth) and best_geo == truth[0]),
                "true_supported": int(bool(truth) and bool(sup[truth[0]])),
                "minimal_unsupported": int((~sup[minimal]).sum()),
                "preferred_cost": float(cost[order[0]]),
                "true_cost": float(cost[truth[0]]) if truth else float("nan")})
    if truth:
        k, gt, m = truth[0], hg.true_layout(w, e), leaves[truth[0]].n_places
        unit = min(d for (_, _, d) in w.edges.values())
        rec["layout_err_odometry"] = float(np.linalg.norm(
            np.asarray(prob.init[k, :m, :2]) - gt[:, :2], axis=1).mean() / unit)
        rec["layout_err_relaxed"] = float(np.linalg.norm(
            np.asarray(chi[k, :m, :2]) - gt[:, :2], axis=1).mean() / unit)
    nav = hg.evaluate_navigation(w, e, best, cfg["nav_pairs"], seed=cfg["seed"] + i)
    rec["nav_success"], rec["nav_length_ratio"] = nav["success"], nav["length_ratio"]
    short = e._replace(views=e.views[:cfg["basic_travels"] + 1],
                       bearings=e.bearings[:cfg["basic_travels"] + 1],
                       turns=e.turns[:cfg["basic_travels"]])
    rec["star_leaves_prefix"] = len(hg.build_tree(short).leaves)
    try:
        rec["basic_leaves_prefix"] = len(hg.build_basic_tree(short, cfg["max_leaves"]).leaves)
    except hg.TreeTooLarge:
        rec["basic_leaves_prefix"] = -1  # sentinel: more than max_leaves
    return rec


def run_office(cfg: dict, s: int) -> dict:
    from .. import hssh_global as hg

    w = hg.office_world()
    e = hg.explore(w, PUBLISHED["office_travels"], seed=cfg["seed"] + 5000 + s,
                   sigma_xy=cfg["sigma_xy"], sigma_theta=cfg["sigma_theta"])
    log = hg.build_tree(e, max_leaves=cfg["max_leaves"])
    minimal = hg.minimal_models(log.leaves)
    truth = [k for k, h in enumerate(log.leaves) if hg.is_true_map(h, e)]
    _, _, cost = hg.relax_many(log.leaves, e.odometry, cfg["sigma_xy"], cfg["sigma_theta"])
    best = hg.preference_order(log.leaves, cost)[0]
    sup = hg.layout_supported(cost, log.leaves, len(e.odometry), cfg["geo_alpha"])
    best_geo = hg.preference_order(log.leaves, cost, sup)[0]
    planar = [h for h in log.leaves if hg.is_planar(h)]   # optional filter (B §8.3)
    return {"seed": s, "leaves": log.n_leaves.tolist(), "final_leaves": len(log.leaves),
            "minimal_models": len(minimal), "seen_places": len(set(e.true_places.tolist())),
            "true_in_leaves": int(len(truth) == 1),
            "true_minimal": int(bool(truth) and truth[0] in minimal),
            "preferred_true": int(bool(truth) and best == truth[0]), "k": log.k_max,
            "preferred_true_geo": int(bool(truth) and best_geo == truth[0]),
            "true_supported": int(bool(truth) and bool(sup[truth[0]])),
            "minimal_unsupported": int((~sup[minimal]).sum()),
            "branch_events": log.branch_events,
            "planar_leaves": len(planar), "planar_minimal": len(hg.minimal_models(planar)),
            "true_planar": int(bool(truth) and hg.is_planar(log.leaves[truth[0]]))}


def run_sim_world(cfg: dict, i: int, fig_dir: Path | None = None) -> dict:
    """One simulator-driven world: explore with the local levels, tree, layout, map, navigation."""
    import time

    from .. import hssh_global as hg

    nx_, ny = cfg["sim_sizes"][i % len(cfg["sim_sizes"])]
    seed = cfg["seed"] + 7000 + i
    w = hg.grid_world(nx_, ny, loop_prob=cfg["loop_prob"], seed=seed)
    params = hg.SimParams(width=cfg["sim_width"], sigma_v=cfg["sim_sigma_v"],
                          sigma_w=cfg["sim_sigma_w"])
    sw = hg.sim_world(w, params)
    rec = {"world": i, "lattice": f"{nx_}x{ny}", "places": w.n_places}
    t0 = time.perf_counter()
    try:
        se = hg.explore_sim(sw, cfg["sim_travels"], seed=seed + 1)
    except hg.SimulationError as exc:
        return {**rec, "lost": 1, "reason": str(exc)[:400]}
    ex = se.experience
    rec.update({"lost": 0, "explore_s": time.perf_counter() - t0, "checks": se.checks,
                "rejected_views": se.rejected,
                "seen_places": len(set(ex.true_places.tolist())),
                "views_true": int(sum(hg.view_match(v, (w.stars[int(p)], int(a))) for v, p, a
                                      in zip(ex.views, ex.true_places, ex.true_arrivals,
                                             strict=True))),
                "views": len(ex.views)})
    try:
        log = hg.build_tree(ex, max_leaves=cfg["max_leaves"])
    except hg.TreeTooLarge:
        return {**rec, "too_large": 1}
    leaves = log.leaves
    truth = [k for k, h in enumerate(leaves) if hg.is_true_map(h, ex)]
    sx, st_ = cfg["sim_layout_sigma"]
    prob = hg.pack(leaves, ex.odometry, sx, st_)
    chi, cost = hg.relax(prob)
    order = hg.preference_order(leaves, np.asarray(cost))
    # re-localisation at revisits (B §9.2): corrected displacements per hypothesis
    t1 = time.perf_counter()
    rl = hg.visit_offsets(sw, se, leaves, hg.RelocParams(**cfg["sim_reloc"]))
    prob_r = hg.pack(leaves, rl.odometry, sx, st_)
    chi_r, cost_r = hg.relax(prob_r)
    rec["reloc_s"] = time.perf_counter() - t1
    order_r = hg.preference_order(leaves, np.asarray(cost_r))
    best = leaves[order_r[0]]
    n_tr = len(ex.odometry)
    sup = hg.layout_supported(np.asarray(cost), leaves, n_tr, cfg["geo_alpha"])
    sup_r = hg.layout_supported(np.asarray(cost_r), leaves, n_tr, cfg["geo_alpha"])
    order_g = hg.preference_order(leaves, np.asarray(cost), sup)
    order_rg = hg.preference_order(leaves, np.asarray(cost_r), sup_r)
    unit = min(d for (_, _, d) in w.edges.values())
    rec.update({"too_large": 0, "final_leaves": len(leaves), "k": log.k_max,
                "branch_events": log.branch_events,
                "true_in_leaves": int(len(truth) == 1),
                "preferred_true": int(hg.is_true_map(leaves[order[0]], ex)),
                "preferred_true_reloc": int(hg.is_true_map(best, ex)),
                "preferred_true_geo": int(hg.is_true_map(leaves[order_g[0]], ex)),
                "preferred_true_reloc_geo": int(hg.is_true_map(leaves[order_rg[0]], ex)),
                "true_supported": int(bool(truth) and bool(sup[truth[0]])),
                "true_supported_reloc": int(bool(truth) and bool(sup_r[truth[0]]))})
    odo_err = np.abs(ex.odometry - ex.true_odometry)
    rec["odometry_err_xy"] = float(np.linalg.norm(odo_err[:, :2], axis=1).mean() / unit)
    if truth:
        k, gt = truth[0], hg.true_layout_sim(se)
        m = leaves[k].n_places
        rec["layout_err_odometry"] = float(np.linalg.norm(
            np.asarray(prob.init[k, :m, :2]) - gt[:, :2], axis=1).mean() / unit)
        rec["layout_err_relaxed"] = float(np.linalg.norm(
            np.asarray(chi[k, :m, :2]) - gt[:, :2], axis=1).mean() / unit)
        rec["layout_err_reloc"] = float(np.linalg.norm(
            np.asarray(chi_r[k, :m, :2]) - gt[:, :2], axis=1).mean() / unit)
        jxy, jth = hg.revisit_jitter(se, leaves[k])
        rec["revisit_jitter_xy"], rec["revisit_jitter_theta"] = jxy / unit, jth
        jxy, jth = hg.revisit_jitter(se, leaves[k], rl.offsets[k])
        rec["reloc_err_xy"], rec["reloc_err_theta"] = jxy / unit, jth
        rev = ~np.isnan(rl.score[k])
        rec["reloc_used"] = float(rl.used[k][rev].mean()) if rev.any() else float("nan")
        maps = {}
        for name, c, off in (("odometry", prob.init[k], None), ("relaxed", chi[k], None),
                             ("reloc", chi_r[k], rl.offsets[k])):
            maps[name] = hg.global_occupancy(sw, se, leaves[k], np.asarray(c), off)
            rec[f"map_agree_{name}"] = hg.map_agreement(sw, *maps[name], se.true_dividing[0])
        if fig_dir is not None:
            _sim_map_figure(fig_dir, sw, maps, rec)
    nav = hg.evaluate_navigation_sim(sw, se, best, cfg["sim_nav_pairs"], seed=seed + 2)
    rec.update({"nav_success": nav["success"], "nav_length_ratio": nav["length_ratio"],
                "nav_lost": nav["lost"], "nav_lost_reasons": nav["lost_reasons"]})
    return rec


def _sim_map_figure(out: Path, sw, maps: dict, rec: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .store import atomic_savefig

    fig, axes = plt.subplots(1, len(maps), figsize=(5 * len(maps), 5))
    for ax, (name, (grid, origin, res)) in zip(axes, maps.items(), strict=True):
        ext = (origin[0], origin[0] + grid.shape[1] * res, origin[1],
               origin[1] + grid.shape[0] * res)
        ax.imshow(np.clip(grid, -4, 4), origin="lower", extent=ext, cmap="gray_r")
        ax.set_title(f"global map from {name} poses (walls agree {rec[f'map_agree_{name}']:.2f})",
                     fontsize=9)
        ax.set_aspect("equal")
    fig.suptitle(f"simulator world {rec['world']} ({rec['lattice']}): LPM snapshots at places "
                 "projected from place poses (frame of the first place)", fontsize=9)
    fig.tight_layout()
    atomic_savefig(fig, out / "sim_map.png", dpi=100)
    plt.close(fig)


def _mean(rows, key):
    v = [r[key] for r in rows if r.get(key) is not None and np.isfinite(r[key])]
    return float(np.mean(v)) if v else float("nan")


def report_text(st, cfg, worlds, office, sim=()) -> str:
    """``report.md`` (written to the store ``st``) from the records; its text."""
    ok = [r for r in worlds if not r["too_large"]]
    n_fewer = sum(r["star_leaves_prefix"] <= r["basic_leaves_prefix"]
                  or r["basic_leaves_prefix"] < 0 for r in ok)
    lines = [f"# {NAME}: HSSH global levels (B §8.3, ch. 9)", "",
             f"{len(worlds)} random worlds ({len(worlds) - len(ok)} too large to enumerate), "
             f"{cfg['travels']} travels each; odometry sd {cfg['sigma_xy']}·d (x, y), "
             f"{cfg['sigma_theta']} rad per unit corridor (θ).", "",
             "## Claims", "", *protocol.claims_table(_claims(cfg, worlds, office)), "",
             "## Random worlds", "",
             "| world | lattice | places (seen) | final leaves | minimal | k | branch events "
             "(≤ ml/2) | true in leaves | preferred true | layout err odo → relaxed | nav "
             "success | nav length ratio | leaves star / basic (prefix) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in worlds:
        if r["too_large"]:
            lines.append(f"| {r['world']} | {r['lattice']} | {r['places']} | too large | | | "
                         "| | | | | | |")
            continue
        lines.append(
            f"| {r['world']} | {r['lattice']} | {r['places']} ({r['seen_places']}) | "
            f"{r['final_leaves']} | {r['minimal_models']} | {r['k']} | {r['branch_events']} "
            f"(≤ {r['bound_events']:.0f}) | {r['true_in_leaves']} | {r['preferred_true']} | "
            f"{r.get('layout_err_odometry', float('nan')):.3f} → "
            f"{r.get('layout_err_relaxed', float('nan')):.3f} | {r['nav_success']:.2f} | "
            f"{r['nav_length_ratio']:.3f} | {r['star_leaves_prefix']} / "
            f"{r['basic_leaves_prefix'] if r['basic_leaves_prefix'] >= 0 else '>max'} |")
    lines += ["", "Summary:", "",
              f"* true map among the leaves: {sum(r['true_in_leaves'] for r in ok)}/{len(ok)} "
              "(must be all: the correct map is never discarded)",
              f"* preferred leaf is the true map: {sum(r['preferred_true'] for r in ok)}/"
              f"{len(ok)}; true map among the minimal models: "
              f"{sum(r['true_minimal'] for r in ok)}/{len(ok)}",
              f"* §8.3 bounds held: branching ≤ k+1 in {sum(r['bound_branching_ok'] for r in ok)}"
              f"/{len(ok)}, branching travels ≤ ml/2 in {sum(r['bound_events_ok'] for r in ok)}"
              f"/{len(ok)}",
              "* mean layout error (lattice spacings): odometry "
              f"{_mean(ok, 'layout_err_odometry'):.3f} → relaxed "
              f"{_mean(ok, 'layout_err_relaxed'):.3f}",
              f"* navigation with the preferred map: success {_mean(ok, 'nav_success'):.3f}, "
              f"length / shortest {_mean(ok, 'nav_length_ratio'):.3f}",
              f"* star-view leaves ≤ basic-SSH leaves on the prefix in {n_fewer}/{len(ok)} "
              "worlds", "",
              "## §8.3 office (6 paths, 9 places, 4 distinct local topologies)", "",
              "The thesis's exploration trace (Fig. 8.2a) is not published, so our 14-travel "
              "explorations are different traces of a stand-in floor plan with the same counts; "
              "only the order of magnitude of leaves and minimal models can be compared. Our "
              "preference is *fewest places* (the thesis's prioritized circumscription is not "
              "specified there). Planarity is an optional filter on leaves "
              "(`hssh_global.is_planar`: the stars' clockwise orders as a rotation system, "
              "Euler's V − E + F = 2 per component, unexplored gateways as pendant edges); the "
              "tree itself does not prune with it.", "",
              "| seed | places seen | leaves after 14 travels | minimal models | true minimal | "
              "preferred true | planar leaves → minimal | true map planar | published (no "
              "planarity) | published (planarity) |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for r in office:
        lines.append(f"| {r['seed']} | {r['seen_places']} | {r['final_leaves']} | "
                     f"{r['minimal_models']} | {r['true_minimal']} | {r['preferred_true']} | "
                     f"{r.get('planar_leaves', '')} → {r.get('planar_minimal', '')} | "
                     f"{r.get('true_planar', '')} | "
                     f"{PUBLISHED['office_leaves']} → {PUBLISHED['office_minimal']} | "
                     f"{PUBLISHED['office_leaves_planar']} → {PUBLISHED['office_minimal_planar']}"
                     " |")
    lv = [r["final_leaves"] for r in office]
    mag = ("match (within a factor 10)" if lv and 8.3 <= np.median(lv) <= 830
           else "mismatch (more than a factor 10)")
    mm = [r["minimal_models"] for r in office]
    pl = [r["planar_leaves"] for r in office if "planar_leaves" in r]
    pm = [r["planar_minimal"] for r in office if "planar_minimal" in r]
    planar_line = (f" With the planarity filter: median leaves {np.median(pl):.0f} (published "
                   f"46), median minimal models {np.median(pm):.0f} (published 1); the true "
                   f"map is planar in {sum(r.get('true_planar', 0) for r in office)}/"
                   f"{len(office)}." if pl else "")
    lines += ["", f"Median leaves {np.median(lv):.0f} vs published 83: order of magnitude "
              f"**{mag}**; median minimal models {np.median(mm):.0f} vs published 4 (1 with "
              "planarity)." + planar_line + " Mechanism of the difference: the leaf count "
              "depends on the trace (how many travels enter new territory at aliased places "
              "before the loops are confirmed), on the floor plan (ours is a stand-in), and on "
              "the axioms (the tree prunes with the path-order axioms 3.7–3.10; planarity only "
              "filters the final leaves)."]
    lines += _sim_report(cfg, sim)
    lines += _geo_report(cfg, ok, office, sim)
    lines += ["", "## Figures", "", *_figure_lines(st.path("."))]
    text = "\n".join(lines) + "\n"
    st.write_text("report.md", text)
    return text


FIGURES = {
    "tree_size.png": "Consistent leaves of the tree of maps after each travel (log scale): "
                     "blue, the random worlds; red, the office explorations; dotted, the "
                     "published 83 leaves of the office.",
    "layout.png": "Global layout of the places of a 4 x 4 lattice world before and after the "
                  "spring relaxation: black dots true, orange crosses compounded odometry, "
                  "blue pluses relaxed (grey: the corridors).",
    "navigation.png": "Three navigation runs planned on the true map and executed in a 4 x 4 "
                      "lattice world (grey: corridors); the legend lists each run's "
                      "F/L/R/T commands.",
    "sim_map.png": "Global occupancy maps of simulator world 0: LPM snapshots at the places "
                   "projected from odometry, relaxed and re-localised place poses; the title "
                   "of each gives its agreement with the true walls.",
}
"""The report's figures and their captions (``sim_map.png`` is drawn while simulator world 0
is computed)."""


def _figure_lines(out: Path) -> list[str]:
    return [line for name, cap in FIGURES.items()
            if name != "sim_map.png" or (Path(out) / name).exists()
            for line in protocol.figure(name, cap)]


def _geo_report(cfg: dict, worlds: list, office: list, sim) -> list[str]:
    """The declared geometric test (beyond B) on and off, per family of runs."""
    def count(rows, key):
        have = [r for r in rows if key in r]
        return f"{sum(r[key] for r in have)}/{len(have)}" if have else "-"

    sim_ok = [r for r in sim if not r["lost"] and not r.get("too_large")]
    lines = ["", "## Declared geometric test (beyond B; issue 26)", "",
             "A map whose relaxed layout cost 2·cost exceeds the χ² quantile 1 − "
             f"{cfg.get('geo_alpha', 1e-3):g} with 3N − 3(M − 1) degrees of freedom is "
             "demoted behind every supported map (`hssh_global.layout_supported`, "
             "`preference_order(..., supported)`). B's ordering (fewest places, then layout "
             "cost) is *off*.", "",
             "| runs | preferred true, off (B) | preferred true, on | true map supported | "
             "minimal models rejected by the test |", "|---|---|---|---|---|",
             f"| random worlds | {count(worlds, 'preferred_true')} | "
             f"{count(worlds, 'preferred_true_geo')} | {count(worlds, 'true_supported')} | "
             f"{sum(r.get('minimal_unsupported', 0) for r in worlds)} of "
             f"{sum(r['minimal_models'] for r in worlds if 'minimal_unsupported' in r)} |",
             f"| office | {count(office, 'preferred_true')} | "
             f"{count(office, 'preferred_true_geo')} | {count(office, 'true_supported')} | "
             f"{sum(r.get('minimal_unsupported', 0) for r in office)} of "
             f"{sum(r['minimal_models'] for r in office if 'minimal_unsupported' in r)} |",
             f"| simulator (odometry) | {count(sim_ok, 'preferred_true')} | "
             f"{count(sim_ok, 'preferred_true_geo')} | {count(sim_ok, 'true_supported')} | - |",
             f"| simulator (re-localised) | {count(sim_ok, 'preferred_true_reloc')} | "
             f"{count(sim_ok, 'preferred_true_reloc_geo')} | "
             f"{count(sim_ok, 'true_supported_reloc')} | - |"]
    return lines


def _sim_report(cfg: dict, sim) -> list[str]:
    sim = list(sim)
    ok = [r for r in sim if not r["lost"] and not r.get("too_large")]
    lines = ["", "## Simulator-driven worlds (local levels → views)", "",
             f"{len(sim)} random lattice worlds rendered into occupancy grids (corridor width "
             f"{cfg['sim_width']} of the shortest corridor), {cfg['sim_travels']} travels each, "
             "driven by the simulated rover: lidar → scrolling LPM → gateways → local topology "
             "→ star views; odometry is the rover's dead reckoning (speed sd "
             f"{cfg['sim_sigma_v']}, heading-rate sd {cfg['sim_sigma_w']} rad per width). "
             "Errors are in lattice spacings; place truth is the true dividing pose.", "",
             "| world | lattice | places (seen) | views true | lost | leaves | true in leaves | "
             "preferred true (odo / reloc) | odometry err/travel | layout err odo → relaxed → "
             "relaxed+reloc | map agreement odo → relaxed → relaxed+reloc | nav success (sim) | "
             "nav length ratio | explore s |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in sim:
        if r["lost"]:
            lines.append(f"| {r['world']} | {r['lattice']} | {r['places']} | | lost: "
                         f"{r.get('reason', '')} | | | | | | | | | |")
            continue
        if r.get("too_large"):
            lines.append(f"| {r['world']} | {r['lattice']} | {r['places']} | | | too large "
                         "| | | | | | | | |")
            continue
        g = r.get
        lines.append(
            f"| {r['world']} | {r['lattice']} | {r['places']} ({r['seen_places']}) | "
            f"{r['views_true']}/{r['views']} | 0 | {r['final_leaves']} | {r['true_in_leaves']} "
            f"| {r['preferred_true']} / {g('preferred_true_reloc', float('nan'))} | "
            f"{r['odometry_err_xy']:.4f} | "
            f"{g('layout_err_odometry', float('nan')):.4f} → "
            f"{g('layout_err_relaxed', float('nan')):.4f} → "
            f"{g('layout_err_reloc', float('nan')):.4f} | "
            f"{g('map_agree_odometry', float('nan')):.3f} → "
            f"{g('map_agree_relaxed', float('nan')):.3f} → "
            f"{g('map_agree_reloc', float('nan')):.3f} | {r['nav_success']:.2f} "
            f"(lost {r['nav_lost']}) | {r['nav_length_ratio']:.3f} | {r['explore_s']:.1f} |")
    lines += ["", f"* explorations completed: {len(ok)}/{len(sim)}; every view matched its true "
              f"place in {sum(r['views_true'] == r['views'] for r in ok)}/{len(ok)}",
              f"* true map among the leaves: {sum(r['true_in_leaves'] for r in ok)}/{len(ok)}; "
              f"preferred leaf true: {sum(r['preferred_true'] for r in ok)}/{len(ok)} (layout "
              "score from raw odometry), "
              f"{sum(r.get('preferred_true_reloc', 0) for r in ok)}/{len(ok)} (re-localised)",
              f"* mean layout error (lattice spacings): dead reckoning "
              f"{_mean(ok, 'layout_err_odometry'):.4f} → relaxed "
              f"{_mean(ok, 'layout_err_relaxed'):.4f} → relaxed with re-localisation "
              f"{_mean(ok, 'layout_err_reloc'):.4f}; global map wall agreement "
              f"{_mean(ok, 'map_agree_odometry'):.3f} → {_mean(ok, 'map_agree_relaxed'):.3f} → "
              f"{_mean(ok, 'map_agree_reloc'):.3f}",
              "* place-frame jitter at revisits (true dividing pose vs the first visit's frame): "
              f"{_mean(ok, 'revisit_jitter_xy'):.4f} lattice spacings, "
              f"{_mean(ok, 'revisit_jitter_theta'):.3f} rad, beside odometry error "
              f"{_mean(ok, 'odometry_err_xy'):.4f} per travel; after re-localisation in the "
              f"place's stored LPM (B §9.2) {_mean(ok, 'reloc_err_xy'):.4f} spacings, "
              f"{_mean(ok, 'reloc_err_theta'):.3f} rad (corrections applied to "
              f"{_mean(ok, 'reloc_used'):.2f} of the revisits)",
              f"* navigation executed in the simulator: success {_mean(ok, 'nav_success'):.3f},"
              f" length / shortest route {_mean(ok, 'nav_length_ratio'):.3f} (distance driven, "
              "manoeuvres at places included)"]
    for r in ok:
        for why in r.get("nav_lost_reasons", []):
            lines.append(f"* world {r['world']} navigation lost: {why}")
    return lines


def figures(out: Path, cfg: dict, worlds: list, office: list) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .. import hssh_global as hg
    from .store import atomic_savefig

    fig, ax = plt.subplots(figsize=(6, 4))
    for r in worlds:
        if not r["too_large"]:
            ax.plot(r["leaves"], color="tab:blue", alpha=0.5)
    for r in office:
        ax.plot(r["leaves"], color="tab:red", alpha=0.7)
    ax.axhline(PUBLISHED["office_leaves"], color="tab:red", ls=":", label="published office: 83")
    ax.set_yscale("log")
    ax.set_xlabel("travel")
    ax.set_ylabel("consistent leaves")
    ax.set_title("tree of maps (blue: random worlds, red: office)")
    ax.legend()
    fig.tight_layout()
    atomic_savefig(fig, out / "tree_size.png", dpi=110)
    plt.close(fig)

    w = hg.grid_world(4, 4, loop_prob=cfg["loop_prob"], seed=cfg["seed"])
    e = hg.explore(w, cfg["travels"], seed=cfg["seed"], sigma_xy=2 * cfg["sigma_xy"],
                   sigma_theta=2 * cfg["sigma_theta"])
    h = next(h for h in hg.build_tree(e, max_leaves=cfg["max_leaves"]).leaves
             if hg.is_true_map(h, e))
    prob = hg.pack([h], e.odometry, 2 * cfg["sigma_xy"], 2 * cfg["sigma_theta"])
    chi, _ = hg.relax(prob)
    gt = hg.true_layout(w, e)
    m = h.n_places
    fig, ax = plt.subplots(figsize=(5, 5))
    for (p, _), (q, _) in h.edges.items():
        ax.plot(*gt[[p, q], :2].T, color="0.8", lw=3, zorder=0)
    ax.scatter(*gt[:, :2].T, c="k", label="true", zorder=3)
    ax.scatter(*np.asarray(prob.init[0, :m, :2]).T, marker="x", c="tab:orange",
               label="compounded odometry")
    ax.scatter(*np.asarray(chi[0, :m, :2]).T, marker="+", s=80, c="tab:blue", label="relaxed")
    ax.set_aspect("equal")
    ax.legend(loc="best", fontsize=8)
    ax.set_title("global layout before/after relaxation")
    fig.tight_layout()
    atomic_savefig(fig, out / "layout.png", dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(5, 5))
    for (p, _), (q, _, _) in w.edges.items():
        ax.plot(*w.positions[[p, q]].T, color="0.8", lw=3, zorder=0)
    rng = np.random.default_rng(cfg["seed"])
    for c in range(3):
        i = int(rng.integers(len(h.visits)))
        goal = int(rng.choice([p for p in range(h.n_places) if p != h.visits[i][0]]))
        _, cmds = hg.plan_route(h, e.odometry, h.visits[i], goal)
        places, _, _ = hg.execute(w, (int(e.true_places[i]), int(e.true_arrivals[i])), cmds)
        xy = w.positions[places] + 0.04 * (c - 1)
        ax.plot(*xy.T, "-o", label=f"run {c}: {' '.join(k[0][0] for k in cmds)}")
    ax.set_aspect("equal")
    ax.legend(fontsize=7)
    ax.set_title("navigation runs (F/L/R/T commands)")
    fig.tight_layout()
    atomic_savefig(fig, out / "navigation.png", dpi=110)
    plt.close(fig)


def _units(cfg: Config) -> list[tuple[str, int]]:
    # simulator world 0 first: item 0 of the units left always falls to process 0, which
    # draws its map figure
    return ([("sim", i) for i in range(cfg.sim_worlds)]
            + [("world", i) for i in range(cfg.worlds)]
            + [("office", s) for s in range(cfg.office_seeds)])


def _logs(st) -> dict:
    return {"world": st.records("worlds.jsonl", key=lambda r: r["world"],
                                required=("world", "too_large")),
            "office": st.records("office.jsonl", key=lambda r: r["seed"],
                                 required=("seed", "leaves")),
            "sim": st.records("sim.jsonl", key=lambda r: r["world"], required=("world", "lost"))}


def _sorted(logs: dict, n_worlds: int) -> tuple[list, list, list]:
    """(random worlds below ``n_worlds``, office runs, simulator worlds), in unit order."""
    sim = sorted(logs["sim"].values(), key=lambda r: r["world"])
    worlds = sorted((r for r in logs["world"].values() if r["world"] < n_worlds),
                    key=lambda r: r["world"])
    office = sorted(logs["office"].values(), key=lambda r: r["seed"])
    return worlds, office, sim


def run_study(cfg: Config, out: Path, *, quiet: bool = False, cluster=None,
              fresh: bool = False) -> None:
    """Every world, office and simulator unit not yet recorded, split over the processes;
    process 0 appends each record as it arrives, then writes ``results.csv``."""
    from tqdm.auto import tqdm

    from . import distributed
    from .store import Store, tidy_rows

    cluster = cluster or distributed.current()
    c = cfg.to_json()
    distributed.agree(cluster, c, f"{NAME} config")
    units = _units(cfg)
    st = None
    logs: dict = {}

    def left():  # process 0 only: open the store, list the units not yet recorded
        nonlocal st
        st = Store.open(out, NAME, c, selection=("worlds",), fresh=fresh)
        logs.update(_logs(st))
        return [i not in logs[kind] for kind, i in units]

    def compute(unit):
        kind, i = unit
        if kind == "world":
            return run_world(c, i)
        if kind == "office":
            return run_office(c, i)
        return run_sim_world(c, i, st.path(".") if i == 0 and st is not None else None)

    try:
        mask = distributed.decide(cluster, len(units), left)
        todo = [u for u, m in zip(units, mask, strict=True) if m]
        for j, rec in tqdm(distributed.map_units(compute, todo, cluster, codec="json"),
                           total=len(todo), disable=quiet or not cluster.is_main,
                           desc="units"):
            if st is not None:
                logs[todo[j][0]].add(rec)
        if st is None:
            return
        worlds, office, sim = _sorted(logs, cfg.worlds)
        st.write_results_csv(
            tidy_rows(worlds, unit=lambda r: f"world{r['world']}", skip=("world", "leaves",
                                                                          "lattice"))
            + tidy_rows(office, unit=lambda r: f"office{r['seed']}", skip=("seed", "leaves"))
            + tidy_rows(sim, unit=lambda r: f"sim{r['world']}",
                        skip=("world", "lattice", "reason", "nav_lost_reasons")))
    finally:
        if st is not None:
            st.close()


def _load(out: Path, worlds: int | None = None):
    """(stored config, random worlds, office runs, simulator worlds) of ``out``; the first
    ``worlds`` random worlds (default: as many as the stored config runs)."""
    from .store import Store, StudyError

    with Store.open(out, NAME, None) as st:
        c = st.config
        rows = _sorted(_logs(st), worlds or c["worlds"])
    if not any(rows):
        raise StudyError(f"{out} holds no {NAME} results; run the study first")
    return (c, *rows)


def _claims(cfg: dict, worlds: list, office: list) -> list[protocol.Claim]:
    ok = [r for r in worlds if not r["too_large"]]
    n = len(ok)
    truth = sum(r["true_in_leaves"] for r in ok)
    bounds = sum(r["bound_branching_ok"] and r["bound_events_ok"] for r in ok)
    cs = [protocol.Claim("the true map is never discarded (random worlds)",
                         "always among the leaves (B §8.3)", f"{truth}/{n}", None,
                         protocol.MATCH if truth == n else protocol.MISMATCH),
          protocol.Claim("§8.3 bounds (branching ≤ k+1, branching travels ≤ ml/2)",
                         "hold in every world (B §8.3)", f"{bounds}/{n}", None,
                         protocol.MATCH if bounds == n else protocol.MISMATCH)]
    if office:
        lv = float(np.median([r["final_leaves"] for r in office]))
        mm = float(np.median([r["minimal_models"] for r in office]))
        cs += [protocol.Claim("office: leaves after 14 travels (order of magnitude)",
                              f"{PUBLISHED['office_leaves']} (trace not published)", lv,
                              (8.3, 830.0), protocol.verdict_in(lv, 8.3, 830.0)),
               protocol.Claim("office: minimal models (median)",
                              f"{PUBLISHED['office_minimal']} (trace not published)", mm,
                              None, protocol.NOT_CHECKED)]
    return cs


def claims(out: Path) -> list[protocol.Claim]:
    """B §8.3's claims: the true map is never discarded, the branching bounds hold, and the
    office's leaf count is within a factor 10 of the published 83 (its trace is not
    published, so only the order of magnitude is compared)."""
    c, worlds, office, _ = _load(Path(out))
    return _claims(c, worlds, office)


def report(out: Path, worlds: int | None = None) -> Path:
    """``report.md`` and the figures from the records (the first ``worlds`` random worlds;
    default: as many as the stored config runs)."""
    from .store import Store

    out = Path(out)
    c, ws, office, sim = _load(out, worlds)
    with Store.open(out, NAME, None) as st:
        report_text(st, c, ws, office, sim)
    figures(out, c, ws, office)
    return out / "report.md"


def main(argv: list[str] | None = None) -> int:
    """``pqrm-jax study hssh-maps`` (the protocol's driver; ``--worlds N`` also limits the
    report to the first N random worlds)."""
    from . import distributed

    cfg, a = configure(list(argv or []))
    if not a.report_only:
        cluster = distributed.initialize_from(a)
        run_study(cfg, Path(a.out), quiet=a.no_progress, cluster=cluster, fresh=a.fresh)
        if not cluster.is_main:
            return 0
    print(f"wrote {report(Path(a.out), a.worlds)}")
    return 0


sweep_summary = protocol.summary_for(sys.modules[__name__])
