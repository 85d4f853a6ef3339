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

import numpy as np

from depthguard.config import PRODUCT_RHO as RHO   # the product defaults, defined once in MonitorConfig
from depthguard.config import PRODUCT_INVALID, PRODUCT_METHOD, PRODUCT_ROBOT_IN_OTHERS
from depthguard.distance.api import DistanceResult, DistanceWorkspace

__all__ = ["OneCameraMap"]


class OneCameraMap:
    """The one-camera distance (R3-R9) with the depth grid's interface (see module docstring)."""

    def __init__(self, cam):
        self.camera = cam
        self.ws = DistanceWorkspace(cam, max_points=64, parallel=False)

    def set_frames(self, depths: dict, robot_depths: dict | None = None, *, robot_offset: float,
                   robot_capsules=None, invalid: str = PRODUCT_INVALID, robot_in_others: str = PRODUCT_ROBOT_IN_OTHERS,
                   changed=None, silhouette_px: int = 0, gap_px: int = 0) -> None:
        """Load the camera's frame (R9, R28, R32): ``robot_capsules`` and ``robot_in_others``
        have no meaning for one camera (the robot pixels are dropped)."""
        cid = self.camera.id
        rd = (robot_depths or {}).get(cid)
        self.ws.set_depth(depths[cid], robot_depth=rd, invalid=invalid, robot_mode="drop",
                          robot_offset=robot_offset, silhouette_px=silhouette_px, gap_px=gap_px)

    def query(self, points, rho: float = RHO, method: str = PRODUCT_METHOD, threads: int | None = None,
              rho_core: float | None = None) -> DistanceResult:
        """Distances of the points (N, 3) world m to what the camera sees (views of reused buffers).
        ``rho_core < rho``: the answer of radius ``rho_core`` where it finds something, else the
        nearest within ``rho`` (the min rule), as the depth grid's band
        (:meth:`depthguard.fusion.depth_grid.DepthGridMap.query`)."""
        if rho_core is None or rho_core >= rho:
            if rho_core is not None and rho_core > rho:
                raise ValueError(f"rho_core must be <= rho (got rho_core={rho_core!r}, rho={rho!r})")
            return self.ws.query(points, rho=rho, method=method)
        core = self.ws.query(points, rho=rho_core, method=method)
        D, V, obs, n = (np.array(a) for a in (core.distance, core.direction, core.observed, core.count))
        wide = self.ws.query(points, rho=rho, method="min")
        band = ~np.isfinite(D)
        D[band] = wide.distance[band]
        V[band] = wide.direction[band]
        n[band] = wide.count[band]
        return DistanceResult(D, V, obs, n)

    def principal_view(self) -> tuple:
        """``(R, t, pint, W, H)`` of the camera, as :meth:`DepthGridMap.principal_view`."""
        c = self.camera
        pint = np.array([c.fx, c.fy, c.cx, c.cy, float(c.width), float(c.height), c.min_range, c.max_range])
        return np.ascontiguousarray(c.R, dtype=np.float64), np.ascontiguousarray(c.t, dtype=np.float64), pint, \
            c.width, c.height
