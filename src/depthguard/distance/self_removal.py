"""Self removal (SPEC §2.4, R9): the robot rendered into a camera at its current joints."""

from __future__ import annotations

import numpy as np

from depthguard.camera import Camera

__all__ = ["robot_depth"]


def robot_depth(cam: Camera, robot, q) -> np.ndarray:
    """(H, W) float32 metres: the robot's link meshes at joints ``q`` rendered into ``cam``
    (0 where the robot is not seen). Pass it as ``robot_depth`` to
    :func:`~depthguard.distance.depth_space_distance`.

    robot : a :class:`~depthguard.robot.RobotModel` (``.dof``, ``.link_meshes(q)``).
    q : (dof,) joint values, radians / metres.
    """
    from depthguard.render import render_depth

    qa = np.asarray(q, dtype=np.float64).reshape(-1)
    if qa.shape[0] != robot.dof:
        raise ValueError(f"robot has {robot.dof} joints, got {qa.shape[0]} joint values")
    if not np.all(np.isfinite(qa)):
        raise ValueError("joint values must be finite")
    return render_depth(cam, robot.link_meshes(qa))
