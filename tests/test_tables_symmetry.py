"""Exact shortcuts of the table build: mirror symmetry and path-consistency refutation."""

from __future__ import annotations

import numpy as np

from pqrm_jax import calculi
from pqrm_jax.calculi import Calculus, alpha, beta
from pqrm_jax.tables import problems as pb
from pqrm_jax.tables import symmetry


def test_mirror_atoms():
    edc = calculi.get("edc")
    at, _ = pb.atoms(edc)
    s = symmetry.mirror_atoms(edc, at)
    assert all(s[s[i]] == i and s[i] != i for i in range(len(at)))  # no atom on the axis
    assert all(at[s[i]][0] == -at[i][0] and at[s[i]][1:] == at[i][1:] for i in range(len(at)))
    dcc = calculi.get("dcc")
    at, _ = pb.atoms(dcc)
    s = symmetry.mirror_atoms(dcc, at)
    fixed = {at[i] for i in range(len(at)) if s[i] == i}
    assert fixed == {a for a in at if isinstance(a, str) or a[0] == 0}
    skew = Calculus.from_rule("skew_t", [alpha - beta], lambda g: "p" if g[0] > 0 else "n")
    assert symmetry.mirror_atoms(skew, pb.atoms(skew)[0]) is None


def _atom_tables(calc):
    at, astate = pb.atoms(calc)
    t = calc.tables
    Q = len(at)
    st = np.asarray(astate)  # EDC: one atom per state
    assert len(set(astate)) == Q
    un = {op: getattr(t, op)[np.ix_(st, st)] for op in ("left", "right", "inverse")}
    comp = t.compose[np.ix_(st, st, st)]
    return at, un, comp


def test_path_consistency_never_refutes_a_realised_configuration():
    """Random 4-point configurations: their (AB:C, BC:D, AB:D) is never refuted under the
    exact tables (soundness), while some table-absent triples are."""
    edc = calculi.get("edc")
    at, un, comp = _atom_tables(edc)
    state_to_atom = np.argsort(np.asarray(pb.atoms(edc)[1]))
    rng = np.random.default_rng(0)
    P = rng.normal(0, 1.5, (3000, 4, 2))
    A, B, C, D = (P[:, i] for i in range(4))
    s = np.stack([np.asarray(edc.classify(A, B, C)), np.asarray(edc.classify(B, C, D)),
                  np.asarray(edc.classify(A, B, D))], 1)
    s = s[(s >= 0).all(1)]
    probs = state_to_atom[s]
    refuted = symmetry.path_consistency_refutes(un["left"], un["right"], un["inverse"], comp,
                                                probs)
    assert len(probs) > 2500 and not refuted.any()
    absent = np.argwhere(~comp)[:500]
    r = symmetry.path_consistency_refutes(un["left"], un["right"], un["inverse"], comp, absent)
    assert r.sum() > 50


def test_representatives_pairs_each_problem_with_its_mirror():
    keys = [(0, 1, 2), (1, 0, 3), (2, 3, 0), (3, 2, 1), (0, 0, 0)]
    sigma = [1, 0, 3, 2]
    rep = symmetry.representatives(keys, sigma)
    assert rep == [0, 0, 2, 2, 4]  # (0,0,0) has no mirror among the keys
    assert symmetry.representatives(keys, None) == list(range(5))
    assert symmetry.mirror_witness([[0.5, 1.0], [-2, 3]]) == [[-0.5, 1.0], [2.0, 3.0]]
