"""One camera's share of a depth grid build: its frame's per-pixel state (R9, R28, R32).

A depth grid build (:class:`~depthguard.fusion.depth_grid.DepthGridMap.set_frames`) starts
with each new frame's per-pixel state — the depth up to which each pixel's ray is free and
what the pixel is (a measured surface, the robot, unknown) — from that frame and the robot
rendered at its capture joints alone. Nothing of the other cameras or of the grid enters it,
so it can be worked out where the frame is, before the build: on the camera's own worker
thread (:class:`~depthguard.runtime.ingest.CameraWorker`), in parallel with the fusion of the
other cameras' frames. The build then copies it in (a memory copy) instead of working it
out, and works it out itself only when the state was made with other settings.

Use::

    options = StateOptions.of(config)                 # a MonitorConfig, or the five fields
    maker = StateMaker(camera)                        # per thread: scratch buffers
    state = maker.make(depth, robot_depth, options, robot_free=False)
    grid.set_frames(depths, robot_depths, ..., states={camera.id: state})
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from numba import njit, prange

from depthguard.camera import check_depth_image
from depthguard.distance.gaps import GapBuffers, check_gap_px
from depthguard.distance.silhouette import SilhouetteBuffers, check_silhouette_px
from depthguard.fusion.camera_views import readable
from depthguard.fusion.depth_grid_kernels import build_pyramids, frame_state, pixel_state
from depthguard.fusion.depth_grid_state_fused import frame_state_fused
from depthguard.fusion.free32 import FREE_DTYPE

__all__ = ["StateOptions", "CameraState", "StateMaker", "state_into", "pyramid_levels", "pyramid_layout",
           "bin_state", "bin_state_numpy", "state_pyramids", "frame_state_binned", "frame_state_fused",
           "state_into_unfused"]


def pyramid_levels(height: int, width: int) -> int:
    """Levels of the min / max pyramids of an (H, W) image: down to one pixel."""
    return max(1, int(math.ceil(math.log2(max(int(height), int(width), 1)))) + 1)


def pyramid_layout(height: int, width: int, levels: int) -> tuple[np.ndarray, np.ndarray, int]:
    """``(offsets (levels,), dims (levels, 2), size)``: where level ``l`` of a flat pyramid of an
    (H, W) image starts, its ``(h_l, w_l)``, and the flat length
    (:func:`~depthguard.fusion.depth_grid_kernels.build_pyramids`)."""
    dims = np.zeros((levels, 2), dtype=np.int64)
    offs = np.zeros(levels, dtype=np.int64)
    h, w, o = int(height), int(width), 0
    for lv in range(levels):
        dims[lv] = (h, w)
        offs[lv] = o
        o += h * w
        h, w = (h + 1) // 2, (w + 1) // 2
    return offs, dims, o


class StateOptions(NamedTuple):
    """The settings a frame's state depends on (R9, R28, R32): ``robot_offset`` (m),
    ``invalid`` (``"unknown"`` / ``"free"``), ``robot_in_others`` (``"unknown"`` / ``"free"``),
    ``silhouette_px`` and ``gap_px`` (pixels)."""
    robot_offset: float
    invalid: str
    robot_in_others: str
    silhouette_px: int
    gap_px: int

    @classmethod
    def of(cls, config) -> "StateOptions":
        """The options of a :class:`~depthguard.config.MonitorConfig`."""
        return cls(float(config.robot_offset), config.invalid, config.robot_in_others,
                   int(config.silhouette_px), int(config.gap_px))


class CameraState(NamedTuple):
    """A frame's per-pixel state (:func:`~depthguard.fusion.depth_grid_kernels.frame_state`):
    ``free`` (H, W) m, the depth up to which each ray is free (float64; float32 rounded down in a
    camera other than the principal made by :class:`StateMaker`, :mod:`~depthguard.fusion.free32`);
    ``kind`` (H, W) int8, ``KIND_SURFACE`` / ``KIND_ROBOT`` / ``KIND_UNKNOWN``; ``options`` and
    ``robot_free`` (a robot pixel confirms nothing: a non-principal camera with
    ``robot_in_others="free"``) as it was made with; for a camera that confirms the principal's
    cells, the min / max pyramids of ``free`` (flat, its dtype, :func:`pyramid_layout` with
    ``levels``), else None."""
    free: np.ndarray
    kind: np.ndarray
    options: StateOptions
    robot_free: bool
    pmin: np.ndarray | None = None
    pmax: np.ndarray | None = None
    levels: int = 0
    bin: int = 1


@njit(cache=True, parallel=True, nogil=True)
def bin_state(free, kind, b, out_free, out_kind):
    """A frame's state (``free`` (H, W) float64 m, ``kind`` (H, W) int8) at the principal's
    binned pixel (R10, ``principal_bin``): pixel ``(u, v)`` of ``out_*`` (``ceil(H / b)``,
    ``ceil(W / b)``) is the ``b x b`` block of pixels ``b v .. b v + b - 1`` x ``b u .. b u + b - 1``
    (those inside the image). Its free depth is the block's smallest — the block's frustum is
    free only up to where every pixel's ray is — and its kind that pixel's, the smallest kind
    where several share it, so ``KIND_SURFACE`` first (a measured return there is an obstacle
    without confirmation, R12 case 2; the other kinds leave the cell to the other cameras). Every cell
    the pixels' states make an obstacle lies in an obstacle cell of the block or in space no
    camera clears (the safe side); :func:`bin_state_numpy` is its twin."""
    H, W = free.shape
    hb = out_free.shape[0]
    wb = out_free.shape[1]
    if b == 2 and H % 2 == 0 and W % 2 == 0:
        for j in prange(hb):               # the common case, unrolled (4x faster)
            for i in range(wb):
                m = free[2 * j, 2 * i]
                k = kind[2 * j, 2 * i]
                for c in range(1, 4):
                    f = free[2 * j + (c >> 1), 2 * i + (c & 1)]
                    kk = kind[2 * j + (c >> 1), 2 * i + (c & 1)]
                    if f < m or (f == m and kk < k):
                        m = f
                        k = kk
                out_free[j, i] = m
                out_kind[j, i] = k
        return
    for j in prange(hb):
        v1 = min(H, j * b + b)
        for i in range(wb):
            u1 = min(W, i * b + b)
            m = np.inf
            k = np.int8(-1)
            for v in range(j * b, v1):
                for u in range(i * b, u1):
                    f = free[v, u]
                    if f < m or k < 0 or (f == m and kind[v, u] < k):
                        m = f
                        k = kind[v, u]
            out_free[j, i] = m
            out_kind[j, i] = k


@njit(cache=True, nogil=True)
def state_pyramids(free, H, W, pmin, pmax, offsets, dims, first):
    """:func:`~depthguard.fusion.depth_grid_kernels.build_pyramids` (the same arrays, bit for bit:
    level ``l`` >= 1 of ``pmin`` / ``pmax`` the min / max of the aligned ``2^l x 2^l`` blocks of
    ``free`` (H, W) float64 m, flat at ``offsets`` (levels,) with ``dims`` (levels, 2),
    :func:`pyramid_layout`; level 0 not written unless it is the only one) for the camera worker
    (R36, issue 29): a level's full pairs of columns in a loop over row views indexed from 0
    (LLVM vectorises it), the last column of an odd width after it. A min / max selects, and a
    state's free depth is never NaN: the order of the pairs does not change a bit. On the
    calling thread: a parallel loop per level (8-9 fork-joins) took 1.0-2.0 ms of wall time on
    two threads against 0.36-0.45 ms on one (ur3-cell builds, 2026-11-27). ``first`` (>= 1): the
    first level written: 1, or 2 where level 1 is there already, written with the state by
    :func:`~depthguard.fusion.depth_grid_state_fused.frame_state_fused` (no default: numba's disk
    cache crashed on a kernel with an omitted argument)."""
    nl = offsets.shape[0]
    if nl == 1:
        build_pyramids(free, H, W, pmin, pmax, offsets, dims)
        return
    for lv in range(max(first, 1), nl):
        hp = H if lv == 1 else dims[lv - 1, 0]
        wp = W if lv == 1 else dims[lv - 1, 1]
        hl = dims[lv, 0]
        wl = dims[lv, 1]
        op = offsets[lv - 1]
        ol = offsets[lv]
        half = wp // 2
        for v in range(hl):
            r0 = 2 * v
            r1 = min(2 * v + 1, hp - 1)
            if lv == 1:
                a = free[r0, :]
                b = free[r1, :]
                c = a
                d = b
            else:
                a = pmin[op + r0 * wp:op + r0 * wp + wp]
                b = pmin[op + r1 * wp:op + r1 * wp + wp]
                c = pmax[op + r0 * wp:op + r0 * wp + wp]
                d = pmax[op + r1 * wp:op + r1 * wp + wp]
            omin = pmin[ol + v * wl:ol + v * wl + wl]
            omax = pmax[ol + v * wl:ol + v * wl + wl]
            for u in range(half):
                omin[u] = min(min(a[2 * u], a[2 * u + 1]), min(b[2 * u], b[2 * u + 1]))
                omax[u] = max(max(c[2 * u], c[2 * u + 1]), max(d[2 * u], d[2 * u + 1]))
            if wl > half:                      # an odd width: the last column repeats itself
                omin[half] = min(a[wp - 1], b[wp - 1])
                omax[half] = max(c[wp - 1], d[wp - 1])


def bin_state_numpy(free: np.ndarray, kind: np.ndarray, b: int) -> tuple[np.ndarray, np.ndarray]:
    """The plain-numpy twin of :func:`bin_state`: ``(free, kind)`` of the binned pixels."""
    H, W = free.shape
    hb, wb = -(-H // b), -(-W // b)
    f = np.full((hb * b, wb * b), np.inf)
    f[:H, :W] = free
    k = np.full((hb * b, wb * b), 127, dtype=np.int16)
    k[:H, :W] = kind
    blocks_f = f.reshape(hb, b, wb, b).transpose(0, 2, 1, 3).reshape(hb, wb, b * b)
    blocks_k = k.reshape(hb, b, wb, b).transpose(0, 2, 1, 3).reshape(hb, wb, b * b)
    out_f = blocks_f.min(axis=2)
    at_min = (blocks_f == out_f[..., None]) & (blocks_k != 127)
    # the kind at the smallest free depth, the smallest kind (a surface first) where several share it
    rank = np.where(at_min, blocks_k, 1000)
    pick = np.take_along_axis(blocks_k, rank.argmin(axis=2)[..., None], axis=2)[..., 0]
    return out_f, pick.astype(np.int8)


@njit(cache=True, parallel=True, nogil=True)
def frame_state_binned(depth, robot_depth, use_robot, min_range, max_range, robot_offset, invalid_free, robot_free,
                       b, out_free, out_kind, silhouette=None, gap=None):
    """:func:`~depthguard.fusion.depth_grid_kernels.frame_state` and :func:`bin_state` in one
    pass (the same per-pixel rule, the same block rule; the full-resolution state is never
    written): ``out_*`` (``ceil(H / b)``, ``ceil(W / b)``)."""
    H, W = depth.shape
    hb = -(-H // b)                        # (not the buffer's shape: a wider one is written top-left only)
    wb = -(-W // b)
    if b == 2 and H % 2 == 0 and W % 2 == 0:
        for j in prange(hb):               # the common case, unrolled
            for i in range(wb):
                m, k = pixel_state(depth, robot_depth, use_robot, min_range, max_range, robot_offset,
                                   invalid_free, robot_free, silhouette, gap, 2 * j, 2 * i)
                for c in range(1, 4):
                    f, kk = pixel_state(depth, robot_depth, use_robot, min_range, max_range, robot_offset,
                                        invalid_free, robot_free, silhouette, gap, 2 * j + (c >> 1), 2 * i + (c & 1))
                    if f < m or (f == m and kk < k):
                        m = f
                        k = kk
                out_free[j, i] = m
                out_kind[j, i] = k
        return
    for j in prange(hb):
        v1 = min(H, j * b + b)
        for i in range(wb):
            u1 = min(W, i * b + b)
            m = np.inf
            k = -1
            for v in range(j * b, v1):
                for u in range(i * b, u1):
                    f, kk = pixel_state(depth, robot_depth, use_robot, min_range, max_range, robot_offset,
                                        invalid_free, robot_free, silhouette, gap, v, u)
                    if f < m or k < 0 or (f == m and kk < k):
                        m = f
                        k = kk
            out_free[j, i] = m
            out_kind[j, i] = k


def state_into(cam, depth, robot_depth, options: StateOptions, robot_free: bool, silhouette: SilhouetteBuffers,
               gaps: GapBuffers, out_free: np.ndarray, out_kind: np.ndarray, bin: int = 1,
               robot_spans: np.ndarray | None = None, level1=None) -> None:
    """Write the state of ``depth`` (H, W) m with the robot rendered as ``robot_depth`` (H, W) m
    (None: no robot) into ``out_free`` / ``out_kind`` (>= H, >= W; the top-left (H, W) is
    written; with ``bin > 1`` the binned state, :func:`frame_state_binned`, into the top-left
    ``(ceil(H / bin), ceil(W / bin))``); ``out_free`` float64, or float32 rounded down
    (:mod:`~depthguard.fusion.free32`). ``silhouette`` and ``gaps`` are scratch buffers of the
    calling thread (the fused pass uses the first's; the second is kept for
    :func:`state_into_unfused`). The one place that turns a frame into its state: the grid's own
    build and :class:`StateMaker` both call it (R9, R28, R32), in one pass over the image
    (:func:`~depthguard.fusion.depth_grid_state_fused.frame_state_fused`: the arrays of the
    unfused passes bit for bit, in about a third of their CPU on a 640x480 frame). ``robot_spans``
    (H, 2) int32 or None: per row ``[a, b)`` outside which ``robot_depth`` is 0 (the renderer's
    spans, as the camera worker keeps them): the robot's pixels are looked for there alone (the
    same arrays). ``level1``: ``(pmin, pmax, offset)`` flat float32 pyramids of the layout
    :func:`pyramid_layout` and where their level 1 starts: written with the state (``bin`` 1
    only; :func:`state_pyramids` with ``first=2`` then makes the levels above), or None."""
    d = check_depth_image(cam, depth)
    if d.dtype not in (np.float32, np.float64):
        d = d.astype(np.float64)
    use = robot_depth is not None
    if use:
        rd = check_depth_image(cam, robot_depth, name="robot_depth")
        if rd.dtype not in (np.float32, np.float64):
            rd = rd.astype(np.float64)
    else:
        rd = d                         # never read as a robot (one compiled signature per image dtype)
    consts = fused_constants(cam, options, robot_free, silhouette, rd.dtype, bin)
    if robot_spans is None:
        robot_spans = _whole_rows(d.shape)
    elif not (use and isinstance(robot_spans, np.ndarray) and robot_spans.shape == (d.shape[0], 2)
              and robot_spans.dtype == np.int32):
        raise ValueError(f"robot_spans must be ({d.shape[0]}, 2) int32 with a robot depth, "
                         f"got {getattr(robot_spans, 'shape', robot_spans)}")
    if out_free.dtype not in (np.float64, FREE_DTYPE):
        raise ValueError(f"out_free must be float64 or float32, got {out_free.dtype}")
    pmin, pmax, p1 = _NO_LEVEL1[int(out_free.dtype == FREE_DTYPE)] if level1 is None else level1
    if level1 is not None and not (consts[7] == 1 and 0 <= p1 and p1 + -(-d.shape[0] // 2) * -(-d.shape[1] // 2) <= pmin.size
                                   and pmin.shape == pmax.shape and readable(pmin) and readable(pmax)
                                   and out_free.dtype == FREE_DTYPE):
        raise ValueError("level1 must be (pmin, pmax, offset) of a float32 pyramid layout of the image, with a "
                         "float32 state at bin 1")
    run_fused(d, rd, use, consts, out_free, out_kind, robot_spans, pmin, pmax, int(p1))


def fused_constants(cam, options: StateOptions, robot_free: bool, silhouette: SilhouetteBuffers, dtype,
                    bin: int) -> tuple:
    """The arguments of :func:`frame_state_fused` that stay the same from frame to frame of one
    camera with one role: ``(min_range, max_range, robot_offset, invalid_free, robot_free,
    n_sil, n_gap, bin, tmp, masked, rows)`` — the options checked, the scratch ``silhouette``'s
    for a robot depth of ``dtype``. :func:`state_into` works them out per call;
    :class:`StateMaker` once per options and role (issue 29: per frame on the camera worker)."""
    n_sil = check_silhouette_px(options.silhouette_px)
    n_gap = check_gap_px(options.gap_px)
    tmp, masked, rows = silhouette.scratch(dtype, cam.shape)
    return (cam.min_range, cam.max_range, float(options.robot_offset), options.invalid == "free",
            bool(robot_free), n_sil, n_gap, max(int(bin), 1), tmp, masked, rows)


def run_fused(d, rd, use: bool, consts: tuple, out_free, out_kind, robot_spans, pmin, pmax, p1: int) -> None:
    """:func:`frame_state_fused` with :func:`fused_constants`' ``consts`` (arguments checked by the caller)."""
    mn, mx, offset, invalid_free, robot_free, n_sil, n_gap, b, tmp, masked, rows = consts
    frame_state_fused(d, rd, use, mn, mx, offset, invalid_free, robot_free, n_sil, n_gap, b, tmp, masked, rows,
                      out_free, out_kind, robot_spans, pmin, pmax, p1)


#: the image dtypes :class:`StateMaker` hands to the fused pass as they are
_FLOAT_DTYPES = (np.dtype(np.float32), np.dtype(np.float64))

#: ``level1`` of :func:`state_into` when no pyramid is written with the state
_NO_LEVEL1 = ((np.zeros(0), np.zeros(0), -1),                                       # a float64 state's
              (np.zeros(0, FREE_DTYPE), np.zeros(0, FREE_DTYPE), -1))                 # a float32 one's


#: (H, 2) int32 spans ``(0, W)`` per image shape: the whole of every row (one compiled signature
#: whether or not the caller knows where the robot depth is 0)
_WHOLE_ROWS: dict = {}


def _whole_rows(shape) -> np.ndarray:
    H, W = int(shape[0]), int(shape[1])
    spans = _WHOLE_ROWS.get((H, W))
    if spans is None:
        spans = np.zeros((H, 2), dtype=np.int32)
        spans[:, 1] = W
        _WHOLE_ROWS[(H, W)] = spans
    return spans


_ZEROS: dict = {}


def _zeros(shape, dtype) -> np.ndarray:
    """An (H, W) array of zeros of ``dtype``, made once per shape and dtype and shared: never written."""
    key = (tuple(shape), np.dtype(dtype).str)
    z = _ZEROS.get(key)
    if z is None:
        z = _ZEROS[key] = np.zeros(shape, dtype)
    return z


def state_into_unfused(cam, depth, robot_depth, options: StateOptions, robot_free: bool,
                       silhouette: SilhouetteBuffers, gaps: GapBuffers, out_free: np.ndarray, out_kind: np.ndarray,
                       bin: int = 1) -> None:
    """:func:`state_into` the way it was made before :func:`frame_state_fused`: the dilated robot
    depth and the small-gap depth as whole images
    (:func:`~depthguard.distance.silhouette.dilate_robot_depth`,
    :func:`~depthguard.distance.gaps.gap_depth`), then
    :func:`~depthguard.fusion.depth_grid_kernels.frame_state` or :func:`frame_state_binned` —
    the second implementation the tests and the bench (``share.state_cpu_ms``'s peer) hold the
    fused pass to (the same arrays, bit for bit)."""
    d = check_depth_image(cam, depth)
    use = robot_depth is not None
    rd = check_depth_image(cam, robot_depth, name="robot_depth") if use else np.zeros((1, 1), np.float32)
    invalid_free = options.invalid == "free"
    n_sil = check_silhouette_px(options.silhouette_px)
    n_gap = check_gap_px(options.gap_px)
    # a rule that is off reads zeros ("no robot nearby", "no gap": the kernels' meaning of 0), not
    # None: one compiled signature per kernel instead of four (~35 CPU-s on a fresh clone)
    sil = silhouette.dilate(rd, n_sil) if (use and n_sil > 0 and not invalid_free) else _zeros(d.shape, rd.dtype)
    gap = gaps.gaps(d, cam.min_range, cam.max_range, n_gap) if (n_gap > 0 and not invalid_free) else \
        _zeros(d.shape, np.float64)
    if int(bin) > 1:
        frame_state_binned(d, rd, use, cam.min_range, cam.max_range, float(options.robot_offset), invalid_free,
                           bool(robot_free), int(bin), out_free, out_kind, sil, gap)
        return
    frame_state(d, rd, use, cam.min_range, cam.max_range, float(options.robot_offset), invalid_free,
                bool(robot_free), out_free, out_kind, sil, gap)


class StateMaker:
    """Makes :class:`CameraState` of one camera's frames (R9, R28, R32), with scratch buffers of
    its own: one per thread that makes states."""

    def __init__(self, cam):
        self.camera = cam
        self._silhouette = SilhouetteBuffers(cam.shape)
        self._gaps = GapBuffers(cam.shape)
        self._pyr = None                   # pyramid_layout of the camera, made once
        self._shape = tuple(cam.shape)
        self._spans_shape = (self._shape[0], 2)
        self._levels = pyramid_levels(cam.height, cam.width)
        self._constants: dict = {}         # fused_constants by (options, robot_free, bin, robot depth dtype)
        self._layouts: dict = {}           # layout() by (pyramids, bin)

    def layout(self, pyramids: bool = False, bin: int = 1) -> tuple:
        """``((shape, dtype), ...)`` of the arrays :meth:`make` writes with these arguments:
        ``free`` float64 and ``kind`` int8 at the camera's pixel (or, ``bin > 1``, the binned
        one); with ``pyramids`` (a camera other than the principal) ``free`` float32 (rounded
        down, :mod:`~depthguard.fusion.free32`), ``kind`` and the flat ``pmin`` and ``pmax``
        float32 (:func:`pyramid_layout`) — the ``out`` a caller that reuses buffers passes in."""
        key = (bool(pyramids), max(int(bin), 1))
        out = self._layouts.get(key)            # made once per key (issue 29: asked twice a frame)
        if out is None:
            cam = self.camera
            b = key[1]
            shape = (-(-cam.height // b), -(-cam.width // b)) if b > 1 else tuple(cam.shape)
            if pyramids and b == 1:         # another camera's: float32, rounded down (free32)
                size = pyramid_layout(cam.height, cam.width, pyramid_levels(cam.height, cam.width))[2]
                out = ((shape, FREE_DTYPE), (shape, np.int8), ((size,), FREE_DTYPE), ((size,), FREE_DTYPE))
            else:
                out = ((shape, np.float64), (shape, np.int8))
            self._layouts[key] = out
        return out

    def make(self, depth, robot_depth, options: StateOptions, robot_free: bool = False,
             pyramids: bool = False, bin: int = 1, out=None, robot_spans=None) -> CameraState:
        """The state of one frame, in new arrays (the grid copies them in; the frame's product
        holds them) or in ``out`` (arrays of :meth:`layout`, e.g. from the worker's
        :class:`~depthguard.frame_pool.BufferPool`: every element is written); with
        ``pyramids`` (a camera other than the principal) its min / max pyramids too; with
        ``bin > 1`` (the principal of a grid with ``principal_bin``) at the binned pixel
        (:func:`bin_state`; no pyramids). ``robot_spans``: :func:`state_into`'s."""
        cam = self.camera
        b = max(int(bin), 1)
        if out is None:
            out = [np.empty(shape, dtype=dt) for shape, dt in self.layout(pyramids, b)]
        else:
            want = self.layout(pyramids, b)
            if len(out) != len(want) or any(a.shape != shape or a.dtype != dt or not a.flags.c_contiguous
                                             for a, (shape, dt) in zip(out, want)):
                raise ValueError(f"out must be C-contiguous arrays of {want}")
        free, kind = out[0], out[1]
        pyr = pyramids and b == 1
        levels = self._levels if pyr else 0
        if self._checked(depth, robot_depth, robot_spans):
            # a worker's frame (float arrays of the camera's shape, the renderer's spans): the
            # checks of state_into hold, its constants are made once per options and role
            key = (options, bool(robot_free), b, robot_depth.dtype)
            consts = self._constants.get(key)
            if consts is None:
                consts = self._constants[key] = fused_constants(cam, options, robot_free, self._silhouette,
                                                                robot_depth.dtype, b)
            if pyr and levels > 1:
                run_fused(depth, robot_depth, True, consts, free, kind, robot_spans, out[2], out[3],
                          int(self._pyramid_layout()[0][1]))
            else:
                run_fused(depth, robot_depth, True, consts, free, kind, robot_spans,
                          *_NO_LEVEL1[int(free.dtype == FREE_DTYPE)])
        elif pyr:
            # level 1 with the state, from each pair of rows as it is made; the levels above from it
            state_into(cam, depth, robot_depth, options, robot_free, self._silhouette, self._gaps, free, kind, 1,
                       robot_spans, level1=(out[2], out[3], int(self._pyramid_layout()[0][1])) if levels > 1 else None)
        else:
            state_into(cam, depth, robot_depth, options, robot_free, self._silhouette, self._gaps, free, kind, b,
                       robot_spans)
        if b > 1:
            return CameraState(free, kind, options, bool(robot_free), bin=b)
        if not pyramids:
            return CameraState(free, kind, options, bool(robot_free))
        offs, dims, _size = self._pyramid_layout()
        pmin, pmax = out[2], out[3]
        state_pyramids(free, cam.height, cam.width, pmin, pmax, offs, dims, 2 if levels > 1 else 1)
        return CameraState(free, kind, options, bool(robot_free), pmin, pmax, levels)

    def _checked(self, depth, robot_depth, robot_spans) -> bool:
        """``depth`` and ``robot_depth`` are float32 / float64 arrays of the camera's shape and
        ``robot_spans`` (H, 2) int32: what :func:`state_into` checks, in a few comparisons."""
        shape = self._shape
        return (type(depth) is np.ndarray and type(robot_depth) is np.ndarray and type(robot_spans) is np.ndarray
                and depth.shape == shape and robot_depth.shape == shape and depth.dtype in _FLOAT_DTYPES
                and robot_depth.dtype in _FLOAT_DTYPES and robot_spans.dtype == np.int32
                and robot_spans.shape == self._spans_shape)

    def _pyramid_layout(self):
        if self._pyr is None:
            cam = self.camera
            self._pyr = pyramid_layout(cam.height, cam.width, pyramid_levels(cam.height, cam.width))
        return self._pyr
