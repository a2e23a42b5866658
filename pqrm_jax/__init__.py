"""pqrm-jax: qualitative relational mapping and navigation as vectorised JAX programs.

Subpackages (each imported on first access, ``pqrm_jax.qrm`` etc.; design notes in docs/):

* :mod:`~pqrm_jax.calculi` — ternary qualitative calculi, the registry and their protocol.
* :mod:`~pqrm_jax.tables` — exact operator tables (unary, compose, adjacency).
* :mod:`~pqrm_jax.pqrm` — probabilistic qualitative relational mapping (P ch. 2).
* :mod:`~pqrm_jax.qrm` — camera-based deterministic QRM and RNG navigation (M, MT).
* :mod:`~pqrm_jax.serge` — salient region generation (P ch. 3).
* :mod:`~pqrm_jax.compositions` — composable sets and composition propagation (Z).
* :mod:`~pqrm_jax.qlink` — Q-Link navigation over qualitative maps (P ch. 4).
* :mod:`~pqrm_jax.bsp` — Zilberman's belief-space planning with compositions (Z ch. 4).
* :mod:`~pqrm_jax.hssh` — HSSH local levels: LPM, localization, gateways, places (B ch. 4–6).
* :mod:`~pqrm_jax.hssh_global` — HSSH global levels: tree of maps, layout, navigation (B ch. 8–9).
* :mod:`~pqrm_jax.sim` — the JAX 2D rover simulator.
* :mod:`~pqrm_jax.studies` — long studies run by ``pqrm-jax study NAME``.
* :mod:`~pqrm_jax.triplets` — the triplet vocabulary: orderings, layouts and converters.
* :mod:`~pqrm_jax.protocols` — the step convention ``init`` / ``update(state, key, *obs)`` and
  :func:`~pqrm_jax.protocols.run`.
* :mod:`~pqrm_jax.io` — your data in (CSV/NumPy, ROS maps), maps out (save/load, GraphML).
* :mod:`~pqrm_jax.plot` — figures of maps: PQRM/QRM, Link Graph, HSSH local and global.

>>> import pqrm_jax
>>> pqrm_jax.calculi.get("lr").states
('l', 'r')
>>> sorted(pqrm_jax.__all__)[:3]
['calculi', 'cli', 'compositions']
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"
__all__ = ["calculi", "tables", "pqrm", "qrm", "serge", "compositions", "sim", "studies",
           "triplets", "cli", "qlink", "bsp", "hssh", "hssh_global", "protocols", "io",
           "plot"]
SUBPACKAGES = tuple(__all__)


def __getattr__(name: str):
    if name in SUBPACKAGES:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *SUBPACKAGES])
