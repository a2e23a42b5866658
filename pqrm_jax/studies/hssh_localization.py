"""``pqrm-jax study hssh-localization``: adaptive proposals vs action models (B §4.3.2, Table 4.2).

B's log (3961 odometry and laser readings of a 9-minute run) is not available, so this runs
in simulation: a robot drives a fixed route through the corridor network of
:func:`pqrm_jax.sim.corridors.network_rectangles` (80 m x 80 m at 0.1 m cells); its odometry
is the true motion corrupted by the "fitted" action model of Table 4.1 (the robot's real
noise); a 180° lidar (180 beams, 8 m, 1 cm noise) scans the world at every true pose. Every
step restarts at the ground-truth previous pose (as in B), and each of the five algorithms
(:data:`pqrm_jax.hssh.localization.METHODS`) proposes particles from each of the three action
models ("large" overestimates, "small" underestimates the noise); the metric is the best
scan likelihood found (likelihood field against the true map, in (0, 1]). Two runs with
different particle draws over the same log (odometry and scans); Table 4.2's layout: run-1
rows minus run-2 columns, mean over steps, ``*`` when a paired t-test gives p < 0.01.

Compared with B: orderings, not values (published: shrink beats PF on every model; shrink
beats grow with "large"; grow beats shrink with "small"; shrink-and-grow is best on all).
Work unit = one (run, model): its five algorithms over all steps, written atomically to
``units/`` of a :class:`~pqrm_jax.studies.store.Store`; a rerun resumes; a different
configuration in the same ``--out`` is refused; ``results.csv`` is the tidy table.

As N processes on ``jax.distributed`` (README "Running on a cluster"; flags of
:func:`.distributed.add_arguments`) process 0 lists the units left, the processes compute them
in rounds of N (:func:`.distributed.map_units`) and process 0 writes each as it arrives: the
units equal a one-process run's bit for bit (every unit draws from its own fold-in keys).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from pathlib import Path

import numpy as np

from . import protocol
from .store import Store, StudyError, atomic_savefig, atomic_write_text

NAME = "hssh-localization"
HELP = "HSSH adaptive particle proposals x action models in simulation (B §4.3.2, Table 4.2)"

MODELS = ("large", "small", "fitted")
ROUTE = [(0.1, 0.65), (0.35, 0.65), (0.35, 0.25), (0.75, 0.25), (0.75, 0.65), (0.4, 0.65)]


def _kld_default() -> dict:
    # the extra KLD-sampling rows (B §4.3.2 runs every filter with it; Fox 2003): B's
    # confidence, error and bins; n_min is this library's choice (B gives none)
    return {"epsilon": 0.5, "confidence": 0.95, "bin_size": [0.05, 0.05, 0.006], "n_min": 10}


@dataclasses.dataclass(frozen=True)
class Config:
    """Every setting of the study (stored in ``config.json`` by :meth:`to_json`, except the
    two switches of extra rows, which only add units beside the stored ones).

    ``steps`` steps per run; ``runs`` = 2 (Table 4.2 compares run 1 with run 2); the world
    (``world_cells`` at ``resolution`` m, :func:`pqrm_jax.sim.corridors.network_rectangles`),
    the route (:data:`ROUTE`, fractions of the side), the odometry's true noise model
    (``truth_model``), the lidar (``beams``, ``fov_deg``, ``max_range`` m, ``range_sigma`` m),
    the filters (``blocks`` × ``block`` particles, likelihood field sd ``field_sigma`` m capped
    at ``field_cap_cells``, grow/shrink ``threshold`` and ``anneal``), the action ``models``
    and ``kld`` (KLD-sampling settings of the extra rows). ``kld_rows``: also the five
    algorithms with KLD-sampling (``--kld``); ``equal_budget``: also the KLD filters at an
    equal particle budget (``--equal-budget``, implies ``kld_rows``).
    """

    steps: int = 400
    runs: int = 2
    seed: int = 0
    world_cells: int = 801
    resolution: float = 0.1
    route: tuple[tuple[float, float], ...] = tuple(ROUTE)
    truth_model: str = "fitted"
    beams: int = 180
    fov_deg: float = 180.0
    max_range: float = 8.0
    range_sigma: float = 0.01
    blocks: int = 5
    block: int = 100
    field_sigma: float = 0.1
    field_cap_cells: int = 20
    threshold: float = 0.8
    anneal: float = 0.9
    models: tuple[str, ...] = MODELS
    kld: dict = dataclasses.field(default_factory=_kld_default)
    kld_rows: bool = False
    equal_budget: bool = False

    def to_json(self) -> dict:
        """The stored config: every field but the two switches of extra rows."""
        d = protocol.config_json(self)
        del d["kld_rows"], d["equal_budget"]
        return json.loads(json.dumps(d))


PRESETS: dict[str, dict] = {"tiny": {"steps": 8}, "reduced": {"steps": 40}, "full": {}}
"""Field overrides of :class:`Config` per preset (``--reduced``: 40 steps per run)."""


def configure(argv: list[str], overrides: dict | None = None
              ) -> tuple[Config, argparse.Namespace]:
    """The study's Config and parsed flags (every number checked before any work)."""
    p = protocol.parser(NAME, HELP, seed=Config.seed)
    p.add_argument("--steps", type=protocol.positive_int, default=None,
                   help="steps per run (default 400; --reduced 40, --tiny 8)")
    p.add_argument("--kld", dest="kld_rows", action="store_const", const=True, default=None,
                   help="also run the five algorithms with KLD-sampling (extra rows; the "
                        "full-block units stay as they are)")
    p.add_argument("--equal-budget", action="store_const", const=True, default=None,
                   help="also run the KLD filters at an equal particle budget (implies --kld): "
                        "at each step every method scores at most the fewest particles any "
                        "of PF, shrink, grow, shrink-and-grow scored there with KLD")
    a = p.parse_args(argv)
    cfg = protocol.apply_preset(Config, PRESETS, a.preset, a,
                                {"steps": "steps", "kld_rows": "kld_rows",
                                 "equal_budget": "equal_budget"}, overrides)
    if "seed" not in (overrides or {}):
        cfg = dataclasses.replace(cfg, seed=a.seed)
    if cfg.equal_budget:
        cfg = dataclasses.replace(cfg, kld_rows=True)
    if cfg.steps < 1:
        p.error(f"argument --steps: must be an integer ≥ 1, got {cfg.steps}")
    if cfg.runs != 2:
        p.error(f"runs must be 2 (Table 4.2 compares run 1 with run 2), got {cfg.runs}")
    if tuple(cfg.models) != MODELS:
        p.error(f"models must be {', '.join(MODELS)} (the three rows of Table 4.2), got "
                f"{cfg.models}")
    return cfg, a


def _route(n_steps: int, side: float) -> np.ndarray:
    pts = np.array(ROUTE) * side
    seg = np.diff(pts, axis=0)
    lengths = np.hypot(*seg.T)
    s = np.linspace(0, lengths.sum(), n_steps + 1)
    cum = np.concatenate([[0], np.cumsum(lengths)])
    k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    xy = pts[k] + (s - cum[k])[:, None] * (seg[k] / lengths[k, None])
    th = np.arctan2(seg[k, 1], seg[k, 0])
    return np.concatenate([xy, th[:, None]], axis=1).astype(np.float32)


def _kld_params(cfg: dict):
    from ..hssh.localization import KLDParams

    k = cfg["kld"]
    return KLDParams(epsilon=k["epsilon"], confidence=k["confidence"],
                     bin_size=tuple(k["bin_size"]), n_min=k["n_min"])


def run_unit(run: int, model: str, cfg: dict, kld: bool = False,
             budget: list | None = None) -> dict:
    """Best likelihoods ``[5, J]`` of the five methods for one run and one action model.

    With ``kld`` every proposal is cut by KLD-sampling (``cfg["kld"]``, Fox 2003) and the
    unit also holds the particles scored per step (``"<method>_n"``) and the settings
    (``"kld"``); the draws are the same keys as the unit without it. With ``budget`` (one
    int per step, with ``kld``) each method scores at most that many particles per step
    (:func:`~pqrm_jax.hssh.localization.localize_with_count`'s ``budget``).
    """
    import jax
    import jax.numpy as jnp

    from ..hssh import squared_distance_transform
    from ..hssh.localization import METHODS, LocalizeParams, localize_with_count
    from ..hssh.motion import ACTION_MODELS, sample_motion
    from ..sim import corridors
    from ..sim.lidar import LidarParams, lidar_scan

    side_cells, res = cfg["world_cells"], cfg["resolution"]
    img = np.asarray(corridors.render_free_rectangles(side_cells, corridors.network_rectangles(),
                                                      supersample=2))
    world = jnp.asarray((img < 128)[::-1].copy())
    d2 = squared_distance_transform(world[None], cap=cfg["field_cap_cells"])[0]
    true = jnp.asarray(_route(cfg["steps"], side_cells * res))
    base = jax.random.key(cfg["seed"])
    # the robot's odometry: true motion corrupted by the "fitted" model (same for all models)
    truth_c = jnp.asarray(ACTION_MODELS[cfg["truth_model"]])

    def odo_step(prev, j):
        k = jax.random.fold_in(jax.random.fold_in(base, 17), j)   # one log for both runs
        nxt = sample_motion(k, prev[None], true[j - 1], true[j], truth_c)[0]
        return nxt, nxt

    _, odom = jax.lax.scan(odo_step, true[0], jnp.arange(1, cfg["steps"] + 1))
    odom = jnp.concatenate([true[:1], odom])
    lp = LidarParams(n_beams=cfg["beams"], max_range=cfg["max_range"],
                     fov=math.radians(cfg["fov_deg"]), sigma=cfg["range_sigma"])
    keys = jax.vmap(lambda j: jax.random.fold_in(jax.random.fold_in(base, 1000), j))(
        jnp.arange(cfg["steps"] + 1))
    scans = jax.vmap(lambda k, p: lidar_scan(k, p, world, res, params=lp))(keys, true)
    params = LocalizeParams(blocks=cfg["blocks"], block=cfg["block"], sigma=cfg["field_sigma"],
                            threshold=cfg["threshold"], anneal=cfg["anneal"],
                            kld=_kld_params(cfg) if kld else None)
    c = jnp.asarray(ACTION_MODELS[model])
    out = {}
    steps = jnp.arange(1, cfg["steps"] + 1)
    pkeys = jax.vmap(lambda j: jax.random.fold_in(jax.random.fold_in(base, 5000 + run), j))(steps)
    step_scans = jax.tree.map(lambda x: x[1:], scans)
    cap = (jnp.full(cfg["steps"], cfg["blocks"] * cfg["block"], jnp.int32) if budget is None
           else jnp.asarray(budget, jnp.int32))
    for meth in METHODS:
        f = jax.vmap(lambda k, pr, po, o, z, b, meth=meth: localize_with_count(
            k, pr, po, o, z, d2, jnp.zeros(2), res, c, method=meth, params=params,
            budget=None if budget is None else b)[1:])
        lik, n = f(pkeys, true[:-1], odom[:-1], odom[1:], step_scans, cap)
        out[meth] = np.asarray(lik).tolist()
        if kld:
            out[f"{meth}_n"] = np.asarray(n).tolist()
    if kld:
        out["kld"] = cfg["kld"]
    if budget is not None:
        out["budget"] = [int(x) for x in budget]
    return out


BUDGETED = ("pf", "shrink", "grow", "shrink_and_grow")


def equal_budget(kunit: dict) -> list[int]:
    """Per step, the fewest particles any of :data:`BUDGETED` scored with KLD (raw's single
    odometry particle is not a filter)."""
    return np.min(np.array([kunit[f"{m}_n"] for m in BUDGETED]), axis=0).astype(int).tolist()


def _unit_name(run: int, model: str, kld: bool = False, eq: bool = False) -> str:
    return f"units/run{run}_{model}{'_kld' if kld else ''}{'_eq' if eq else ''}.json"


def _check(u: dict, steps: int) -> bool:
    """A unit holds one number per step for every method (else it is recomputed)."""
    from ..hssh.localization import METHODS

    return all(isinstance(u[m], list) and len(u[m]) == steps
               and all(isinstance(v, (int, float)) for v in u[m]) for m in METHODS)


def _check_kld(u: dict, cfg: dict) -> bool:
    """Also the particle counts, and the KLD settings it was computed with."""
    from ..hssh.localization import METHODS

    return (_check(u, cfg["steps"]) and u.get("kld") == cfg["kld"]
            and all(isinstance(u.get(f"{m}_n"), list) and len(u[f"{m}_n"]) == cfg["steps"]
                    for m in METHODS))


def _read(st, cfg: dict, r: int, m: str, k: bool):
    from ..hssh.localization import METHODS

    names = METHODS + tuple(f"{x}_n" for x in METHODS) + ("kld",) if k else METHODS
    return st.read_json(_unit_name(r, m, k), names,
                        (lambda u: _check_kld(u, cfg)) if k else
                        (lambda u: _check(u, cfg["steps"])))


def _read_eq(st, cfg: dict, r: int, m: str, budget: list[int]):
    from ..hssh.localization import METHODS

    return st.read_json(_unit_name(r, m, True, True), METHODS + ("budget", "kld"),
                        lambda u: _check_kld(u, cfg) and u.get("budget") == budget)


def run_study(cfg: Config, out: Path, *, quiet: bool = False, cluster=None,
              fresh: bool = False) -> None:
    """Every unit not yet stored (``units/``), split over the processes; process 0 writes
    each as it arrives, then the equal-budget units (``equal_budget``, process 0 alone: the
    budgets come from the stored KLD units) and ``results.csv``."""
    from tqdm import tqdm

    from ..hssh.localization import METHODS
    from . import distributed

    cluster = cluster or distributed.current()
    c = cfg.to_json()
    distributed.agree(cluster, c, f"{NAME} config")
    # the five published algorithms as B ran them (full blocks), then the same with KLD
    units = [(r, m, k) for k in ((False, True) if cfg.kld_rows else (False,))
             for r in range(cfg.runs) for m in cfg.models]
    st = None

    def left():  # process 0 only: open the store, list the units not yet written
        nonlocal st
        # "kld" is not guarded: a directory from before the KLD rows keeps its five-algorithm
        # units (unchanged by this option); each KLD unit records its settings (_check_kld)
        st = Store.open(out, NAME, c, selection=("kld",), fresh=fresh)
        return [_read(st, c, *u) is None for u in units]

    try:
        mask = distributed.decide(cluster, len(units), left)
        todo = [u for u, m in zip(units, mask, strict=True) if m]
        for i, rec in tqdm(distributed.map_units(lambda u: run_unit(u[0], u[1], c, kld=u[2]),
                                                 todo, cluster, codec="json"),
                           total=len(todo), desc=NAME, unit="unit",
                           disable=quiet or not cluster.is_main):
            if st is not None:
                st.write_json(_unit_name(*todo[i]), rec)  # atomic
        if st is None:
            return
        both = {u: _read(st, c, *u) for u in units}
        if any(v is None for v in both.values()):
            raise StudyError(f"{NAME}: a unit did not read back as written")
        data = {(r, m): v for (r, m, k), v in both.items() if not k}
        kdata = {(r, m): v for (r, m, k), v in both.items() if k} or None
        if cfg.equal_budget:  # process 0 alone (the budgets come from the stored KLD units)
            for r in range(cfg.runs):
                for m in cfg.models:
                    budget = equal_budget(kdata[(r, m)])
                    if _read_eq(st, c, r, m, budget) is None:
                        st.write_json(_unit_name(r, m, True, True),
                                      run_unit(r, m, c, kld=True, budget=budget))
        st.write_results_csv(
            [(f"run{r}_{m}_{meth}", "mean_best_likelihood", float(np.mean(data[(r, m)][meth])))
             for r in range(cfg.runs) for m in cfg.models for meth in METHODS]
            + [(f"run{r}_{m}_{meth}_kld", q, float(np.mean(kdata[(r, m)][meth + suffix])))
               for r in range(cfg.runs) for m in cfg.models for meth in METHODS
               for q, suffix in (("mean_best_likelihood", ""), ("mean_particles", "_n"))
               if kdata])
    finally:
        if st is not None:
            st.close()


def _load(out: Path) -> tuple[dict, dict, dict | None, dict | None]:
    """(stored config, full-block units, KLD units or None, equal-budget units or None) of
    ``out``: the KLD and equal-budget rows when every one of their units is stored."""
    with Store.open(out, NAME, None) as st:
        c = st.config
        keys = [(r, m) for r in range(c["runs"]) for m in c["models"]]
        data = {u: _read(st, c, *u, False) for u in keys}
        if any(v is None for v in data.values()):
            raise StudyError(f"{out} holds no finished {NAME} results; run the study first")
        kdata = {u: _read(st, c, *u, True) for u in keys}
        kdata = kdata if all(v is not None for v in kdata.values()) else None
        edata = None
        if kdata:
            edata = {u: _read_eq(st, c, *u, equal_budget(kdata[u])) for u in keys}
            edata = edata if all(v is not None for v in edata.values()) else None
    return c, data, kdata, edata


def _claims(data: dict) -> list[protocol.Claim]:
    verdicts = {"yes": protocol.MATCH, "no": protocol.MISMATCH}
    return [protocol.Claim(text, "holds (B Table 4.2)", nums, None,
                           verdicts.get(v, f"{protocol.MISMATCH}: {v}"))
            for text, v, nums in orderings(data)]


def claims(out: Path) -> list[protocol.Claim]:
    """B's published orderings (Table 4.2) on the full-block units: mean paired difference
    over the steps, held when every difference is > 0 with p < 0.01."""
    return _claims(_load(Path(out))[1])


def report(out: Path) -> Path:
    """``report.md`` and ``best_likelihood.png`` from the stored units (with the KLD and
    equal-budget rows when they are stored)."""
    out = Path(out)
    c, data, kdata, edata = _load(out)
    _report(data, c, out, kdata, edata)
    return out / "report.md"


sweep_summary = protocol.summary_for(sys.modules[__name__])
main = protocol.main_for(sys.modules[__name__])


def table(data: dict, model: str) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Table 4.2 layout: mean (run-1 row method − run-2 column method) and paired-t p-values."""
    from scipy import stats

    from ..hssh.localization import METHODS

    a = np.array([data[(0, model)][m] for m in METHODS])
    b = np.array([data[(1, model)][m] for m in METHODS])
    k = len(METHODS)
    mean = np.zeros((k, k))
    p = np.ones((k, k))
    for i in range(k):
        for j in range(k):
            d = a[i] - b[j]
            mean[i, j] = d.mean()
            if np.any(d != d[0]):
                p[i, j] = stats.ttest_rel(a[i], b[j]).pvalue
    return mean, p, list(METHODS)


def _verdict(pairs) -> str:
    """'yes' if every difference is > 0 with p < 0.01, 'no' if one is < 0 with p < 0.01,
    else 'tie (n.s.)'."""
    if all(d > 0 and p < 0.01 for d, p in pairs):
        return "yes"
    if any(d < 0 and p < 0.01 for d, p in pairs):
        return "no"
    return "tie (n.s.)"


def orderings(data: dict) -> list[tuple[str, str, str]]:
    """B's published orderings: (ordering, verdict here, the numbers)."""
    checks = []
    idx = {m: i for i, m in enumerate(table(data, "large")[2])}

    def diff(model, x, y):
        mean, p, _ = table(data, model)
        return mean[idx[x], idx[y]], p[idx[x], idx[y]]

    for model in MODELS:
        d, p = diff(model, "shrink", "pf")
        checks.append((f"shrink beats PF ({model})", _verdict([(d, p)]), f"{d:+.4f} (p={p:.2g})"))
    d, p = diff("large", "shrink", "grow")
    checks.append(("shrink beats grow (large)", _verdict([(d, p)]), f"{d:+.4f} (p={p:.2g})"))
    d, p = diff("small", "grow", "shrink")
    checks.append(("grow beats shrink (small)", _verdict([(d, p)]), f"{d:+.4f} (p={p:.2g})"))
    for model in MODELS:
        ds = [diff(model, "shrink_and_grow", o) for o in ("raw", "pf", "shrink", "grow")]
        checks.append((f"shrink-and-grow best ({model})", _verdict(ds),
                       ", ".join(f"{x:+.4f} (p={q:.2g})" for x, q in ds)
                       + " vs raw/pf/shrink/grow"))
    return checks


def kld_effect(data: dict, kdata: dict, model: str) -> list[tuple[str, float, float, float,
                                                                    float, float]]:
    """Per method: (name, mean best likelihood with full blocks, with KLD, paired mean
    difference KLD − full over the steps of both runs, its paired-t p-value, mean particles
    scored with KLD)."""
    from scipy import stats

    from ..hssh.localization import METHODS

    rows = []
    for m in METHODS:
        a = np.concatenate([data[(r, model)][m] for r in range(2)])
        b = np.concatenate([kdata[(r, model)][m] for r in range(2)])
        d = b - a
        p = float(stats.ttest_rel(b, a).pvalue) if np.any(d != d[0]) else 1.0
        n = np.concatenate([kdata[(r, model)][f"{m}_n"] for r in range(2)])
        rows.append((m, float(a.mean()), float(b.mean()), float(d.mean()), p, float(n.mean())))
    return rows


def _report(data, cfg, out: Path, kdata: dict | None = None,
            edata: dict | None = None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lines = ["# hssh-localization: adaptive proposals x action models (B §4.3.2, Table 4.2)", "",
             "B's robot log is not available: this is a simulation (see the module docstring "
             "and `config.json`), so orderings are compared, not values.", "",
             f"{cfg['steps']} steps per run, 2 runs, {cfg['blocks']} x {cfg['block']} particles.",
             ""]
    for model in MODELS:
        mean, p, names = table(data, model)
        lines += [f"## {model}", "", "| run 1 \\ run 2 | " + " | ".join(names) + " |",
                  "|---" * (len(names) + 1) + "|"]
        for i, n in enumerate(names):
            cells = [f"{mean[i, j]:+.3f}{'*' if p[i, j] < 0.01 else ''}"
                     for j in range(len(names))]
            lines.append(f"| {n} | " + " | ".join(cells) + " |")
        lines.append("")
    lines += ["## Published orderings", "", *protocol.claims_table(_claims(data))]
    if kdata:
        k = cfg["kld"]
        lines += ["", "## KLD-sampling on every filter (Fox 2003; extra rows, `--kld`)", "",
                  "B runs all its filters with KLD-sampling (confidence "
                  f"{k['confidence']}, error {k['epsilon']}, bins {k['bin_size']}; "
                  f"`n_min` = {k['n_min']} is this library's choice). Same keys and log as "
                  "the full-block rows above, which are unchanged; each proposal block is "
                  "cut to the first n particles that meet Fox's bound. Particle budget "
                  f"without KLD: up to {cfg['blocks'] * cfg['block']}.", ""]
        for model in MODELS:
            lines += [f"### {model}", "", "| method | full blocks | KLD | KLD − full | "
                      "mean particles (KLD) |", "|---|---|---|---|---|"]
            for m, a, b, d, p, n in kld_effect(data, kdata, model):
                lines.append(f"| {m} | {a:.4f} | {b:.4f} | {d:+.4f}"
                             f"{'*' if p < 0.01 else ''} (p={p:.2g}) | {n:.1f} |")
            lines.append("")
        lines += ["Published orderings with KLD-sampling on:", "",
                  "| ordering (B) | holds here (KLD) | numbers |", "|---|---|---|"]
        for text, verdict, nums in orderings(kdata):
            lines.append(f"| {text} | {verdict} | {nums} |")
    if edata:
        lines += ["", "## KLD at an equal particle budget (`--equal-budget`, issue 26)", "",
                  "KLD cuts each proposal separately, so shrink scores about twice PF's "
                  "particles and shrink-and-grow more again. Here every filter keeps KLD but "
                  "scores at most, per step, the fewest particles any of PF, shrink, grow and "
                  "shrink-and-grow scored there with KLD (the first in draw order; refits use "
                  "only those). Same keys and log.", "",
                  "| model | mean budget | " + " | ".join(f"{m} (particles)" for m in BUDGETED)
                  + " |", "|---" * (len(BUDGETED) + 2) + "|"]
        for model in MODELS:
            b = np.concatenate([edata[(r, model)]["budget"] for r in range(2)])
            def both(key, model=model):
                return np.mean(np.concatenate([edata[(r, model)][key] for r in range(2)]))

            cells = [f"{both(m):.4f} ({both(m + '_n'):.1f})" for m in BUDGETED]
            lines.append(f"| {model} | {b.mean():.1f} | " + " | ".join(cells) + " |")
        lines += ["", "Published orderings, KLD at an equal budget:", "",
                  "| ordering (B) | holds here (equal budget) | numbers |", "|---|---|---|"]
        for text, verdict, nums in orderings(edata):
            lines.append(f"| {text} | {verdict} | {nums} |")
    lines += ["", "Mechanisms: grow and shrink-and-grow stop at the first stage with a particle "
              f"above the threshold ({cfg['threshold']}, x{cfg['anneal']} per stage), so grow "
              "often spends 100 of the 500 particles; shrink-and-grow then spends the rest on "
              "the fitted Gaussian. With an overestimating model the proposal already covers "
              "the truth and the extra spread of grow wastes particles; with an "
              "underestimating one only growing reaches the truth. Shrink vs PF: the "
              "likelihood field saturates near the best pose (1-cell sigma), so 500 proposal "
              "particles already find it and the Gaussian refit adds nothing measurable; B's "
              "Konolige likelihood on 5 cm cells is far more peaked than its proposals.", "",
              *protocol.figure("best_likelihood.png", "Mean best scan likelihood (between 0 and 1, "
                               "over the steps of both runs) of each algorithm, one bar per "
                               "action model: large (overestimates the noise), small "
                               "(underestimates it) and fitted (the robot's own).")]
    atomic_write_text(out / "report.md", "\n".join(lines) + "\n")
    fig, ax = plt.subplots(figsize=(7, 3.5))
    names = table(data, "large")[2]
    for i, model in enumerate(MODELS):
        vals = [np.mean(data[(0, model)][m] + data[(1, model)][m]) for m in names]
        ax.bar(np.arange(len(names)) + 0.27 * (i - 1), vals, 0.27, label=model)
    ax.set_xticks(range(len(names)), names)
    ax.set_ylabel("mean best likelihood")
    ax.legend()
    fig.tight_layout()
    atomic_savefig(fig, out / "best_likelihood.png", dpi=110)
    plt.close(fig)
