"""The in-vivo-like Q-Link study (P §4.4.2): bands calculus, reference rule, executive, and the
reduced study (files, acceptance checks, resume)."""

import csv
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pqrm_jax import calculi
from pqrm_jax.qlink import hybrid as hy
from pqrm_jax.studies import discover


def test_bands_are_the_double_cross_bands():
    """front / between / behind of (A, B) = the Double Cross's three bands merged
    (docs/qlink.md §invivo): a point's band is the sign test on its projection along AB."""
    b, dc = hy.bands_calculus(), calculi.get("double_cross")
    rng = np.random.default_rng(0)
    a, bb = jnp.array([0.0, 0.0]), jnp.array([7.0, 3.0])
    x = jnp.asarray(rng.uniform(-20, 25, (200, 2)), jnp.float32)
    got = np.asarray(jax.vmap(lambda p: b.classify(a, bb, p))(x))
    t = np.asarray((x - a) @ (bb - a)) / float((bb - a) @ (bb - a))
    want = np.where(t > 1, 0, np.where(t < 0, 2, 1))
    assert (got == want).all()
    fine = np.asarray(jax.vmap(lambda p: dc.classify(a, bb, p))(x))
    assert (np.asarray(b.parent_map)[fine] == got).all()


def test_reference_rule_bands_use_the_walls():
    walls = (8, 9)
    # bands element {2, 8, 9} -> LR element {2, 8, 5}: refs = walls, target = point 2
    refs, t, o = hy.reference_rule([[2, 8, 9]], [hy.BANDS], [[2, 5, 8]], walls)
    assert refs.tolist() == [[8, 9]] and t.tolist() == [2] and o.tolist() == [3]
    # bands -> bands sharing both walls: nothing to search
    refs, t, o = hy.reference_rule([[2, 8, 9]], [hy.BANDS], [[3, 8, 9]], walls)
    assert t.tolist() == [-1]
    # LR {1, 2, 8} -> bands {1, 8, 9}: the link is the point 1, refs (2, 8); target 1
    refs, t, o = hy.reference_rule([[1, 2, 8]], [hy.LR], [[1, 8, 9]], walls)
    assert refs.tolist() == [[2, 8]] and t.tolist() == [1]


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    mod = discover()["qlink-invivo"]
    out = tmp_path_factory.mktemp("inv") / "s"
    assert mod.main(["--reduced", "--out", str(out)]) == 0
    return mod, out


def test_reduced_invivo_study(study):
    mod, out = study
    rows = list(csv.DictReader((out / "trials.csv").open()))
    cfg = json.loads((out / "config.json").read_text())
    assert set(mod.REASONS) == set(cfg["reasons"]) == set(cfg) - {"reasons", "precision"}
    assert len(rows) == cfg["trials"] * len(cfg["p_miss"])
    clean = [r for r in rows if float(r["p_miss"]) == 0.0]
    assert all(r["success"] == "1" and r["replans"] == "0" for r in clean)
    for r in rows:      # lengths within the Prop. 2 and Prop. 4 bounds, successes attributed
        n = max(int(r["n_entered"]), 1)
        if r["success"] == "1":
            assert float(r["length_m"]) <= cfg["map_range"] * n
            assert r["attributed"] == "1"
    w = np.load(out / "world.npz")
    assert w["walls"].shape == (2, 2, 2) and set(np.unique(w["element_kind"])) <= {0, 1}
    report = (out / "report.md").read_text()
    assert "72%" in report and "Table 4.2" in report and "| match |" in report
    assert (out / "invivo_world.png").exists()
    before = (out / "trials.csv").read_text()
    assert mod.main(["--reduced", "--out", str(out)]) == 0      # resume: same rows
    assert (out / "trials.csv").read_text() == before
    # the study protocol: claims from the stored results, the report rebuilt from them alone
    cs = mod.claims(out)
    assert cs and {c.verdict for c in cs} <= {"match", "mismatch", "not checked"}
    assert cs[0].name == "p_miss = 0: all succeed, 0 re-plans" and cs[0].verdict == "match"
    text = (out / "report.md").read_text()
    (out / "report.md").unlink()
    assert mod.main(["--report-only", "--out", str(out)]) == 0
    assert (out / "report.md").read_text() == text
    assert "![" in text and "*The synthetic world" in text      # a captioned figure


def test_misses_fail_trials_and_replanning_follows(study):
    """With every scan missing (p_miss = 1) and no re-planning, no trial with a transition to
    make can succeed, and each failure names a search reason; the same trials succeed
    without misses."""
    mod, _ = study
    cfg = mod.Config(**{**mod.REDUCED, "max_replans": 0})
    world = mod.build(cfg)
    ok = mod.run_setting(cfg, world, 0.0)
    bad = mod.run_setting(cfg, world, 1.0)
    assert all(r["success"] for r in ok)
    assert any(r["n_planned"] > 1 for r in bad)     # else the loop below checks nothing
    for r in bad:
        if r["n_planned"] > 1:
            assert not r["success"] and r["reason"] in ("link_not_found", "refs_not_found")
    with pytest.raises(ValueError, match="p_miss"):
        hy.drive(jax.random.split(jax.random.key(0), 1), world["hmap"], world["landmarks"],
                 world["walls"], np.zeros((1, 1), np.int32), [1], np.zeros((1, 2), np.int32),
                 np.zeros((1, 2)), hy.HybridParams(60.0, 0.7, 1.5), world["tables"])


def test_visible_references_match_a_per_element_oracle():
    """Re-planning sources: per element, the executive's entry rule on an exact range test
    (walls by their nearest point) — checked against a plain NumPy loop over elements."""
    rng = np.random.default_rng(3)
    walls = np.array([[[10.0, 0.0], [10.0, 8.0]], [[20.0, 0.0], [20.0, 8.0]]], np.float32)
    pts = rng.uniform(0, 30, (4, 2)).astype(np.float32)
    lm = np.concatenate([pts, walls.mean(1)])
    ids = np.array([[0, 1, 2], [0, 4, 5], [1, 2, 4], [2, 3, 5], [1, 4, 5]], np.int32)
    kind = np.array([hy.LR, hy.BANDS, hy.LR, hy.LR, hy.BANDS], np.int32)
    from pqrm_jax.qlink import MapElements

    hmap = hy.HybridMap(MapElements(jnp.asarray(ids), jnp.zeros((5, 6, 3)), 6), kind, (4, 5))

    def dist(pos, x):
        if x < 4:
            return np.linalg.norm(pts[x] - pos)
        a, b = walls[x - 4].astype(np.float64)
        t = np.clip(np.dot(pos - a, b - a) / np.dot(b - a, b - a), 0, 1)
        return np.linalg.norm(a + t * (b - a) - pos)

    seen = 0
    for pos in rng.uniform(-10, 40, (40, 2)).astype(np.float32):
        ok, refs = hy.visible_references(hmap, lm, walls, pos, 14.0)
        for e in range(5):
            vis = np.array([dist(pos, x) <= 14.0 for x in ids[e]])
            if kind[e] == hy.BANDS:
                want = ids[e, 1:] if vis[1] and vis[2] else None
            else:
                want = ids[e][vis][:2] if vis.sum() >= 2 else None
            assert bool(ok[e]) == (want is not None)
            if want is not None:
                assert refs[e].tolist() == want.tolist()
                seen += 1
    assert 0 < seen < 40 * 5        # both outcomes occur


def test_length_order_check_skips_bins_without_a_spread_of_their_own():
    """The mean-length-vs-|P| check orders only bins with at least ``min_bin_trials``
    successes (issue 24 item 4: a one-trial bin flipped it at p_miss 0.3): a one-trial bin
    above its neighbour is shown but not ordered; a decrease between two full bins is still a
    mismatch, and with ``min_bin_trials = 1`` the one-trial bin counts again."""
    mod = discover()["qlink-invivo"]

    def rows(lengths):   # {|P|: [lengths]} -> successful trial rows at p_miss 0
        return [dict(p_miss=0.0, success=1, replans=0, attributed=1, n_planned=k,
                     n_entered=k, length_m=x) for k, xs in lengths.items() for x in xs]

    def mono(cfg, lengths):
        (row,) = [c for c in mod.checks(cfg, rows(lengths)) if "non-decreasing" in c[0]]
        return row

    cfg = mod.Config(p_miss=(0.0,))
    assert cfg.min_bin_trials == 2
    row = mono(cfg, {2: [55.0], 3: [30.0, 50.0], 4: [45.0, 60.0]})
    assert row[3] and "(n = 1, not ordered)" in row[2]
    assert not mono(cfg, {2: [55.0, 56.0], 3: [30.0, 50.0]})[3]
    assert not mono(mod.Config(p_miss=(0.0,), min_bin_trials=1),
                    {2: [55.0], 3: [30.0, 50.0], 4: [45.0, 60.0]})[3]
