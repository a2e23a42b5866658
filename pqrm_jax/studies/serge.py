"""``pqrm-jax study serge``: the SERGE evaluation of Padgett §3.4 (docs/decisions.md §5).

5-fold cross validation on (a) 49 well-separated Gaussian beliefs, (b) the simulated hallway
(triplets, variance 0.1 m², 10 000 samples per belief) and (c) a simulated 55-object lab;
sweeps μ = 1..K at σ = 2 and σ = 2..16 at μ = 20; number of SRs, test log likelihood and error
rate (P Fig. 3.7), example maps (P Fig. 3.8) and ``report.md`` against the published behaviour.

Results are appended to ``results.jsonl`` one evaluation at a time; a rerun with the same
``--out`` skips what is done (an interrupted study resumes). ``--reduced`` runs a subset
(2 folds, a few μ and σ values, fewer trials and samples) in about a minute or two.
As N processes on ``jax.distributed`` (``--coordinator/--processes/--process-id``, the
environment or Slurm; :mod:`pqrm_jax.studies.distributed`) the solves are split over the
processes and process 0 alone writes them (the same results as one process, except the
measured ``seconds``).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
import zlib
from pathlib import Path

import numpy as np

from . import protocol

NAME = "serge"
HELP = "SERGE salient regions: 5-fold CV on well-separated, hallway and lab scenes (P§3.4)"

PUBLISHED = {
    "well_separated": "|R| = μ in every test, log-likelihood 0, no errors",
    "lab": "error < 3 % in every test",
    "all": "worst-case error < 7 % (the fold-mean error rates of Fig. 3.7e,f)",
    "sigma": "larger σ gives fewer regions and a higher log likelihood (hallway, lab)",
}


@dataclasses.dataclass(frozen=True)
class Config(protocol.StudyConfig):
    """Every result-changing setting (each knob's reason in :data:`REASONS`).

    ``reduced`` selects the reduced plan (2 folds run, a few μ and σ values, 2000 hallway
    samples, 4·K trials, a 64² grid); ``grid`` and ``trials`` 0 mean the plan's default.
    """

    datasets: tuple[str, ...] = ("well_separated", "hallway", "lab")
    folds: int = 5
    reduced: bool = False
    grid: int = 0
    trials: int = 0
    seed: int = 0



REASONS = {
    "datasets": "P§3.4's three scenes (simulated: docs/decisions.md §5)",
    "folds": "P§3.4: 5-fold cross validation",
    "reduced": "the reduced plan for quick checks (2 folds, few μ/σ, fewer samples)",
    "grid": "grid cells per axis (0: 96; 64 reduced) — enough to separate the hallway beliefs",
    "trials": "merge-search trials per solve (0: 20·K; 4·K reduced; Padgett suggests > 100·K)",
    "seed": "scene, fold and search seed",
}

PRESETS: dict[str, dict] = {
    "tiny": {"reduced": True, "datasets": ("hallway",), "grid": 40, "trials": 8},
    "reduced": {"reduced": True},
    "full": {},
}


def configure(argv: list[str], overrides: dict | None = None
              ) -> tuple[Config, argparse.Namespace]:
    """The study's Config and parsed flags (every number checked before any work)."""
    from ..serge import scenes as scenes_mod

    p = protocol.parser(NAME, HELP, seed=Config.seed)
    p.add_argument("--trials", type=protocol.positive_int, default=None,
                   help="merge-search trials per solve (default 20·K; 4·K reduced; "
                        "Padgett suggests > 100·K)")
    p.add_argument("--folds", type=protocol.positive_int, default=None,
                   help="number of CV folds (≥ 2; default 5)")
    p.add_argument("--datasets", default=None,
                   help="comma-separated scenes (default well_separated,hallway,lab)")
    p.add_argument("--grid", type=protocol.positive_int, default=None,
                   help="grid cells per axis (≥ 2; default 96; 64 reduced)")
    a = p.parse_args(argv)
    if a.datasets is not None:
        a.datasets = tuple(d.strip() for d in a.datasets.split(",") if d.strip())
    cfg = protocol.apply_preset(Config, PRESETS, a.preset, a,
                                {"trials": "trials", "folds": "folds", "datasets": "datasets",
                                 "grid": "grid"}, overrides)
    if "seed" not in (overrides or {}):
        cfg = dataclasses.replace(cfg, seed=a.seed)
    if cfg.folds < 2:
        p.error(f"argument --folds: must be an integer ≥ 2, got {cfg.folds}")
    if cfg.grid == 1:
        p.error(f"argument --grid: must be an integer ≥ 2, got {cfg.grid}")
    if cfg.reduced and cfg.folds < 2:
        p.error(f"argument --folds: must be ≥ 2 with --reduced, got {cfg.folds}")
    unknown = [d for d in cfg.datasets if d not in scenes_mod.SCENES]
    if unknown or not cfg.datasets:
        p.error(f"argument --datasets: unknown {unknown or list(cfg.datasets)}; known: "
                f"{', '.join(sorted(scenes_mod.SCENES))}")
    return cfg, a


def _meta(cfg: Config) -> dict:
    """The stored config (the form earlier versions stored, so their directories resume)."""
    return {"reduced": cfg.reduced, "folds": cfg.folds,
            "folds_run": list(range(2 if cfg.reduced else cfg.folds)),
            "grid": cfg.grid or (64 if cfg.reduced else 96), "seed": cfg.seed,
            "trials": cfg.trials or None}


def _plan(k: int, reduced: bool) -> list[tuple[str, int, float]]:
    if reduced:
        mus = sorted({1, max(1, k // 4), max(1, k // 2), max(1, 3 * k // 4), k})
        sigmas = [2.0, 4.0, 8.0, 16.0]
    else:
        mus = list(range(1, k + 1))
        sigmas = [float(s) for s in range(2, 17)]
    return ([("mu", m, 2.0) for m in mus] + [("sigma", min(20, k), s) for s in sigmas])


def _scene(name: str, reduced: bool, seed: int):
    from ..serge import scenes

    if name == "hallway":
        return scenes.hallway(seed=seed, n_samples=2000 if reduced else 10_000)
    return scenes.SCENES[name](seed=seed)


def _grid(scene, n: int):
    from ..serge import Grid

    q = 0.01 if scene.kind == "triplets" else None
    return Grid.covering(np.concatenate(scene.points), (n, n), quantile=q)


def run_study(cfg: Config, out: Path, *, quiet: bool = False, cluster=None,
              fresh: bool = False) -> None:
    """Every solve not yet stored (``results.jsonl``, appended one by one), split over the
    processes; process 0 writes."""
    import jax
    from tqdm import tqdm

    from ..serge.evaluate import evaluate, make_fold
    from . import distributed
    from .store import Store

    cluster = cluster or distributed.current()
    meta = dict(_meta(cfg), devices=str(jax.local_devices()))
    folds_run, datasets = meta["folds_run"], list(cfg.datasets)
    # every process: the same scenes, grids and unit list; the devices may differ
    distributed.agree(cluster, dict(meta, devices=None, datasets=datasets), "serge config")
    scenes, grids, units = {}, {}, []
    for d in datasets:
        sc = _scene(d, cfg.reduced, cfg.seed)
        scenes[d], grids[d] = sc, _grid(sc, meta["grid"])
        units += [(d, f, sweep, mu, sigma) for f in folds_run
                  for sweep, mu, sigma in _plan(sc.k, cfg.reduced)]
    st = log = None

    def left():
        nonlocal st, log
        st = Store.open(out, NAME, dict(meta, reasons=REASONS), fresh=fresh,
                        selection=("folds_run", "devices"),
                        legacy=("meta.json", "results.jsonl", "report.md", "fig_*.png",
                                "config.json", "study.json", "results.csv", "*.corrupt"),
                        legacy_config="meta.json")
        log = st.records("results.jsonl", key=_key, required=_FIELDS)
        return [(d, sweep, mu, sigma, f) not in log for d, f, sweep, mu, sigma in units]

    folds_cache: dict = {}

    def solve(task):
        d, f, sweep, mu, sigma = task
        sc = scenes[d]
        if (d, f) not in folds_cache:
            folds_cache.clear()
            folds_cache[(d, f)] = make_fold(sc, grids[d], sc.folds(cfg.folds, cfg.seed), f,
                                            jax.random.PRNGKey(1000 * cfg.seed + f))
        trials = cfg.trials or (4 if cfg.reduced else 20) * sc.k
        t0 = time.perf_counter()
        seed = zlib.crc32(f"{d}/{sweep}/{mu}/{sigma}/{f}".encode()) % 2**31
        r = evaluate(folds_cache[(d, f)], mu, sigma, jax.random.PRNGKey(seed), trials)
        r.update(dataset=d, sweep=sweep, mu=mu, sigma=sigma, fold=f, trials=trials,
                 seconds=time.perf_counter() - t0)
        return r

    try:
        mask = distributed.decide(cluster, len(units), left)
        tasks = [u for u, m in zip(units, mask, strict=True) if m]
        for _, r in tqdm(distributed.map_units(solve, tasks, cluster, codec="json"),
                         total=len(tasks), desc="serge study", unit="solve",
                         disable=quiet or not cluster.is_main):
            if log is not None:
                log.add(r)
    finally:
        if st is not None:
            st.close()


def _rows(out: Path) -> tuple[dict, list[dict]]:
    """(stored config, the stored results of the datasets and folds it runs)."""
    import json

    from .store import StudyError, read_jsonl

    try:
        meta = json.loads((Path(out) / "config.json").read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        raise StudyError(f"{out} holds no {NAME} results; run the study first") from None
    good, _ = read_jsonl(Path(out) / "results.jsonl", _key)
    times, _ = read_jsonl(Path(out) / "results.times.jsonl", key=lambda r: r["key"])
    rows = [dict(r, **{k: v for k, v in times.get(repr(k2), {}).items() if k != "key"})
            for k2, r in sorted(good.items())]
    return meta, [r for r in rows if r["fold"] in meta["folds_run"]]


def report(out: Path) -> Path:
    """``report.md``, the figures and ``results.csv`` from the stored results."""
    from .store import tidy_rows, write_results_csv

    out = Path(out)
    meta, rows = _rows(out)
    datasets = sorted({r["dataset"] for r in rows})
    summary = _summarise(rows)
    scenes = {d: _scene(d, meta["reduced"], meta["seed"]) for d in datasets}
    grids = {d: _grid(scenes[d], meta["grid"]) for d in datasets}
    _figures(summary, scenes, grids, out, meta)
    _report(summary, rows, out, meta)
    write_results_csv(out / "results.csv", NAME, tidy_rows(
        rows, unit=lambda r: "/".join(str(r[k]) for k in _KEY), skip=(*_KEY, "trials")))
    return out / "report.md"


_KEY = ("dataset", "sweep", "mu", "sigma", "fold")
_FIELDS = (*_KEY, "n_regions", "log_likelihood", "error_rate", "seconds")


def _key(r: dict) -> tuple:
    """A result's unit: (dataset, sweep, μ, σ, fold), each of the expected type."""
    d, sweep, mu, sigma, fold = (r[k] for k in _KEY)
    if not (isinstance(d, str) and sweep in ("mu", "sigma") and isinstance(fold, int)
            and isinstance(mu, (int, float)) and isinstance(sigma, (int, float))):
        raise ValueError(f"bad unit {[r[k] for k in _KEY]}")
    return (d, sweep, mu, float(sigma), fold)


def _summarise(rows: list[dict]) -> dict:
    groups: dict = {}
    for r in rows:
        groups.setdefault((r["dataset"], r["sweep"], r["mu"], r["sigma"]), []).append(r)
    out = {}
    for key, rs in sorted(groups.items()):
        out[key] = {m: float(np.mean([r.get(m, np.nan) for r in rs]))
                    for m in ("n_regions", "log_likelihood", "error_rate", "seconds")}
        out[key]["max_error"] = float(np.max([r["error_rate"] for r in rs]))
        out[key]["n"] = len(rs)
    return out


def _series(summary, d, sweep, metric):
    pts = sorted((k[2] if sweep == "mu" else k[3], v[metric])
                 for k, v in summary.items() if k[0] == d and k[1] == sweep)
    return np.array([p[0] for p in pts]), np.array([p[1] for p in pts])


def _examples(datasets) -> list[tuple[str, int, float]]:
    """(dataset, μ, σ) of the region maps of ``fig_3_8_maps.png`` (the datasets present)."""
    examples = [("hallway", 18, 2.0), ("hallway", 10, 2.0), ("lab", 55, 0.01), ("lab", 10, 2.0)]
    return [e for e in examples if e[0] in datasets]


def _figures(summary, scenes, grids, out: Path, meta) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import jax
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    from ..serge import initial_cells, serge
    from .store import atomic_savefig

    fig, axes = plt.subplots(3, 2, figsize=(10, 10))
    for col, sweep in enumerate(("mu", "sigma")):
        for row, (metric, lab) in enumerate((("n_regions", "number of SRs"),
                                             ("log_likelihood", "test log likelihood"),
                                             ("error_rate", "error rate"))):
            ax = axes[row, col]
            for d in scenes:
                x, y = _series(summary, d, sweep, metric)
                ax.plot(x, y, "o-", ms=3, label=d)
            ax.set_xlabel("μ (σ = 2)" if sweep == "mu" else "σ (μ = 20)")
            ax.set_ylabel(lab)
            ax.grid(alpha=0.3)
    axes[0, 0].legend()
    fig.suptitle(f"SERGE {meta['folds']}-fold CV, {len(meta['folds_run'])} folds run "
                 "(cf. Padgett Fig. 3.7)")
    fig.tight_layout()
    atomic_savefig(fig, out / "fig_3_7_cv.png", dpi=110)
    plt.close(fig)

    examples = _examples(scenes)
    if not examples:
        return
    fig, axes = plt.subplots(1, len(examples), figsize=(5 * len(examples), 4.5))
    axes = np.atleast_1d(axes)
    for ax, (d, mu, sigma) in zip(axes, examples, strict=True):
        sc, g = scenes[d], grids[d]
        p = initial_cells(jax.random.PRNGKey(0), sc.beliefs(), g, unseparated="attach")
        trials = meta["trials"] or (4 if meta["reduced"] else 20) * sc.k
        r = serge(jax.random.PRNGKey(7), p, min(mu, sc.k), sigma, trials=trials)
        lab = np.asarray(r.cell_labels).reshape(g.shape).T
        ax.imshow(lab, origin="lower", extent=g.extent(), cmap="tab20",
                  interpolation="nearest", aspect="auto")
        # region borders as thin white lines: tab20 repeats its colours beyond 20 regions
        x0, x1, y0, y1 = g.extent()
        dx, dy = (x1 - x0) / lab.shape[1], (y1 - y0) / lab.shape[0]
        seg = [((x0 + (j + 1) * dx, y0 + i * dy), (x0 + (j + 1) * dx, y0 + (i + 1) * dy))
               for i, j in zip(*np.nonzero(lab[:, :-1] != lab[:, 1:]), strict=True)]
        seg += [((x0 + j * dx, y0 + (i + 1) * dy), (x0 + (j + 1) * dx, y0 + (i + 1) * dy))
                for i, j in zip(*np.nonzero(lab[:-1] != lab[1:]), strict=True)]
        ax.add_collection(LineCollection(seg, colors="white", linewidths=0.6))
        pts = np.concatenate(sc.points)
        ax.plot(pts[:, 0], pts[:, 1], "k.", ms=1)
        ax.set_title(f"{d}: μ={mu}, σ={sigma} → {r.n_regions} SRs")
        ax.set_xlabel("x")
        ax.set_ylabel("y")
    fig.tight_layout()
    atomic_savefig(fig, out / "fig_3_8_maps.png", dpi=110)
    plt.close(fig)


def _claims(summary: dict) -> list[protocol.Claim]:
    """P§3.4–3.5's claims against the fold means (``summary`` of :func:`_summarise`)."""
    def sel(d, sweep=None):
        return {k: v for k, v in summary.items() if k[0] == d and (sweep is None or k[1] == sweep)}

    C, yes = protocol.Claim, protocol.MATCH
    cs = []
    ws = sel("well_separated")
    if ws:
        eq = all(abs(v["n_regions"] - min(k[2], 49)) < 1e-9 for k, v in ws.items())
        ll = max(abs(v["log_likelihood"]) for v in ws.values())
        er = max(v["max_error"] for v in ws.values())
        ok = eq and ll < 1e-2 and er == 0
        cs.append(C("well separated: #SRs = μ, LL 0, no errors", PUBLISHED["well_separated"],
                    f"#SRs = μ in all: {eq}; max |LL| = {ll:.2e}; max error = {er:.3%}",
                    None, yes if ok else protocol.MISMATCH))
    lab = sel("lab")
    if lab:
        er = max(v["max_error"] for v in lab.values())
        cs.append(C("lab: error < 3 % in all tests", PUBLISHED["lab"], er, (0.0, 0.03),
                    yes if er < 0.03 else protocol.MISMATCH))
    if summary:
        # P Fig. 3.7(e, f) plot the error rate averaged over the folds; "less than 7 % worst
        # case" (P§3.5) is the worst of those plotted averages over all datasets and settings
        mean_worst = max(v["error_rate"] for v in summary.values())
        cs.append(C("worst case error < 7 % (fold-mean error, Fig. 3.7e,f)", PUBLISHED["all"],
                    mean_worst, (0.0, 0.07), yes if mean_worst < 0.07 else protocol.MISMATCH))
    for d in ("hallway", "lab"):
        if len(sel(d, "sigma")) >= 2:
            x, n = _series(summary, d, "sigma", "n_regions")
            _, ll = _series(summary, d, "sigma", "log_likelihood")
            ok = n[-1] <= n[0] and ll[-1] >= ll[0] - 1e-6
            cs.append(C(f"{d}: larger σ → fewer SRs, higher LL", PUBLISHED["sigma"],
                        f"σ {x[0]:g}→{x[-1]:g}: #SRs {n[0]:.1f}→{n[-1]:.1f}, "
                        f"LL {ll[0]:.3f}→{ll[-1]:.3f}", None,
                        yes if ok else protocol.MISMATCH))
    return cs


def claims(out: Path) -> list[protocol.Claim]:
    """The published claims of P§3.4–3.5 with the stored results' values and verdicts."""
    return _claims(_summarise(_rows(out)[1]))


def _report(summary, rows, out: Path, meta) -> None:
    cs = _claims(summary)
    checks = [c.verdict == protocol.MATCH for c in cs]
    lines = ["# SERGE study (Padgett §3.4)", "",
             f"Preset: {'reduced' if meta['reduced'] else 'full'}; folds run {meta['folds_run']} "
             f"of {meta['folds']}; grid {meta['grid']}²; trials "
             f"{meta['trials'] or ('4·K' if meta['reduced'] else '20·K')}; "
             f"devices {meta.get('devices')}; {len(rows)} evaluations.", "",
             "Scenes are simulated (docs/decisions.md §5: no Kinect lab data is available).", "",
             "## Measured vs published", "", *protocol.claims_table(cs), ""]
    if summary:
        er = max(v["max_error"] for v in summary.values())
        at = max(summary.items(), key=lambda kv: kv[1]["max_error"])[0]
        lines.append(f"Not a published figure: the worst single fold's error is {er:.2%} "
                     f"(at {at[0]}, μ={at[2]}, σ={at[3]}).")
    for d in ("hallway", "lab"):
        if any(k[0] == d and k[1] == "mu" for k in summary):
            x, n = _series(summary, d, "mu", "n_regions")
            less = bool(np.any(n < x - 1e-9))
            lines.append(f"{d}: #SRs < μ for some μ at σ = 2 (overlapping beliefs): "
                         f"{'yes' if less else 'no'} (#SRs at μ = K: {n[-1]:.1f} of {x[-1]}).")
    lines += ["", f"All checked claims hold: **{all(checks)}**", "",
              "## Mean over folds", "",
              "| dataset | sweep | μ | σ | SRs | test LL | error | max error | s/solve |",
              "|---|---|---|---|---|---|---|---|---|"]
    for (d, sweep, mu, sigma), v in summary.items():
        lines.append(f"| {d} | {sweep} | {mu} | {sigma:g} | {v['n_regions']:.1f} | "
                     f"{v['log_likelihood']:.3f} | {v['error_rate']:.2%} | {v['max_error']:.2%} | "
                     f"{v['seconds']:.2f} |")
    lines += ["", "## Figures", "", *protocol.figure("fig_3_7_cv.png", (
        "Means over the cross-validation folds, one line per dataset: number of spatial "
        "regions (SRs), test log-likelihood and error rate (rows) against μ at σ = 2 (left) "
        "and against σ at μ = 20 (right) (cf. P Fig. 3.7)."))]
    examples = _examples({r["dataset"] for r in rows})
    if examples:
        shown = "; ".join(f"{d} μ = {mu}, σ = {sigma:g}" for d, mu, sigma in examples)
        lines += protocol.figure("fig_3_8_maps.png", (
            f"The spatial regions SERGE finds ({shown}; left to right): each grid cell "
            "coloured by its region (white lines: region borders), the data points of the "
            "scene's K beliefs as black dots, x and y in the scene's coordinates; each title "
            "gives the number of SRs (cf. P "
            "Fig. 3.8)."))
    from .store import atomic_write_text

    atomic_write_text(out / "report.md", "\n".join(lines))


sweep_summary = protocol.summary_for(sys.modules[__name__])
main = protocol.main_for(sys.modules[__name__])
