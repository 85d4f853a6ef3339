"""One camera in the runtime: the depth-space distance of Flacco 2014 behind the depth grid's
interface (R3-R9).

With a single camera nothing can confirm a cell, so the depth grid would count the robot's
own shadow (R9: unknown behind the robot) as an obstacle and the robot's control points,
which sit on or behind their links, would see themselves. Flacco 2014 (§3.5) drops the robot
pixels for one camera instead (``robot_mode="drop"``); :class:`OneCameraMap` gives the
monitor that method with the grid's ``set_frames`` / ``query`` calls, so the fusion worker
and ``step`` treat one camera and several alike.
"""

from __future__ import annotations

from depthguard.distance.api import DistanceResult, DistanceWorkspace

__all__ = ["OneCameraMap"]


class OneCameraMap:
    """The one-camera distance (R3-R9) with the depth grid's interface (see module docstring)."""

    def __init__(self, cam):
        self.camera = cam
        self.ws = DistanceWorkspace(cam, max_points=64, parallel=False)

    def set_frames(self, depths: dict, robot_depths: dict | None = None, *, robot_offset: float,
                   robot_capsules=None, invalid: str = "unknown", robot_in_others: str = "unknown",
                   changed=None, silhouette_px: int = 0, gap_px: int = 0) -> None:
        """Load the camera's frame (R9, R28, R32): ``robot_capsules`` and ``robot_in_others``
        have no meaning for one camera (the robot pixels are dropped)."""
        cid = self.camera.id
        rd = (robot_depths or {}).get(cid)
        self.ws.set_depth(depths[cid], robot_depth=rd, invalid=invalid, robot_mode="drop",
                          robot_offset=robot_offset, silhouette_px=silhouette_px, gap_px=gap_px)

    def query(self, points, rho: float = 0.4, method: str = "hybrid", threads: int | None = None) -> DistanceResult:
        """Distances of the points (N, 3) world m to what the camera sees (views of reused buffers)."""
        return self.ws.query(points, rho=rho, method=method)
