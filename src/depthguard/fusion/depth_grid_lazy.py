"""Lazy per-frame work of the depth grid map (the default; SPEC §3, R10–R12).

A principal column's cells are classified on first use within a frame, only
over the slices a query needs, and memoised as bits (the eager form, every
column's obstacle runs at once, is :func:`depthguard.fusion.depth_grid_eager.column_runs`).
``obits[v, u, w]`` / ``cbits[v, u, w]`` (uint64) hold bit
``g & 63`` of word ``g >> 6`` for slice ``g`` in ``0..n_d-1``: obstacle /
already classified. ``stamp[v, u]`` is the frame number the pixel's bits and
free stretch (``free_to``, ``clear``) belong to; a pixel with an older stamp
reads as not yet touched (free to its free depth, nothing cleared) and is reset
on first touch, so a new frame costs no work on the memo, only the tiles' least
free depths (:func:`tile_min`; it filled two (H, W) arrays before, 0.9 MB of a
binned 640x480 principal a build: issue 29). Each cell gets exactly the class
that :func:`~depthguard.fusion.depth_grid_eager.column_runs` gives it (same
rule, same exact stretch shortcuts), so the answers equal the eager runs'
(without their run-overflow merging).

Per query and principal pixel the cheap tests come first (R12 case 1, the
column's memoised free stretch, the pixel column's distance to the point),
so that only the columns that can hold an obstacle within ``rho`` pay for
the slice arithmetic; the per-point and per-row terms of the R10 distance
are computed once per point / row (the same expressions as the eager form,
so the answers are bit-identical to it).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from depthguard.distance.window import surveillance_window
from depthguard.fusion.depth_grid_capsules import MAX_CAPS_PER_PIXEL, _in_caps
from depthguard.fusion.depth_grid_kernels import KIND_SURFACE, TILE
from depthguard.fusion.depth_grid_memo import gray_stretch
from depthguard.fusion.depth_grid_memo import mask_range as _mask_range
from depthguard.fusion.depth_grid_memo import msb as _msb

__all__ = ["tile_min", "ensure_cells"]

_ONE = np.uint64(1)
_ALL = np.uint64(0xFFFFFFFFFFFFFFFF)


@njit(cache=True, nogil=True)
def tile_min(pfree, tmin):
    """What a new frame needs of the memo (module docstring): ``tmin`` (ceil(H/TILE),
    ceil(W/TILE)) float64 per tile of the principal's free depths ``pfree`` (H, W) float64 m the
    smallest (a point with ``dp + rho`` below it has every pixel of the tile in case 1, R12).
    Compiled: numpy's calls each gave the GIL away and waited to take it back in a real-time run
    (issue 29)."""
    H = pfree.shape[0]
    W = pfree.shape[1]
    for ty in range(tmin.shape[0]):
        for tx in range(tmin.shape[1]):
            tmin[ty, tx] = np.inf
    for v in range(H):
        ty = v // TILE
        for u in range(W):
            x = pfree[v, u]
            tx = u // TILE
            if x < tmin[ty, tx]:
                tmin[ty, tx] = x


@njit(cache=True, inline="always")
def pixel_free_to(stamp, free_to, pfree, frame, v, u):
    """``free_to[v, u]`` of this ``frame`` (module docstring): the pixel's free depth until it is
    touched in this frame."""
    return free_to[v, u] if stamp[v, u] == frame else pfree[v, u]


@njit(cache=True, inline="always")
def pixel_clear(stamp, clear, frame, v, u):
    """``clear[v, u]`` of this ``frame`` (module docstring): -1 until the pixel is touched in
    this frame."""
    return clear[v, u] if stamp[v, u] == frame else -1


@njit(cache=True, inline="always")
def _bit(bits, v, u, g):
    return (bits[v, u, g >> 6] >> np.uint64(g & 63)) & _ONE


@njit(cache=True, inline="always")
def _word_range(bits, v, u, w, lo, hi):
    """Word ``w`` of a pixel's bits with only slices ``lo..hi`` kept."""
    x = bits[v, u, w]
    if (hi >> 6) == w and (hi & 63) < 63:
        x = x & ((_ONE << np.uint64((hi & 63) + 1)) - _ONE)
    if (lo >> 6) == w:
        x = x & (_ALL << np.uint64(lo & 63))
    return x


@njit(cache=True, inline="always")
def _highest_bit(bits, v, u, lo, hi):
    """Largest slice in ``lo..hi`` (inside ``0..n_d-1``) whose bit is set, -1 if none."""
    if lo > hi:
        return -1
    w = hi >> 6
    while w >= (lo >> 6):
        x = _word_range(bits, v, u, w, lo, hi)
        if x != np.uint64(0):
            return w * 64 + _msb(x)
        w -= 1
    return -1


@njit(cache=True, inline="always")
def _lowest_bit(bits, v, u, lo, hi):
    """Smallest slice in ``lo..hi`` (inside ``0..n_d-1``) whose bit is set, -1 if none."""
    if lo > hi:
        return -1
    w = lo >> 6
    while w <= (hi >> 6):
        x = _word_range(bits, v, u, w, lo, hi)
        if x != np.uint64(0):
            return w * 64 + _msb(x & (~x + _ONE))
        w += 1
    return -1


@njit(cache=True, inline="always")
def _all_set(bits, v, u, lo, hi):
    """Every slice ``lo..hi`` (inside ``0..n_d-1``, ``lo <= hi``) has its bit set."""
    for w in range(lo >> 6, (hi >> 6) + 1):
        need = _mask_range(w, lo, hi)
        if (bits[v, u, w] & need) != need:
            return False
    return True


@njit(cache=True, inline="always")
def _col_setup(u, v, pfree, dmin, dd, nd, cap_n, ncaps):
    """Per pixel: ``(gs, ncp)`` — first slice of the column that may hold an obstacle
    (``r(df)``) and the number of capsule intervals."""
    gs = int(math.floor((pfree[v, u] - dmin) / dd))
    ncp = cap_n[v, u] if ncaps > 0 else 0
    return gs, ncp


@njit(cache=True, inline="always")
def _fill_stretch(u, v, g0, g1, gs, direct, ncp, fx, fy, cx, cy, dmin, dd, kfree, kpmin, kpmax, koff,
                  kdims, rays, origins, kint, nk, kmemo, caps, ncaps, cap_lo, cap_hi, band, obits, cbits):
    """Classify slices ``g0..g1`` (inside ``0..n_d-1``, all ``>= gs``) of column ``(u, v)``
    by the rule of :func:`column_runs` and set their bits; the gray cells through the
    other cameras' memo (:func:`~depthguard.fusion.depth_grid_memo.gray_stretch`)."""
    g = g0
    while g <= g1:
        d1 = dmin + g * dd
        d2 = d1 + dd
        incap = ncaps > 0 and _in_caps(cap_lo, cap_hi, ncp, v, u, d1, d2, caps, ncaps, fx, fy, cx, cy, g)
        if incap and ncp <= MAX_CAPS_PER_PIXEL:
            # slices g..h inside an interval holding g: d1 only grows, so inside while d2 <= hi
            h = g
            for j in range(ncp):
                lo = cap_lo[v, u, j]
                hi = cap_hi[v, u, j]
                if not (lo <= d1 and d2 <= hi):
                    continue
                if dmin + g1 * dd + dd <= hi:
                    hj = g1
                else:
                    hj = min(max(int(math.floor((hi - dmin) / dd)) - 1, g), g1)
                    while hj > g and not (dmin + hj * dd + dd <= hi):
                        hj -= 1
                    while hj < g1 and dmin + (hj + 1) * dd + dd <= hi:
                        hj += 1
                h = max(h, hj)
            for w in range(g >> 6, (h >> 6) + 1):
                cbits[v, u, w] = cbits[v, u, w] | _mask_range(w, g, h)
            g = h + 1
            continue
        if incap:
            obst = False
        elif g == gs and direct:
            obst = True
        elif nk == 0 or g < band[v, u, 0] or g > band[v, u, 1]:
            obst = True
        else:
            # gray cells up to the band's end or the next capsule interval (a capsule interval
            # started at or before g ends before d2, so before every later slice; R12)
            e = min(g1, band[v, u, 1])
            for j in range(min(ncp, MAX_CAPS_PER_PIXEL)):
                if cap_lo[v, u, j] > d1:
                    e = min(e, int(math.ceil((cap_lo[v, u, j] - dmin) / dd)) - 2)
            if ncp > MAX_CAPS_PER_PIXEL or e < g:
                e = g
            gray_stretch(u, v, g, e, kfree, kpmin, kpmax, koff, kdims, rays, origins, kint, nk, dmin, dd, kmemo,
                         obits, cbits)
            g = e + 1
            continue
        w = g >> 6
        b = _ONE << np.uint64(g & 63)
        cbits[v, u, w] = cbits[v, u, w] | b
        if obst:
            obits[v, u, w] = obits[v, u, w] | b
        g += 1


@njit(cache=True, inline="always")
def _needed_slices(ax, ay, bx, by, dp, lim2, dmin, dd, g_lo, g_hi):
    """Slices ``ga..gb`` of a principal column that can lie within ``sqrt(lim2)`` of the point
    by the R10 distance (one slice of margin each side), clipped to ``g_lo..g_hi``;
    ``ga > gb``: none (the whole column is farther). Along the column
    ``f(ôd)^2 = A ôd^2 - 2 B ôd + C`` (R3, R10) with the terms of :func:`_ray_x` and
    :func:`_point_terms`. Reciprocals instead of divisions: the range only has to hold
    every slice within reach, which the slice of margin on each side covers."""
    A = ax * ax + ay * ay + 1.0
    B = ax * bx + ay * by + dp
    C = bx * bx + by * by + dp * dp
    disc = B * B - A * (C - lim2 * (1.0 + 1e-9) - 1e-12)
    if not disc >= 0.0:
        return 1, 0
    ia = 1.0 / A
    s = math.sqrt(disc) * ia
    dstar = B * ia
    idd = 1.0 / dd                  # a constant of the call: hoisted by the compiler
    ga = max(g_lo, int(math.floor((dstar - s - dmin) * idd)) - 2)
    gb = min(g_hi, int(math.floor((dstar + s - dmin) * idd)) + 1)
    return ga, gb


@njit(cache=True, inline="always")
def _ray_x(px, u, cx, fx):
    """``ax`` of column ``u`` (R3: the pixel point nearest to the point's projection,
    back-projected to unit depth); ``_ray_x(py, v, cy, fy)`` is ``ay``."""
    return (min(max(px, u - 0.5), u + 0.5) - cx) / fx


@njit(cache=True, inline="always")
def _point_terms(px, py, dp, fx, fy, cx, cy):
    """``(bx, by)``: the point's camera-frame x and y, from its projection (R3, R10)."""
    return (px - cx) * dp / fx, (py - cy) * dp / fy


@njit(cache=True, inline="always")
def _surface_first(direct, gs, ncp, ga, gb, ax, ay, bx, by, dp, dmin, dd):
    """The last slice of ``ga..gb`` (``gb`` clipped to the grid) that a query of the point
    needs classified in this column: ``gs`` when the point lies in front of the column's
    measured surface, else ``gb``. The surface cell ``r(df) = gs`` is an obstacle (R12 case
    2: a measured return, ``direct``, outside the robot's capsules: ``ncp == 0``) and the
    R10 distance along the column is unimodal with its minimum at ``r(dstar)``; with
    ``r(dstar) + 1 < gs`` every cell before ``gs`` is free and every cell after it is
    farther, so the column's nearest obstacle is ``gs`` whatever the cells behind it are
    (:func:`_column_bits` reads it as the lowest obstacle bit from ``gs`` on). Those cells
    need the other cameras' clearing: this leaves them to a point that can be nearer to
    them."""
    if direct and ncp == 0 and 0 <= gs and ga <= gs and gs <= gb:
        dstar = (ax * bx + ay * by + dp) / (ax * ax + ay * ay + 1.0)
        if math.floor((dstar - dmin) / dd) + 1 < gs:
            return gs
    return gb


@njit(cache=True, inline="always")
def _ensure_pixel(u, v, ga, gb, gs, direct, ncp, pint, dmin, dd, kfree, kpmin, kpmax, koff, kdims,
                  rays, origins, kint, nk, kmemo, caps, ncaps, cap_lo, cap_hi, band, frame, pmemo, obits, cbits):
    """Classify the not yet classified slices of ``ga..gb`` (inside the grid, ``>= gs``) of
    column ``(u, v)`` in this ``frame`` (resetting the pixel's bits on its first touch).
    ``clear[v, u]``: the largest ``h`` with every slice ``max(gs, 0)..h`` classified free
    (-1 for a pixel not yet touched in this frame: every frame starts with -1, :func:`pixel_clear`);
    ``free_to[v, u]``: the principal depth up to which the column is known free —
    its free depth ``df`` (R12 case 1; what every frame starts with, :func:`pixel_free_to`),
    raised here to ``d_min + (clear + 1) delta_d`` when ``r(df)`` lies inside the grid.
    ``pmemo = (stamp, clear, free_to, pfree)``; ``pint`` the principal's intrinsics. (At most 30
    parameters: CPython packs a longer call into ``*args``, which numba cannot inline.)"""
    stamp, clear, free_to, pfree = pmemo
    fx = pint[0]
    fy = pint[1]
    cx = pint[2]
    cy = pint[3]
    g = ga
    if stamp[v, u] != frame:
        for w in range(obits.shape[2]):
            obits[v, u, w] = np.uint64(0)
            cbits[v, u, w] = np.uint64(0)
        stamp[v, u] = frame
        clear[v, u] = max(gs, 0) - 1
        free_to[v, u] = pfree[v, u]
    elif _all_set(cbits, v, u, ga, gb):
        g = gb + 1                      # every slice classified already: only the free stretch below
    while g <= gb:
        g = _lowest_stop(cbits, cbits, v, u, g, gb, False)      # next unclassified slice
        if g < 0:
            break
        e = _lowest_bit(cbits, v, u, g, gb)                    # next classified one after it
        e = gb if e < 0 else e - 1
        _fill_stretch(u, v, g, e, gs, direct, ncp, fx, fy, cx, cy, dmin, dd, kfree, kpmin, kpmax, koff,
                      kdims, rays, origins, kint, nk, kmemo, caps, ncaps, cap_lo, cap_hi, band, obits, cbits)
        g = e + 1
    hmax = obits.shape[2] * 64          # slices past n_d are never classified
    h = clear[v, u] + 1
    if h < hmax:
        # first slice from h on that is unclassified or an obstacle
        h = _lowest_stop(cbits, obits, v, u, h, hmax - 1, True)
        if h < 0:
            h = hmax
    clear[v, u] = h - 1
    if gs >= 0:
        free_to[v, u] = max(free_to[v, u], dmin + h * dd)


@njit(cache=True, nogil=True)
def _ensure_one(u, v, ga, gb, gs, direct, ncp, pint, dmin, dd, kfree, kpmin, kpmax, koff, kdims,
                rays, origins, kint, nk, kmemo, caps, ncaps, cap_lo, cap_hi, band, frame, pmemo, obits, cbits):
    """:func:`_ensure_pixel` as a call of its own, for the query's fill path (it meets a pixel
    to classify rarely: the cells were classified ahead)."""
    _ensure_pixel(u, v, ga, gb, gs, direct, ncp, pint, dmin, dd, kfree, kpmin, kpmax, koff, kdims,
                  rays, origins, kint, nk, kmemo, caps, ncaps, cap_lo, cap_hi, band, frame, pmemo, obits, cbits)


@njit(cache=True, inline="always")
def _lowest_stop(cbits, obits, v, u, lo, hi, with_obst):
    """Smallest slice in ``lo..hi`` (inside the bit words) whose ``cbits`` bit is clear or,
    with ``with_obst``, whose ``obits`` bit is set; -1 if none."""
    if lo > hi:
        return -1
    w = lo >> 6
    while w <= (hi >> 6):
        x = ~cbits[v, u, w]
        if with_obst:
            x = x | obits[v, u, w]
        x = x & _mask_range(w, lo, hi)
        if x != np.uint64(0):
            return w * 64 + _msb(x & (~x + _ONE))
        w += 1
    return -1


@njit(cache=True, parallel=True)  # no nogil: numba's launcher takes the GIL to start each prange region
# (numba/np/ufunc/parallel.py): called without the GIL, a call with k regions took it back 1 + 2k times, not k
def ensure_cells(model, fr, memo, points, n_points, rho, ws, span):
    """Lazy per-frame work (R12): classify every cell that a query of these points can
    look at — per pixel of each point's region of surveillance outside case 1, the
    slices within ``rho`` of the point (:func:`_needed_slices`) from ``r(df)`` on, inside
    the grid — unless already done this ``frame``. One parallel region over the image
    rows that the windows cover; a row (and so each pixel) belongs to one thread. Per
    pixel the points' slice ranges are merged first (``lo..hi`` from the smallest to the
    largest slice any point needs) and classified in one pass: long stretches let the
    pyramids settle many cells at once (R12 classes do not depend on the order).
    model, fr, memo : the grid's :class:`~depthguard.fusion.depth_grid_data.LazyModel`,
    :class:`~depthguard.fusion.depth_grid_data.LazyFrame` and
    :class:`~depthguard.fusion.depth_grid_data.LazyMemo` (the memo filled in place).
    points : (>= n_points, 3) float64 world m; rho : m.
    ws : (>= n_points, 10) float64 workspace (per point: px, py, dp, window, slices).
    span : (2, H, W) int32 workspace (per pixel: the merged range)."""
    pint, Rp, tp, dmin, dd, nd, koff, kdims, rays, origins, kint, nk = model
    pfree, pkind, tmin, kfree, kpmin, kpmax, caps, ncaps, cap_lo, cap_hi, cap_n, band = fr
    frame, stamp, obits, cbits, clear, free_to, kmemo = memo
    H = pfree.shape[0]
    W = pfree.shape[1]
    fx = pint[0]
    fy = pint[1]
    cx = pint[2]
    cy = pint[3]
    rmin = pint[6]
    rho2 = rho * rho
    vlo = H
    vhi = -1
    for i in range(n_points):
        X = points[i, 0]
        Y = points[i, 1]
        Z = points[i, 2]
        xc = Rp[0, 0] * X + Rp[0, 1] * Y + Rp[0, 2] * Z + tp[0]
        yc = Rp[1, 0] * X + Rp[1, 1] * Y + Rp[1, 2] * Z + tp[1]
        dp = Rp[2, 0] * X + Rp[2, 1] * Y + Rp[2, 2] * Z + tp[2]
        ws[i, 2] = dp
        if not dp > 0.0:
            ws[i, 5] = 1.0
            ws[i, 6] = 0.0
            continue
        ws[i, 0] = xc * fx / dp + cx
        ws[i, 1] = yc * fy / dp + cy
        u0, u1, v0, v1 = surveillance_window(xc, yc, dp, rho, fx, fy, cx, cy, rmin, W, H)
        ws[i, 3] = u0
        ws[i, 4] = u1
        ws[i, 5] = v0
        ws[i, 6] = v1
        ws[i, 7] = int(math.floor((dp - rho - dmin) / dd))
        ws[i, 8] = int(math.floor((dp + rho - dmin) / dd))
        if v0 <= v1:
            vlo = min(vlo, v0)
            vhi = max(vhi, v1)
    for v in prange(vlo, vhi + 1):
        ty = v // TILE
        ulo = W
        # int64, not the literal -1: typed as Literal[int](-1) on type inference's first pass, the
        # call below compiled _ensure_row_cells once more for that signature, never run (numba's
        # compile events named both; this kernel's compilation 53 -> 36 CPU-s, same answers)
        uhi = np.int64(-1)
        for i in range(n_points):
            if ws[i, 5] <= v and v <= ws[i, 6]:
                ulo = min(ulo, int(ws[i, 3]))
                uhi = max(uhi, int(ws[i, 4]))
        for u in range(ulo, uhi + 1):
            span[0, v, u] = nd
            span[1, v, u] = -1
        for i in range(n_points):
            if not (ws[i, 5] <= v and v <= ws[i, 6]):
                continue
            px = ws[i, 0]
            py = ws[i, 1]
            dp = ws[i, 2]
            u0 = int(ws[i, 3])
            u1 = int(ws[i, 4])
            g_lo = int(ws[i, 7])
            g_hi = int(ws[i, 8])
            far = dp + rho
            bx, by = _point_terms(px, py, dp, fx, fy, cx, cy)
            ay = _ray_x(py, v, cy, fy)
            for tx in range(u0 // TILE, u1 // TILE + 1):
                if tmin[ty, tx] > far:
                    continue
                for u in range(max(u0, tx * TILE), min(u1, tx * TILE + TILE - 1) + 1):
                    if pixel_free_to(stamp, free_to, pfree, frame, v, u) > far:
                        continue                                       # case 1 / known free
                    ga, gb = _needed_slices(_ray_x(px, u, cx, fx), ay, bx, by, dp, rho2, dmin, dd, g_lo, g_hi)
                    if ga > gb or (ga >= 0 and pixel_clear(stamp, clear, frame, v, u) >= gb):
                        continue                                       # too far / known free
                    gs, ncp = _col_setup(u, v, pfree, dmin, dd, nd, cap_n, ncaps)
                    gb = _surface_first(pkind[v, u] == KIND_SURFACE, gs, ncp, ga, min(gb, nd - 1),
                                        _ray_x(px, u, cx, fx), ay, bx, by, dp, dmin, dd)
                    ga = max(ga, gs, 0)
                    if ga <= gb:
                        span[0, v, u] = min(span[0, v, u], ga)
                        span[1, v, u] = max(span[1, v, u], gb)
        _ensure_row_cells(v, ulo, uhi, span, pfree, pkind, pint, dmin, dd, nd, kfree, kpmin, kpmax, koff, kdims,
                          rays, origins, kint, nk, kmemo, caps, ncaps, cap_lo, cap_hi, cap_n, band, frame, stamp,
                          obits, cbits, clear, free_to)


@njit(cache=True, nogil=True)
def _ensure_row_cells(v, ulo, uhi, span, pfree, pkind, pint, dmin, dd, nd, kfree, kpmin, kpmax, koff, kdims,
                      rays, origins, kint, nk, kmemo, caps, ncaps, cap_lo, cap_hi, cap_n, band, frame, stamp,
                      obits, cbits, clear, free_to):
    """Classify row ``v``'s merged slice ranges ``span[:, v, ulo..uhi]`` (:func:`ensure_cells`).
    One call per row (a prange body of its own): :func:`_ensure_pixel` is inlined here — a
    call per pixel passing some twenty arrays cost ~300 ns, more than a pixel whose cells
    are all memoised."""
    pmemo = (stamp, clear, free_to, pfree)
    for u in range(ulo, uhi + 1):
        ga = span[0, v, u]
        gb = span[1, v, u]
        if ga > gb or (stamp[v, u] == frame and _all_set(cbits, v, u, ga, gb)):
            continue
        gs, ncp = _col_setup(u, v, pfree, dmin, dd, nd, cap_n, ncaps)
        direct = pkind[v, u] == KIND_SURFACE
        _ensure_pixel(u, v, ga, gb, gs, direct, ncp, pint, dmin, dd, kfree, kpmin, kpmax, koff, kdims, rays,
                      origins, kint, nk, kmemo, caps, ncaps, cap_lo, cap_hi, band, frame, pmemo, obits, cbits)
