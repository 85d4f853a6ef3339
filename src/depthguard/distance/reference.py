"""Plain-numpy twins of the distance kernels (SPEC §2), written like the equations.

Only the tests use them: they are the independent reading of R3–R7, R9 and
R28 that the numba kernels in :mod:`depthguard.distance.kernels` must match.
They scan every pixel of the window at once (no ring scan, no shrinking);
``window=False`` scans the whole image, which is how the tests show that the
region of surveillance (R6) loses nothing.
"""

from __future__ import annotations

import numpy as np

from depthguard.camera import Camera, RETURN_LIMIT_FACTOR
from depthguard.config import PRODUCT_INVALID, PRODUCT_ROBOT_OFFSET

__all__ = ["obstacle_start_depth_numpy", "surveillance_window_numpy", "pixel_vector_numpy",
           "depth_space_distance_numpy"]


def obstacle_start_depth_numpy(depth, robot_depth, min_range, max_range, invalid=PRODUCT_INVALID,
                               robot_mode="drop", robot_offset=PRODUCT_ROBOT_OFFSET, silhouette_px=0,
                               gap_px=0) -> np.ndarray:
    """(H, W) float64 start depth of each pixel's obstacle frustum; ``inf`` = no obstacle.
    ``invalid="unknown"``: a finite return beyond ``max_range`` starts at ``max_range``, an
    invalid pixel at ``min_range``, except: within ``silhouette_px`` pixels of the robot's
    silhouette it is a robot pixel at the smallest robot depth nearby (R32), else in a gap of
    at most ``gap_px`` invalid pixels it starts at the gap's nearer end."""
    m = np.asarray(depth, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(m) & (m > 0) & (m >= min_range) & (m <= max_range)
        beyond = np.isfinite(m) & (m > max_range) & (m <= RETURN_LIMIT_FACTOR * max_range)
    unknown = invalid == "unknown"
    d0 = np.where(valid, m, min_range if unknown else np.inf)
    if unknown:
        d0 = np.where(beyond, max_range, d0)
    none = ~valid & ~beyond                          # no return at all
    halo = np.zeros(m.shape, bool)
    if robot_depth is not None:
        dr = np.asarray(robot_depth, dtype=np.float64)
        robot = valid & (dr > 0) & (m >= dr - robot_offset)
        d0 = np.where(robot, np.inf if robot_mode == "drop" else dr, d0)
        if silhouette_px > 0 and unknown:
            from depthguard.distance.silhouette import dilate_robot_depth_numpy

            drd = dilate_robot_depth_numpy(dr, silhouette_px)
            halo = none & (drd > 0)
            d0 = np.where(halo, np.inf if robot_mode == "drop" else drd, d0)
    if gap_px > 0 and unknown:
        from depthguard.distance.gaps import gap_depth_numpy

        g = gap_depth_numpy(m, min_range, max_range, gap_px)
        d0 = np.where(none & ~halo & (g > 0), g, d0)
    return d0


def surveillance_window_numpy(pc, r, cam: Camera):
    """R6: bounding box of the projected corners of the cube ``pc ± r``, clipped to the image;
    the whole image when ``dp - r <= min_range``. Returns ``(u0, u1, v0, v1)`` inclusive."""
    W, H = cam.width, cam.height
    if pc[2] - r <= cam.min_range:
        return 0, W - 1, 0, H - 1
    s = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], dtype=np.float64)
    corners = pc + r * s
    px = corners[:, 0] * cam.fx / corners[:, 2] + cam.cx
    py = corners[:, 1] * cam.fy / corners[:, 2] + cam.cy
    u0 = max(int(np.floor(np.clip(px.min(), -1, W + 1) + 0.5)), 0)
    u1 = min(int(np.floor(np.clip(px.max(), -1, W + 1) + 0.5)), W - 1)
    v0 = max(int(np.floor(np.clip(py.min(), -1, H + 1) + 0.5)), 0)
    v1 = min(int(np.floor(np.clip(py.max(), -1, H + 1) + 0.5)), H - 1)
    return u0, u1, v0, v1


def pixel_vector_numpy(u, v, do, px, py, dp, cam: Camera) -> np.ndarray:
    """R3–R5 for arrays of pixels ``(u, v)`` with start depth ``do``; (..., 3) camera frame."""
    ox = np.clip(px, u - 0.5, u + 0.5)                                   # R3
    oy = np.clip(py, v - 0.5, v + 0.5)
    od = np.where(do > dp, do, dp)                                       # R4
    vx = ((ox - cam.cx) * od - (px - cam.cx) * dp) / cam.fx              # R5
    vy = ((oy - cam.cy) * od - (py - cam.cy) * dp) / cam.fy
    vz = od - dp
    return np.stack([vx, vy, vz], axis=-1)


def depth_space_distance_numpy(cam: Camera, d0: np.ndarray, points, rho: float, method: str,
                               window: bool = True):
    """(distance (N,), direction (N, 3) world, count (N,), observed (N,)) like the kernel."""
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    N = len(P)
    dist = np.full(N, np.inf)
    direc = np.zeros((N, 3))
    count = np.zeros(N, dtype=np.int64)
    observed = cam.in_view(P)
    pcs = cam.world_to_camera(P)
    for i, pc in enumerate(pcs):
        dp = pc[2]
        if not dp > 0:
            observed[i] = False
            continue
        px, py = pc[0] * cam.fx / dp + cam.cx, pc[1] * cam.fy / dp + cam.cy
        if window:
            u0, u1, v0, v1 = surveillance_window_numpy(pc, rho, cam)
        else:
            u0, u1, v0, v1 = 0, cam.width - 1, 0, cam.height - 1
        if u0 > u1 or v0 > v1:
            continue
        v, u = np.mgrid[v0:v1 + 1, u0:u1 + 1]
        do = d0[v0:v1 + 1, u0:u1 + 1]
        keep = do <= dp + rho
        u, v, do = u[keep].astype(np.float64), v[keep].astype(np.float64), do[keep]
        vec = pixel_vector_numpy(u, v, do, px, py, dp, cam)
        D = np.sqrt(np.sum(vec * vec, axis=1))
        S = D <= rho
        if not S.any():
            continue
        D, vec = D[S], vec[S]
        if method == "min":
            j = int(np.argmin(D))        # first in row-major order on ties
            dist[i], count[i] = D[j], 1
            V = vec[j] / D[j] if D[j] > 0 else np.zeros(3)
        else:
            count[i] = len(D)
            dist[i] = D.mean() if method == "mean" else D.min()
            pos = D > 0
            s = (vec[pos] / D[pos, None]).sum(axis=0)
            n = np.linalg.norm(s)
            V = s / n if n > 0 else np.zeros(3)
        direc[i] = cam.R.T @ V
    return dist, direc, count, observed
