"""``warm_up``: compile every kernel of the monitor's path before any clock of a run starts (R29)."""

from __future__ import annotations

import time

import numpy as np

__all__ = ["warm_up"]


def warm_up(rig, config=None) -> float:
    """Compile every kernel of the monitor's path (numba, ``cache=True``: from the disk cache
    after the first time) on a throwaway monitor fed with the known scene's expected depth, so
    that no clock of a run includes compilation. Returns the seconds it took."""
    from depthguard.filtering.expected import ExpectedDepth
    from depthguard.runtime.monitor import Monitor
    from depthguard.sources.frame import Frame

    t0 = time.perf_counter()
    q0 = np.asarray(rig.robot_q0, dtype=np.float64)
    with Monitor(rig, config) as mon:
        mon.push_joints(0.0, q0)
        mon.push_joints(0.001, q0)
        for cid in mon.camera_ids:
            cam = rig.camera(cid)
            mon.push_frame(Frame(cid, np.array(ExpectedDepth(cam, rig.robot, rig.static_meshes()).known(q0)),
                                 0.0005))
        mon.flush(timeout=600.0)
        mon.step(0.001)
        # the distance thread's band query and the cycles' bound of its answer (real_time())
        from depthguard.runtime.distances import DistanceSnapshot, bound_distances, moved_beyond

        cfg = mon.config
        grid = mon.fusion.front.grid
        P = mon._P.copy()
        res = grid.query(P, rho=cfg.query_rho + cfg.distance_margin, method=cfg.method, threads=1,
                         rho_core=cfg.query_rho)
        snap = DistanceSnapshot(P, res.distance.copy(), res.direction.copy(), res.observed.copy(), cfg.query_rho,
                                cfg.distance_margin, cfg.method, {}, {}, {}, grid.principal_view(), 0.0)
        m = len(P)
        bound_distances(snap, P, cfg.query_rho, np.empty(m), np.empty((m, 3)), np.empty(m, dtype=bool))
        moved_beyond(P, P.copy(), cfg.distance_margin)          # the worker's test of its newest answer
    from depthguard.runtime.voxel_input import VoxelObstacles
    units = VoxelObstacles()                      # the remote units' kernel
    units.push("warm-up", np.zeros((1, 3)), 0.05, 0.0)
    units.nearest(np.ones((2, 3)), 0.4, np.full(2, np.inf), np.zeros((2, 3)),
                  robot_capsules=rig.robot.collision_segments(q0, 0.05))
    return time.perf_counter() - t0
