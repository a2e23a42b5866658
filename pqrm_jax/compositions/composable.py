"""Composable sets of triplets and the constructive proof of Z Thm. 3.1.

Offers the landmark space of a set of unordered triplets, the cut tree that decides
composability (Z Def. 3.2.1–3.2.4) with its certificate, the composable triplets, and the
composition tree of a target built by the proof of Thm. 3.1. Repeated landmarks, an empty
source set or a target outside the landmark space raise ``ValueError``.

The polynomial decision procedure, why its answer does not depend on the merge order, and
the conventions: docs/compositions.md §composable.

>>> tree = cut_tree(["ABC", "BCD", "ADE"])
>>> sorted(tree.common)
['A', 'D']
>>> t = compose_from_cut_tree(tree, "BCE")
>>> t.is_valid(["ABC", "BCD", "ADE"])
True
"""

from __future__ import annotations

import sys
from collections import Counter
from collections.abc import Hashable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

Landmark = Hashable
Triplet = frozenset  # frozenset of three distinct landmarks

__all__ = [
    "Triplet", "as_triplet", "as_triplet_set", "landmark_space", "CutTree", "CompositionTree",
    "cut_tree", "is_composable", "clusters", "composable_triplets", "compose_from_cut_tree",
    "verify_cut_tree", "fmt",
]


# --------------------------------------------------------------------------------- triplets
def as_triplet(t: Iterable[Landmark]) -> Triplet:
    """Normalise ``t`` to an unordered triplet (Z §3.1).

    Args:
        t: three distinct hashable landmarks (a string of three letters works).

    Returns:
        The triplet as a ``frozenset``.

    Raises:
        ValueError: unless ``t`` has exactly 3 distinct items.

    >>> sorted(as_triplet("CAB"))
    ['A', 'B', 'C']
    """
    if isinstance(t, frozenset) and len(t) == 3:
        return t
    items = tuple(t)
    s = frozenset(items)
    if len(items) != 3:
        raise ValueError(f"a triplet has exactly 3 landmarks, got {len(items)}: {items!r}")
    if len(s) != 3:
        raise ValueError(f"triplet {items!r} repeats a landmark (Z §3.1 needs 3 distinct ones)")
    return s


def as_triplet_set(triplets: Iterable[Iterable[Landmark]]) -> frozenset[Triplet]:
    """Normalise a source set of triplets (Z Def. 3.2.4); duplicates and re-orderings collapse.

    Args:
        triplets: a collection of triplets (not one string).

    Returns:
        ``frozenset`` of :func:`as_triplet` triplets.

    Raises:
        ValueError: for an empty set, a single string, or a malformed triplet.
    """
    if isinstance(triplets, str):
        raise ValueError("pass a collection of triplets, e.g. ['ABC', 'BCD'], not one string")
    out = frozenset(as_triplet(t) for t in triplets)
    if not out:
        raise ValueError("the source set of triplets is empty (Z Def. 3.2.4 needs |T| ≥ 1)")
    return out


def landmark_space(triplets: Iterable[Iterable[Landmark]]) -> frozenset:
    """``L(T)``: the union of the triplets (Z Def. 3.2.1, eq. 3.1).

    Args:
        triplets: the source triplets.

    Returns:
        ``frozenset`` of landmarks.

    Raises:
        ValueError: as :func:`as_triplet_set`.

    >>> sorted(landmark_space(["ABC", "BCD"]))
    ['A', 'B', 'C', 'D']
    """
    return frozenset().union(*as_triplet_set(triplets))


def fmt(t: Iterable[Landmark]) -> str:
    """Canonical text of a triplet (sorted landmarks).

    Args:
        t: the triplet's landmarks.

    Returns:
        ``'ABC'`` for one-letter names, else the names joined by ``-`` (``'0-1-2'``).

    >>> fmt("CAB"), fmt((2, 0, 1))
    ('ABC', '0-1-2')
    """
    items = sorted(t, key=lambda x: (str(type(x)), x))
    if all(isinstance(x, str) and len(x) == 1 for x in items):
        return "".join(items)
    return "-".join(str(x) for x in items)


# --------------------------------------------------------------------------------- cut tree
@dataclass(frozen=True, eq=False)
class CutTree:
    """Certificate of composability: a binary tree of 2-common cuts (Z Def. 3.2.2–3.2.4).

    A leaf holds one source triplet. An internal node holds the cut ``(left, right)`` of its
    triplets and ``common`` = ``L(T_L) ∩ L(T_R)`` (at least two landmarks).
    """

    triplets: frozenset
    landmarks: frozenset
    left: CutTree | None = None
    right: CutTree | None = None
    common: frozenset = field(default_factory=frozenset)

    @property
    def is_leaf(self) -> bool:
        return self.left is None

    def depth(self) -> int:
        d, stack = 0, [(self, 1)]
        while stack:
            node, k = stack.pop()
            d = max(d, k)
            if not node.is_leaf:
                stack += [(node.left, k + 1), (node.right, k + 1)]
        return d

    def __repr__(self) -> str:
        if self.is_leaf:
            return f"CutTree(leaf {fmt(next(iter(self.triplets)))})"
        return (f"CutTree({len(self.triplets)} triplets, |L|={len(self.landmarks)}, "
                f"common={{{', '.join(sorted(map(str, self.common)))}}})")


def _merge_clusters(T: frozenset[Triplet]) -> list[CutTree]:
    """Greedy 2-common merging; returns the final clusters as cut trees.

    Why the merge order does not matter: docs/compositions.md §composable.
    """
    order = sorted(T, key=fmt)  # deterministic
    nodes: dict[int, CutTree] = {}
    by_landmark: dict[Landmark, set[int]] = {}
    for i, t in enumerate(order):
        nodes[i] = CutTree(frozenset([t]), t)
        for x in t:
            by_landmark.setdefault(x, set()).add(i)
    work = list(range(len(order)))[::-1]
    next_id = len(order)
    while work:
        c = work.pop()
        if c not in nodes:
            continue
        counts = Counter()
        for x in nodes[c].landmarks:
            counts.update(by_landmark[x])
        del counts[c]
        partner = next((d for d, k in sorted(counts.items()) if k >= 2), None)
        if partner is None:
            continue  # stable until a grown cluster finds it
        a, b = nodes.pop(c), nodes.pop(partner)
        merged = CutTree(a.triplets | b.triplets, a.landmarks | b.landmarks, a, b,
                         a.landmarks & b.landmarks)
        for x in a.landmarks:
            by_landmark[x].discard(c)
        for x in b.landmarks:
            by_landmark[x].discard(partner)
        for x in merged.landmarks:
            by_landmark[x].add(next_id)
        nodes[next_id] = merged
        work.append(next_id)
        next_id += 1
    return list(nodes.values())


def clusters(triplets: Iterable[Iterable[Landmark]]) -> list[CutTree]:
    """Maximal composable groups of ``triplets`` (each with its cut tree), largest first.

    ``T`` is composable iff there is one group (Z Def. 3.2.4). Distinct groups share at most
    one landmark, which certifies that no 2-common cut joins them.

    Args:
        triplets: the source triplets.

    Returns:
        ``list`` of :class:`CutTree`, one per cluster, largest first.

    Raises:
        ValueError: as :func:`as_triplet_set`.
    """
    out = _merge_clusters(as_triplet_set(triplets))
    return sorted(out, key=lambda c: (-len(c.triplets), sorted(map(fmt, c.triplets))))


def cut_tree(triplets: Iterable[Iterable[Landmark]],
             landmarks: Iterable[Landmark] | None = None) -> CutTree | None:
    """Decide whether ``triplets`` is composable under ``landmarks`` (Z Def. 3.2.4).

    Runs in about O(|T|·|L|) set operations (docs/compositions.md §composable).

    Args:
        triplets: the source triplets T (each three distinct hashable landmarks).
        landmarks: the landmark space; defaults to ``L(T)``. A landmark space that is not inside
            ``L(T)`` makes the answer ``None``.

    Returns:
        The certificate (a :class:`CutTree`), or ``None`` when T is not composable.

    Raises:
        ValueError: for a triplet with a repeated landmark or an empty source set.

    >>> cut_tree(["ABC", "BCD", "ADE"]) is not None
    True
    >>> cut_tree(["ABC", "CDE"]) is None   # share one landmark only
    True
    """
    T = as_triplet_set(triplets)
    space = frozenset().union(*T)
    if landmarks is not None:
        L = frozenset(landmarks)
        if not L <= space:
            return None
    groups = _merge_clusters(T)
    return groups[0] if len(groups) == 1 else None


def is_composable(triplets: Iterable[Iterable[Landmark]],
                  landmarks: Iterable[Landmark] | None = None) -> bool:
    """Whether ``triplets`` is composable under ``landmarks`` (Z Def. 3.2.4, Thm 3.2.1).

    Args:
        triplets: the source triplets.
        landmarks: the landmark space (default ``L(T)``).

    Returns:
        True iff a cut tree exists.

    >>> is_composable(["ABC", "BCD"]), is_composable(["ABC", "CDE"])
    (True, False)
    """
    return cut_tree(triplets, landmarks) is not None


def composable_triplets(triplets: Iterable[Iterable[Landmark]]) -> set[Triplet]:
    """Every triplet that some sequence of compositions from ``triplets`` can produce.

    Exactly the triplets inside one cluster's landmark space; see
    docs/compositions.md §composable (Z §3.2).

    Args:
        triplets: the source triplets.

    Returns:
        ``set`` of triplets (the sources included).
    """
    from itertools import combinations

    out: set[Triplet] = set()
    for c in clusters(triplets):
        out.update(frozenset(x) for x in combinations(c.landmarks, 3))
    return out


def verify_cut_tree(tree: CutTree, triplets: Iterable[Iterable[Landmark]] | None = None) -> None:
    """Check a composability certificate independently (Z Def. 3.2.2–3.2.4).

    Args:
        tree: the cut tree.
        triplets: when given, the tree must cover exactly these.

    Raises:
        ValueError: naming the first violation.
    """
    T = None if triplets is None else as_triplet_set(triplets)
    if T is not None and tree.triplets != T:
        raise ValueError("cut tree does not cover exactly the given triplets")
    stack = [tree]
    while stack:
        n = stack.pop()
        if n.landmarks != frozenset().union(*n.triplets):
            raise ValueError(f"{n}: landmark space is not the union of its triplets")
        if n.is_leaf:
            if len(n.triplets) != 1 or n.right is not None:
                raise ValueError(f"{n}: a leaf must hold exactly one triplet")
            continue
        a, b = n.left, n.right
        if a.triplets & b.triplets or (a.triplets | b.triplets) != n.triplets:
            raise ValueError(f"{n}: children are not a cut (partition) of its triplets")
        common = a.landmarks & b.landmarks
        if len(common) < 2 or common != n.common:
            raise ValueError(f"{n}: cut is not 2-common (common landmarks {set(common)})")
        stack += [a, b]


# ----------------------------------------------------------------------- composition trees
@dataclass(frozen=True, eq=False)
class CompositionTree:
    """A composition tree (Z Def. 3.2.5); subtrees may be shared (a DAG).

    ``children`` is ``None`` for a source leaf, else the pair ``(τ_L, τ_R)`` composing
    ``triplet`` directly (Lemma 2.4.1). ``cost`` is the cumulative cost ``d`` when the tree
    comes from Alg. 4 (eq. 3.2), else ``nan``.
    """

    triplet: Triplet
    children: tuple[CompositionTree, CompositionTree] | None = None
    cost: float = float("nan")

    @property
    def is_leaf(self) -> bool:
        return self.children is None

    def postorder(self) -> Iterator[CompositionTree]:
        seen: set[int] = set()
        stack: list[tuple[CompositionTree, bool]] = [(self, False)]
        while stack:
            node, expanded = stack.pop()
            if id(node) in seen:
                continue
            if expanded or node.is_leaf:
                seen.add(id(node))
                yield node
            else:
                stack.append((node, True))
                stack += [(c, False) for c in reversed(node.children)]

    def steps(self) -> list[tuple[Triplet, Triplet, Triplet]]:
        """Distinct compositions ``(target, τ_L, τ_R)`` in an executable order."""
        return [(n.triplet, n.children[0].triplet, n.children[1].triplet)
                for n in self.postorder() if not n.is_leaf]

    def sources(self) -> set[Triplet]:
        """The distinct source triplets the tree uses."""
        return {n.triplet for n in self.postorder() if n.is_leaf}

    def num_compositions(self) -> int:
        """Compositions in the tree counted as a tree (shared subtrees counted each time)."""
        count: dict[int, int] = {}
        for n in self.postorder():
            count[id(n)] = 0 if n.is_leaf else (
                1 + count[id(n.children[0])] + count[id(n.children[1])])
        return count[id(self)]

    def depth(self) -> int:
        """Number of composition levels on the longest root-to-leaf path."""
        dep: dict[int, int] = {}
        for n in self.postorder():
            dep[id(n)] = 0 if n.is_leaf else 1 + max(dep[id(c)] for c in n.children)
        return dep[id(self)]

    def is_valid(self, sources: Iterable[Iterable[Landmark]]) -> bool:
        """Leaves are sources and every step obeys Lemma 2.4.1 (see :meth:`check`)."""
        try:
            self.check(sources)
        except ValueError:
            return False
        return True

    def check(self, sources: Iterable[Iterable[Landmark]]) -> None:
        """``ValueError`` naming the first leaf not in ``sources`` or step breaking Lemma 2.4.1."""
        S = as_triplet_set(sources)
        for n in self.postorder():
            if n.is_leaf:
                if n.triplet not in S:
                    raise ValueError(f"leaf {fmt(n.triplet)} is not a source triplet")
                continue
            a, b = (c.triplet for c in n.children)
            if len(a & b) != 2 or not n.triplet <= (a | b) or n.triplet in (a, b):
                raise ValueError(f"{fmt(n.triplet)} cannot be composed directly from "
                                 f"{fmt(a)} and {fmt(b)} (Lemma 2.4.1)")

    def pretty(self) -> str:
        """Indented text rendering (shared subtrees are printed each time)."""
        lines: list[str] = []

        def rec(n: CompositionTree, ind: int) -> None:
            c = "" if n.cost != n.cost else f"  d={n.cost:g}"
            lines.append("  " * ind + fmt(n.triplet) + (" [source]" if n.is_leaf else "") + c)
            if not n.is_leaf:
                for ch in n.children:
                    rec(ch, ind + 1)

        with _recursion(self.depth() + 50):
            rec(self, 0)
        return "\n".join(lines)

    def __repr__(self) -> str:
        kind = "source" if self.is_leaf else f"{self.num_compositions()} compositions"
        return f"CompositionTree({fmt(self.triplet)}, {kind})"


@contextmanager
def _recursion(depth: int):
    old = sys.getrecursionlimit()
    sys.setrecursionlimit(max(old, depth + 100))
    try:
        yield
    finally:
        sys.setrecursionlimit(old)


def compose_from_cut_tree(tree: CutTree, target: Iterable[Landmark]) -> CompositionTree:
    """Constructive proof of Z Thm. 3.1: a composition tree for ``target`` from ``tree``'s sources.

    The tree is valid (leaves are sources, every step obeys Lemma 2.4.1) but not optimal; use
    :func:`pqrm_jax.compositions.optimal_composition_tree` for the optimal one (Alg. 1).

    Args:
        tree: a cut tree (:func:`cut_tree`).
        target: the triplet to compose.

    Returns:
        The :class:`CompositionTree` of ``target`` (a DAG: repeated subtrees are shared).

    Raises:
        ValueError: when ``target`` has a landmark outside ``L(T)``.

    >>> t = compose_from_cut_tree(cut_tree(["ABC", "BCD"]), "ABD")
    >>> [(fmt(a), fmt(b), fmt(c)) for a, b, c in t.steps()]
    [('ABD', 'ABC', 'BCD')]
    """
    tau = as_triplet(target)
    if not tau <= tree.landmarks:
        missing = sorted(map(str, tau - tree.landmarks))
        raise ValueError(f"target {fmt(tau)} has landmarks {missing} outside the landmark "
                         f"space of the source set")
    memo: dict[Triplet, CompositionTree] = {}
    for t in tree.triplets:
        memo[t] = CompositionTree(t)

    def step(t: Triplet, a: CompositionTree, b: CompositionTree) -> CompositionTree:
        if t not in memo:
            memo[t] = CompositionTree(t, (a, b))
        return memo[t]

    def rec(node: CutTree, t: Triplet) -> CompositionTree:
        if t in memo:
            return memo[t]
        assert t <= node.landmarks and not node.is_leaf
        L, R = node.left, node.right
        if t <= L.landmarks:
            return rec(L, t)
        if t <= R.landmarks:
            return rec(R, t)
        a, b = sorted(node.common, key=lambda x: (x not in t, str(x)))[:2]
        shared = t & {a, b}
        if len(shared) == 2:  # case 1: the third landmark is on one side, handled above
            raise AssertionError("unreachable: case 1 always fits one side")
        if len(shared) == 1:  # case 2: t = A L2 L3, L2 only left, L3 only right
            A = next(iter(shared))
            B = b if A == a else a
            l2 = next(iter((t - {A}) - R.landmarks))
            l3 = next(iter((t - {A}) - L.landmarks))
            left = rec(L, frozenset({A, B, l2}))
            right = rec(R, frozenset({A, B, l3}))
            return step(t, left, right)
        # case 3: no common landmark in t; two on side S, one (R3) only on the other side
        S, O = (L, R) if len(t & L.landmarks) == 2 else (R, L)
        inside = t & S.landmarks
        p, q = sorted(inside, key=str)
        r = next(iter(t - inside))
        apq = rec(S, frozenset({a, p, q}))
        abq = rec(S, frozenset({a, b, q}))
        abr = rec(O, frozenset({a, b, r}))
        aqr = step(frozenset({a, q, r}), abq, abr)
        return step(t, apq, aqr)

    with _recursion(4 * tree.depth() + 50):
        return rec(tree, tau)
