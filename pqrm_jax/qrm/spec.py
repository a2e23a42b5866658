"""Static per-calculus arrays used by the QRM pipeline (M§II–III, docs/decisions.md §4).

:func:`qrm_spec` turns a :class:`~pqrm_jax.calculi.Calculus` into a :class:`QRMSpec`: the
constraint coefficients needed by the camera measurement (M§IV, Table III), the atom
(sign-pattern) structure, and the operator tables as uint32 bitmasks (bit ``i`` = state ``i``)
for the map update (M§VI.B). Everything is a plain NumPy array so it can be closed over by
jitted functions (hashable by identity through :func:`qrm_spec`'s cache).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import cache

import numpy as np

from ..calculi import Calculus
from ..calculi import get as get_calculus
from ..triplets import sets_to_masks

__all__ = ["QRMSpec", "qrm_spec", "mask_of", "states_of", "popcount", "CYCLIC"]

#: the three cyclic relations of a slot triple (near, mid, far) = (0, 1, 2): XY:Z
CYCLIC = ((0, 1, 2), (1, 2, 0), (2, 0, 1))

#: EDC lune states (M Alg. 2): C inside both circles of radius |AB| around A and B.
_LUNE = {"edc": ("7", "8", "13", "14"), "edc_lune": ("lune",)}


@dataclass(frozen=True, eq=False)
class QRMSpec:
    """Arrays describing one calculus for the QRM pipeline.

    lin: [K, 4] float64, coefficients (c_n, c_u, c_v, c_m) of the homogenised constraint
        ``c_n·n + c_u·u + c_v·v + c_m·m`` (each constraint is a line or circle in (α, β)).
    atom_signs: [A, K] int8, sign pattern of each atom (a realisable pattern).
    atom_state: (A,) int32 state of each atom.
    pos / neg / amb: [K] uint32 atom masks compatible with a constraint that is certainly
        positive / certainly negative / of undetermined sign over a box.
    pattern_atom: (3**K,) int32, atom of a ±1 sign pattern (index Σ (s+1)·3^k), −1 if none.
    left / right / inverse: [Q] uint32, lifted unary operators (M Table I).
    compose: [Q, Q] uint32, ``compose[i, j]`` = mask of AB:D given AB:C=i, BC:D=j.
    adjacency: [Q, Q] bool conceptual neighbourhood (for the "not adjacent" metric).
    lune: uint32 mask of the lune states, 0 when the calculus has no lune (no RNG).
    """

    calc: Calculus
    lin: np.ndarray
    atom_signs: np.ndarray
    atom_state: np.ndarray
    pos: np.ndarray
    neg: np.ndarray
    amb: np.ndarray
    pattern_atom: np.ndarray
    left: np.ndarray
    right: np.ndarray
    inverse: np.ndarray
    compose: np.ndarray
    adjacency: np.ndarray
    lune: int

    @property
    def num_states(self) -> int:
        return self.calc.num_states

    @property
    def num_atoms(self) -> int:
        return int(self.atom_state.shape[0])

    @property
    def k(self) -> int:
        return int(self.lin.shape[0])

    @property
    def full(self) -> int:
        """Mask with every state set."""
        return (1 << self.num_states) - 1

    @property
    def atom_full(self) -> int:
        return (1 << self.num_atoms) - 1


def mask_of(calc: Calculus | str, labels) -> int:
    """Bitmask of a collection of state labels, e.g. ``mask_of("edc", [7, 8])`` (M§VI.A).

    Args:
        calc: the calculus or its name.
        labels: state labels (or their string forms).

    Returns:
        The int mask with bit ``i`` set for state ``i``.

    Raises:
        ValueError: for a label that is not a state of ``calc``.
    """
    calc = get_calculus(calc)
    m = 0
    for lab in labels:
        m |= 1 << calc.index(lab)
    return m


def states_of(calc: Calculus | str, mask: int) -> list[str]:
    """State labels in a bitmask (inverse of :func:`mask_of`; M§VI.A).

    Args:
        calc: the calculus or its name.
        mask: an integer mask.

    Returns:
        The labels of the set bits, in state order.

    Raises:
        TypeError: for a mask that is not an integer.
        ValueError: for a negative mask or one with bits at or above ``num_states`` (no state
            of ``calc`` has them, so the mask is not a set of its states).
    """
    calc = get_calculus(calc)
    if isinstance(mask, bool | np.bool_) or not isinstance(mask, int | np.integer):
        raise TypeError(f"a state mask must be an integer, got {type(mask).__name__}")
    mask = int(mask)
    if mask < 0 or mask >> calc.num_states:
        raise ValueError(f"mask {mask:#x} has bits outside the {calc.num_states} states of "
                         f"{calc.name!r} (valid masks are < 2**{calc.num_states})")
    return [s for i, s in enumerate(calc.states) if mask >> i & 1]


def popcount(x):
    """Number of set bits of uint32 masks (NumPy or JAX arrays)."""
    import jax.numpy as jnp

    if isinstance(x, np.ndarray | np.integer | int):
        x = np.asarray(x, np.uint32)
        return np.bitwise_count(x).astype(np.int32) if hasattr(np, "bitwise_count") else \
            np.array([bin(int(v)).count("1") for v in x.ravel()], np.int32).reshape(x.shape)
    return jnp.bitwise_count(x.astype(jnp.uint32)).astype(jnp.int32)


def _linear_coefficients(calc: Calculus) -> np.ndarray:
    lin = np.zeros((calc.k, 4))
    slot = {(0, 0, 0): 0, (1, 0, 0): 1, (0, 1, 0): 2, (0, 0, 1): 3}
    for i, poly in enumerate(calc.constraints):
        for mono, coef in poly.terms.items():
            if tuple(mono) not in slot:
                raise ValueError(
                    f"calculus {calc.name!r}: constraint {i} ({poly}) is not a line or circle "
                    "(c0 + c1·α + c2·β + c3·ρ); the camera measurement supports only those")
            lin[i, slot[tuple(mono)]] = float(coef)
    return lin


@cache
def _spec(calc: Calculus) -> QRMSpec:
    from ..calculi.calculus import pattern_index

    if calc.num_states > 32:
        raise ValueError(f"calculus {calc.name!r} has {calc.num_states} states; the QRM "
                         "bitmask map supports at most 32")
    lin = _linear_coefficients(calc)
    k = calc.k
    sign_set = (-1, 0, 1) if calc.boundary_inclusive else (-1, 1)
    atoms, states = [], []
    for signs in itertools.product(sign_set, repeat=k):
        st = int(calc.sign_table[pattern_index(signs)])
        if st >= 0:
            atoms.append(signs)
            states.append(st)
    if len(atoms) > 32:
        raise ValueError(f"calculus {calc.name!r} has {len(atoms)} sign-pattern atoms; the "
                         "camera measurement supports at most 32")
    atom_signs = np.asarray(atoms, np.int8).reshape(len(atoms), k)
    pos = sets_to_masks((atom_signs == 1).T)
    neg = sets_to_masks((atom_signs == -1).T)
    amb = np.full(k, (1 << len(atoms)) - 1, np.uint32)
    pattern_atom = np.full(3**k, -1, np.int32)
    for a, signs in enumerate(atoms):
        if all(s != 0 for s in signs):
            pattern_atom[pattern_index(signs)] = a
    t = calc.tables
    lune = 0
    for name, labels in _LUNE.items():
        if calc.name == name:
            lune = mask_of(calc, labels)
    return QRMSpec(
        calc=calc, lin=lin, atom_signs=atom_signs, atom_state=np.asarray(states, np.int32),
        pos=pos, neg=neg, amb=amb, pattern_atom=pattern_atom,
        left=sets_to_masks(np.asarray(t.left, bool)),
        right=sets_to_masks(np.asarray(t.right, bool)),
        inverse=sets_to_masks(np.asarray(t.inverse, bool)),
        compose=sets_to_masks(np.asarray(t.compose, bool)),
        adjacency=np.asarray(t.adjacency, bool), lune=lune,
    )


def qrm_spec(calc: Calculus | str = "edc") -> QRMSpec:
    """The (cached) :class:`QRMSpec` of a calculus or calculus name (M§VI).

    Args:
        calc: the calculus or its name.

    Returns:
        The :class:`QRMSpec` (state tables, atoms, lune mask).

    Raises:
        ValueError: for a calculus the QRM masks cannot hold (more than 32 states or atoms) or
            whose constraints are not lines or circles.

    >>> s = qrm_spec("edc")
    >>> s.num_states, s.num_atoms, states_of("edc", s.lune)
    (20, 20, ['7', '8', '13', '14'])
    """
    return _spec(get_calculus(calc))
