"""Qualitative calculi: definitions, registry and classification (docs/decisions.md §2).

>>> from pqrm_jax import calculi
>>> calculi.get("edc").num_states
20
>>> calculi.names()[:3]
('edc', 'edc_lune', 'triple_cross')
"""

from __future__ import annotations

from collections.abc import Callable

from . import library
from .calculus import Calculus, classify_all
from .poly import Poly, alpha, beta, circle, line, rho
from .protocol import BOUNDARY, DEGENERATE, INVALID, TernaryCalculus, check_calculus

__all__ = [
    "BOUNDARY", "DEGENERATE", "INVALID", "Calculus", "TernaryCalculus", "check_calculus", "Poly",
    "classify_all",
    "alpha", "beta", "rho", "line", "circle", "get", "is_builtin", "names", "register",
]

_BUILDERS: dict[str, Callable[[], Calculus]] = {
    "edc": library.edc,
    "edc_lune": lambda: library.edc_lune(get("edc")),
    "triple_cross": lambda: library.triple_cross(get("edc")),
    "double_cross": lambda: library.double_cross(get("edc")),
    "single_cross": lambda: library.single_cross(get("edc")),
    "lr": lambda: library.lr(get("edc")),
    "quadrant": lambda: library.quadrant(get("edc")),
    "dcc": library.dcc,
    "lr_full": lambda: library.lr_full(get("dcc")),
}
_CACHE: dict[str, Calculus] = {}

#: Padgett's six reduced representations (P Fig. 2.2), finest first.
PADGETT_REPRESENTATIONS = ("edc", "edc_lune", "triple_cross", "double_cross", "single_cross", "lr")


def names() -> tuple[str, ...]:
    """Names of the built-in and registered calculi.

    Returns:
        The names, built-in first (P Fig. 2.2 order), then registered ones.
    """
    return tuple(dict.fromkeys([*_BUILDERS, *_CACHE]))


def is_builtin(name: str) -> bool:
    """Whether ``name`` is one of the calculi shipped with the package (tables in package data).

    Args:
        name: a calculus name.

    Returns:
        True for the built-in calculi (P Fig. 2.2, MT App. C), False for registered ones.
    """
    return name in _BUILDERS


def get(name: str | TernaryCalculus) -> Calculus | TernaryCalculus:
    """The calculus called ``name`` (the registry of docs/decisions.md §2).

    Args:
        name: a registered name, or a calculus object, which is checked against
            :class:`TernaryCalculus` and returned as it is.

    Returns:
        The (frozen, shared) calculus.

    Raises:
        KeyError: for an unknown name (the message lists the known names).
        TypeError: for an object that is not a :class:`TernaryCalculus`.

    >>> get("lr").states
    ('l', 'r')
    """
    if not isinstance(name, str):
        return check_calculus(name)
    if name not in _CACHE:
        if name not in _BUILDERS:
            raise KeyError(f"unknown calculus {name!r}; known calculi: {', '.join(names())}")
        _CACHE[name] = _BUILDERS[name]()
    return _CACHE[name]


def register(calc: TernaryCalculus, *, overwrite: bool = False) -> TernaryCalculus:
    """Make a user-defined calculus available through :func:`get`.

    Args:
        calc: a :class:`TernaryCalculus` (``name``, ``states``, ``num_states``, ``classify``).
        overwrite: replace a registered calculus of the same name.

    Returns:
        ``calc``.

    Raises:
        TypeError: naming a missing member of the protocol.
        ValueError: for a name already taken (and ``overwrite`` False).
    """
    check_calculus(calc)
    if not overwrite and (calc.name in _BUILDERS or calc.name in _CACHE):
        raise ValueError(f"a calculus named {calc.name!r} already exists")
    _CACHE[calc.name] = calc
    return calc
