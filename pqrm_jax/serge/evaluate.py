"""Cross-validated evaluation of SR maps (Padgett §3.4.1–3.4.2).

Metrics on a held-out fold (P§3.4.1):

* data log likelihood ``log ψ3(B_test, L^B, R)``: the test beliefs (built from the test
  fold's data points exactly as the training beliefs are) scored on the training map;
* error rate ``|Z_test ∉ R^B_train| / |Z_test|``: the fraction of test data points that do not
  fall in the SR of their belief's training assignment.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import numpy as np

from .cells import Problem, initial_cells
from .grid import Grid
from .potential import SAL_FLOOR
from .scenes import Scene
from .search import SergeResult, serge


@dataclass
class Fold:
    """Training problem and test data of one cross-validation fold."""

    problem: Problem
    test_mass: np.ndarray            # (K, N) test-belief cell masses
    test_cells: list[np.ndarray]     # per belief: flat cell of every test data point


def make_fold(scene: Scene, grid: Grid, folds: list[np.ndarray], f: int,
              key: jax.Array) -> Fold:
    """Build the training problem (beliefs from folds ≠ f) and the test data of fold f."""
    k1, k2, k3, k4 = jax.random.split(key, 4)
    train = [np.flatnonzero(fd != f) for fd in folds]
    test = [np.flatnonzero(fd == f) for fd in folds]
    prob = initial_cells(k2, scene.beliefs(train, k1), grid, unseparated="attach")
    test_b = scene.beliefs(test, k3)
    test_mass = np.asarray(test_b.cell_masses(grid, key=k4), np.float64)
    cells = [np.asarray(grid.cell_of(np.asarray(p[t], np.float64)))
             for p, t in zip(scene.points, test, strict=True)]
    return Fold(prob, test_mass, cells)


def score(result: SergeResult, fold: Fold) -> dict:
    """Test log likelihood and error rate of a training map on a fold."""
    lab = result.cell_labels
    bl = result.belief_labels
    onehot = np.zeros((lab.size, result.n_regions))
    onehot[np.arange(lab.size), lab] = 1.0
    region_mass = fold.test_mass @ onehot                             # (K, |R|)
    sal = region_mass[np.arange(len(bl)), bl]
    ll = float(np.sum(np.log(np.maximum(sal, SAL_FLOOR))))
    wrong = sum(int(np.sum(lab[c] != bl[k])) for k, c in enumerate(fold.test_cells))
    total = sum(len(c) for c in fold.test_cells)
    return {"n_regions": result.n_regions, "log_likelihood": ll,
            "error_rate": wrong / max(total, 1), "train_log_psi3": result.log_psi3,
            "n_init": result.problem.n_init}


def evaluate(fold: Fold, mu: int, sigma: float, key: jax.Array, trials: int) -> dict:
    """Run SERGE on a fold's training problem and score it on the test fold."""
    mu = min(int(mu), fold.problem.k)
    res = serge(key, fold.problem, mu, sigma, trials=trials)
    return score(res, fold)
