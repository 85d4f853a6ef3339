"""A depth grid map per camera, for a rig where no camera sees the whole workspace
(Flacco & De Luca 2015, §IX future work; SPEC §3, R10–R12).

Each control point is evaluated with a principal that sees it
(:meth:`MultiPrincipalDepthGrid.principal_for`); a point no camera sees is
``observed = False`` with ``distance = inf`` (R26: cannot judge).
"""

from __future__ import annotations

import numpy as np

from depthguard.config import PRODUCT_INVALID, PRODUCT_METHOD, PRODUCT_RHO, PRODUCT_ROBOT_IN_OTHERS, PRODUCT_ROBOT_OFFSET   # the product's defaults, defined once
from depthguard.distance.api import DistanceResult, check_points, check_rho
from depthguard.fusion.depth_grid import DepthGridMap

__all__ = ["MultiPrincipalDepthGrid"]


class MultiPrincipalDepthGrid:
    """A depth grid map per camera; each control point is evaluated with a
    principal that sees it (Flacco & De Luca 2015, §IX future work).

    For a point the principal is, among the cameras whose image and range hold
    it, one whose view holds the whole cube of side ``2 rho`` around it (so no
    obstacle within ``rho`` lies outside the principal's image), preferring
    the nearest such camera (finest cells); if none holds the whole cube, the
    camera holding most of the cube's 8 corners (ties: nearest). A point no
    camera sees is ``observed = False`` with ``distance = inf`` (cannot judge).
    """

    def __init__(self, cameras, d_min: float, d_max: float, delta_d: float, cache_dir=None,
                 *, cache: bool = True, quiet: bool = True):
        cams = list(cameras)
        self.cameras = cams
        self.maps = {c.id: DepthGridMap(cams, c.id, d_min, d_max, delta_d, cache_dir,
                                        cache=cache, quiet=quiet) for c in cams}

    @property
    def nbytes(self) -> int:
        return sum(m.nbytes for m in self.maps.values())

    def principal_for(self, points, rho: float = PRODUCT_RHO) -> np.ndarray:
        """(N,) index into ``cameras`` of each point's principal, -1 where no camera sees it."""
        p = check_points(points)
        r = check_rho(rho)
        corners = (p[:, None, :] + r * np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1)
                                                  for sz in (-1, 1)], float)[None]).reshape(-1, 3)
        best = np.full(len(p), -1)
        score = np.full(len(p), -np.inf)
        for k, cam in enumerate(self.cameras):
            sees = cam.in_view(p)
            n_in = cam.in_view(corners).reshape(-1, 8).sum(1)
            dp = cam.world_to_camera(p)[:, 2]
            s = n_in * 1e3 - dp
            take = sees & (s > score)
            best[take] = k
            score[take] = s[take]
        return best

    def distance(self, depths: dict, points, rho: float = PRODUCT_RHO, method: str = PRODUCT_METHOD,
                 robot_depths: dict | None = None, *, robot_capsules=None,
                 robot_offset: float = PRODUCT_ROBOT_OFFSET, invalid: str = PRODUCT_INVALID,
                 robot_in_others: str = PRODUCT_ROBOT_IN_OTHERS, silhouette_px: int = 0,
                 gap_px: int = 0) -> DistanceResult:
        """As :meth:`DepthGridMap.distance`, each point through its own principal."""
        p = check_points(points)
        n = len(p)
        dist = np.full(n, np.inf)
        direc = np.zeros((n, 3))
        obs = np.zeros(n, dtype=bool)
        count = np.zeros(n, dtype=np.int64)
        who = self.principal_for(p, rho)
        for k, cam in enumerate(self.cameras):
            sel = who == k
            if not sel.any():
                continue
            res = self.maps[cam.id].distance(depths, p[sel], rho, method, robot_depths,
                                             robot_capsules=robot_capsules, robot_offset=robot_offset,
                                             invalid=invalid, robot_in_others=robot_in_others,
                                             silhouette_px=silhouette_px, gap_px=gap_px)
            dist[sel], direc[sel], obs[sel], count[sel] = res.distance, res.direction, res.observed, res.count
        return DistanceResult(dist, direc, obs, count)
