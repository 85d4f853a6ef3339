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
(R9: free up to the robot, unknown behind), ``max_range`` for a return beyond
the rated range and ``min_range`` for an invalid pixel (R28: unknown from the
near range on, so it never clears; :func:`frame_state` has the silhouette and
small-gap rules). A gray
cell of the principal is an obstacle unless some camera clears it, which is
the SPEC's "obstacle only if every camera that sees it confirms it"; a cell
that no other camera sees whole stays an obstacle.

This is stricter than the paper's test ``do_k < dstart_k`` at one pixel:
that test lets a cell through when ``k``'s measured surface lies *inside*
the cell (``dstart_k <= do_k <= dend_k``), or when only some of its pixels
see beyond it, and a real surface point can then be dropped. Requiring all
pixels and ``dend_k`` makes "not confirmed" mean "``k`` has seen all of it
free", so a cell holding a real obstacle point is never dropped.

The distances from the classified cells (R10, R7) are in
:mod:`depthguard.fusion.depth_grid_lookup`, the slices the robot can reach in
:mod:`depthguard.fusion.depth_grid_reach`; the plain-numpy twins in
:mod:`depthguard.fusion.depth_grid_ref`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from depthguard.camera import RETURN_LIMIT_FACTOR
from depthguard.distance.window import grow_pixel_box
from depthguard.fusion.camera_views import camera_free, camera_pyramid

__all__ = [
    "D_ZERO", "KIND_SURFACE", "KIND_ROBOT", "KIND_UNKNOWN", "METHOD_MIN", "METHOD_MEAN", "METHOD_HYBRID",
    "frame_state", "build_pyramids", "RUN_END", "TILE", "cell_footprint", "cell_cleared",
]

KIND_SURFACE, KIND_ROBOT, KIND_UNKNOWN = 0, 1, 2
METHOD_MIN, METHOD_MEAN, METHOD_HYBRID = 0, 1, 2

# intrinsics row of a camera in ``kint``: fx, fy, cx, cy, W, H, min_range, max_range
_FX, _FY, _CX, _CY, _W, _H, _RMIN, _RMAX = range(8)

# A distance at or below this (metres) is reported as 0 and carries no
# direction: the vector is rounding noise (P inside the cell's frustum).
D_ZERO = 1e-9


@njit(cache=True, parallel=True, nogil=True)
def frame_state(depth, robot_depth, use_robot, min_range, max_range, robot_offset,
                invalid_free, robot_free, out_free, out_kind, silhouette=None, gap=None):
    """Per-pixel state of one depth frame (R1, R9, R28, R32).

    depth : (H, W) float metres; valid in ``[min_range, max_range]``; a finite
        ``m > max_range`` is a return beyond the rated range; 0, NaN, inf or
        ``< min_range`` is invalid (no return).
    robot_depth : (H, W) float, the robot rendered into this camera (0 = none);
        read only when ``use_robot``. A valid pixel is the robot's where
        ``measured >= robot_depth - robot_offset`` (R9).
    invalid_free : the R28 policy. False (safe default): an invalid pixel's
        ray is unknown from ``min_range`` on, a return beyond the rated range is
        free up to ``max_range`` and unknown behind (``KIND_UNKNOWN`` both);
        True: both are free (nothing within the sensor's range, e.g. a simulated
        cell without walls).
    robot_free : False (R9): a robot pixel is free up to ``dr``, unknown behind;
        True (the paper's removal, for the non-principal cameras only): the
        pixel is no evidence of anything, its whole ray counts as free.
    out_free : (>= H, >= W) float64 written: the depth up to which the ray is
        free — ``do`` (surface), ``dr`` or ``+inf`` (robot), ``max_range`` (beyond
        the rated range), ``min_range`` (invalid), ``+inf`` (either, ``invalid_free``).
    out_kind : (>= H, >= W) int8 written: ``KIND_SURFACE`` (a measured surface,
        an obstacle without confirmation), ``KIND_ROBOT`` or ``KIND_UNKNOWN``.
    silhouette : None (default: off) or (H, W) float, the robot depth dilated by
        ``silhouette_px`` pixels (:func:`~depthguard.distance.silhouette.dilate_robot_depth`,
        0 = no robot nearby). An *invalid* pixel with
        ``drd = silhouette > 0`` (and ``invalid_free`` False) is ``KIND_ROBOT`` with
        free depth ``drd``: free up to the nearest robot surface around, unknown
        behind it (R9, R32). Also when ``robot_free``: such a pixel is only
        presumed to be the robot (nothing was measured), so it clears only the
        space in front of the robot. Valid and beyond-range pixels never read it.
    gap : None (default: off) or (H, W) float64, the small-gap depths
        (:func:`~depthguard.distance.gaps.gap_depth`, 0 = no gap). An invalid pixel
        outside the silhouette rule with ``g = gap > 0`` (and ``invalid_free`` False)
        is ``KIND_UNKNOWN`` with free depth ``g``: free up to the nearer end of its
        gap, unknown behind it.
    """
    H, W = depth.shape
    for v in prange(H):                       # rows on the caller's numba threads
        for u in range(W):
            f, k = pixel_state(depth, robot_depth, use_robot, min_range, max_range, robot_offset,
                               invalid_free, robot_free, silhouette, gap, v, u)
            out_free[v, u] = f
            out_kind[v, u] = k


@njit(cache=True, inline="always")
def pixel_state(depth, robot_depth, use_robot, min_range, max_range, robot_offset, invalid_free, robot_free,
                silhouette, gap, v, u):
    """``(free depth, kind)`` of pixel ``(v, u)``: the rule of :func:`frame_state`, stated once."""
    m = np.float64(depth[v, u])
    if not ((m == m) and m > 0.0 and m >= min_range and m <= max_range):
        if invalid_free:
            return np.inf, KIND_UNKNOWN
        if m > max_range and m <= RETURN_LIMIT_FACTOR * max_range:   # a return beyond the rated range
            return max_range, KIND_UNKNOWN
        if silhouette is not None:
            drd = np.float64(silhouette[v, u])
            if drd > 0.0:
                return drd, KIND_ROBOT
        if gap is not None:
            g = np.float64(gap[v, u])
            if g > 0.0:
                return g, KIND_UNKNOWN
        return min_range, KIND_UNKNOWN
    if use_robot:
        dr = np.float64(robot_depth[v, u])
        if dr > 0.0 and m >= dr - robot_offset:
            return (np.inf if robot_free else dr), KIND_ROBOT
    return m, KIND_SURFACE


@njit(cache=True, parallel=True, nogil=True)
def build_pyramids(free, H, W, pmin, pmax, offsets, dims):
    """Min- and max-pyramids of a free-depth image: level ``l`` holds the
    minimum (maximum) over aligned ``2^l x 2^l`` blocks. Level 0 (the image itself) is
    not written — :func:`_box_min` / :func:`_box_max` start at level 1 (a superset of a box
    bounds it as well), so a frame costs one read of ``free`` and a third of its size in
    writes — unless it is the only level (a 1 x 1 image).
    ``pmin`` / ``pmax`` are flat float64 buffers; level ``l`` (``dims[l] = (h_l, w_l)``)
    starts at ``offsets[l]``, row-major. Used only to skip work exactly: a box
    whose minimum free depth exceeds a depth is free up to it in every pixel;
    one whose maximum is below a depth is occupied or hidden before it in every pixel."""
    nl = offsets.shape[0]
    if nl == 1:
        for v in range(H):
            for u in range(W):
                pmin[offsets[0] + v * W + u] = free[v, u]
                pmax[offsets[0] + v * W + u] = free[v, u]
        return
    hl = dims[1, 0]
    wl = dims[1, 1]
    ol = offsets[1]
    for v in prange(hl):                      # level 1 from the image, rows on the caller's threads
        r0 = 2 * v
        r1 = min(2 * v + 1, H - 1)
        for u in range(wl):
            u0 = 2 * u
            u1 = min(2 * u + 1, W - 1)
            pmin[ol + v * wl + u] = min(min(free[r0, u0], free[r0, u1]), min(free[r1, u0], free[r1, u1]))
            pmax[ol + v * wl + u] = max(max(free[r0, u0], free[r0, u1]), max(free[r1, u0], free[r1, u1]))
    for lv in range(2, nl):
        hp = dims[lv - 1, 0]
        wp = dims[lv - 1, 1]
        hl = dims[lv, 0]
        wl = dims[lv, 1]
        op = offsets[lv - 1]
        ol = offsets[lv]
        # a block past the last row / column repeats it (min / max of an element twice: same result)
        for v in prange(hl):
            r0 = op + 2 * v * wp
            r1 = op + min(2 * v + 1, hp - 1) * wp
            for u in range(wl):
                u0 = 2 * u
                u1 = min(2 * u + 1, wp - 1)
                pmin[ol + v * wl + u] = min(min(pmin[r0 + u0], pmin[r0 + u1]), min(pmin[r1 + u0], pmin[r1 + u1]))
                pmax[ol + v * wl + u] = max(max(pmax[r0 + u0], pmax[r0 + u1]), max(pmax[r1 + u0], pmax[r1 + u1]))


@njit(cache=True, inline="always")
def _box_min(pyr, offsets, dims, u0, u1, v0, v1):
    """Lower bound of the free depth over pixels ``u0..u1 x v0..v1`` (inclusive):
    the minimum over the pyramid blocks covering the box (at most 2 x 2, from level 1 up:
    level 0 is not kept, :func:`build_pyramids`).
    With the max-pyramid and the comparison reversed, the upper bound."""
    nl = offsets.shape[0]
    lv = 1 if nl > 1 else 0
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


@njit(cache=True, inline="always")
def _box_max(pyr, offsets, dims, u0, u1, v0, v1):
    nl = offsets.shape[0]
    lv = 1 if nl > 1 else 0
    while lv < nl - 1 and ((u1 >> lv) - (u0 >> lv) > 1 or (v1 >> lv) - (v0 >> lv) > 1):
        lv += 1
    wl = dims[lv, 1]
    ol = offsets[lv]
    m = -np.inf
    for b in range(v0 >> lv, (v1 >> lv) + 1):
        for a in range(u0 >> lv, (u1 >> lv) + 1):
            x = pyr[ol + b * wl + a]
            if x > m:
                m = x
    return m


@njit(cache=True, nogil=True)
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
            pumin, pumax, pvmin, pvmax = grow_pixel_box(X, Y, Z, fx, fy, cx, cy, pumin, pumax, pvmin, pvmax)
    if not seen:
        return False, 0, -1, 0, -1, zmin, zmax
    if not (pumin >= -0.5 and pumax < W - 0.5 and pvmin >= -0.5 and pvmax < H - 0.5):
        return False, 0, -1, 0, -1, zmin, zmax
    u0 = int(math.floor(pumin + 0.5))
    u1 = int(math.floor(pumax + 0.5))
    v0 = int(math.floor(pvmin + 0.5))
    v1 = int(math.floor(pvmax + 0.5))
    return True, u0, u1, v0, v1, zmin, zmax


@njit(cache=True, nogil=True)
def cell_cleared(kfree, rays, origins, kint, nk, gx, gy, d1, d2):
    """True when some other camera clears the piece ``pixel (gx, gy) x [d1, d2]``:
    it sees it whole and every footprint pixel is free beyond ``dend_k``
    (module docstring). False = confirmed by every camera (an obstacle)."""
    for k in range(nk):
        seen, u0, u1, v0, v1, zmin, zmax = cell_footprint(rays, origins, kint, k, gx, gy, d1, d2)
        if not seen:
            continue
        ok = True
        free = camera_free(kfree, k)
        for v in range(v0, v1 + 1):
            for u in range(u0, u1 + 1):
                if not (free[v, u] > zmax):
                    ok = False
                    break
            if not ok:
                break
        if ok:
            return True
    return False


@njit(cache=True, nogil=True)
def _range_cleared(kpyr, koff, kdims, rays, origins, kint, nk, gx, gy, d1, d2):
    """Fast sufficient test that the whole piece ``[d1, d2]`` of a column is
    cleared by one camera, from the min-pyramid (a superset of the footprint).
    True implies :func:`cell_cleared` is True for every cell inside."""
    for k in range(nk):
        seen, u0, u1, v0, v1, zmin, zmax = cell_footprint(rays, origins, kint, k, gx, gy, d1, d2)
        if not seen:
            continue
        if _box_min(camera_pyramid(kpyr, k), koff[k], kdims[k], u0, u1, v0, v1) > zmax:
            return True
    return False


@njit(cache=True, nogil=True)
def _range_confirmed(kpmax, koff, kdims, rays, origins, kint, nk, gx, gy, d1, d2):
    """Fast sufficient test that every cell of the piece ``[d1, d2]`` of a column
    is confirmed by every other camera: each camera sees the piece whole and the
    largest free depth over its footprint is below the piece's ``dstart``.
    True implies :func:`cell_cleared` is False for every cell inside."""
    for k in range(nk):
        seen, u0, u1, v0, v1, zmin, zmax = cell_footprint(rays, origins, kint, k, gx, gy, d1, d2)
        if not seen:
            return False
        if not (_box_max(camera_pyramid(kpmax, k), koff[k], kdims[k], u0, u1, v0, v1) < zmin):
            return False
    return True


@njit(cache=True, nogil=True)
def _range_settled(kpmin, kpmax, koff, kdims, rays, origins, kint, nk, gx, gy, d1, d2):
    """:func:`_range_cleared` (1), else :func:`_range_confirmed` (2), else 0, computing
    each camera's footprint of the piece once."""
    conf = True
    for k in range(nk):
        seen, u0, u1, v0, v1, zmin, zmax = cell_footprint(rays, origins, kint, k, gx, gy, d1, d2)
        if not seen:
            conf = False
            continue
        if _box_min(camera_pyramid(kpmin, k), koff[k], kdims[k], u0, u1, v0, v1) > zmax:
            return 1
        if conf and not (_box_max(camera_pyramid(kpmax, k), koff[k], kdims[k], u0, u1, v0, v1) < zmin):
            conf = False
    return 2 if conf else 0


RUN_END = 1 << 30          # "to the end of the ray" in a run of cells
TILE = 8                   # principal pixels per tile side (query skips whole tiles)



@njit(cache=True, inline="always")
def _section(rays, origins, kint, k, gx, gy, d):
    """Camera ``k``'s view of the cross-section of principal pixel ``(gx, gy)``'s
    frustum at depth ``d`` (4 corners): ``(in_range, pumin, pumax, pvmin, pvmax,
    zmin, zmax)``, the same arithmetic as :func:`cell_footprint`."""
    fx = kint[k, _FX]
    fy = kint[k, _FY]
    cx = kint[k, _CX]
    cy = kint[k, _CY]
    rmin = kint[k, _RMIN]
    rmax = kint[k, _RMAX]
    pumin = np.inf
    pumax = -np.inf
    pvmin = np.inf
    pvmax = -np.inf
    zmin = np.inf
    zmax = -np.inf
    ok = True
    for j in range(4):
        a = gy + (j >> 1)
        b = gx + (j & 1)
        X = origins[k, 0] + d * rays[k, a, b, 0]
        Y = origins[k, 1] + d * rays[k, a, b, 1]
        Z = origins[k, 2] + d * rays[k, a, b, 2]
        if Z < zmin:
            zmin = Z
        if Z > zmax:
            zmax = Z
        if not (Z >= rmin and Z <= rmax):
            ok = False
            continue
        pumin, pumax, pvmin, pvmax = grow_pixel_box(X, Y, Z, fx, fy, cx, cy, pumin, pumax, pvmin, pvmax)
    return ok, pumin, pumax, pvmin, pvmax, zmin, zmax


@njit(cache=True, inline="always")
def _cleared_by_sections(kfree, kint, k, s1, s2):
    """:func:`cell_cleared` for one camera from the cell's two cross-sections."""
    if not (s1[0] and s2[0]):
        return False
    pumin = min(s1[1], s2[1])
    pumax = max(s1[2], s2[2])
    pvmin = min(s1[3], s2[3])
    pvmax = max(s1[4], s2[4])
    zmax = max(s1[6], s2[6])
    if not (pumin >= -0.5 and pumax < kint[k, _W] - 0.5 and pvmin >= -0.5 and pvmax < kint[k, _H] - 0.5):
        return False
    u0 = int(math.floor(pumin + 0.5))
    u1 = int(math.floor(pumax + 0.5))
    v0 = int(math.floor(pvmin + 0.5))
    v1 = int(math.floor(pvmax + 0.5))
    free = camera_free(kfree, k)
    for v in range(v0, v1 + 1):
        for u in range(u0, u1 + 1):
            if not (free[v, u] > zmax):
                return False
    return True


@njit(cache=True, inline="always")
def _confirmed_cell(kfree, rays, origins, kint, nk, u, v, g, d1, d2, sec, sec_g):
    """Is cell ``g`` (depths ``[d1, d2]`` with ``d1 = dmin + g * dd``, ``d2 = dmin + (g + 1) * dd``:
    one float per boundary, the lazy form's) of principal pixel ``(u, v)`` confirmed, i.e. not
    cleared by the other cameras (R12)? Returns ``(obstacle, sec, sec_g)``: with one other
    camera, consecutive cells share a cross-section, so the far one (``sec``, valid for cell
    ``sec_g``) is kept and only 4 corners are projected per cell, not 8."""
    if nk == 1:
        s1 = sec if sec_g == g else _section(rays, origins, kint, 0, u, v, d1)
        s2 = _section(rays, origins, kint, 0, u, v, d2)
        return not _cleared_by_sections(kfree, kint, 0, s1, s2), s2, g + 1
    return not cell_cleared(kfree, rays, origins, kint, nk, u, v, d1, d2), sec, sec_g
