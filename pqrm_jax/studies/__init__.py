"""Studies run by ``pqrm-jax study NAME``.

Each study is a module in this package that defines ``NAME`` (the CLI name, e.g.
``"padgett-mc"``), ``HELP`` (one line) and ``main(argv: list[str]) -> int``. The CLI discovers
them; adding a study never edits a shared file. A study keeps its results in a
:class:`~pqrm_jax.studies.store.Store` (``Store.open(out, NAME, config)``: lock, study marker,
config guard with the precision, atomic writes, verified records, ``results.csv``).
"""

from __future__ import annotations

import importlib
import pkgutil
from types import ModuleType

__all__ = ["discover"]


def discover() -> dict[str, ModuleType]:
    """Map study name → module for every study module in this package."""
    found = {}
    for info in pkgutil.iter_modules(__path__):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{__name__}.{info.name}")
        name = getattr(mod, "NAME", None)
        if name:
            found[name] = mod
    return found
