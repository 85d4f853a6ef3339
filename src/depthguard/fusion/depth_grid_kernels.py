"""Numba kernels of the depth grid map (SPEC §3, R10–R12).

The map is *compact* (R11 allows it): for every other camera ``k`` it keeps
the rays through the corners of the principal camera's pixels, expressed in
``k``'s frame (``rays[k, v, u] = M_k (((u - 1/2 - cx)/fx, (v - 1/2 - cy)/fy, 1)``,
``(H+1, W+1, 3)``) and the principal's optical centre in ``k``'s frame
(``origins[k]``). A cell ``(gx, gy, gd)`` spans the principal depths
``[d1, d2] = d_min + [gd, gd + 1] * delta_d``; its 8 corners in ``k`` are
``origins[k] + d * rays[k, gy + {0,1}, gx + {0,1}]`` for ``d`` in ``{d1, d2}``.
The cell is the convex hull of these corners, so its projection in ``k`` is
the convex hull of the 8 projected corners (the cell slides along the
epipolar line of its principal pixel as ``gd`` grows) and its depth range in
``k`` is ``[dstart_k, dend_k]`` = min / max of the corners' ``z_k``.

**Pixels of a cell** in camera ``k`` (:func:`cell_footprint`): every pixel of
the bounding box of the 8 projected corners. This is a superset of the
pixels the cell truly projects onto; more pixels can only make ``k`` confirm
more cells (see below), so the superset is on the safe side.

**Confirmation** (R12, the rule used here, stated once):
camera ``k`` *clears* a cell when it sees the whole cell (all 8 corners
inside its image and its range ``[min_range, max_range]``) and **every**
pixel of the cell's footprint has a free depth ``> dend_k``: then the whole
cell lies in space ``k`` has seen free. Otherwise ``k`` *confirms* the cell
(for ``k`` it is occupied, hidden, or partly out of view). A pixel's free
depth is its measured depth, the robot's rendered depth for a robot pixel
(R9: free up to the robot, unknown behind) and ``min_range`` for an invalid
pixel (R28: unknown from the near range on, so it never clears). A gray
cell of the principal is an obstacle unless some camera clears it, which is
the SPEC's "obstacle only if every camera that sees it confirms it"; a cell
that no other camera sees whole stays an obstacle.

This is stricter than the paper's test ``do_k < dstart_k`` at one pixel:
that test lets a cell through when ``k``'s measured surface lies *inside*
the cell (``dstart_k <= do_k <= dend_k``), or when only some of its pixels
see beyond it, and a real surface point can then be dropped. Requiring all
pixels and ``dend_k`` makes "not confirmed" mean "``k`` has seen all of it
free", so a cell holding a real obstacle point is never dropped.

The plain-numpy twins are in :mod:`depthguard.fusion.depth_grid_ref`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from depthguard.distance.window import surveillance_window

__all__ = [
    "D_ZERO", "KIND_SURFACE", "KIND_ROBOT", "KIND_UNKNOWN", "METHOD_MIN", "METHOD_MEAN", "METHOD_HYBRID",
    "frame_state", "build_min_pyramid", "capsule_intervals", "MAX_CAPS_PER_PIXEL", "cell_footprint", "cell_cleared", "cell_in_capsules",
    "grid_distances",
]

KIND_SURFACE, KIND_ROBOT, KIND_UNKNOWN = 0, 1, 2
METHOD_MIN, METHOD_MEAN, METHOD_HYBRID = 0, 1, 2

# intrinsics row of a camera in ``kint``: fx, fy, cx, cy, W, H, min_range, max_range
_FX, _FY, _CX, _CY, _W, _H, _RMIN, _RMAX = range(8)

# A distance at or below this (metres) is reported as 0 and carries no
# direction: the vector is rounding noise (P inside the cell's frustum).
D_ZERO = 1e-9


@njit(cache=True, parallel=True)
def frame_state(depth, robot_depth, use_robot, min_range, max_range, robot_offset,
                invalid_free, robot_free, out_free, out_kind):
    """Per-pixel state of one depth frame (R1, R9, R28).

    depth : (H, W) float metres; invalid = 0, NaN or outside ``[min_range, max_range]``.
    robot_depth : (H, W) float, the robot rendered into this camera (0 = none);
        read only when ``use_robot``. A valid pixel is the robot's where
        ``measured >= robot_depth - robot_offset`` (R9).
    invalid_free : the R28 policy. False (safe default): an invalid pixel's
        ray is unknown from ``min_range`` on; True: it is free (nothing within
        the sensor's range, e.g. a simulated cell without walls).
    robot_free : False (R9): a robot pixel is free up to ``dr``, unknown behind;
        True (the paper's removal, for the non-principal cameras only): the
        pixel is no evidence of anything, its whole ray counts as free.
    out_free : (>= H, >= W) float64 written: the depth up to which the ray is
        free — ``do`` (surface), ``dr`` or ``+inf`` (robot), ``min_range`` or
        ``+inf`` (invalid).
    out_kind : (>= H, >= W) int8 written: ``KIND_SURFACE`` (a measured surface,
        an obstacle without confirmation), ``KIND_ROBOT`` or ``KIND_UNKNOWN``.
    """
    H, W = depth.shape
    for v in prange(H):
        for u in range(W):
            m = np.float64(depth[v, u])
            if not ((m == m) and m > 0.0 and m >= min_range and m <= max_range):
                out_free[v, u] = np.inf if invalid_free else min_range
                out_kind[v, u] = KIND_UNKNOWN
                continue
            if use_robot:
                dr = np.float64(robot_depth[v, u])
                if dr > 0.0 and m >= dr - robot_offset:
                    out_free[v, u] = np.inf if robot_free else dr
                    out_kind[v, u] = KIND_ROBOT
                    continue
            out_free[v, u] = m
            out_kind[v, u] = KIND_SURFACE


@njit(cache=True)
def build_min_pyramid(free, H, W, pyr, offsets, dims):
    """Min-pyramid of a free-depth image: level ``l`` holds the minimum over
    aligned ``2^l x 2^l`` blocks (level 0 is the image). ``pyr`` is a flat
    float64 buffer; level ``l`` (``dims[l] = (h_l, w_l)``) starts at
    ``offsets[l]``, row-major. Used only to skip work: a box whose minimum
    free depth exceeds a depth is free up to that depth in every pixel."""
    nl = offsets.shape[0]
    o = offsets[0]
    for v in range(H):
        for u in range(W):
            pyr[o + v * W + u] = free[v, u]
    for lv in range(1, nl):
        hp = dims[lv - 1, 0]
        wp = dims[lv - 1, 1]
        hl = dims[lv, 0]
        wl = dims[lv, 1]
        op = offsets[lv - 1]
        ol = offsets[lv]
        for v in range(hl):
            for u in range(wl):
                m = np.inf
                for dv in range(2):
                    vv = 2 * v + dv
                    if vv >= hp:
                        continue
                    for du in range(2):
                        uu = 2 * u + du
                        if uu >= wp:
                            continue
                        x = pyr[op + vv * wp + uu]
                        if x < m:
                            m = x
                pyr[ol + v * wl + u] = m


@njit(cache=True, inline="always")
def _box_min(pyr, offsets, dims, u0, u1, v0, v1):
    """Lower bound of the free depth over pixels ``u0..u1 x v0..v1`` (inclusive):
    the minimum over the pyramid blocks covering the box (at most 2 x 2)."""
    nl = offsets.shape[0]
    lv = 0
    while lv < nl - 1 and ((u1 >> lv) - (u0 >> lv) > 1 or (v1 >> lv) - (v0 >> lv) > 1):
        lv += 1
    a0 = u0 >> lv
    a1 = u1 >> lv
    b0 = v0 >> lv
    b1 = v1 >> lv
    wl = dims[lv, 1]
    ol = offsets[lv]
    m = np.inf
    for b in range(b0, b1 + 1):
        for a in range(a0, a1 + 1):
            x = pyr[ol + b * wl + a]
            if x < m:
                m = x
    return m


@njit(cache=True)
def cell_footprint(rays, origins, kint, k, gx, gy, d1, d2):
    """Footprint of the principal-grid frustum piece ``pixel (gx, gy) x [d1, d2]``
    in camera ``k`` (R11).

    Returns ``(seen, u0, u1, v0, v1, dstart, dend)``: ``seen`` is True when
    all 8 corners project inside ``k``'s image with ``z_k`` in
    ``[min_range, max_range]``; ``u0..u1 x v0..v1`` (inclusive) is the
    bounding box of the pixels the projected corners fall in; ``dstart`` /
    ``dend`` are the smallest / largest ``z_k`` of the piece (metres).
    With ``d1, d2`` a cell's depths this is the cell; with a longer range it
    is a box of consecutive cells of the column.
    """
    fx = kint[k, _FX]
    fy = kint[k, _FY]
    cx = kint[k, _CX]
    cy = kint[k, _CY]
    W = kint[k, _W]
    H = kint[k, _H]
    rmin = kint[k, _RMIN]
    rmax = kint[k, _RMAX]
    ox = origins[k, 0]
    oy = origins[k, 1]
    oz = origins[k, 2]
    pumin = np.inf
    pumax = -np.inf
    pvmin = np.inf
    pvmax = -np.inf
    zmin = np.inf
    zmax = -np.inf
    seen = True
    for j in range(4):
        a = gy + (j >> 1)
        b = gx + (j & 1)
        rx = rays[k, a, b, 0]
        ry = rays[k, a, b, 1]
        rz = rays[k, a, b, 2]
        for s in range(2):
            d = d1 if s == 0 else d2
            X = ox + d * rx
            Y = oy + d * ry
            Z = oz + d * rz
            if Z < zmin:
                zmin = Z
            if Z > zmax:
                zmax = Z
            if not (Z >= rmin and Z <= rmax):
                seen = False
                continue
            pu = X * fx / Z + cx
            pv = Y * fy / Z + cy
            pumin = min(pumin, pu)
            pumax = max(pumax, pu)
            pvmin = min(pvmin, pv)
            pvmax = max(pvmax, pv)
    if not seen:
        return False, 0, -1, 0, -1, zmin, zmax
    if not (pumin >= -0.5 and pumax < W - 0.5 and pvmin >= -0.5 and pvmax < H - 0.5):
        return False, 0, -1, 0, -1, zmin, zmax
    u0 = int(math.floor(pumin + 0.5))
    u1 = int(math.floor(pumax + 0.5))
    v0 = int(math.floor(pvmin + 0.5))
    v1 = int(math.floor(pvmax + 0.5))
    return True, u0, u1, v0, v1, zmin, zmax


@njit(cache=True)
def cell_cleared(kfree, rays, origins, kint, nk, gx, gy, d1, d2):
    """True when some other camera clears the piece ``pixel (gx, gy) x [d1, d2]``:
    it sees it whole and every footprint pixel is free beyond ``dend_k``
    (module docstring). False = confirmed by every camera (an obstacle)."""
    for k in range(nk):
        seen, u0, u1, v0, v1, zmin, zmax = cell_footprint(rays, origins, kint, k, gx, gy, d1, d2)
        if not seen:
            continue
        ok = True
        for v in range(v0, v1 + 1):
            for u in range(u0, u1 + 1):
                if not (kfree[k, v, u] > zmax):
                    ok = False
                    break
            if not ok:
                break
        if ok:
            return True
    return False


@njit(cache=True)
def _range_cleared(kpyr, koff, kdims, rays, origins, kint, nk, gx, gy, d1, d2):
    """Fast sufficient test that the whole piece ``[d1, d2]`` of a column is
    cleared by one camera, from the min-pyramid (a superset of the footprint).
    True implies :func:`cell_cleared` is True for every cell inside."""
    for k in range(nk):
        seen, u0, u1, v0, v1, zmin, zmax = cell_footprint(rays, origins, kint, k, gx, gy, d1, d2)
        if not seen:
            continue
        if _box_min(kpyr[k], koff[k], kdims[k], u0, u1, v0, v1) > zmax:
            return True
    return False


@njit(cache=True)
def _seg_dist2(px, py, pz, cap):
    ax = cap[0]
    ay = cap[1]
    az = cap[2]
    ex = cap[3] - ax
    ey = cap[4] - ay
    ez = cap[5] - az
    wx = px - ax
    wy = py - ay
    wz = pz - az
    ee = ex * ex + ey * ey + ez * ez
    t = 0.0
    if ee > 0.0:
        t = (wx * ex + wy * ey + wz * ez) / ee
        t = min(max(t, 0.0), 1.0)
    dx = wx - t * ex
    dy = wy - t * ey
    dz = wz - t * ez
    return dx * dx + dy * dy + dz * dz


@njit(cache=True)
def cell_in_capsules(caps, ncaps, fx, fy, cx, cy, gx, gy, d1, d2):
    """True when the cell lies inside one padded robot capsule.

    caps : (>= ncaps, 7) end points ``a, b`` (principal camera frame, m) and radius.
    The cell is convex (hull of its 8 corners) and so is a capsule: the cell
    is inside iff its 8 corners are (R12, "never obstacles for its own points").
    """
    for c in range(ncaps):
        r2 = caps[c, 6] * caps[c, 6]
        inside = True
        for j in range(8):
            ux = gx - 0.5 + (j & 1)
            vy = gy - 0.5 + ((j >> 1) & 1)
            d = d1 if (j >> 2) == 0 else d2
            X = (ux - cx) * d / fx
            Y = (vy - cy) * d / fy
            if _seg_dist2(X, Y, d, caps[c]) > r2:
                inside = False
                break
        if inside:
            return True
    return False


@njit(cache=True, inline="always")
def _ray_capsule(cx_, cy_, cap):
    """Interval ``[a, b]`` of principal depths ``d`` with ``d * (cx_, cy_, 1)`` inside
    the capsule ``cap`` (a, b, radius; principal frame); ``a > b`` when empty.
    The capsule is convex, so the set is one interval: the union of the
    ray's intervals in the two end spheres and in the cylinder slab."""
    ax = cap[0]
    ay = cap[1]
    az = cap[2]
    ex = cap[3] - ax
    ey = cap[4] - ay
    ez = cap[5] - az
    r2 = cap[6] * cap[6]
    lo = np.inf
    hi = -np.inf
    rr = cx_ * cx_ + cy_ * cy_ + 1.0
    # end spheres: |d c - s|^2 <= r^2
    for e in range(2):
        sx = ax + e * ex
        sy = ay + e * ey
        sz = az + e * ez
        bb = cx_ * sx + cy_ * sy + sz
        cc = sx * sx + sy * sy + sz * sz - r2
        disc = bb * bb - rr * cc
        if disc >= 0.0:
            sq = math.sqrt(disc)
            lo = min(lo, (bb - sq) / rr)
            hi = max(hi, (bb + sq) / rr)
    # cylinder: |w - (w.e / e.e) e|^2 <= r^2 with w = d c - a, and 0 <= w.e / e.e <= 1
    ee = ex * ex + ey * ey + ez * ez
    if ee > 0.0:
        ce = cx_ * ex + cy_ * ey + ez
        ae = ax * ex + ay * ey + az * ez
        # w.e = d ce - ae ; |w|^2 = d^2 rr - 2 d (c.a) + a.a
        ca = cx_ * ax + cy_ * ay + az
        aa = ax * ax + ay * ay + az * az
        A = rr - ce * ce / ee
        B = -2.0 * ca + 2.0 * ce * ae / ee
        C = aa - ae * ae / ee - r2
        # slab 0 <= (d ce - ae) / ee <= 1 -> d in [s0, s1]
        if ce > 0.0:
            s0 = ae / ce
            s1 = (ee + ae) / ce
        elif ce < 0.0:
            s0 = (ee + ae) / ce
            s1 = ae / ce
        else:
            s0 = -np.inf if (ae <= 0.0 and -ae <= ee) else np.inf
            s1 = np.inf if (ae <= 0.0 and -ae <= ee) else -np.inf
        if A > 1e-15:
            disc = B * B - 4.0 * A * C
            if disc >= 0.0:
                sq = math.sqrt(disc)
                c0 = max((-B - sq) / (2.0 * A), s0)
                c1 = min((-B + sq) / (2.0 * A), s1)
                if c0 <= c1:
                    lo = min(lo, c0)
                    hi = max(hi, c1)
        elif C <= 0.0 and s0 <= s1:         # ray parallel to the axis, inside the cylinder
            lo = min(lo, s0)
            hi = max(hi, s1)
    return lo, hi


MAX_CAPS_PER_PIXEL = 4


@njit(cache=True, parallel=True)
def capsule_intervals(caps, ncaps, boxes, fx, fy, cx, cy, H, W, out_lo, out_hi, out_n):
    """Per principal pixel, the depth intervals ``[lo, hi]`` where the pixel's
    cross-section (its 4 corner rays) lies inside each padded robot capsule
    (R12: cells inside the robot's volume are never obstacles).

    A cell ``pixel x [d1, d2]`` is inside capsule ``c`` iff its 8 corners are,
    iff ``lo_c <= d1`` and ``d2 <= hi_c`` (the corners' rays each meet the
    convex capsule in one interval; ``lo_c, hi_c`` = max / min over the 4).
    boxes : (ncaps, 4) int64 inclusive pixel box ``u0, u1, v0, v1`` holding the
        capsule's projection (pixels outside cannot meet it).
    out_lo, out_hi : (H, W, MAX_CAPS_PER_PIXEL) float64; out_n : (H, W) int64
    number of intervals (``MAX_CAPS_PER_PIXEL + 1`` = too many: test cells directly).
    """
    for v in prange(H):
        for u in range(W):
            out_n[v, u] = 0
    for c in range(ncaps):
        for v in prange(boxes[c, 2], boxes[c, 3] + 1):
            for u in range(boxes[c, 0], boxes[c, 1] + 1):
                lo = -np.inf
                hi = np.inf
                for j in range(4):
                    cxr = (u - 0.5 + (j & 1) - cx) / fx
                    cyr = (v - 0.5 + (j >> 1) - cy) / fy
                    a, b = _ray_capsule(cxr, cyr, caps[c])
                    lo = max(lo, a)
                    hi = min(hi, b)
                    if lo > hi:
                        break
                if lo > hi:
                    continue
                n = out_n[v, u]
                if n < MAX_CAPS_PER_PIXEL:
                    out_lo[v, u, n] = lo
                    out_hi[v, u, n] = hi
                out_n[v, u] = min(n + 1, MAX_CAPS_PER_PIXEL + 1)


@njit(cache=True)
def _column(u, v, df, kind, px, py, dp, lim2, fx, fy, cx, cy, dmin, dd, nd,
            kfree, kpyr, koff, kdims, rays, origins, kint, nk, caps, ncaps, cap_lo, cap_hi, cap_n):
    """Nearest obstacle cell of the principal pixel ``(u, v)``'s column (R10, R12).

    Walks the cells whose R10 distance can be ``<= sqrt(lim2)``, from the
    minimiser of the distance along the column outwards, and stops in each
    direction once the distance grows past the best found (the R10 distance
    is a convex function of ``ôd``, which is monotone in ``gd``). A gray cell
    is first tested against the robot's capsules (per-pixel intervals), then
    for clearing: a run of cells ahead is tried at once on the other
    cameras' min-pyramids (a sufficient test), halving the run down to the
    single cell, which is then tested exactly (:func:`cell_cleared`).
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
    gs = int(math.floor((df - dmin) / dd))                    # cell of the free depth
    g_hi = int(math.floor((dp + rho - dmin) / dd))
    g_lo = max(gs, int(math.floor((dp - rho - dmin) / dd)))
    if g_lo > g_hi:
        return False, 0.0, 0.0, 0.0, 0.0
    direct = kind == KIND_SURFACE
    ncp = cap_n[v, u] if ncaps > 0 else 0
    gm = int(math.floor((dstar - dmin) / dd))
    gm = min(max(gm, g_lo), g_hi)
    best2 = lim2
    found = False
    bvx = 0.0
    bvy = 0.0
    bvz = 0.0
    for dirn in range(2):
        if dirn == 0:
            g = gm
            step = 1
            gend = g_hi
        else:
            g = gm - 1
            step = -1
            gend = g_lo
        clear_to = g - step                   # cells strictly before this (in walk order) are cleared
        while g_lo <= g <= g_hi:
            d1 = dmin + g * dd
            d2 = d1 + dd
            od = min(max(dp, d1), d2)                          # R10 depth rule
            wx = ax * od - bx
            wy = ay * od - by
            wz = od - dp
            f2 = wx * wx + wy * wy + wz * wz
            if f2 > best2 or (found and f2 == best2):
                if (step == 1 and od >= dstar) or (step == -1 and od <= dstar):
                    break
                g += step
                continue
            if g == gs and direct:
                obst = True
            elif g < 0 or g >= nd:
                obst = True                                    # outside the grid: unknown
            else:
                obst = True
                # inside the padded robot?
                if ncp > MAX_CAPS_PER_PIXEL:
                    if cell_in_capsules(caps, ncaps, fx, fy, cx, cy, u, v, d1, d2):
                        obst = False
                else:
                    for j in range(ncp):
                        if cap_lo[v, u, j] <= d1 and d2 <= cap_hi[v, u, j]:
                            obst = False
                            break
                if obst and nk > 0:
                    if (step == 1 and g <= clear_to) or (step == -1 and g >= clear_to):
                        obst = False
                    else:
                        # try a run of cells g .. g + step*(span-1) at once
                        span = (gend - g) * step + 1
                        lim_hi = nd - 1 - g if step == 1 else g
                        span = min(span, lim_hi + 1)
                        while span > 1:
                            ga = g if step == 1 else g - span + 1
                            gb = ga + span - 1
                            if _range_cleared(kpyr, koff, kdims, rays, origins, kint, nk, u, v,
                                              dmin + ga * dd, dmin + (gb + 1) * dd):
                                clear_to = gb if step == 1 else ga
                                break
                            span = span // 2
                        if span > 1:
                            obst = False
                        else:
                            obst = not cell_cleared(kfree, rays, origins, kint, nk, u, v, d1, d2)
            if g == gs and direct and ncaps > 0:
                if ncp > MAX_CAPS_PER_PIXEL:
                    if cell_in_capsules(caps, ncaps, fx, fy, cx, cy, u, v, d1, d2):
                        obst = False
                else:
                    for j in range(ncp):
                        if cap_lo[v, u, j] <= d1 and d2 <= cap_hi[v, u, j]:
                            obst = False
                            break
            if obst and (g < 0 or g >= nd) and ncaps > 0:
                if cell_in_capsules(caps, ncaps, fx, fy, cx, cy, u, v, d1, d2):
                    obst = False
            if obst:
                best2 = f2
                found = True
                bvx = wx        # camera-frame vector (R5): ((ôx-cx)ôd - (px-cx)dp)/fx ...
                bvy = wy
                bvz = wz
            g += step
    return found, best2, bvx, bvy, bvz


@njit(cache=True, parallel=True)
def grid_distances(pfree, pkind, Rp, tp, pint, dmin, dd, nd,
                   kfree, kpyr, koff, kdims, rays, origins, kint, nk,
                   caps, ncaps, cap_lo, cap_hi, cap_n, points, n_points, rho, method,
                   out_distance, out_direction, out_count, out_observed):
    """On-line distances of ``n_points`` control points through the depth grid (R12).

    pfree, pkind : (H, W) principal frame state from :func:`frame_state`.
    Rp, tp : principal ``camera_from_world`` (3, 3), (3,).
    pint : (8,) principal fx, fy, cx, cy, W, H, min_range, max_range.
    dmin, dd, nd : grid start depth, slice depth (m), number of slices (R10).
    kfree : (nk, Hk, Wk) free depths of the other cameras; kpyr / koff / kdims:
        their min-pyramids (:func:`build_min_pyramid`), flat per camera.
    rays, origins, kint : the compact map (module docstring).
    caps : (>= ncaps, 7) robot capsules in the principal frame (a, b, radius);
        cap_lo / cap_hi / cap_n their per-pixel intervals (:func:`capsule_intervals`).
    points : (>= n_points, 3) world metres. method : METHOD_*.
    out_* : as in :func:`depthguard.distance.kernels.depth_space_distances`:
        distance (inf = nothing within rho), unit world direction, count of
        columns in S, observed (P inside the principal's image and range).

    Per principal pixel of the region of surveillance (R6) with free depth
    ``df``: case 1 ``df > dp + rho`` skips it; otherwise the nearest obstacle
    cell of the column is found by :func:`_column` — the measured surface
    cell (case 2, and the end of case 3's walk) is an obstacle without
    confirmation; gray cells behind a surface (case 3), behind the robot
    (case 4) or on an invalid ray are obstacles unless another camera clears
    them; cells inside the padded robot are never obstacles.
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
        X = points[i, 0]
        Y = points[i, 1]
        Z = points[i, 2]
        xc = Rp[0, 0] * X + Rp[0, 1] * Y + Rp[0, 2] * Z + tp[0]   # (1)
        yc = Rp[1, 0] * X + Rp[1, 1] * Y + Rp[1, 2] * Z + tp[1]
        dp = Rp[2, 0] * X + Rp[2, 1] * Y + Rp[2, 2] * Z + tp[2]
        out_direction[i, 0] = 0.0
        out_direction[i, 1] = 0.0
        out_direction[i, 2] = 0.0
        out_distance[i] = np.inf
        out_count[i] = 0
        if not dp > 0.0:
            out_observed[i] = False
            continue
        px = xc * fx / dp + cx                                     # (2)
        py = yc * fy / dp + cy
        out_observed[i] = (dp >= rmin and dp <= rmax and px >= -0.5 and px < W - 0.5
                           and py >= -0.5 and py < H - 0.5)
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
        for v in range(v0, v1 + 1):
            for u in range(u0, u1 + 1):
                df = pfree[v, u]
                if df > dp + rho:                                  # case 1
                    continue
                lim2 = best2 if method == METHOD_MIN else rho2
                found, D2, vx, vy, vz = _column(u, v, df, pkind[v, u], px, py, dp, lim2,
                                                fx, fy, cx, cy, dmin, dd, nd,
                                                kfree, kpyr, koff, kdims, rays, origins, kint, nk,
                                                caps, ncaps, cap_lo, cap_hi, cap_n)
                if not found:
                    continue
                D = math.sqrt(D2)
                if D <= D_ZERO:
                    D = 0.0
                    D2 = 0.0
                if method == METHOD_MIN:
                    if D2 < best2 or n == 0:
                        best2 = D2
                        dmin_found = D
                        bx = vx
                        by = vy
                        bz = vz
                        n = 1
                    continue
                n += 1
                sD += D
                if D < dmin_found:
                    dmin_found = D
                if D > 0.0:
                    sx += vx / D
                    sy += vy / D
                    sz += vz / D
        if n == 0:
            continue
        out_count[i] = n
        if method == METHOD_MIN:
            out_distance[i] = dmin_found
            if dmin_found > 0.0:
                vx = bx / dmin_found
                vy = by / dmin_found
                vz = bz / dmin_found
            else:
                continue
        else:
            out_distance[i] = sD / n if method == METHOD_MEAN else dmin_found
            norm = math.sqrt(sx * sx + sy * sy + sz * sz)
            if norm == 0.0:
                continue
            vx = sx / norm
            vy = sy / norm
            vz = sz / norm
        out_direction[i, 0] = Rp[0, 0] * vx + Rp[1, 0] * vy + Rp[2, 0] * vz
        out_direction[i, 1] = Rp[0, 1] * vx + Rp[1, 1] * vy + Rp[2, 1] * vz
        out_direction[i, 2] = Rp[0, 2] * vx + Rp[1, 2] * vy + Rp[2, 2] * vz
