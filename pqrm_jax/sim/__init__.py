"""``pqrm_jax.sim``: a JAX 2D kinematic rover simulator for Monte Carlo studies.

Decisions: docs/decisions.md §9; how it works: docs/sim.md.

Pure functions over explicit state pytrees and explicit PRNG keys, jitted at the public
boundary, ``vmap``-able over runs:

* :mod:`sim.world` -- landmark worlds (uniform, clustered, hallway, corridor grid).
* :mod:`sim.rover` -- unicycle rover: ``reset`` / ``step`` / ``rollout`` (``lax.scan``).
* :mod:`sim.sensors` -- relative-position sensor (range, field of view, occlusion, Gaussian
  noise) and camera measurement (bearings + range ordering).
* :mod:`sim.lidar` -- lidar ray casting into an occupancy grid.
* :mod:`sim.trajectories` -- perimeter loop, random imaging points, traverses, waypoint
  controller.
* :mod:`sim.coverage` -- the lawnmower mapping sweep (P §4.4.1).
* :mod:`sim.occlusion` -- partial disc occlusion and wall segments (P §4.4.1).
* :mod:`sim.corridors` -- corridor-network occupancy worlds (B ch. 6).

Example (Padgett's PQRM Monte Carlo setup, P §2.3.1)::

    import jax
    from pqrm_jax import sim
    lm = sim.uniform_landmarks(jax.random.key(0), 30)           # 100 m x 100 m square
    poses = sim.perimeter_loop()                                # a pose every 16 degrees
    keys = jax.random.split(jax.random.key(1), poses.shape[0])
    obs = jax.vmap(sim.observe, (0, 0, None, None))(keys, poses, lm,
                                                    sim.SensorParams(max_range=60.0, sigma=1.0))
"""

from pqrm_jax.sim import (
    corridors,
    coverage,
    lidar,
    occlusion,
    rover,
    sensors,
    trajectories,
    world,
)
from pqrm_jax.sim.corridors import (
    INTERSECTIONS,
    intersection_rectangles,
    plus_image,
    render_free_rectangles,
    room_doorway_rectangles,
)
from pqrm_jax.sim.coverage import lawnmower
from pqrm_jax.sim.lidar import LidarParams, LidarScan, lidar_scan, rasterize_discs
from pqrm_jax.sim.occlusion import (
    disc_visibility,
    local_target_visibility,
    occluder_table,
    segment_distance,
    segment_visibility,
    target_visibility,
)
from pqrm_jax.sim.rover import (
    RoverParams,
    RoverState,
    clip_control,
    reset,
    rollout,
    step,
    wrap_angle,
)
from pqrm_jax.sim.sensors import (
    CameraObservation,
    Observation,
    SensorParams,
    camera,
    observe,
    relative_positions,
    visibility,
)
from pqrm_jax.sim.trajectories import (
    ControllerGains,
    FollowResult,
    follow_waypoints,
    perimeter_loop,
    random_imaging_points,
    traverse,
    waypoint_controller,
)
from pqrm_jax.sim.world import (
    clustered_landmarks,
    corridor_grid_landmarks,
    hallway_landmarks,
    uniform_landmarks,
)

__all__ = [
    # modules
    "world", "rover", "sensors", "trajectories", "lidar", "coverage", "occlusion", "corridors",
    # worlds
    "uniform_landmarks", "clustered_landmarks", "hallway_landmarks", "corridor_grid_landmarks",
    # the rover
    "RoverParams", "RoverState", "reset", "step", "rollout", "clip_control", "wrap_angle",
    # sensors
    "SensorParams", "Observation", "CameraObservation", "observe", "camera",
    "relative_positions", "visibility",
    "LidarParams", "LidarScan", "lidar_scan", "rasterize_discs",
    # trajectories and control
    "perimeter_loop", "random_imaging_points", "traverse", "lawnmower",
    "ControllerGains", "FollowResult", "waypoint_controller", "follow_waypoints",
    # occlusion (P §4.4.1)
    "disc_visibility", "target_visibility", "occluder_table", "local_target_visibility",
    "segment_distance", "segment_visibility",
    # corridor worlds (B ch. 6)
    "INTERSECTIONS", "intersection_rectangles", "plus_image", "render_free_rectangles",
    "room_doorway_rectangles",
]
