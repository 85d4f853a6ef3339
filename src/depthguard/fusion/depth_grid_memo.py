"""What each other camera clears, remembered for as long as that camera's frame (R12).

A gray cell of the principal grid (behind the measured surface, behind the
robot, or on an invalid ray) is an obstacle unless *some* other camera sees it
whole and free (R11, R12): ``obstacle = not (cleared_1 or cleared_2 or ...)``.
``cleared_k`` depends on camera ``k``'s frame and on the cameras' poses only —
not on the principal's frame, the robot's volume or the other cameras — so it
is kept per camera, per principal pixel, as bits, and stays valid until camera
``k`` loads a new frame. With cameras that are not synchronised, a build after a
principal frame reuses every other camera's bits, and a build after camera
``k``'s frame evaluates ``k`` only, and only for the cells no other camera
clears already (:func:`gray_stretch`).

The memo is the tuple ``kmemo = (kver, kstamp, kdone, kclr)``:

* ``kver`` (nk,) int64 — camera ``k``'s frame version (raised when it loads);
* ``kstamp`` (nk, H, W) int64 — the version a principal pixel's bits belong to
  (older bits are dropped on first touch, so a new frame costs no work here);
* ``kdone`` / ``kclr`` (nk, H, W, n_w) uint64 — bit ``g & 63`` of word
  ``g >> 6``: slice ``g`` of that column evaluated for camera ``k`` / cleared by it.

Each bit is exactly :func:`~depthguard.fusion.depth_grid_kernels.cell_cleared`
for that one camera on the cell ``[d_min + g delta_d, d_min + (g + 1) delta_d]`` (each
boundary one float, so neighbouring cells share its cross-section) (cell by cell, or a whole stretch at once where the
camera's min / max pyramids prove it cleared / confirmed, an exact shortcut),
so a cell's class equals the eager runs'
(:func:`~depthguard.fusion.depth_grid_eager.column_runs`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from depthguard.fusion.camera_views import camera_free, camera_pyramid
from depthguard.fusion.depth_grid_kernels import (_CX, _CY, _FX, _FY, _H, _W, _box_max, _box_min,
                                                  _cleared_by_sections, _section)

__all__ = ["new_memo", "gray_stretch", "mask_range", "msb"]

_ONE = np.uint64(1)
_ALL = np.uint64(0xFFFFFFFFFFFFFFFF)
_ZERO = np.uint64(0)


def new_memo(nk: int, height: int, width: int, n_words: int) -> tuple:
    """An empty memo for ``nk`` other cameras over an (H, W) principal with ``n_words``
    bit words per column (module docstring)."""
    n = max(int(nk), 1)
    return (np.zeros(n, dtype=np.int64), np.full((n, height, width), -1, dtype=np.int64),
            np.zeros((n, height, width, n_words), dtype=np.uint64),
            np.zeros((n, height, width, n_words), dtype=np.uint64))


@njit(cache=True, inline="always")
def mask_range(w, lo, hi):
    """Word ``w``'s bits of slices ``lo..hi`` (uint64)."""
    m = _ALL
    if (hi >> 6) == w and (hi & 63) < 63:
        m = m & ((_ONE << np.uint64((hi & 63) + 1)) - _ONE)
    if (lo >> 6) == w:
        m = m & (_ALL << np.uint64(lo & 63))
    return m


@njit(cache=True, inline="always")
def msb(x):
    """Index of the highest set bit of a non-zero uint64."""
    n = 0
    for s in (32, 16, 8, 4, 2, 1):
        y = x >> np.uint64(s)
        if y != _ZERO:
            x = y
            n += s
    return n


@njit(cache=True, inline="always")
def _lowest(x):
    """Index of the lowest set bit of a non-zero uint64."""
    return msb(x & (~x + _ONE))


@njit(cache=True, inline="always")
def _todo_word(obits, kdone, k, v, u, w, lo, hi):
    """Slices of word ``w`` in ``lo..hi`` still obstacle candidates and not evaluated for ``k``."""
    return obits[v, u, w] & ~kdone[k, v, u, w] & mask_range(w, lo, hi)


@njit(cache=True, nogil=True)
def _next_todo(obits, kdone, k, v, u, lo, hi):
    """First slice in ``lo..hi`` to evaluate for camera ``k`` and the last one of its run; (-1, -1): none."""
    w = lo >> 6
    while w <= (hi >> 6):
        x = _todo_word(obits, kdone, k, v, u, w, lo, hi)
        if x != _ZERO:
            a = w * 64 + _lowest(x)
            # the run ends before the first slice from a on that is not to do
            w2 = a >> 6
            while w2 <= (hi >> 6):
                y = ~_todo_word(obits, kdone, k, v, u, w2, lo, hi) & mask_range(w2, a, hi)
                if y != _ZERO:
                    return a, w2 * 64 + _lowest(y) - 1
                w2 += 1
            return a, hi
        w += 1
    return -1, -1


@njit(cache=True, inline="always")
def _range_sections(kpmin, kpmax, koff, kdims, kint, k, s1, s2):
    """Camera ``k`` alone on a piece of a column given by its near and far cross-sections
    (:func:`~depthguard.fusion.depth_grid_kernels._section`; the footprint is their union, the
    arithmetic of :func:`~depthguard.fusion.depth_grid_kernels.cell_footprint`): 1 = clears every
    cell in it, 2 = clears none (sees it whole, everything behind its free depth), 0 = unknown."""
    if not (s1[0] and s2[0]):
        return 0
    pumin = min(s1[1], s2[1])
    pumax = max(s1[2], s2[2])
    pvmin = min(s1[3], s2[3])
    pvmax = max(s1[4], s2[4])
    if not (pumin >= -0.5 and pumax < kint[k, _W] - 0.5 and pvmin >= -0.5 and pvmax < kint[k, _H] - 0.5):
        return 0
    u0 = int(math.floor(pumin + 0.5))
    u1 = int(math.floor(pumax + 0.5))
    v0 = int(math.floor(pvmin + 0.5))
    v1 = int(math.floor(pvmax + 0.5))
    if _box_min(camera_pyramid(kpmin, k), koff[k], kdims[k], u0, u1, v0, v1) > max(s1[6], s2[6]):
        return 1
    if _box_max(camera_pyramid(kpmax, k), koff[k], kdims[k], u0, u1, v0, v1) < min(s1[5], s2[5]):
        return 2
    return 0


# margins of :func:`_centre_blocks` (pixels, metres): far above the rounding of the projections
# (~1e-12 px, ~1e-15 m), so the centre's pixel and depth bound the corners' exactly
_PX_MARGIN = 1e-6
_Z_MARGIN = 1e-9


@njit(cache=True, inline="always")
def _centre_ray(rays, k, u, v):
    """Principal pixel ``(u, v)``'s centre ray in camera ``k``: the mean of its 4 corner rays
    ``rays[k, v:v+2, u:u+2]`` ((K, H+1, W+1, 3) float64, per metre of principal depth)."""
    rx = 0.25 * ((rays[k, v, u, 0] + rays[k, v, u + 1, 0]) + (rays[k, v + 1, u, 0] + rays[k, v + 1, u + 1, 0]))
    ry = 0.25 * ((rays[k, v, u, 1] + rays[k, v, u + 1, 1]) + (rays[k, v + 1, u, 1] + rays[k, v + 1, u + 1, 1]))
    rz = 0.25 * ((rays[k, v, u, 2] + rays[k, v, u + 1, 2]) + (rays[k, v + 1, u, 2] + rays[k, v + 1, u + 1, 2]))
    return rx, ry, rz


@njit(cache=True, inline="always")
def _centre_blocks_ray(kfree, origins, kint, k, rx, ry, rz, dc):
    """:func:`_centre_blocks` with the column's centre ray ``(rx, ry, rz)`` (:func:`_centre_ray`)
    given: :func:`_camera_stretch` takes it once per column, not once per cell."""
    Z = origins[k, 2] + dc * rz
    if not Z > _Z_MARGIN:
        return False
    pu = (origins[k, 0] + dc * rx) * kint[k, _FX] / Z + kint[k, _CX]
    pv = (origins[k, 1] + dc * ry) * kint[k, _FY] / Z + kint[k, _CY]
    fu = math.floor(pu + 0.5)
    fv = math.floor(pv + 0.5)
    if not (fu >= 0.0 and fu < kint[k, _W] and fv >= 0.0 and fv < kint[k, _H]):
        return False
    if abs(pu - fu) > 0.5 - _PX_MARGIN or abs(pv - fv) > 0.5 - _PX_MARGIN:
        return False
    return camera_free(kfree, k)[int(fv), int(fu)] <= Z - _Z_MARGIN


@njit(cache=True, inline="always")
def _centre_blocks(kfree, rays, origins, kint, k, u, v, dc):
    """Exact shortcut for a cell camera ``k`` does not clear (R12): the cell's centre (principal
    pixel ``(u, v)``'s centre ray at depth ``dc``, the mean of its 4 corner rays) projects into
    pixel ``(iu, iv)`` of ``k`` with depth ``zc``; when camera k's free depth there is <= ``zc``, that pixel —
    inside the cell's footprint, the centre being inside the cell — is not free beyond
    ``dend_k >= zc``, so :func:`~depthguard.fusion.depth_grid_kernels.cell_cleared` is False for
    ``k`` whether or not ``k`` sees the cell whole. One point projected instead of the cell's
    cross-sections; False = no conclusion (then the full rule). The margins keep the
    conclusion exact where the centre's pixel or depth sits within rounding of a bound."""
    rx, ry, rz = _centre_ray(rays, k, u, v)
    return _centre_blocks_ray(kfree, origins, kint, k, rx, ry, rz, dc)


@njit(cache=True, nogil=True)
def _camera_stretch(kfree, kpmin, kpmax, koff, kdims, rays, origins, kint, nk, k, u, v, g0, g1, dmin, dd,
                    kdone, kclr):
    """Evaluate ``cleared_k`` for slices ``g0..g1`` of column ``(u, v)`` and set their bits:
    stretches settled from camera ``k``'s pyramids where they can be (growing after a
    success, shrinking after a failure), the rest cell by cell — first by the cell's centre
    (:func:`_centre_blocks`, the column's centre ray taken once: most cells left to this are
    ones ``k`` does not clear), else by the cell's footprint. After a cell its centre settled,
    the next cells are tested by their centre before any stretch, until one it does not
    settle: on a run of cells ``k`` does not clear (the gray cells no camera clears, asked of a
    camera with a new frame) no stretch is re-tried every other cell. Every test is exact, so
    the bits are the same whichever settles a cell. Every piece is bounded by the cross-sections at ``dmin + g * dd``
    (one float per boundary ``g``), so a boundary's cross-section is projected once and shared
    by the pieces on both sides of it: 4 corners per cell or stretch test, not 8."""
    span_next = 64
    sec_g = g0 - 1          # the boundary whose cross-section ``sec`` holds (none yet)
    sec = (False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    rx, ry, rz = _centre_ray(rays, k, u, v)
    centre_first = False    # after a cell its centre settled: the centre before any stretch
    g = g0
    while g <= g1:
        w = g >> 6
        b = _ONE << np.uint64(g & 63)
        open_ = False       # the centre is known not to settle cell g
        if centre_first:
            if _centre_blocks_ray(kfree, origins, kint, k, rx, ry, rz, dmin + (g + 0.5) * dd):
                kdone[k, v, u, w] = kdone[k, v, u, w] | b      # not cleared by k (exact)
                g += 1
                continue
            centre_first = False
            open_ = True
        span = min(span_next, g1 - g + 1)
        if span > 1:
            if sec_g != g:
                sec = _section(rays, origins, kint, k, u, v, dmin + g * dd)
                sec_g = g
            far = _section(rays, origins, kint, k, u, v, dmin + (g + span) * dd)
            r = _range_sections(kpmin, kpmax, koff, kdims, kint, k, sec, far)
            if r != 0:
                h = g + span - 1
                for w in range(g >> 6, (h >> 6) + 1):
                    m = mask_range(w, g, h)
                    kdone[k, v, u, w] = kdone[k, v, u, w] | m
                    if r == 1:
                        kclr[k, v, u, w] = kclr[k, v, u, w] | m
                span_next = min(2 * span, 256)
                sec = far
                sec_g = h + 1
                g = h + 1
                continue
            span_next = max(span // 4, 1)
        else:
            span_next = min(span_next * 2, 8)
        kdone[k, v, u, w] = kdone[k, v, u, w] | b
        if not open_ and _centre_blocks_ray(kfree, origins, kint, k, rx, ry, rz, dmin + (g + 0.5) * dd):
            centre_first = True
        else:
            if sec_g != g:
                sec = _section(rays, origins, kint, k, u, v, dmin + g * dd)
            s2 = _section(rays, origins, kint, k, u, v, dmin + (g + 1) * dd)
            if _cleared_by_sections(kfree, kint, k, sec, s2):
                kclr[k, v, u, w] = kclr[k, v, u, w] | b
            sec = s2
            sec_g = g + 1
        g += 1


@njit(cache=True, inline="always")
def gray_stretch(u, v, g, e, kfree, kpmin, kpmax, koff, kdims, rays, origins, kint, nk, dmin, dd, kmemo,
                 obits, cbits):
    """Classify slices ``g..e`` of column ``(u, v)``, all gray cells (none in a robot capsule,
    none the measured surface, all inside the band and the grid, ``nk >= 1``): an obstacle
    unless another camera clears it (R12). Sets their ``cbits`` and, for the obstacles,
    ``obits``. First the cameras whose bits hold for their frame drop the cells they are
    known to clear (bit operations), then camera by camera only the cells that no camera
    cleared so far are looked at, from the memo where camera ``k`` already evaluated them
    for its frame (a camera with a new frame evaluates only what the others do not clear)."""
    kver, kstamp, kdone, kclr = kmemo
    for w in range(g >> 6, (e >> 6) + 1):
        m = mask_range(w, g, e)
        cbits[v, u, w] = cbits[v, u, w] | m
        obits[v, u, w] = obits[v, u, w] | m          # candidates; cleared ones are dropped below
    # first what the cameras whose bits hold for their frame clear already (bit operations
    # only), so that a camera that must evaluate (a new frame, or cells not yet asked of it)
    # looks only at the cells none of them clears; a cell's class is the same whatever order
    # the cameras are asked in (obstacle = not any cleared_k, each bit exact); one camera: the
    # loop below does the same
    for k in range(nk if nk > 1 else 0):
        if kstamp[k, v, u] == kver[k]:
            for w in range(g >> 6, (e >> 6) + 1):
                obits[v, u, w] = obits[v, u, w] & ~(kclr[k, v, u, w] & mask_range(w, g, e))
    for k in range(nk):
        if kstamp[k, v, u] != kver[k]:
            for w in range(kdone.shape[3]):
                kdone[k, v, u, w] = _ZERO
                kclr[k, v, u, w] = _ZERO
            kstamp[k, v, u] = kver[k]
        lo = g
        while lo <= e:
            a, b = _next_todo(obits, kdone, k, v, u, lo, e)
            if a < 0:
                break
            _camera_stretch(kfree, kpmin, kpmax, koff, kdims, rays, origins, kint, nk, k, u, v, a, b, dmin, dd,
                            kdone, kclr)
            lo = b + 1
        any_left = False
        for w in range(g >> 6, (e >> 6) + 1):
            x = obits[v, u, w] & ~(kclr[k, v, u, w] & mask_range(w, g, e))
            obits[v, u, w] = x
            if (x & mask_range(w, g, e)) != _ZERO:
                any_left = True
        if not any_left:
            return
