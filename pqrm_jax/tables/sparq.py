"""Export exact operator tables as a SparQ calculus definition (``def-calculus`` file).

SparQ (Wolter et al., the qualitative spatial reasoning toolbox) reads a calculus as one Lisp
form ``(def-calculus "NAME" :arity :ternary ... :base-relations (...) :inverse-operation (...)
:shortcut-operation (...) :homing-operation (...) :composition-operation (...))``. A ternary
constraint ``(A B r C)`` there is what pqrm-jax writes ``AB:C = r``: the relation of the
point C to the directed pair A→B (M §III.A). The operations map as follows (derivation in
docs/tables.md §sparq):

* ``inverse``: ``(A B r C) -> (B A r' C)`` is pqrm-jax INVERSE (the same permutation);
* ``homing``: ``(A B r C) -> (B C r' A)`` is pqrm-jax LEFT (the same permutation);
* ``shortcut``: ``(A B r C) -> (A C r' B)`` is INVERSE applied after RIGHT;
* ``composition``: ``(A B r1 C), (B C r2 D) -> (A B r D)`` is pqrm-jax COMPOSE.

pqrm-jax's RIGHT, ``AB:C -> CA:B``, is homing applied twice; SparQ derives it and has no slot
for it. The shortcut table is the relational product ``RIGHT ; INVERSE``; it is exact when
INVERSE is single-valued (true for every shipped calculus: each configuration in RIGHT's
image class ``j`` has the one inverse state ``INVERSE(j)``). For a calculus whose INVERSE is
multi-valued the product is only an upper bound; it is then intersected with the second
upper bound ``INVERSE ; LEFT`` and the file says so in its header.

State labels that are not safe Lisp symbols (``"1"`` reads as a number, case folds, spaces)
are renamed; the mapping is written into the file's header comments and returned by
:func:`sparq_names`.

>>> from pqrm_jax import calculi
>>> text = to_sparq(calculi.get("lr").tables)
>>> print(text.splitlines()[0])
;;; SparQ calculus definition of the pqrm-jax calculus "lr"
>>> ":homing-operation ((l l) (r r))" in " ".join(text.split())
True
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from .store import OperatorTables

__all__ = ["conceptual_neighbours", "identity_relation", "shortcut_table", "sparq_names",
           "to_sparq", "write_sparq"]

_SAFE = re.compile(r"^[A-Za-z][A-Za-z0-9_\-]*$")
_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")


def sparq_names(states: tuple[str, ...] | list[str]) -> dict[str, str]:
    """SparQ symbol for every state label: the label itself when it is a safe symbol.

    A safe symbol starts with a letter, holds only letters, digits, ``_`` and ``-``, does not
    read as a number, is not ``nil``/``t`` and is unique without regard to case (the Lisp
    reader folds case). Any other label becomes ``r`` + the label with other characters
    replaced by ``_``, made unique with a numeric suffix.

    Args:
        states: the state labels.

    Returns:
        ``label -> SparQ symbol``.

    >>> sparq_names(("1", "2", "lune"))
    {'1': 'r1', '2': 'r2', 'lune': 'lune'}
    """
    out: dict[str, str] = {}
    keep = [s for s in states if _SAFE.match(s) and not _NUMBER.match(s)
            and s.lower() not in ("nil", "t")]
    lower = [s.lower() for s in keep]
    keep = {s for s in keep if lower.count(s.lower()) == 1}
    taken = {s.lower() for s in keep}
    for s in states:
        if s in keep:
            out[s] = s
            continue
        base = "r" + re.sub(r"[^A-Za-z0-9_\-]", "_", s)
        name, k = base, 1
        while name.lower() in taken:
            k += 1
            name = f"{base}_{k}"
        taken.add(name.lower())
        out[s] = name
    return out


def _product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Relational product ``a ; b``: ``[Q, Q] x [Q, Q] -> [Q, Q]`` (apply ``a`` then ``b``)."""
    return (a[:, :, None] & b[None, :, :]).any(axis=1)


def shortcut_table(tables: OperatorTables) -> tuple[np.ndarray, bool]:
    """SparQ's shortcut ``AB:C -> AC:B`` as a ``[Q, Q]`` boolean table, and whether it is exact.

    ``AC:B`` is INVERSE of ``CA:B`` = RIGHT(``AB:C``), so the table is ``RIGHT ; INVERSE``;
    exact when INVERSE is single-valued on every state, otherwise intersected with
    ``INVERSE ; LEFT`` (``AB:C -> BA:C -> AC:B``) and reported as an upper bound.

    Args:
        tables: the calculus's tables.

    Returns:
        ``([Q, Q] bool, exact)``.
    """
    via_right = _product(tables.right, tables.inverse)
    exact = bool((tables.inverse.sum(axis=1) == 1).all())
    if exact:
        return via_right, True
    return via_right & _product(tables.inverse, tables.left), False


def _identity(tables: OperatorTables) -> int | None:
    """The state ``e`` (SparQ's identity relation: D = C), or None.

    ``e`` qualifies when COMPOSE(r, e) is ``{r}`` or empty for every state r (empty where the
    pair cannot occur, e.g. r with B = C) — the convention of SparQ's own ternary calculi (its
    flip-flop calculus declares ``e``, ``b = c``, as identity). Of the qualifying states the
    one non-empty for the most r is taken (``tri`` also qualifies, for two r only); a tie
    gives None.
    """
    Q = tables.num_states
    eye = np.eye(Q, dtype=bool)
    found = []
    for e in range(Q):
        col = tables.compose[:, e, :]
        rows_ok = [(col[r] == eye[r]).all() or not col[r].any() for r in range(Q)]
        if all(rows_ok) and col.any():
            found.append((int(col.any(axis=1).sum()), e))
    found.sort(reverse=True)
    if not found or (len(found) > 1 and found[0][0] == found[1][0]):
        return None
    return found[0][1]


def identity_relation(tables: OperatorTables) -> tuple[int, bool]:
    """The state written as SparQ's ``:identity-relation`` and whether it is a true identity.

    SparQ refuses a calculus file without ``:identity-relation`` (``Identity relation not
    specified``), whatever the arity. A true identity ``e`` (``B C e D`` means D = C, so
    COMPOSE(r, e) is ``{r}`` or empty for every r) exists only in calculi with a B = C state
    (``lr_full``'s ``e``, ``dcc``'s ``5``). For the others (``edc``, ``lr``, ...) no state can
    be one, and the file names a *placeholder*: the state ``e`` with ``r ∈ COMPOSE(r, e)`` for
    the most r (first in state order on a tie) — the closest to an identity, still not one.
    SparQ reads the identity only in its binary-calculus code (binary matching and the
    converse-based ``analyze-calculus test-algebra``); its ternary composition, closure and
    scenario commands never read it, so the placeholder changes no ternary result.

    Args:
        tables: the calculus's tables.

    Returns:
        ``(index, True)`` for a true identity, ``(index, False)`` for the placeholder.
    """
    ident = _identity(tables)
    if ident is not None:
        return ident, True
    Q = tables.num_states
    self_count = [int(sum(tables.compose[r, e, r] for r in range(Q))) for e in range(Q)]
    return int(np.argmax(self_count)), False


def conceptual_neighbours(tables: OperatorTables) -> list[list[int]]:
    """SparQ's ``:cnhs`` rows: each state's conceptual neighbours (P §2.3.1).

    Args:
        tables: the calculus's tables.

    Returns:
        for every state, its neighbours (``tables.adjacency`` without the diagonal) as state
        indices in state order.
    """
    adj = np.asarray(tables.adjacency, bool)
    return [[int(j) for j in np.flatnonzero(adj[i]) if j != i] for i in range(adj.shape[0])]


def _rows(table: np.ndarray, names: list[str]) -> list[str]:
    return [f"({names[i]} {' '.join(names[j] for j in np.flatnonzero(table[i]))})"
            for i in range(len(names))]


def to_sparq(tables: OperatorTables) -> str:
    """The text of a SparQ ``def-calculus`` file for ``tables``.

    Args:
        tables: the calculus's tables.

    Returns:
        The file text; header comments state the relation-name mapping and the operation
        semantics.
    """
    S = list(tables.states)
    mapping = sparq_names(S)
    N = [mapping[s] for s in S]
    shortcut, exact = shortcut_table(tables)
    ident, true_identity = identity_relation(tables)
    ind = "  "
    head = [
        f';;; SparQ calculus definition of the pqrm-jax calculus "{tables.calculus}"',
        f";;; written by pqrm-jax from tables with definition hash {tables.definition_hash}",
        ";;;",
        ";;; A SparQ constraint (A B r C) is pqrm-jax's AB:C = r (point C relative to A->B).",
        ";;;   :inverse-operation     (A B r C) -> (B A r' C) = pqrm-jax INVERSE",
        ";;;   :homing-operation      (A B r C) -> (B C r' A) = pqrm-jax LEFT",
        ";;;   :shortcut-operation    (A B r C) -> (A C r' B) = pqrm-jax INVERSE after RIGHT"
        + (" (exact: INVERSE is single-valued)" if exact else
           " (UPPER BOUND: INVERSE is multi-valued; intersected with LEFT after INVERSE)"),
        ";;;   :composition-operation (r1 r2 (r ...)): (A B r1 C), (B C r2 D) -> (A B r D)"
        " = pqrm-jax COMPOSE",
        ";;;   pqrm-jax RIGHT, (A B r C) -> (C A r' B), is homing applied twice.",
        ";;; No :qualifier is exported: pqrm-jax classifies points with its own JAX code.",
    ]
    if true_identity:
        head.append(f";;; Identity relation: {N[ident]} (COMPOSE(r, {N[ident]}) is {{r}} or empty "
                    "for every r: (B C {N[ident]} D) means D = C).")
    else:
        head += [
            f";;; Identity relation: {N[ident]} is a PLACEHOLDER, not an identity. No state e of",
            ";;;   this calculus has COMPOSE(r, e) = {r} or empty for every r (no state means",
            ";;;   D = C). SparQ refuses a file without :identity-relation, so the file names the",
            ";;;   state with r in COMPOSE(r, e) for the most r. SparQ reads the identity only in",
            ";;;   binary-calculus code (matching, analyze-calculus test-algebra); its ternary",
            ";;;   composition / closure / scenario commands do not use it.",
        ]
    head += [
        ";;; :cnhs exports the conceptual neighbourhood (pqrm-jax adjacency) as neighbourhood"
        " 'default' (alias 'def').",
        ";;;",
        ";;; Relation-name mapping (SparQ base relation <- pqrm-jax state label):",
    ]
    head += [f";;;   {n} <- {s!r}" for s, n in zip(S, N, strict=True)]
    body = [f'(def-calculus "pqrm-jax {tables.calculus}"',
            f"{ind}:arity :ternary", f"{ind}:basis-entity :2d-point", f"{ind}:parametric? nil",
            f"{ind}:consistency :unknown"]
    body.append(f"{ind}:identity-relation {N[ident]}")
    body.append(f"{ind}:base-relations ({' '.join(N)})")
    for key, table in (("inverse", tables.inverse), ("shortcut", shortcut),
                       ("homing", tables.left)):
        rows = _rows(table, N)
        body.append(f"{ind}:{key}-operation ({rows[0]}")
        body += [f"{ind}{' ' * (len(key) + 13)}{r}" for r in rows[1:]]
        body[-1] += ")"
    comp = []
    for i in range(len(S)):
        for j in range(len(S)):
            ks = np.flatnonzero(tables.compose[i, j])
            res = f"({' '.join(N[k] for k in ks)})" if len(ks) else "NIL"
            comp.append(f"({N[i]} {N[j]} {res})")
    cn = [f"({N[i]}{''.join(' ' + N[j] for j in nb)})"
          for i, nb in enumerate(conceptual_neighbours(tables))]
    body.append(f"{ind}:cnhs (((default def) ({cn[0]}")
    body += [f"{ind}{' ' * 23}{c}" for c in cn[1:]]
    body[-1] += ")))"
    body.append(f"{ind}:composition-operation ({comp[0]}")
    body += [f"{ind}{' ' * 24}{c}" for c in comp[1:]]
    body[-1] += "))"
    return "\n".join(head + [""] + body) + "\n"


def write_sparq(tables: OperatorTables, path: str | Path) -> Path:
    """Write :func:`to_sparq` of ``tables`` to ``path`` atomically (temp file + rename).

    Args:
        tables: the calculus's tables.
        path: the output file.

    Returns:
        ``path`` as a :class:`~pathlib.Path`.
    """
    import os

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(to_sparq(tables))
    os.replace(tmp, path)
    return path
