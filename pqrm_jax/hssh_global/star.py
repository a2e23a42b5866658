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

The star type and the host isomorphism are the local levels' (:class:`pqrm_jax.hssh.star.Star`,
:func:`pqrm_jax.hssh.star.star_isomorphisms`; one type and one isomorphism for the HSSH);
:func:`match_matrix` is the isomorphism's batched twin (padded arrays, ``vmap`` over all view
pairs, jitted), checked against it in the tests.

>>> plus = Star.from_entries([(0, 1, 1), (1, 1, 1), (0, -1, 1), (1, -1, 1)])
>>> len(star_isomorphisms(plus, plus))
4
>>> tee = Star.from_entries([(0, -1, 0), (1, 1, 1), (0, 1, 1), (1, -1, 1)])
>>> star_isomorphisms(tee, tee)
[0]
>>> view_match((tee, 1), (tee, 1)), view_match((tee, 1), (tee, 3))
(True, False)
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..hssh.star import Star, star_isomorphisms


def view_match(v: tuple[Star, int], w: tuple[Star, int]) -> bool:
    """``match(v, w)`` of B §8.2: an isomorphism maps v's arrival entry onto w's.

    Args:
        v: ``(star, arrival entry index)``.
        w: ``(star, arrival entry index)``.

    Returns:
        True when the views match.
    """
    (sa, ia), (sb, ib) = v, w
    n = len(sa)
    return len(sb) == n and (ib - ia) % n in star_isomorphisms(sa, sb)


def view_from_local_star(entries, arrival_gateway: int) -> tuple[tuple[Star, int], tuple]:
    """The view and entry bearings of a place from the local levels' small-scale star.

    Bridge from :func:`pqrm_jax.hssh.star.build_star` (entries with ``path``, ``direction``,
    ``traversable``, ``gateway`` and ``angle``: clockwise degrees from "up") to the experience
    record of :mod:`~pqrm_jax.hssh_global.world`: the robot entered through gateway
    ``arrival_gateway``, so it arrived on the directed local-path opposite to the traversable
    entry of that gateway (B Fig. 8.1: entering via g5 is arriving on π̃_c^-).

    Args:
        entries: the [L] clockwise :class:`~pqrm_jax.hssh.star.StarEntry` records.
        arrival_gateway: index of the gateway the robot entered through.

    Returns:
        ``((star, arrival entry), bearings)``; bearings are counter-clockwise radians from the
        arrival heading, as :func:`~pqrm_jax.hssh_global.world.explore` records them.

    Raises:
        ValueError: no traversable entry leaves through ``arrival_gateway``.
    """
    star = Star.from_entries(entries)
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
