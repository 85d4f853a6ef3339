"""The lazy depth grid's per-cycle query: distances from the cells classified this frame (R10, R12, R7).

Per point and principal pixel of its region of surveillance, the cheap tests first (R12 case 1,
the column's memoised free stretch, the pixel column's distance to the point), then the
column's nearest obstacle slice within ``rho`` from the memoised bits of
:mod:`depthguard.fusion.depth_grid_lazy` (classifying, on one thread, what is not yet), and the
R10 distance to it; the R7 fold over the pixels is :mod:`depthguard.fusion.depth_grid_lookup`'s.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from depthguard.distance.window import start_point, surveillance_window
from depthguard.fusion.depth_grid_capsules import _in_caps
from depthguard.fusion.depth_grid_kernels import KIND_SURFACE, METHOD_MIN, TILE
from depthguard.fusion.depth_grid_lazy import (_all_set, _bit, _col_setup, _ensure_one, _highest_bit, _lowest_bit,
                                               _needed_slices, _point_terms, _ray_x, _surface_first, pixel_clear,
                                               pixel_free_to)
from depthguard.fusion.depth_grid_lookup import _f2, _finish_point, _fold_pixel

__all__ = ["grid_distances_lazy"]


@njit(cache=True, inline="always")
def _obst_cell(u, v, g, gs, ncp, nd, obits, caps, ncaps, cap_lo, cap_hi, fx, fy, cx, cy, dmin, dd):
    """Is slice ``g`` of column ``(u, v)`` an obstacle: free before ``r(df)``; inside the
    grid its memoised bit; outside the grid an obstacle unless inside a padded capsule."""
    if g < gs:
        return False
    if g >= 0 and g < nd:
        return _bit(obits, v, u, g) != np.uint64(0)
    d1 = dmin + g * dd
    return not (ncaps > 0 and _in_caps(cap_lo, cap_hi, ncp, v, u, d1, d1 + dd, caps, ncaps, fx, fy, cx, cy, g))


@njit(cache=True, nogil=True)
def _scan_down(u, v, lo, hi, gs, ncp, nd, obits, caps, ncaps, cap_lo, cap_hi, fx, fy, cx, cy, dmin, dd):
    """Largest obstacle slice in ``lo..hi``, or ``lo - 1`` if none."""
    g = hi
    while g >= lo and g >= nd:
        if _obst_cell(u, v, g, gs, ncp, nd, obits, caps, ncaps, cap_lo, cap_hi, fx, fy, cx, cy, dmin, dd):
            return g
        g -= 1
    if g >= lo and g >= 0:
        b = _highest_bit(obits, v, u, max(lo, 0, gs), g)
        if b >= 0:
            return b
        g = -1
    while g >= lo:
        if _obst_cell(u, v, g, gs, ncp, nd, obits, caps, ncaps, cap_lo, cap_hi, fx, fy, cx, cy, dmin, dd):
            return g
        g -= 1
    return lo - 1


@njit(cache=True, nogil=True)
def _scan_up(u, v, lo, hi, gs, ncp, nd, obits, caps, ncaps, cap_lo, cap_hi, fx, fy, cx, cy, dmin, dd):
    """Smallest obstacle slice in ``lo..hi``, or ``hi + 1`` if none."""
    g = max(lo, gs)
    while g <= hi and g < 0:
        if _obst_cell(u, v, g, gs, ncp, nd, obits, caps, ncaps, cap_lo, cap_hi, fx, fy, cx, cy, dmin, dd):
            return g
        g += 1
    if g <= hi and g < nd:
        b = _lowest_bit(obits, v, u, g, min(hi, nd - 1))
        if b >= 0:
            return b
        g = nd
    while g <= hi:
        if _obst_cell(u, v, g, gs, ncp, nd, obits, caps, ncaps, cap_lo, cap_hi, fx, fy, cx, cy, dmin, dd):
            return g
        g += 1
    return hi + 1


@njit(cache=True, inline="always")
def _column_bits(u, v, gs, ncp, nd, obits, caps, ncaps, cap_lo, cap_hi, ax, ay, bx, by, dp, lim2,
                 fx, fy, cx, cy, dmin, dd, ga, gb):
    """:func:`~depthguard.fusion.depth_grid_lookup._column` over the memoised bits: the
    nearest obstacle cell of column ``(u, v)`` (ray terms ``ax, ay`` of :func:`_ray_x`,
    point terms ``bx, by`` of :func:`_point_terms`) among slices ``ga..gb`` by the R10
    distance. ``f`` is unimodal in the slice with its minimum at one of
    ``gr - 1 .. gr + 1`` (``gr = r(dstar)``): the candidates are those three and the
    nearest obstacle slice below / above them."""
    dstar = (ax * bx + ay * by + dp) / (ax * ax + ay * ay + 1.0)
    qx = ax * dstar - bx
    qy = ay * dstar - by
    qz = dstar - dp
    if qx * qx + qy * qy + qz * qz > lim2:
        return False, 0.0, 0.0, 0.0, 0.0
    gr = int(math.floor((dstar - dmin) / dd))
    best2 = lim2
    found = False
    bvx = 0.0
    bvy = 0.0
    bvz = 0.0
    a = max(ga, gs)
    for c in range(5):
        if c < 3:
            g = gr - 1 + c
            if g < a or g > gb:
                continue
            if not _obst_cell(u, v, g, gs, ncp, nd, obits, caps, ncaps, cap_lo, cap_hi, fx, fy, cx, cy, dmin, dd):
                continue
        elif c == 3 and a >= 0 and gb < nd:                    # all inside the grid: the bits
            g = _highest_bit(obits, v, u, a, min(gr - 2, gb))
            if g < 0:
                continue
        elif c == 4 and a >= 0 and gb < nd:
            g = _lowest_bit(obits, v, u, max(gr + 2, a), gb)
            if g < 0:
                continue
        elif c == 3:
            g = _scan_down(u, v, a, min(gr - 2, gb), gs, ncp, nd, obits, caps, ncaps, cap_lo, cap_hi,
                           fx, fy, cx, cy, dmin, dd)
            if g < a:
                continue
        else:
            g = _scan_up(u, v, max(gr + 2, a), gb, gs, ncp, nd, obits, caps, ncaps, cap_lo, cap_hi,
                         fx, fy, cx, cy, dmin, dd)
            if g > gb:
                continue
        f2, wx, wy, wz = _f2(g, dmin, dd, dp, ax, ay, bx, by)
        if f2 < best2 or (not found and f2 == best2):
            best2 = f2
            found = True
            bvx = wx
            bvy = wy
            bvz = wz
    return found, best2, bvx, bvy, bvz


@njit(cache=True, parallel=True)  # no nogil: numba's launcher takes the GIL to start each prange region
# (numba/np/ufunc/parallel.py): called without the GIL, a call with k regions took it back 1 + 2k times, not k
def grid_distances_lazy(model, fr, memo, points, n_points, rho, method, out, fill, axbuf, rho_core):
    """:func:`~depthguard.fusion.depth_grid_lookup.grid_distances` over the memoised cells: same cases, same R10 distance, same
    R7 reduction. ``fill`` False: :func:`ensure_cells` was called first with the same
    points. ``fill`` True: the cells are classified here as they are met (one pass; only
    on one thread — the points' windows overlap). axbuf : (>= n_points, W) float64
    workspace (each point's column terms ``ax``).

    ``rho_core <= rho`` (m): the mean / hybrid direction is that of the pixels within
    ``rho_core`` (R7 with radius ``rho_core``); the pixels between ``rho_core`` and ``rho``
    (the band) count for the distance only. A point with no pixel within ``rho_core`` but
    one in the band gets the band's nearest distance and its direction (the min rule). With
    ``rho_core == rho`` there is no band: the R7 answer of radius ``rho``. The band lets a
    result stay a bound for a point that moved less than ``rho - rho_core`` since
    (:mod:`depthguard.runtime.distances`).

    model, fr, memo : the grid's :class:`~depthguard.fusion.depth_grid_data.LazyModel`,
    :class:`~depthguard.fusion.depth_grid_data.LazyFrame`, :class:`~depthguard.fusion.depth_grid_data.LazyMemo`;
    points : (>= n_points, 3) float64 world m; rho, rho_core : m; method : METHOD_*;
    out : ``(distance (N,) m, direction (N, 3), count (N,) int64, observed (N,) bool)``, written."""
    pint, Rp, tp, dmin, dd, nd, koff, kdims, rays, origins, kint, nk = model
    pfree, pkind, tmin, kfree, kpmin, kpmax, caps, ncaps, cap_lo, cap_hi, cap_n, band = fr
    frame, stamp, obits, cbits, clear, free_to, kmemo = memo
    out_distance, out_direction, out_count, out_observed = out
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
        rc2 = rho_core * rho_core
        best2 = rho2
        n = 0
        nb = 0                                                     # pixels in the band only
        bb2 = rho2
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
        far = dp + rho
        bx_, by_ = _point_terms(px, py, dp, fx, fy, cx, cy)
        for u in range(u0, u1 + 1):
            axbuf[i, u] = _ray_x(px, u, cx, fx)
        for v in range(v0, v1 + 1):
            ty = v // TILE
            ay = _ray_x(py, v, cy, fy)
            for tx in range(u0 // TILE, u1 // TILE + 1):
                if tmin[ty, tx] > far:                            # every pixel in case 1
                    continue
                for u in range(max(u0, tx * TILE), min(u1, tx * TILE + TILE - 1) + 1):
                    if pixel_free_to(stamp, free_to, pfree, frame, v, u) > far:
                        continue                                   # case 1 / known free to r(dp + rho)
                    ax = axbuf[i, u]
                    ga, gb = _needed_slices(ax, ay, bx_, by_, dp, rho2, dmin, dd, g_lo, g_hi)
                    if ga > gb or (ga >= 0 and pixel_clear(stamp, clear, frame, v, u) >= gb):
                        continue                                   # too far from the point / known free
                    gs, ncp = _col_setup(u, v, pfree, dmin, dd, nd, cap_n, ncaps)
                    direct = pkind[v, u] == KIND_SURFACE
                    gn = min(gb, nd - 1)
                    if fill:
                        gn = _surface_first(direct, gs, ncp, ga, gn, ax, ay, bx_, by_, dp, dmin, dd)
                    if (fill and max(ga, gs, 0) <= gn
                            and (stamp[v, u] != frame or not _all_set(cbits, v, u, max(ga, gs, 0), gn))):
                        _ensure_one(u, v, max(ga, gs, 0), gn, gs, direct,
                                    ncp, pint, dmin, dd, kfree, kpmin, kpmax, koff, kdims, rays, origins, kint,
                                    nk, kmemo, caps, ncaps, cap_lo, cap_hi, band, frame, (stamp, clear, free_to, pfree),
                                    obits, cbits)
                    a = max(ga, gs)
                    if a > gb:
                        continue
                    lim2 = best2 if method == METHOD_MIN else rho2
                    found, D2, vx, vy, vz = _column_bits(u, v, gs, ncp, nd, obits, caps, ncaps, cap_lo,
                                                         cap_hi, ax, ay, bx_, by_, dp, lim2, fx, fy, cx, cy,
                                                         dmin, dd, ga, gb)
                    if not found:
                        continue
                    if method != METHOD_MIN and D2 > rc2:                # the band: its nearest only
                        if nb == 0 or D2 < bb2:
                            bb2 = D2
                            bx = vx
                            by = vy
                            bz = vz
                        nb += 1
                        continue
                    n, best2, dmin_found, bx, by, bz, sD, sx, sy, sz = _fold_pixel(
                        method, D2, vx, vy, vz, n, best2, dmin_found, bx, by, bz, sD, sx, sy, sz)
        if n == 0 and nb > 0:
            dmin_found = math.sqrt(bb2)
            _finish_point(i, METHOD_MIN, nb, dmin_found, bx, by, bz, sD, sx, sy, sz, Rp, out_distance,
                          out_direction, out_count)
        else:
            _finish_point(i, method, n, dmin_found, bx, by, bz, sD, sx, sy, sz, Rp, out_distance, out_direction,
                          out_count)
