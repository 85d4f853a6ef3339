"""The robot's padded volume in the principal camera's pixels (R12, R25).

Cells whose centre lies inside one of the robot's padded capsules are never
obstacles (R12). The depth grid keeps, per principal pixel, the depth
intervals where the pixel's centre ray runs inside each capsule
(:func:`capsule_intervals`, bounded by each capsule's pixel box
:func:`capsule_boxes`); a cell is the robot's when its centre depth lies in one
of them (:func:`_in_caps`), or, for a pixel that meets more than
``MAX_CAPS_PER_PIXEL`` capsules, when its centre lies in one
(:func:`cell_in_capsules`). Capsules are ``(a (3,), b (3,), radius)`` rows of a
``(C, 7)`` array in the principal camera's frame, metres. The plain-numpy
twins are in :mod:`depthguard.fusion.depth_grid_ref` and
:meth:`~depthguard.fusion.depth_grid.DepthGridMap._capsule_boxes_numpy`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from depthguard.distance.window import grow_pixel_box

__all__ = ["MAX_CAPS_PER_PIXEL", "capsule_intervals", "capsule_boxes", "cell_in_capsules", "principal_capsules"]


@njit(cache=True, nogil=True)
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


@njit(cache=True, nogil=True)
def cell_in_capsules(caps, ncaps, fx, fy, cx, cy, gx, gy, d1, d2):
    """True when the cell's centre lies inside one padded robot capsule (R12;
    the rule of :func:`capsule_intervals`).

    caps : (>= ncaps, 7) end points ``a, b`` (principal camera frame, m) and radius.
    """
    d = 0.5 * (d1 + d2)
    X = (gx - cx) * d / fx
    Y = (gy - cy) * d / fy
    for c in range(ncaps):
        if _seg_dist2(X, Y, d, caps[c]) <= caps[c, 6] * caps[c, 6]:
            return True
    return False


@njit(cache=True, inline="always")
def _capsule_terms(cap):
    """The terms of a ray's interval in the capsule that depend on the capsule alone (a, b, radius; principal
    frame, m), computed once per capsule: ``(ax, ay, az, ex, ey, ez, r2, cc0, cc1, ee, ae, aa, C)``
    — the end spheres' ``|s|^2 - r^2`` and the cylinder's constant term, by the same expressions
    as per pixel (so every interval is bit for bit the same)."""
    ax = cap[0]
    ay = cap[1]
    az = cap[2]
    ex = cap[3] - ax
    ey = cap[4] - ay
    ez = cap[5] - az
    r2 = cap[6] * cap[6]
    cc0 = ax * ax + ay * ay + az * az - r2
    sx = ax + 1 * ex
    sy = ay + 1 * ey
    sz = az + 1 * ez
    cc1 = sx * sx + sy * sy + sz * sz - r2
    ee = ex * ex + ey * ey + ez * ez
    ae = ax * ex + ay * ey + az * ez
    aa = ax * ax + ay * ay + az * az
    C = 0.0
    if ee > 0.0:
        C = aa - ae * ae / ee - r2
    return ax, ay, az, ex, ey, ez, r2, cc0, cc1, ee, ae, aa, C


@njit(cache=True, inline="always")
def _ray_capsule_terms(cx_, cy_, rr, terms):
    """The interval of :func:`_ray_capsule` with the capsule's own terms (:func:`_capsule_terms`)
    given and ``rr = cx_^2 + cy_^2 + 1``: the per-pixel arithmetic only (R12, R25). :func:`capsule_intervals` calls it for ~10k (pixel, capsule) pairs a build
    (ur3-cell); with the capsule's terms worked out once per row and capsule instead of per pixel
    the kernel took 0.86-0.91x the time (0.593 -> 0.537 ms median on ur3-cell's builds, one thread)."""
    ax, ay, az, ex, ey, ez, r2, cc0, cc1, ee, ae, aa, C = terms
    lo = np.inf
    hi = -np.inf
    # end spheres: |d c - s|^2 <= r^2
    for e in range(2):
        sx = ax + e * ex
        sy = ay + e * ey
        sz = az + e * ez
        bb = cx_ * sx + cy_ * sy + sz
        cc = cc0 if e == 0 else cc1
        disc = bb * bb - rr * cc
        if disc >= 0.0:
            sq = math.sqrt(disc)
            lo = min(lo, (bb - sq) / rr)
            hi = max(hi, (bb + sq) / rr)
    # cylinder: |w - (w.e / e.e) e|^2 <= r^2 with w = d c - a, and 0 <= w.e / e.e <= 1
    if ee > 0.0:
        ce = cx_ * ex + cy_ * ey + ez
        # w.e = d ce - ae ; |w|^2 = d^2 rr - 2 d (c.a) + a.a
        ca = cx_ * ax + cy_ * ay + az
        A = rr - ce * ce / ee
        B = -2.0 * ca + 2.0 * ce * ae / ee
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


MAX_CAPS_PER_PIXEL = 8


@njit(cache=True, inline="always")
def _ray_capsule(cx_, cy_, cap):
    """Interval ``[a, b]`` of principal depths ``d`` with ``d * (cx_, cy_, 1)`` inside
    the capsule ``cap`` (a, b, radius; principal frame); ``a > b`` when empty.
    The capsule is convex, so the set is one interval: the union of the
    ray's intervals in the two end spheres and in the cylinder slab
    (:func:`_ray_capsule_terms` with the capsule's terms worked out here)."""
    return _ray_capsule_terms(cx_, cy_, cx_ * cx_ + cy_ * cy_ + 1.0, _capsule_terms(cap))


@njit(cache=True, nogil=True)
def capsule_intervals(caps, ncaps, boxes, fx, fy, cx, cy, H, W, out_lo, out_hi, out_n, written):
    """Per principal pixel, the depth intervals ``[lo, hi]`` where the pixel's
    centre ray lies inside each padded robot capsule (R12: cells inside the
    robot's volume are never obstacles).

    A cell ``pixel x [d1, d2]`` counts as inside the padded volume when its
    centre, the centre ray at ``(d1 + d2) / 2``, lies in one capsule:
    ``lo_c <= (d1 + d2) / 2 <= hi_c``. So an excluded cell lies within
    ``padding`` + half the cell's diagonal of the robot's capsules (R25: within
    the discretisation), and a cell straddling two capsules of the same arm or
    the silhouette of a padded link is judged by where its bulk is; a rule
    needing all 8 corners in one capsule reported such cells at the joints as
    obstacles a few centimetres from the robot's own control points.
    boxes : (ncaps, 4) int64 inclusive pixel box ``u0, u1, v0, v1`` holding the
        capsule's projection (pixels outside cannot meet it).
    out_lo, out_hi : (H, W, MAX_CAPS_PER_PIXEL) float64; out_n : (H, W) int64
    number of intervals (``MAX_CAPS_PER_PIXEL + 1`` = too many: test cells directly).
    written : (4,) int64 inclusive pixel box ``v0, v1, u0, u1`` outside which ``out_n`` is 0 on
    entry (the last call's boxes; the whole image for an ``out_n`` not known to be 0): only that
    box is set to 0 before the boxes are filled, and it is set to the union of this call's boxes
    (``v1 < v0``: none). Every pixel of ``out_n`` comes out as if the whole image had been set to
    0 first; a monitor's build no longer writes the 0.6 MB of a binned 640x480 principal's counts
    (issue 29).
    A ray farther from the capsule's centre than its bounding radius, or from its
    axis line than its radius (relative margin 1e-6), misses it and is skipped.
    On the calling thread: over numba's threads it took 1.0-1.6x the time of one (0.12-0.19 ms,
    same frames in one process, ur3-cell, flacco-cell, fr3-cell, ur5-urdf-posts; 2026-11-27).
    """
    for v in range(max(written[0], 0), min(written[1], H - 1) + 1):
        for u in range(max(written[2], 0), min(written[3], W - 1) + 1):
            out_n[v, u] = 0
    va = H
    vb = -1
    ua = W
    ub = -1
    for c in range(ncaps):
        if boxes[c, 0] <= boxes[c, 1] and boxes[c, 2] <= boxes[c, 3]:
            va = min(va, max(boxes[c, 2], 0))
            vb = max(vb, min(boxes[c, 3], H - 1))
            ua = min(ua, max(boxes[c, 0], 0))
            ub = max(ub, min(boxes[c, 1], W - 1))
    written[0] = va
    written[1] = vb
    written[2] = ua
    written[3] = ub
    for v in range(va, vb + 1):                # per pixel the capsules in order
        cyr = (v - cy) / fy
        for c in range(ncaps):
            u0 = boxes[c, 0]
            u1 = boxes[c, 1]
            if u0 > u1 or not (boxes[c, 2] <= v <= boxes[c, 3]):
                continue
            mx = 0.5 * (caps[c, 0] + caps[c, 3])
            my = 0.5 * (caps[c, 1] + caps[c, 4])
            mz = 0.5 * (caps[c, 2] + caps[c, 5])
            ex = caps[c, 3] - caps[c, 0]
            ey = caps[c, 4] - caps[c, 1]
            ez = caps[c, 5] - caps[c, 2]
            rb = (0.5 * math.sqrt(ex * ex + ey * ey + ez * ez) + caps[c, 6]) * (1.0 + 1e-6) + 1e-9
            rb2 = rb * rb
            mm = mx * mx + my * my + mz * mz
            ax = caps[c, 0]
            ay = caps[c, 1]
            az = caps[c, 2]
            rc = caps[c, 6] * (1.0 + 1e-6) + 1e-9
            rc2 = rc * rc
            terms = _capsule_terms(caps[c])      # once per row and capsule, not per pixel
            for u in range(u0, u1 + 1):
                cxr = (u - cx) / fx
                rr = cxr * cxr + cyr * cyr + 1.0
                cm = cxr * mx + cyr * my + mz
                nx = cyr * ez - ey
                ny = ex - cxr * ez
                nz = cxr * ey - cyr * ex
                an = ax * nx + ay * ny + az * nz
                if mm - cm * cm / rr > rb2 or an * an > rc2 * (nx * nx + ny * ny + nz * nz):
                    continue
                lo, hi = _ray_capsule_terms(cxr, cyr, rr, terms)
                if lo > hi:
                    continue
                n = out_n[v, u]
                if n < MAX_CAPS_PER_PIXEL:
                    out_lo[v, u, n] = lo
                    out_hi[v, u, n] = hi
                out_n[v, u] = min(n + 1, MAX_CAPS_PER_PIXEL + 1)


@njit(cache=True)      # microseconds: keeps the GIL (a release costs a retake behind the other threads)
def principal_capsules(seg, rad, Rp, tp, out):
    """The robot's capsules in the principal camera's frame, checked first (R12): ``seg``
    (C, 2, 3) float64 world end points and ``rad`` (C,) float64 radii (m) into ``out`` (>= C, 7)
    float64 rows ``a, b, radius`` with ``a = Rp a_w + tp`` (``Rp`` (3, 3), ``tp`` (3,): world ->
    principal). Returns False, ``out`` untouched, when an end point is not finite or a radius is
    not a finite number >= 0. One call where the numpy steps took ~0.15 ms of the fusion's serial
    path per build (issue 29)."""
    n = seg.shape[0]
    for c in range(n):
        r = rad[c]
        if not (math.isfinite(r) and r >= 0.0):
            return False
        for e in range(2):
            for i in range(3):
                if not math.isfinite(seg[c, e, i]):
                    return False
    for c in range(n):
        for e in range(2):
            x = seg[c, e, 0]
            y = seg[c, e, 1]
            z = seg[c, e, 2]
            for i in range(3):
                out[c, 3 * e + i] = Rp[i, 0] * x + Rp[i, 1] * y + Rp[i, 2] * z + tp[i]
        out[c, 6] = rad[c]
    return True


@njit(cache=True)      # microseconds: keeps the GIL (a release costs a retake behind the other threads)
def capsule_boxes(caps, ncaps, fx, fy, cx, cy, H, W, out):
    """(ncaps, 4) int64 written into ``out``: the inclusive pixel box ``u0, u1, v0, v1`` holding
    each capsule's projection (principal frame capsules): the projected corners of its
    axis-aligned bounding box, plus a pixel; the whole image when a corner has ``z <= 1e-6``."""
    for i in range(ncaps):
        full = False
        pumin = np.inf
        pumax = -np.inf
        pvmin = np.inf
        pvmax = -np.inf
        lx = min(caps[i, 0], caps[i, 3]) - caps[i, 6]
        hx = max(caps[i, 0], caps[i, 3]) + caps[i, 6]
        ly = min(caps[i, 1], caps[i, 4]) - caps[i, 6]
        hy = max(caps[i, 1], caps[i, 4]) + caps[i, 6]
        lz = min(caps[i, 2], caps[i, 5]) - caps[i, 6]
        hz = max(caps[i, 2], caps[i, 5]) + caps[i, 6]
        for j in range(8):
            sx = 1.0 if (j >> 2) & 1 else -1.0
            sy = 1.0 if (j >> 1) & 1 else -1.0
            sz = 1.0 if j & 1 else -1.0
            c0 = (lx + hx) / 2 + sx * (hx - lx) / 2
            c1 = (ly + hy) / 2 + sy * (hy - ly) / 2
            c2 = (lz + hz) / 2 + sz * (hz - lz) / 2
            if c2 <= 1e-6:
                full = True
                break
            pumin, pumax, pvmin, pvmax = grow_pixel_box(c0, c1, c2, fx, fy, cx, cy, pumin, pumax, pvmin, pvmax)
        if full:
            out[i, 0] = 0
            out[i, 1] = W - 1
            out[i, 2] = 0
            out[i, 3] = H - 1
            continue
        out[i, 0] = max(int(math.floor(pumin + 0.5)) - 1, 0)
        out[i, 1] = min(int(math.floor(pumax + 0.5)) + 1, W - 1)
        out[i, 2] = max(int(math.floor(pvmin + 0.5)) - 1, 0)
        out[i, 3] = min(int(math.floor(pvmax + 0.5)) + 1, H - 1)


@njit(cache=True, inline="always")
def _in_caps(cap_lo, cap_hi, ncp, v, u, d1, d2, caps, ncaps, fx, fy, cx, cy, g):
    if ncp > MAX_CAPS_PER_PIXEL:
        return cell_in_capsules(caps, ncaps, fx, fy, cx, cy, u, v, d1, d2)
    dm = 0.5 * (d1 + d2)
    for j in range(ncp):
        if cap_lo[v, u, j] <= dm <= cap_hi[v, u, j]:
            return True
    return False
