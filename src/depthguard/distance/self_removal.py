"""Self removal (SPEC §2.4, R9): the robot rendered into a camera at its current joints.

A pixel is the robot's where ``measured >= robot_depth - offset``: the ray is
free up to the robot's depth ``dr``, and what lies behind the robot is
unknown. :func:`~depthguard.distance.depth_space_distance` offers two ways
to use that (``robot_mode``):

- ``"drop"`` (default): the robot pixels carry no obstacle — the paper's
  treatment for one camera (§3.5). It is the only choice with which the
  robot's own control points (on or inside the links, i.e. at or behind
  ``dr``) do not read their own link as an obstacle at distance 0. The
  price: whatever hides right behind the robot is invisible to this
  camera; the several-camera depth grid (R12 step 4) closes that gap by
  confirming the cells behind the robot with the other cameras.
- ``"shadow"``: the robot pixel's frustum starts at ``dr`` (free up to the
  robot, unknown behind it, counted as obstacle, R1). Safe for points that
  are not on the robot (a tool, a free point), useless for the robot's own
  control points, which sit in their link's shadow.

A pixel where something is measured in front of the robot (a hand,
``measured < dr - offset``) stays an obstacle in both modes.
"""

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
