"""The row traffic of the sparse update's piece loop: the map's arrays as they are against
one packed array — the most a packed map layout could save (issue 31, docs/benchmarks.md
§bench_padgett).

    .venv/bin/python benchmarks/bench_piece_layout.py [--runs 1000] [--repeat 3]
                                                      [--out benchmarks/results/piece_layout.json]

The padgett-mc map (``pqrm.mapper`` of the study's configuration: 10 landmarks, 720
triplets, the six representations) for ``--runs`` runs, flattened to rows as the sparse
update does. Each run sees the triplets of a random half of its landmarks at each of the 23
steps (about 1 triplet in 8, as in the study), and the seen rows are compacted in order and
cut into pieces of 1 024 rows. The loop over the pieces gathers every seen row, changes
every field (each probability halved, each counter incremented, ``mapped`` set) and scatters
it back — the gathers and scatters of ``_sparse_group_update`` without the sampling kernel
and eq. 2.10:

* **fields** — the per-triplet arrays of :class:`pqrm_jax.pqrm.MapState` as the map stores
  them (15 for six representations: the probability tables, the conflict counters,
  ``mapped``, ``num_updates``, ``num_rejected``; taken from the state, counted in the JSON);
* **packed** — one [rows, ΣQ + counters] float32 array holding the same fields (counters
  and flags bitcast), one gather and one scatter a piece.

Both loops compute the same values (checked). Wall and CPU seconds of each, best of
``--repeat``, alternating in one process, and the ratio.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _env import write_result  # noqa: E402
from _timing import best_of_cpu  # noqa: E402

BLOCK = 1024
STEPS = 23


def seen_pieces(pq, runs: int, seed: int = 0) -> np.ndarray:
    """[P, BLOCK] int32 row indices (``runs · T`` = padding): each step's seen rows in order."""
    rng = np.random.default_rng(seed)
    tri = np.asarray(pq.triplets)
    t = len(tri)
    out = []
    for _ in range(STEPS):
        vis = rng.random((runs, pq.num_landmarks)) < 0.5
        seen = np.all(vis[:, tri], axis=-1).reshape(-1)
        idx = np.flatnonzero(seen)
        out.append(np.concatenate([idx, np.full(-len(idx) % BLOCK, runs * t)]))
    return np.concatenate(out).reshape(-1, BLOCK).astype(np.int32)


def row_arrays(state) -> list:
    """The per-triplet arrays of a map state (every leaf with a triplet axis), in leaf order."""
    return [x for x in jax.tree_util.tree_leaves(state) if x.ndim >= 1]


def bump(x):
    """The change a piece makes to a field: probabilities halved, counters +1, flags set."""
    return x | True if x.dtype == bool else x * 0.5 if jnp.issubdtype(x.dtype, jnp.floating) \
        else x + 1


@jax.jit
def loop_fields(rows, pieces):
    def body(c):
        p, rows = c
        idx = pieces[p]
        return p + 1, jax.tree_util.tree_map(
            lambda x: x.at[idx].set(bump(x[idx]), mode="drop"), rows)

    return jax.lax.while_loop(lambda c: c[0] < pieces.shape[0], body, (0, rows))[1]


def pack(rows) -> jax.Array:
    """The row arrays side by side in one [rows, W] float32 array (integers and flags bitcast),
    probability columns first."""
    floats = [x for x in rows if x.ndim == 2]
    ints = [x.astype(jnp.int32) for x in rows if x.ndim == 1]
    return jnp.concatenate([*floats, jax.lax.bitcast_convert_type(jnp.stack(ints, -1),
                                                                  jnp.float32)], axis=-1)


def column_kinds(rows) -> np.ndarray:
    """[W] what :func:`bump` does to each packed column: 0 halve, 1 add one, 2 set to one."""
    floats = [np.zeros(x.shape[1], np.int32) for x in rows if x.ndim == 2]
    ints = [np.int32(2 if x.dtype == bool else 1) for x in rows if x.ndim == 1]
    return np.concatenate([*floats, np.array(ints, np.int32)])


@jax.jit
def loop_packed(packed, pieces, kinds):
    def body(c):
        p, x = c
        idx = pieces[p]
        g = x[idx]
        ints = jax.lax.bitcast_convert_type(g, jnp.int32)
        ints = jax.lax.bitcast_convert_type(jnp.where(kinds == 2, 1, ints + 1), jnp.float32)
        return p + 1, x.at[idx].set(jnp.where(kinds == 0, g * 0.5, ints), mode="drop")

    return jax.lax.while_loop(lambda c: c[0] < pieces.shape[0], body, (0, packed))[1]


def main(argv=None) -> int:
    from pqrm_jax import calculi, pqrm

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=1000)
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--out", default="benchmarks/results/piece_layout.json")
    a = p.parse_args(argv)

    pq = pqrm.mapper(calculi.PADGETT_REPRESENTATIONS, 10, 256)
    pieces = jnp.asarray(seen_pieces(pq, a.runs))
    r = a.runs

    def fresh():
        return jax.block_until_ready([
            jnp.broadcast_to(x, (r, *x.shape)).reshape(r * x.shape[0], *x.shape[1:])
            for x in row_arrays(pq.init())])

    kinds = jnp.asarray(column_kinds(fresh()))
    want = pack(loop_fields(fresh(), pieces))  # also compiles
    got = loop_packed(pack(fresh()), pieces, kinds)
    same = bool(jnp.array_equal(jax.lax.bitcast_convert_type(want, jnp.int32),
                                jax.lax.bitcast_convert_type(got, jnp.int32)))
    if not same:
        raise SystemExit("the two loops disagree")
    res = {"fields": [], "packed": []}
    for _ in range(a.repeat):  # alternating, each on a fresh map
        rows = fresh()
        res["fields"].append(best_of_cpu(lambda rows=rows: loop_fields(rows, pieces), 1)[:2])
        packed = jax.block_until_ready(pack(fresh()))
        res["packed"].append(
            best_of_cpu(lambda packed=packed: loop_packed(packed, pieces, kinds), 1)[:2])
    best = {k: min(v) for k, v in res.items()}
    out = {
        "runs": r, "pieces": int(pieces.shape[0]), "block": BLOCK,
        "row_arrays": len(row_arrays(pq.init())), "row_columns_packed": int(got.shape[1]),
        "identical": same,
        "fields_wall_s": best["fields"][0], "fields_cpu_s": best["fields"][1],
        "packed_wall_s": best["packed"][0], "packed_cpu_s": best["packed"][1],
        "cpu_ratio_fields_over_packed": best["fields"][1] / best["packed"][1],
        "all_runs": res,
    }
    print({k: v for k, v in out.items() if k != "all_runs"})
    print("wrote", write_result(out, a.out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
