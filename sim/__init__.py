"""Deprecated alias of :mod:`pqrm_jax.sim`, kept for one release.

``import sim`` and ``import sim.world`` (and the other submodules) give the modules of
``pqrm_jax.sim``; new code should write ``from pqrm_jax import sim``.
"""

import sys
import warnings

import pqrm_jax.sim as _sim
from pqrm_jax.sim import *  # noqa: F403
from pqrm_jax.sim import __all__  # noqa: F401

warnings.warn(
    "the top-level 'sim' package is deprecated: use 'from pqrm_jax import sim'",
    DeprecationWarning,
    stacklevel=2,
)

for _name in ("world", "rover", "sensors", "trajectories", "lidar"):
    sys.modules[f"{__name__}.{_name}"] = getattr(_sim, _name)
