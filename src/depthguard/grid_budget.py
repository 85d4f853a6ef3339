"""The depth grid's column size chosen from a budget, not from the camera (R10, issue 29).

The fusion's work per frame is the cells of the principal's grid within the query radius
of the robot's points: a point's region of surveillance is ``2 rho f / d`` pixels across at
the depth ``d`` it lies at (``f`` the principal's focal length in pixels), times
``2 rho / delta_d`` slices. So the same ``rho`` costs ~4x more columns on a camera twice as
close to the robot or with twice the resolution: with one column per 2x2 pixels, a UR3 1.5 m
from a 640x480 D435 (f = 385) needed 105 columns across a 0.4 m region, a UR5 under posts
109, the Kinects 2.8 m from flacco-cell's robot 83, fr3-cell's 424x240 cameras 38.

:func:`auto_principal_bin` picks ``principal_bin`` (pixels per column side) so that the
region around a point at the robot's depth is at most :data:`COLUMNS_ACROSS` columns
across: ``b = ceil(2 rho f / (d_robot COLUMNS_ACROSS))``, at least 1 (the paper's grid,
pixel per column) and at most 8, ``d_robot`` the median depth of the robot's capsules'
mid-points at the rig's joints in the principal camera and ``rho`` the grid's query
radius (``MonitorConfig.query_rho``). The cost of a build is then bounded by the budget
(``COLUMNS_ACROSS^2`` columns of ``2 rho / delta_d`` slices per point) whatever the
cameras; the price is the discretisation: a reported distance can come out smaller (never
larger) by at most a column's width at its depth, ``b d / f`` (1.5 cm for the UR3 above with
b = 4, instead of 0.8 cm with b = 2). A rig's own ``monitor: principal_bin`` wins.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["COLUMNS_ACROSS", "MAX_BIN", "auto_principal_bin", "robot_depth"]

#: the most grid columns across the region of surveillance of a point at the robot's depth
COLUMNS_ACROSS = 64
#: the coarsest column (pixels per side); MonitorConfig.principal_bin's upper bound
MAX_BIN = 8


def robot_depth(camera, robot, q) -> float:
    """Median depth (m, > 0) of the robot's collision capsules' mid-points at joints ``q``
    (dof,) rad in ``camera`` (its optical axis); ``nan`` when no mid-point lies in front of it."""
    data = robot.create_data()
    robot.forward(np.asarray(q, dtype=np.float64), data)
    mids = []
    for c in robot.capsules:
        T = data.link_poses[robot.chain.link_index(c.link)]
        mids.append(T[:3, :3] @ (0.5 * (np.asarray(c.a) + np.asarray(c.b))) + T[:3, 3])
    if not mids:
        return math.nan
    z = camera.world_to_camera(np.asarray(mids, dtype=np.float64))[:, 2]
    z = z[z > 0.0]
    return float(np.median(z)) if z.size else math.nan


def auto_principal_bin(camera, robot, q, rho: float, columns_across: int = COLUMNS_ACROSS) -> tuple[int, str]:
    """``(principal_bin, why)`` for a principal ``camera`` watching ``robot`` at joints ``q``
    with query radius ``rho`` m (module docstring); ``why`` one sentence with the figures.
    Without a robot point in front of the camera: ``(2, why)``, the product's earlier default."""
    if not (rho > 0 and columns_across >= 1):
        raise ValueError(f"rho must be > 0 m and columns_across >= 1 (got {rho!r}, {columns_across!r})")
    f = 0.5 * (float(camera.fx) + float(camera.fy))
    d = robot_depth(camera, robot, q)
    if not (math.isfinite(d) and d > 0.0):
        return 2, f"principal_bin 2: the robot is not in front of camera {camera.id}"
    across = 2.0 * rho * f / d
    b = min(MAX_BIN, max(1, math.ceil(across / columns_across - 1e-9)))
    return b, (f"principal_bin {b}: the robot {d:.2f} m from {camera.id} (f {f:.0f} px), a {2 * rho:.2f} m region "
               f"{across:.0f} px across -> {math.ceil(across / b - 1e-9)} columns (budget {columns_across}); "
               f"a column {b * d / f * 100:.1f} cm wide there")
