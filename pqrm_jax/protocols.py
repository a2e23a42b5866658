"""The step convention of every recursive estimator: :class:`Estimator` and one generic :func:`run`.

Mappers, trackers and filters have one shape, in the manner of blackjax's
``kernel(rng_key, state) -> (state, info)`` and optax's ``(init, update)`` pairs:

* ``init(...) -> state`` builds the first state (its arguments depend on the estimator);
* ``update(state, key, *obs) -> (state, info)`` folds in one observation. The PRNG ``key`` is
  the argument right after the state and is accepted even where it is unused (the QRM map is
  deterministic); ``obs`` is one or more per-step arrays (or pytrees); ``info`` is a pytree of
  per-call diagnostics (counters, the localized pose, ...), never needed to continue.

So one scan runs any of them over a sequence: :func:`run` splits ``key`` into one subkey per
step and scans ``update``. The estimators of the library:

* :func:`pqrm_jax.pqrm.mapper`: ``update(state, key, positions, visible, sigma)``, info
  :class:`~pqrm_jax.pqrm.MapInfo` (this call's counters);
* :func:`pqrm_jax.qrm.mapper`: ``update(map, key, image)`` (key unused), info
  :class:`~pqrm_jax.qrm.UpdateReport`;
* :func:`pqrm_jax.hssh.lpm_tracker`: ``update(state, key, odom, scan)``, info
  :class:`~pqrm_jax.hssh.TrackStep`.

Planners and executives take the PRNG key *first* (``qlink.navigate(key, ...)``,
``hssh.localize(key, ...)``, ``sim.observe(key, ...)``), as gymnax's ``step(key, state, ...)``.

The calculus protocol :class:`~pqrm_jax.calculi.TernaryCalculus` is the other protocol of the
package (``pqrm_jax.calculi.protocol``).

>>> import jax
>>> from pqrm_jax import qrm, sim
>>> lm = sim.uniform_landmarks(jax.random.key(0), 6)
>>> poses = sim.random_imaging_points(jax.random.key(1), 3)
>>> images = jax.vmap(lambda p: sim.camera(p, lm, sim.SensorParams(max_range=1e6)))(poses)
>>> qm = qrm.mapper("edc", 6, n=6)
>>> isinstance(qm, Estimator)
True
>>> m, reports = run(qm, jax.random.key(2), qm.init(), images)
>>> reports.inconsistent.shape
(3,)
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import jax
import numpy as np

__all__ = ["Estimator", "run"]


@runtime_checkable
class Estimator(Protocol):
    """A recursive estimator (mapper, tracker or filter): ``init`` and ``update``.

    ``init(...) -> state``; ``update(state, key, *obs) -> (state, info)``, pure and traceable
    (it may check shapes on the host, never values of traced arrays).
    """

    def init(self, *args: Any) -> Any:
        """The first state."""
        ...

    def update(self, state: Any, key: jax.Array, *obs: Any) -> tuple[Any, Any]:
        """Fold in one observation: ``(state, info)``."""
        ...


def run(estimator: Estimator, key: jax.Array, state: Any, *observations: Any
        ) -> tuple[Any, Any]:
    """Run ``estimator.update`` over a sequence in one ``lax.scan``.

    Args:
        estimator: anything with ``update(state, key, *obs) -> (state, info)``
            (:class:`Estimator`).
        key: PRNG key; step ``t`` gets ``jax.random.split(key, T)[t]``.
        state: the state before the first step (``estimator.init(...)``).
        *observations: the per-step arguments of ``update`` after the key, each a pytree whose
            leaves have the leading axis ``T`` (e.g. ``images``; or ``positions [T, M, 2]``,
            ``visible [T, M]``, ``sigmas [T]``).

    Returns:
        ``(final state, info with leading axis T)``.

    Raises:
        ValueError: for no observations, a leaf without a leading axis, or observations of
            different lengths.

    ``run`` is not jitted itself (an estimator need not be hashable): call it inside your own
    ``jax.jit``, with the estimator closed over, to reuse one program across calls.
    """
    if not observations:
        raise ValueError("run needs at least one observation sequence")
    shapes = [np.shape(x) for x in jax.tree.leaves(observations)]
    if not shapes or any(len(sh) == 0 for sh in shapes):
        raise ValueError("every observation leaf needs a leading axis T (one entry per step)")
    lengths = {sh[0] for sh in shapes}
    if len(lengths) != 1:
        raise ValueError(f"observations must share one leading axis T, got lengths "
                         f"{sorted(lengths)}")
    keys = jax.random.split(key, lengths.pop())

    def step(s, xs):
        k, obs = xs
        return estimator.update(s, k, *obs)

    return jax.lax.scan(step, state, (keys, observations))
