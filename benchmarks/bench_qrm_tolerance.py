"""Soundness of the camera measurement for the scene under the rounding of the bearings (#27).

Random scenes of every kind — ``uniform``, ``far_cluster``, ``collinear_1e-5`` …
``collinear_1e-9`` (landmarks within that relative distance of a common line),
``equal_bearings`` (landmarks on a few rays from the camera), ``near_ray`` (three
landmarks within ~2e-8 relative of one ray: their float32 bearings often round to one
value), ``equidistant`` (ranges equal
within ~1e-7 relative), ``camera_at_landmark`` — are imaged by the simulator's camera
(:func:`pqrm_jax.sim.sensors.camera_kernel`) in float32 and in float64. For every image
the ``n`` nearest landmarks are measured (:func:`pqrm_jax.qrm.camera.measure_image`, the
batched kernel as the pipeline runs it) at bearing tolerance 0 ("before": exact for the
computed bearings) and at the dtype's default (:func:`pqrm_jax.qrm.camera.default_tolerance`),
and every cyclic relation is checked against its **exact** true state, decided in rational
arithmetic on the landmark coordinates (relations whose truth is a boundary, e.g. exactly
collinear after rounding, are counted apart: no open state holds them). Each layout's images
are also fused by the mapper (``qrm.mapper``), image by image, and the inconsistent updates
counted (noise-free images: every one is a lost truth).

Second part: the set-size cost of the default tolerance per bearing spread (random triples
with bearings uniform in a sector, as benchmarks/bench_camera_exact.py), mean states kept
per relation by the kernel at tolerance 0 and at the default, float32 and float64.

    /work/bin/heavy .venv/bin/python benchmarks/bench_qrm_tolerance.py \
        [--layouts 40] [--images 4] [--out benchmarks/results/qrm_tolerance.json]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _env import device_info  # noqa: E402  benchmarks/_env.py

from pqrm_jax import qrm, sim  # noqa: E402
from pqrm_jax.qrm import camera as C  # noqa: E402
from pqrm_jax.qrm.spec import CYCLIC, popcount, qrm_spec  # noqa: E402
from pqrm_jax.tables.exact import exact_interior_state  # noqa: E402

N = 6  # landmarks per layout, all measured (n = N): 20 triples, 60 relations per image
KINDS = ("uniform", "far_cluster", "collinear_1e-5", "collinear_1e-7", "collinear_1e-9",
         "equal_bearings", "near_ray", "equidistant", "camera_at_landmark")
SPREADS = (0.003, 0.05, 0.3, 1.0, 2 * np.pi)


def scene(kind: str, rng: np.random.Generator, images: int):
    """(landmarks [N, 2], poses [images, 3]) float64, of one kind."""
    head = rng.uniform(-np.pi, np.pi, images)
    if kind == "uniform":
        lm = rng.uniform(0, 100, (N, 2))
        xy = rng.uniform(0, 100, (images, 2))
    elif kind == "far_cluster":
        c = rng.uniform(-50, 50, 2)
        lm = c + rng.normal(0, rng.uniform(0.1, 2.0), (N, 2))
        ang = rng.uniform(-np.pi, np.pi, images)
        dist = np.exp(rng.uniform(np.log(50), np.log(1000), images))
        xy = c + dist[:, None] * np.stack([np.cos(ang), np.sin(ang)], -1)
    elif kind.startswith("collinear"):
        rel = float(kind.split("_")[1])
        a, ang = rng.uniform(-50, 50, 2), rng.uniform(-np.pi, np.pi)
        u, v = np.array([np.cos(ang), np.sin(ang)]), np.array([-np.sin(ang), np.cos(ang)])
        s = rng.uniform(-50, 50, N)
        lm = a + s[:, None] * u + (rel * 100 * rng.normal(0, 1, N))[:, None] * v
        off = rng.choice([-1, 1], images) * rng.uniform(5, 60, images)
        xy = a + rng.uniform(-60, 60, images)[:, None] * u + off[:, None] * v
    elif kind == "equal_bearings":  # 3 rays from the first pose, 2 landmarks on each
        p = rng.uniform(-50, 50, 2)
        phi = np.repeat(rng.uniform(-np.pi, np.pi, 3), 2)
        r = rng.uniform(5, 60, N)
        lm = p + r[:, None] * np.stack([np.cos(phi), np.sin(phi)], -1)
        xy = np.concatenate([p[None], rng.uniform(-60, 60, (images - 1, 2))])
    elif kind == "near_ray":  # 3 landmarks within ~2e-8 (relative) of one ray of the first pose
        p = rng.uniform(-50, 50, 2)
        phi = rng.uniform(-np.pi, np.pi)
        w, nrm = np.array([np.cos(phi), np.sin(phi)]), np.array([-np.sin(phi), np.cos(phi)])
        r = rng.uniform(5, 60, 3)
        ray = p + r[:, None] * w + (rng.normal(0, 2e-8, 3) * r)[:, None] * nrm
        lm = np.concatenate([ray, p + rng.uniform(-60, 60, (N - 3, 2))])
        xy = np.concatenate([p[None], rng.uniform(-60, 60, (images - 1, 2))])
    elif kind == "equidistant":  # every landmark at ~R from the first pose
        p = rng.uniform(-50, 50, 2)
        phi = rng.uniform(-np.pi, np.pi, N)
        r = rng.uniform(10, 60) * (1 + 1e-7 * rng.normal(0, 1, N))
        lm = p + r[:, None] * np.stack([np.cos(phi), np.sin(phi)], -1)
        xy = np.concatenate([p[None], rng.uniform(-60, 60, (images - 1, 2))])
    elif kind == "camera_at_landmark":
        lm = rng.uniform(0, 100, (N, 2))
        xy = lm[rng.integers(0, N, images)]
    else:
        raise ValueError(kind)
    return lm, np.concatenate([xy, head[:, None]], -1)


def exact_state(spec, P, X, Y, Z) -> int:
    """True state index of XY:Z from exact coordinates (rational), −1 on a boundary."""
    return exact_interior_state(spec.calc, *(tuple(float(c) for c in P[i]) for i in (X, Y, Z)))


def programs(dtype, tols):
    """The compiled measurement (vmapped over images) and mapper update of each tolerance."""
    spec = qrm_spec("edc")
    meas = {t: jax.jit(jax.vmap(lambda b, r, v, t=t: C.measure_image_kernel(
        spec, b, r, v, None, jnp.asarray(t, dtype), n=N))) for t in tols}
    mappers = {t: qrm.mapper(spec, N, n=N, tol=t) for t in tols}
    scans = {t: jax.jit(lambda cams, qm=qm: jax.lax.scan(
        lambda m, img: qm.update(m, jax.random.key(0), img), qm.init(), cams)[1])
             for t, qm in mappers.items()}
    return meas, scans


def check_kind(kind, dtype, layouts, images, seed, tols, progs):
    spec = qrm_spec("edc")
    rng = np.random.default_rng(seed)
    sensor = sim.SensorParams(max_range=1e9)
    out = {str(t): dict(relations=0, dropped=0, open_sum=0, inconsistent=0, updates=0,
                        undecided=0) for t in tols}
    boundary = 0
    meas, scans = progs
    drops = []
    for _ in range(layouts):
        lm, poses = scene(kind, rng, images)
        lm, poses = lm.astype(dtype), poses.astype(dtype)
        cams = jax.vmap(lambda p, lm=lm: sim.sensors.camera_kernel(
            p, jnp.asarray(lm), sensor))(jnp.asarray(poses))
        truth = {}
        for t in tols:
            m = meas[t](cams.bearings, cams.range_rank, cams.visible)
            ids, sets = np.asarray(m.triples), np.asarray(m.sets)
            valid, und = np.asarray(m.valid), np.asarray(m.undecided)
            for im in range(images):
                for r in np.flatnonzero(valid[im]):
                    for o, (X, Y, Z) in enumerate(CYCLIC):
                        key = tuple(ids[im, r, [X, Y, Z]])
                        if key not in truth:
                            truth[key] = exact_state(spec, lm, *key)
                        st = truth[key]
                        if st < 0:
                            boundary += 1
                            continue
                        rec = out[str(t)]
                        rec["relations"] += 1
                        rec["open_sum"] += int(popcount(np.uint32(sets[im, r, o])))
                        rec["undecided"] += int(popcount(np.uint32(und[im, r, o])))
                        if not int(sets[im, r, o]) >> st & 1:
                            rec["dropped"] += 1
                            if len(drops) < 5:
                                b = np.asarray(cams.bearings)[im][list(key)]
                                drops.append(dict(tol=t, relation=[int(k) for k in key],
                                                  truth=st, bearings=b.tolist(),
                                                  set=int(sets[im, r, o])))
            rep = scans[t](cams)
            out[str(t)]["inconsistent"] += int(np.asarray(rep.inconsistent).sum())
            out[str(t)]["updates"] += images
    for rec in out.values():
        rec["mean_open"] = rec["open_sum"] / max(rec["relations"], 1)
    return dict(kind=kind, dtype=np.dtype(dtype).name, boundary_relations=boundary // len(tols),
                by_tol=out, examples=drops)


def spread_cost(dtype, count, seed):
    rows = []
    for k, spread in enumerate(SPREADS):
        rng = np.random.default_rng(seed + k)
        c = rng.uniform(-np.pi, np.pi, (count, 1))
        b = (c + rng.uniform(0, spread, (count, 3))).astype(dtype)
        row = dict(spread=spread)
        for name, t in (("tol0", 0.0), ("default", C.default_tolerance(dtype))):
            m = C.measure_triples(b, "edc", exact=False, tol=t)
            row[name] = float(np.asarray(popcount(m.sets)).mean())
            row[name + "_undecided"] = float(np.asarray(popcount(m.undecided)).mean())
        rows.append(row)
    return dict(dtype=np.dtype(dtype).name, rows=rows)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--layouts", type=int, default=40, help="layouts per kind and dtype")
    ap.add_argument("--images", type=int, default=4, help="images per layout")
    ap.add_argument("--triples", type=int, default=4096, help="triples per spread")
    ap.add_argument("--seed", type=int, default=27)
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args(argv)
    if a.layouts < 1 or a.images < 1 or a.triples < 1:
        ap.error("--layouts, --images and --triples must be >= 1")
    kinds = a.kinds.split(",")
    bad = [k for k in kinds if k not in KINDS]
    if bad:
        ap.error(f"--kinds: unknown {bad}; choose from {KINDS}")
    t0 = time.time()
    res = dict(device=device_info(), layouts=a.layouts, images=a.images, kinds=[],
               spread_cost=[])
    for dtype in (np.float32, np.float64):
        tols = (0.0, C.default_tolerance(dtype))
        progs = programs(dtype, tols)
        for i, kind in enumerate(kinds):
            r = check_kind(kind, dtype, a.layouts, a.images, a.seed + 1000 * i, tols, progs)
            res["kinds"].append(r)
            b0, b1 = (r["by_tol"][str(t)] for t in tols)
            print(f"{r['dtype']:8s} {kind:19s} rel {b1['relations']:6d}  dropped "
                  f"{b0['dropped']:4d} -> {b1['dropped']:4d}  inconsistent {b0['inconsistent']:3d}"
                  f" -> {b1['inconsistent']:3d}/{b1['updates']}  mean open {b0['mean_open']:.3f}"
                  f" -> {b1['mean_open']:.3f}  undecided {b1['undecided']}", flush=True)
        sc = spread_cost(dtype, a.triples, a.seed)
        res["spread_cost"].append(sc)
        for row in sc["rows"]:
            print(f"{sc['dtype']:8s} spread {row['spread']:.3f}: mean states {row['tol0']:.4f}"
                  f" -> {row['default']:.4f} (undecided {row['tol0_undecided']:.4f} -> "
                  f"{row['default_undecided']:.4f})", flush=True)
    res["wall_s"] = time.time() - t0
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        tmp = a.out.with_suffix(".tmp")
        tmp.write_text(json.dumps(res, indent=1))
        tmp.replace(a.out)
    return res


if __name__ == "__main__":
    main()
