"""Issue 26 items 1--2: T, L, straight corridor and dead end with their expected topology.

Before issue 26 (B's half-plane ``left_of`` and exits counted cell by cell): every noise-free
grid-aligned T and L with corridors of about 16 cells or more laid a gateway across the junction
(T side 63 / corridor 20: the stem's hypothesis crawled into the core, where the T's top wall
counted as a "side" obstacle; L side 63 / 21: the east gateway crossed the core centre), and a
noise-free 45° dead end whose corridor leaves the grid at a corner read ``enclosed``.
"""

from __future__ import annotations

import numpy as np
import pytest

from pqrm_jax.hssh import local_topology
from pqrm_jax.hssh.shapes import EXPECTED, SHAPES, ShapeCase, shape_cases, shape_check, shape_image


def _topology(case: ShapeCase, k: int = 0):
    occ, rc = shape_image(case)
    occ = np.ascontiguousarray(np.rot90(occ, k))
    side = occ.shape[0]
    rc = [(rc[0], rc[1]), (side - 1 - rc[1], rc[0]), (side - 1 - rc[0], side - 1 - rc[1]),
          (rc[1], side - 1 - rc[0])][k]
    return local_topology(occ, rc)


@pytest.mark.parametrize("kind,side,cells", [("T", 63, 20), ("T", 99, 33), ("L", 63, 21),
                                             ("L", 149, 50)])
@pytest.mark.parametrize("k", [0, 1, 2, 3])
def test_wide_grid_aligned_junctions(kind, side, cells, k):
    """Gateways at the arms' mouths, none across the junction: the right count and star, and
    every gateway centre at least 0.8 of its radius away from the junction point (the centre
    of the drawing; the arms' mouths are one radius away)."""
    lt = _topology(ShapeCase(kind, side, 0.0, 0.0, width=cells / side), k)
    assert shape_check(lt, kind) == ""
    centre = np.array([(side - 1) / 2, (side - 1) / 2])
    for g in lt.details:
        assert np.hypot(*(g.centre - centre)) >= 0.8 * g.radius


def test_dead_end_at_45_degrees_is_a_dead_end():
    lt = _topology(ShapeCase("dead_end", 63, 45.0, 0.0, width=20 / 63))
    assert lt.kind == "dead_end" and shape_check(lt, "dead_end") == ""


def test_expected_table_matches_the_noise_free_drawings():
    for kind in SHAPES:
        lt = _topology(ShapeCase(kind, 59, 0.0, 0.0))
        n, _, want = EXPECTED[kind]
        assert (len(lt.gateways), lt.kind) == (n, want)
        assert shape_check(lt, kind) == ""


def test_reduced_family_noise_free():
    """Random sizes, rotations, widths and robot offsets (noise-free): all correct. Sizes are
    drawn from three values to keep compiles few."""
    cases = shape_cases(4, seed=26, sizes=(49, 51), noise=(0.0, 0.0))
    bad = [(c, shape_check(_topology(c), c.kind)) for c in cases]
    assert [b for b in bad if b[1]] == []


def test_dead_ends_under_noise():
    """Dead ends at 5--10 % noise (16 seeded cases of the generator at side 63): all correct.
    On main 3 of them read as two-gateway places: noise cells on the border row split the
    corridor's opening, the skeleton forked around them into two exits, and the two exits
    counted as two ways out (docs/hssh.md, decision "Border stubs")."""
    cases = shape_cases(16, seed=26, sizes=(63, 63), noise=(0.05, 0.10), kinds=("dead_end",))
    bad = [(c, shape_check(_topology(c), c.kind)) for c in cases]
    assert [b for b in bad if b[1]] == []


def test_border_noise_fork_is_one_exit():
    """A noise cell on the border row inside a dead end's opening: one exit, one gateway."""
    case = ShapeCase("dead_end", 63, 0.0, 0.0, width=21 / 63, along=0.25)
    occ, rc = shape_image(case)
    cols = np.nonzero(~occ[-1])[0]
    occ[-1, cols[len(cols) // 2]] = True          # split the opening in two
    lt = local_topology(occ, rc)
    assert len(lt.skeleton.exits) == 1 and shape_check(lt, "dead_end") == ""


def test_shape_input_checks():
    with pytest.raises(ValueError, match="kind"):
        shape_image(ShapeCase("Y", 39, 0.0, 0.0))
    with pytest.raises(ValueError, match="robot offset"):
        shape_image(ShapeCase("T", 39, 0.0, 0.0, along=0.9))
    with pytest.raises(ValueError, match="noise"):
        shape_image(ShapeCase("T", 39, 0.0, 1.5))


@pytest.mark.slow
def test_family_with_noise():
    """The issue's family (sizes 39--299, rotations 0--45°, noise 0--10 %, robot off the
    centre): T, L and straight all correct; dead ends at least 80 % (the bound from before
    the border-stub rule; the default suite's test_dead_ends_under_noise checks the class)."""
    cases = shape_cases(10, seed=1)
    ok: dict = {}
    for c in cases:
        ok.setdefault(c.kind, []).append(shape_check(_topology(c), c.kind) == "")
    assert all(ok["T"]) and all(ok["L"]) and all(ok["straight"])
    assert np.mean(ok["dead_end"]) >= 0.8
