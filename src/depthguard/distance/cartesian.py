"""The Cartesian baseline of Flacco et al. 2014 §4 (SPEC §2.3, R8) — for comparison only.

Every surveyed pixel (region of surveillance R6, depth within ``dp ± rho``)
is back-projected to a world point and the control point takes the nearest
one (point-to-point distance, eq. 1): by brute force (vectorised numpy) or
with a k-d tree (``scipy.spatial.cKDTree``) built from the surveyed points
each cycle, as the paper's Cartesian approach does. It ignores pixel frusta
and the gray area (so it misses occluded obstacles) and ignores invalid
pixels; it is **not** safe and exists for the validation experiment and the
benchmarks.

The image is back-projected once per frame (:meth:`CartesianBaseline.set_depth`,
with :meth:`depthguard.camera.Camera.depth_to_points`); a query only slices
the window, selects and searches.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from depthguard.config import PRODUCT_RHO as RHO   # the product default, defined once in MonitorConfig
from depthguard.camera import Camera, check_depth_image
from depthguard.distance.api import DistanceResult, check_points, check_rho
from depthguard.distance.window import surveillance_window

__all__ = ["CartesianBaseline", "cartesian_distance"]

_SEARCH = ("kdtree", "brute")


class CartesianBaseline:
    """Point-cloud distance (R8) for one camera; ``set_depth`` per frame, ``query`` per cycle."""

    def __init__(self, cam: Camera):
        if not isinstance(cam, Camera):
            raise ValueError(f"cam must be a depthguard Camera (got {type(cam).__name__})")
        self.cam = cam
        self.xyz = np.zeros(cam.shape + (3,))            # (H, W, 3) world points
        self.z = np.full(cam.shape, np.inf)              # camera depth, inf = no point
        self.has_depth = False

    def set_depth(self, depth: np.ndarray, robot_depth: np.ndarray | None = None,
                  robot_offset: float = 0.03) -> None:
        """Back-project the valid, non-robot pixels of one frame (R8, R9)."""
        cam = self.cam
        d = np.asarray(check_depth_image(cam, depth), dtype=np.float64)
        with np.errstate(invalid="ignore"):
            valid = np.isfinite(d) & (d > 0) & (d >= cam.min_range) & (d <= cam.max_range)
            if robot_depth is not None:
                rd = np.asarray(check_depth_image(cam, robot_depth, name="robot_depth"), dtype=np.float64)
                valid &= ~((rd > 0) & (d >= rd - robot_offset))
        pts = cam.depth_to_points(d, frame="world", mask=valid)
        v, u = np.nonzero(valid)
        self.z.fill(np.inf)
        self.z[v, u] = d[v, u]
        self.xyz[v, u] = pts
        self.has_depth = True

    def query(self, points: np.ndarray, rho: float = RHO, search: str = "kdtree") -> DistanceResult:
        """Nearest back-projected point within ``rho`` of each control point.

        Returns a :class:`DistanceResult` (direction = unit vector to the
        nearest point, world frame; ``count`` = surveyed points).
        """
        if not self.has_depth:
            raise ValueError("CartesianBaseline.query: call set_depth(depth) first")
        if search not in _SEARCH:
            raise ValueError(f"search must be one of {_SEARCH} (got {search!r})")
        cam = self.cam
        P = check_points(points)
        r = check_rho(rho)
        n = len(P)
        dist = np.full(n, np.inf)
        direc = np.zeros((n, 3))
        count = np.zeros(n, dtype=np.int64)
        observed = cam.in_view(P)
        pcs = cam.world_to_camera(P)
        for i in range(n):
            xc, yc, dp = pcs[i]
            if not dp > 0:
                continue
            u0, u1, v0, v1 = surveillance_window(xc, yc, dp, r, cam.fx, cam.fy, cam.cx, cam.cy,
                                                 cam.min_range, cam.width, cam.height)
            if u0 > u1 or v0 > v1:
                continue
            zw = self.z[v0:v1 + 1, u0:u1 + 1]
            sel = (zw >= dp - r) & (zw <= dp + r)
            Q = self.xyz[v0:v1 + 1, u0:u1 + 1][sel]
            count[i] = len(Q)
            if len(Q) == 0:
                continue
            if search == "kdtree":
                tree = cKDTree(Q)
                D, j = tree.query(P[i], k=1, distance_upper_bound=r)
                if not np.isfinite(D):
                    continue
            else:
                d2 = np.einsum("ij,ij->i", Q - P[i], Q - P[i])
                j = int(np.argmin(d2))
                D = float(np.sqrt(d2[j]))
                if D > r:
                    continue
            dist[i] = D
            if D > 0:
                direc[i] = (Q[j] - P[i]) / D
        return DistanceResult(dist, direc, observed, count)


def cartesian_distance(cam: Camera, depth: np.ndarray, points: np.ndarray, rho: float = RHO,
                       search: str = "kdtree", robot_depth: np.ndarray | None = None) -> DistanceResult:
    """One-shot Cartesian baseline (R8); see :class:`CartesianBaseline`."""
    cb = CartesianBaseline(cam)
    cb.set_depth(depth, robot_depth)
    return cb.query(points, rho=rho, search=search)
