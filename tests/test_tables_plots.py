"""regions.png shows every relation its frame can show, with axis labels."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from pqrm_jax import calculi  # noqa: E402
from pqrm_jax.tables.plots import plot_regions, region_image  # noqa: E402


@pytest.mark.parametrize("name,shown,absent", [
    ("dcc", 15, {"dou", "tri"}), ("lr_full", 7, {"dou", "tri"}), ("edc", 20, set()),
    ("lr", 2, set())])
def test_every_relation_with_a_distinct_a_b_is_drawn_and_labelled(name, shown, absent):
    calc = calculi.get(name)
    img = region_image(calc)
    present = {calc.states[i] for i in np.unique(img[img >= 0])}
    assert len(present) == shown and set(calc.states) - present == absent
    fig, ax = plt.subplots()
    plot_regions(calc, ax)
    texts = {t.get_text() for t in ax.texts}
    assert present <= texts  # every present relation carries its label
    assert ax.get_xlabel().startswith("x of C") and ax.get_ylabel() == "y of C"
    assert f"{shown} of {calc.num_states} relations" in ax.get_title()
    for a in absent:
        assert a in ax.get_title()
    plt.close(fig)


def test_line_and_point_relations_are_drawn_visibly():
    calc = calculi.get("lr_full")
    fig, ax = plt.subplots()
    plot_regions(calc, ax)
    # the three line relations (b, i, f) are scatter collections, the two point relations
    # (s: C = A, e: C = B) markers at A and B
    assert len(ax.collections) == 3
    pts = {tuple(np.round(ln.get_xydata()[0], 6)) for ln in ax.lines if ln.get_marker() == "o"}
    assert pts == {(0.0, 0.0), (0.0, 1.0)}
    plt.close(fig)
