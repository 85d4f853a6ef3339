"""The robot's silhouette grown by a few pixels, for invalid pixels at its edge (R9, R28, R32).

Depth sensors lose their return at depth edges (:mod:`depthguard.sources.noise`:
``edge_dropout``), and the robot's own outline is such an edge. Under the safe
invalid-pixel policy (R28: the ray is unknown from ``min_range`` on, and unknown
is an obstacle, R25) that ring of dropout makes the robot see itself a few
centimetres away, which R32 forbids ("the robot alone in its cell, with realistic
dropout, must not see itself").

The rule (``silhouette_px = n``): an **invalid** pixel within ``n`` pixels
(Chebyshev distance, the ``(2n+1) x (2n+1)`` window) of a pixel where the robot is
rendered takes the robot's R9 meaning with the *smallest* robot depth of that
window, ``drd`` — free up to ``drd``, unknown behind it (the safe side: the
nearest robot surface around). Valid pixels are untouched (they keep the
undilated robot depth and the test ``measured >= dr - offset``).

What the rule costs (R25): an obstacle whose pixels are all invalid (a person in
dark clothing) keeps every pixel farther than ``n`` pixels from the robot's
silhouette as unknown-from-``min_range``; only the ring of width ``n`` next to the
robot, in front of ``drd``, is taken as free. Its reported distance can grow by at
most the footprint of ``n`` pixels at its depth (``n d / f``; 4 px at 2 m with
f = 585 px: 1.4 cm). Behind ``drd`` the ray stays unknown, and in the depth grid
(R12) the other cameras must clear those cells as for any robot pixel.

:func:`dilate_robot_depth` is the allocation-free numba kernel (buffers passed
in); :func:`dilate_robot_depth_numpy` is its plain-numpy twin for the tests.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["dilate_robot_depth", "dilate_robot_depth_numpy", "SilhouetteBuffers", "check_silhouette_px"]


def check_silhouette_px(silhouette_px) -> int:
    """``silhouette_px`` as an int >= 0 (pixels), or ValueError naming the problem."""
    if isinstance(silhouette_px, (bool, np.bool_)) or not isinstance(silhouette_px, (int, np.integer)):
        raise ValueError(f"silhouette_px must be an integer number of pixels >= 0 (got {silhouette_px!r})")
    n = int(silhouette_px)
    if n < 0:
        raise ValueError(f"silhouette_px must be >= 0 pixels (got {silhouette_px!r})")
    return n


@njit(cache=True, nogil=True)
def dilate_robot_depth(robot_depth, n, tmp, out):
    """Robot depth image grown by ``n`` pixels: per pixel the smallest *positive*
    robot depth within the ``(2n+1) x (2n+1)`` window around it (clipped at the
    image border), 0 where the window holds no robot pixel (R9, R32).

    robot_depth : (H, W) float32/float64 metres, the robot rendered into the camera
        (0 = no robot; NaN and values <= 0 count as no robot).
    n : int >= 0, the half width of the window in pixels; ``n = 0`` copies the
        positive depths (0 elsewhere).
    tmp : (>= H, >= W) float scratch (the row pass), the dtype of ``out``.
    out : (>= H, >= W) float written over ``[:H, :W]``: the dilated depth, metres.
        With float32 buffers and a float32 ``robot_depth`` the values are exact
        copies of robot depths (a min selects, it does not round).

    Separable: a min over each row's window, then over each column's; both passes
    work only inside the bounding box of the robot pixels grown by ``n`` (the rest
    of ``out`` is set to 0), so an image with a small robot costs little more than
    one read of it. No allocation.
    """
    H, W = robot_depth.shape
    inf = out.dtype.type(np.inf)
    zero = out.dtype.type(0.0)
    # bounding box of the robot pixels
    v0 = H
    v1 = -1
    u0 = W
    u1 = -1
    for v in range(H):
        row = robot_depth[v]
        a = -1
        for u in range(W):
            if row[u] > 0.0:
                a = u
                break
        if a < 0:
            continue
        b = a
        for u in range(W - 1, a, -1):
            if row[u] > 0.0:
                b = u
                break
        if v0 == H:
            v0 = v
        v1 = v
        u0 = min(u0, a)
        u1 = max(u1, b)
    if v1 < 0:
        for v in range(H):
            orow = out[v]
            for u in range(W):
                orow[u] = zero
        return
    ga = max(v0 - n, 0)
    gb = min(v1 + n, H - 1)
    ua = max(u0 - n, 0)
    ub = min(u1 + n, W - 1)
    L = ub - ua + 1
    # (the loops index row views from 0 so that LLVM vectorises them: no negative-index checks)
    # rows v0..v1 of out <- the robot depths over ua..ub, +inf for "no robot" (branch-free mins below)
    for v in range(v0, v1 + 1):
        src = robot_depth[v, ua:ub + 1]
        orow = out[v, ua:ub + 1]
        for i in range(L):
            x = src[i]
            orow[i] = x if x > 0.0 else inf
    # row pass: tmp[v, u] = min of out[v, u-n..u+n] (clipped to ua..ub; outside it nothing is positive)
    for v in range(v0, v1 + 1):
        orow = out[v, ua:ub + 1]
        trow = tmp[v, ua:ub + 1]
        for i in range(L):
            trow[i] = orow[i]
        for k in range(1, min(n, L - 1) + 1):
            ahead = orow[k:]
            tk = trow[k:]
            for i in range(L - k):
                x = ahead[i]
                trow[i] = x if x < trow[i] else trow[i]
            for i in range(L - k):
                x = orow[i]
                tk[i] = x if x < tk[i] else tk[i]
    # column pass: out[v, u] = min of tmp[v-n..v+n, u] over the robot's rows v0..v1
    for v in range(H):
        if v < ga or v > gb:
            orow = out[v]
            for u in range(W):
                orow[u] = zero
            continue
        for u in range(0, ua):
            out[v, u] = zero
        for u in range(ub + 1, W):
            out[v, u] = zero
        ra = max(v - n, v0)
        rb = min(v + n, v1)
        orow = out[v, ua:ub + 1]
        t0 = tmp[ra, ua:ub + 1]
        for i in range(L):
            orow[i] = t0[i]
        for r in range(ra + 1, rb + 1):
            trow = tmp[r, ua:ub + 1]
            for i in range(L):
                x = trow[i]
                orow[i] = x if x < orow[i] else orow[i]
        for i in range(L):
            x = orow[i]
            orow[i] = zero if x == inf else x


def dilate_robot_depth_numpy(robot_depth, n: int) -> np.ndarray:
    """Plain-numpy twin of :func:`dilate_robot_depth`: (H, W) float64, the smallest
    positive robot depth within Chebyshev distance ``n`` of each pixel, 0 where none."""
    rd = np.asarray(robot_depth, dtype=np.float64)
    n = check_silhouette_px(n)
    H, W = rd.shape
    pos = np.where(rd > 0, rd, np.inf)          # NaN > 0 is False: no robot
    pad = np.full((H + 2 * n, W + 2 * n), np.inf)
    pad[n:n + H, n:n + W] = pos
    best = np.full((H, W), np.inf)
    for dv in range(2 * n + 1):
        for du in range(2 * n + 1):
            best = np.minimum(best, pad[dv:dv + H, du:du + W])
    return np.where(np.isfinite(best), best, 0.0)


class SilhouetteBuffers:
    """Preallocated scratch and output of :func:`dilate_robot_depth` for images up to
    ``shape`` (H, W); one pair per robot-depth dtype (float32 renders stay float32, so
    the dilated depths are exact copies of rendered ones), made on first use."""

    def __init__(self, shape: tuple[int, int]):
        self.shape = (int(shape[0]), int(shape[1]))
        self._buffers: dict = {}
        self._rows = None

    def dilate(self, robot_depth: np.ndarray, n: int) -> np.ndarray:
        """(H, W) the robot depth dilated by ``n`` pixels (a view of a reused buffer,
        overwritten by the next call with the same dtype)."""
        H, W = robot_depth.shape
        if H > self.shape[0] or W > self.shape[1]:
            raise ValueError(f"robot depth image {W}x{H} exceeds the buffers {self.shape[1]}x{self.shape[0]}")
        dt = np.float32 if robot_depth.dtype == np.float32 else np.float64
        bufs = self._buffers.get(dt)
        if bufs is None:
            bufs = self._buffers[dt] = (np.zeros(self.shape, dt), np.zeros(self.shape, dt))
        if robot_depth.dtype not in (np.float32, np.float64):
            robot_depth = robot_depth.astype(np.float64)
        dilate_robot_depth(robot_depth, check_silhouette_px(n), bufs[0], bufs[1])
        return bufs[1][:H, :W]

    def scratch(self, dtype, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(tmp, masked, rows)``: the scratch of the fused state pass
        (:func:`~depthguard.fusion.depth_grid_state.frame_state_fused`) for an image of ``shape``
        — the two buffers of :meth:`dilate` of ``dtype`` (>= H, >= W) and (>= H, 2) int64 —
        reused from call to call."""
        H, W = int(shape[0]), int(shape[1])
        if H > self.shape[0] or W > self.shape[1]:
            raise ValueError(f"image {W}x{H} exceeds the buffers {self.shape[1]}x{self.shape[0]}")
        dt = np.dtype(dtype).type
        bufs = self._buffers.get(dt)
        if bufs is None:
            bufs = self._buffers[dt] = (np.zeros(self.shape, dt), np.zeros(self.shape, dt))
        if self._rows is None:
            self._rows = np.zeros((self.shape[0], 2), np.int64)
        return bufs[0], bufs[1], self._rows
