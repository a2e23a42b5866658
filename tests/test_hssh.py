"""HSSH local levels: cellular stages against oracles, gateways, stars, places (B ch. 5--6)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
from scipy import ndimage
from skimage.measure import euler_number
from skimage.morphology import skeletonize

from pqrm_jax import hssh
from pqrm_jax.sim import corridors

SIDE = 81


def _grid(kind, width=0.2, rot=0.0, side=SIDE):
    rects = corridors.intersection_rectangles(corridors.INTERSECTIONS[kind], width, rot)
    return np.asarray(corridors.render_free_rectangles(side, rects))


def _centre(side=SIDE):
    return (side // 2, side // 2)


# Beeson's example stars (B §5.1), first element pointing up
PLUS = [(0, 1, True), (1, 1, True), (0, -1, True), (1, -1, True)]
TEE = [(0, -1, False), (1, 1, True), (0, 1, True), (1, -1, True)]
ELL = [(0, 1, True), (1, 1, True), (0, -1, False), (1, -1, False)]
WYE = [(0, -1, False), (1, 1, True), (2, -1, False), (0, 1, True), (1, -1, False), (2, 1, True)]
STRAIGHT = [(0, 1, True), (0, -1, True)]


# ---------------------------------------------------------------- cellular stages vs oracles

def test_distance_transform_equals_scipy_exactly():
    rng = np.random.default_rng(0)
    occ = rng.random((4, 33, 47)) < np.array([0.02, 0.1, 0.3, 0.0005])[:, None, None]
    occ[3, 5, 7] = True
    d2 = np.asarray(hssh.squared_distance_transform(jnp.asarray(occ)))
    for k in range(4):
        ref = ndimage.distance_transform_edt(~occ[k]) ** 2
        np.testing.assert_array_equal(d2[k], np.rint(ref).astype(int))
    capped = np.asarray(hssh.squared_distance_transform(jnp.asarray(occ), cap=4))
    for k in range(4):
        ref = np.rint(ndimage.distance_transform_edt(~occ[k]) ** 2).astype(int)
        near = ref <= 16
        np.testing.assert_array_equal(capped[k][near], ref[near])
        assert np.all(capped[k][~near] > 16)


@pytest.mark.parametrize("cap", [0, 1, 15, 16, 17, 124, 125])
def test_capped_distance_transform_exact_below_cap(cap):
    # caps around the 16-offset chunks and the int16 / int32 switch (2 (cap + 2)**2 < 32000)
    rng = np.random.default_rng(cap)
    occ = rng.random((2, 270, 37)) < np.array([0.0004, 0.05])[:, None, None]
    occ[0, 0, 0] = True
    d2 = np.asarray(hssh.squared_distance_transform(jnp.asarray(occ), cap=cap))
    assert d2.dtype == np.int32
    for k in range(2):
        ref = np.rint(ndimage.distance_transform_edt(~occ[k]) ** 2).astype(int)
        near = ref <= cap * cap
        np.testing.assert_array_equal(d2[k][near], ref[near])
        assert np.all(d2[k][~near] > cap * cap)


def _zs_reference(img, protect=None, pad=False):
    """Straight transcription of Zhang & Suen (1984), parallel sub-iterations; ``pad`` is the
    value beyond the border, ``protect`` cells are never deleted."""
    x = np.pad(np.asarray(img, bool), 1, constant_values=pad).astype(int)
    keep = np.zeros(np.shape(img), bool) if protect is None else np.asarray(protect, bool)
    while True:
        changed = False
        for first in (True, False):
            p = {}
            h, w = x.shape
            c = x[1:-1, 1:-1]
            for name, (di, dj) in {"P2": (-1, 0), "P3": (-1, 1), "P4": (0, 1), "P5": (1, 1),
                                   "P6": (1, 0), "P7": (1, -1), "P8": (0, -1),
                                   "P9": (-1, -1)}.items():
                p[name] = x[1 + di:h - 1 + di, 1 + dj:w - 1 + dj]
            ring = [p[f"P{k}"] for k in range(2, 10)]
            b = sum(ring)
            a = sum(((ring[k] == 0) & (ring[(k + 1) % 8] == 1)).astype(int) for k in range(8))
            if first:
                c1 = p["P2"] * p["P4"] * p["P6"] == 0
                c2 = p["P4"] * p["P6"] * p["P8"] == 0
            else:
                c1 = p["P2"] * p["P4"] * p["P8"] == 0
                c2 = p["P2"] * p["P6"] * p["P8"] == 0
            delete = (c == 1) & (b >= 2) & (b <= 6) & (a == 1) & c1 & c2 & ~keep
            if delete.any():
                changed = True
                x[1:-1, 1:-1] = np.where(delete, 0, c)
        if not changed:
            return x[1:-1, 1:-1].astype(bool)


def test_zhang_suen_equals_paper_rules_and_tracks_scikit_image():
    rng = np.random.default_rng(1)
    imgs = []
    for t in range(6):
        img = rng.random((40, 52)) < 0.75
        imgs.append(ndimage.binary_opening(img) if t % 2 else img)
    imgs.append(np.asarray(corridors.plus_image(40, 20.0)) >= 128)
    stack = np.stack([np.pad(i, ((0, 40 - i.shape[0]), (0, 52 - i.shape[1]))) for i in imgs])
    ours = np.asarray(hssh.zhang_suen_thin(jnp.asarray(stack)))
    for k in range(len(stack)):
        np.testing.assert_array_equal(ours[k], _zs_reference(stack[k]))
        sk = skeletonize(stack[k], method="zhang")
        # scikit-image's hand-made table differs in a few patterns (see zhang_suen_lut):
        # same topology, nearly the same cells
        assert euler_number(ours[k], connectivity=2) == euler_number(sk, connectivity=2)
        near = ndimage.binary_dilation(sk, np.ones((3, 3), bool))
        assert (ours[k] & ~near).sum() <= 0.05 * max(ours[k].sum(), 1)


@pytest.mark.parametrize("width", [65] + [pytest.param(w, marks=pytest.mark.slow)
                                           for w in (7, 31, 32, 33, 64, 70)])
def test_bit_packed_thinning_equals_paper_rules_at_word_edges(width):
    # the thinning runs on uint32 words of 32 columns: widths around word boundaries, both
    # border values and protected cells against the NumPy transcription
    rng = np.random.default_rng(width)
    imgs = rng.random((4, 23, width)) < 0.7
    imgs[1] = ndimage.binary_opening(imgs[1])
    imgs[3] = True
    prot = rng.random(imgs.shape) < 0.02
    for pad in (False, True):
        ours = np.asarray(hssh.zhang_suen_thin(jnp.asarray(imgs), jnp.asarray(prot), pad=pad))
        for k in range(len(imgs)):
            np.testing.assert_array_equal(ours[k], _zs_reference(imgs[k], prot[k], pad))


def test_thinning_deletes_exactly_the_table_neighbourhoods():
    # every 3 x 3 neighbourhood with only its centre deletable: thinning removes the centre
    # iff one of the two sub-iterations of the paper's table deletes it (the bitwise rules
    # count B(P) and the 0->1 transitions differently from the table)
    codes = np.arange(256)
    img = np.ones((256, 3, 3), bool)
    order = [(0, 0), (0, 1), (0, 2), (1, 2), (2, 2), (2, 1), (2, 0), (1, 0)]  # NW clockwise
    for k, (r, c) in enumerate(order):
        img[:, r, c] = (codes >> k) & 1
    prot = np.ones_like(img)
    prot[:, 1, 1] = False
    lut = hssh.cellular.zhang_suen_lut()
    for pad in (False, True):
        out = np.asarray(hssh.zhang_suen_thin(jnp.asarray(img), jnp.asarray(prot), pad=pad))
        np.testing.assert_array_equal(~out[:, 1, 1], lut > 0)


def test_island_removal_follows_winding_runs_across_words():
    # a serpentine wall touching the border at one end only: the flood runs east and west
    # along 65-cell rows (three packed words) and back, as scipy's labelling says
    h, w = 17, 65  # the shapes of test_island_removal_matches_connected_components: one compile
    occ = np.zeros((3, h, w), bool)
    for r in range(2, h - 2, 2):
        occ[0, r, 2:w - 2] = True
        occ[0, r + 1, (w - 3) if (r // 2) % 2 else 2] = True
    occ[0, 2, 0:2] = True  # the only contact with the border
    occ[1] = occ[0]
    occ[1, 2, 0:2] = False  # same wall, no contact: an island
    occ[1, 5, 0] = True
    occ[2] = occ[0, :, ::-1]  # mirrored: enters from the east border, first run westward
    o, _ = hssh.remove_islands(jnp.asarray(occ), jnp.zeros_like(jnp.asarray(occ)))
    for k in range(3):
        lab, _ = ndimage.label(occ[k])
        edge = set(np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))) - {0}
        np.testing.assert_array_equal(np.asarray(o[k]), occ[k] & np.isin(lab, list(edge)))
    assert np.asarray(o[0]).sum() == occ[0].sum() and np.asarray(o[1]).sum() == 1


def test_protected_cells_survive_thinning():
    img = np.zeros((1, 9, 9), bool)
    img[0, 2:7, 2:7] = True
    prot = np.zeros_like(img)
    prot[0, 2, 2] = True
    out = np.asarray(hssh.zhang_suen_thin(jnp.asarray(img), jnp.asarray(prot)))
    assert out[0, 2, 2]
    assert ndimage.label(out[0], np.ones((3, 3)))[1] == 1


@pytest.mark.parametrize("shape", [(30, 30), (41, 32), (17, 65)])
def test_island_removal_matches_connected_components(shape):
    rng = np.random.default_rng(2)
    occ = rng.random((3, *shape)) < 0.45
    occ[2] = rng.random(shape) < 0.58  # near the percolation threshold: long winding floods
    unk = rng.random((3, *shape)) < 0.05
    o, u = hssh.remove_islands(jnp.asarray(occ), jnp.asarray(unk))
    for k in range(3):
        lab, _ = ndimage.label(occ[k] | unk[k])  # 4-connectivity
        edge = set(np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))) - {0}
        keep = np.isin(lab, list(edge))
        np.testing.assert_array_equal(np.asarray(o[k]), occ[k] & keep)
        np.testing.assert_array_equal(np.asarray(u[k]), unk[k] & keep)


# ---------------------------------------------------------------- local topology

@pytest.mark.parametrize("kind, expected, place", [
    ("plus", PLUS, "place"), ("T", TEE, "place"), ("L", ELL, "place"), ("Y", WYE, "place"),
    ("straight", STRAIGHT, "path"),
])
@pytest.mark.parametrize("rot", [0.0, 20.0])
def test_intersection_stars(kind, expected, place, rot):
    lt = hssh.local_topology(_grid(kind, rot=rot), _centre())
    assert lt.kind == place
    assert lt.num_paths == len({p for p, _, _ in expected})
    assert lt.gateways.shape == (len([e for e in expected if e[2]]), 2, 2)
    assert hssh.star_isomorphisms(lt.star, expected), (lt.star, expected)


def test_dead_end_and_room_behind_doorway():
    lt = hssh.local_topology(_grid("dead_end"), _centre())
    assert (lt.kind, lt.num_paths, len(lt.gateways)) == ("dead_end", 1, 1)
    assert sorted(lt.star) == [(0, -1, False), (0, 1, True)]
    room = np.asarray(corridors.render_free_rectangles(SIDE, corridors.room_doorway_rectangles()))
    at_door = hssh.local_topology(room, (40, 24))
    assert at_door.kind == "place" and len(at_door.gateways) == 3
    assert hssh.star_isomorphisms(at_door.star, TEE)       # the doorway is a side branch
    along = hssh.local_topology(room, (16, 24))
    assert along.kind == "path"


def test_two_plus_stars_have_exactly_four_isomorphisms():
    a = hssh.local_topology(_grid("plus"), _centre()).star
    b = hssh.local_topology(_grid("plus", rot=35.0), _centre()).star
    assert len(hssh.star_isomorphisms(a, b)) == 4
    assert len(hssh.star_isomorphisms(TEE, TEE)) == 1
    assert len(hssh.star_isomorphisms(ELL, ELL)) == 1
    assert hssh.star_isomorphisms(PLUS, TEE) == []


def test_path_continuity_pairs_opposite_gateways_only():
    lt = hssh.local_topology(_grid("plus"), _centre())
    by_side = {}
    for g, (ends, out) in enumerate(zip(lt.gateways, lt.outward, strict=True)):
        by_side[tuple(np.round(out).astype(int))] = (ends, out, g)
    up, down = by_side[(-1, 0)], by_side[(1, 0)]
    right = by_side[(0, 1)]
    assert hssh.path_continuity(up[0], up[1], down[0], down[1])
    assert not hssh.path_continuity(up[0], up[1], right[0], right[1])


def test_left_and_right_of_a_path():
    lt = hssh.local_topology(_grid("T"), _centre())
    entries = {(e.path, e.direction): e for e in lt.entries}
    # the traversable entry leaving through the left arm (gateway with outward col < 0)
    left_arm = next(e for e in lt.entries if e.traversable and lt.outward[e.gateway][1] < -0.9)
    rights = hssh.right_of(lt.star, left_arm.path, left_arm.direction)
    lefts = hssh.left_of(lt.star, left_arm.path, left_arm.direction)
    # leaving west, the stem (south) is on the left and nothing leads north
    stem = next(e for e in lt.entries if e.traversable and lt.outward[e.gateway][0] > 0.9)
    assert (stem.path, stem.direction) in lefts
    assert all(not entries[r].traversable for r in rights)


def test_batch_equals_single_and_rotation_free():
    grids = np.stack([_grid("T"), _grid("plus", rot=10.0)])
    batch = hssh.local_topology_batch(grids, [_centre()] * 2)
    for g, lt in zip(grids, batch, strict=True):
        one = hssh.local_topology(g, _centre())
        assert one.star == lt.star
        np.testing.assert_allclose(one.gateways, lt.gateways)
    turned = hssh.local_topology(np.rot90(grids[0]).copy(), _centre())
    assert hssh.star_isomorphisms(turned.star, TEE)


def test_constriction_baseline_and_bool_input():
    occ = _grid("plus") < 128
    lt = hssh.local_topology(occ, _centre(), method="constriction")
    assert len(lt.gateways) == 4 and hssh.star_isomorphisms(lt.star, PLUS)


@pytest.mark.slow
def test_robot_radius_closes_a_narrow_doorway():
    room = np.asarray(corridors.render_free_rectangles(
        SIDE, corridors.room_doorway_rectangles(door=0.05)))
    open_door = hssh.local_topology(room, (40, 24))
    closed = hssh.local_topology(room, (40, 24), robot_radius=3.0)
    assert len(open_door.gateways) == 3
    assert closed.kind == "path"


def test_unknown_cells_make_exits():
    grid = _grid("T")
    unknown = np.zeros(grid.shape, bool)
    unknown[:, :20] = True                          # the west arm is unseen
    lt = hssh.local_topology(grid, _centre(), unknown=unknown)
    assert len(lt.gateways) == 3
    assert any(e[1] < 22 for e in lt.skeleton.exits)


def test_enclosed_robot():
    grid = np.ones((SIDE, SIDE), bool)
    grid[20:60, 20:60] = False
    lt = hssh.local_topology(grid, (40, 40))
    assert lt.kind == "enclosed" and lt.gateways.shape == (0, 2, 2) and lt.num_paths == 0


# ---------------------------------------------------------------- bad input

def test_bad_input():
    g = _grid("plus")
    with pytest.raises(TypeError, match="uint8"):
        hssh.local_topology(g.astype(float), _centre())
    with pytest.raises(ValueError, match="2-D"):
        hssh.local_topology(g[None], _centre())
    with pytest.raises(ValueError, match="too small"):
        hssh.local_topology(g[:8, :8], (4, 4))
    with pytest.raises(ValueError, match="no free cell"):
        hssh.local_topology(np.zeros((20, 20), np.uint8), (3, 3))
    with pytest.raises(ValueError, match="featureless"):
        hssh.local_topology(np.full((20, 20), 255, np.uint8), (3, 3))
    with pytest.raises(ValueError, match="not in free space"):
        hssh.local_topology(g, (2, 2))
    with pytest.raises(ValueError, match="outside"):
        hssh.local_topology(g, (SIDE, 3))
    with pytest.raises(ValueError, match="robot_radius"):
        hssh.local_topology(g, _centre(), robot_radius=-1.0)
    with pytest.raises(ValueError, match="robot_radius"):
        hssh.local_topology(g, _centre(), robot_radius=float("nan"))
    with pytest.raises(ValueError, match="method"):
        hssh.local_topology(g, _centre(), method="voronoi")
    with pytest.raises(ValueError, match="one robot cell per grid"):
        hssh.local_topology_batch(np.stack([g, g]), [_centre()])


def test_resolution_bound_matches_worked_example():
    assert hssh.resolution_bound(300.0, 30.0) == (20.0, 17)
    assert hssh.resolution_bound(3.0, 0.3) == (0.2, 17)     # scale-free


@pytest.mark.slow
def test_corridor_network_places_from_lpm_windows():
    s, win = 801, 121
    img = np.asarray(corridors.render_free_rectangles(s, corridors.network_rectangles(),
                                                      supersample=2))
    expect = {"plus": PLUS, "L": ELL, "T": TEE, "plus_2": PLUS, "path": STRAIGHT,
              "dead_end": [(0, 1, True), (0, -1, False)]}
    crops = []
    for name in expect:
        x, y = corridors.NETWORK_PLACES[name]
        r, c = int((1 - y) * s), int(x * s)
        crops.append(img[r - win // 2:r + win // 2 + 1, c - win // 2:c + win // 2 + 1])
    tops = hssh.local_topology_batch(np.stack(crops), [(win // 2, win // 2)] * len(crops))
    for (name, star), lt in zip(expect.items(), tops, strict=True):
        assert hssh.star_isomorphisms(lt.star, star), (name, lt.star)
    assert [lt.kind for lt in tops] == ["place"] * 4 + ["path", "dead_end"]
