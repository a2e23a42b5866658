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
from .calculus import BOUNDARY, DEGENERATE, INVALID, Calculus
from .poly import Poly, alpha, beta, circle, line, rho

__all__ = [
    "BOUNDARY", "DEGENERATE", "INVALID", "Calculus", "Poly", "alpha", "beta", "rho", "line",
    "circle", "get", "names", "register",
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
    """Names of the built-in and registered calculi."""
    return tuple(dict.fromkeys([*_BUILDERS, *_CACHE]))


def get(name: str) -> Calculus:
    """The calculus called ``name``; an unknown name raises ``KeyError`` listing known names."""
    if isinstance(name, Calculus):
        return name
    if name not in _CACHE:
        if name not in _BUILDERS:
            raise KeyError(f"unknown calculus {name!r}; known calculi: {', '.join(names())}")
        _CACHE[name] = _BUILDERS[name]()
    return _CACHE[name]


def register(calc: Calculus, *, overwrite: bool = False) -> Calculus:
    """Make a user-defined calculus available through :func:`get`."""
    if not overwrite and (calc.name in _BUILDERS or calc.name in _CACHE):
        raise ValueError(f"a calculus named {calc.name!r} already exists")
    _CACHE[calc.name] = calc
    return calc
