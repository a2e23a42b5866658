"""Benchmark: HSSH cellular stages batched in JAX vs a per-image scipy/scikit-image pipeline,
and local-topology throughput on a 300 x 300 LPM (B §6.2.1: ~2 Hz on a Pentium III 450 MHz).

    .venv/bin/python benchmarks/bench_hssh.py [--batch B [B ...]] [--side N] [--noise P]
        [--repeats R] [--json PATH]

Workload, for each batch size ``B`` (default 16 and 64): ``B`` noisy +-intersection grids
of ``N x N`` cells (corpus drawing, 25° rotation,
free-cell noise ``P``), all in the same process:

* ``batched_s`` -- :func:`pqrm_jax.hssh.cellular_stages` on the whole stack (island removal,
  exact distance transform, EVG thinning = Zhang--Suen twice) in one jitted program, best of 3
  after a warm-up (compile excluded, reported separately as ``compile_s``).
* ``reference_s`` -- the same stages one image at a time with the field's C libraries:
  ``scipy.ndimage.label`` (4-connected) for island removal, ``distance_transform_edt`` and
  scikit-image ``skeletonize(method='zhang')`` (one thinning, no EVG cap: less work than the
  batched side does). ``speedup`` = reference / batched. Timings are the best of
  ``--repeats`` alternating rounds (batched, reference, batched, ...), so a load change on a
  shared machine hits both sides alike.
* ``stages_s`` -- the batched stages one by one (island removal, distance transform, first and
  second thinning of the EVG), each its own jitted call, best of the same rounds.
* ``local_topology_hz`` / ``gateways_per_s`` -- the whole pipeline
  (:func:`pqrm_jax.hssh.local_topology_batch`: cellular stages + host graph stages) on the
  stack of 300 x 300 grids, per image (first batch size only).

Results go to ``benchmarks/results/hssh.json`` with ``env`` (backend, device, load average:
``benchmarks/_env.py``).
"""

from __future__ import annotations

import argparse
import json
import platform
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from scipy import ndimage
from skimage.morphology import skeletonize

from pqrm_jax import hssh
from pqrm_jax.sim.corridors import plus_image

try:
    from _env import device_info, write_result
    from _timing import timed
except ImportError:  # run from the repository root
    from benchmarks._env import device_info, write_result
    from benchmarks._timing import timed


def _grids(batch: int, side: int, noise: float, seed: int = 0) -> np.ndarray:
    base = np.asarray(plus_image(side, 25.0)) < 128
    rng = np.random.default_rng(seed)
    return np.stack([base | ((rng.random(base.shape) < noise) & ~base) for _ in range(batch)])


def _reference(occ: np.ndarray) -> list:
    out = []
    for g in occ:
        lab, _ = ndimage.label(g)
        edge = np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))
        keep = np.isin(lab, edge[edge > 0])
        occ_i = g & keep
        dist = ndimage.distance_transform_edt(~occ_i)
        out.append((dist, skeletonize(~occ_i, method="zhang")))
    return out


def _timed(f):
    wall, _, out = timed(f)  # CPU time logged beside it (benchmarks/_timing.py)
    return wall, out


def _stage_fns(jo, ju, side):
    m = side / 5.0
    cap = int(np.ceil(m + 2.0))
    occ, _ = hssh.remove_islands(jo, ju)
    d2 = hssh.squared_distance_transform(occ, cap=cap)
    free = ~occ
    far = free & (d2 >= m * m)
    first = hssh.zhang_suen_thin(free, far, pad=True)
    rim = first & (d2 < (m + 1.5) ** 2)
    return {
        "remove_islands": lambda: hssh.remove_islands(jo, ju),
        "distance_transform": lambda: hssh.squared_distance_transform(occ, cap=cap),
        "thinning_1": lambda: hssh.zhang_suen_thin(free, far, pad=True),
        "thinning_2": lambda: hssh.zhang_suen_thin(rim, None, pad=True),
    }


def bench_batch(batch: int, side: int, noise: float, repeats: int) -> dict:
    """Batched cellular stages vs the per-image C pipeline on ``batch`` grids."""
    occ = _grids(batch, side, noise)
    jo, ju = jnp.asarray(occ), jnp.asarray(np.zeros_like(occ))
    compile_s, _ = _timed(lambda: hssh.cellular_stages(jo, ju))
    stages = _stage_fns(jo, ju, side)
    for f in stages.values():
        jax.block_until_ready(f())  # compile
    tb, tr, ts = [], [], {k: [] for k in stages}
    maps = ref = None
    for _ in range(repeats):
        t, maps = _timed(lambda: hssh.cellular_stages(jo, ju))
        tb.append(t)
        t, ref = _timed(lambda: _reference(occ))
        tr.append(t)
        for k, f in stages.items():
            ts[k].append(_timed(f)[0])
    batched_s, reference_s = min(tb), min(tr)
    # the distance transforms agree exactly below the cap (same algorithm); skeletons differ
    # by design (EVG cap, scikit-image's table)
    d2 = np.asarray(maps.dist2)
    below = d2 <= (0.2 * side) ** 2
    dist_equal = all(np.array_equal(d2[i][below[i]], np.rint(ref[i][0] ** 2)[below[i]])
                     for i in range(batch))
    return {
        "batch": batch, "compile_s": compile_s, "batched_s": batched_s,
        "reference_s": reference_s, "speedup": reference_s / batched_s,
        "batched_ms_per_image": 1e3 * batched_s / batch,
        "reference_ms_per_image": 1e3 * reference_s / batch,
        "stages_s": {k: min(v) for k, v in ts.items()},
        "distance_transform_equal_below_cap": bool(dist_equal),
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--batch", type=int, nargs="+", default=[16, 64])
    p.add_argument("--side", type=int, default=300)
    p.add_argument("--noise", type=float, default=0.1)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--out", "--json", dest="out",
                   default=str(Path(__file__).parent / "results" / "hssh.json"))
    args = p.parse_args()
    env_start = device_info()
    runs = [bench_batch(b, args.side, args.noise, args.repeats) for b in args.batch]
    occ = _grids(args.batch[0], args.side, args.noise)
    rc = [(args.side // 2, args.side // 2)] * len(occ)
    hssh.local_topology_batch(occ, rc)  # warm-up
    full_s, lts = _timed(lambda: hssh.local_topology_batch(occ, rc))
    n_gw = sum(len(lt.gateways) for lt in lts)
    res = {
        "workload": f"grids {args.side}x{args.side}, + at 25 deg, noise {args.noise}, "
                    f"batches {args.batch}",
        "platform": platform.platform(),
        "runs": runs,
        "speedup": {str(r["batch"]): r["speedup"] for r in runs},
        "local_topology_s": full_s, "local_topology_hz": len(occ) / full_s,
        "gateways_per_s": n_gw / full_s, "gateways_found": n_gw,
        "correct_plus": sum(bool(hssh.star_isomorphisms(lt.star, [(0, 1, True), (1, 1, True),
                                                                 (0, -1, True), (1, -1, True)]))
                            for lt in lts),
        "thesis_reference_hz": "~2 Hz on a 300x300 LPM, Pentium III 450 MHz (B §6.2.1)",
        "load_average_start": env_start["load_average"],
    }
    print(json.dumps(res, indent=1))
    write_result(res, args.out)  # + env at the end and timings with CPU time
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
