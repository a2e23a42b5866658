"""What every ternary calculus provides: the :class:`TernaryCalculus` protocol and its sentinels.

A ternary calculus classifies the relation ``AB:C`` of three points (C in the frame of the
ordered pair A, B) into one of ``num_states`` states, returned as an int32 state index.
:class:`~pqrm_jax.calculi.Calculus` (polynomial sign constraints) and
:class:`~pqrm_jax.serge.SergeCalculus` (a learned SR map on a grid) implement it;
:func:`pqrm_jax.calculi.register` checks it, so anything registered works where a calculus is
accepted (``pqrm.state_probabilities``, ``pqrm.mapper``, ``pqrm.metrics.true_states``).

Sentinel results of ``classify`` (documented, never a silent wrong state):

* ``BOUNDARY`` (−1): C lies on a boundary of an *open* calculus (measure zero).
* ``DEGENERATE`` (−2): A = B in an open calculus (the frame does not exist).
* ``INVALID`` (−3): a NaN or infinite coordinate.

>>> from pqrm_jax import calculi
>>> isinstance(calculi.get("lr"), TernaryCalculus)
True
>>> check_calculus(object())
Traceback (most recent call last):
    ...
TypeError: object is not a ternary calculus: missing name, states, num_states, classify
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import jax

__all__ = ["BOUNDARY", "DEGENERATE", "INVALID", "MEMBERS", "TernaryCalculus", "check_calculus"]

BOUNDARY = -1
DEGENERATE = -2
INVALID = -3

#: The members :func:`check_calculus` requires.
MEMBERS = ("name", "states", "num_states", "classify")


@runtime_checkable
class TernaryCalculus(Protocol):
    """A ternary qualitative calculus: states of ``AB:C`` for points of shape ``[..., 2]``.

    Attributes:
        name: registry name.
        states: state labels, ``Q`` strings.
        num_states: ``Q``.

    Optional members used when present: ``parent`` / ``parent_map`` (a merge of a finer
    calculus: one sampling pass of the parent serves both) and ``definition_hash`` (a stable
    identity of the definition).
    """

    name: str
    states: tuple[str, ...]

    @property
    def num_states(self) -> int: ...

    def classify(self, a, b, c) -> jax.Array:
        """int32 state index of ``AB:C``, broadcast over ``[..., 2]`` inputs; sentinels < 0."""
        ...


def check_calculus(calc: object) -> TernaryCalculus:
    """Return ``calc`` if it has the :class:`TernaryCalculus` members, else raise ``TypeError``.

    Args:
        calc: any object.

    Returns:
        ``calc``, unchanged.

    Raises:
        TypeError: naming every missing member, a ``classify`` that is not callable, an empty
            name, or a ``num_states`` that does not match ``states``.
    """
    missing = [m for m in MEMBERS if not hasattr(calc, m)]
    if missing:
        raise TypeError(f"{type(calc).__name__} is not a ternary calculus: missing "
                        f"{', '.join(missing)}")
    if not callable(calc.classify):
        raise TypeError(f"{type(calc).__name__}.classify must be callable")
    if not isinstance(calc.name, str) or not calc.name:
        raise TypeError(f"{type(calc).__name__}.name must be a non-empty string, got "
                        f"{calc.name!r}")
    if len(tuple(calc.states)) != int(calc.num_states):
        raise TypeError(f"{calc.name}: {len(tuple(calc.states))} states but num_states = "
                        f"{calc.num_states}")
    return calc
