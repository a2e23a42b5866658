"""Compile count of ``qlink.navigate_pairs`` (the pattern of tests/test_compilation.py).

A second call with new values of the same shapes (other trials, other keys, another
setting's ranges, the other sensing model) must not trace or compile anything: the study
drives every setting and block of a world through it.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from compile_count import count_compiles

from pqrm_jax import sim
from pqrm_jax.qlink import elements as qel
from pqrm_jax.qlink import guarantees as gu
from pqrm_jax.qlink import linkgraph as lg
from pqrm_jax.qlink import navigate as nav


def test_navigate_pairs_compiles_once_per_shape():
    r = 15.0
    size = (40.0, 40.0)
    lm = sim.uniform_landmarks(jax.random.key(8), 14, size=size)
    vis = np.asarray(jax.vmap(sim.visibility, (0, None, None))(
        sim.lawnmower(size, spacing=r, step=1.0), lm, sim.SensorParams(max_range=r)))
    ids, _ = qel.co_observed_triplets(vis, 1)
    el = qel.exact_elements(lm, ids[gu.assumption1(lm, ids, r)])
    g = lg.link_graph(el, 2)
    lms = np.flatnonzero(qel.incidence(el).any(1))
    goal_row = np.full(el.num_landmarks, -1)
    goal_row[lms] = np.arange(len(lms))
    to_go = lg.goal_distances(g, el, lms)
    tables = nav.start_tables(el)
    pairs = np.array([(s, t) for s in lms for t in lms if s != t])
    rng = np.random.default_rng(0)

    def run(seed, params):
        sel = pairs[rng.choice(len(pairs), 12, replace=False)]
        keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(seed), i))(jnp.arange(12))
        res = nav.navigate_pairs(nav.Trials(keys, sel[:, 0], sel[:, 1]),
                                 nav.NavMap(lm, el, g, to_go, goal_row, tables), params,
                                 chunk=8)
        jax.block_until_ready(res.nav.status)
        return res

    p = nav.NavParams(map_range=r, nav_range=r, sigma=0.1, ds=r / 40, start_offset=r / 20)
    run(0, p)                                                       # warm up: compiles
    with count_compiles() as again:
        run(1, p._replace(nav_range=0.8 * r, sense_epochs=1.0, sigma=0.2))
    assert again == [], again
