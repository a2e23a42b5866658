"""Qualitative belief-space planning with link actions, with and without compositions (Z ch. 4).

* :mod:`.models` — offline transition, association + measurement, link, global-scale and
  unary models sampled under uniform-within-state priors (Z eqs. 4.5, 4.11–4.17, 4.22–4.24),
  with per-cell counts, standard errors and a hashed cache (``sample_tables``: any subset).
* :mod:`.belief` — the qualitative belief pytree and its update ψ (Z eqs. 4.18–4.25);
  ``non_detection``, an EXTENSION beyond Z (off by default in execution).
* :mod:`.compose` — the augmented belief from minimal composition trees (Z eqs. 4.26–4.28),
  the Link-Graph (Thm 4.1).
* :mod:`.graph` — frame graph of a frozen belief: observability, hops, "plan exists".
* :mod:`.planner` — the level-synchronous expectimax belief tree, costs eq. 4.29 / 4.30;
  :mod:`.draws` — its random draws (``jax.random``'s threefry bits, unrolled).
* :mod:`.env` — random study environments, composable initial beliefs (Z §4.3), one or
  many environments at a time.
* :mod:`.execute` — receding-horizon execution in ``pqrm_jax.sim`` with PQRM map updates.

>>> from pqrm_jax import bsp
>>> bsp.ModelParams().n_f
5
"""

from .belief import (
    SCALE_MODELS,
    QBelief,
    belief_scales,
    check_distribution,
    in_belief,
    non_detection,
    scale_posteriors,
    update,
)
from .compose import augment, triplet_link_graph
from .env import MODES, Environment, check_environment, generate, initial_belief, initial_beliefs
from .execute import ExecParams, Lane, LaneState, Outcome, run_lane, run_lanes
from .graph import FrameGraph, frame_graph, plan_exists, plans_exist
from .models import ModelParams, Models, build_models, load_models, sample_tables, stderr
from .planner import Plan, PlannerParams, plan, trees_exist

__all__ = [
    "SCALE_MODELS", "QBelief", "belief_scales", "check_distribution", "in_belief",
    "non_detection", "scale_posteriors", "update", "augment",
    "triplet_link_graph", "Environment", "check_environment", "generate", "initial_belief",
    "initial_beliefs", "MODES",
    "ExecParams", "Lane", "LaneState", "Outcome", "run_lane", "run_lanes", "FrameGraph",
    "frame_graph", "plan_exists", "plans_exist", "ModelParams", "Models", "build_models",
    "load_models", "sample_tables", "stderr", "Plan", "PlannerParams", "plan", "trees_exist",
]
