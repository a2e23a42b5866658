"""Padgett's PQRM Monte Carlo study (P §2.3.1, Figs 2.6–2.11; Fig. 2.16 in simulation).

Maps all ordered triplets of random landmark worlds along a perimeter loop for the six
representations of docs/decisions.md §2.2, at 21 noise levels plus the figure levels, and
reports entropy, error rates, P(ML state), neighbour distance, confusion matrices and error
locations against the published numbers. The open choices (number of landmarks, samples per
update) are recorded in ``config.json``; a killed study resumes at the first unfinished level.

The study protocol of :mod:`pqrm_jax.studies.protocol` (``Config``, ``PRESETS``,
``configure``, ``run_study``, ``report``, ``claims``; the common flags incl. ``--chunk``;
``--sweep``).

Setup, recorded choices and engineering: docs/studies.md §padgett-mc. As N processes on
``jax.distributed`` (``--coordinator/--processes/--process-id``, the environment or Slurm;
:mod:`pqrm_jax.studies.distributed`) the chunks of each level are split over the processes and
gathered, bit-identical to one process; process 0 alone writes.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import math
import os
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from .. import calculi
from ..pqrm.measurement import KERNEL_COMPILER_OPTIONS
from . import protocol
from .padgett_common import (
    BD_BINS,
    LINE_FIELDS,
    SIGMA_E,
    boundary_distance,
    level_check,
    load_results,
    npz_required,
)

NAME = "padgett-mc"
HELP = "Padgett's PQRM Monte Carlo study (P §2.3.1, Figs 2.6–2.11, 2.16)"

REPS = calculi.PADGETT_REPRESENTATIONS  # Padgett's six reduced representations (P Fig. 2.2)
PAPER_FIG28_SIGMA_R = (1.0, 50.0)  # Fig. 2.8/2.9: σ_N = 0.04 and 1.73
TOPN_SIGMA_N = (0.05, 0.7, 1.5)  # Fig. 2.16 regimes (P §2.3.2)
#: rows per piece of the sparse batched update (results do not depend on it, docs/pqrm.md §map)
SPARSE_BLOCK = 1024
#: the XLA option that keeps XLA:CPU from handing reductions to YNNPACK (its own emitters
#: compute them instead); see :data:`CHUNK_COMPILER_OPTIONS`
NO_YNN_FUSIONS = {"xla_cpu_experimental_ynn_fusion_type": ""}
#: XLA options of the compiled chunk program (measured in docs/benchmarks.md §bench_padgett):
#:
#: * the sampling kernel's 512-bit vectors
#:   (:data:`pqrm_jax.pqrm.measurement.KERNEL_COMPILER_OPTIONS`, which JAX cannot set on the
#:   kernel's own jit once it is traced into this program); results unchanged; a CPU without
#:   512-bit vectors ignores it;
#: * no YNNPACK fusions (:data:`NO_YNN_FUSIONS`): with XLA's own reduction emitters a
#:   1 000-run level took 2.10 instead of 2.49 CPU-s on the 2-core host; the float sums of
#:   the metrics (per-run entropy, P(ML), the error locations' normalised positions) change
#:   in the last bits, hence numerics version 4. A jaxlib whose XLA has no such option (no
#:   YNNPACK fusions to turn off) compiles without it (:func:`chunk_compiler_options`).
CHUNK_COMPILER_OPTIONS = dict(KERNEL_COMPILER_OPTIONS, **NO_YNN_FUSIONS)
NUMERICS_VERSION = 4  # bump when the map's floating-point results change (see Config notes)
#: runs per compiled call on a CPU backend when ``--chunk`` is not given (at most; fewer when
#: the memory is short): a chunk's map (≈ 0.2 MB a run) then stays near the core's caches, and
#: a 1 000-run level took 2.10 CPU-s in chunks of 100 against 2.45 in one call of 1 000 (50:
#: 2.15, 250: 2.29; docs/benchmarks.md §bench_padgett); the results do not depend on it
CPU_CHUNK_RUNS = 100


@dataclasses.dataclass
class Config:
    runs: int = 1000
    levels: int = 21
    max_sigma_r: float = 100.0
    num_landmarks: int = 10
    num_samples: int = 256
    world_size: float = 100.0
    loop_radius: float = 50.0
    dtheta_deg: float = 16.0
    max_range: float = 60.0
    representations: tuple[str, ...] = REPS
    seed: int = 0
    #: runs per compiled call; None sizes it from the device's memory (:func:`auto_chunk`)
    chunk_runs: int | None = None
    max_error_points: int = 4000

    def sigma_levels(self) -> list[dict]:
        """Main levels (linspace) then the extra figure levels, each a dict with a tag."""
        out = [{"tag": "main", "sigma_r": float(s)}
               for s in np.linspace(0.0, self.max_sigma_r, self.levels)]
        out += [{"tag": "fig2.8", "sigma_r": float(PAPER_FIG28_SIGMA_R[0])}]
        out += [{"tag": "topn", "sigma_r": float(sn * SIGMA_E)} for sn in TOPN_SIGMA_N]
        return out

    def to_json(self) -> dict:
        d = dataclasses.asdict(self)
        d["representations"] = list(self.representations)
        d.pop("chunk_runs")  # the effective layout is stored by run_study (see ``layout``)
        d["sigma_e"] = SIGMA_E
        d["levels_sigma_r"] = [lv["sigma_r"] for lv in self.sigma_levels()]
        d["numerics"] = NUMERICS_VERSION
        d["notes"] = {
            "num_landmarks": "not stated in P §2.3.1 ('no more than 10 landmarks are observed "
                             "at a single time'); chosen so that bound always holds",
            "num_samples": "samples per triplet per update (s in P's O(nsQ^2)); not stated",
            "loop": "circle of radius loop_radius about the world centre, a pose every "
                    "dtheta_deg (23 poses), omnidirectional sensor, no occlusion",
            "sampling": "one standard-normal bank per update shared by the triplets "
                        "(common random numbers); fresh bank every update",
            "numerics": "2 = power-of-two rescaled EDC kernel and a fixed-order Bayes "
                        "normaliser (entropy and p_ml differ from version 1 in the last bits); "
                        "3 = no FMA contraction in that normaliser, so the sparse runner "
                        "equals the dense reference bit for bit (probabilities of lr, "
                        "single/double/triple_cross differ from version 2 by a few ulps, so "
                        "their ML state can flip where two states are within an ulp: on the "
                        "full study rates moved by at most 3.3e-6, about one triplet in "
                        "300 000; counts and every EDC and edc_lune result unchanged); "
                        "4 = the chunk program compiled without YNNPACK fusions (XLA's own "
                        "reduction emitters in the metrics; the maps are unchanged bit for "
                        "bit): per-run entropy and P(ML) differ from version 3 in the last "
                        "bits (level means within 1.2e-7), the error locations' normalised "
                        "positions by at most 1.5e-5 |AB| (one triplet moved to the next "
                        "boundary-distance bin in 2 of 25 levels); counts, error, top-n and "
                        "neighbour rates and confusion matrices unchanged; "
                        "a directory written by another version is refused, not mixed",
        }
        return d


# --------------------------------------------------------------------------------------
# the per-run computation
# --------------------------------------------------------------------------------------


def _distance_matrices(reps) -> dict[str, np.ndarray | None]:
    from pqrm_jax import calculi

    from .store import StudyError

    out = {}
    for name in reps:
        try:
            out[name] = np.asarray(calculi.get(name).neighbor_distance, np.int32)
        except (OSError, ValueError, KeyError, RuntimeError) as exc:
            # a failed dependency fails the study: never store NaN metrics as results
            raise StudyError(f"{NAME}: the neighbour-distance table of {name!r} is not "
                             f"available ({type(exc).__name__}: {exc})") from exc
    return out


def _setup(cfg: Config):
    from pqrm_jax import pqrm, sim

    pq = pqrm.mapper(cfg.representations, cfg.num_landmarks, cfg.num_samples,
                     sparse_block=SPARSE_BLOCK)
    half = cfg.world_size / 2
    poses = sim.trajectories.perimeter_loop((half, half), cfg.loop_radius,
                                            math.radians(cfg.dtheta_deg))
    return pq, poses


def _run_inputs(cfg: Config, poses, key, sigma_r):
    """One run's world, sensor and per-step keys (as in the original per-run function)."""
    from pqrm_jax import sim

    k_world, k_steps = jax.random.split(key)
    lm = sim.world.uniform_landmarks(k_world, cfg.num_landmarks,
                                     (cfg.world_size, cfg.world_size))
    params = sim.sensors.SensorParams(max_range=cfg.max_range, fov=2 * jnp.pi,
                                      landmark_radius=0.0, sigma=sigma_r)
    keys = jax.random.split(k_steps, poses.shape[0])
    return lm, params, keys


def _observe_step(k, pose, lm, params):
    from pqrm_jax import sim

    k_obs, k_map = jax.random.split(k)
    obs = sim.sensors.observe(k_obs, pose, lm, params)
    return obs.rel, obs.visible, k_map


def _make_metrics_fn(cfg: Config, dists: dict, pq):
    """``metrics(lm, state) -> dict`` of one run's results from its final map."""
    from pqrm_jax.pqrm import metrics

    cals = pq.calculi
    tri = pq.triplets

    def run_metrics(lm, state):
        out = {"n_mapped": jnp.sum(state.mapped), "n_updates": jnp.sum(state.num_updates),
               "n_rejected": jnp.sum(state.num_rejected)}
        # one sign evaluation for the six merges of the EDC (equal to true_states per calculus)
        truths = dict(zip((c.name for c in cals), metrics.true_states_all(cals, lm, tri),
                          strict=True))
        for c in cals:
            truth = truths[c.name]
            mask = state.mapped & (truth >= 0)
            p = state.probs[c.name]
            r = {
                "entropy": metrics.mean_map_entropy(p, mask),
                "error": metrics.error_rate(p, truth, mask),
                "p_ml": metrics.ml_probability(p, mask),
                "topn": metrics.topn_error_rates(p, truth, mask),
                "confusion": metrics.confusion_matrix(p, truth, mask),
                "conflicts": jnp.sum(state.num_conflicts[c.name]),
                "n_eval": jnp.sum(mask),
            }
            d = dists.get(c.name)
            r["neighbor"] = (metrics.neighbor_distance(p, truth, mask, d) if d is not None
                             else jnp.float32(jnp.nan))
            out[c.name] = r
        # EDC error locations (P Fig. 2.8): normalised C, |AB|, truth, estimate, error mask
        truth = truths["edc"]  # the EDC is among the representations (its map is read next)
        p = state.probs["edc"]
        est = metrics.ml_states(p)
        xy, dab = metrics.normalized_positions(lm, tri)
        out["err"] = {"xy": xy, "dab": dab, "truth": truth, "est": est,
                      "mask": state.mapped & (truth >= 0) & (est != truth),
                      "mapped": state.mapped & (truth >= 0)}
        return out

    return run_metrics


def _make_dense_run_fn(cfg: Config, dists: dict):
    """``run(key, sigma_r) -> dict`` of one run, sampling every triplet at every step.

    The original per-run formulation (``jax.vmap`` it over runs); kept as the reference the
    sparse batched runner is tested and benchmarked against.
    """
    pq, poses = _setup(cfg)
    run_metrics = _make_metrics_fn(cfg, dists, pq)

    def run(key, sigma_r):
        lm, params, keys = _run_inputs(cfg, poses, key, sigma_r)

        def step(state, inp):
            pose, k = inp
            rel, vis, k_map = _observe_step(k, pose, lm, params)
            return pq.update(state, k_map, rel, vis, sigma_r)[0], None

        state, _ = jax.lax.scan(step, pq.init(), (poses, keys))
        return run_metrics(lm, state)

    return run


def _make_maps_fn(cfg: Config, groups: int = 1):
    """``(maps, mapper)``: ``maps(run_keys [R], sigma_r) -> (landmarks [R, M, 2], MapState)``,
    the R runs' worlds and their maps after the loop — the study's mapping, which
    :func:`_make_batch_fn` scores.

    The R maps are stepped together with ``Mapper.update_batch``, which samples eq. 2.9 only
    for the triplets seen at each step (compacted across the R runs; ``groups`` independent
    compactions, one per device).
    """
    pq, poses = _setup(cfg)

    def maps(run_keys, sigma_r):
        lm, params, keys = jax.vmap(partial(_run_inputs, cfg, poses),
                                    in_axes=(0, None))(run_keys, sigma_r)
        r = run_keys.shape[0]
        state0 = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (r, *x.shape)),
                                        pq.init())

        def step(states, inp):
            pose, k = inp  # (3,), (R,)
            rel, vis, k_map = jax.vmap(_observe_step, in_axes=(0, None, 0, 0))(
                k, pose, lm, params)
            return pq.update_batch(states, k_map, rel, vis, sigma_r, groups=groups)[0], None

        states, _ = jax.lax.scan(step, state0, (poses, jnp.swapaxes(keys, 0, 1)))
        return lm, states

    return maps, pq


def _make_batch_fn(cfg: Config, dists: dict, groups: int = 1):
    """``run_batch(keys [R], sigma_r) -> dict`` of per-run results (leading axis R).

    Same results as ``jax.vmap(_make_dense_run_fn(...))`` bit for bit (same keys, same draws):
    the maps of :func:`_make_maps_fn`, scored run by run.
    """
    maps, pq = _make_maps_fn(cfg, groups)
    run_metrics = _make_metrics_fn(cfg, dists, pq)

    def run_batch(run_keys, sigma_r):
        return jax.vmap(run_metrics)(*maps(run_keys, sigma_r))

    return run_batch


def _mesh_sharding():
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    devs = np.array(jax.local_devices())  # this process's devices (all of them with one)
    mesh = Mesh(devs, ("runs",))
    return NamedSharding(mesh, PartitionSpec("runs")), len(devs)


_COMPILED: dict = {}


@functools.cache
def _xla_takes(name: str, value) -> bool:
    """Whether this jaxlib's XLA accepts the compile option ``name`` (a one-op program)."""
    try:
        jax.jit(lambda x: x + 1).lower(jnp.float32(0)).compile(compiler_options={name: value})
    except Exception as exc:  # noqa: BLE001  (XLA's error type varies by version)
        if name not in str(exc):
            raise
        return False
    return True


def chunk_compiler_options() -> dict:
    """:data:`CHUNK_COMPILER_OPTIONS` as this jaxlib takes them: without
    :data:`NO_YNN_FUSIONS` when its XLA does not know that option (a jaxlib without YNNPACK
    fusions computes its reductions with XLA's own emitters anyway). Checked once per
    option; any other option XLA does not know is refused by name when the chunk program
    compiles.
    """
    return {k: v for k, v in CHUNK_COMPILER_OPTIONS.items()
            if k not in NO_YNN_FUSIONS or _xla_takes(k, v)}


def compiled_runner(cfg: Config, *, dense: bool = False):
    """(run_batch, jitted run_batch, sharding) for ``cfg``, cached per configuration.

    ``dense=True`` gives the reference runner (``vmap`` of the per-run function, every triplet
    sampled at every step); the default samples only the seen triplets (same results).
    """
    sharding, ndev = _mesh_sharding()
    key = (json.dumps(cfg.to_json(), sort_keys=True), ndev, dense)
    if key not in _COMPILED:
        _COMPILED.clear()
        dists = _distance_matrices(cfg.representations)
        if dense:
            fn = jax.vmap(_make_dense_run_fn(cfg, dists), in_axes=(0, None))
        else:
            fn = _make_batch_fn(cfg, dists, groups=ndev)
        _COMPILED[key] = (fn, jax.jit(fn, out_shardings=sharding), sharding)
    return _COMPILED[key]


PROBE_LANES = 1  # runs per device of the program whose size bounds one run's memory
_AOT: dict = {}


_LOCK = threading.Lock()  # levels run side by side (level_workers): compile once


def _compiled_chunk(cfg: Config, chunk: int, *, dense: bool = False):
    """(compiled call, sharding) of the runner for chunks of ``chunk`` runs, cached."""
    with _LOCK:
        _, batched, sharding = compiled_runner(cfg, dense=dense)
        options = chunk_compiler_options()
        key = (id(batched), chunk, json.dumps(options, sort_keys=True))
        if key not in _AOT:
            if len(_AOT) > 4:
                _AOT.clear()
            keys = jax.device_put(jax.random.split(jax.random.key(0), chunk), sharding)
            _AOT[key] = (batched, batched.lower(keys, jnp.float32(0.0)).compile(
                compiler_options=options or None))
        return _AOT[key][1], sharding


def chunk_program(cfg: Config, chunk: int, *, dense: bool = False,
                  memory_bytes: int | None = None):
    """(compiled call, sharding) of the runner for chunks of ``chunk`` runs, cached.

    Compiled ahead of time so that its size (XLA's memory analysis) is checked against the
    device's memory before anything runs: a chunk needing more than
    :data:`~pqrm_jax.studies.chunking.FRACTION` of ``memory_bytes`` (default: what the
    device has available) is refused with a message naming ``--chunk``.
    """
    from . import chunking

    compiled, sharding = _compiled_chunk(cfg, chunk, dense=dense)
    chunking.check_fits(chunking.program_bytes(compiled), chunking.budget(memory_bytes),
                        option="--chunk",
                        what=f"{NAME}: a chunk of {chunk} runs "
                             f"({chunk // len(jax.local_devices())} per device)")
    return compiled, sharding


def auto_chunk(cfg: Config, *, memory_bytes: int | None = None) -> int:
    """Runs per compiled call sized from the device memory (docs/studies.md §padgett-mc).

    :func:`~pqrm_jax.studies.chunking.auto` with this study's programs: first the program of
    every run in one call (``cfg.runs`` rounded up to the devices; on a CPU backend at most
    :data:`CPU_CHUNK_RUNS` runs, evened out: 1 000 runs are 10 calls of 100) — the program
    the study then runs, so in the usual case nothing else is compiled — is taken when it
    fits; otherwise one run's bytes are bounded by the compiled program of
    :data:`PROBE_LANES` run per device and the largest power of two of runs per device that
    fits is taken (at most the CPU cap). Without memory figures:
    :data:`~pqrm_jax.studies.chunking.FALLBACK_CHUNK` (at most the CPU cap).
    """
    from . import chunking

    ndev = len(jax.local_devices())
    per_device = min(PROBE_LANES, -(-cfg.runs // ndev))

    def full(lanes: int) -> int | None:
        return chunking.program_bytes(
            _compiled_chunk(dataclasses.replace(cfg, chunk_runs=lanes), lanes)[0])

    def probe() -> int | None:
        lanes = per_device * ndev
        compiled, _ = chunk_program(dataclasses.replace(cfg, chunk_runs=lanes), lanes,
                                    memory_bytes=memory_bytes)
        return chunking.program_bytes(compiled)

    return chunking.auto(probe, total=cfg.runs, devices=ndev, per_probe=per_device,
                         memory_bytes=memory_bytes, whole=full, option="--chunk",
                         cpu_cap=CPU_CHUNK_RUNS)


def run_keys(cfg: Config, level_index: int, runs) -> jax.Array:
    """The PRNG keys of some runs of one noise level: the study's key scheme.

    One key per (level, run) whatever the chunking: the root key of ``cfg.seed`` folded with
    the level index, then with the run index (:func:`run_level` derives its chunks' keys so).

    Args:
        cfg: the study's configuration (its ``seed``).
        level_index: the level's index in ``cfg.sigma_levels()``.
        runs: [K] run indices.

    Returns:
        [K] PRNG keys.
    """
    base = jax.random.fold_in(jax.random.key(cfg.seed), level_index)
    return jax.vmap(lambda i: jax.random.fold_in(base, i))(jnp.asarray(runs, jnp.uint32))


def run_level(cfg: Config, level_index: int, sigma_r: float, progress=None, *,
              dense: bool = False, cluster=None, memory_bytes: int | None = None) -> dict:
    """All runs of one noise level, sharded over devices, in chunks; returns numpy results.

    With a multi-process ``cluster`` (:mod:`.distributed`) process ``p`` of ``K`` computes the
    chunks ``c`` with ``c % K == p`` — each chunk exactly as a one-process run computes it
    (same runs, padding, per-device batch and compiled program) — and the chunks are gathered
    on every process, so the result is bit-identical to a one-process run. ``chunk_runs=None``
    sizes the chunks from the device memory (:func:`auto_chunk`; ``memory_bytes``
    overrides what the device reports); a chunk that does not fit fails before it runs, with
    a message naming ``--chunk``.
    """
    from . import distributed

    cluster = cluster or distributed.Cluster(0, 1, None)
    if cfg.chunk_runs is None:
        cfg = dataclasses.replace(cfg, chunk_runs=auto_chunk(cfg, memory_bytes=memory_bytes))
    chunk = layout(cfg)["chunk"]
    batched, sharding = chunk_program(cfg, chunk, dense=dense, memory_bytes=memory_bytes)
    starts = list(range(0, cfg.runs, chunk))
    # Every eager op of a level runs here, holding the lock: two level threads dispatching
    # the same new eager op at once each compile it (JAX does not serialise that), so the
    # per-chunk keys and the noise scalar are derived up front, one level at a time.
    with _LOCK:
        # the last chunk is padded by repeating a run
        idx = np.minimum(np.arange(len(starts) * chunk), cfg.runs - 1).reshape(-1, chunk)
        chunk_keys = [jax.device_put(run_keys(cfg, level_index, row), sharding)
                      for row in idx]
        sigma = jnp.float32(sigma_r)

    def compute(c: int):
        try:
            res = jax.device_get(batched(chunk_keys[c], sigma))
        except Exception as exc:  # noqa: BLE001  (XLA's runtime error type varies by version)
            oom = memory_error(exc, cfg, chunk)
            if oom is None:
                raise
            raise oom from exc
        return jax.tree_util.tree_map(np.asarray, res)

    def done(c: int, _) -> None:
        if progress is not None:
            progress.update(min(chunk, cfg.runs - starts[c]) * cluster.num_processes)

    parts = distributed.map_chunks(compute, len(starts), cluster, done=done)
    out = jax.tree_util.tree_map(lambda *xs: np.concatenate(xs), *parts)
    return jax.tree_util.tree_map(lambda x: x[:cfg.runs], out)


def memory_error(exc: BaseException, cfg: Config, chunk: int):
    """A :class:`~pqrm_jax.studies.store.StudyError` naming ``--chunk`` when ``exc`` is
    the device running out of memory for one chunk, else None.

    >>> memory_error(RuntimeError("RESOURCE_EXHAUSTED: Out of memory allocating 9 GiB"),
    ...              Config(chunk_runs=500), 500)  # doctest: +ELLIPSIS
    StudyError('padgett-mc: a chunk of 500 runs does not fit in the memory of ...')
    >>> memory_error(ValueError("bad"), Config(), 250) is None
    True
    """
    from .store import StudyError

    text = str(exc)
    if "RESOURCE_EXHAUSTED" not in text and "out of memory" not in text.lower():
        return None
    dev = jax.local_devices()[0]
    return StudyError(f"{NAME}: a chunk of {chunk} runs does not fit in the memory of "
                      f"{dev.device_kind} ({dev.platform}); lower --chunk (now "
                      f"{cfg.chunk_runs}, per device {chunk // len(jax.local_devices())} "
                      f"runs): {text.splitlines()[0][:200]}")


def summarise_level(cfg: Config, level: dict, res: dict, level_index: int) -> tuple[dict, dict]:
    """(JSON summary line, npz arrays) of one finished level."""
    line = {"level": level_index, "tag": level["tag"], "sigma_r": level["sigma_r"],
            "sigma_n": level["sigma_r"] / SIGMA_E, "runs": cfg.runs,
            "mean_mapped": float(res["n_mapped"].mean()),
            "mean_updates_per_triplet": float(res["n_updates"].sum()
                                              / max(res["n_mapped"].sum(), 1)),
            "rejected": int(res["n_rejected"].sum()), "reps": {}}
    arrays = {}
    for name in cfg.representations:
        r = res[name]
        q = r["topn"].shape[-1]
        n_eval = r["n_eval"].astype(float)
        w = n_eval / max(n_eval.sum(), 1.0)
        line["reps"][name] = {
            "num_states": int(q),
            "entropy_mean": float(r["entropy"].mean()),
            "entropy_std": float(r["entropy"].std()),
            "norm_entropy_mean": float(r["entropy"].mean() / math.log(q)),
            "error_mean": float(r["error"].mean()),
            "error_std": float(r["error"].std()),
            "p_ml_mean": float(r["p_ml"].mean()),
            "neighbor_mean": float(np.mean(r["neighbor"])),
            "neighbor_std": float(np.std(r["neighbor"])),
            "topn_mean": [float(x) for x in r["topn"].mean(axis=0)],
            "topn_pooled": [float(x) for x in (r["topn"] * w[:, None]).sum(axis=0)],
            "conflicts": int(r["conflicts"].sum()),
            "conflicts_per_update": float(r["conflicts"].sum()
                                          / max(res["n_updates"].sum(), 1)),
        }
        for key in ("entropy", "error", "p_ml", "neighbor"):
            arrays[f"{name}/{key}"] = r[key]
        arrays[f"{name}/confusion"] = r["confusion"].sum(axis=0)
    err = res["err"]
    m = err["mask"].reshape(-1)
    sel = np.flatnonzero(m)
    if sel.size > cfg.max_error_points:
        sel = np.random.default_rng(level_index).choice(sel, cfg.max_error_points,
                                                        replace=False)
    for k in ("xy", "dab", "truth", "est"):
        arrays[f"err/{k}"] = err[k].reshape(-1, *err[k].shape[2:])[sel]
    mapped = err["mapped"].reshape(-1)
    arrays["err/num_errors"] = np.asarray(int(m.sum()))
    arrays["err/num_mapped"] = np.asarray(int(mapped.sum()))
    # boundary distances of all mapped triplets (for the "errors on boundaries" claim)
    xy_all = err["xy"].reshape(-1, 2)[mapped]
    arrays["err/all_boundary_dist_hist"] = np.histogram(
        boundary_distance(xy_all), bins=BD_BINS)[0]
    arrays["err/all_truth_hist"] = np.bincount(err["truth"].reshape(-1)[mapped], minlength=20)
    arrays["err/err_truth_hist"] = np.bincount(err["truth"].reshape(-1)[m], minlength=20)
    arrays["err/err_est_hist"] = np.bincount(err["est"].reshape(-1)[m], minlength=20)
    arrays["err/err_boundary_dist_hist"] = np.histogram(
        boundary_distance(err["xy"].reshape(-1, 2)[m]), bins=BD_BINS)[0]
    return line, arrays


# --------------------------------------------------------------------------------------
# storage / resume
# --------------------------------------------------------------------------------------


LEGACY = ("config.json", "levels.jsonl", "level_*.npz", "timing.json", "report.md",
          "fig*.png", "results.csv", "study.json", "*.corrupt")
def layout(cfg: Config) -> dict:
    """The run layout that changes float bits (per-device batch of the batched mapper).

    Discrete metrics are layout-free, but entropies, P(ML) and error locations differ in
    the last bits between batch shapes (XLA reduction order over the compacted triplets), so
    the effective chunk and the device count are stored in the config (a resume with
    another layout is refused instead of mixing bits).
    """
    if cfg.chunk_runs is None:
        raise ValueError("layout needs an explicit chunk_runs (see auto_chunk)")
    ndev = len(jax.local_devices())  # per process: the split over processes is bit-neutral
    chunk = max(ndev, int(math.ceil(min(cfg.chunk_runs, cfg.runs) / ndev)) * ndev)
    return {"chunk": chunk, "devices": ndev}


def open_store(cfg: Config, out: Path, *, fresh: bool = False):
    """The study's :class:`~pqrm_jax.studies.store.Store` for ``cfg`` (locked)."""
    from .store import Store

    return Store.open(out, NAME, dict(cfg.to_json(), layout=layout(cfg)), legacy=LEGACY,
                      legacy_assume=("layout",), fresh=fresh,
                      advice="use another --out or --fresh")


def results_rows(lines: list[dict]) -> list[tuple[str, str, float]]:
    """Tidy ``(unit, metric, value)`` rows of the level summaries (unit ``level_XX``)."""
    from .store import tidy_rows

    return tidy_rows(lines, unit=lambda r: f"level_{r['level']:02d}", skip=("level",))


def resolve_chunk(cfg: Config, out: Path, *, fresh: bool = False, cluster=None,
                  memory_bytes: int | None = None) -> Config:
    """``cfg`` with an explicit ``chunk_runs``, the same on every process.

    Given by the user: kept. Else process 0 reuses the chunk stored in ``out`` (a resume
    keeps its layout, hence its float bits, whatever the free memory is now) or sizes a new
    one from the device memory (:func:`auto_chunk`), and broadcasts it
    (:func:`~pqrm_jax.studies.chunking.resolve`).
    """
    from . import chunking

    if cfg.chunk_runs is not None:
        return cfg
    chunk = chunking.resolve(None, out, lambda: auto_chunk(cfg, memory_bytes=memory_bytes),
                             fresh=fresh, cluster=cluster)
    return dataclasses.replace(cfg, chunk_runs=chunk)


def level_workers(cluster=None) -> int:
    """Noise levels computed side by side by :func:`run_study`: 2 on a CPU host with at least
    two cores and one process, else 1.

    XLA's CPU code keeps about 1.6 of 2 cores busy on one level (many small kernels per step);
    two levels at once fill them (each level is the same program on its own keys, so the
    results are those of one level at a time, bit for bit; the files are written in level
    order). Not with several processes (their collectives must run in one order) nor on an
    accelerator (one device runs one program at a time).

    Args:
        cluster: the :mod:`.distributed` cluster (None: one process).

    Returns:
        1 or 2.
    """
    if cluster is not None and cluster.distributed:
        return 1
    if jax.default_backend() != "cpu":
        return 1
    return 2 if (os.cpu_count() or 1) >= 2 else 1


def run_study(cfg: Config, out: Path, *, quiet: bool = False, fresh: bool = False,
              store=None, cluster=None, memory_bytes: int | None = None) -> list[dict]:
    """Run (or resume) the study into ``out``; returns the level summaries.

    Every level is its own unit: ``level_XX.npz`` then its line in ``levels.jsonl``, both
    written atomically under the store's lock; a corrupt or missing one is recomputed alone.
    With a multi-process ``cluster`` (:mod:`.distributed`, already initialised) every process
    calls this with the same arguments: the configs are compared (a differing one is refused
    on every process), process 0 alone opens the store and decides which levels are left,
    every process computes its chunks of each level (:func:`run_level`) and process 0 writes.
    ``cfg.chunk_runs=None`` takes the stored chunk or one sized from the device memory
    (:func:`resolve_chunk`; ``memory_bytes`` overrides the device's figure); a chunk that does
    not fit is refused before it runs, naming ``--chunk``.
    """
    from tqdm.auto import tqdm

    from . import distributed

    cluster = cluster or distributed.current()
    cfg = resolve_chunk(cfg, out, fresh=fresh, cluster=cluster, memory_bytes=memory_bytes)
    distributed.agree(cluster, dict(cfg.to_json(), layout=layout(cfg)), "padgett-mc config")
    levels = cfg.sigma_levels()
    st = log = None

    def prepare():  # process 0 only: open the store, check the records, list the levels left
        nonlocal st, log
        st = store if store is not None else open_store(cfg, out, fresh=fresh)
        log = st.records("levels.jsonl", key=lambda r: r["level"], required=LINE_FIELDS,
                         check=level_check(len(levels)))
        req = npz_required(cfg.representations)
        for i in list(log.done):
            if st.read_npz(f"level_{i:02d}.npz", req) is None:
                log.discard(i)
        return [i not in log for i in range(len(levels))]

    try:
        left = distributed.decide(cluster, len(levels), prepare)
        todo = [i for i in range(len(levels)) if left[i]]
        bar = tqdm(total=len(todo) * cfg.runs, desc="padgett-mc runs", unit="run",
                   disable=quiet or not cluster.is_main, file=sys.stderr)
        t0 = time.perf_counter()

        def compute(i):
            return run_level(cfg, i, levels[i]["sigma_r"], bar, cluster=cluster,
                             memory_bytes=memory_bytes)

        workers = level_workers(cluster)
        pool = ThreadPoolExecutor(workers) if workers > 1 else None
        try:
            results = pool.map(compute, todo) if pool else map(compute, todo)
            for i, res in zip(todo, results, strict=True):  # in level order
                bar.set_postfix_str(f"σ_R={levels[i]['sigma_r']:.1f} m")
                if cluster.is_main:
                    line, arrays = summarise_level(cfg, levels[i], res, i)
                    st.write_npz(f"level_{i:02d}.npz", arrays)
                    log.add(line)
        finally:
            if pool:
                pool.shutdown(cancel_futures=True)
        bar.close()
        elapsed = time.perf_counter() - t0
        if not cluster.is_main:
            return []
        timing = {"elapsed_s_this_invocation": elapsed, "levels_computed": len(todo),
                  "runs_per_level": cfg.runs, "devices_per_process": len(jax.local_devices()),
                  "processes": cluster.num_processes, "devices": len(jax.devices())}
        st.write_json("timing.json", timing, indent=2)
        done = log.values()
        st.write_results_csv(results_rows(done))
        return done
    finally:
        if store is None and st is not None:
            st.close()


#: the presets (``--tiny``, ``--reduced``; ``full`` = P's 1000 runs per level)
PRESETS: dict[str, dict] = {
    "tiny": {"runs": 4, "levels": 2, "num_samples": 16, "num_landmarks": 4,
             "representations": ("edc",)},
    "reduced": {"runs": 100},
    "full": {},
}

_FLAGS = {"runs": "runs", "levels": "levels", "num_samples": "samples",
          "num_landmarks": "landmarks"}


def configure(argv: list[str], overrides: dict | None = None
              ) -> tuple[Config, argparse.Namespace]:
    """The :class:`Config` and parsed flags of ``argv``, with ``overrides`` applied last.

    ``overrides`` maps Config fields to values (one cell of ``--sweep``,
    :mod:`pqrm_jax.studies.sweep`); the bounds are checked on the final config, naming the
    flag or the overridden field.
    """
    p = protocol.parser(NAME, HELP, seed=0, chunk=True)
    p.add_argument("--runs", type=protocol.positive_int,
                   help="Monte Carlo runs per noise level (default 1000, as P; reduced 100)")
    p.add_argument("--levels", type=protocol.positive_int,
                   help="main noise levels σ_R = 0..100 m (≥ 2; default 21, as P)")
    p.add_argument("--samples", type=protocol.positive_int,
                   help="samples per triplet per update (default 256)")
    p.add_argument("--landmarks", type=protocol.positive_int,
                   help="landmarks per world (≥ 3; default 10)")
    args = p.parse_args(argv)
    overrides = dict(overrides or {})
    cfg = protocol.apply_preset(Config, PRESETS, args.preset, args, _FLAGS)
    cfg = dataclasses.replace(cfg, seed=args.seed, chunk_runs=args.chunk or None)
    cfg = dataclasses.replace(cfg, **overrides)
    # (flag, Config field, smallest value, why)
    bounds = (("--runs", "runs", 1, ""), ("--chunk", "chunk_runs", 1, ""),
              ("--samples", "num_samples", 1, ""),
              ("--landmarks", "num_landmarks", 3, " (a triplet needs 3 landmarks)"),
              ("--levels", "levels", 2, " (the report compares σ_R = 0 with the next level)"),
              ("--seed", "seed", 0, ""), ("max_error_points", "max_error_points", 0, ""))
    for flag, attr, lo, why in bounds:
        if getattr(cfg, attr) is not None and getattr(cfg, attr) < lo:  # chunk_runs: None=auto
            p.error(f"{attr if attr in overrides else flag} must be ≥ {lo}{why}, "
                    f"got {getattr(cfg, attr)}")
    for attr in ("max_range", "dtheta_deg", "world_size", "loop_radius", "max_sigma_r"):
        if not (math.isfinite(getattr(cfg, attr)) and getattr(cfg, attr) > 0):
            p.error(f"{attr} must be > 0 and finite, got {getattr(cfg, attr)}")
    unknown = [r for r in cfg.representations if r not in REPS]
    if unknown or not cfg.representations:
        p.error(f"representations must be a non-empty subset of {', '.join(REPS)}, got "
                f"{'+'.join(cfg.representations) or 'none'}")
    return cfg, args


def sweep_summary(out: Path) -> dict:
    """Headline numbers and claim verdicts of a finished study directory (for ``--sweep``)."""
    from ._padgett_sweep import sweep_summary as summary

    return summary(out)


def report(out: Path) -> Path:
    """``report.md`` and the figures from the stored levels (under the store's lock)."""
    from ._padgett_report import write_report
    from .store import Store

    with Store.open(Path(out), NAME, None, legacy=LEGACY):
        return write_report(Path(out))


def claims(out: Path) -> list[protocol.Claim]:
    """Each published claim of P §2.3.1 (docs/decisions.md §3) against the stored levels."""
    from ._padgett_report import claim_rows

    cfg, lines, arrays = load_results(Path(out))
    return [protocol.Claim(name, pub, measured, criterion, verdict)
            for name, pub, measured, criterion, verdict in claim_rows(cfg, lines, arrays)]


main = protocol.main_for(sys.modules[__name__])


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1:]))


__all__ = ["Config", "PRESETS", "claims", "configure", "report", "sweep_summary", "run_study",
           "run_level", "run_keys", "auto_chunk",
           "chunk_compiler_options", "CHUNK_COMPILER_OPTIONS", "CPU_CHUNK_RUNS",
           "resolve_chunk", "chunk_program", "level_workers", "summarise_level", "memory_error",
           "load_results", "main", "boundary_distance"]
