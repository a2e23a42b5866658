"""Operator-table store: the tables dataclass, its JSON cache and the build orchestration.

>>> from pqrm_jax import calculi
>>> t = calculi.get("edc").tables
>>> sorted(t.compose_labels("1", "5"), key=int)
['1', '5', '11', '12', '17', '19']
>>> t.left_labels("7")
['1', '5']

Tables are cached as JSON keyed by the calculus's definition hash: built-in calculi in the
package data (``pqrm_jax/data/tables/NAME.json``), user calculi in ``$PQRM_JAX_CACHE`` (default
``~/.cache/pqrm-jax/tables``) as ``SAFE-NAME-HASH.json`` — the name sanitised so that it cannot
leave the cache directory, the definition hash so that two calculi with the same name never
share (and rebuild) one file. A stale file (hash mismatch) is rebuilt with a warning; a corrupt
file (bad JSON, bad checksum, wrong shapes) raises :class:`CacheError` naming the file and how
to repair it — it is never silently used.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import warnings
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from ..calculi.calculus import Calculus

FORMAT_VERSION = 1
PACKAGE_DIR = Path(__file__).resolve().parent.parent / "data" / "tables"
UNARY = ("left", "right", "inverse")


class CacheError(RuntimeError):
    """A cached table file is corrupt or inconsistent."""


@dataclass
class OperatorTables:
    """Boolean operator tables over state indices, with witnesses and provenance."""

    calculus: str
    states: tuple[str, ...]
    definition_hash: str
    left: np.ndarray  # (Q, Q): AB:C = i allows BC:A = j
    right: np.ndarray  # (Q, Q): CA:B
    inverse: np.ndarray  # (Q, Q): BA:C
    compose: np.ndarray  # (Q, Q, Q): AB:C = i, BC:D = j allows AB:D = k
    adjacency: np.ndarray  # (Q, Q) conceptual neighbourhood
    witnesses: dict = field(default_factory=dict)  # "S1|S2|S3" -> [[ax,ay],...,[dx,dy]]
    unary_witnesses: dict = field(default_factory=dict)  # "left|S1|S2" -> [[ax,ay],[bx,by],[cx,cy]]
    undecided: list = field(default_factory=list)
    stats: dict = field(default_factory=dict)
    settings: dict = field(default_factory=dict)
    prob: dict | None = None  # probabilistic composition (open calculi)

    # convenience ----------------------------------------------------------------------------
    @property
    def num_states(self) -> int:
        return len(self.states)

    @cached_property
    def neighbor_distance(self) -> np.ndarray:
        from .build import neighbor_distance

        return neighbor_distance(self.adjacency)

    @property
    def prob_compose(self) -> np.ndarray:
        """[Q, Q, Q] P(AB:D | AB:C, BC:D) under uniform-within-state priors (Z eq. 2.4)."""
        if self.prob is None:
            raise ValueError(f"no probabilistic composition for {self.calculus!r}")
        return self.prob["P"]

    def _idx(self, label) -> int:
        lab = str(label)
        if lab not in self.states:
            raise ValueError(f"{lab!r} is not a state of {self.calculus!r}")
        return self.states.index(lab)

    def _labels(self, mask) -> list[str]:
        return [self.states[i] for i in np.flatnonzero(mask)]

    def left_labels(self, s) -> list[str]:
        return self._labels(self.left[self._idx(s)])

    def right_labels(self, s) -> list[str]:
        return self._labels(self.right[self._idx(s)])

    def inverse_labels(self, s) -> list[str]:
        return self._labels(self.inverse[self._idx(s)])

    def compose_labels(self, s1, s2) -> set[str]:
        """COMPOSE(AB:C = s1, BC:D = s2) as a set of labels (M§III.B)."""
        return set(self._labels(self.compose[self._idx(s1), self._idx(s2)]))

    def apply(self, op: str, states) -> set[str]:
        """Set-valued unary operator on a set of labels (union over members)."""
        table = getattr(self, op)
        mask = np.zeros(self.num_states, bool)
        for s in states:
            mask |= table[self._idx(s)]
        return set(self._labels(mask))

    def compose_sets(self, set1, set2) -> set[str]:
        """COMPOSE lifted to sets by union (M§III.B)."""
        m1 = np.isin(np.arange(self.num_states), [self._idx(s) for s in set1])
        m2 = np.isin(np.arange(self.num_states), [self._idx(s) for s in set2])
        return set(self._labels(self.compose[m1][:, m2].any((0, 1))))

    def summary(self) -> dict:
        return {"calculus": self.calculus, "states": len(self.states),
                "compose_entries": int(self.compose.sum()),
                "unary_entries": {op: int(getattr(self, op).sum()) for op in UNARY},
                "adjacent_pairs": int(self.adjacency.sum() // 2),
                "undecided_by_bnb": self.stats.get("parent_undecided_by_bnb",
                                                   len(self.undecided)),
                "open": self.stats.get("parent_open",
                                       sum(u["resolved"] == "open" for u in self.undecided))}

    # serialisation ---------------------------------------------------------------------------
    def to_json(self) -> dict:
        """The export format of ``pqrm-jax tables NAME --json`` (plus provenance fields)."""
        S = self.states

        def unary(tab):
            return {S[i]: self._labels(tab[i]) for i in range(len(S))}

        out = {
            "calculus": self.calculus,
            "states": list(S),
            "unary": {op: unary(getattr(self, op)) for op in UNARY},
            "compose": {f"{S[i]}|{S[j]}": self._labels(self.compose[i, j])
                        for i in range(len(S)) for j in range(len(S))},
            "witnesses": self.witnesses,
            "unary_witnesses": self.unary_witnesses,
            "undecided": self.undecided,
            "adjacency": {S[i]: self._labels(self.adjacency[i]) for i in range(len(S))},
            "definition_hash": self.definition_hash,
            "format_version": FORMAT_VERSION,
            "stats": self.stats,
            "settings": self.settings,
        }
        if self.prob is not None:
            out["prob_compose"] = {k: (np.round(v, 6).tolist() if isinstance(v, np.ndarray)
                                       else v) for k, v in self.prob.items()}
        return out

    @classmethod
    def from_json(cls, d: dict, source: str = "<json>") -> OperatorTables:
        try:
            S = tuple(d["states"])
            Q = len(S)
            idx = {s: i for i, s in enumerate(S)}

            def unary(m):
                t = np.zeros((Q, Q), bool)
                for a, bs in m.items():
                    for b in bs:
                        t[idx[a], idx[b]] = True
                return t

            comp = np.zeros((Q, Q, Q), bool)
            for key, ks in d["compose"].items():
                a, b = key.split("|")
                for k in ks:
                    comp[idx[a], idx[b], idx[k]] = True
            prob = None
            if "prob_compose" in d:
                prob = dict(d["prob_compose"])
                prob["P"] = np.asarray(prob["P"], np.float64)
                prob["n"] = np.asarray(prob["n"], np.float64)
                if prob["P"].shape != (Q, Q, Q):
                    raise ValueError("prob_compose has the wrong shape")
            return cls(d["calculus"], S, d["definition_hash"],
                       *(unary(d["unary"][op]) for op in UNARY), comp, unary(d["adjacency"]),
                       d.get("witnesses", {}), d.get("unary_witnesses", {}),
                       d.get("undecided", []), d.get("stats", {}), d.get("settings", {}), prob)
        except (KeyError, ValueError, TypeError, AttributeError) as exc:
            name = d.get("calculus") if isinstance(d, dict) else None
            raise CacheError(f"table file {source} is corrupt ({exc!r}); "
                             f"{_repair_advice(source, name)}") from exc


def is_builtin_calculus(calc: Calculus) -> bool:
    """Whether ``calc`` is the registry's own built-in calculus of that name (shipped tables)."""
    from .. import calculi

    return calculi.is_builtin(calc.name) and calculi.get(calc.name) is calc


def cache_dir(calc: Calculus) -> Path:
    """Directory of the table file of ``calc``: package data (built-in) or ``$PQRM_JAX_CACHE``.

    Args:
        calc: the calculus.

    Returns:
        The directory (``~/.cache/pqrm-jax/tables`` when ``$PQRM_JAX_CACHE`` is unset).
    """
    if is_builtin_calculus(calc):
        return PACKAGE_DIR
    return Path(os.environ.get("PQRM_JAX_CACHE", Path.home() / ".cache" / "pqrm-jax" / "tables"))


def safe_file_stem(name: str) -> str:
    """``name`` reduced to a file-name stem that stays in its directory (``[A-Za-z0-9_.-]``).

    Args:
        name: any calculus name.

    Returns:
        The stem (``"calculus"`` when nothing is left).

    >>> safe_file_stem("../escaped"), safe_file_stem("my lr/2")
    ('escaped', 'my_lr_2')
    """
    stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", str(name)).strip("._-")
    return stem or "calculus"


def cache_path(calc: Calculus) -> Path:
    """Table file of ``calc``; user calculi are keyed by name *and* definition hash.

    Args:
        calc: the calculus.

    Returns:
        Built-in calculi: ``PACKAGE_DIR / NAME.json``. User calculi:
        ``$PQRM_JAX_CACHE / SAFE-NAME-HASH.json`` (see :func:`safe_file_stem`), always inside
        the cache directory whatever the name.
    """
    if is_builtin_calculus(calc):
        return PACKAGE_DIR / f"{calc.name}.json"
    return cache_dir(calc) / f"{safe_file_stem(calc.name)}-{calc.definition_hash}.json"


def _repair_advice(path, name: str | None = None) -> str:
    from .. import calculi

    if name is not None and calculi.is_builtin(name) and Path(path).parent == PACKAGE_DIR:
        return f"regenerate it with `pqrm-jax tables --rebuild {name}` (or delete it)"
    return f"delete {path}; it is rebuilt on next access"


def _checksum(payload: dict) -> str:
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()


def write_cache(tables: OperatorTables, path: Path) -> None:
    """Write ``tables`` to ``path`` with a checksum, atomically (temp file + rename).

    Args:
        tables: the tables.
        path: the table file (its directory is created).
    """
    payload = tables.to_json()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps({"checksum": _checksum(payload), "payload": payload}))
    tmp.replace(path)


def read_cache(path: Path) -> OperatorTables:
    """Read a table file written by :func:`write_cache`, verifying its checksum.

    Args:
        path: the table file.

    Returns:
        :class:`OperatorTables`.

    Raises:
        CacheError: for a corrupt, truncated or edited file (the message says how to repair).
    """
    try:
        raw = json.loads(path.read_text())
        payload = raw["payload"]
        ok = raw["checksum"] == _checksum(payload)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise CacheError(f"table file {path} is corrupt ({exc.__class__.__name__}: {exc}); "
                         f"{_repair_advice(path, path.stem)}") from exc
    if not ok:
        raise CacheError(f"table file {path} fails its checksum (edited or truncated); "
                         f"{_repair_advice(path, path.stem)}")
    return OperatorTables.from_json(payload, str(path))


_MEMO: dict[tuple[str, str], OperatorTables] = {}


def clear_memo() -> None:
    """Forget the tables held in this process (the next access re-reads the cache files)."""
    _MEMO.clear()


def build_tables(calc: Calculus, *, progress: bool = False, with_prob: bool = True,
                 **kwargs) -> OperatorTables:
    """Compute the tables of ``calc`` from geometry (merges: from the parent's tables).

    The pipeline of docs/tables.md §build (MT App. C, P §2.2.2).

    Args:
        calc: the calculus.
        progress: show progress bars.
        with_prob: also compute the probabilistic tables (``prob_compose`` etc.).
        **kwargs: settings of :func:`~pqrm_jax.tables.build.build_base`.

    Returns:
        :class:`OperatorTables` (not written to the cache; :func:`load_tables` does that).
    """
    from .build import build_base, merge_tables

    if calc.parent is not None:
        parent = load_tables(calc.parent, progress=progress)
        raw = merge_tables(calc, {op: getattr(parent, op) for op in
                                  (*UNARY, "compose", "adjacency")} |
                           {"unary_witnesses": parent.unary_witnesses,
                            "witnesses": parent.witnesses, "undecided": parent.undecided})
    else:
        raw = build_base(calc, progress=progress, **kwargs)
    prob = None
    if with_prob and not calc.boundary_inclusive:
        from .probabilistic import prob_compose

        prob = prob_compose(calc)
        prob["P"] = np.where(raw["compose"], prob["P"], 0.0)  # exact support
    return OperatorTables(calc.name, calc.states, calc.definition_hash, raw["left"],
                          raw["right"], raw["inverse"], raw["compose"], raw["adjacency"],
                          raw["witnesses"], raw["unary_witnesses"], raw["undecided"],
                          raw["stats"], raw["settings"], prob)


def load_tables(calc: Calculus, *, rebuild: bool = False, progress: bool = False,
                write: bool = True, certify_all: bool = True) -> OperatorTables:
    """Tables of ``calc`` from the cache, building (and caching) them when missing or stale.

    Args:
        calc: the calculus.
        rebuild: build even when a valid table file exists.
        progress: show progress bars while building.
        write: write a built table file to :func:`cache_path`.
        certify_all: confirm every refutation with z3 when building (as the shipped tables).

    Returns:
        :class:`OperatorTables` (memoised per name and definition hash).

    Raises:
        CacheError: for a corrupt table file.

    >>> from pqrm_jax import calculi
    >>> load_tables(calculi.get("lr")).inverse.astype(int).tolist()
    [[0, 1], [1, 0]]
    """
    key = (calc.name, calc.definition_hash)
    if not rebuild and key in _MEMO:
        return _MEMO[key]
    path = cache_path(calc)
    tables = None
    if path.exists() and not rebuild:
        tables = read_cache(path)
        if tables.definition_hash != calc.definition_hash or tables.states != calc.states:
            warnings.warn(f"table cache {path} is stale (definition changed); rebuilding",
                          stacklevel=2)
            tables = None
    if tables is None:
        kw = {"certify_all": certify_all} if calc.parent is None else {}
        tables = build_tables(calc, progress=progress, **kw)
        if write:
            try:
                write_cache(tables, path)
            except OSError as exc:
                warnings.warn(f"could not write table cache {path}: {exc}", stacklevel=2)
    _MEMO[key] = tables
    return tables


__all__ = ["OperatorTables", "CacheError", "load_tables", "build_tables", "cache_path",
           "cache_dir", "clear_memo", "read_cache", "write_cache", "safe_file_stem",
           "FORMAT_VERSION", "PACKAGE_DIR", "UNARY"]
