"""Coverage trajectories for mapping runs: the lawnmower (boustrophedon) sweep (P §4.4.1).

Padgett maps the Q-Link world by "driving the environment" with a range-R sensor (P §4.4.1);
the path is not given. :func:`lawnmower` is the sweep used for the Q-Link study: lanes
``spacing`` apart (``y = spacing/2 + k·spacing``), driven alternately left→right and
right→left, with a pose every ``step`` metres along each lane.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["lawnmower"]


def lawnmower(size: Sequence[float] = (100.0, 100.0), spacing: float = 20.0,
              step: float = 1.0) -> jax.Array:
    """Poses ``[P, 3]`` (x, y, heading) of a boustrophedon sweep over ``[0, W] x [0, H]``.

    Args:
        size: (W, H) of the area in metres.
        spacing: distance between lanes (the first lane is at ``y = spacing / 2``).
        step: distance between consecutive poses along a lane.

    Returns:
        ``[P, 3]`` poses, lane after lane; headings 0 on even lanes, π on odd lanes.

    >>> p = lawnmower((4.0, 4.0), spacing=2.0, step=2.0)
    >>> p.shape, p[:, :2].tolist()
    ((6, 3), [[0.0, 1.0], [2.0, 1.0], [4.0, 1.0], [4.0, 3.0], [2.0, 3.0], [0.0, 3.0]])
    """
    w, h = (float(s) for s in size)
    for name, v in (("size", min(w, h)), ("spacing", spacing), ("step", step)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be positive and finite, got {v!r}")
    n_lanes = max(1, int(math.floor(h / spacing + 1e-9)))
    n_pts = int(math.floor(w / step + 1e-9)) + 1
    xs = np.arange(n_pts) * step
    poses = []
    for k in range(n_lanes):
        y = spacing / 2 + k * spacing
        x = xs if k % 2 == 0 else xs[::-1]
        th = 0.0 if k % 2 == 0 else math.pi
        poses.append(np.stack([x, np.full_like(x, y), np.full_like(x, th)], axis=1))
    return jnp.asarray(np.concatenate(poses), jnp.result_type(float))
