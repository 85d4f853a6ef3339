"""Small gaps of invalid pixels between measured ones (R28, R32): the fixed scene's edge dropout.

Depth sensors lose their return at depth edges (:mod:`depthguard.sources.noise`:
``edge_dropout``): a table's edge against the floor leaves a line of invalid
pixels one or two pixels wide. Under the safe invalid-pixel policy (R28: the ray
is unknown from ``min_range`` on, and unknown is an obstacle, R25) each of them
is an unknown ray from the camera on, and a robot control point near such a ray
sees a false obstacle (R32 forbids it: the robot alone in its cell must not see
itself nearer than it is to the fixed scene).

The rule (``gap_px = n``): an **invalid** pixel lying in a run of at most ``n``
invalid pixels along its row **or** its column, bounded at both ends by pixels
that returned a depth, is "free up to the nearer end's depth, unknown behind it"
(not from ``min_range``). An *end* is a pixel with a finite measurement ``m >=
min_range`` (and ``m > 0``); its depth is ``min(m, max_range)`` (a return beyond the
rated range says "free up to ``max_range``"). When both the row and the column
qualify, the nearer of the two is taken. A run that touches the image border is
not bounded. ``n = 0`` is off.

What the rule costs (R25): an object whose pixels are *all* invalid (dark clothing,
a black cable) and that is no wider than ``n`` pixels in some direction, in front of
the surfaces on both sides of it, is taken as free in front of those surfaces: it
can be missed. Its width is at most ``n d / f`` at depth ``d``:

==================  =======  =======  =======  =======
                     n = 2            n = 3
------------------  ----------------  ----------------
camera (f)           2 m      4 m      2 m      4 m
==================  =======  =======  =======  =======
Kinect v1 (585 px)  6.8 mm   13.7 mm  10.3 mm  20.5 mm
D435 640x480 (385)  10.4 mm  20.8 mm  15.6 mm  31.2 mm
==================  =======  =======  =======  =======

Anything wider keeps at least one invalid run longer than ``n`` across it and stays
unknown from ``min_range`` (R28) where it is wider; a dark person is a few hundred
pixels wide. The pixels of a dark object's own outline next to a measured surface
(its rim, up to ``n`` pixels) are taken as free up to that surface's depth when the
object is narrower than ``n`` there only.

:func:`gap_depth` is the allocation-free numba kernel (buffers passed in);
:func:`gap_depth_numpy` is its plain-numpy twin for the tests. Both the depth grid
(:func:`~depthguard.fusion.depth_grid_kernels.frame_state`) and the one-camera
distance (:func:`~depthguard.distance.kernels.obstacle_start_depth`) read its output.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from depthguard.camera import RETURN_LIMIT_FACTOR
__all__ = ["gap_depth", "gap_at", "gap_depth_numpy", "GapBuffers", "check_gap_px"]


def check_gap_px(gap_px) -> int:
    """``gap_px`` as an int >= 0 (pixels), or ValueError naming the problem."""
    if isinstance(gap_px, (bool, np.bool_)) or not isinstance(gap_px, (int, np.integer)):
        raise ValueError(f"gap_px must be an integer number of pixels >= 0 (got {gap_px!r})")
    n = int(gap_px)
    if n < 0:
        raise ValueError(f"gap_px must be >= 0 pixels (got {gap_px!r})")
    return n


@njit(cache=True, nogil=True, inline="always")
def _end_depth(m, min_range, max_range):
    """Depth of an end pixel (``min(m, max_range)``), or 0 when ``m`` is no return."""
    if m == m and m > 0.0 and m >= min_range and m <= RETURN_LIMIT_FACTOR * max_range:
        return m if m <= max_range else max_range
    return 0.0


@njit(cache=True, nogil=True, inline="always")
def gap_at(depth, v, u, min_range, max_range, n):
    """The small-gap rule at one pixel ``(v, u)`` of ``depth`` (H, W) m that is no end pixel
    (no return): the free depth (m) of :func:`gap_depth` there, 0 where the rule does not
    apply. It looks at most ``n + 1`` pixels each way along the pixel's row and column. The
    one statement of the rule, shared by :func:`gap_depth` and the fused state pass
    (:func:`~depthguard.fusion.depth_grid_state.frame_state_fused`), which calls it only at
    the invalid pixels that need it."""
    H, W = depth.shape
    best = np.inf
    # along the row: the nearest end on each side, at most n + 1 pixels away
    a = -1
    ea = 0.0
    for k in range(1, n + 1):
        uu = u - k
        if uu < 0:
            break
        e = _end_depth(np.float64(depth[v, uu]), min_range, max_range)
        if e > 0.0:
            a = uu
            ea = e
            break
    if a >= 0:
        for k in range(1, n + 1 - (u - a - 1)):
            uu = u + k
            if uu >= W:
                break
            e = _end_depth(np.float64(depth[v, uu]), min_range, max_range)
            if e > 0.0:
                best = min(ea, e)
                break
    # along the column
    a = -1
    for k in range(1, n + 1):
        vv = v - k
        if vv < 0:
            break
        e = _end_depth(np.float64(depth[vv, u]), min_range, max_range)
        if e > 0.0:
            a = vv
            ea = e
            break
    if a >= 0:
        for k in range(1, n + 1 - (v - a - 1)):
            vv = v + k
            if vv >= H:
                break
            e = _end_depth(np.float64(depth[vv, u]), min_range, max_range)
            if e > 0.0:
                best = min(best, min(ea, e))
                break
    return best if best < np.inf else 0.0


@njit(cache=True, parallel=True, nogil=True)
def gap_depth(depth, min_range, max_range, n, out):
    """Per pixel: the free depth the small-gap rule gives an invalid pixel, 0 where it does not
    apply (module docstring).

    depth : (H, W) float32/float64 metres as measured (0 / NaN / < min_range / inf = no return).
    min_range, max_range : the camera's rated range (m).
    n : int >= 0, the longest run of invalid pixels that counts as a gap (0: ``out`` all 0).
    out : (>= H, >= W) float64 written over ``[:H, :W]``: for an invalid pixel in a run of at
        most ``n`` invalid pixels along its row or column with end pixels on both sides, the
        smaller end depth (``min(m, max_range)``; the smaller of the row's and the column's when
        both qualify); 0 for every other pixel (valid pixels included).

    Per invalid pixel it looks at most ``n + 1`` pixels each way along its row and column; no
    allocation.
    """
    H, W = depth.shape
    if n <= 0:
        for v in prange(H):
            for u in range(W):
                out[v, u] = 0.0
        return
    for v in prange(H):                       # rows on the caller's numba threads; one pass
        for u in range(W):
            if _end_depth(np.float64(depth[v, u]), min_range, max_range) > 0.0:
                out[v, u] = 0.0
            else:
                out[v, u] = gap_at(depth, v, u, min_range, max_range, n)


def gap_depth_numpy(depth, min_range: float, max_range: float, n: int) -> np.ndarray:
    """Plain-numpy twin of :func:`gap_depth`: (H, W) float64, from the runs of invalid pixels
    of every row and column (found with ``np.diff``), 0 where the rule does not apply."""
    n = check_gap_px(n)
    d = np.asarray(depth, dtype=np.float64)
    H, W = d.shape
    with np.errstate(invalid="ignore"):
        end = np.isfinite(d) & (d > 0) & (d >= min_range) & (d <= RETURN_LIMIT_FACTOR * max_range)
    e = np.where(end, np.minimum(d, max_range), 0.0)
    best = np.full((H, W), np.inf)
    if n > 0:
        for mat_end, mat_e, view in ((end, e, best), (end.T, e.T, best.T)):
            for i in range(mat_end.shape[0]):
                inv = ~mat_end[i]
                # runs of invalid pixels: [s, t) from the rising / falling edges of the mask
                x = np.diff(np.r_[0, inv.astype(np.int8), 0])
                starts, stops = np.flatnonzero(x == 1), np.flatnonzero(x == -1)
                for s, t in zip(starts, stops):
                    if t - s <= n and s > 0 and t < len(inv):
                        view[i, s:t] = np.minimum(view[i, s:t], min(mat_e[i, s - 1], mat_e[i, t]))
    return np.where(np.isfinite(best), best, 0.0)


class GapBuffers:
    """The preallocated output of :func:`gap_depth` for images up to ``shape`` (H, W)."""

    def __init__(self, shape: tuple[int, int]):
        self.shape = (int(shape[0]), int(shape[1]))
        self._out = np.zeros(self.shape, np.float64)

    def gaps(self, depth: np.ndarray, min_range: float, max_range: float, n: int) -> np.ndarray:
        """(H, W) the gap depths of ``depth`` (a view of a reused buffer, overwritten by the next call)."""
        H, W = depth.shape
        if H > self.shape[0] or W > self.shape[1]:
            raise ValueError(f"depth image {W}x{H} exceeds the buffers {self.shape[1]}x{self.shape[0]}")
        if depth.dtype not in (np.float32, np.float64):
            depth = depth.astype(np.float64)
        gap_depth(depth, float(min_range), float(max_range), check_gap_px(n), self._out)
        return self._out[:H, :W]
