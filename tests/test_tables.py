"""Exact operator tables: published fixtures, properties, witnesses, oracle, cache, CLI."""

import json
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from pqrm_jax import calculi, tables
from pqrm_jax.calculi import Calculus, alpha, beta
from pqrm_jax.tables import CacheError, certify, exact
from pqrm_jax.tables import problems as pb

# McClelland Table I: AB:C -> (BC:A, CA:B, BA:C)
TABLE_I = """1 17 7 20|2 18 8 19|3 19 13 18|4 20 14 17|5 12 7 16|6 11 13 15|7 1,5 12,17 14|
8 2,10 15,18 13|9 16 14 12|10 15 8 11|11 13 6 10|12 7 5 9|13 3,6 11,19 8|14 4,9 16,20 7|
15 8 10 6|16 14 9 5|17 7 1 4|18 8 2 3|19 13 3 2|20 14 4 1"""
ADJ = ("1:2,3,4,5,6 · 2:1,3,4,9,10 · 3:1,2,4,5,6,7,8 · 4:1,2,3,7,8,9,10 · 5:1,3,6,7,11,12,13 · "
       "6:1,3,5,7,11,12,13 · 7:3,4,5,6,8,11,12,13,14 · 8:3,4,7,9,10,13,14,15,16 · "
       "9:2,4,8,10,14,15,16 · 10:2,4,8,9,14,15,16 · 11:5,6,7,12,13,17,19 · 12:5,6,7,11,13,17,19 · "
       "13:5,6,7,8,11,12,14,17,18 · 14:7,8,9,10,13,15,16,17,18 · 15:8,9,10,14,16,18,20 · "
       "16:8,9,10,14,15,18,20 · 17:11,12,13,14,18,19,20 · 18:13,14,15,16,17,19,20 · "
       "19:11,12,17,18,20 · 20:15,16,17,18,19")
OPEN = ("edc", "edc_lune", "triple_cross", "double_cross", "single_cross", "lr", "quadrant")


@pytest.fixture(scope="module")
def edc():
    return calculi.get("edc").tables


def test_table_I(edc):
    for row in TABLE_I.replace("\n", "").split("|"):
        s, left, right, inv = row.split()
        assert set(edc.left_labels(s)) == set(left.split(","))
        assert set(edc.right_labels(s)) == set(right.split(","))
        assert set(edc.inverse_labels(s)) == set(inv.split(","))


def test_published_compositions(edc):
    assert edc.compose_labels("1", "5") == {"1", "5", "11", "12", "17", "19"}
    assert edc.compose_labels("5", "5") == {"12", "17", "18", "19", "20"}
    assert edc.compose_labels("11", "5") == {"17", "18", "19", "20"}
    X, Y = {"6", "7"}, {"16"}
    assert edc.compose_sets(edc.apply("left", X), edc.apply("inverse", Y)) == \
        {"1", "5", "11", "12", "17", "18", "19", "20"}


def test_adjacency_fixture_and_neighbour_distance(edc):
    e = calculi.get("edc")
    F = np.zeros((20, 20), bool)
    for part in ADJ.split(" · "):
        a, bs = part.split(":")
        for b in bs.split(","):
            F[e.index(a), e.index(b)] = True
    np.testing.assert_array_equal(edc.adjacency, F)
    assert edc.neighbor_distance.max() == 4
    assert (np.diag(edc.neighbor_distance) == 0).all()


@pytest.mark.parametrize("name", list(calculi.names()))
def test_unary_identities_and_no_open_problems(name):
    calc = calculi.get(name)
    t = calc.tables
    Q = calc.num_states
    inv = t.inverse.astype(int)
    assert (inv.sum(1) == 1).all() and (inv @ inv == np.eye(Q)).all()  # involution
    for i in range(Q):
        assert t.right[t.left[i]].any(0)[i]  # RIGHT(LEFT(AB:C)) = AB:C
        assert (t.left[t.left[i]].any(0) >= t.right[i]).all()  # LEFT∘LEFT ⊇ RIGHT
    assert all(u["resolved"] != "open" for u in t.undecided)
    assert t.summary()["open"] == 0


def test_edc_inverse_and_mirror_symmetry(edc):
    e = calculi.get("edc")
    for i in range(1, 21):
        assert edc.inverse_labels(str(i)) == [str(21 - i)]
    pairs = {"1": "2", "3": "4", "5": "10", "6": "9", "7": "8", "13": "14", "12": "15",
             "11": "16", "17": "18", "19": "20"}
    pairs |= {v: k for k, v in pairs.items()}
    m = np.array([e.index(pairs[s]) for s in e.states])
    np.testing.assert_array_equal(edc.compose[np.ix_(m, m, m)], edc.compose)
    for op in ("left", "right", "inverse"):
        tab = getattr(edc, op)
        np.testing.assert_array_equal(tab[np.ix_(m, m)], tab)


@pytest.mark.parametrize("name", ["edc", "dcc"])
def test_witnesses_reverify_exactly(name):
    calc = calculi.get(name)
    t = calc.tables
    keys = sorted(t.witnesses)
    assert len(keys) == int(t.compose.sum())
    rng = np.random.default_rng(0)
    for key in rng.choice(keys, size=min(400, len(keys)), replace=False):
        s1, s2, s3 = key.split("|")
        A, B, C, D = t.witnesses[key]
        got = (exact.exact_state(calc, A, B, C), exact.exact_state(calc, B, C, D),
               exact.exact_state(calc, A, B, D))
        if got != tuple(calc.index(s) for s in (s1, s2, s3)):
            # only a z3 witness of this very entry may be an approximation of an algebraic point
            assert key in _algebraic_witness_keys(calc, t), f"witness of {key} does not verify"
    for key, (A, B, C) in t.unary_witnesses.items():
        op, s1, s2 = key.split("|")
        X, Y, Z = {"left": (B, C, A), "right": (C, A, B), "inverse": (B, A, C)}[op]
        assert exact.exact_state(calc, A, B, C) == calc.index(s1)
        assert exact.exact_state(calc, X, Y, Z) == calc.index(s2)


def _algebraic_witness_keys(calc, t) -> set[str]:
    """'S1|S2|S3' keys of compose entries whose z3 witness is not exactly representable."""
    from pqrm_jax.calculi.calculus import pattern_index

    def label(atom):
        if isinstance(atom, str):
            return atom
        return calc.states[calc.sign_table[pattern_index(atom)]]

    return {"|".join(label(a) for a in u["tag"][1:]) for u in t.undecided
            if u["problem"] == "compose" and u.get("exact_witness") is False}


def _check_compose(calc, P):
    A, B, C, D = (P[:, i] for i in range(4))
    s1 = np.asarray(calc.classify(A, B, C))
    s2 = np.asarray(calc.classify(B, C, D))
    s3 = np.asarray(calc.classify(A, B, D))
    ok = (s1 >= 0) & (s2 >= 0) & (s3 >= 0)
    comp = calc.tables.compose
    bad = ok & ~comp[np.where(ok, s1, 0), np.where(ok, s2, 0), np.where(ok, s3, 0)]
    assert not bad.any(), P[bad][:3]
    return ok.sum()


@settings(max_examples=25, deadline=None)
@given(arrays(np.float64, (256, 4, 2), elements=st.floats(-4, 4, width=32)),
       st.sampled_from(OPEN))
def test_compose_holds_on_random_floats(P, name):
    _check_compose(calculi.get(name), P)


@settings(max_examples=25, deadline=None)
@given(arrays(np.int64, (512, 4, 2), elements=st.integers(-3, 3)),
       st.sampled_from(("dcc", "lr_full", "edc", "lr")))
def test_compose_holds_on_integer_grids(P, name):
    """Collinear, perpendicular and coincident configurations: boundary relations."""
    _check_compose(calculi.get(name), P.astype(np.float64))


def test_z3_oracle_agrees_on_random_entries():
    calc = calculi.get("edc")
    t = calc.tables
    atoms, st_ = pb.atoms(calc)
    rng = np.random.default_rng(3)
    for _ in range(40):
        i, j, k = rng.integers(0, 20, 3)
        pr = pb.compose_problem(calc, atoms[i], atoms[j], atoms[k])
        verdict = certify.UNSAT if pr.trivially_infeasible else certify.decide(pr.constraints)[0]
        assert (verdict == certify.SAT) == bool(t.compose[st_[i], st_[j], st_[k]])


def test_prob_compose_support_and_normalisation(edc):
    P = edc.prob_compose
    assert P.shape == (20, 20, 20)
    assert (P >= 0).all() and not np.isnan(P).any()
    assert (P[~edc.compose] == 0).all()
    rows = P.sum(-1)
    np.testing.assert_allclose(rows[edc.compose.any(-1)], 1.0, atol=1e-6)
    with pytest.raises(ValueError, match="boundary"):
        from pqrm_jax.tables.probabilistic import prob_compose

        prob_compose(calculi.get("dcc"))


def test_direct_constraint_calculus_equals_merge(tmp_path, monkeypatch):
    """The solver run on the open FDC defined by constraints gives the merged-EDC tables."""
    monkeypatch.setenv("PQRM_JAX_CACHE", str(tmp_path))
    direct = Calculus.from_rule(
        "fdc_direct_t", [-alpha, -beta, 1 - beta],
        lambda s: None if (s[2] < 0 and s[1] > 0) else
        ("l" if s[0] > 0 else "r") + ("f" if s[2] < 0 else ("b" if s[1] > 0 else "m")),
        ["lf", "rf", "lm", "rm", "lb", "rb"])
    merged = calculi.get("double_cross").tables
    t = tables.load_tables(direct, certify_all=True)
    for op in ("left", "right", "inverse", "compose", "adjacency"):
        np.testing.assert_array_equal(getattr(t, op), getattr(merged, op), err_msg=op)
    assert tables.cache_path(direct).exists()
    assert tables.cache_path(direct).parent == tmp_path
    assert tables.cache_path(direct).name.startswith("fdc_direct_t")


def test_cache_corrupt_and_stale(tmp_path, monkeypatch):
    monkeypatch.setenv("PQRM_JAX_CACHE", str(tmp_path))
    lr2 = Calculus.from_rule("lr_cache_t", [-alpha], lambda s: "r" if s[0] < 0 else "l")
    tables.load_tables(lr2)
    path = tables.cache_path(lr2)
    assert path.parent == tmp_path and path.name.startswith("lr_cache_t")
    good = path.read_text()
    path.write_text(good[:-20])  # truncated
    tables.clear_memo()
    with pytest.raises(CacheError, match="corrupt"):
        tables.load_tables(lr2)
    raw = json.loads(good)
    raw["payload"]["compose"]["l|l"] = []  # edited content, checksum no longer matches
    path.write_text(json.dumps(raw))
    with pytest.raises(CacheError, match="checksum"):
        tables.load_tables(lr2)
    raw = json.loads(good)
    raw["payload"]["definition_hash"] = "0" * 16
    tables.write_cache(tables.OperatorTables.from_json(raw["payload"]), path)
    with pytest.warns(UserWarning, match="stale"):
        t = tables.load_tables(lr2)
    assert t.definition_hash == lr2.definition_hash


def test_cli_json_export(tmp_path, capsys):
    from pqrm_jax.cli import main

    out = tmp_path / "edc.json"
    assert main(["tables", "edc", "--json", str(out)]) == 0
    d = json.loads(out.read_text())
    assert d["calculus"] == "edc" and d["states"][0] == "1"
    assert set(d["unary"]["left"]["7"]) == {"1", "5"}
    assert set(d["compose"]["1|5"]) == {"1", "5", "11", "12", "17", "19"}
    A, B, C, D = d["witnesses"]["1|5|11"]
    assert len(A) == 2 and isinstance(d["undecided"], list)
    # an unknown calculus is a user error: one line naming the known calculi, exit code 2 (D16)
    assert main(["tables", "nope", "--json", str(out)]) == 2
    assert "known calculi" in capsys.readouterr().err


def test_cache_repair_advice_works_for_user_calculi(tmp_path, monkeypatch):
    """D18: the advice for a user calculus is to delete the file (no CLI command can see it)."""
    monkeypatch.setenv("PQRM_JAX_CACHE", str(tmp_path))
    lr2 = Calculus.from_rule("lr_advice_t", [-alpha], lambda s: "r" if s[0] < 0 else "l")
    tables.load_tables(lr2)
    path = tables.cache_path(lr2)
    path.write_text("{not json")
    tables.clear_memo()
    with pytest.raises(CacheError, match="rebuilt on next access") as err:
        tables.load_tables(lr2)
    assert str(path) in str(err.value) and "pqrm-jax tables" not in str(err.value)
    path.unlink()  # following the advice repairs it
    assert tables.load_tables(lr2).definition_hash == lr2.definition_hash


def test_cache_keyed_by_definition_and_confined(tmp_path, monkeypatch):
    """D19: two merges with one name get two files; a name cannot leave the cache directory."""
    cache = tmp_path / "c"
    monkeypatch.setenv("PQRM_JAX_CACHE", str(cache))
    edc = calculi.get("edc")
    states = [str(i) for i in range(1, 21)]
    g1 = {"l": "1 3 5 6 7 11 12 13 17 19".split(), "r": "2 4 8 9 10 14 15 16 18 20".split()}
    g2 = {"a": states[:10], "b": states[10:]}
    m1, m2 = edc.merge("../escaped", g1), edc.merge("../escaped", g2)
    p1, p2 = tables.cache_path(m1), tables.cache_path(m2)
    assert p1 != p2 and p1.parent == cache and p2.parent == cache
    t1 = tables.load_tables(m1)
    t2 = tables.load_tables(m2)
    assert p1.exists() and p2.exists()
    assert not (tmp_path / "escaped.json").exists()
    assert sorted(x.name for x in tmp_path.iterdir()) == ["c"]
    tables.clear_memo()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "stale" rebuild when alternating
        assert tables.load_tables(m1).definition_hash == t1.definition_hash
        assert tables.load_tables(m2).definition_hash == t2.definition_hash
    assert tables.safe_file_stem("../../x/y") == "x_y"
    assert tables.cache_path(edc) == tables.PACKAGE_DIR / "edc.json"
