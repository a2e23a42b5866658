"""Which issue-26 change moved the hssh-maps wall agreement (docs/hssh_global.md, "Results").

    .venv/bin/python scripts/hssh_cone_experiment.py            # both parts (~2 min on 2 cores)

Part 1, the reduced study's one simulator world, side by side: today's code; the old dead-end
reading (``SimParams.dead_end_wall`` = 1e9); noise-free odometry; B's 90° side-obstacle cone
(``hssh.local_topology(side_cone=90)``) with and without those. Part 2, the full preset's 8
simulator worlds with the 45° and the 90° cone. Prints the map agreement from odometry and after
re-localisation (the metrics the reduced test bounds)."""

from __future__ import annotations

from functools import partial

import numpy as np

from pqrm_jax import hssh
from pqrm_jax import hssh_global as hg
from pqrm_jax.studies import hssh_maps as S

SIM, TOPOLOGY = hg.SimParams, hssh.local_topology


def _run(c: dict, i: int, *, cone: float = 45.0, dead_end_wall=None, noise: bool = True) -> dict:
    def params(**kw):
        if not noise:
            kw["sigma_v"], kw["sigma_w"] = 0.0, 0.0
        p = SIM(**kw)
        return p if dead_end_wall is None else p._replace(dead_end_wall=dead_end_wall)

    hg.SimParams, hssh.local_topology = params, partial(TOPOLOGY, side_cone=cone)
    try:
        return S.run_sim_world(c, i)
    finally:
        hg.SimParams, hssh.local_topology = SIM, TOPOLOGY


def main() -> None:
    cfg, _ = S.configure(["--reduced"])
    c = cfg.to_json()
    print("part 1: the reduced study's simulator world (odometry / re-localised agreement)")
    for name, kw in [("45° cone (today)", {}), ("45°, old dead-end reading",
                                                {"dead_end_wall": 1e9}),
                     ("45°, noise-free odometry", {"noise": False}),
                     ("90° cone (B)", {"cone": 90.0}),
                     ("90°, old dead-end reading", {"cone": 90.0, "dead_end_wall": 1e9}),
                     ("90°, noise-free odometry", {"cone": 90.0, "noise": False})]:
        r = _run(c, 0, **kw)
        print(f"  {name:28s} lost {r.get('lost')}  {r.get('map_agree_odometry', np.nan):.3f} / "
              f"{r.get('map_agree_reloc', np.nan):.3f}", flush=True)
    full, _ = S.configure([])
    c = full.to_json()
    print("part 2: the full preset's simulator worlds (re-localised agreement per world)")
    for cone in (45.0, 90.0):
        rows = [_run(c, i, cone=cone) for i in range(full.sim_worlds)]
        a = np.array([r.get("map_agree_reloc", np.nan) for r in rows], float)
        print(f"  cone {cone:.0f}°: lost {sum(r.get('lost', 0) for r in rows)}; "
              + " ".join(f"{v:.3f}" for v in a) + f"; mean {np.nanmean(a):.3f}", flush=True)


if __name__ == "__main__":
    main()
