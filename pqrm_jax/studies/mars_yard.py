"""Mars-Yard-like traverse (M§VIII.C, Figs. 10–11) and RNG navigation (M§VII.B).

The JPL Mars Yard data are not available; we simulate its structure: 30 landmarks uniform in
a 30 m × 30 m yard, one traverse of 50 imaging poses 1–2 m apart (``sim.traverse``), the 18
nearest landmarks measured at every pose (M: "the nearest 18 landmarks were then used").
Outputs: Fig. 10 (cumulative % of EDC states removed, % open states not adjacent to truth,
RNG cost per image), Fig. 11 (RNG estimate after images 1, 15, 30, 50, edges coloured by
w_ij), the wall time of the whole traverse (M: 250 s in C#), and closed-loop navigation
along the final RNG estimate between random start/goal pairs (success rate, path length vs
straight line), also along the true RNG for reference.

The study protocol of :mod:`pqrm_jax.studies.protocol` (``Config``, ``PRESETS``,
``configure``, ``run_study``, ``report``, ``claims``; the common flags; ``--sweep``); setup
and engineering: docs/studies.md §mars-yard.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from . import protocol

NAME = "mars-yard"
HELP = "Mars-Yard-like traverse (M§VIII.C, Figs. 10-11) + RNG navigation (M§VII.B)"


@dataclasses.dataclass(frozen=True)
class Config(protocol.StudyConfig):
    """Every result-changing setting of the study (each knob's reason in :data:`REASONS`)."""

    landmarks: int = 30
    size: float = 30.0
    images: int = 50
    n: int = 18
    nav_pairs: int = 200
    nav_steps: int = 1500
    traverses: int = 5
    seed: int = 0
    snapshots: tuple[int, ...] = (1, 15, 30, 50)
    #: bearing tolerance of the camera measurement in radians (issue #27); None = the
    #: default of the float32 bearings (qrm.camera.default_tolerance; docs/qrm.md §camera)
    bearing_tol: float | None = None



REASONS = {
    "landmarks": "30 landmarks in the yard (M§VIII.C)",
    "size": "a 30 m × 30 m yard, the JPL Mars Yard's scale",
    "images": "50 imaging poses 1–2 m apart, as M's traverse",
    "n": "the nearest 18 landmarks measured per pose (M: 'the nearest 18 landmarks were then "
         "used')",
    "nav_pairs": "random start/goal pairs per traverse for the navigation success rate",
    "nav_steps": "rover steps per navigation attempt before it counts as a failure",
    "traverses": "independent yards and traverses (M shows one; 5 give a spread)",
    "seed": "the root seed of yards, traverses and navigation pairs",
    "snapshots": "the images after which Fig. 11 draws the RNG estimate (M: 1, 15, 30, 50)",
    "bearing_tol": "None: the rounding of the float32 bearings, so the true state is never "
                   "dropped (docs/qrm.md §camera)",
}

PRESETS: dict[str, dict[str, Any]] = {
    "tiny": {"landmarks": 10, "n": 6, "images": 30, "nav_pairs": 4, "nav_steps": 100,
             "traverses": 1, "snapshots": (1, 30)},
    "reduced": {"nav_pairs": 48, "traverses": 2},
    "full": {},
}
REDUCED = PRESETS["reduced"]  # the old name


def configure(argv: list[str], overrides: dict | None = None
              ) -> tuple[Config, argparse.Namespace]:
    """The study's Config and parsed flags (every number checked before any work)."""
    p = protocol.parser(NAME, HELP, seed=Config.seed)
    p.add_argument("--runs", type=protocol.positive_int, default=None,
                   help="number of traverses (default 5)")
    a = p.parse_args(argv)
    cfg = protocol.apply_preset(Config, PRESETS, a.preset, a, {"traverses": "runs"},
                                overrides)
    if "seed" not in (overrides or {}):
        cfg = dataclasses.replace(cfg, seed=a.seed)
    # images ≥ 30: the report compares the removed % after images 1, 15, 30 and the last
    for key, lo in (("traverses", 1), ("landmarks", 3), ("images", 30), ("nav_pairs", 1),
                    ("nav_steps", 1)):
        if getattr(cfg, key) < lo:
            p.error(f"argument {'--runs' if key == 'traverses' else key}: must be an integer "
                    f"≥ {lo}, got {getattr(cfg, key)}")
    if not 3 <= cfg.n <= cfg.landmarks:
        p.error(f"n must lie in 3..landmarks ({cfg.landmarks}), got {cfg.n}")
    if not (np.isfinite(cfg.size) and cfg.size > 0):
        p.error(f"size must be a positive, finite number, got {cfg.size}")
    if not cfg.snapshots or not all(1 <= t <= cfg.images for t in cfg.snapshots):
        p.error(f"snapshots must be images in 1..{cfg.images}, got {list(cfg.snapshots)}")
    if cfg.bearing_tol is not None and not (np.isfinite(cfg.bearing_tol)
                                            and cfg.bearing_tol >= 0):
        p.error(f"bearing_tol must be None or a finite number ≥ 0, got {cfg.bearing_tol}")
    return cfg, a


def _world(cfg: Config, i: int):
    from pqrm_jax import sim

    k = jax.random.fold_in(jax.random.key(cfg.seed), i)
    k1, k2 = jax.random.split(k)
    lm = sim.uniform_landmarks(k1, cfg.landmarks, (cfg.size, cfg.size))
    poses = sim.traverse(k2, cfg.images, size=(cfg.size, cfg.size))
    return lm, poses


def run_traverse(cfg: Config, i: int) -> dict:
    """Map one traverse image by image (jitted steps); per-image metrics, maps and times."""
    from pqrm_jax.qrm import hypergraph as H
    from pqrm_jax.qrm import pipeline as P
    from pqrm_jax.qrm.spec import qrm_spec

    spec = qrm_spec("edc")
    lm, poses = _world(cfg, i)
    truth = H.true_relations(lm, spec)
    # compile once (not timed), then the timed traverse as one scanned program
    m, met = P.run_sequence(lm, poses, cfg.n, spec, tol=cfg.bearing_tol)
    jax.block_until_ready(m.rel)
    t0 = time.perf_counter()
    m, met = P.run_sequence(lm, poses, cfg.n, spec, tol=cfg.bearing_tol)
    jax.block_until_ready(m.rel)
    wall = time.perf_counter() - t0
    # snapshots: image-by-image (for Fig. 11)
    maps = []
    mm = H.empty_map(cfg.landmarks, spec)
    for t in range(cfg.images):
        mm, _ = P.map_step(mm, poses[t], lm, cfg.n, spec, truth=truth, tol=cfg.bearing_tol)
        if t + 1 in cfg.snapshots:
            maps.append((t + 1, mm))
    rec = {f: np.asarray(getattr(met, f)) for f in met._fields}
    return {"lm": np.asarray(lm), "poses": np.asarray(poses), "met": rec, "wall": wall,
            "final": m, "snaps": maps}


def run_navigation(cfg: Config, lm, m, key) -> dict:
    from pqrm_jax import sim
    from pqrm_jax.qrm import hypergraph as H
    from pqrm_jax.qrm import navigation as NAV
    from pqrm_jax.qrm import rng as R

    k1, k2, k3 = jax.random.split(key, 3)
    starts = jnp.concatenate([jax.random.uniform(k1, (cfg.nav_pairs, 2)) * cfg.size,
                              jax.random.uniform(k3, (cfg.nav_pairs, 1), minval=-3, maxval=3)],
                             1)
    goals = jax.random.uniform(k2, (cfg.nav_pairs, 2)) * cfg.size
    params = sim.RoverParams(dt=0.1, max_speed=1.0, max_turn_rate=1.0)
    out = {}
    for name, est in (("estimated", R.rng_estimate(m)), ("true", R.rng_estimate(H.true_map(lm)))):
        res = NAV.navigate_many(lm, est, starts, goals, params=params, n_steps=cfg.nav_steps)
        s = NAV.summarize(res)
        s["mean_hops"] = float(np.asarray(res.hops).mean())
        out[name] = s
        out[name + "_res"] = res
    return out


def _plots(out: Path, cfg: Config, tr: dict, nav: dict):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pqrm_jax.qrm import rng as R

    met = tr["met"]
    x = np.arange(1, cfg.images + 1)
    fig, ax = plt.subplots(1, 3, figsize=(15, 4))
    ax[0].plot(x, met["removed_pct"])
    ax[0].set_title("(a) EDC states removed [% of 30-landmark map]")
    ax[1].plot(x, met["not_adjacent_pct"])
    ax[1].set_title("(b) open states not adjacent to truth [%]")
    ax[2].plot(x, met["rng_cost"])
    ax[2].set_title("(c) total RNG edge cost")
    for a in ax:
        a.set_xlabel("image")
    fig.tight_layout()
    fig.savefig(out / "fig10.png", dpi=110)
    plt.close(fig)

    lm, poses = tr["lm"], tr["poses"]
    fig, ax = plt.subplots(1, len(tr["snaps"]), figsize=(4.2 * len(tr["snaps"]), 4.2))
    cmap = plt.cm.jet
    for a, (t, m) in zip(np.atleast_1d(ax), tr["snaps"], strict=True):
        est = R.rng_estimate(m)
        e, w = np.asarray(est.edges), np.asarray(est.cost)
        known = np.asarray(m.known)
        for i, j in zip(*np.nonzero(np.triu(e)), strict=True):
            c = "k" if w[i, j] == 0 else cmap(min(w[i, j] / max(w.max(), 1e-9), 1.0))
            a.plot(lm[[i, j], 0], lm[[i, j], 1], color=c, lw=1.2)
        a.plot(lm[~known, 0], lm[~known, 1], "o", mfc="none", mec="0.7")
        a.plot(lm[known, 0], lm[known, 1], "bo")
        a.plot(poses[:t, 0], poses[:t, 1], "g^", ms=4)
        a.plot(poses[t - 1, 0], poses[t - 1, 1], "r^", ms=8)
        a.set_title(f"RNG after image {t}")
        a.set_aspect("equal")
    fig.tight_layout()
    fig.savefig(out / "fig11.png", dpi=110)
    plt.close(fig)

    res = nav["estimated_res"]
    fig, a = plt.subplots(figsize=(5.5, 5.5))
    from pqrm_jax.qrm import rng as R2

    e = R2.true_rng(lm)
    for i, j in zip(*np.nonzero(np.triu(e)), strict=True):
        a.plot(lm[[i, j], 0], lm[[i, j], 1], color="0.6", lw=0.8)
    a.plot(lm[:, 0], lm[:, 1], "ko", mfc="none")
    for k in range(min(6, res.poses.shape[0])):
        p = np.asarray(res.poses[k])
        a.plot(p[:, 0], p[:, 1], lw=1.2)
        a.plot(p[0, 0], p[0, 1], "o")
    a.set_title("navigation along the estimated RNG (6 runs)")
    a.set_aspect("equal")
    fig.tight_layout()
    fig.savefig(out / "navigation.png", dpi=110)
    plt.close(fig)


LEGACY = ("config.json", "traverse_*.json", "report.md", "*.png", "study.json", "results.csv",
          "*.corrupt")
_ROW_FIELDS = ("traverse", "removed_pct", "constrained_pct", "not_adjacent_pct",
               "rng_cost", "truth_kept", "nav_estimated", "nav_true")


def run_study(cfg: Config, out: Path, *, quiet: bool = False, cluster=None,
              fresh: bool = False) -> list[dict]:
    """Run (or resume) the traverses into ``out``; returns the rows (:func:`report` then
    writes ``report.md``).

    With a multi-process ``cluster`` (:mod:`.distributed`, already initialised) every process
    calls this with the same ``cfg``: differing configs are refused, process 0 alone opens the
    store and lists the traverses left, the processes compute them in rounds
    (:func:`.distributed.map_units`; traverse 0, recomputed for the figures, always falls to
    process 0) and process 0 writes the rows and figures. The rows equal a
    one-process run's bit for bit; the measured ``wall_s`` is stored apart
    (``traverse_I.times.json``).
    """
    from tqdm.auto import tqdm

    from . import distributed
    from .store import Store, tidy_rows

    cluster = cluster or distributed.current()
    distributed.agree(cluster, cfg.to_json(), f"{NAME} config")
    st, stored = None, {}

    def left():
        nonlocal st
        st = Store.open(out, NAME, dict(cfg.to_json(), reasons=REASONS),
                        selection=("traverses",), legacy=LEGACY, fresh=fresh)
        for i in range(1, cfg.traverses):  # traverse 0 is recomputed for the figures
            row = st.read_json(f"traverse_{i}.json", _ROW_FIELDS,
                               check=lambda r, i=i: (r["traverse"] == i
                                                     and len(r["removed_pct"]) == cfg.images))
            if row is not None:
                stored[i] = row
        return [i not in stored for i in range(cfg.traverses)]

    try:
        mask = distributed.decide(cluster, cfg.traverses, left)
        todo = [i for i in range(cfg.traverses) if mask[i]]

        def compute(i):
            row, tr, nav = _traverse(cfg, i)
            if i == 0 and st is not None:  # map_units gives item 0 to process 0
                _plots(st.out, cfg, tr, nav)
            return {"row": row, "wall_s": tr["wall"]}

        new = distributed.map_units(compute, todo, cluster, codec="json")
        for k, rec in tqdm(new, total=len(todo), desc=NAME,
                           disable=quiet or not cluster.is_main):
            if st is not None:
                i = todo[k]
                st.write_json(f"traverse_{i}.json", rec["row"], indent=None)
                # the measured time apart from the results (identical runs: identical rows)
                st.write_json(f"traverse_{i}.times.json", {"traverse": i,
                                                           "wall_s": rec["wall_s"]},
                              indent=None)
                stored[i] = rec["row"]
        if st is None:
            return []
        rows = [stored[i] for i in range(cfg.traverses)]
        st.write_results_csv(tidy_rows(rows, unit=lambda r: f"traverse_{r['traverse']}",
                                       skip=("traverse",)))
        return rows
    finally:
        if st is not None:
            st.close()


def _traverse(cfg: Config, i: int) -> tuple[dict, dict, dict]:
    """Traverse ``i``'s stored row, with its traverse and navigation results (for figures)."""
    tr = run_traverse(cfg, i)
    nav = run_navigation(cfg, jnp.asarray(tr["lm"]), tr["final"], jax.random.key(100 + i))
    row = {"traverse": i,
           "removed_pct": tr["met"]["removed_pct"].tolist(),
           "constrained_pct": tr["met"]["constrained_pct"].tolist(),
           "not_adjacent_pct": tr["met"]["not_adjacent_pct"].tolist(),
           "rng_cost": tr["met"]["rng_cost"].tolist(),
           "truth_kept": bool(tr["met"]["truth_kept"].all()),
           "nav_estimated": nav["estimated"], "nav_true": nav["true"]}
    return row, tr, nav


def stored_config(out: Path) -> Config:
    """The :class:`Config` stored in ``out/config.json`` (the stored run's settings)."""
    return Config.stored(out, NAME)


def _rows(out: Path, cfg: Config) -> list[dict]:
    from .store import StudyError, read_json

    rows = [read_json(Path(out) / f"traverse_{i}.json", _ROW_FIELDS, quarantine=False)
            for i in range(cfg.traverses)]
    missing = [i for i, r in enumerate(rows) if r is None]
    if missing:
        raise StudyError(f"{out}: traverses {missing} are not stored; run the study first")
    # with the measured wall time (``traverse_I.times.json``; older rows held it themselves)
    times = [read_json(Path(out) / f"traverse_{i}.times.json", ("wall_s",), quarantine=False)
             for i in range(cfg.traverses)]
    return [dict(r, wall_s=t["wall_s"] if t else r.get("wall_s", float("nan")))
            for r, t in zip(rows, times, strict=True)]


def _claims(rows: list[dict]) -> list[protocol.Claim]:
    n = len(rows)
    kept = sum(bool(r["truth_kept"]) for r in rows)
    mono = all(np.all(np.diff(r["removed_pct"]) >= -1e-6) for r in rows)
    final = float(np.mean([r["removed_pct"][-1] for r in rows]))
    return [
        protocol.Claim("true state never removed", "never (M§VIII.A soundness)",
                       f"{kept} of {n} traverses", (n, n), protocol.verdict_in(kept, n, n)),
        protocol.Claim("removed % only grows along the traverse (M Fig. 10a)",
                       "monotone, slower than the Monte Carlo", final, None,
                       protocol.MATCH if mono else protocol.MISMATCH),
        protocol.Claim("wall time of the whole traverse", "250 s (C#, M§VIII.C)",
                       f"{np.mean([r['wall_s'] for r in rows]):.2f} s", None,
                       f"{protocol.NOT_CHECKED}: a timing of another implementation"),
    ]


def claims(out: Path) -> list[protocol.Claim]:
    """M§VIII.C's claims against the stored traverses."""
    return _claims(_rows(Path(out), stored_config(out)))


def report(out: Path) -> Path:
    """``report.md`` from the stored traverses and figures (under the store's lock)."""
    from .store import Store

    out = Path(out)
    with Store.open(out, NAME, None, legacy=LEGACY) as st:
        cfg = stored_config(out)
        _write_report(out, cfg, _rows(out, cfg), st)
    return out / "report.md"


def _ratio(x) -> str:
    """A median path-length ratio for the report; "n/a" when no route succeeded (NaN)."""
    return "n/a" if not np.isfinite(x) else f"{x:.2f}"


def _mean_ratio(navs: list[dict]) -> str:
    """Mean of the traverses' median ratios over those with a successful route, or "n/a"."""
    vals = [s["length_ratio_median"] for s in navs if np.isfinite(s["length_ratio_median"])]
    return _ratio(float(np.mean(vals))) if vals else "n/a (no successful route)"


def _write_report(out: Path, cfg: Config, rows: list[dict], st) -> None:
    walls = [r["wall_s"] for r in rows]
    ne = [r["nav_estimated"] for r in rows]
    nt = [r["nav_true"] for r in rows]
    lines = [f"# {NAME}: Mars-Yard-like traverse (M§VIII.C) and RNG navigation (M§VII.B)", "",
             f"Config: `{json.dumps(dataclasses.asdict(cfg))}`", "",
             "## Claims", "", *protocol.claims_table(_claims(rows)), "",
             *protocol.figure("fig10.png", "M Fig. 10 for traverse 0: per image, (a) the "
                              "EDC states removed (% of the whole map), (b) the open states "
                              "not adjacent to the truth (%), (c) the total RNG edge cost."),
             *protocol.figure("fig11.png", "M Fig. 11 for traverse 0: the RNG estimate after "
                              "the snapshot images (edges coloured by their cost w_ij, black: "
                              "w = 0), mapped landmarks blue, unseen ones grey, the poses so "
                              "far green and the current one red."),
             *protocol.figure("navigation.png", "Six navigation runs of traverse 0 along the "
                              "estimated RNG (coloured paths, dots at the starts) over the true "
                              "RNG (grey) and the landmarks (circles)."),
             "| traverse | wall s (50 images, measure + update) | removed % img 1 / 15 / 30 / 50 "
             "| constrained % final | RNG cost peak → final | truth kept | nav success est. / "
             "true RNG | length ratio est. / true |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        rp = r["removed_pct"]
        lines.append(
            f"| {r['traverse']} | {r['wall_s']:.2f} | {rp[0]:.1f} / {rp[14]:.1f} / "
            f"{rp[29]:.1f} / {rp[-1]:.1f} | {r['constrained_pct'][-1]:.1f} | "
            f"{max(r['rng_cost']):.2f} → {r['rng_cost'][-1]:.2f} | {r['truth_kept']} | "
            f"{100 * r['nav_estimated']['success_rate']:.0f} % / "
            f"{100 * r['nav_true']['success_rate']:.0f} % | "
            f"{_ratio(r['nav_estimated']['length_ratio_median'])} / "
            f"{_ratio(r['nav_true']['length_ratio_median'])} |")
    lines += ["", f"Whole traverse: **{np.mean(walls):.2f} s** mean wall time (compiled; "
              f"2-core CPU shared with other jobs) vs 250 s in McClelland's C# (target ≤ 1 s "
              "with exact sets, issue #14).",
              "", f"Navigation over {cfg.nav_pairs} random start/goal pairs per traverse: "
              f"success {100 * np.mean([s['success_rate'] for s in ne]):.1f} % along the "
              f"estimated RNG, {100 * np.mean([s['success_rate'] for s in nt]):.1f} % along the "
              f"true RNG; median path length / straight line "
              f"{_mean_ratio(ne)} (estimated) and {_mean_ratio(nt)} (true).", "",
              "## Comparison with M Figs. 10–11", "",
              "- M: slower, sigmoid-shaped convergence of the removed % than the random-point "
              "Monte Carlo (Fig. 7, n = 18), because sequential images 1–2 m apart are highly "
              "correlated and landmarks enter the map gradually. Here: removed % after images "
              f"1 / 15 / 30 / 50 = {np.mean([r['removed_pct'][0] for r in rows]):.1f} / "
              f"{np.mean([r['removed_pct'][14] for r in rows]):.1f} / "
              f"{np.mean([r['removed_pct'][29] for r in rows]):.1f} / "
              f"{np.mean([r['removed_pct'][-1] for r in rows]):.1f} (compare the n = 18 row of "
              "the mcclelland-mc report).",
              "- M: the RNG grows slowly but stays well constrained (Fig. 11); here RNG cost "
              f"peak → final {np.mean([max(r['rng_cost']) for r in rows]):.2f} → "
              f"{np.mean([r['rng_cost'][-1] for r in rows]):.2f}.",
              "- The estimated RNG keeps candidate edges that are not yet pruned; they act as "
              "shortcuts for navigation (the simulated camera sees every landmark), so paths "
              "along the estimate can be shorter than along the true RNG.",
              "- The true state is never removed ('truth kept')."]
    st.write_text("report.md", "\n".join(lines) + "\n")
    print("\n".join(lines[lines.index("## Claims"):]))


main = protocol.main_for(sys.modules[__name__])
sweep_summary = protocol.summary_for(sys.modules[__name__])
