"""Local topology stars, views and view matching by star isomorphism (B §5.1, §8.2).

A *star* is the circular (clockwise) list of directed local-paths at a place; entry ``i`` has a
local path id ``path[i]``, a direction ``dir[i]`` (+1/-1) and a traversability ``alpha[i]``
(1 when a corridor leads away from the place in that direction). ``opp[i]`` is the entry of the
same local path in the other direction. An isomorphism ``φ: S → S'`` is a bijection with
``next(φ(x)) = φ(next(x))``, ``α(φ(x)) = α(x)`` and which maps opposite directions to opposite
directions (B §5.1): for stars it is a rotation ``i → i + s`` of the circular list that preserves
``alpha`` and the pairing ``opp``. A *view* (B §8.2) is ``⟨S_p, ψ_p(q)⟩``: a star and the entry the
robot arrived on; ``match(v, v')`` holds iff an isomorphism maps the arrival entry of ``v`` onto
the one of ``v'``.

Two implementations: :func:`isomorphisms` (host Python, used by the tree of maps) and
:func:`match_matrix` (padded arrays, ``vmap`` over all view pairs, jitted), checked against each
other in the tests.

>>> plus = Star.from_entries([(0, 1, 1), (1, 1, 1), (0, -1, 1), (1, -1, 1)])
>>> len(isomorphisms(plus, plus))
4
>>> tee = Star.from_entries([(0, -1, 0), (1, 1, 1), (0, 1, 1), (1, -1, 1)])
>>> isomorphisms(tee, tee)
[0]
>>> view_match((tee, 1), (tee, 1)), view_match((tee, 1), (tee, 3))
(True, False)
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np


class Star(NamedTuple):
    """A local topology: the clockwise circular list of directed local-paths (B §5.1).

    Attributes:
        path: local path id of each entry, ``tuple[int]`` of length ``L``.
        dir: direction of each entry away from the place, +1 or -1.
        alpha: traversability away from the place, 0 or 1.
    """

    path: tuple
    dir: tuple
    alpha: tuple

    @staticmethod
    def from_entries(entries) -> Star:
        """Builds a star from ``[(path, dir, alpha), ...]`` in clockwise order; validates it."""
        entries = [tuple(int(v) for v in e) for e in entries]
        if not entries:
            raise ValueError("a star needs at least one directed local-path")
        path, dirs, alpha = zip(*entries, strict=True)
        star = Star(tuple(path), tuple(dirs), tuple(alpha))
        seen = {}
        for i, (p, d) in enumerate(zip(path, dirs, strict=True)):
            if d not in (1, -1):
                raise ValueError(f"entry {i}: direction must be +1 or -1, got {d}")
            if (p, d) in seen:
                raise ValueError(f"entry {i}: directed local-path ({p}, {d}) appears twice")
            seen[(p, d)] = i
        for p, d in seen:
            if (p, -d) not in seen:
                raise ValueError(f"star not closed under opposite direction: path {p}")
        if any(a not in (0, 1) for a in alpha):
            raise ValueError("alpha must be 0 or 1")
        return star

    def __len__(self) -> int:  # number of entries L
        return len(self.path)

    @property
    def opp(self) -> tuple:
        """Index of the opposite direction of each entry."""
        index = {(p, d): i for i, (p, d) in enumerate(zip(self.path, self.dir, strict=True))}
        return tuple(index[(p, -d)] for p, d in zip(self.path, self.dir, strict=True))

    def rotate(self, s: int) -> Star:
        """The same star listed from entry ``s`` (entry ``s`` becomes entry 0)."""
        n = len(self)
        idx = [(i + s) % n for i in range(n)]
        return Star(tuple(self.path[i] for i in idx), tuple(self.dir[i] for i in idx),
                    tuple(self.alpha[i] for i in idx))


def isomorphisms(a: Star, b: Star) -> list[int]:
    """All shifts ``s`` such that ``φ(i) = (i + s) mod L`` is an isomorphism ``a → b`` (B §5.1).

    Args:
        a: source star.
        b: target star.

    Returns:
        The valid shifts in increasing order (empty when the stars are not isomorphic).
    """
    n = len(a)
    if len(b) != n:
        return []
    oa, ob = a.opp, b.opp
    out = []
    for s in range(n):
        if all(b.alpha[(i + s) % n] == a.alpha[i] and ob[(i + s) % n] == (oa[i] + s) % n
               for i in range(n)):
            out.append(s)
    return out


def view_match(v: tuple[Star, int], w: tuple[Star, int]) -> bool:
    """``match(v, w)`` of B §8.2: an isomorphism maps v's arrival entry onto w's.

    Args:
        v: ``(star, arrival entry index)``.
        w: ``(star, arrival entry index)``.
    """
    (sa, ia), (sb, ib) = v, w
    n = len(sa)
    return len(sb) == n and (ib - ia) % n in isomorphisms(sa, sb)


def view_from_local_star(entries, arrival_gateway: int) -> tuple[tuple[Star, int], tuple]:
    """The view and entry bearings of a place from the local levels' small-scale star.

    Bridge from :func:`pqrm_jax.hssh.star.build_star` (entries with ``path``, ``direction``,
    ``traversable``, ``gateway`` and ``angle``: clockwise degrees from "up") to the experience
    record of :mod:`~pqrm_jax.hssh_global.world`: the robot entered through gateway
    ``arrival_gateway``, so it arrived on the directed local-path opposite to the traversable
    entry of that gateway (B Fig. 8.1: entering via g5 is arriving on π̃_c^-).

    Args:
        entries: the clockwise star entries.
        arrival_gateway: index of the gateway the robot entered through.

    Returns:
        ``((star, arrival entry), bearings)``; bearings are counter-clockwise radians from the
        arrival heading, as :func:`~pqrm_jax.hssh_global.world.explore` records them.

    Raises:
        ValueError: no traversable entry leaves through ``arrival_gateway``.
    """
    star = Star.from_entries([(int(e.path), int(e.direction), int(bool(e.traversable)))
                              for e in entries])
    out = [i for i, e in enumerate(entries) if e.traversable and int(e.gateway) == arrival_gateway]
    if not out:
        raise ValueError(f"no traversable entry leaves through gateway {arrival_gateway}")
    arr = star.opp[out[0]]
    ang = np.radians([float(e.angle) for e in entries])
    bear = tuple(float((-(a - ang[arr]) + np.pi) % (2 * np.pi) - np.pi) for a in ang)
    return (star, arr), bear


def pad_views(views, l_max: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Padded arrays of views for :func:`match_matrix`.

    Args:
        views: sequence of ``(star, arrival)``.
        l_max: padded star length (at least the longest star).

    Returns:
        ``alpha [V, l_max]`` (-1 padding), ``opp [V, l_max]``, ``length [V]``, ``arrival [V]``.
    """
    nv = len(views)
    alpha = -np.ones((nv, l_max), np.int32)
    opp = -np.ones((nv, l_max), np.int32)
    length = np.zeros(nv, np.int32)
    arrival = np.zeros(nv, np.int32)
    for k, (s, a) in enumerate(views):
        if len(s) > l_max:
            raise ValueError(f"star of length {len(s)} exceeds l_max={l_max}")
        alpha[k, :len(s)] = s.alpha
        opp[k, :len(s)] = s.opp
        length[k] = len(s)
        arrival[k] = a
    return alpha, opp, length, arrival


def _match_one(alpha_a, opp_a, la, ia, alpha_b, opp_b, lb, ib):
    l_max = alpha_a.shape[0]
    i = jnp.arange(l_max)
    valid_i = i < la
    s = jnp.mod(ib - ia, jnp.maximum(la, 1))
    j = jnp.mod(i + s, jnp.maximum(la, 1))
    ok = (alpha_b[j] == alpha_a) & (opp_b[j] == jnp.mod(opp_a + s, jnp.maximum(la, 1)))
    return (la == lb) & jnp.all(ok | ~valid_i)


@jax.jit
def match_matrix(alpha_a, opp_a, len_a, arr_a, alpha_b, opp_b, len_b, arr_b) -> jax.Array:
    """``match`` for every pair of padded views, ``vmap`` over both sets (B §8.2).

    Args:
        alpha_a, opp_a: ``[A, L]`` padded views (see :func:`pad_views`); ``len_a, arr_a`` ``[A]``.
        alpha_b, opp_b, len_b, arr_b: the same for ``B`` views.

    Returns:
        ``bool [A, B]``.
    """
    row = jax.vmap(_match_one, in_axes=(None, None, None, None, 0, 0, 0, 0))
    return jax.vmap(row, in_axes=(0, 0, 0, 0, None, None, None, None))(
        alpha_a, opp_a, len_a, arr_a, alpha_b, opp_b, len_b, arr_b)
