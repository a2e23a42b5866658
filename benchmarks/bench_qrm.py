"""QRM camera-measurement + map-update benchmarks (issue #4, docs/decisions.md §10).

1. Per-update time vs n (n nearest of 30 landmarks): the first update (every state open,
   the peak of M Fig. 7d) and the mean over the following images; fitted log-log slope of
   the peak, beside McClelland's 3.5.
2. Batched pipeline vs one triple at a time, same algorithm, same process: the batched
   measurement kernel on all C(n,3) triples + the dense fixed-point update, against the same
   kernel called once per triple (compiled for one triple) + the one-relation-at-a-time
   worklist propagation of :mod:`pqrm_jax.qrm.reference` (M§VI.B steps 1–9 literally).
3. The whole Mars-Yard-like traverse (50 images 1–2 m apart, 18 nearest of 30 landmarks):
   wall time of the compiled scan (McClelland: 250 s).

    .venv/bin/python benchmarks/bench_qrm.py [--quick]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import jax
import numpy as np
from _env import write_result  # benchmarks/_env.py

from pqrm_jax import sim
from pqrm_jax.qrm import camera as C
from pqrm_jax.qrm import hypergraph as H
from pqrm_jax.qrm import pipeline as P
from pqrm_jax.qrm.reference import ReferenceMap
from pqrm_jax.qrm.spec import qrm_spec

SENSOR = sim.SensorParams(max_range=1e6)


def per_update_vs_n(ns, images: int, reps: int) -> dict:
    spec = qrm_spec("edc")
    lm = sim.uniform_landmarks(jax.random.key(0), 30)
    poses = sim.random_imaging_points(jax.random.key(1), images)
    truth = H.true_relations(lm, spec)
    out = {}
    for n in ns:
        m0 = H.empty_map(30, spec)
        m, _ = P.map_step(m0, poses[0], lm, n, spec, truth=truth)  # compile
        jax.block_until_ready(m.rel)
        peak = []
        for _ in range(reps):
            t0 = time.perf_counter()
            m, _ = P.map_step(m0, poses[0], lm, n, spec, truth=truth)
            jax.block_until_ready(m.rel)
            peak.append(time.perf_counter() - t0)
        later = []
        for t in range(1, images):
            t0 = time.perf_counter()
            m, _ = P.map_step(m, poses[t], lm, n, spec, truth=truth)
            jax.block_until_ready(m.rel)
            later.append(time.perf_counter() - t0)
        out[n] = {"peak_s": float(np.min(peak)), "later_mean_s": float(np.mean(later))}
        print(f"n={n:2d}: first update {out[n]['peak_s']:.4f} s, later mean "
              f"{out[n]['later_mean_s']:.4f} s")
    ns_ = np.array(list(out), float)
    pk = np.array([out[n]["peak_s"] for n in out])
    slope = float(np.polyfit(np.log(ns_), np.log(pk), 1)[0])
    return {"per_n": out, "peak_loglog_slope": slope, "paper_slope": 3.5}


def batched_vs_single(n: int, images: int) -> dict:
    spec = qrm_spec("edc")
    lm = sim.uniform_landmarks(jax.random.key(2), n)
    poses = sim.random_imaging_points(jax.random.key(3), images)
    cams = [sim.camera(p, lm, SENSOR) for p in poses]

    def batched():
        m = H.empty_map(n, spec)
        for cam in cams:
            meas = C.measure_image(cam.bearings, cam.range_rank, cam.visible, n, spec, m.rel,
                                   check=False)
            m, _ = H.update_image(m, meas, spec)
        return jax.block_until_ready(m.rel)

    tri = C.slot_triples(n)

    def single():
        ref = ReferenceMap(spec, n)
        for cam in cams:
            ids = np.asarray(C.select_nearest(cam.range_rank, cam.visible, n))
            b = np.asarray(cam.bearings)
            before = ref.rel.copy()  # the batched update also tests against the prior map
            for s in tri:
                lid = ids[s]
                target = np.array([[before[lid[X], lid[Y], lid[Z]] for X, Y, Z in C.CYCLIC]],
                                  np.uint32)
                meas = C.measure_triples(b[lid][None], spec, target, exact=False)
                sets = np.asarray(meas.sets)[0]
                for o, (X, Y, Z) in enumerate(C.CYCLIC):
                    ref.update((lid[X], lid[Y], lid[Z]), int(sets[o]))
        return ref.rel

    a = batched()
    t0 = time.perf_counter()
    a = batched()
    tb = time.perf_counter() - t0
    single()  # compile the one-triple kernel
    t0 = time.perf_counter()
    r = single()
    ts = time.perf_counter() - t0
    d = H.distinct_mask(n)
    same = bool((np.asarray(a)[d] == r[d].astype(np.uint32)).all())
    print(f"batched {tb:.3f} s vs one-triple-at-a-time {ts:.3f} s: {ts / tb:.1f}x "
          f"(identical maps: {same})")
    return {"n": n, "images": images, "triples_per_image": int(len(tri)), "batched_s": tb,
            "single_s": ts, "speedup": ts / tb, "identical_maps": same, "target": 50.0}


def traverse(reps: int) -> dict:
    lm = sim.uniform_landmarks(jax.random.key(1), 30, (30.0, 30.0))
    poses = sim.traverse(jax.random.key(2), 50, size=(30.0, 30.0))
    t0 = time.perf_counter()
    m, _ = P.run_sequence(lm, poses, 18)
    jax.block_until_ready(m.rel)
    compile_s = time.perf_counter() - t0
    walls = []
    for _ in range(reps):
        t0 = time.perf_counter()
        m, met = P.run_sequence(lm, poses, 18)
        jax.block_until_ready(m.rel)
        walls.append(time.perf_counter() - t0)
    print(f"Mars-Yard-like traverse: {min(walls):.2f} s (first call incl. compile "
          f"{compile_s:.1f} s); McClelland 250 s, target <= 1 s (issue #14)")
    return {"wall_s_min": float(min(walls)), "wall_s_all": walls, "compile_plus_run_s": compile_s,
            "paper_s": 250.0, "target_s": 1.0, "truth_kept": bool(met.truth_kept.all())}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "qrm.json"))
    a = ap.parse_args()
    ns = (6, 12, 18, 30) if a.quick else (6, 9, 12, 18, 24, 30)
    res = {"devices": [str(d) for d in jax.devices()], "cpu_count": os.cpu_count(),
           "load_avg_start": os.getloadavg()}
    res["per_update"] = per_update_vs_n(ns, images=6 if a.quick else 11, reps=2 if a.quick else 3)
    res["batched_vs_single"] = batched_vs_single(n=10 if a.quick else 18, images=2)
    res["traverse"] = traverse(reps=1 if a.quick else 3)
    res["load_avg_end"] = os.getloadavg()
    print(f"peak per-update log-log slope {res['per_update']['peak_loglog_slope']:.2f} "
          "(paper 3.5)")
    write_result(res, a.out)  # + env: where it ran; timings with CPU time


if __name__ == "__main__":
    main()
