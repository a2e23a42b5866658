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

Third part (``--traverse``, issue #27 item 4): the kernel's speed on the Mars-Yard traverse
(benchmarks/bench_warm.py ``--what traverse``: 30 landmarks, 50 images, 18 nearest → 816
triples an image, float32, default tolerance). Per image, CPU and wall seconds of
:func:`pqrm_jax.qrm.exact_camera.exact_sets` as shipped (the screen: full tolerant decision
only on the flagged triples) against ``screen=False`` (the full decision on every triple,
the kernel before the screen) and against tolerance 0, interleaved in one process; the
ratios survive load. The sets of both tolerant paths must be identical; the triples flagged
per image and the whole warm ``run_sequence`` are recorded too.

    /work/bin/heavy .venv/bin/python benchmarks/bench_qrm_tolerance.py \
        [--layouts 40] [--images 4] [--out benchmarks/results/qrm_tolerance.json]
    /work/bin/heavy .venv/bin/python benchmarks/bench_qrm_tolerance.py --traverse-only \
        [--out benchmarks/results/qrm_tolerance_traverse.json]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _env import write_result  # noqa: E402  benchmarks/_env.py

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


def traverse_speed(rounds: int = 3) -> dict:
    """Per-image CPU/wall seconds of the screened kernel vs ``screen=False`` and tolerance 0
    on the traverse's images (float32), interleaved; the sets must be identical."""
    from pqrm_jax.qrm import exact_camera as X
    from pqrm_jax.qrm import pipeline as P

    spec = qrm_spec("edc")
    lm = sim.uniform_landmarks(jax.random.key(1), 30, (30.0, 30.0))
    poses = sim.traverse(jax.random.key(2), 50, size=(30.0, 30.0))
    sensor = sim.SensorParams(max_range=1e6)
    tri = C.slot_triples(18)
    imgs = []
    for p in poses:  # the 816 triples of each image, as run_sequence measures them
        cam = sim.camera(p, lm, sensor)
        ids = np.asarray(C.select_nearest(cam.range_rank, cam.visible, 18))
        imgs.append(jnp.asarray(np.asarray(cam.bearings)[ids[tri]]))
    tol = jnp.asarray(C.default_tolerance(np.float32), jnp.float32)
    paths = {
        "screened": jax.jit(lambda b, t: X.exact_sets(spec, b, t)),
        "all_triples": jax.jit(lambda b, t: X.exact_sets(spec, b, t, screen=False)),
        "tol0": jax.jit(lambda b: X.exact_sets(spec, b, 0.0)),
    }
    args = {"screened": (tol,), "all_triples": (tol,), "tol0": ()}
    same = True
    for b in imgs:
        a, r = paths["screened"](b, tol), paths["all_triples"](b, tol)
        same &= all(bool(jnp.all(x == y)) for x, y in zip(a, r, strict=True))
    flags = jax.jit(lambda b, t: X.tolerant_flags(spec, b, t))
    nflag = [int(flags(b, tol).sum()) for b in imgs]
    times = {k: {"cpu_s": [], "wall_s": []} for k in paths}
    for _ in range(rounds):
        for k, f in paths.items():
            jax.block_until_ready(f(imgs[0], *args[k]))
            c0, w0 = time.process_time(), time.perf_counter()
            for b in imgs:
                out = f(b, *args[k])
            jax.block_until_ready(out)
            times[k]["cpu_s"].append((time.process_time() - c0) / len(imgs))
            times[k]["wall_s"].append((time.perf_counter() - w0) / len(imgs))
    best = {k: min(v["cpu_s"]) for k, v in times.items()}
    # the whole warm traverse (the shipped kernel only)
    jax.block_until_ready(P.run_sequence(lm, poses, 18)[0].rel)
    c0, w0 = time.process_time(), time.perf_counter()
    jax.block_until_ready(P.run_sequence(lm, poses, 18)[0].rel)
    run = {"cpu_s": time.process_time() - c0, "wall_s": time.perf_counter() - w0}
    size = X.screen_buffer(int(tri.shape[0]))
    res = dict(images=len(imgs), triples=int(tri.shape[0]), identical_sets=bool(same),
               flagged_mean=float(np.mean(nflag)), flagged_max=int(max(nflag)),
               buffer=size, one_chunk_images=int(sum(n <= size for n in nflag)),
               overflow_images=int(sum(n > size for n in nflag)),
               per_image=times, best_cpu_s=best,
               cpu_ratio_screened_vs_all=best["screened"] / best["all_triples"],
               cpu_ratio_screened_vs_tol0=best["screened"] / best["tol0"],
               run_sequence_warm=run, load_avg=os.getloadavg())
    print(f"traverse kernel per image (best of {rounds}, CPU ms): screened "
          f"{1e3 * best['screened']:.1f}, all triples {1e3 * best['all_triples']:.1f}, tol 0 "
          f"{1e3 * best['tol0']:.1f}; ratio screened/all {res['cpu_ratio_screened_vs_all']:.3f}"
          f"; flagged {res['flagged_mean']:.1f} (max {res['flagged_max']}, buffer "
          f"{res['buffer']}, overflow in {res['overflow_images']} images); identical sets "
          f"{same}; warm run_sequence {run['wall_s']:.2f} s wall {run['cpu_s']:.2f} CPU-s "
          f"(load {os.getloadavg()[0]:.1f})", flush=True)
    return res


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--layouts", type=int, default=40, help="layouts per kind and dtype")
    ap.add_argument("--images", type=int, default=4, help="images per layout")
    ap.add_argument("--triples", type=int, default=4096, help="triples per spread")
    ap.add_argument("--seed", type=int, default=27)
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--traverse", action="store_true",
                    help="also time the kernel on the Mars-Yard traverse (screen vs all)")
    ap.add_argument("--traverse-only", action="store_true", help="only the traverse timing")
    a = ap.parse_args(argv)
    if a.layouts < 1 or a.images < 1 or a.triples < 1:
        ap.error("--layouts, --images and --triples must be >= 1")
    kinds = a.kinds.split(",")
    bad = [k for k in kinds if k not in KINDS]
    if bad:
        ap.error(f"--kinds: unknown {bad}; choose from {KINDS}")
    t0, c0 = time.perf_counter(), time.process_time()
    res = dict(layouts=a.layouts, images=a.images, kinds=[],
               spread_cost=[])
    if a.traverse or a.traverse_only:
        res["traverse_speed"] = traverse_speed()
    for dtype in (() if a.traverse_only else (np.float32, np.float64)):
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
    res["wall_s"], res["cpu_s"] = time.perf_counter() - t0, time.process_time() - c0
    if a.out:  # + env: where it ran, the load, the process's CPU seconds
        write_result(res, a.out)
    return res


if __name__ == "__main__":
    main()
