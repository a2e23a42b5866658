"""McClelland's QRM Monte Carlo study (M§VIII.B, Fig. 7a–d).

Runs the camera QRM on random 30-landmark layouts with 50 imaging poses, measuring the n
nearest landmarks per pose for n ∈ {6, 9, 12, 18, 24, 30}, and reports the M§VIII.A metrics
per image; every finished (n, run) is stored, so a killed study resumes.

The study protocol of :mod:`pqrm_jax.studies.protocol` (``Config``, ``PRESETS``,
``configure``, ``run_study``, ``report``, ``claims``; the common flags; ``--sweep``).
Setup, metrics and engineering: docs/studies.md §mcclelland-mc. As N processes on
``jax.distributed`` (``--coordinator/--processes/--process-id``, the environment or Slurm;
:mod:`pqrm_jax.studies.distributed`) the (n, run) units are split over the processes and
process 0 alone writes them (the old ``--shard I/K`` is removed).
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
import numpy as np

from . import protocol

NAME = "mcclelland-mc"
HELP = "McClelland's QRM Monte Carlo study (M§VIII.B, Fig. 7): n nearest of 30 landmarks"


@dataclasses.dataclass(frozen=True)
class Config(protocol.StudyConfig):
    """Every result-changing setting of the study (each knob's reason in :data:`REASONS`)."""

    runs: int = 100
    images: int = 50
    landmarks: int = 30
    size: float = 100.0
    ns: tuple[int, ...] = (6, 9, 12, 18, 24, 30)
    timed_runs: int = 2
    seed: int = 0
    #: triples of the first image of run 0 (per n) whose relations the report also decides
    #: with the exact z3 oracle (issue #14: kernel sets vs the exact feasible sets)
    exact_sample: int = 24
    #: bearing tolerance of the camera measurement in radians (issue #27); None = the
    #: default of the float32 bearings, qrm.camera.default_tolerance: the rounding of the
    #: simulated camera, so the true state is never dropped (docs/qrm.md §camera)
    bearing_tol: float | None = None



REASONS = {
    "runs": "M§VIII.B averages random layouts; 100 runs give the per-image means a standard "
            "error well under the differences between the n rows",
    "images": "50 imaging poses per run, as M Fig. 7",
    "landmarks": "30 landmarks, as M§VIII.B",
    "size": "a 100 m square: only the layout's shape matters (the QRM is scale-free)",
    "ns": "the n nearest landmarks measured per pose, M Fig. 7's rows",
    "timed_runs": "runs per n whose per-update times are measured for Fig. 7d (timings only)",
    "seed": "the root seed of the layouts and poses",
    "exact_sample": "first-image triples per n also decided by the exact z3 oracle, to tell "
                    "the kernel's undecided states from the exact sets (issue #14)",
    "bearing_tol": "None: the rounding of the float32 bearings, so the true state is never "
                   "dropped (docs/qrm.md §camera)",
}

PRESETS: dict[str, dict[str, Any]] = {
    "tiny": {"runs": 1, "images": 6, "ns": (6, 8), "timed_runs": 1, "exact_sample": 2},
    "reduced": {"runs": 3, "images": 20, "ns": (6, 12, 18, 30), "timed_runs": 1},
    "full": {},
}
REDUCED = PRESETS["reduced"]  # the old name

_FLAGS = {"runs": "runs", "images": "images", "ns": "ns", "exact_sample": "exact_sample"}


def configure(argv: list[str], overrides: dict | None = None
              ) -> tuple[Config, argparse.Namespace]:
    """The study's Config and parsed flags (every number checked before any work)."""
    p = protocol.parser(NAME, HELP, seed=Config.seed)
    p.add_argument("--runs", type=protocol.positive_int, default=None,
                   help="random layouts per n (default 100)")
    p.add_argument("--images", type=protocol.positive_int, default=None,
                   help="imaging poses per run (default 50)")
    p.add_argument("--ns", type=protocol.positive_int, nargs="+", default=None,
                   help="nearest landmarks measured per pose, each in 3..landmarks "
                        "(default 6 9 12 18 24 30)")
    p.add_argument("--exact-sample", type=protocol.nonneg_int, dest="exact_sample",
                   default=None,
                   help="first-image triples per n decided exactly (z3) for the report "
                        "(default 24)")
    a = p.parse_args(argv)
    if a.ns is not None:
        a.ns = tuple(a.ns)
    cfg = protocol.apply_preset(Config, PRESETS, a.preset, a, _FLAGS, overrides)
    if "seed" not in (overrides or {}):
        cfg = dataclasses.replace(cfg, seed=a.seed)
    bad = [n for n in cfg.ns if not 3 <= n <= cfg.landmarks]
    if bad or not cfg.ns:
        p.error(f"argument --ns: each n must lie in 3..{cfg.landmarks} (the landmarks), "
                f"got {list(cfg.ns)}")
    for flag, v, lo in (("--runs", cfg.runs, 1), ("--images", cfg.images, 1),
                        ("--exact-sample", cfg.exact_sample, 0),
                        ("timed_runs", cfg.timed_runs, 0), ("landmarks", cfg.landmarks, 3)):
        if v < lo:
            p.error(f"argument {flag}: must be an integer ≥ {lo}, got {v}")
    if not (np.isfinite(cfg.size) and cfg.size > 0):
        p.error(f"size must be a positive, finite number, got {cfg.size}")
    return cfg, a


def layout(cfg: Config, run: int) -> tuple[jax.Array, jax.Array]:
    """Landmarks [landmarks, 2] and imaging poses [images, 3] of run ``run`` (key
    ``fold_in(seed, run)``: the same layout and poses for every n)."""
    from pqrm_jax import sim

    k = jax.random.fold_in(jax.random.key(cfg.seed), run)
    k1, k2 = jax.random.split(k)
    lm = sim.uniform_landmarks(k1, cfg.landmarks, (cfg.size, cfg.size))
    poses = sim.random_imaging_points(k2, cfg.images, (cfg.size, cfg.size))
    return lm, poses


def _time_updates(cfg: Config, lm, poses, n: int) -> np.ndarray:
    from pqrm_jax.qrm import hypergraph as H
    from pqrm_jax.qrm import pipeline as P
    from pqrm_jax.qrm.spec import qrm_spec

    spec = qrm_spec("edc")
    truth = H.true_relations(lm, spec)
    m = H.empty_map(cfg.landmarks, spec)
    m, _ = P.map_step(m, poses[0], lm, n, spec, truth=truth, tol=cfg.bearing_tol)
    jax.block_until_ready(m.rel)  # compile
    m = H.empty_map(cfg.landmarks, spec)
    out = []
    for t in range(poses.shape[0]):
        t0 = time.perf_counter()
        m, met = P.map_step(m, poses[t], lm, n, spec, truth=truth, tol=cfg.bearing_tol)
        jax.block_until_ready(m.rel)
        out.append(time.perf_counter() - t0)
    return np.asarray(out)


def run_study(cfg: Config, out: Path, *, quiet: bool = False, cluster=None,
              fresh: bool = False) -> None:
    """Run (and resume) the study into ``out``; every (n, run) is its own file, written
    atomically and read back in full (a corrupt one is set aside and recomputed).

    With a multi-process ``cluster`` (:mod:`.distributed`, already initialised) every process
    calls this with the same ``cfg``: differing configs are refused on every process, process
    0 alone opens the store and lists the units left, the processes compute them in rounds
    (process p the p-th unit of each round, :func:`.distributed.map_units`) and process 0
    writes each one; the stored runs are those of one process bit for bit (the measured
    ``wall`` and ``update_time`` are stored apart, in ``times/``).
    """
    from tqdm.auto import tqdm

    from . import distributed
    from .store import Store

    cluster = cluster or distributed.current()
    distributed.agree(cluster, cfg.to_json(), f"{NAME} config")
    units = [(n, r) for n in cfg.ns for r in range(cfg.runs)]
    st = None

    def left():
        nonlocal st
        st = Store.open(out, NAME, dict(cfg.to_json(), reasons=REASONS),
                        selection=("runs", "ns", "timed_runs", "exact_sample"), legacy=LEGACY,
                        fresh=fresh)
        return [st.read_npz(f"runs/n{n}_r{r}.npz", RUN_FIELDS) is None for n, r in units]

    try:
        mask = distributed.decide(cluster, len(units), left)
        todo = [u for u, m in zip(units, mask, strict=True) if m]
        done = distributed.map_units(lambda u: run_unit(cfg, *u), todo, cluster, codec="npz")
        for i, rec in tqdm(done, total=len(todo), desc=NAME,
                           disable=quiet or not cluster.is_main):
            if st is not None:
                n, r = todo[i]
                # the measured times apart (identical runs: identical run records); the
                # run record last, as the unit's "done" mark
                times = {k: rec[k] for k in TIMED if k in rec}
                st.write_npz(f"times/n{n}_r{r}.npz", times, compressed=False)
                st.write_npz(f"runs/n{n}_r{r}.npz",
                             {k: v for k, v in rec.items() if k not in times},
                             compressed=False)  # atomic
    finally:
        if st is not None:
            st.close()


LEGACY = ("config.json", "runs", "report.md", "fig7.png", "summary.json", "study.json",
          "results.csv", "timing.json", "times")
#: the summary's measured times (``timing.json``, not ``summary.json`` or ``results.csv``)
TIMES = ("*_s", "*_s_mean", "update_time_*")
RUN_FIELDS = ("removed_pct", "constrained_pct", "not_adjacent_pct", "rng_cost", "first_open",
              "first_proven", "truth_kept", "inconsistent")
#: a run's measured times, stored apart in ``times/n{n}_r{run}.npz`` (older versions kept them
#: in the run record, which is still read)
TIMED = ("wall", "update_time")


def run_unit(cfg: Config, n: int, r: int) -> dict[str, np.ndarray]:
    """The stored record of run ``r`` measuring the ``n`` nearest landmarks per image."""
    from pqrm_jax.qrm import pipeline as P

    lm, poses = layout(cfg, r)
    t0 = time.perf_counter()
    m, met = P.run_sequence(lm, poses, n, "edc", tol=cfg.bearing_tol)
    jax.block_until_ready(m.rel)
    wall = time.perf_counter() - t0
    rec = {f: np.asarray(getattr(met, f)) for f in met._fields}
    rec["wall"] = np.asarray(wall)
    if r < cfg.timed_runs:
        rec["update_time"] = _time_updates(cfg, lm, poses, n)
    return rec


def exact_first_image(cfg: Config, n: int) -> dict:
    """Kernel vs exact sets on ``cfg.exact_sample`` triples of the first image of run 0.

    The triples are spread evenly over the C(n, 3) of the image; the exact sets come from
    :func:`pqrm_jax.qrm.camera_oracle.oracle_sets` (z3, every state decided).
    """
    from pqrm_jax import sim
    from pqrm_jax.qrm import camera as C
    from pqrm_jax.qrm.camera_oracle import oracle_sets
    from pqrm_jax.qrm.spec import popcount, qrm_spec

    spec = qrm_spec("edc")
    lm, poses = layout(cfg, 0)
    cam = sim.camera(poses[0], lm, sim.SensorParams(max_range=1e6))
    m = C.measure_image(cam.bearings, cam.range_rank, cam.visible, n, spec,
                        tol=cfg.bearing_tol)
    valid = np.flatnonzero(np.asarray(m.valid))
    pick = valid[np.linspace(0, len(valid) - 1, min(cfg.exact_sample, len(valid))).astype(int)]
    bear = np.asarray(cam.bearings)[np.asarray(m.triples)[pick]]
    exact = np.stack([oracle_sets(b, spec) for b in bear])
    kern = np.asarray(m.sets)[pick]
    k, e = popcount(kern), popcount(exact)
    return {"triples": int(len(pick)), "kernel_kept_mean": float(k.mean()),
            "exact_kept_mean": float(e.mean()), "equal_frac": float((kern == exact).mean()),
            "kernel_half_frac": float((k <= 10).mean()), "exact_half_frac": float((e <= 10).mean()),
            "sound": bool(((exact & ~kern) == 0).all())}


def load(out: Path, cfg: Config) -> dict:
    from .store import read_npz

    res = {}
    for n in cfg.ns:
        recs = []
        for r in range(cfg.runs):
            rec = read_npz(out / "runs" / f"n{n}_r{r}.npz", RUN_FIELDS)
            if rec is None:
                continue
            rec |= read_npz(out / "times" / f"n{n}_r{r}.npz", ("wall",)) or {}
            rec.setdefault("wall", np.asarray(np.nan))  # a times file lost: no time
            recs.append(rec)
        if not recs:
            continue
        res[n] = {k: np.stack([r[k] for r in recs]) for k in recs[0]
                  if k != "update_time"}
        times = [r["update_time"] for r in recs if "update_time" in r]
        if times:
            res[n]["update_time"] = np.stack(times)
    return res


def _fit_slope(ns, t):
    ns, t = np.asarray(ns, float), np.asarray(t, float)
    ok = t > 0
    if ok.sum() < 2:
        return float("nan")
    return float(np.polyfit(np.log(ns[ok]), np.log(t[ok]), 1)[0])


def stored_config(out: Path) -> Config:
    """The :class:`Config` stored in ``out/config.json`` (the stored run's settings)."""
    return Config.stored(out, NAME)


def report(out: Path) -> Path:
    """``report.md``, ``fig7.png``, ``summary.json`` and ``results.csv`` from the stored runs
    (under the store's lock)."""
    from .store import Store

    out = Path(out)
    with Store.open(out, NAME, None, legacy=LEGACY):
        summarise(out, stored_config(out))
    return out / "report.md"


def _claims(per_n: dict[int, dict]) -> list[protocol.Claim]:
    """M§VIII.B's claims against the per-n summary (the report's table)."""
    ns = sorted(per_n)
    cs = []
    kept = sum(bool(per_n[n]["truth_kept"]) for n in ns)
    cs.append(protocol.Claim("true state never removed", "never (M§VIII.A soundness)",
                             f"{kept} of {len(ns)} n", (len(ns), len(ns)),
                             protocol.verdict_in(kept, len(ns), len(ns))))
    ex = [per_n[n]["exact_first_image"]["exact_half_frac"] for n in ns
          if "exact_first_image" in per_n[n]]
    half = float(np.mean(ex)) if ex else float(np.mean([per_n[n]["first_half_removed_frac"]
                                                        for n in ns]))
    cs.append(protocol.Claim(
        "first measurement removes ≥ half the states", "in almost all cases (read: ≥ 90 %)",
        half, (0.9, 1.0), protocol.verdict_in(half, 0.9, 1.0)))
    big = [n for n in ns if n >= 18]
    if big:
        na = max(per_n[n]["not_adjacent_pct_final"] for n in big)
        cs.append(protocol.Claim("open states cluster at the truth for n ≥ 18 (Fig. 7b)",
                                 "< 45 % not adjacent", na, (0.0, 45.0),
                                 protocol.verdict_in(na, 0.0, 45.0)))
    for n in (n for n in ns if n <= 9):
        na = per_n[n]["not_adjacent_pct_final"]
        cs.append(protocol.Claim(f"n = {n} stays in the 'uniform' band (Fig. 7b)", "45–90 %",
                                 na, (45.0, 90.0), protocol.verdict_in(na, 45.0, 90.0)))
    if 18 in per_n and 30 in per_n:
        r = per_n[18]["removed_pct_final"] / max(per_n[30]["removed_pct_final"], 1e-12)
        cs.append(protocol.Claim("n = 18 ends nearly as well as n = 30",
                                 "nearly as well (read: final removed % within 5 %)", r,
                                 (0.95, 1.05), protocol.verdict_in(r, 0.95, 1.05)))
    return cs


def claims(out: Path) -> list[protocol.Claim]:
    """The published claims (M§VIII.B) against ``out/summary.json`` (written by
    :func:`report`)."""
    from .store import StudyError, read_json

    doc = read_json(Path(out) / "summary.json", ("per_n",), quarantine=False)
    if doc is None:
        raise StudyError(f"{out} holds no {NAME} summary (summary.json); run the study first")
    return _claims({int(n): s for n, s in doc["per_n"].items()})


def summarise(out: Path, cfg: Config) -> dict:
    """The per-n summary of the stored runs; writes ``fig7.png``, ``summary.json``,
    ``results.csv`` and ``report.md``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    res = load(out, cfg)
    ns = sorted(res)
    fig, ax = plt.subplots(2, 3, figsize=(15, 8.5))
    panels = [("removed_pct", "(a) incorrect states removed [%]"),
              ("not_adjacent_pct", "(b) open states not adjacent to truth [%]"),
              ("rng_cost", "(c) total RNG edge cost Σw"),
              ("update_time", "(d) time per update [s]"),
              ("constrained_pct", "fully constrained edges [%]")]
    colors = plt.cm.viridis(np.linspace(0, 0.9, max(len(ns), 1)))
    for (key, title), a in zip(panels, ax.ravel(), strict=False):
        for n, c in zip(ns, colors, strict=True):
            if key not in res[n]:
                continue
            v = res[n][key]
            x = np.arange(1, v.shape[1] + 1)
            mu, sd = v.mean(0), v.std(0)
            a.plot(x, mu, color=c, label=f"n={n}")
            if key != "update_time":
                a.fill_between(x, mu - sd, mu + sd, color=c, alpha=0.15)
        a.set_title(title)
        a.set_xlabel("image")
        if key == "update_time":
            a.set_yscale("log")
    ax[0, 0].legend()
    a = ax[1, 2]
    for n, c in zip(ns, colors, strict=True):
        h = res[n]["first_open"].sum((0, 1))
        a.plot(np.arange(h.size), h / max(h.sum(), 1), "o-", color=c, label=f"n={n}")
    a.axvline(10.5, color="k", ls=":")
    a.set_title("open states after the first measurement of a relation")
    a.set_xlabel("open states (of 20)")
    fig.suptitle(f"QRM Monte Carlo (M Fig. 7): {cfg.landmarks} landmarks, {cfg.images} images,"
                 f" {len(next(iter(res.values()))['wall']) if res else 0} runs")
    fig.tight_layout()
    fig.savefig(out / "fig7.png", dpi=110)
    plt.close(fig)

    summary = {}
    for n in ns:
        r = res[n]
        h = r["first_open"].sum((0, 1))
        s = {
            "runs": int(r["wall"].shape[0]),
            "removed_pct_final": float(r["removed_pct"][:, -1].mean()),
            "removed_pct_final_sd": float(r["removed_pct"][:, -1].std()),
            "removed_pct_image1": float(r["removed_pct"][:, 0].mean()),
            "constrained_pct_final": float(r["constrained_pct"][:, -1].mean()),
            "not_adjacent_pct_final": float(r["not_adjacent_pct"][:, -1].mean()),
            "rng_cost_peak": float(r["rng_cost"].mean(0).max()),
            "rng_cost_final": float(r["rng_cost"][:, -1].mean()),
            "first_half_removed_frac": float(h[:11].sum() / max(h.sum(), 1)),
            "first_half_removed_frac_proven": float(
                r["first_proven"].sum((0, 1))[:11].sum() / max(h.sum(), 1)),
            "first_open_mean": float((h * np.arange(h.size)).sum() / max(h.sum(), 1)),
            "truth_kept": bool(r["truth_kept"].all()),
            "inconsistent": int(r["inconsistent"].sum()),
            "run_wall_s_mean": float(r["wall"].mean()),
        }
        if "update_time" in r:
            s["update_time_peak_s"] = float(r["update_time"].mean(0).max())
            s["update_time_mean_s"] = float(r["update_time"].mean())
        if cfg.exact_sample > 0:
            s["exact_first_image"] = exact_first_image(cfg, n)
        summary[n] = s
    peaks = [summary[n].get("update_time_peak_s", np.nan) for n in ns]
    slope = _fit_slope(ns, peaks)
    from .store import (
        atomic_write_json,
        atomic_write_text,
        is_measured,
        tidy_rows,
        write_results_csv,
    )

    # measured times apart from the results (two identical runs: identical results files)
    timed = {n: {k: v for k, v in s.items() if is_measured(k, TIMES)} for n, s in summary.items()}
    atomic_write_json(out / "summary.json", {"per_n": {
        n: {k: v for k, v in s.items() if not is_measured(k, TIMES)} for n, s in summary.items()}})
    atomic_write_json(out / "timing.json", {"per_n": timed, "peak_slope": slope})
    write_results_csv(out / "results.csv", NAME, tidy_rows(
        [{"n": n, **s} for n, s in summary.items()], unit=lambda r: f"n={r['n']}", skip=("n",),
        measured=TIMES))
    lines = [f"# {NAME}: QRM Monte Carlo study (M§VIII.B, Fig. 7)", "",
             f"Config: `{json.dumps(dataclasses.asdict(cfg))}`", "",
             "## Claims", "", *protocol.claims_table(_claims(summary)), "",
             "The update-time slope (M: 3.5 in C#) is a timing of another implementation on "
             "another machine: reported below, not checked.", "",
             *protocol.figure("fig7.png", "M Fig. 7 reproduced: per image (x axis), the mean "
                              "over runs (band: ± one standard deviation) of (a) the incorrect "
                              "states removed, (b) the open states not adjacent to the truth, "
                              "(c) the RNG edge cost, (d) the time per update (log scale, timed "
                              "runs only) and the fully constrained edges, one line per n; the "
                              "last panel is the distribution of open states after a "
                              "relation's first measurement (dotted: half of the 20 states)."),
             "| n | runs | removed % (img 1) | removed % (final) | constrained % | not-adjacent % "
             "| RNG cost peak → final | first meas. ≥ half removed (all kept / witnessed only) "
             "| truth kept | peak update s |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for n in ns:
        s = summary[n]
        lines.append(
            f"| {n} | {s['runs']} | {s['removed_pct_image1']:.1f} | "
            f"{s['removed_pct_final']:.1f} ± {s['removed_pct_final_sd']:.1f} | "
            f"{s['constrained_pct_final']:.1f} | {s['not_adjacent_pct_final']:.1f} | "
            f"{s['rng_cost_peak']:.2f} → {s['rng_cost_final']:.2f} | "
            f"{100 * s['first_half_removed_frac']:.1f} % / "
            f"{100 * s['first_half_removed_frac_proven']:.1f} % | {s['truth_kept']} | "
            f"{s.get('update_time_peak_s', float('nan')):.3f} |")
    lines += ["", f"Peak update time vs n, fitted log-log slope: **{slope:.2f}** "
              "(McClelland: 3.5, unoptimised C#). Here an update is the measurement of the "
              "C(n,3) triples (∝ n³) plus the path-consistency closure of the whole "
              "30-landmark map, whose cost does not depend on n; at small n that fixed part "
              "dominates, so the fitted slope stays well below 3 (timed runs: "
              f"{cfg.timed_runs} per n, on a machine that may be shared).", "",
              "## Comparison with the published behaviour (M§VIII.B)", "",
              "- *First measurement removes at least half the states in almost all cases*: "
              "see the 'first meas.' column (fraction of newly measured relations with ≤ 10 "
              "of 20 states open). The measurement is the exact boundary decision "
              "(docs/qrm.md §camera): 'all kept' counts every state it keeps, including the "
              "few that near-degenerate float32 input leaves undecided (kept for soundness); "
              "'witnessed only' counts states with a witness range assignment (the exact "
              "figure's lower bound).",
              "- Exact sets (z3 oracle, every state decided) on "
              f"{cfg.exact_sample} triples of the first image of run 0: first measurement "
              "≥ half removed, kernel vs exact — " + "; ".join(
                  f"n = {n}: {100 * summary[n]['exact_first_image']['kernel_half_frac']:.0f} % "
                  f"vs {100 * summary[n]['exact_first_image']['exact_half_frac']:.0f} % (mean "
                  f"kept {summary[n]['exact_first_image']['kernel_kept_mean']:.1f} vs "
                  f"{summary[n]['exact_first_image']['exact_kept_mean']:.1f}, sound "
                  f"{summary[n]['exact_first_image']['sound']})"
                  for n in ns if "exact_first_image" in summary[n]) + ". The published "
              "'almost all cases' is a property of the exact sets; the kernel's gap to them "
              "is its undecided states (none when the two columns agree).",
              "- *n ≥ 18 ends nearly as well as n = 30; n < 15 converges much slower*: compare "
              "the final removed % across rows.",
              "- *The RNG converges faster than the map*: RNG cost peaks early and decays while "
              "the removed % still grows.",
              "- *Open states cluster around the truth for n ≥ 18* (Fig. 7b: < 45 % "
              "not adjacent) while n = 6, 9 stay in the 45–90 % 'uniform' band.",
              "- The true state was never removed (soundness) in any run: 'truth kept'."]
    atomic_write_text(out / "report.md", "\n".join(lines) + "\n")
    return summary


main = protocol.main_for(sys.modules[__name__])
sweep_summary = protocol.summary_for(sys.modules[__name__])
