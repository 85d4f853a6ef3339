"""Numba kernels of the depth-space distance (SPEC §2, R3–R7, R9, R28).

Two passes, both allocation-free (every buffer is passed in):

1. :func:`obstacle_start_depth` — once per depth frame. Turns the measured
   image (and, optionally, the robot rendered into the same camera) into the
   *start depth* ``d0[v, u]`` of the obstacle frustum of each pixel: the
   frustum of pixel ``(u, v)`` is everything from ``d0`` to infinity inside
   the pixel's cone (surface plus gray area, R1); ``d0 = +inf`` means the
   pixel holds no obstacle at all.
2. :func:`depth_space_distances` — once per control-point cycle, in parallel
   over the control points (``prange``). For each point: equations (1)(2),
   the region of surveillance (R6, :func:`surveillance_window`), the
   point-to-frustum vector (R3–R5, :func:`pixel_vector`) and the aggregation
   (R7): ``min`` scans outward ring by ring from the point's pixel and
   shrinks the window to the current minimum; ``mean`` and ``hybrid`` scan
   the whole window.

The plain-numpy twins that read like the equations are in
:mod:`depthguard.distance.reference`; the tests compare the two at 1e-9.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from depthguard.camera import RETURN_LIMIT_FACTOR
from depthguard.distance.window import ball_row_span, start_point, surveillance_window

__all__ = [
    "METHOD_MIN", "METHOD_MEAN", "METHOD_HYBRID", "METHODS",
    "INVALID_UNKNOWN", "INVALID_FREE", "INVALID_POLICIES",
    "ROBOT_DROP", "ROBOT_SHADOW", "ROBOT_MODES",
    "obstacle_start_depth", "pixel_vector", "depth_space_distances",
    "depth_space_distances_serial", "PARALLEL_MIN_POINTS",
]

METHOD_MIN, METHOD_MEAN, METHOD_HYBRID = 0, 1, 2
METHODS = {"min": METHOD_MIN, "mean": METHOD_MEAN, "hybrid": METHOD_HYBRID}
INVALID_UNKNOWN, INVALID_FREE = 0, 1
INVALID_POLICIES = {"unknown": INVALID_UNKNOWN, "free": INVALID_FREE}
ROBOT_DROP, ROBOT_SHADOW = 0, 1
ROBOT_MODES = {"drop": ROBOT_DROP, "shadow": ROBOT_SHADOW}

# The shrunk window of the min scan is padded by this relative amount so that
# a pixel exactly at the current minimum is never pruned (ties stay exact).
_SHRINK_PAD = 1e-9

# Floating-point freedoms of the window scan: reassociation of the sums (the
# twins sum in another order anyway) and reciprocals; no contraction into FMA.
_FASTMATH = {"reassoc", "nsz", "arcp"}

#: ``obstacle_start_depth``'s "off" for its silhouette (per robot-depth dtype) and its gaps:
#: empty arrays of the dtypes the buffers have (writable, C-ordered: one signature with the buffers)
NO_SILHOUETTE = {np.dtype(np.float32): np.zeros((0, 0), np.float32),
                 np.dtype(np.float64): np.zeros((0, 0), np.float64)}
NO_GAP = np.zeros((0, 0), np.float64)

# Below this many control points the serial kernel is used.
PARALLEL_MIN_POINTS = 16


@njit(cache=True)
def obstacle_start_depth(depth, robot_depth, use_robot, min_range, max_range,
                         invalid_policy, robot_mode, robot_offset, out, silhouette, gap):
    """Start depth of each pixel's obstacle frustum (R1, R9, R28, R32).

    depth : (H, W) float32/float64 metres as measured; valid in ``[min_range, max_range]``;
        a finite ``m > max_range`` is a return beyond the rated range; 0, NaN, inf or
        ``< min_range`` is invalid (no return).
    robot_depth : (H, W) float robot rendered into this camera (0 = no robot);
        read only when ``use_robot``.
    out : (H, W) float64, written: ``do`` for a valid pixel; for a robot pixel (valid and
        ``measured >= robot_depth - offset``) ``+inf`` under ``ROBOT_DROP`` and
        ``robot_depth`` under ``ROBOT_SHADOW`` (free up to the robot, unknown behind it).
        Under ``INVALID_FREE`` every pixel that is not valid is ``+inf`` (beyond-range ones
        too, as before). Under ``INVALID_UNKNOWN``: a return beyond the rated range is
        ``max_range`` (free up to ``max_range``, unknown behind it); an invalid pixel is
        ``min_range`` (its whole ray is unknown from the near range on), unless one of the
        two rules below applies (the silhouette first).
    silhouette : (H, W) float, the robot depth dilated by
        ``silhouette_px`` pixels (:func:`~depthguard.distance.silhouette.dilate_robot_depth`;
        0 = no robot nearby). Under ``INVALID_UNKNOWN`` an
        *invalid* pixel with ``drd = silhouette > 0`` takes the robot pixel's
        meaning (R9, R32): ``+inf`` under ``ROBOT_DROP``, ``drd`` under
        ``ROBOT_SHADOW``. Valid and beyond-range pixels never read it. An empty array
        (:data:`NO_SILHOUETTE`, or a (0, 0) array of the robot depth's dtype) = off.
    gap : (H, W) float64, the small-gap depths
        (:func:`~depthguard.distance.gaps.gap_depth`, 0 = no gap). Under
        ``INVALID_UNKNOWN`` an invalid pixel outside the silhouette with ``g = gap > 0``
        starts at ``g`` (free up to the nearer end of its gap, unknown behind it). An empty
        array (:data:`NO_GAP`) = off.

    Off is an empty array, not ``None``: every combination of the two options is then one
    compiled signature per depth dtype (``None``, an omitted argument and an array were a
    signature each: 7 compilations of this kernel in the test suite, about 0.7 s each).
    """
    use_silhouette = silhouette.size > 0
    use_gap = gap.size > 0
    H, W = depth.shape
    inf = np.inf
    for v in range(H):        # serial: a light pass, not worth a parallel launch
        for u in range(W):
            m = np.float64(depth[v, u])
            valid = (m == m) and m > 0.0 and m >= min_range and m <= max_range
            if not valid:
                if invalid_policy != INVALID_UNKNOWN:
                    out[v, u] = inf
                    continue
                if m > max_range and m <= RETURN_LIMIT_FACTOR * max_range:   # a return beyond the rated range
                    out[v, u] = max_range
                    continue
                out[v, u] = min_range
                if use_silhouette:
                    drd = np.float64(silhouette[v, u])
                    if drd > 0.0:
                        out[v, u] = inf if robot_mode == ROBOT_DROP else drd
                        continue
                if use_gap:
                    g = np.float64(gap[v, u])
                    if g > 0.0:
                        out[v, u] = g
                continue
            if use_robot:
                dr = np.float64(robot_depth[v, u])
                if dr > 0.0 and m >= dr - robot_offset:
                    out[v, u] = inf if robot_mode == ROBOT_DROP else dr
                    continue
            out[v, u] = m


@njit(cache=True, inline="always")
def pixel_vector(u, v, do, px, py, dp, pxd, pyd, fx, fy, cx, cy):
    """Vector from ``P = (px, py, dp)`` to the nearest point of pixel ``(u, v)``'s
    frustum from ``do`` on (R3–R5), camera frame; ``pxd = (px - cx) dp``.
    """
    ox = min(max(px, u - 0.5), u + 0.5)                 # R3
    oy = min(max(py, v - 0.5), v + 0.5)
    od = do if do > dp else dp                           # R4
    vx = ((ox - cx) * od - pxd) / fx                     # R5
    vy = ((oy - cy) * od - pyd) / fy
    vz = od - dp
    return vx, vy, vz


@njit(cache=True)
def _min_scan(d0, px, py, dp, rho, xc, yc, fx, fy, cx, cy, min_range, u0, u1, v0, v1):
    """R7 minimum: scan rings of pixels outward from the point's pixel and
    shrink the window to the current minimum (exact: a pixel outside the
    window of radius ``Dmin`` has every frustum point farther than ``Dmin``).
    Ties are broken towards the smaller row-major pixel index.
    Returns ``(D, vx, vy, vz)``; ``D = inf`` when nothing lies within ``rho``.
    """
    H, W = d0.shape
    pxd = (px - cx) * dp
    pyd = (py - cy) * dp
    uc = int(math.floor(min(max(px, -1.0), W + 1.0) + 0.5))
    vc = int(math.floor(min(max(py, -1.0), H + 1.0) + 0.5))
    uc = min(max(uc, 0), W - 1)
    vc = min(max(vc, 0), H - 1)
    best = np.inf
    bidx = -1
    bx = 0.0
    by = 0.0
    bz = 0.0
    lim = rho                       # accept D <= lim
    dlim = dp + rho                 # skip pixels with do > dlim
    lim2 = rho * rho * (1.0 + 1e-12)
    k = 0
    while u0 <= u1 and v0 <= v1:
        kmax = max(max(uc - u0, u1 - uc), max(vc - v0, v1 - vc))
        if k > kmax:
            break
        improved = False
        # the ring at Chebyshev distance k: two rows and two columns
        for side in range(4):
            if side == 0:
                a0, a1, fixed, is_row = uc - k, uc + k, vc - k, True
            elif side == 1:
                if k == 0:
                    break
                a0, a1, fixed, is_row = uc - k, uc + k, vc + k, True
            elif side == 2:
                a0, a1, fixed, is_row = vc - k + 1, vc + k - 1, uc - k, False
            else:
                a0, a1, fixed, is_row = vc - k + 1, vc + k - 1, uc + k, False
            if is_row:
                if fixed < v0 or fixed > v1:
                    continue
                a0 = max(a0, u0)
                a1 = min(a1, u1)
            else:
                if fixed < u0 or fixed > u1:
                    continue
                a0 = max(a0, v0)
                a1 = min(a1, v1)
            for a in range(a0, a1 + 1):
                if is_row:
                    u = a
                    v = fixed
                else:
                    u = fixed
                    v = a
                do = d0[v, u]
                if do > dlim:
                    continue
                vx, vy, vz = pixel_vector(u, v, do, px, py, dp, pxd, pyd, fx, fy, cx, cy)
                D2 = vx * vx + vy * vy + vz * vz
                if D2 > lim2:
                    continue
                D = math.sqrt(D2)
                if D > lim:
                    continue
                idx = v * W + u
                if D < best or (D == best and idx < bidx):
                    best = D
                    bidx = idx
                    bx = vx
                    by = vy
                    bz = vz
                    improved = True
        if improved:
            r = best * (1.0 + _SHRINK_PAD) + 1e-12
            lim = best
            dlim = dp + r
            lim2 = r * r
            nu0, nu1, nv0, nv1 = surveillance_window(xc, yc, dp, r, fx, fy, cx, cy, min_range, W, H)
            u0 = max(u0, nu0)
            u1 = min(u1, nu1)
            v0 = max(v0, nv0)
            v1 = min(v1, nv1)
        k += 1
    return best, bx, by, bz


@njit(cache=True, fastmath=_FASTMATH)
def _window_scan(d0, px, py, dp, rho, xc, yc, fx, fy, cx, cy, u0, u1, v0, v1):
    """R7 mean and hybrid: every pixel of the window, row-major.

    Within each row only the columns whose pixel cones meet the ball of radius
    ``rho`` are visited (:func:`~depthguard.distance.window.ball_row_span`, a
    refinement of the R6 box that drops only pixels farther than ``rho``).
    Returns ``(n, sum D, Dmin, sum Vx, sum Vy, sum Vz)`` over the set ``S`` of
    pixels with ``D <= rho``; a pixel with ``D = 0`` (``P`` inside its
    frustum) counts in ``n`` and ``sum D`` but adds no direction.

    R5 is evaluated as ``vx = ((ôx - px) ôd + (px - cx)(ôd - dp)) / fx``, the
    same number without the cancellation (exactly 0 when ``P`` is inside).
    """
    dlim = dp + rho
    lim2 = rho * rho * (1.0 + 1e-12)
    n = 0
    sD = 0.0
    dmin = np.inf
    sx = 0.0
    sy = 0.0
    sz = 0.0
    pxc = px - cx
    pyc = py - cy
    ifx = 1.0 / fx
    ify = 1.0 / fy
    for v in range(v0, v1 + 1):
        a0, a1 = ball_row_span(v, xc, yc, dp, rho, fx, fy, cx, cy, u0, u1)
        oy = min(max(py, v - 0.5), v + 0.5)              # R3
        oyp = oy - py
        for u in range(a0, a1 + 1):
            do = d0[v, u]
            if do > dlim:
                continue
            ox = min(max(px, u - 0.5), u + 0.5)          # R3
            od = do if do > dp else dp                   # R4
            dd = od - dp
            vx = ((ox - px) * od + pxc * dd) * ifx       # R5
            vy = (oyp * od + pyc * dd) * ify
            D2 = vx * vx + vy * vy + dd * dd
            if D2 > lim2:
                continue
            D = math.sqrt(D2)
            if D > rho:
                continue
            n += 1
            sD += D
            if D < dmin:
                dmin = D
            if D > 0.0:
                iD = 1.0 / D
                sx += vx * iD
                sy += vy * iD
                sz += dd * iD
    return n, sD, dmin, sx, sy, sz


@njit(cache=True)
def _one_point(i, d0, R, t, fx, fy, cx, cy, min_range, max_range, points, rho, method,
               out_distance, out_direction, out_count, out_observed):
    """Control point ``i`` of :func:`depth_space_distances`."""
    H, W = d0.shape
    ok, xc, yc, dp, px, py = start_point(i, points, R, t, fx, fy, cx, cy, min_range, max_range, W, H,
                                         out_distance, out_direction, out_count, out_observed)
    if not ok:
        return
    u0, u1, v0, v1 = surveillance_window(xc, yc, dp, rho, fx, fy, cx, cy, min_range, W, H)
    if u0 > u1 or v0 > v1:
        return
    if method == METHOD_MIN:
        D, vx, vy, vz = _min_scan(d0, px, py, dp, rho, xc, yc, fx, fy, cx, cy, min_range,
                                  u0, u1, v0, v1)
        if D == np.inf:
            return
        out_distance[i] = D
        out_count[i] = 1
        if D == 0.0:
            return
        vx /= D
        vy /= D
        vz /= D
    else:
        n, sD, dmin, vx, vy, vz = _window_scan(d0, px, py, dp, rho, xc, yc, fx, fy, cx, cy,
                                                u0, u1, v0, v1)
        if n == 0:
            return
        out_count[i] = n
        out_distance[i] = sD / n if method == METHOD_MEAN else dmin
        norm = math.sqrt(vx * vx + vy * vy + vz * vz)
        if norm == 0.0:
            return
        vx /= norm
        vy /= norm
        vz /= norm
    # world direction R^T v
    out_direction[i, 0] = R[0, 0] * vx + R[1, 0] * vy + R[2, 0] * vz
    out_direction[i, 1] = R[0, 1] * vx + R[1, 1] * vy + R[2, 1] * vz
    out_direction[i, 2] = R[0, 2] * vx + R[1, 2] * vy + R[2, 2] * vz


@njit(cache=True, parallel=True)
def depth_space_distances(d0, R, t, fx, fy, cx, cy, min_range, max_range,
                          points, n_points, rho, method,
                          out_distance, out_direction, out_count, out_observed):
    """Distances from ``n_points`` world control points to one camera's obstacles,
    in parallel over the points.

    d0 : (H, W) float64 start depths from :func:`obstacle_start_depth`.
    R, t : camera_from_world rotation (3, 3) and translation (3,).
    points : (>= n_points, 3) float64 world metres.
    out_distance : (>= n,) float64 metres, ``inf`` where nothing within ``rho``.
    out_direction : (>= n, 3) float64 unit vectors in the world frame towards
        the obstacle; zero where the distance is ``inf`` or 0, or where the
        directions cancel.
    out_count : (>= n,) int64 pixels in the set ``S`` (D <= rho); for ``min``
        1 if a minimum was found, else 0.
    out_observed : (>= n,) bool: ``P`` projects inside the image with depth in
        ``[min_range, max_range]`` (R26).
    """
    for i in prange(n_points):
        _one_point(i, d0, R, t, fx, fy, cx, cy, min_range, max_range, points, rho, method,
                   out_distance, out_direction, out_count, out_observed)


@njit(cache=True)
def depth_space_distances_serial(d0, R, t, fx, fy, cx, cy, min_range, max_range,
                                 points, n_points, rho, method,
                                 out_distance, out_direction, out_count, out_observed):
    """:func:`depth_space_distances` on one thread: for a few points the launch of a
    parallel region costs more than it saves (and waits for a free core)."""
    for i in range(n_points):
        _one_point(i, d0, R, t, fx, fy, cx, cy, min_range, max_range, points, rho, method,
                   out_distance, out_direction, out_count, out_observed)
