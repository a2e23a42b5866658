"""Compile counts of the qualitative-BSP entry points (``bsp.plan``, ``bsp.run_lanes``), in the
manner of tests/test_compilation.py: a second call with new values of the same shapes and equal
static settings (equal, not identical, parameter objects; the other cost, a traced argument)
must not trace or compile again."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from compile_count import count_compiles

from pqrm_jax import calculi
from pqrm_jax.bsp import env as E
from pqrm_jax.bsp import execute as X
from pqrm_jax.bsp import graph as G
from pqrm_jax.bsp import models as M
from pqrm_jax.bsp import planner as P

PARAMS = M.ModelParams(samples=600, pool=1 << 18, seed=3)




@pytest.fixture(scope="module")
def setup(request):
    mod = M.load_models(PARAMS, directory=request.config.cache.mkdir("bsp-models"))
    D1 = jnp.asarray(calculi.get("edc").tables.neighbor_distance, jnp.float32)
    envs = [E.generate(np.random.default_rng([4, e]), 9, 2.5) for e in range(2)]
    bels = [E.initial_belief(jax.random.key(e), mod, env, compositions=True, samples=64)
            for e, env in enumerate(envs)]
    return mod, D1, envs, bels


def test_plan_compiles_once(setup):
    mod, D1, envs, bels = setup
    args = []
    for env, b in zip(envs, bels, strict=True):
        goal = jnp.asarray(env.goal, jnp.int32)
        fg = G.frame_graph(mod, b.trip, b.trip_src, b.scale, b.lm_mask, goal, 0.3)
        args.append((b.trip, b.scale, fg, goal, b.frame, b.robot))
    jax.block_until_ready(P.plan(jax.random.key(0), mod, D1, *args[0],
                                 P.PlannerParams(depth=2), 1))
    with count_compiles() as again:
        jax.block_until_ready(P.plan(jax.random.key(1), mod, D1, *args[1],
                                     P.PlannerParams(depth=2), 2))
    assert again == []


@pytest.mark.slow
def test_run_lanes_compiles_once(setup):
    mod, D1, envs, bels = setup
    L = 12

    def lanes(env, b, key, cost):
        one = lambda x: jnp.asarray(x)[None]  # noqa: E731
        return jax.random.key(key)[None], X.Lane(
            pos=one(E.padded_positions(env, L)), lm_mask=one(np.arange(L) < len(env.pos)),
            goal=one(np.asarray(env.goal, np.int32)), start=one(np.asarray(env.start, np.float32)),
            belief=jax.tree.map(lambda x: x[None], b), ref=one(np.asarray(env.frame, np.int32)),
            ref_scale=one(E.reference_scale(mod, env)), cost=jnp.asarray([cost], jnp.int32))

    pp, ep = P.PlannerParams(depth=1), X.ExecParams(t_max=2, eps_obs=0.3)
    k0, lanes0 = lanes(envs[0], bels[0], 0, 1)
    jax.block_until_ready(X.run_lanes(k0, mod, D1, lanes0, pp, ep))
    k1, lanes1 = lanes(envs[1], bels[1], 1, 2)
    with count_compiles() as again:
        jax.block_until_ready(X.run_lanes(k1, mod, D1, lanes1, P.PlannerParams(depth=1),
                                          X.ExecParams(t_max=2, eps_obs=0.3)))
    assert again == []
