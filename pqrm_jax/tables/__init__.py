"""Exact operator tables of a calculus: unary operators, composition, adjacency.

Decisions: docs/decisions.md §2.3; the build pipeline: docs/tables.md §method.

>>> from pqrm_jax import calculi
>>> t = calculi.get("edc").tables
>>> sorted(t.compose_labels("1", "5"), key=int)
['1', '5', '11', '12', '17', '19']
>>> t.left_labels("7")
['1', '5']

* :mod:`.store` — :class:`OperatorTables`, the JSON cache (paths, read/write, checksum,
  :class:`CacheError`) and :func:`load_tables` / :func:`build_tables`.
* :mod:`.build` — the exact build (branch and bound + z3 certificates); :mod:`.feasibility`,
  :mod:`.problems`, :mod:`.exact`, :mod:`.symmetry`, :mod:`.certify` are its parts.
* :mod:`.probabilistic` — probabilistic composition of open calculi (Z eq. 2.4).
* :mod:`.sparq` — export as a SparQ ``def-calculus`` file (:func:`to_sparq`, :func:`write_sparq`).
* :mod:`.reference` — a plain NumPy solver (test oracle, benchmark baseline).
"""

from .sparq import shortcut_table, sparq_names, to_sparq, write_sparq
from .store import (
    FORMAT_VERSION,
    PACKAGE_DIR,
    UNARY,
    CacheError,
    OperatorTables,
    build_tables,
    cache_dir,
    cache_path,
    clear_memo,
    load_tables,
    read_cache,
    safe_file_stem,
    write_cache,
)

__all__ = [
    "FORMAT_VERSION", "PACKAGE_DIR", "UNARY", "CacheError", "OperatorTables", "build_tables",
    "cache_dir", "cache_path", "clear_memo", "load_tables", "read_cache", "safe_file_stem",
    "write_cache", "shortcut_table", "sparq_names", "to_sparq", "write_sparq",
]
