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

* **fields** — the 15 arrays of :class:`pqrm_jax.pqrm.MapState` (six probability tables, six
  conflict counters, ``mapped``, ``num_updates``, ``num_rejected``), as the map is stored;
* **packed** — one [rows, ΣQ + 9] float32 array holding the same fields (counters bitcast),
  one gather and one scatter a piece.

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


def fields(state):
    """The 15 row arrays of a map state, flattened to rows."""
    return (tuple(state.probs.values()), state.mapped, state.num_updates,
            tuple(state.num_conflicts.values()), state.num_rejected)


def bump(x):
    return x | True if x.dtype == bool else x + 1 if x.dtype == jnp.int32 else x * 0.5


@jax.jit
def loop_fields(rows, pieces):
    def body(c):
        p, rows = c
        idx = pieces[p]
        return p + 1, jax.tree_util.tree_map(
            lambda x: x.at[idx].set(bump(x[idx]), mode="drop"), rows)

    return jax.lax.while_loop(lambda c: c[0] < pieces.shape[0], body, (0, rows))[1]


def pack(rows):
    probs, mapped, num_updates, conflicts, rejected = rows
    ints = jnp.stack([*conflicts, num_updates, rejected, mapped.astype(jnp.int32)], axis=-1)
    return jnp.concatenate([*probs, jax.lax.bitcast_convert_type(ints, jnp.float32)], axis=-1)


def loop_packed(packed, pieces, nq: int):
    cols = jnp.arange(packed.shape[1])

    def body(c):
        p, x = c
        idx = pieces[p]
        g = x[idx]
        ints = jax.lax.bitcast_convert_type(g, jnp.int32)
        new = jnp.where(cols < nq, g * 0.5, jax.lax.bitcast_convert_type(
            jnp.where(cols == packed.shape[1] - 1, 1, ints + 1), jnp.float32))
        return p + 1, x.at[idx].set(new, mode="drop")

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
        return jax.block_until_ready(jax.tree_util.tree_map(
            lambda x: jnp.broadcast_to(x, (r, *x.shape)).reshape(r * x.shape[0], *x.shape[1:]),
            fields(pq.init())))

    nq = sum(x.shape[1] for x in fresh()[0])
    lp = jax.jit(loop_packed, static_argnums=2)
    want = pack(loop_fields(fresh(), pieces))  # also compiles
    got = lp(pack(fresh()), pieces, nq)
    same = bool(jnp.array_equal(jax.lax.bitcast_convert_type(want, jnp.int32),
                                jax.lax.bitcast_convert_type(got, jnp.int32)))
    if not same:
        raise SystemExit("the two loops disagree")
    res = {"fields": [], "packed": []}
    for _ in range(a.repeat):  # alternating, each on a fresh map
        rows = fresh()
        res["fields"].append(best_of_cpu(lambda rows=rows: loop_fields(rows, pieces), 1)[:2])
        packed = jax.block_until_ready(pack(fresh()))
        res["packed"].append(best_of_cpu(lambda packed=packed: lp(packed, pieces, nq), 1)[:2])
    best = {k: min(v) for k, v in res.items()}
    out = {
        "runs": r, "pieces": int(pieces.shape[0]), "block": BLOCK, "row_columns_packed":
        int(got.shape[1]), "identical": same,
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
