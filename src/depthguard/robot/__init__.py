"""Robots: kinematic chains from DH tables and URDF, FK, point Jacobians, control points,
link meshes and covering capsules (R9, R14, R16).

    robot = load_robot("lwr4" | "ur3" | "/path/robot.urdf", base=T)
    robot.link_poses(q); robot.control_point_jacobians(q); robot.link_meshes(q)
    data = robot.create_data(); robot.forward(q, data)      # the 500 Hz path
"""

from depthguard.robot.builtin import (LWR4_DH, UR3_DH, available_robots, load_robot, robot_from_urdf,
                                      ur3_dh, ur3_urdf_path)
from depthguard.robot.capsules import LinkCapsule, fit_capsule
from depthguard.robot.chain import Chain, LinkSpec
from depthguard.robot.dh import DHRow, dh_links, dh_transform
from depthguard.robot.model import ControlPoint, RobotData, RobotModel

__all__ = ["RobotModel", "RobotData", "ControlPoint", "LinkCapsule", "load_robot", "available_robots",
           "robot_from_urdf", "ur3_dh", "ur3_urdf_path", "LWR4_DH", "UR3_DH", "DHRow", "dh_links",
           "dh_transform", "Chain", "LinkSpec", "fit_capsule"]
