"""The named calculi of docs/decisions.md §2.1–2.2.

* ``edc`` — the 20-state Extended Double Cross, numbered as in docs/decisions.md §2.1
  (M Table I/II, MT App. C).
* ``edc_lune``, ``triple_cross``, ``double_cross``, ``single_cross``, ``lr`` — Padgett's
  reduced representations (P Fig. 2.2, decisions in docs/decisions.md §2.2), merges of ``edc``.
* ``quadrant`` — LR × front/behind the mid-perpendicular (P Fig. 4.5), a merge of ``edc``.
* ``dcc`` — boundary-inclusive Double Cross (MT ch. 1): 15 relations for A≠B, index
  3·(row−1)+col with rows front-of-B / on-perpendicular-through-B / between /
  on-perpendicular-through-A / behind-A and columns left / on-line / right, plus ``dou``
  (A=B≠C) and ``tri`` (A=B=C): 17.
* ``lr_full`` — Scivos–Nebel LR: l, r, f, b, i, s, e, dou, tri (a merge of ``dcc``).
"""

from __future__ import annotations

from .calculus import Calculus
from .poly import alpha, beta, rho

# M Table II, each "< 0" reading: C right of AB · in front of A · in front of B ·
# |AC| > |BC| · |AC| > |AB| · |BC| > |AB|
EDC_CONSTRAINTS = (-alpha, -beta, 1 - beta, 1 - 2 * beta, 1 - rho, 2 * beta - rho)

_EDC_LAYOUT = {
    # (band, inside A-circle, inside B-circle): (left, right)
    ("front", False, False): ("1", "2"),
    ("front", False, True): ("3", "4"),
    ("upper", False, False): ("5", "10"),
    ("upper", False, True): ("6", "9"),
    ("upper", True, True): ("7", "8"),
    ("lower", True, True): ("13", "14"),
    ("lower", True, False): ("12", "15"),
    ("lower", False, False): ("11", "16"),
    ("behind", True, False): ("17", "18"),
    ("behind", False, False): ("19", "20"),
}


def _band(s_neg_beta: int, s_one_minus_beta: int, s_one_minus_2beta: int) -> str | None:
    """Band along AB from the signs of −β, 1−β, 1−2β (None if contradictory)."""
    beta_pos = s_neg_beta < 0
    above_one = s_one_minus_beta < 0
    above_half = s_one_minus_2beta < 0
    if above_one:
        return "front" if above_half and beta_pos else None
    if above_half:
        return "upper" if beta_pos else None
    return "lower" if beta_pos else "behind"


def _edc_rule(s):
    band = _band(s[1], s[2], s[3])
    if band is None:
        return None
    pair = _EDC_LAYOUT.get((band, s[4] > 0, s[5] > 0))
    if pair is None:
        return None
    return pair[1] if s[0] < 0 else pair[0]


EDC_LUNE = ("7", "8", "13", "14")
EDC_LEFT = ("1", "3", "5", "6", "7", "11", "12", "13", "17", "19")
EDC_RIGHT = ("2", "4", "10", "9", "8", "16", "15", "14", "18", "20")
_EDC_BANDS = {
    "front": (("1", "3"), ("2", "4")),
    "upper": (("5", "6", "7"), ("8", "9", "10")),
    "lower": (("11", "12", "13"), ("14", "15", "16")),
    "behind": (("17", "19"), ("18", "20")),
}


def edc() -> Calculus:
    return Calculus.from_rule(
        "edc", EDC_CONSTRAINTS, _edc_rule, [str(i) for i in range(1, 21)],
        description="Extended Double Cross, 20 open states (M§II, docs/decisions.md §2.1)",
    )


def edc_lune(base: Calculus) -> Calculus:
    groups = {s: [s] for s in base.states if s not in EDC_LUNE}
    order = ["1", "2", "3", "4", "5", "6", "lune", "9", "10", "11", "12", "15", "16",
             "17", "18", "19", "20"]
    groups["lune"] = list(EDC_LUNE)
    return base.merge("edc_lune", {k: groups[k] for k in order},
                      "EDC with the lune {7,8,13,14} merged into one state (17)")


def triple_cross(base: Calculus) -> Calculus:
    groups = {}
    for i, band in enumerate(("front", "upper", "lower", "behind"), start=1):
        left, right = _EDC_BANDS[band]
        groups[f"l{i}"] = list(left)
        groups[f"r{i}"] = list(right)
    return base.merge("triple_cross", groups,
                      "left/right × four bands cut by the perpendiculars through A, mid, B (8)")


def double_cross(base: Calculus) -> Calculus:
    b = _EDC_BANDS
    groups = {
        "lf": list(b["front"][0]), "rf": list(b["front"][1]),
        "lm": list(b["upper"][0] + b["lower"][0]), "rm": list(b["upper"][1] + b["lower"][1]),
        "lb": list(b["behind"][0]), "rb": list(b["behind"][1]),
    }
    return base.merge("double_cross", groups,
                      "open Freksa Double Cross: left/right × front of B / between / behind A (6)")


def _half_split(base: Calculus, name: str, labels: tuple[str, str, str, str], desc: str):
    b = _EDC_BANDS
    front_l = list(b["front"][0] + b["upper"][0])
    front_r = list(b["front"][1] + b["upper"][1])
    back_l = list(b["lower"][0] + b["behind"][0])
    back_r = list(b["lower"][1] + b["behind"][1])
    return base.merge(name, dict(zip(labels, (front_l, front_r, back_l, back_r), strict=True)),
                      desc)


def single_cross(base: Calculus) -> Calculus:
    return _half_split(base, "single_cross", ("lf", "rf", "lb", "rb"),
                       "left/right × in front of / behind the mid-perpendicular (4)")


def quadrant(base: Calculus) -> Calculus:
    return _half_split(base, "quadrant", ("front-left", "front-right", "back-left", "back-right"),
                       "Q-Link quadrant QSR (P Fig. 4.5): LR × front/behind the mid-perpendicular")


def lr(base: Calculus) -> Calculus:
    return base.merge("lr", {"l": list(EDC_LEFT), "r": list(EDC_RIGHT)},
                      "left/right of AB (flip-flop, open) (2)")


_DCC_ROWS = ("front", "on_b", "between", "on_a", "behind")


def _dcc_rule(s):
    s_neg_alpha, s_neg_beta, s_one_minus_beta = s
    beta_sign = -s_neg_beta
    if s_one_minus_beta < 0:
        row = 1 if beta_sign > 0 else None
    elif s_one_minus_beta == 0:
        row = 2 if beta_sign > 0 else None
    elif beta_sign > 0:
        row = 3
    elif beta_sign == 0:
        row = 4
    else:
        row = 5
    if row is None:
        return None
    col = {1: 1, 0: 2, -1: 3}[s_neg_alpha]  # −α > 0: left
    return str(3 * (row - 1) + col)


def dcc() -> Calculus:
    return Calculus.from_rule(
        "dcc", (-alpha, -beta, 1 - beta), _dcc_rule,
        [str(i) for i in range(1, 16)] + ["dou", "tri"],
        boundary_inclusive=True, degenerate=("dou", "tri"),
        description="boundary-inclusive Double Cross (MT ch. 1): 15 relations + A=B≠C, A=B=C",
    )


def lr_full(base: Calculus) -> Calculus:
    groups = {
        "l": ["1", "4", "7", "10", "13"], "r": ["3", "6", "9", "12", "15"],
        "f": ["2"], "b": ["14"], "i": ["8"], "s": ["11"], "e": ["5"],
        "dou": ["dou"], "tri": ["tri"],
    }
    return base.merge("lr_full", groups,
                      "Scivos–Nebel LR with boundaries: l r f b i s e + dou, tri (9)")
