"""The Q-Link search POMDP (P §4.3.3, eqs. 4.2–4.3) against brute-force belief-tree search."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pqrm_jax.qlink import pomdp


def _brute(feasible, d, p_move, q_r, b, h, cost=-1.0, reward=100.0):
    """Normalised-belief expectimax over the full observation tree (independent oracle)."""
    if h == 0:
        return 0.0
    q = len(b)
    best = -np.inf
    for a in range(q):
        if not feasible[q_r, a]:
            continue
        total = cost
        for q2 in range(q):
            pt = p_move * (q2 == a) + (1 - p_move) * (q2 == q_r)
            if pt == 0:
                continue
            p_seen = float(np.dot(b, d[q2]))
            v = p_seen * reward
            if p_seen < 1 - 1e-12:
                post = b * (1 - d[q2])
                post = post / post.sum()
                v += (1 - p_seen) * _brute(feasible, d, p_move, q2, post, h - 1, cost, reward)
            total += pt * v
        best = max(best, total)
    return best


def _random_model(rng, horizon, p_move):
    d = rng.uniform(0.0, 1.0, (4, 4)).astype(np.float32)
    base = pomdp.search_model("quadrant", horizon=horizon, p_move=p_move, detect=d)
    return base, np.asarray(base.feasible), d


@pytest.mark.parametrize("horizon", [1, 2, 3, pytest.param(4, marks=pytest.mark.slow)])
def test_exact_matches_brute_force(horizon):
    rng = np.random.default_rng(horizon)
    n = 12 if horizon < 4 else 5
    for k in range(n):
        p_move = 1.0 if k % 2 == 0 else float(rng.uniform(0.3, 0.95))
        model, feas, d = _random_model(rng, horizon, p_move)
        q_r = rng.integers(0, 4, 6)
        b = rng.dirichlet(np.ones(4), 6).astype(np.float32)
        v, a = pomdp.solve_exact(model, q_r, b)
        for i in range(6):
            want = _brute(feas, d.astype(np.float64), p_move, q_r[i], b[i].astype(np.float64),
                          horizon)
            np.testing.assert_allclose(float(v[i]), want, rtol=2e-4, atol=2e-3)
            assert feas[q_r[i], int(a[i])]          # an infeasible control is never chosen
        if p_move == 1.0:                           # open-loop enumeration is exact then
            vo, seq = pomdp.open_loop_plan(model, q_r, b)
            np.testing.assert_allclose(np.asarray(vo), np.asarray(v), rtol=1e-4, atol=1e-3)
            prev = np.concatenate([q_r[:, None], np.asarray(seq)[:, :-1]], axis=1)
            assert feas[prev, np.asarray(seq)].all()


def test_certain_detection_never_repeats_a_state():
    d = np.eye(4, dtype=np.float32)
    model = pomdp.search_model(horizon=4, detect=d)
    rng = np.random.default_rng(0)
    b = rng.dirichlet(np.ones(4) * 0.7, 40).astype(np.float32) + 1e-3
    b = b / b.sum(1, keepdims=True)
    q_r = rng.integers(0, 4, 40)
    _, seq = pomdp.open_loop_plan(model, q_r, b)
    for s in np.asarray(seq):
        # every quadrant searched at most once: with detection 1 a miss rules it out
        assert len(set(s.tolist())) == 4


def test_first_control_is_adjacent_argmax():
    model = pomdp.search_model(horizon=1)
    adj = pomdp.edge_adjacency() | np.eye(4, dtype=bool)
    rng = np.random.default_rng(1)
    for _ in range(30):
        q_r = int(rng.integers(4))
        b = rng.dirichlet(np.ones(4))
        top = int(np.argmax(b))
        if not adj[q_r, top] or np.sort(b)[-2] > 0.6 * b[top]:
            continue
        _, a = pomdp.solve_exact(model, [q_r], [b])
        assert int(a[0]) == top


def test_eq43_recursion_and_costs():
    jax.config.update("jax_enable_x64", True)
    try:
        rng = np.random.default_rng(2)
        for _ in range(50):
            h = jnp.asarray(rng.uniform(0, 1, rng.integers(1, 8)), jnp.float64)
            p = float(pomdp.success_probability(h))
            np.testing.assert_allclose(1 - p, float(np.prod(1 - np.asarray(h))), atol=1e-12)
        # full hazards: success probability = total detected mass of the sequence
        model = pomdp.search_model(horizon=4)
        b = jnp.asarray(rng.dirichlet(np.ones(4)))
        seq = jnp.array([0, 1, 3, 2])
        h = pomdp.hazards(model, b, seq, full=True)
        m, seen = np.asarray(b), 0.0
        for a in seq.tolist():
            seen += m @ np.asarray(model.detect)[a]
            m = m * (1 - np.asarray(model.detect)[a])
        np.testing.assert_allclose(float(pomdp.success_probability(h)), seen, rtol=1e-6)
        np.testing.assert_allclose(
            float(pomdp.expected_commands(h)),
            sum(np.prod(1 - np.asarray(h)[:t]) for t in range(4)), rtol=1e-9)
        # literal eq. 4.2 counts goal-state detections only: never above the full hazard
        assert (np.asarray(pomdp.hazards(model, b, seq)) <= np.asarray(h) + 1e-12).all()
    finally:
        jax.config.update("jax_enable_x64", False)


def test_greedy_fsc_is_feasible():
    model = pomdp.search_model(horizon=4)
    feas = np.asarray(model.feasible)
    rng = np.random.default_rng(4)
    for _ in range(20):
        q_r = int(rng.integers(4))
        seq = np.asarray(pomdp.greedy_sequence(model, jnp.int32(q_r),
                                               jnp.asarray(rng.dirichlet(np.ones(4)))))
        for a, b in itertools.pairwise([q_r, *seq.tolist()]):
            assert feas[a, b]


def test_bad_input():
    for h in (0, -1, 2.5):
        with pytest.raises(ValueError, match="horizon"):
            pomdp.search_model(horizon=h)
    with pytest.raises(ValueError, match="p_move"):
        pomdp.search_model(p_move=1.5)
    with pytest.raises(ValueError, match="open_loop_plan"):
        pomdp.open_loop_plan(pomdp.search_model(p_move=0.5), [0], [[1, 0, 0, 0]])
    with pytest.raises(ValueError, match="belief"):
        pomdp.solve_exact(pomdp.search_model(), [0], [[1, 0, 0]])
