"""Your own data in, maps out: loaders, ROS occupancy grids, map files, graph export.

The array contract (docs/io.md §contract) — what the loaders return and the mappers take:

========================  =====================================  ===========================
data                      array                                  consumer
========================  =====================================  ===========================
landmarks                 ``[N, 2]`` float, world frame          ``qlink.from_mapping_run``,
                          (any unit: every calculus is            ``qrm.true_map``, metrics,
                          scale-free)                            ``sim.camera``
robot poses               ``[P, 3]`` (x, y, heading rad, CCW     ``qlink.from_mapping_run``,
                          from +x)                               ``sim.camera``/``observe``
robot-frame positions     :class:`Observations`: ``[T, M, 2]``   ``pqrm.mapper(...).update``
                          + ``visible [T, M]``                   per step t
camera bearings           :class:`Bearings`: ``bearings``,        ``qrm.mapper(...).update``
                          ``range_rank``, ``visible`` ``[T, N]``  (``protocols.run`` over T)
occupancy grid            :class:`OccupancyGrid`: ``occupied``,  ``hssh.local_topology``
                          ``unknown`` ``[H, W]`` bool, row 0 =    (``grid``, ``unknown``)
                          top, ``cell_of(xy)``
========================  =====================================  ===========================

>>> import numpy as np, jax
>>> from pqrm_jax import io, pqrm
>>> obs = io.Observations(np.array([[[1., 0.], [0., 2.], [3., 3.]]], np.float32),
...                       np.ones((1, 3), bool))
>>> pq = pqrm.mapper(("edc",), num_landmarks=3, num_samples=16)
>>> s, info = pq.update(pq.init(), jax.random.key(0), obs.positions[0], obs.visible[0], 0.05)
>>> int(s.mapped.sum())
6
"""

from .arrays import (
    Bearings,
    DataError,
    Observations,
    load_bearings,
    load_landmarks,
    load_observations,
    load_poses,
)
from .maps import (
    MAP_FORMAT,
    MAP_FORMAT_VERSION,
    load_map,
    map_kind,
    networkx_graph,
    save_map,
    write_graphml,
)
from .rosmap import OccupancyGrid, load_ros_map, read_pgm, write_ros_map

__all__ = ["Bearings", "DataError", "Observations", "load_bearings", "load_landmarks",
           "load_observations", "load_poses", "MAP_FORMAT", "MAP_FORMAT_VERSION", "load_map",
           "map_kind", "save_map", "networkx_graph", "write_graphml", "OccupancyGrid",
           "load_ros_map", "read_pgm", "write_ros_map"]
