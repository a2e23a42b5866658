"""Qualitative BSP with and without compositions: the study of Z §4.3 (Table 4.1, Figs. 4.5–4.6).

``pqrm-jax study qbsp --out DIR [--reduced | --tiny] [--envs N] [--size S] [--chunk C]``

The study protocol of :mod:`pqrm_jax.studies.protocol` (``Config``, ``PRESETS``,
``configure``, ``run_study``, ``report``, ``claims``; the common flags incl. ``--chunk``;
``--sweep``); :func:`config_for` turns a :class:`Config` into the stored configuration (every
parameter and decision).

Random environments of 8–12 landmarks (units of R), a composable initial belief by
nearest-landmark growth, a random target triplet of the initial belief; every environment is
run four times (cost eq. 4.29 / eq. 4.30 × without / with compositions) with receding-horizon
execution in the simulator (``pqrm_jax.bsp``). The four tests of an environment share their
random numbers (common random numbers: paired comparisons).

Calibration (the one declared knob, docs/bsp.md §calibration): unless ``--eps`` is given, the
observability threshold ``eps_obs`` (a candidate triplet counts as observable from a frame when
the predicted probability of seeing it from the best robot state is at least ``eps_obs``) is
chosen from a grid on a separate calibration seed so that the *with-composition* plan-exists
rate is closest to the published 81.6 %; every other published number is then a held-out
prediction on fresh environments. The first plan made S/R the knob; under the
nearest-landmark-growth generator (every initial triplet has its minimum enclosing circle
within R) the plan-exists rates do not move with S/R (measured: 0.85 / 1.00 at S/R = 2.5, 3.5
and 4.5, 40 environments, eps_obs = 0.01), so S/R is fixed at 2.5 and the threshold, which
decides how far an uncertain composed triplet is trusted, is the knob instead. Plan
existence is decided at the first planning session by the frame graph (topology +
observability) and so needs no execution, which keeps the calibration cheap.

Outputs in ``DIR``, kept by the shared study store (:mod:`pqrm_jax.studies.store`: a lock
refuses a second process on the same ``--out``, ``study.json`` marks the directory as a qbsp
study, every file is written atomically): ``config.json`` (every parameter and decision, the
precision and the lane layout), ``calibration.json`` (the chosen ``eps_obs`` and the grid
rates), ``environments.jsonl`` (landmarks, initial-belief triplets, target, frame, start),
``chunks/env*.json`` (one checked record per environment, the resume unit: a torn or garbage one
is named in a warning, set aside and recomputed alone), ``tests.csv`` (one row per test),
``results.json``, ``timing.json`` (the measured times), the tidy ``results.csv`` (``study, unit,
metric, value``: one row per test × number and the Table 4.1 summary), ``report.md`` (published
vs measured with 95 % intervals and match/mismatch), figures ``*.png``. Discrete outcomes do not
depend on ``--chunk`` or the device count, but float costs may differ at rounding, so both are
part of the stored config (a resume with another layout is refused). A model or table cache that
cannot be read fails the study with a :class:`~pqrm_jax.studies.store.StudyError`.

As N processes on ``jax.distributed`` (``--coordinator/--processes/--process-id``, the
environment or Slurm; :mod:`pqrm_jax.studies.distributed`) process ``p`` computes the
calibration blocks (:data:`CALIB_BLOCK` environments) and the environment chunks ``≡ p (mod N)``
whole, on its own devices;
the answers are gathered and process 0 alone reads and writes the store, so the files are
bit-identical to one process (which is why the process count is not part of the config).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from . import distributed, protocol
from .store import Store, StudyError, flatten_metrics, tidy_rows

NAME = "qbsp"
HELP = "qualitative BSP with/without compositions (Z §4.3, Table 4.1, Figs. 4.5-4.6)"

PUBLISHED = {"exists_without": 0.684, "exists_with": 0.816, "comparable_different": 0.13,
             "cost1_without": 6.45, "cost1_with": 4.97, "cost2_without": 2.76,
             "cost2_with": 2.32}

DECISIONS = {
    "Z-1": "scale bins [(s-1)2R/nF, s 2R/nF), last bin [2R, inf) (sampled on [2R, 3R])",
    "Z-3": "Q actions 'go to state j' (target point = most-eroded grid point of the state in "
           "a 1.5-frame-unit box around the frame midpoint); n_actions kept per node by a "
           "one-step proxy c + E_beta min h",
    "Z-5": "discrete measurement z = (robot state, triplet state) from one noisy measurement",
    "Z-6": "z sampled from P(z|beta,a), plain average (n_z = 1)",
    "Z-7": "eta divides (normalisation)",
    "Z-8": "association and measurement condition on the scale of F_{t-1}",
    "Z-9": "frame scale = reference scale x |X1 - X2| (tables G2, GA, GB)",
    "Z-10": "reference = F_1's true scale bin (one-hot); scale_model 'composed' (default): "
            "the missing S^L_AB scale rows are composed (Z 4.2.5 eq. 4.24 with 4.2.6) in both "
            "modes, so both modes derive the same frame scales and 'without compositions' "
            "changes only the candidate set; 'belief' (the previous model): scales from the "
            "mode's own rows, pairs inside a measured triplet keep their measured-only scale; "
            "fallback uniform over observable bins for pairs in a known triplet, over all bins "
            "otherwise",
    "Z-11": "expectimax tree: min over actions, expectation over beta and z, min over links; "
            "goal branch terminal; leaf h = cbar (1 + rho) (hops + 1) with rho = 10 (each "
            "remaining link costs ten mean steps: progress first, cost second; rho = 0 made "
            "the cost-1 planner dither), lambda = 1e5 cbar without a path",
    "Z-12": "map frozen during lookahead",
    "Z-13": "cost 1 uses the EDC neighbour distance with edges and corners as neighbours "
            "(P §2.3.1; docs/decisions.md §2.1)",
    "Z-14": "cost 2 literal: D2[s,s] > 0; mid(last bin) = 2R",
    "Z-15": "comparable = plan exists in both modes and both executions reach the goal; "
            "different = executed (frame, action) sequences differ; share of all tests, "
            "per cost (also share of comparable)",
    "Z-16": "success = the three goal landmarks visible at once",
    "Z-17": "executed costs are ground truth from the simulator; cost 2 in units of R; "
            "compare with/without ratios",
    "Z-24": "beta weights renormalised over the kept candidates",
    "Z-25": "one minimal tree per composed triplet, product of marginals",
    "Z-26": "controller: move to the target point + N(0, sigma_m^2)",
    "compositions": "composed once per episode (initial session); measured rows updated by "
                    "PQRM during execution",
    "observability": "candidate observable iff max_sx P(beta | sx) >= eps_obs",
    "target": "uniform over initial-belief triplets not containing F_1",
    "link_rule": "at execution: among observed candidates the link whose frame has the "
                 "smallest leaf value (goal first, ties keep the frame)",
}


#: Extensions beyond the thesis's model, each off by default (the default study is Z's model
#: and its config.json has no such key); ``--nondetection`` / ``--nothing-seen`` add theirs
#: to ``config["extensions"]`` with the reason.
EXTENSIONS = {
    "nondetection": "EXTENSION beyond Z (off by default, an ablation): after each move the "
                    "rows ij:k and ji:k of the frame's candidates that were not seen get "
                    "P(s_tau) * sum_{s_x,b} P(s_x) P_F(b) (1 - A[s_x, s_tau, b]) "
                    "(negative information with the association model, Z eq. 4.12). "
                    "Reason: in Z's psi not seeing a candidate gives no evidence, and "
                    "most failed executions never leave the first frame, repeating one "
                    "action (docs/bsp.md §execution-failures, §non-detection)",
    "nothing_seen": "EXTENSION beyond Z (off by default, an ablation): the planner's "
                    "expectation over candidates gets a 'nothing seen' branch of weight "
                    "1 - min(1, sum_beta P(beta | a)) valued as staying (h(F) + cbar), "
                    "instead of renormalising the kept candidates' weights to 1 (Z-24, "
                    "eq. 4.14). Reason: with renormalisation an action that sees a "
                    "candidate with probability 0.01 is valued as if it saw it surely, so "
                    "the cheapest such action is repeated (docs/bsp.md §nothing-seen)",
}


def _extensions(cfg) -> dict:
    on = [k for k in EXTENSIONS if getattr(cfg, k, False)]
    return {"extensions": {k: EXTENSIONS[k] for k in on}} if on else {}


@dataclasses.dataclass(frozen=True)
class Config:
    """The study's settings (the full study by default; :data:`PRESETS` for the others).

    :func:`config_for` expands it into the stored configuration (every parameter and
    decision with its reason, :data:`DECISIONS`, :data:`EXTENSIONS`).
    """

    envs: int = 3000  # environments of the held-out tests (Z: not stated; 3000 → ±1.5 %)
    calib_envs: int = 300  # environments of the calibration seed
    samples: int = 4000  # model samples per cell of the observation models
    depth: int = 2  # planner depth L (receding horizon)
    t_max: int = 12  # planning sessions per execution before it counts as a failure
    seed: int = 2022  # root seed: tests on seed, calibration on seed + 10000, sweep + 20000
    eps: float | None = None  # eps_obs fixed by --eps (no calibration); None: calibrated
    size: float = 2.5  # environment size S/R (docs/bsp.md §calibration: not the knob)
    models_pool: int = 1 << 20  # sample pool of the observation models
    models_seed: int = 0  # seed of the observation models
    sweep_envs: int = 200  # environments per size of the plan-exists sweep
    sweep_sizes: tuple[float, ...] = (1.5, 2.5, 3.5, 5.0)  # S/R of the sweep
    sweep_depths: tuple[int, ...] = (1, 2, 3)  # planner depths L of the sweep
    nondetection: bool = False  # EXTENSIONS["nondetection"] (ablation, off)
    nothing_seen: bool = False  # EXTENSIONS["nothing_seen"] (ablation, off)
    scale_model: str = "composed"  # docs/bsp.md §Z-10
    on_no_plan: str = "continue"  # docs/bsp.md §execution
    chunk: int | None = None  # environments per call (None: sized from the memory)

    def to_json(self) -> dict:
        """The stored configuration (:func:`config_for`)."""
        return config_for(self)


PRESETS: dict[str, dict[str, Any]] = {
    "tiny": {"envs": 8, "calib_envs": 8, "samples": 600, "depth": 1, "t_max": 4,
             "models_pool": 1 << 18, "models_seed": 3, "sweep_envs": 4,
             "sweep_sizes": (2.5, 4.0), "sweep_depths": (1,)},  # the tests' models
    "reduced": {"envs": 300, "calib_envs": 100, "samples": 2000, "sweep_envs": 60},
    "full": {},
}


def config_for(cfg: Config) -> dict:
    """The study configuration (every parameter; calibration filled in later)."""
    return {
        "envs": cfg.envs, "calib_envs": cfg.calib_envs, "landmarks": [8, 12],
        "seed": cfg.seed, "calib_seed": cfg.seed + 10_000,
        "eps_grid": [0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45, 0.5], "eps_fixed": cfg.eps,
        "size": cfg.size,
        "R": 1.0, "r_min": 0.05, "L_max": 12,
        "models": {"calculus": "edc", "n_f": 5, "window": 3.0, "sigma_m": 0.05,
                   "sigma_z": 0.05, "r_min": 0.05, "samples": cfg.samples,
                   "pool": cfg.models_pool, "seed": cfg.models_seed,
                   "target_half_width": 1.5},
        "planner": {"depth": cfg.depth, "n_actions": 4, "n_beta": 3, "lam": 1.0e5, "rho": 10.0,
                    "n_z": 1},
        "execution": {"t_max": cfg.t_max, "sigma_m": 0.05, "sigma_z": 0.05,
                      "pqrm_samples": 64, "eps_obs": 0.01,
                      # a later session's "no plan" does not end the lane (measured,
                      # docs/bsp.md §execution)
                      "on_no_plan": cfg.on_no_plan},
        "initial_measurement_samples": 256,
        # how frame scales are derived (docs/bsp.md §Z-10): "composed" in both modes
        # (default) or "belief" (the mode's own rows; the previous model)
        "scale_model": cfg.scale_model,
        # plan exists vs S/R and vs the depth L (no execution; own seed, docs/bsp.md §sweep)
        "sweep": {"seed": cfg.seed + 20_000, "envs": cfg.sweep_envs,
                  "sizes": list(cfg.sweep_sizes), "depths": list(cfg.sweep_depths)},
        "chunk": cfg.chunk,
        "decisions": DECISIONS,
        "published": PUBLISHED,
    } | _extensions(cfg)


def _probability(raw: str) -> float:
    """A probability in [0, 1] (argparse type of ``--eps``)."""
    v = protocol.finite_float(raw)
    if not 0.0 <= v <= 1.0:
        raise argparse.ArgumentTypeError(f"must be a probability in [0, 1] (the "
                                         f"observability threshold eps_obs), got {raw!r}")
    return v


def configure(argv: list[str], overrides: dict | None = None
              ) -> tuple[Config, argparse.Namespace]:
    """The study's Config and parsed flags (every number checked before any work)."""
    ap = protocol.parser(NAME, HELP, seed=Config.seed, chunk=True)
    ap.add_argument("--envs", type=protocol.positive_int,
                    help="environments (default 3000; reduced 300; tiny 8)")
    ap.add_argument("--memory-bytes", type=protocol.positive_int,
                    help="device memory the automatic chunk is sized for and checked against "
                         "(default: what the device reports)")
    ap.add_argument("--depth", type=protocol.positive_int,
                    help="planner depth L (≥ 1; L = 0 plans nothing)")
    ap.add_argument("--samples", type=protocol.positive_int, help="model samples per cell")
    ap.add_argument("--size", type=protocol.positive_float, help="environment size S/R "
                    "(default 2.5)")
    ap.add_argument("--eps", type=_probability, help="fix eps_obs (no calibration)")
    ap.add_argument("--nondetection", action="store_true", default=None,
                    help="EXTENSION beyond the thesis (ablation): negative-information update "
                         "of candidates not seen (docs/bsp.md §non-detection)")
    ap.add_argument("--nothing-seen", dest="nothing_seen", action="store_true", default=None,
                    help="EXTENSION beyond the thesis (ablation): a 'nothing seen' branch "
                         "in the planner instead of renormalised candidate weights "
                         "(docs/bsp.md §nothing-seen)")
    ap.add_argument("--scale-model", dest="scale_model", choices=("composed", "belief"),
                    help="frame scales from measured and composed rows in both modes "
                         "(default composed) or from each mode's own belief (the previous "
                         "model; docs/bsp.md §Z-10)")
    ap.add_argument("--on-no-plan", dest="on_no_plan", choices=("stop", "continue"),
                    help="after a later session's 'no plan' the lane goes on (default "
                         "continue) or ends as a failure (the previous rule; docs/bsp.md "
                         "§execution)")
    ap.add_argument("--models-dir", type=Path, help="model cache directory")
    a = ap.parse_args(argv)
    a.chunk = a.chunk or None
    flags = {k: k for k in ("envs", "depth", "samples", "size", "eps", "nondetection",
                            "nothing_seen", "scale_model", "on_no_plan", "chunk")}
    cfg = protocol.apply_preset(Config, PRESETS, a.preset, a, flags, overrides)
    if "seed" not in (overrides or {}):
        cfg = dataclasses.replace(cfg, seed=a.seed)
    o = set(overrides or {})
    for key, v, lo in (("envs", cfg.envs, 1), ("calib_envs", cfg.calib_envs, 1),
                       ("depth", cfg.depth, 1), ("samples", cfg.samples, 1),
                       ("t_max", cfg.t_max, 1), ("sweep_envs", cfg.sweep_envs, 1),
                       ("chunk", cfg.chunk or 1, 1), ("models_pool", cfg.models_pool, 1),
                       ("seed", cfg.seed, 0)):
        if v < lo:
            ap.error(f"argument {key if key in o else '--' + key}: must be an integer ≥ {lo}, "
                     f"got {v}")
    if not (np.isfinite(cfg.size) and cfg.size > 0):
        ap.error(f"argument --size: must be a positive, finite S/R, got {cfg.size}")
    if cfg.eps is not None and not (np.isfinite(cfg.eps) and 0.0 <= cfg.eps <= 1.0):
        ap.error(f"argument --eps: must be a probability in [0, 1] (the observability "
                 f"threshold eps_obs), got {cfg.eps}")
    if not cfg.sweep_sizes or not all(np.isfinite(x) and x > 0 for x in cfg.sweep_sizes):
        ap.error(f"sweep_sizes must be positive, finite S/R, got {list(cfg.sweep_sizes)}")
    if not cfg.sweep_depths or min(cfg.sweep_depths) < 1:
        ap.error(f"sweep_depths must be depths ≥ 1, got {list(cfg.sweep_depths)}")
    if cfg.scale_model not in ("composed", "belief"):
        ap.error(f"scale_model must be composed or belief, got {cfg.scale_model!r}")
    if cfg.on_no_plan not in ("stop", "continue"):
        ap.error(f"on_no_plan must be stop or continue, got {cfg.on_no_plan!r}")
    full = config_for(cfg)
    try:  # a size too small for the landmarks at their minimum spacing: refused up front
        make_env(full, full["calib_seed"], 0, full["size"])
    except RuntimeError as exc:
        ap.error(f"argument --size: {cfg.size} is too small for {full['landmarks']} landmarks "
                 f"{full['r_min']} R apart ({exc})")
    return cfg, a


def _env_rng(seed: int, e: int) -> np.random.Generator:
    return np.random.default_rng([seed, e])


def make_env(cfg: dict, seed: int, e: int, size: float):
    from ..bsp import env as E

    rng = _env_rng(seed, e)
    n = int(rng.integers(cfg["landmarks"][0], cfg["landmarks"][1] + 1))
    return E.generate(rng, n, size, r_min=cfg["r_min"], R=cfg["R"])


def calibrate(cfg: dict, models, progress: bool, cluster=None) -> tuple[float, dict]:
    """Choose eps_obs on the calibration seed (with-composition plan-exists rate vs 81.6 %).

    The environments go in blocks of :data:`CALIB_BLOCK` (one compiled call each: batched
    initial beliefs, ``plans_exist`` per threshold). With a multi-process ``cluster`` process
    ``p`` of ``K`` computes the blocks ``≡ p (mod K)`` and the answers are gathered: the same
    result on every process.
    """
    import jax
    import jax.numpy as jnp
    from tqdm.auto import tqdm

    from ..bsp import graph as G

    cluster = cluster or distributed.Cluster(0, 1, None)
    n, grid = cfg["calib_envs"], cfg["eps_grid"]
    bar = tqdm(total=n, desc="qbsp calibration", disable=not progress)
    blocks = -(-n // CALIB_BLOCK)

    def plan_exists(u: int) -> np.ndarray:  # [CALIB_BLOCK, grid] int8: a plan exists at eps
        ids = list(range(u * CALIB_BLOCK, min(n, (u + 1) * CALIB_BLOCK)))
        envs = [make_env(cfg, cfg["calib_seed"], e, cfg["size"]) for e in ids]
        b = _beliefs(cfg, models, envs, [jax.random.key(e) for e in ids], ("with",))["with"]
        goals = jnp.asarray([env.goal for env in envs], jnp.int32)
        ok = np.stack([np.asarray(G.plans_exist(models, b, goals, float(x))) for x in grid], 1)
        out = np.zeros((CALIB_BLOCK, len(grid)), np.int8)  # equal shapes for map_chunks
        out[:len(ids)] = ok
        return out

    ok = np.concatenate(distributed.map_chunks(
        plan_exists, blocks, cluster,
        done=lambda u, _: bar.update(min(n, (u + 1) * CALIB_BLOCK) - u * CALIB_BLOCK)))[:n]
    bar.close()
    rates = {str(x): float(np.mean(ok[:n, c])) for c, x in enumerate(grid)}
    best = min(cfg["eps_grid"], key=lambda x: abs(rates[str(x)] - PUBLISHED["exists_with"]))
    return float(best), rates


def sweep(cfg: dict, models, D1, eps: float, progress: bool) -> dict:
    """Plan exists vs S/R (frame graph) and vs the depth L (tree root < λ), both modes.

    Environments on the sweep seed (``cfg["sweep"]``), ``eps_obs`` = the study's. Existence
    by the frame graph does not involve L; the tree's existence is measured at each depth on
    the ``cfg["size"]`` environments (it equals the graph's by construction, §plan-exists: a
    figure of the check, not of a dependence).
    """
    import jax
    import jax.numpy as jnp
    from tqdm.auto import tqdm

    from ..bsp import graph as G
    from ..bsp import planner as P
    from ..bsp.env import MODES

    sw = cfg["sweep"]
    sizes = sorted(set(sw["sizes"]) | {cfg["size"]})
    out = {"sizes": sizes, "depths": sw["depths"], "eps_obs": eps, "envs": sw["envs"],
           "exists": {m: {} for m in ("without", "with")},
           "tree_exists": {m: {} for m in ("without", "with")}}
    pps = {d: P.PlannerParams(depth=d, n_actions=cfg["planner"]["n_actions"],
                              n_beta=cfg["planner"]["n_beta"], lam=cfg["planner"]["lam"],
                              rho=cfg["planner"]["rho"],
                              nothing_seen="nothing_seen" in cfg.get("extensions", {}))
           for d in sw["depths"]}
    bar = tqdm(total=len(sizes) * sw["envs"], desc="qbsp sweep", disable=not progress)
    topo: dict[str, list] = {m: [] for m in MODES}
    for size in sizes:
        envs = [make_env(cfg, sw["seed"], e, size) for e in range(sw["envs"])]
        keys = [jax.random.key(e) for e in range(sw["envs"])]
        goals = jnp.asarray([env.goal for env in envs], jnp.int32)
        bels = _beliefs(cfg, models, envs, keys, MODES)
        for mode in MODES:
            b = bels[mode]
            ok = np.asarray(G.plans_exist(models, b, goals, float(eps)))
            out["exists"][mode][str(size)] = float(np.mean(ok))
            if size == cfg["size"]:  # the topological reading: every candidate observable
                topo[mode] = np.asarray(G.plans_exist(models, b, goals, 0.0)).tolist()
                out["tree_exists"][mode] = {
                    str(d): float(np.mean(np.asarray(P.trees_exist(jnp.stack(keys), models, D1,
                                                                   b, goals, float(eps), pp))))
                    for d, pp in pps.items()}
        bar.update(sw["envs"])
    bar.close()
    out["topological"] = {"envs": sw["envs"], "size": cfg["size"],
                          **{m: float(np.mean(v)) for m, v in topo.items()}}
    return out


CALIB_BLOCK = 50  # calibration environments per compiled call (and per distributed unit)


def _beliefs(cfg: dict, models, envs: list, keys: list, modes: tuple[str, ...]) -> dict:
    """The initial beliefs of ``envs`` (one PRNG key each) in ``modes``, batched
    (:func:`~pqrm_jax.bsp.env.initial_beliefs` with the study's settings)."""
    import jax.numpy as jnp

    from ..bsp import env as E

    return E.initial_beliefs(jnp.stack(keys), models, envs, modes=modes, L_max=cfg["L_max"],
                             sigma_z=cfg["execution"]["sigma_z"],
                             samples=cfg["initial_measurement_samples"],
                             scale_model=cfg["scale_model"])


def shard_lanes(tree):
    """Place the lane axis of every array of ``tree`` across all devices (1-D mesh "lanes").

    With one device, or a lane count not divisible by the device count, ``tree`` is returned
    unchanged. Every lane is computed independently, so results do not depend on this.
    """
    import jax
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    devs = jax.local_devices()  # per process: a multi-process run splits whole chunks
    n = jax.tree.leaves(tree)[0].shape[0]
    if lane_devices(n) < 2:
        return tree
    sh = NamedSharding(Mesh(np.array(devs), ("lanes",)), PartitionSpec("lanes"))
    return jax.device_put(tree, sh)


def lane_devices(n_lanes: int) -> int:
    """How many devices :func:`shard_lanes` spreads ``n_lanes`` lanes over (1: not sharded)."""
    import jax

    d = len(jax.local_devices())
    return 1 if d < 2 or n_lanes % d else d


COMBO_ORDER = [(m, c) for m in ("without", "with") for c in (1, 2)]  # lane blocks of a chunk


def run_chunk(cfg: dict, models, D1, envs: list, ids: list[int], size: float) -> list[dict]:
    """Run the four tests of each environment in ``envs`` (padded to the chunk width)."""
    out, dt = run_chunk_arrays(cfg, models, D1, envs, ids)
    return chunk_rows(out, dt, envs, ids)


def run_chunk_arrays(cfg: dict, models, D1, envs: list, ids: list[int],
                     memory_bytes: int | None = None):
    """The batched :func:`~pqrm_jax.bsp.execute.run_lanes` of the four tests of each
    environment in ``envs`` (padded to the chunk width): (numpy Outcome, seconds).

    The program is compiled ahead of time and refused before it runs, naming ``--chunk``,
    when it needs more than :data:`~pqrm_jax.studies.chunking.FRACTION` of ``memory_bytes``
    (default: what the device has available)."""
    import jax

    from . import chunking

    lanes, pp, ep = _chunk_lanes(cfg, models, envs, ids)
    compiled = chunk_program(cfg, models, D1, lanes, pp, ep)
    chunking.check_fits(chunking.program_bytes(compiled), chunking.budget(memory_bytes),
                        option="--chunk",
                        what=f"{NAME}: a chunk of {cfg['chunk']} environments "
                             f"({4 * cfg['chunk']} lanes)")
    t0 = time.perf_counter()
    out = jax.device_get(compiled(lanes[0], models, D1, lanes[1]))
    dt = time.perf_counter() - t0
    return tuple(np.asarray(x) for x in out), dt


_AOT: dict = {}  # compiled run_lanes per (models key, lane layout, static params)


def chunk_program(cfg: dict, models, D1, lanes, pp, ep):
    """:func:`~pqrm_jax.bsp.execute.run_lanes` compiled ahead of time for these lanes
    (cached per models key and layout): its XLA memory analysis sizes and checks the chunk."""
    from ..bsp import execute as X

    n = int(lanes[0].shape[0])
    key = (cfg["models_key"], n, lane_devices(n), pp, ep)
    if key not in _AOT:
        if len(_AOT) > 4:
            _AOT.clear()
        _AOT[key] = X.run_lanes.lower(lanes[0], models, D1, lanes[1], pp, ep).compile()
    return _AOT[key]


def auto_chunk(cfg: dict, models, D1, memory_bytes: int | None = None) -> int:
    """Environments per call sized from the device memory (docs/studies.md §qbsp).

    :func:`~pqrm_jax.studies.chunking.auto` with the compiled program of one environment as
    the probe (its four lanes split over the devices; XLA's memory analysis, its fixed part
    counted for every environment): the largest power of two per device that fits, capped at
    ``cfg["envs"]``, the calls then evened out (:func:`~pqrm_jax.studies.chunking.balance`).
    Without memory figures: :data:`~pqrm_jax.studies.chunking.FALLBACK_CHUNK`.
    """
    import copy

    import jax

    from . import chunking

    def probe() -> int | None:
        one = copy.deepcopy(cfg)
        one["chunk"] = 1
        one["execution"].setdefault("eps_obs", 0.01)  # static, shapes do not depend on it
        env = make_env(one, one["seed"], 0, one["size"])
        lanes, pp, ep = _chunk_lanes(one, models, [env], [0])
        nbytes = chunking.program_bytes(chunk_program(one, models, D1, lanes, pp, ep))
        return nbytes and nbytes * lane_devices(len(COMBO_ORDER))  # 4 lanes over d devices

    return chunking.auto(probe, total=cfg["envs"], devices=len(jax.local_devices()),
                         option="--chunk", memory_bytes=memory_bytes, even=True, say=NAME,
                         unit="environments")


def _chunk_lanes(cfg: dict, models, envs: list, ids: list[int]):
    """(lanes, planner params, execution params) of the four tests of each environment of
    ``envs`` padded to ``cfg["chunk"]``, the lanes placed over the devices."""
    import jax
    import jax.numpy as jnp

    from ..bsp import env as E
    from ..bsp import execute as X
    from ..bsp import planner as P
    from ..bsp.env import MODES

    width = cfg["chunk"]
    pad = envs + [envs[-1]] * (width - len(envs))
    pid = ids + [ids[-1]] * (width - len(ids))
    L = cfg["L_max"]
    ex = cfg["execution"]
    ep = X.ExecParams(t_max=ex["t_max"], sigma_m=ex["sigma_m"], sigma_z=ex["sigma_z"],
                      pqrm_samples=ex["pqrm_samples"], eps_obs=ex["eps_obs"],
                      nondetection="nondetection" in cfg.get("extensions", {}),
                      scale_model=cfg["scale_model"],
                      on_no_plan=ex["on_no_plan"])
    pos = jnp.asarray(np.stack([E.padded_positions(e, L) for e in pad]))
    lm = jnp.asarray(np.stack([np.arange(L) < len(e.pos) for e in pad]))
    goal = jnp.asarray([e.goal for e in pad], jnp.int32)
    start = jnp.asarray(np.stack([e.start for e in pad]), jnp.float32)
    ref = jnp.asarray([e.frame for e in pad], jnp.int32)
    rs = jnp.asarray(np.stack([E.reference_scale(models, e) for e in pad]))
    keys = jnp.stack([jax.random.fold_in(jax.random.key(cfg["seed"]), i) for i in pid])
    # the padding environments repeat the last one (same id, same key): their beliefs too
    bels = _beliefs(cfg, models, envs, [jax.random.fold_in(jax.random.key(cfg["seed"] + 1), i)
                                        for i in ids], MODES)
    fill = np.minimum(np.arange(width), len(envs) - 1)
    beliefs = {m: jax.tree.map(lambda x: x[fill], b) for m, b in bels.items()}
    # all four tests of every environment in one batched call: lanes = (mode, cost, env)
    combos = COMBO_ORDER
    B = jax.tree.map(lambda *x: jnp.concatenate(x), *[beliefs[m] for m, _ in combos])
    rep = lambda x: jnp.concatenate([x] * len(combos))  # noqa: E731
    costs = jnp.asarray(np.repeat([c for _, c in combos], width), jnp.int32)
    pp = P.PlannerParams(depth=cfg["planner"]["depth"], n_actions=cfg["planner"]["n_actions"],
                         n_beta=cfg["planner"]["n_beta"], lam=cfg["planner"]["lam"],
                         rho=cfg["planner"]["rho"],
                         nothing_seen="nothing_seen" in cfg.get("extensions", {}))
    # (keys, lanes): run_lanes takes the lanes' keys first
    lanes = (rep(keys), X.Lane(pos=rep(pos), lm_mask=rep(lm), goal=rep(goal), start=rep(start),
                               belief=B, ref=rep(ref), ref_scale=rep(rs), cost=costs))
    return shard_lanes(lanes), pp, ep


def chunk_rows(out, dt: float, envs: list, ids: list[int]) -> list[dict]:
    """The per-test rows of one chunk from :func:`run_chunk_arrays`'s outcome fields."""
    from ..bsp import execute as X

    out = X.Outcome(*out)
    width = out.exists.shape[0] // len(COMBO_ORDER)
    combos = COMBO_ORDER
    rows = []
    for c_i, (mode, cost) in enumerate(combos):
        for r, i in enumerate(ids):
            q = c_i * width + r
            steps = int(out.steps[q])
            rows.append({
                "env": i, "n": len(envs[r].pos), "mode": mode, "cost": cost,
                "plan_exists": bool(out.exists[q]), "tree_exists": bool(out.tree_exists[q]),
                "reached": bool(out.reached[q]),
                "executed_cost": float(out.cost1[q] if cost == 1 else out.cost2[q]),
                "steps": steps, "cost1": float(out.cost1[q]), "cost2": float(out.cost2[q]),
                "conflicts": int(out.conflicts[q]), "root_value": float(out.root_value[q]),
                "frames": np.asarray(out.log_frame[q])[:steps].tolist(),
                "actions": np.asarray(out.log_action[q])[:steps].tolist(),
                "path": np.round(np.asarray(out.log_pos[q])[:steps], 4).tolist(),
                "lane_seconds": dt / (width * len(combos))})
    return rows


# -------------------------------------------------------------------------------- analysis
def wilson(k: int, n: int) -> tuple[float, float]:
    """95 % Wilson score interval of a binomial proportion (``scipy.stats.binomtest``)."""
    if n == 0:
        return (float("nan"), float("nan"))
    from scipy.stats import binomtest
    ci = binomtest(int(k), int(n)).proportion_ci(0.95, method="wilson")
    return (float(ci.low), float(ci.high))


def paired_bootstrap(wo: np.ndarray, wi: np.ndarray, rng: np.random.Generator,
                     n_resamples: int = 2000) -> tuple[tuple[float, float], tuple[float, float]]:
    """95 % percentile intervals of ``mean(wi) / mean(wo)`` and ``mean(wo - wi)`` from one
    paired bootstrap (``scipy.stats.bootstrap``, ``paired=True``; both statistics see the
    same resamples)."""
    from scipy.stats import bootstrap

    def stat(a, b, axis=-1):
        return np.stack([b.mean(axis) / np.maximum(a.mean(axis), 1e-12),
                         (a - b).mean(axis)])

    res = bootstrap((wo, wi), stat, paired=True, n_resamples=n_resamples,
                    method="percentile", confidence_level=0.95, rng=rng)
    lo, hi = res.confidence_interval
    return (float(lo[0]), float(hi[0])), (float(lo[1]), float(hi[1]))


def analyse(rows: list[dict], n_env: int, seed: int = 0) -> dict:
    """Table 4.1 quantities with 95 % intervals from the per-test rows."""
    by = {(r["env"], r["mode"], r["cost"]): r for r in rows}
    res = {"n_env": n_env}
    for mode in ("without", "with"):
        k = sum(by[e, mode, 1]["plan_exists"] for e in range(n_env))
        res[f"exists_{mode}"] = (k / n_env, *wilson(k, n_env))
        res[f"exists_{mode}_cost_equal"] = all(by[e, mode, 1]["plan_exists"]
                                               == by[e, mode, 2]["plan_exists"]
                                               for e in range(n_env))
    res["monotone_violations"] = sum(by[e, "without", 1]["plan_exists"]
                                     and not by[e, "with", 1]["plan_exists"]
                                     for e in range(n_env))
    rng = np.random.default_rng(seed)
    for cost in (1, 2):
        comp = [e for e in range(n_env) if all(by[e, m, cost]["plan_exists"]
                                               and by[e, m, cost]["reached"]
                                               for m in ("without", "with"))]
        both_exist = [e for e in range(n_env) if all(by[e, m, cost]["plan_exists"]
                                                     for m in ("without", "with"))]
        diff = [e for e in comp if (by[e, "without", cost]["frames"],
                                    by[e, "without", cost]["actions"])
                != (by[e, "with", cost]["frames"], by[e, "with", cost]["actions"])]
        k = len(diff)
        res[f"cost{cost}_comparable"] = len(comp)
        res[f"cost{cost}_both_exist"] = len(both_exist)
        res[f"cost{cost}_dropped_by_execution"] = len(both_exist) - len(comp)
        res[f"cost{cost}_comparable_different"] = (k / n_env, *wilson(k, n_env))
        res[f"cost{cost}_cd_of_comparable"] = k / max(len(comp), 1)
        wo = np.array([by[e, "without", cost]["executed_cost"] for e in diff])
        wi = np.array([by[e, "with", cost]["executed_cost"] for e in diff])
        if k >= 2:
            ratio_ci, diff_ci = paired_bootstrap(wo, wi, rng)
            res[f"cost{cost}_without"] = float(wo.mean())
            res[f"cost{cost}_with"] = float(wi.mean())
            res[f"cost{cost}_ratio"] = (float(wi.mean() / max(wo.mean(), 1e-12)), *ratio_ci)
            res[f"cost{cost}_paired_diff"] = (float((wo - wi).mean()), *diff_ci)
        else:
            res[f"cost{cost}_without"] = res[f"cost{cost}_with"] = float("nan")
            res[f"cost{cost}_ratio"] = (float("nan"),) * 3
            res[f"cost{cost}_paired_diff"] = (float("nan"),) * 3
        res[f"reached_given_exists_{cost}"] = {
            m: float(np.mean([by[e, m, cost]["reached"] for e in range(n_env)
                              if by[e, m, cost]["plan_exists"]] or [np.nan]))
            for m in ("without", "with")}
        # execution success split by population (docs/bsp.md §execution-failures): the
        # environments where a plan exists in both modes, and those where only compositions
        # give one; failures that never left the initial frame
        only = [e for e in range(n_env) if by[e, "with", cost]["plan_exists"]
                and not by[e, "without", cost]["plan_exists"]]
        mean = lambda v: float(np.mean(v)) if v else float("nan")  # noqa: E731
        res[f"reached_split_{cost}"] = {
            "both_exist_n": len(both_exist),
            "both_exist_without": mean([by[e, "without", cost]["reached"] for e in both_exist]),
            "both_exist_with": mean([by[e, "with", cost]["reached"] for e in both_exist]),
            "only_with_n": len(only),
            "only_with": mean([by[e, "with", cost]["reached"] for e in only])}
        for m in ("without", "with"):
            fail = [by[e, m, cost] for e in range(n_env)
                    if by[e, m, cost]["plan_exists"] and not by[e, m, cost]["reached"]]
            res[f"reached_split_{cost}"][f"failures_{m}"] = len(fail)
            res[f"reached_split_{cost}"][f"failures_never_linked_{m}"] = sum(
                len({tuple(f) for f in r["frames"]}) <= 1 for r in fail)
    res["tree_vs_graph_agreement"] = float(np.mean([r["tree_exists"] == r["plan_exists"]
                                                    for r in rows]))
    res["conflicts_total"] = int(sum(r["conflicts"] for r in rows))
    return res


def _verdict(pub: float, lo: float, hi: float) -> str:
    if not np.isfinite(lo):
        return f"{protocol.NOT_CHECKED}: too few tests"
    return "match" if lo <= pub <= hi else "mismatch"


def report_text(st: Store, cfg: dict, res: dict, timing: dict) -> str:
    """Writes ``report.md`` (Table 4.1 as the claims table, checks, sweep, calibration)."""
    P = PUBLISHED
    lines = ["# Qualitative BSP with/without compositions (Z §4.3, Table 4.1)", "",
             f"{res['n_env']} environments × 2 modes × 2 costs; S/R = {cfg['size']}, "
             f"eps_obs = {cfg['execution']['eps_obs']} ({cfg['calibration']['how']}); "
             f"planner depth L = {cfg['planner']['depth']}, "
             f"model samples per cell = {cfg['models']['samples']}.", ""]
    if cfg.get("extensions"):
        lines += ["**EXTENSIONS beyond the thesis's model are ON** (an ablation, not the "
                  "thesis's model; docs/bsp.md §non-detection):", ""]
        lines += [f"- {k}: {v}" for k, v in cfg["extensions"].items()]
        lines += [""]
    lines += protocol.claims_table(_claims(cfg, res))
    pub_ratio = P["exists_without"] / P["exists_with"]
    ours = res["exists_without"][0] / max(res["exists_with"][0], 1e-12)
    topo = (res.get("sweep") or {}).get("topological")
    lines += ["", f"Plan-exists ratio without / with: published {pub_ratio:.3f}, measured "
              f"{ours:.3f}."]
    if topo:
        tr = topo["without"] / max(topo["with"], 1e-12)
        lines += [f"Held-out check, topological reading (Link-Graph: every candidate of the "
                  f"belief observable, eps_obs = 0; {topo['envs']} sweep environments at S/R = "
                  f"{cfg['size']}): plan exists without {topo['without']:.3f} / with "
                  f"{topo['with']:.3f}, ratio {tr:.3f} (published ratio {pub_ratio:.3f})."]
    lines += ["", "Absolute executed costs on the comparable & different tests (units differ: "
              "the thesis's are not stated; ours are ground truth, cost 2 in units of R):", "",
              "| cost | published without → with | measured without → with |", "|---|---|---|"]
    for cost in (1, 2):
        lines.append(f"| {cost} | {P[f'cost{cost}_without']} → {P[f'cost{cost}_with']} | "
                     f"{res[f'cost{cost}_without']:.2f} → {res[f'cost{cost}_with']:.2f} |")
    lines += ["", "## Checks", "",
              f"- plan exists identical for both costs: without "
              f"{res['exists_without_cost_equal']}, with {res['exists_with_cost_equal']}",
              f"- monotonicity violations (plan without but not with): "
              f"{res['monotone_violations']}",
              f"- tree root value < λ agrees with the frame-graph oracle in "
              f"{100 * res['tree_vs_graph_agreement']:.1f} % of tests",
              f"- zero-evidence updates (conflicts), all tests: {res['conflicts_total']}"]
    for cost in (1, 2):
        d, lo, hi = res[f"cost{cost}_paired_diff"]
        lines.append(f"- cost {cost}: comparable {res[f'cost{cost}_comparable']}, both exist "
                     f"{res[f'cost{cost}_both_exist']} (dropped only because an execution "
                     f"failed: {res[f'cost{cost}_dropped_by_execution']}); comparable & "
                     f"different as share of comparable {res[f'cost{cost}_cd_of_comparable']:.3f}"
                     f"; paired bootstrap (without − with) {d:.3f} [{lo:.3f}, {hi:.3f}]; "
                     f"reached | plan exists {res[f'reached_given_exists_{cost}']}")
    lines += ["", "## Execution success by population", "",
              "| cost | both exist: n, reached without / with | only with compositions: n, "
              "reached | failures never leaving the first frame, without / with |",
              "|---|---|---|---|"]
    for cost in (1, 2):
        q = res[f"reached_split_{cost}"]
        lines.append(f"| {cost} | {q['both_exist_n']}: {q['both_exist_without']:.3f} / "
                     f"{q['both_exist_with']:.3f} | {q['only_with_n']}: {q['only_with']:.3f} | "
                     f"{q['failures_never_linked_without']}/{q['failures_without']} / "
                     f"{q['failures_never_linked_with']}/{q['failures_with']} |")
    sw = res.get("sweep")
    if sw:
        lines += ["", "## Plan exists vs S/R and vs L", "",
                  f"{sw['envs']} environments per size (sweep seed), eps_obs = {sw['eps_obs']}.",
                  "", "| S/R | without | with |", "|---|---|---|"]
        lines += [f"| {x} | {sw['exists']['without'][str(x)]:.3f} | "
                  f"{sw['exists']['with'][str(x)]:.3f} |" for x in sw["sizes"]]
        lines += ["", f"Tree root < λ at S/R = {cfg['size']}:", "", "| L | without | with |",
                  "|---|---|---|"]
        lines += [f"| {d} | {sw['tree_exists']['without'][str(d)]:.3f} | "
                  f"{sw['tree_exists']['with'][str(d)]:.3f} |" for d in sw["depths"]]
    lines += ["", "## Calibration", "", f"knob: {cfg['calibration']['knob'] or 'none'}; "
              f"grid rates (with compositions, calibration seed): {cfg['calibration']['rates']}",
              "", "## Time", "", f"{json.dumps(timing)}", "",
              "Verdict = the published value lies inside our 95 % interval (Wilson for shares, "
              "bootstrap for ratios).", "", "## Figures", ""]
    for name, caption in FIGURES.items():
        if st.path(name).exists():
            lines += protocol.figure(name, caption)
    text = "\n".join(lines) + "\n"
    st.write_text("report.md", text)
    return text


#: the report's figures (drawn by :func:`figures` when there is something to draw) and what
#: each shows
FIGURES = {
    "fig45_plan_exists.png": "Z Fig. 4.5: share of environments where a plan exists without "
                             "and with compositions (bars, measured) against Table 4.1 "
                             "(black marks, published).",
    "cost_hist.png": "Executed cost of the tests that reached the goal, without (grey) and "
                     "with (blue) compositions, for cost 1 (left) and cost 2 (right).",
    "plan_exists_vs_n.png": "Share of environments where a plan exists against the number of "
                            "landmarks, without (grey) and with (blue) compositions.",
    "plan_exists_vs_size_and_depth.png": "Plan exists on the sweep seed against the "
                                         "environment size S/R (left, frame graph) and "
                                         "against the planner depth L (right, tree root "
                                         "below λ), without (grey) and with (blue) "
                                         "compositions.",
    "plan_exists_vs_eps.png": "Calibration: plan exists with compositions on the calibration "
                              "seed against the observability threshold eps_obs (dots) and "
                              "the published 81.6 % (dotted); the study takes the closest.",
    "fig46a_only_with.png": "Z Fig. 4.6a analogue: the first environment where only the "
                            "planner with compositions reaches the goal (cost 1); left "
                            "without, right with compositions: landmarks (letters), "
                            "initial-belief triplets (grey), goal triplet (green), starting "
                            "frame (orange), executed path with its frames (red).",
    "fig46b_shorter_with.png": "Z Fig. 4.6b analogue: the first environment where both reach "
                               "the goal and the path with compositions is cheaper (cost 2); "
                               "drawn as Fig. 4.6a (goal green, starting frame orange, "
                               "executed path red).",
}


def figures(st: Store, cfg: dict, rows: list[dict], envs: list, res: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    by = {(r["env"], r["mode"], r["cost"]): r for r in rows}
    n_env = res["n_env"]
    fig, ax = plt.subplots(figsize=(5, 3.2))
    vals = [res["exists_without"][0], res["exists_with"][0]]
    ax.bar([0, 1], vals, color=["tab:gray", "tab:blue"], label="measured")
    ax.scatter([0, 1], [PUBLISHED["exists_without"], PUBLISHED["exists_with"]], color="k",
               marker="_", s=400, label="published", zorder=3)
    ax.set_xticks([0, 1], ["without", "with compositions"])
    ax.set_ylabel("plan exists")
    ax.legend()
    fig.tight_layout()
    st.savefig("fig45_plan_exists.png", fig, dpi=120)
    plt.close(fig)

    fig, axs = plt.subplots(1, 2, figsize=(8, 3))
    for ax, cost in zip(axs, (1, 2), strict=True):
        for mode, c in (("without", "tab:gray"), ("with", "tab:blue")):
            v = [by[e, mode, cost]["executed_cost"] for e in range(n_env)
                 if by[e, mode, cost]["reached"]]
            ax.hist(v, bins=20, alpha=0.6, color=c, label=mode)
        ax.set_title(f"executed cost {cost} (reached tests)")
        ax.legend()
    fig.tight_layout()
    st.savefig("cost_hist.png", fig, dpi=120)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(5, 3.2))
    ns = sorted({len(e.pos) for e in envs})
    for mode, c in (("without", "tab:gray"), ("with", "tab:blue")):
        ax.plot(ns, [np.mean([by[e, mode, 1]["plan_exists"] for e in range(n_env)
                              if len(envs[e].pos) == n]) for n in ns], "o-", color=c, label=mode)
    ax.set_xlabel("landmarks n")
    ax.set_ylabel("plan exists")
    ax.legend()
    fig.tight_layout()
    st.savefig("plan_exists_vs_n.png", fig, dpi=120)
    plt.close(fig)

    sw = res.get("sweep")
    if sw:
        fig, axs = plt.subplots(1, 2, figsize=(8, 3.2))
        for mode, c in (("without", "tab:gray"), ("with", "tab:blue")):
            xs = sw["sizes"]
            axs[0].plot(xs, [sw["exists"][mode][str(x)] for x in xs], "o-", color=c,
                        label=mode)
            ds = sw["depths"]
            axs[1].plot(ds, [sw["tree_exists"][mode][str(d)] for d in ds], "o-", color=c,
                        label=mode)
        axs[0].set_xlabel("environment size S/R")
        axs[1].set_xlabel("planner depth L")
        axs[1].set_xticks(sw["depths"])
        for ax in axs:
            ax.set_ylabel("plan exists")
            ax.set_ylim(-0.02, 1.02)
            ax.legend()
        axs[0].set_title(f"frame graph, {sw['envs']} environments per size", fontsize=8)
        axs[1].set_title(f"tree root < λ, S/R = {cfg['size']}", fontsize=8)
        fig.tight_layout()
        st.savefig("plan_exists_vs_size_and_depth.png", fig, dpi=120)
        plt.close(fig)

    rates = cfg["calibration"]["rates"]
    if rates:
        fig, ax = plt.subplots(figsize=(5, 3.2))
        xs = sorted(float(s) for s in rates)
        ax.plot(xs, [rates[str(s)] for s in xs], "o-", label="with compositions (calib. seed)")
        ax.axhline(PUBLISHED["exists_with"], color="k", ls=":", label="published 81.6 %")
        ax.set_xlabel("eps_obs")
        ax.set_ylabel("plan exists")
        ax.legend()
        fig.tight_layout()
        st.savefig("plan_exists_vs_eps.png", fig, dpi=120)
        plt.close(fig)

    # Fig. 4.6 analogues
    only = [e for e in range(n_env) if by[e, "with", 1]["reached"]
            and not by[e, "without", 1]["plan_exists"]]
    shorter = [e for e in range(n_env) if by[e, "with", 2]["reached"]
               and by[e, "without", 2]["reached"]
               and by[e, "with", 2]["executed_cost"] < by[e, "without", 2]["executed_cost"]]
    for name, lst, cost in (("fig46a_only_with.png", only, 1),
                            ("fig46b_shorter_with.png", shorter, 2)):
        if not lst:
            continue
        e = lst[0]
        draw_episode(envs[e], [by[e, m, cost] for m in ("without", "with")], st.path(name),
                     title=f"env {e}, cost {cost}")


def draw_episode(env, runs: list[dict], path: Path, title: str = "") -> None:
    """Landmarks, initial-belief triplets, target and the executed paths of each mode."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .store import atomic_savefig

    fig, axs = plt.subplots(1, len(runs), figsize=(4.2 * len(runs), 4))
    axs = np.atleast_1d(axs)
    pos = np.asarray(env.pos)
    for ax, r in zip(axs, runs, strict=True):
        for t in env.triplets:
            p = pos[list(t) + [t[0]]]
            ax.plot(p[:, 0], p[:, 1], color="0.8", lw=0.8)
        g = pos[list(env.goal) + [env.goal[0]]]
        ax.fill(g[:, 0], g[:, 1], color="tab:green", alpha=0.3)
        ax.scatter(pos[:, 0], pos[:, 1], c="k", s=12)
        for i, p in enumerate(pos):
            ax.annotate("ABCDEFGHIJKL"[i], p, fontsize=8)
        path_ = np.array([env.start] + [np.asarray(p) for p in r["path"]])
        ax.plot(path_[:, 0], path_[:, 1], "o-", color="tab:red", ms=3)
        for p, f in zip(path_[1:], r["frames"], strict=False):
            ax.annotate("".join("ABCDEFGHIJKL"[x] for x in f), p, fontsize=6, color="tab:red")
        fa = pos[list(env.frame)]
        ax.plot(fa[:, 0], fa[:, 1], color="tab:orange", lw=2)
        ax.set_title(f"{r['mode']} compositions: exists={r['plan_exists']}, "
                     f"reached={r['reached']}, cost={r['executed_cost']:.2f}", fontsize=8)
        ax.set_aspect("equal")
    fig.suptitle(title)
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=120)
    plt.close(fig)


TEST_COLUMNS = ["env", "n", "mode", "cost", "plan_exists", "tree_exists", "reached",
                "executed_cost", "steps", "cost1", "cost2", "conflicts", "root_value", "frames",
                "actions"]
ROW_FIELDS = ("env", "n", "mode", "cost", "plan_exists", "tree_exists", "reached",
              "executed_cost", "steps", "cost1", "cost2", "conflicts", "root_value", "frames",
              "actions", "path")  # (older records also hold the measured lane_seconds)
COMBOS = {(m, c) for m in ("without", "with") for c in (1, 2)}
CALIBRATION_FIELDS = ("knob", "how", "rates", "eps_obs")
SWEEP_FIELDS = ("sizes", "depths", "eps_obs", "envs", "exists", "tree_exists")


def _write_tests_csv(st: Store, rows: list[dict]) -> None:
    st.write_csv("tests.csv", TEST_COLUMNS,
                 [{**r, "frames": json.dumps(r["frames"]), "actions": json.dumps(r["actions"])}
                  for r in sorted(rows, key=lambda r: (r["env"], r["mode"], r["cost"]))])


def env_record_ok(rec: dict, env: int) -> bool:
    """True when ``rec`` (``chunks/envNNNNN.json``) holds the four complete tests of ``env``."""
    rows = rec["rows"]
    return (rec["env"] == env and isinstance(rows, list) and len(rows) == len(COMBOS)
            and all(isinstance(r, dict) and all(k in r for k in ROW_FIELDS) and r["env"] == env
                    for r in rows)
            and {(r["mode"], r["cost"]) for r in rows} == COMBOS)


def results_table(rows: list[dict], res: dict) -> list[tuple[str, str, float]]:
    """Tidy ``(unit, metric, value)`` rows: every number of every test, then the summary."""
    per_test = tidy_rows(sorted(rows, key=lambda r: (r["env"], r["mode"], r["cost"])),
                         unit=lambda r: f"env{r['env']:05d}/{r['mode']}/cost{r['cost']}",
                         skip=("env", "mode", "cost", "frames", "actions", "path",
                               "lane_seconds"))
    return per_test + [("table4.1", m, v) for m, v in flatten_metrics(res)]


def _dependencies(cfg: dict, models_dir: Path | None):
    """The BSP models and the EDC neighbour-distance table; a failure fails the study."""
    import jax.numpy as jnp

    from .. import calculi
    from ..bsp import models as M

    mp = M.ModelParams(**cfg["models"])
    try:
        models = M.load_models(mp, directory=models_dir)
    except (OSError, ValueError, KeyError, RuntimeError) as exc:
        raise StudyError(f"{NAME}: the BSP models are not available "
                         f"({type(exc).__name__}: {exc})") from exc
    try:
        D1 = jnp.asarray(calculi.get("edc").tables.neighbor_distance, jnp.float32)
    except (OSError, ValueError, KeyError, RuntimeError) as exc:
        raise StudyError(f"{NAME}: the neighbour-distance table of 'edc' is not available "
                         f"({type(exc).__name__}: {exc})") from exc
    return mp, models, D1


def run_study(config: Config, out: Path, *, quiet: bool = False, cluster=None,
              fresh: bool = False, memory_bytes: int | None = None,
              models_dir: Path | None = None) -> int:
    """Run (or resume) the study into ``out``: calibration, the four tests of every
    environment (one checked record each, the resume unit), the sweep, then ``tests.csv``,
    ``results.json``, ``results.csv``, the figures and ``report.md`` (process 0).

    ``memory_bytes`` overrides the device memory the automatic chunk is sized for;
    ``models_dir`` is the model cache (default: the library's).
    """
    from tqdm.auto import tqdm

    from ..bsp import models as M

    out = Path(out)
    cfg = config_for(config)
    t_start = time.perf_counter()
    cluster = cluster or distributed.current()
    if fresh and cluster.is_main:
        Store.wipe(out, NAME, legacy=())
    chunk = cfg.pop("chunk")
    cfg["models_key"] = M.ModelParams(**cfg["models"]).key()
    # the calibrated threshold is a result (calibration.json), not a setting
    del cfg["execution"]["eps_obs"]
    from . import chunking

    # the user's chunk, else the stored one (a resume keeps its layout), else sized from
    # the device memory on process 0 (a probe program of one environment), broadcast
    chunk = chunking.resolve(chunk, out, lambda: auto_chunk(
        cfg, *_dependencies(cfg, models_dir)[1:], memory_bytes), cluster=cluster)
    # lane layout: batch width and devices (per process) change float bits of the costs at
    # rounding; the process count does not (each chunk is computed whole on one process)
    cfg["layout"] = {"chunk": chunk, "devices": lane_devices(4 * chunk)}
    distributed.agree(cluster, cfg, "qbsp config")
    main_ = cluster.is_main
    progress = main_ and not quiet
    ctx = (Store.open(out, NAME, cfg, selection=("envs",),
                      legacy=("config.json", "calibration.json", "environments.jsonl",
                              "chunks", "tests.csv", "results.json", "timing.json",
                              "report.md", "*.png"))
           if main_ else contextlib.nullcontext(None))
    with ctx as st:
        cfg = st.config if main_ else json.loads(json.dumps(cfg))
        _, models, D1 = _dependencies(cfg, models_dir)
        t_models = time.perf_counter() - t_start
        t0 = time.perf_counter()
        n_env = cfg["envs"]
        # process 0 reads what is stored; everyone learns it (one process: no collective)
        cal = None
        if config.eps is not None:
            cal = {"knob": None, "how": "fixed by --eps", "rates": {}, "eps_obs": config.eps}
        elif main_:
            cal = st.read_json("calibration.json", CALIBRATION_FIELDS)
        have_cal = distributed.broadcast(np.asarray([cal is not None], np.int8), cluster)[0]
        if not have_cal:
            eps, rates = calibrate(cfg, models, progress, cluster)
            cal = {"knob": "eps_obs", "how": "calibrated: with-composition plan-exists "
                   "rate closest to 81.6 % on the calibration seed", "rates": rates,
                   "eps_obs": eps, "target": PUBLISHED["exists_with"]}
            if main_:
                st.write_json("calibration.json", cal)
        eps_obs = float(distributed.broadcast(np.asarray([cal["eps_obs"] if cal else 0.0],
                                                         np.float64), cluster)[0])
        t_calib = time.perf_counter() - t0
        cfg["execution"]["eps_obs"] = eps_obs
        cfg["chunk"] = chunk
        envs = [make_env(cfg, cfg["seed"], e, cfg["size"]) for e in range(n_env)]
        # one checked record per environment id, so any chunking resumes correctly and a
        # torn or garbage record is recomputed alone; process 0 decides what is left
        have: dict[int, dict | None] = {}
        if main_:
            have = {i: st.read_json(f"chunks/env{i:05d}.json", ("env", "rows"),
                                    check=lambda r, i=i: env_record_ok(r, i))
                    for i in range(n_env)}
        left = distributed.broadcast(np.asarray([have.get(i) is None for i in range(n_env)],
                                                np.int8), cluster)
        work = [ids for s0 in range(0, n_env, chunk)
                if (ids := [i for i in range(s0, min(s0 + chunk, n_env)) if left[i]])]
        t0 = time.perf_counter()
        bar = tqdm(total=sum(map(len, work)), desc="qbsp lanes", unit="env",
                   disable=not progress)
        lane_s: list[float] = []  # measured seconds per lane, this invocation (timing.json)

        def compute(w: int):
            return run_chunk_arrays(cfg, models, D1, [envs[i] for i in work[w]], work[w],
                                    memory_bytes)

        def done(w: int, res) -> None:
            bar.update(len(work[w]) * cluster.num_processes)
            if not cluster.distributed and main_:  # write as we go (resume unit)
                _store_rows(st, work[w], chunk_rows(*res, [envs[i] for i in work[w]],
                                                    work[w]), have, lane_s)

        results = distributed.map_chunks(compute, len(work), cluster, done=done)
        bar.close()
        if cluster.distributed and main_:
            for ids, (arrays, dt) in zip(work, results, strict=True):
                _store_rows(st, ids, chunk_rows(arrays, float(dt), [envs[i] for i in ids],
                                                ids), have, lane_s)
        t_lanes = time.perf_counter() - t0
        if not main_:
            return 0
        env_lines = [json.dumps({"env": e, "pos": np.round(v.pos, 6).tolist(),
                                 "triplets": [list(map(int, t)) for t in v.triplets],
                                 "frame": list(map(int, v.frame)),
                                 "goal": list(map(int, v.goal)),
                                 "start": np.round(v.start, 6).tolist()})
                     for e, v in enumerate(envs)]
        st.write_text("environments.jsonl", "\n".join(env_lines) + "\n")
        cfg["calibration"] = cal
        rows = [r for i in range(n_env) for r in have[i]["rows"]]
        _write_tests_csv(st, rows)
        res = analyse(rows, n_env)
        t0 = time.perf_counter()
        sw = st.read_json("sweep.json", SWEEP_FIELDS)
        if sw is None:
            sw = sweep(cfg, models, D1, eps_obs, progress)
            st.write_json("sweep.json", sw)
        res["sweep"] = sw
        t_sweep = time.perf_counter() - t0
        import jax

        timing = {"models_s": round(t_models, 1), "calibration_s": round(t_calib, 1),
                  "lanes_s": round(t_lanes, 1), "sweep_s": round(t_sweep, 1),
                  "total_s": round(time.perf_counter() - t_start, 1),
                  "lane_seconds_mean": float(np.mean(lane_s)) if lane_s else None,
                  "processes": cluster.num_processes,
                  "devices_per_process": len(jax.local_devices()),
                  "devices": len(jax.devices())}
        # measured times apart from the results (two identical runs: identical results.json)
        st.write_text("results.json", json.dumps({"results": res}, indent=1, default=float))
        st.write_json("timing.json", timing)
        st.write_results_csv(results_table(rows, res))
        _render(st, cfg, rows, envs, res, timing, print_report=not quiet)
    return 0


def _render(st: Store, cfg: dict, rows: list[dict], envs: list, res: dict, timing: dict, *,
            print_report: bool = False) -> None:
    figures(st, cfg, rows, envs, res)
    text = report_text(st, cfg, res, timing)
    if print_report:
        print(text)


def _stored(out: Path) -> tuple[dict, dict, dict]:
    """(configuration with the calibration, results, timing) of a finished study in ``out``."""
    from .store import read_json

    cfg = read_json(out / "config.json", ("envs", "execution"), quarantine=False)
    if cfg is not None and cfg.get("eps_fixed") is not None:  # --eps: nothing calibrated
        cal = {"knob": None, "how": "fixed by --eps", "rates": {}, "eps_obs": cfg["eps_fixed"]}
    else:
        cal = read_json(out / "calibration.json", CALIBRATION_FIELDS, quarantine=False)
    doc = read_json(out / "results.json", ("results",), quarantine=False)
    if cfg is None or cal is None or doc is None:
        raise StudyError(f"{out} holds no finished {NAME} study (config.json, "
                         "calibration.json and results.json); run the study first")
    cfg["execution"]["eps_obs"] = cal["eps_obs"]
    cfg["calibration"] = cal
    timing = read_json(out / "timing.json", (), quarantine=False) or doc.get("timing", {})
    return cfg, doc["results"], timing


def report(out: Path) -> Path:
    """``report.md`` and the figures again from the stored results (``--report-only``)."""
    out = Path(out)
    with Store.open(out, NAME, None, legacy=()) as st:
        cfg, res, timing = _stored(out)
        n_env = res["n_env"]
        recs = [st.read_json(f"chunks/env{i:05d}.json", ("env", "rows"),
                             check=lambda r, i=i: env_record_ok(r, i)) for i in range(n_env)]
        if any(r is None for r in recs):
            raise StudyError(f"{out}: some environment records are missing; run the study "
                             "to complete them")
        rows = [r for rec in recs for r in rec["rows"]]
        envs = [make_env(cfg, cfg["seed"], e, cfg["size"]) for e in range(n_env)]
        _render(st, cfg, rows, envs, res, timing)
    return out / "report.md"


def _claims(cfg: dict, res: dict) -> list[protocol.Claim]:
    """Z Table 4.1 against the measured values: the verdict is a match when the published
    value lies in the measured 95 % interval (Wilson for shares, bootstrap for ratios)."""
    P = PUBLISHED
    cs = []

    def claim(name, pub, val, lo, hi):
        cs.append(protocol.Claim(name, f"{pub:.3f}", float(val), (float(lo), float(hi)),
                                 _verdict(pub, lo, hi)))

    for mode in ("without", "with"):
        v, lo, hi = res[f"exists_{mode}"]
        tag = " (calibrated)" if mode == "with" and cfg["calibration"]["knob"] else ""
        claim(f"plan exists, {mode} compositions{tag}", P[f"exists_{mode}"], v, lo, hi)
    for cost in (1, 2):
        v, lo, hi = res[f"cost{cost}_comparable_different"]
        claim(f"comparable & different share (cost {cost})", P["comparable_different"], v,
              lo, hi)
    for cost in (1, 2):
        v, lo, hi = res[f"cost{cost}_ratio"]
        claim(f"executed cost {cost}, with/without ratio",
              P[f"cost{cost}_with"] / P[f"cost{cost}_without"], v, lo, hi)
    return cs


def claims(out: Path) -> list[protocol.Claim]:
    """Z Table 4.1's published values against the stored results (:func:`_claims`)."""
    cfg, res, _ = _stored(Path(out))
    return _claims(cfg, res)


def main(argv: list[str] | None = None) -> int:
    """``pqrm-jax study qbsp``: configure, then run (which writes the report) or
    ``--report-only``; exit 0 (a mismatch with Table 4.1 is a result)."""
    config, a = configure(list(argv or []))
    if a.report_only:
        print(f"wrote {report(Path(a.out))}")
        return 0
    cluster = distributed.initialize_from(a)  # before any JAX computation
    return run_study(config, Path(a.out), quiet=a.no_progress, cluster=cluster,
                     fresh=a.fresh, memory_bytes=a.memory_bytes, models_dir=a.models_dir)


sweep_summary = protocol.summary_for(sys.modules[__name__])


def _store_rows(st: Store, ids: list[int], rows: list[dict], have: dict,
                lane_s: list[float]) -> None:
    """Each environment's record (the resume unit) without the measured ``lane_seconds``,
    which go to ``lane_s`` (this invocation's times, for ``timing.json``)."""
    lane_s += [r["lane_seconds"] for r in rows if r["env"] in ids]
    for i in ids:
        rec = {"env": i, "rows": [{k: v for k, v in r.items() if k != "lane_seconds"}
                                  for r in rows if r["env"] == i]}
        st.write_json(f"chunks/env{i:05d}.json", rec, indent=None)
        have[i] = json.loads(json.dumps(rec))  # the rows as stored
