"""A camera's share of the depth grid's clearing, made on the camera's own worker (issue 29, R11, R12).

A gray cell of the principal grid is an obstacle unless another camera clears it (R12), and
what camera ``k`` clears depends on camera ``k``'s frame alone
(:mod:`~depthguard.fusion.depth_grid_memo`). So the cells ``k`` clears can be worked out
where ``k``'s frame is, as soon as its per-pixel state is made — on the camera's worker
thread (:class:`~depthguard.runtime.ingest.CameraWorker`), beside the other cameras' workers —
rather than in the fusion's build that loads the frame. The work moves (about what the build
saves, per frame: 0.78 ms on the worker against 0.81 ms less in the build on flacco-cell, 0.95
against 1.1 on ur3-cell, one thread, 2026-11-27); the fusion's serial part, which every camera's
frame waits for, shrinks (the bench's build p50 with 2 cameras 3.66 -> 2.84 ms).

:func:`share_spec` takes from a :class:`~depthguard.fusion.depth_grid.DepthGridMap` what
camera ``k``'s clearing needs (the principal's pose and intrinsics, the slices, ``k``'s corner
rays and pyramid layout: read only, shared with the grid) as a :class:`ShareSpec`;
:class:`CameraSharer` (one per camera, its scratch reused) makes a :class:`CameraShare` from
``k``'s :class:`~depthguard.fusion.depth_grid_state.CameraState` for the cells of a request:
what the builds asked of camera ``k`` during an earlier frame of it (:func:`memo_request`,
:meth:`~depthguard.fusion.depth_grid.DepthGridMap.share_request`; the robot moves a frame or
two in between, the cells it needs hardly). A cell the share does not cover is evaluated by the
build as before. Cells chosen by geometry on the worker instead (around the control points at
the capture joints) were 2-3 times as many as the build asks for (the robot's own volume, the
cells other cameras clear): the worker then spent twice what the build saved.

Each bit is :func:`~depthguard.fusion.depth_grid_memo._camera_stretch`'s, the function the
build runs, on the same arrays the build loads (the state's own ``free`` and pyramids), so
the installed memo (:func:`install_share`, by
:meth:`~depthguard.fusion.depth_grid.DepthGridMap.set_frames`'s ``shares``) holds exactly the
bits the build would have worked out, and the distances are the same, cycle by cycle
(``tests/test_depth_grid_share.py``). A share is installed only into a grid whose tables it was
made with (``key``: the grid's map key, ``k`` and the pyramid levels) and only with the state
object it was made from.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from depthguard.fusion.camera_views import CameraViews, readable
from depthguard.fusion.depth_grid_memo import _camera_stretch, mask_range, msb
from depthguard.fusion.free32 import FREE_DTYPE

__all__ = ["ShareSpec", "CameraShare", "CameraSharer", "share_spec", "camera_share", "install_share",
           "memo_request"]

_ZERO = np.uint64(0)
_ALL = np.uint64(0xFFFFFFFFFFFFFFFF)
# what a sharer's views hold between shares
_NOTHING = (np.zeros((1, 1), FREE_DTYPE), np.zeros(1, FREE_DTYPE), np.zeros(1, FREE_DTYPE))


class ShareSpec(NamedTuple):
    """What camera ``k``'s clearing of a grid's cells needs (read-only views of the grid's tables)."""
    key: tuple            # (grid map key, k, pyramid levels): the grid these tables are of
    shape: tuple          # (H, W) the principal's (binned) image
    pint: np.ndarray      # (8,) float64 principal fx, fy, cx, cy, W, H, min range m, max range m
    Rp: np.ndarray        # (3, 3) float64 world -> principal rotation
    tp: np.ndarray        # (3,) float64 world -> principal translation, m
    dmin: float           # m, the first slice's near depth
    dd: float             # m, slice thickness
    nd: int               # slices
    nw: int               # bit words per column, ceil(nd / 64)
    koff: np.ndarray      # (1, levels) int64 camera k's pyramid level offsets
    kdims: np.ndarray     # (1, levels, 2) int64 its level sizes
    rays: np.ndarray      # (1, H+1, W+1, 3) float64 principal pixel-corner rays in camera k
    origins: np.ndarray   # (1, 3) float64 the principal's centre in camera k, m
    kint: np.ndarray      # (1, 8) float64 camera k's intrinsics row
    levels: int           # pyramid levels the grid reads


class CameraShare(NamedTuple):
    """Camera ``k``'s clearing bits for ``M`` principal columns, made from ``state``."""
    key: tuple            # ShareSpec.key
    state: object         # the CameraState the bits were made from (installed only with it)
    idx: np.ndarray       # (M,) int64 principal pixel v * W + u
    done: np.ndarray      # (M, nw) uint64 slices evaluated (bit g & 63 of word g >> 6)
    clr: np.ndarray       # (M, nw) uint64 ... of them, cleared by camera k


def share_spec(grid, camera_id: str) -> ShareSpec | None:
    """The :class:`ShareSpec` of camera ``camera_id`` in ``grid`` (a
    :class:`~depthguard.fusion.depth_grid.DepthGridMap`); None when it is the principal or not in it."""
    ids = [c.id for c in grid.others]
    if camera_id not in ids:
        return None
    k = ids.index(camera_id)
    P = grid.principal
    levels = int(grid._koff.shape[1])
    return ShareSpec((grid.key, k, levels), (P.height, P.width), grid._pint, grid._Rp, grid._tp,
                     float(grid.d_min), float(grid.delta_d), int(grid.n_d), int((grid.n_d + 63) // 64),
                     grid._koff[k:k + 1], grid._kdims[k:k + 1], grid.rays[k:k + 1], grid.origins[k:k + 1],
                     grid._kint[k:k + 1], levels)


@njit(cache=True, inline="always")
def _next_bit(bits, i, g, nw, clear):
    """The first slice from ``g`` on whose bit in ``bits[i]`` (nw words) is set (``clear``: not set);
    -1 if none."""
    w = g >> 6
    x = ~bits[i, w] if clear else bits[i, w]
    x = x & (_ALL << np.uint64(g & 63))
    while x == _ZERO:
        w += 1
        if w >= nw:
            return -1
        x = ~bits[i, w] if clear else bits[i, w]
    return w * 64 + msb(x & (~x + np.uint64(1)))


@njit(cache=True, nogil=True)
def camera_share(idx, want, W, dmin, dd, kfree, kpmin, kpmax, koff, kdims, rays, origins, kint, kdone, kclr):
    """Camera ``k``'s clearing (the build's own :func:`_camera_stretch`, run by run) of the cells
    ``want`` (M, nw) uint64 of the principal columns ``idx`` (M,) int64 (``v * W + u``): the
    returned ``(done, clr)`` (M, nw) uint64 hold, for every wanted cell, ``done`` set and ``clr``
    = cleared by camera k. ``kfree`` (1, 3), ``kpmin`` / ``kpmax`` (1, 2) int64: camera k's
    state's arrays (:class:`~depthguard.fusion.camera_views.CameraViews`' tables); ``koff``,
    ``kdims``, ``rays``, ``origins``, ``kint``: its rows of the grid's tables (:class:`ShareSpec`).
    Scratch: ``kdone`` / ``kclr`` (1, H, W, nw) uint64, zero on entry and on return. Without the
    GIL: about a millisecond, beside the other threads."""
    m = idx.shape[0]
    nw = want.shape[1]
    done = np.empty((m, nw), dtype=np.uint64)
    clr = np.empty((m, nw), dtype=np.uint64)
    for i in range(m):
        v = idx[i] // W
        u = idx[i] - v * W
        g = _next_bit(want, i, 0, nw, False)
        while g >= 0:                       # each run of wanted slices g..e
            e = _next_bit(want, i, g, nw, True)
            e = nw * 64 - 1 if e < 0 else e - 1
            _camera_stretch(kfree, kpmin, kpmax, koff, kdims, rays, origins, kint, 1, 0, u, v, g, e, dmin, dd,
                            kdone, kclr)
            g = _next_bit(want, i, e + 1, nw, False) if e + 1 < nw * 64 else -1
        for w in range(nw):
            done[i, w] = kdone[0, v, u, w]
            clr[i, w] = kclr[0, v, u, w]
            kdone[0, v, u, w] = _ZERO
            kclr[0, v, u, w] = _ZERO
    return done, clr


@njit(cache=True)   # tens of microseconds: keeps the GIL
def memo_request(kstamp, kdone, k, ver, stamp, frame, span):
    """What the grid's builds asked of camera ``k`` during its frame version ``ver``, as the next
    share's request: per principal column touched by the last build's classification
    (``stamp`` (H, W) int64 == ``frame``) whose camera-``k`` memo is of ``ver`` (``kstamp`` (K, H, W)
    int64), the slices evaluated (``kdone`` (K, H, W, nw) uint64) within that build's merged
    range ``span`` (2, H, W) int32 (the slices it needed there). Returns ``(idx (M,) int64
    v * W + u, want (M, nw) uint64)``; columns with nothing left are dropped."""
    H = kstamp.shape[1]
    W = kstamp.shape[2]
    nw = kdone.shape[3]
    m = 0
    for v in range(H):
        for u in range(W):
            if kstamp[k, v, u] == ver and stamp[v, u] == frame and span[0, v, u] <= span[1, v, u]:
                m += 1
    idx = np.empty(m, dtype=np.int64)
    want = np.empty((m, nw), dtype=np.uint64)
    j = 0
    for v in range(H):
        for u in range(W):
            if kstamp[k, v, u] == ver and stamp[v, u] == frame and span[0, v, u] <= span[1, v, u]:
                lo = max(span[0, v, u], 0)
                hi = min(span[1, v, u], nw * 64 - 1)
                any_ = False
                for w in range(nw):
                    x = kdone[k, v, u, w] & mask_range(w, lo, hi) if (lo >> 6) <= w <= (hi >> 6) else _ZERO
                    want[j, w] = x
                    any_ = any_ or x != _ZERO
                if any_:
                    idx[j] = v * W + u
                    j += 1
    return idx[:j], want[:j]


@njit(cache=True)   # microseconds: keeps the GIL
def install_share(kstamp, kdone, kclr, k, ver, idx, done, clr, W):
    """Camera ``k``'s memo (:mod:`~depthguard.fusion.depth_grid_memo`, ``kstamp`` (K, H, W) int64,
    ``kdone`` / ``kclr`` (K, H, W, nw) uint64) for its frame version ``ver``: the share's columns
    ``idx`` (M,) (``v * W + u``) get its ``done`` / ``clr`` words (M, nw) and the stamp ``ver``."""
    for i in range(idx.shape[0]):
        v = idx[i] // W
        u = idx[i] - v * W
        kstamp[k, v, u] = ver
        for w in range(done.shape[1]):
            kdone[k, v, u, w] = done[i, w]
            kclr[k, v, u, w] = clr[i, w]


class CameraSharer:
    """Makes one camera's :class:`CameraShare` s (module docstring), its scratch kept between frames."""

    def __init__(self):
        self._scratch_key = None
        self._kdone = self._kclr = None
        self._views = CameraViews(1)   # the state's arrays as the kernels read them
        self.made = 0             # shares made

    def make(self, spec: ShareSpec, state, request) -> CameraShare | None:
        """Camera k's share from its ``state`` (a CameraState with pyramids at ``spec.levels``) for
        the cells ``request`` = ``(idx (M,), want (M, nw))`` (the grid's
        :meth:`~depthguard.fusion.depth_grid.DepthGridMap.share_request`: what the builds asked
        of camera k during an earlier frame of it). None when the state does not fit the spec, its
        arrays cannot be read in place (then the build works its clearing out) or nothing is asked."""
        if (state is None or state.pmin is None or state.levels != spec.levels or state.bin != 1
                or request is None or not len(request[0])
                or not (readable(state.free) and readable(state.pmin) and readable(state.pmax))):
            return None
        H, W = spec.shape
        if self._scratch_key != (H, W, spec.nw):
            self._kdone = np.zeros((1, H, W, spec.nw), dtype=np.uint64)
            self._kclr = np.zeros((1, H, W, spec.nw), dtype=np.uint64)
            self._scratch_key = (H, W, spec.nw)
        idx, want = request
        views = self._views
        views.point(0, state.free, state.pmin, state.pmax)
        try:
            done, clr = camera_share(idx, want, W, spec.dmin, spec.dd, views.free, views.pmin, views.pmax,
                                     spec.koff, spec.kdims, spec.rays, spec.origins, spec.kint,
                                     self._kdone, self._kclr)
        finally:
            views.point(0, *_NOTHING)     # the state is not held beyond its share
        self.made += 1
        return CameraShare(spec.key, state, idx, done, clr)
