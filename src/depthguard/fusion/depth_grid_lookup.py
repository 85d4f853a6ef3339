"""Distances of points to the classified cells of the depth grid (SPEC §3, R7, R10–R12).

The eager path: :func:`~depthguard.fusion.depth_grid_eager.column_runs` gives
every principal column its obstacle cells as runs, :func:`tile_first_cells`
the first of them per tile of ``TILE`` x ``TILE`` pixels, and
:func:`grid_distances` looks up each point's nearest obstacle per pixel of its
region of surveillance by the R10 distance (the cell's nearest depth to the
point along the pixel's ray) and folds the pixels by the R7 method
(:func:`_fold_pixel`, :func:`_finish_point`, shared with the lazy path,
:func:`~depthguard.fusion.depth_grid_lazy_lookup.grid_distances_lazy`).

The plain-numpy twin is
:func:`~depthguard.fusion.depth_grid_ref.grid_distances_numpy`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from depthguard.distance.window import start_point, surveillance_window
from depthguard.fusion.depth_grid_kernels import D_ZERO, METHOD_MEAN, METHOD_MIN, RUN_END, TILE

__all__ = ["tile_first_cells", "grid_distances"]


@njit(cache=True, nogil=True)
def tile_first_cells(runs, nruns, out):
    """(ceil(H/TILE), ceil(W/TILE)) int32: per tile, the smallest first obstacle cell
    of its columns (``RUN_END`` if none); a point whose reach ends before it skips the tile."""
    H = nruns.shape[0]
    W = nruns.shape[1]
    for ty in range(out.shape[0]):
        for tx in range(out.shape[1]):
            m = RUN_END
            for v in range(ty * TILE, min(H, ty * TILE + TILE)):
                for u in range(tx * TILE, min(W, tx * TILE + TILE)):
                    if nruns[v, u] > 0 and runs[v, u, 0, 0] < m:
                        m = runs[v, u, 0, 0]
            out[ty, tx] = m



@njit(cache=True, inline="always")
def _fold_pixel(method, D2, vx, vy, vz, n, best2, dmin_found, bx, by, bz, sD, sx, sy, sz):
    """R7: fold one principal pixel's nearest obstacle (vector ``v``, squared length ``D2``)
    into a point's running reduction ``(n, best2, dmin_found, bx, by, bz, sD, sx, sy, sz)``
    (min: the nearest vector so far; mean / hybrid: count, sum of distances, smallest
    distance and sum of unit vectors) and return it. A distance at or below
    :data:`D_ZERO` is 0 and adds no direction."""
    D = math.sqrt(D2)
    if D <= D_ZERO:
        D = 0.0
        D2 = 0.0
    if method == METHOD_MIN:
        if D2 < best2 or n == 0:
            return 1, D2, D, vx, vy, vz, sD, sx, sy, sz
        return n, best2, dmin_found, bx, by, bz, sD, sx, sy, sz
    if D < dmin_found:
        dmin_found = D
    if D > 0.0:
        iD = 1.0 / D
        sx += vx * iD
        sy += vy * iD
        sz += vz * iD
    return n + 1, best2, dmin_found, bx, by, bz, sD + D, sx, sy, sz


@njit(cache=True, inline="always")
def _finish_point(i, method, n, dmin_found, bx, by, bz, sD, sx, sy, sz, Rp, out_distance, out_direction,
                  out_count):
    """R7: point ``i``'s distance, pixel count and world direction from its reduction
    (:func:`_fold_pixel`); nothing is written when no pixel had an obstacle within rho (the
    caller has set ``inf``, 0 and a zero direction)."""
    if n == 0:
        return
    out_count[i] = n
    if method == METHOD_MIN:
        out_distance[i] = dmin_found
        if not dmin_found > 0.0:
            return
        vx = bx / dmin_found
        vy = by / dmin_found
        vz = bz / dmin_found
    else:
        out_distance[i] = sD / n if method == METHOD_MEAN else dmin_found
        norm = math.sqrt(sx * sx + sy * sy + sz * sz)
        if norm == 0.0:
            return
        vx = sx / norm
        vy = sy / norm
        vz = sz / norm
    out_direction[i, 0] = Rp[0, 0] * vx + Rp[1, 0] * vy + Rp[2, 0] * vz
    out_direction[i, 1] = Rp[0, 1] * vx + Rp[1, 1] * vy + Rp[2, 1] * vz
    out_direction[i, 2] = Rp[0, 2] * vx + Rp[1, 2] * vy + Rp[2, 2] * vz


@njit(cache=True, inline="always")
def _f2(g, dmin, dd, dp, ax, ay, bx, by):
    d1 = dmin + g * dd
    od = min(max(dp, d1), d1 + dd)                             # R10 depth rule
    wx = ax * od - bx
    wy = ay * od - by
    wz = od - dp
    return wx * wx + wy * wy + wz * wz, wx, wy, wz


@njit(cache=True, nogil=True)
def _column(u, v, runs, nr, px, py, dp, lim2, fx, fy, cx, cy, dmin, dd):
    """Nearest obstacle cell of the principal pixel ``(u, v)``'s column (R10, R12)
    among its obstacle runs, by the R10 distance.

    Along the column the R10 distance is ``f(ôd)`` with ``f`` convex and
    ``ôd = clamp(dp, d1, d2)`` monotone in ``gd``, so ``f`` is unimodal in
    ``gd`` with its minimum at a cell ``g*`` next to ``r(dstar)``; the
    minimum over a run ``[a, b]`` is at ``clamp(g*, a, b)``.
    Returns ``(found, D^2, vx, vy, vz)`` (camera-frame vector, R5).
    """
    ox = min(max(px, u - 0.5), u + 0.5)                       # R3
    oy = min(max(py, v - 0.5), v + 0.5)
    ax = (ox - cx) / fx
    ay = (oy - cy) / fy
    bx = (px - cx) * dp / fx
    by = (py - cy) * dp / fy
    # f(ôd)^2 = (ax ôd - bx)^2 + (ay ôd - by)^2 + (ôd - dp)^2, minimised at dstar
    dstar = (ax * bx + ay * by + dp) / (ax * ax + ay * ay + 1.0)
    qx = ax * dstar - bx
    qy = ay * dstar - by
    qz = dstar - dp
    if qx * qx + qy * qy + qz * qz > lim2:
        return False, 0.0, 0.0, 0.0, 0.0
    rho = math.sqrt(lim2)
    g_lo = int(math.floor((dp - rho - dmin) / dd))
    g_hi = int(math.floor((dp + rho - dmin) / dd))
    gr = int(math.floor((dstar - dmin) / dd))
    best2 = lim2
    found = False
    bvx = 0.0
    bvy = 0.0
    bvz = 0.0
    for j in range(nr):
        a = max(runs[v, u, j, 0], g_lo)
        b = min(runs[v, u, j, 1], g_hi)
        if a > b:
            continue
        for c in range(3):
            g = min(max(gr - 1 + c, a), b)
            f2, wx, wy, wz = _f2(g, dmin, dd, dp, ax, ay, bx, by)
            if f2 < best2 or (not found and f2 == best2):
                best2 = f2
                found = True
                bvx = wx        # camera-frame vector (R5): ((ôx-cx)ôd - (px-cx)dp)/fx ...
                bvy = wy
                bvz = wz
    return found, best2, bvx, bvy, bvz


@njit(cache=True, parallel=True, nogil=True)
def grid_distances(pfree, runs, nruns, tile_first, Rp, tp, pint, dmin, dd,
                   points, n_points, rho, method,
                   out_distance, out_direction, out_count, out_observed):
    """On-line distances of ``n_points`` control points through the depth grid (R12).

    pfree : (H, W) principal free depths from :func:`frame_state`.
    runs, nruns : the frame's obstacle runs per principal column (:func:`column_runs`).
    tile_first : (ceil(H/TILE), ceil(W/TILE)) int32, the first obstacle cell of any
        column of each tile (:func:`tile_first_cells`), to skip tiles at once.
    Rp, tp : principal ``camera_from_world`` (3, 3), (3,).
    pint : (8,) principal fx, fy, cx, cy, W, H, min_range, max_range.
    dmin, dd : grid start depth, slice depth (m) (R10).
    points : (>= n_points, 3) world metres. method : METHOD_*.
    out_* : as in :func:`depthguard.distance.kernels.depth_space_distances`:
        distance (inf = nothing within rho), unit world direction, count of
        columns in S, observed (P inside the principal's image and range).

    Per principal pixel of the region of surveillance (R6) with free depth
    ``df``: case 1 ``df > dp + rho`` skips it; otherwise the nearest of the
    column's obstacle cells (:func:`column_runs`: the measured surface cell
    of cases 2/3 without confirmation, the gray cells of cases 3/4 that no
    other camera clears, never cells inside the padded robot) by the R10
    distance (:func:`_column`); then R7 over the pixels with ``D <= rho``.
    """
    H = pfree.shape[0]
    W = pfree.shape[1]
    fx = pint[0]
    fy = pint[1]
    cx = pint[2]
    cy = pint[3]
    rmin = pint[6]
    rmax = pint[7]
    for i in prange(n_points):
        ok, xc, yc, dp, px, py = start_point(i, points, Rp, tp, fx, fy, cx, cy, rmin, rmax, W, H,
                                             out_distance, out_direction, out_count, out_observed)
        if not ok:
            continue
        u0, u1, v0, v1 = surveillance_window(xc, yc, dp, rho, fx, fy, cx, cy, rmin, W, H)
        rho2 = rho * rho
        best2 = rho2
        n = 0
        sD = 0.0
        dmin_found = np.inf
        sx = 0.0
        sy = 0.0
        sz = 0.0
        bx = 0.0
        by = 0.0
        bz = 0.0
        g_lo = int(math.floor((dp - rho - dmin) / dd))
        g_hi = int(math.floor((dp + rho - dmin) / dd))
        for v in range(v0, v1 + 1):
            ty = v // TILE
            for tx in range(u0 // TILE, u1 // TILE + 1):
                if tile_first[ty, tx] > g_hi:                     # no cell of the tile in reach
                    continue
                for u in range(max(u0, tx * TILE), min(u1, tx * TILE + TILE - 1) + 1):
                    df = pfree[v, u]
                    if df > dp + rho:                              # case 1
                        continue
                    nr = nruns[v, u]
                    reach = False
                    for j in range(nr):
                        if runs[v, u, j, 0] <= g_hi and runs[v, u, j, 1] >= g_lo:
                            reach = True
                            break
                    if not reach:
                        continue
                    lim2 = best2 if method == METHOD_MIN else rho2
                    found, D2, vx, vy, vz = _column(u, v, runs, nr, px, py, dp, lim2, fx, fy, cx, cy,
                                                    dmin, dd)
                    if not found:
                        continue
                    n, best2, dmin_found, bx, by, bz, sD, sx, sy, sz = _fold_pixel(
                        method, D2, vx, vy, vz, n, best2, dmin_found, bx, by, bz, sD, sx, sy, sz)
        _finish_point(i, method, n, dmin_found, bx, by, bz, sD, sx, sy, sz, Rp, out_distance, out_direction,
                      out_count)
