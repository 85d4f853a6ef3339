"""One depth image from one camera at one time (the unit every source yields)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

__all__ = ["Frame", "RobotImage"]


class RobotImage(NamedTuple):
    """The robot alone as a simulated camera drew it into its frame (R9, R16, R30): what the
    monitor's camera worker would render to remove the robot, handed over with the frame.

    q : (dof,) float64 rad, the joints it was drawn at (the frame's capture joints).
    depth : (H, W) float32 m, 0 where no robot; the simulator's pooled array, written again only
        once nothing refers to it (:class:`~depthguard.frame_pool.BufferPool`): hold it, never write it.
    spans : (H, 2) int32, per row ``[a, b)`` outside which ``depth`` is 0.
    robot, camera : the robot model and the camera it was drawn with; the worker takes the image
        only for these very objects and these joints' bits, and only once its first images with
        the robot in view matched its own render bit for bit
        (:meth:`~depthguard.runtime.ingest.CameraWorker.handed_robot`)."""

    q: np.ndarray
    depth: np.ndarray
    spans: np.ndarray
    robot: object
    camera: object


@dataclass(frozen=True, eq=False)
class Frame:
    """A depth frame.

    camera_id : the rig camera that took it.
    depth : (H, W) float32 metres, 0 = no measurement. Handed over: the monitor keeps a float32
        C-contiguous array as it is, without a copy (its worker and the depth grid read it after
        ``push_frame`` returns), so a source must not write into it afterwards — every source of
        the package makes a new array per frame.
    stamp : capture time, seconds (scene time for simulated sources).
    labels : optional (H, W) int32 ground-truth owner of each pixel (simulation
        only; index into the scene's mesh names, -1 = nothing).
    robot_image : optional :class:`RobotImage` (simulation only): the robot layer the simulator
        drew, which spares the monitor's worker its own render of the robot (issue 29).
    """

    camera_id: str
    depth: np.ndarray
    stamp: float
    labels: np.ndarray | None = None
    robot_image: RobotImage | None = None
