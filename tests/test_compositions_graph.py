"""Composable sets (Z Def. 3.2.1–3.2.4, Thm. 3.1) and optimal composition sequences (Alg. 1–4)."""

import doctest
import math
import random
from functools import cache
from itertools import combinations

import pytest

from pqrm_jax import compositions as C
from pqrm_jax.compositions import composable, sequence

RUNNING = ["ABC", "BCD", "ADE"]  # Z §3.2.4


def test_doctests():
    for mod in (C, composable, sequence):
        res = doctest.testmod(mod)
        assert res.failed == 0 and res.attempted > 0, mod.__name__


# ------------------------------------------------------------------ definitions (Z Fig. 3.1)
def test_fig_3_1_definitions():
    assert C.landmark_space(RUNNING) == set("ABCDE")
    tree = C.cut_tree(RUNNING)
    assert tree is not None
    C.verify_cut_tree(tree, RUNNING)
    # the paper's cut ({ABC, BCD}, {ADE}) is 2-common with common {A, D}
    assert {frozenset(map(C.fmt, tree.left.triplets)), frozenset(map(C.fmt, tree.right.triplets))} \
        == {frozenset({"ABC", "BCD"}), frozenset({"ADE"})}
    assert tree.common == {"A", "D"}
    assert C.is_composable(RUNNING, "ABCDE")
    assert C.is_composable(RUNNING, "ACE")          # any L ⊆ L(T)
    assert not C.is_composable(RUNNING, "ABCDEF")   # L ⊄ L(T)
    assert not C.is_composable(["ABC", "CDE"])      # 1-common only
    assert C.is_composable(["ABC"])                 # |T| = 1


def _brute_composable(T):
    """Def. 3.2.4 literally: try every cut (exponential; tiny T only)."""
    T = frozenset(T)

    @cache
    def rec(S):
        if len(S) == 1:
            return True
        items = sorted(S, key=C.fmt)
        first, rest = items[0], items[1:]
        for r in range(len(rest) + 1):
            for extra in combinations(rest, r):
                left = frozenset((first, *extra))
                right = S - left
                if not right:
                    continue
                la = frozenset().union(*left)
                lb = frozenset().union(*right)
                if len(la & lb) >= 2 and rec(left) and rec(right):
                    return True
        return False

    return rec(T)


def _random_triplets(rng, n_landmarks, n_triplets):
    lms = [chr(ord("A") + i) for i in range(n_landmarks)]
    allt = [frozenset(t) for t in combinations(lms, 3)]
    return rng.sample(allt, n_triplets)


def test_decision_matches_definition_bruteforce():
    rng = random.Random(0)
    seen = {True: 0, False: 0}
    for _ in range(300):
        n = rng.randint(4, 8)
        T = _random_triplets(rng, n, rng.randint(1, min(6, math.comb(n, 3))))
        expect = _brute_composable(T)
        tree = C.cut_tree(T)
        assert (tree is not None) == expect, [C.fmt(t) for t in T]
        if tree is not None:
            C.verify_cut_tree(tree, T)
        seen[expect] += 1
    assert seen[True] > 30 and seen[False] > 30


def test_verify_cut_tree_rejects_forgery():
    tree = C.cut_tree(RUNNING)
    bad = composable.CutTree(tree.triplets, tree.landmarks, tree.left, tree.right,
                             frozenset({"A"}))
    with pytest.raises(ValueError, match="2-common"):
        C.verify_cut_tree(bad)
    t1, t2 = (composable.CutTree(frozenset([C.as_triplet(x)]), C.as_triplet(x))
              for x in ("ABC", "CDE"))
    forged = composable.CutTree(t1.triplets | t2.triplets, t1.landmarks | t2.landmarks, t1, t2,
                                t1.landmarks & t2.landmarks)
    with pytest.raises(ValueError, match="2-common"):
        C.verify_cut_tree(forged)


# --------------------------------------------------------------------- Thm. 3.1 constructive
def test_thm_3_1_constructive_every_target():
    rng = random.Random(1)
    done = 0
    for _ in range(200):
        n = rng.randint(4, 9)
        T = _random_triplets(rng, n, rng.randint(2, min(8, math.comb(n, 3))))
        tree = C.cut_tree(T)
        if tree is None:
            continue
        done += 1
        for tau in combinations(sorted(tree.landmarks), 3):
            ct = C.compose_from_cut_tree(tree, tau)
            assert ct.triplet == frozenset(tau)
            ct.check(T)  # leaves are sources, each step obeys Lemma 2.4.1
            if frozenset(tau) in set(map(frozenset, T)):
                assert ct.is_leaf
    assert done > 40


def test_thm_3_1_on_a_long_chain():
    # chain of 300 triplets (deep cut tree); every target must still come out valid
    T = [(i, i + 1, i + 2) for i in range(300)]
    tree = C.cut_tree(T)
    assert tree is not None
    for tau in [(0, 150, 301), (0, 1, 301), (5, 200, 201), (17, 90, 250)]:
        C.compose_from_cut_tree(tree, tau).check(T)


def test_clusters_certify_non_composable():
    T = ["ABC", "BCD", "DEF", "EFG"]  # {ABCD} and {DEFG} share only D
    groups = C.clusters(T)
    assert len(groups) == 2 and C.cut_tree(T) is None
    a, b = groups
    assert len(a.landmarks & b.landmarks) <= 1
    assert C.composable_triplets(T) == {frozenset(t) for t in combinations("ABCD", 3)} | {
        frozenset(t) for t in combinations("DEFG", 3)}


# -------------------------------------------------------------------- Alg. 1–4 (Z §3.2.4)
def test_running_example():
    g = C.optimal_composition_graph(RUNNING)
    cost = {C.fmt(g.triplet(i)): g.d[i] for i in range(g.num_triplets)}
    assert cost["ACE"] == 2 and cost["BCE"] == 3          # Fig. 3.7d
    assert cost["BDE"] == 2 and cost["CDE"] == 2          # text after Fig. 3.7
    assert all(cost[t] == 0 for t in RUNNING)
    assert all(math.isfinite(v) for v in cost.values())   # composable ⇒ every node finite
    for target, k in (("ACE", 2), ("BCE", 3)):
        tree = g.extract(target)
        tree.check(RUNNING)
        assert tree.num_compositions() == k == tree.cost == g.tree_cost(tree)
    # after the first two sources, exactly the four triplets of {A,B,C,D} are finite (Fig. 3.7c)
    g2 = C.CompositionGraph("ABCDE")
    g2.add_source("ABC")
    assert g2.finite() == {frozenset("ABC")}
    g2.add_source("BCD")
    assert g2.finite() == {frozenset(t) for t in combinations("ABCD", 3)}


def test_composition_graph_structure():
    g = C.CompositionGraph("ABCDE")
    nxg = g.to_networkx()
    kinds = [d["kind"] for _, d in nxg.nodes(data=True)]
    assert kinds.count("triplet") == 10 and kinds.count("quartet") == 5
    assert nxg.number_of_edges() == 20
    assert all(nxg.degree(n) == 4 for n, d in nxg.nodes(data=True) if d["kind"] == "quartet")
    assert all(nxg.degree(n) == 2 for n, d in nxg.nodes(data=True) if d["kind"] == "triplet")


class _RandomCosts:
    """Deterministic random symmetric composition costs and source costs."""

    def __init__(self, seed, integer=False):
        self.rng = random.Random(seed)
        self.table = {}
        self.integer = integer

    def _draw(self):
        return float(self.rng.randint(0, 3)) if self.integer else self.rng.uniform(0.0, 2.0)

    def comp(self, a, b, h):
        key = (frozenset((a, b)), h)
        if key not in self.table:
            self.table[key] = self._draw()
        return self.table[key]


def _value_iteration(lms, sources, comp):
    """Independent reference: Bellman–Ford over every explicit hyperedge of every quartet."""
    d = {frozenset(t): math.inf for t in combinations(lms, 3)}
    for t, c in sources.items():
        d[t] = min(d[t], c)
    edges = []
    for q in combinations(lms, 4):
        ts = [frozenset(t) for t in combinations(q, 3)]
        for a, b in combinations(ts, 2):
            for h in ts:
                if h not in (a, b):
                    edges.append((a, b, h, comp(a, b, h)))
    for _ in range(len(d) + 2):
        changed = False
        for a, b, h, w in edges:
            c = d[a] + d[b] + w
            if c < d[h] - 1e-12:
                d[h] = c
                changed = True
        if not changed:
            return d
    raise AssertionError("value iteration did not converge")


def _enumerate_tree_costs(lms, sources, comp, depth):
    """Brute force: the cost of every composition tree of height ≤ depth, per triplet."""
    costs = {frozenset(t): set() for t in combinations(lms, 3)}
    for t, c in sources.items():
        costs[t].add(c)
    hyper = []
    for q in combinations(lms, 4):
        ts = [frozenset(t) for t in combinations(q, 3)]
        for a, b in combinations(ts, 2):
            hyper += [(a, b, h) for h in ts if h not in (a, b)]
    for _ in range(depth):
        new = {t: set(v) for t, v in costs.items()}
        for a, b, h in hyper:
            w = comp(a, b, h)
            new[h].update(round(x + y + w, 9) for x in costs[a] for y in costs[b])
        costs = new
    return costs


def test_optimality_bruteforce_random_instances():
    rng = random.Random(2)
    checked = 0
    for trial in range(40):
        n = rng.randint(4, 6)
        lms = [chr(ord("A") + i) for i in range(n)]
        T = _random_triplets(rng, n, rng.randint(1, min(5, math.comb(n, 3))))
        rc = _RandomCosts(trial, integer=(trial % 2 == 0))
        sources = {t: float(rng.randint(0, 2)) if trial % 2 == 0 else rng.uniform(0, 1)
                   for t in T}
        g = C.optimal_composition_graph(sources, comp_cost=rc.comp, landmarks=lms)
        ref = _value_iteration(lms, sources, rc.comp)
        exhaustive = _enumerate_tree_costs(lms, sources, rc.comp, depth=3) if n <= 5 else None
        finite = set()
        for i in range(g.num_triplets):
            t = g.triplet(i)
            assert g.d[i] == pytest.approx(ref[t], abs=1e-9), (trial, C.fmt(t))
            tree = g.extract(t)
            if math.isinf(ref[t]):
                assert tree is None
                continue
            finite.add(t)
            tree.check(T)
            assert g.tree_cost(tree) == pytest.approx(g.d[i], abs=1e-9)
            if exhaustive is not None and tree.depth() <= 3:
                assert min(exhaustive[t]) == pytest.approx(g.d[i], abs=1e-7)
            checked += 1
        # Thm 3.1 and the cluster characterisation: finite nodes = composable triplets
        assert finite == {t for t in C.composable_triplets(T) if t <= set(lms)}
    assert checked > 200


def test_incremental_updates_are_order_independent():
    rng = random.Random(3)
    lms = list(range(7))
    T = _random_triplets(random.Random(4), 7, 8)
    T = [frozenset(int(ord(x) - 65) for x in t) for t in T]
    costs = {t: rng.uniform(0, 1) for t in T}
    rc = _RandomCosts(5)
    ds = []
    for perm in range(3):
        order = list(T)
        random.Random(perm).shuffle(order)
        g = C.CompositionGraph(lms, rc.comp)
        for t in order:
            g.add_source(t, costs[t])
        ds.append(g.d.copy())
    assert (abs(ds[0] - ds[1]).max() < 1e-12) and (abs(ds[0] - ds[2]).max() < 1e-12)
    # a later, better source cost improves the graph incrementally
    t0 = T[0]
    before = g.cost(t0)
    assert g.add_source(t0, 0.0) >= (1 if before > 0 else 0)
    assert g.cost(t0) == 0.0
    assert g.add_source(t0, 5.0) == 0  # worse information is ignored (Alg. 3 line 6)


def test_thirty_landmarks_full_graph_is_fast():
    import time

    lms = list(range(30))
    T = [(i, i + 1, i + 2) for i in range(28)]
    t0 = time.perf_counter()
    g = C.optimal_composition_graph(T, landmarks=lms)
    dt = time.perf_counter() - t0
    assert g.num_triplets == 4060 and g.num_quartets == 27405
    assert g.finite() == {frozenset(t) for t in combinations(lms, 3)}
    tree = g.extract((0, 15, 29))
    tree.check(T)
    assert dt < 20


# ---------------------------------------------------------------------------- bad input
def test_bad_input():
    with pytest.raises(ValueError, match="repeats a landmark"):
        C.as_triplet("AAB")
    with pytest.raises(ValueError, match="exactly 3"):
        C.as_triplet("ABCD")
    with pytest.raises(ValueError, match="empty"):
        C.cut_tree([])
    with pytest.raises(ValueError, match="empty"):
        C.optimal_composition_graph([])
    with pytest.raises(ValueError, match="not one string"):
        C.cut_tree("ABC")
    with pytest.raises(ValueError, match="outside"):
        C.compose_from_cut_tree(C.cut_tree(RUNNING), "ABF")
    with pytest.raises(ValueError, match="outside"):
        C.optimal_composition_tree(RUNNING, "ABZ")
    g = C.CompositionGraph("ABCDE")
    with pytest.raises(ValueError, match="outside"):
        g.cost("ABX")
    with pytest.raises(ValueError, match="≥ 0"):
        g.add_source("ABC", -1.0)
    with pytest.raises(ValueError, match="≥ 0"):
        g.add_source("ABC", float("nan"))
    with pytest.raises(ValueError, match="≥ 0"):
        C.CompositionGraph("ABCDE", comp_cost=-1.0)
    neg = C.CompositionGraph("ABCD", comp_cost=lambda a, b, h: -1.0)
    neg.add_source("ABC")
    with pytest.raises(ValueError, match="≥ 0"):
        neg.add_source("BCD")
    with pytest.raises(ValueError, match="repeated"):
        C.CompositionGraph("ABCA")
    # cyclic re-orderings of one triplet are the same source (documented handling)
    assert C.as_triplet_set(["ABC", "BCA", "CBA"]) == {frozenset("ABC")}
    assert C.optimal_composition_tree(["ABC", "CAB"], "BAC").is_leaf
    # a composable set with an unreachable target gives the paper's empty tree
    assert C.optimal_composition_graph(["ABC", "CDE"]).extract("ABD") is None
