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

from depthguard.camera import check_depth_image
from depthguard.distance.gaps import GapBuffers, check_gap_px
from depthguard.distance.silhouette import SilhouetteBuffers, check_silhouette_px
from depthguard.fusion.depth_grid_kernels import build_pyramids, frame_state

__all__ = ["StateOptions", "CameraState", "StateMaker", "state_into", "pyramid_levels", "pyramid_layout"]


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
    ``free`` (H, W) float64 m, the depth up to which each ray is free; ``kind`` (H, W) int8,
    ``KIND_SURFACE`` / ``KIND_ROBOT`` / ``KIND_UNKNOWN``; ``options`` and ``robot_free`` (a
    robot pixel confirms nothing: a non-principal camera with ``robot_in_others="free"``) as
    it was made with; for a camera that confirms the principal's cells, the min / max pyramids
    of ``free`` (flat float64, :func:`pyramid_layout` with ``levels``), else None."""
    free: np.ndarray
    kind: np.ndarray
    options: StateOptions
    robot_free: bool
    pmin: np.ndarray | None = None
    pmax: np.ndarray | None = None
    levels: int = 0


def state_into(cam, depth, robot_depth, options: StateOptions, robot_free: bool, silhouette: SilhouetteBuffers,
               gaps: GapBuffers, out_free: np.ndarray, out_kind: np.ndarray) -> None:
    """Write the state of ``depth`` (H, W) m with the robot rendered as ``robot_depth`` (H, W) m
    (None: no robot) into ``out_free`` / ``out_kind`` (>= H, >= W; the top-left (H, W) is
    written). ``silhouette`` and ``gaps`` are scratch buffers of the calling thread. The one
    place that turns a frame into its state: the grid's own build and :class:`StateMaker`
    both call it (R9, R28, R32)."""
    d = check_depth_image(cam, depth)
    use = robot_depth is not None
    rd = check_depth_image(cam, robot_depth, name="robot_depth") if use else np.zeros((1, 1), np.float32)
    invalid_free = options.invalid == "free"
    n_sil = check_silhouette_px(options.silhouette_px)
    n_gap = check_gap_px(options.gap_px)
    sil = silhouette.dilate(rd, n_sil) if (use and n_sil > 0 and not invalid_free) else None
    gap = gaps.gaps(d, cam.min_range, cam.max_range, n_gap) if (n_gap > 0 and not invalid_free) else None
    frame_state(d, rd, use, cam.min_range, cam.max_range, float(options.robot_offset), invalid_free,
                bool(robot_free), out_free, out_kind, sil, gap)


class StateMaker:
    """Makes :class:`CameraState` of one camera's frames (R9, R28, R32), with scratch buffers of
    its own: one per thread that makes states."""

    def __init__(self, cam):
        self.camera = cam
        self._silhouette = SilhouetteBuffers(cam.shape)
        self._gaps = GapBuffers(cam.shape)

    def make(self, depth, robot_depth, options: StateOptions, robot_free: bool = False,
             pyramids: bool = False) -> CameraState:
        """The state of one frame, in new arrays (the grid copies them in; the frame's product
        holds them); with ``pyramids`` (a camera other than the principal) its min / max
        pyramids too."""
        cam = self.camera
        free = np.empty(cam.shape, dtype=np.float64)
        kind = np.empty(cam.shape, dtype=np.int8)
        state_into(cam, depth, robot_depth, options, robot_free, self._silhouette, self._gaps, free, kind)
        if not pyramids:
            return CameraState(free, kind, options, bool(robot_free))
        levels = pyramid_levels(cam.height, cam.width)
        offs, dims, size = pyramid_layout(cam.height, cam.width, levels)
        pmin = np.empty(size)
        pmax = np.empty(size)
        build_pyramids(free, cam.height, cam.width, pmin, pmax, offs, dims)
        return CameraState(free, kind, options, bool(robot_free), pmin, pmax, levels)
