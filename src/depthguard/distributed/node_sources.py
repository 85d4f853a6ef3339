"""What a camera unit looks at when no camera is attached: a synthetic patch or a built-in cell's
simulated camera (``depthguard node --source pattern|sim``), and a camera at another resolution mode."""

from __future__ import annotations

import time
from typing import Callable

import numpy as np

from depthguard.camera import Camera

__all__ = ["FrameSource", "pattern_source", "sim_source", "with_resolution"]

FrameSource = Callable[[], tuple[np.ndarray, float]]


def pattern_source(cam: Camera, workspace, fraction: float = 0.3) -> FrameSource:
    """A synthetic frame: a fronto-parallel patch (the central ``fraction`` of the image)
    at the depth of the workspace centre, nothing valid elsewhere."""
    lo, hi = (np.asarray(w, dtype=float) for w in workspace)
    centre = (lo + hi) / 2
    dp = float(cam.world_to_camera(centre)[0, 2])
    if not (cam.min_range <= dp <= cam.max_range):
        raise ValueError(f"camera {cam.id}: workspace centre at depth {dp:.2f} m is outside its range")
    depth = np.zeros(cam.shape, dtype=np.float32)
    H, W_ = cam.shape
    h0, w0 = int(H * (1 - fraction) / 2), int(W_ * (1 - fraction) / 2)
    depth[h0:H - h0, w0:W_ - w0] = dp

    def capture():
        return depth, time.time()
    return capture


def sim_source(cell, camera: Camera, t: float = 0.0, seed: int = 0) -> FrameSource:
    """The noisy simulated ``camera`` looking at a built-in cell's scene at time ``t`` (captured once).

    The frame is reused (a real camera delivers frames at no CPU cost to the node);
    the stamp is the wall-clock time of each call.
    """
    from dataclasses import replace

    from depthguard.sources import SimSource

    src = SimSource(rig=replace(cell.rig, cameras=[camera]), scene=cell.scene, seed=seed)
    depth = src.frames(t)[camera.id].depth

    def capture():
        return depth, time.time()
    return capture


def with_resolution(cam: Camera, width: int, height: int) -> Camera:
    """The camera at another resolution mode of its sensor (same pose)."""
    from depthguard.sensors import intrinsics_for

    if cam.sensor is None:
        raise ValueError(f"camera {cam.id} has no sensor preset; cannot change its resolution")
    k = intrinsics_for(cam.sensor, width, height)
    return Camera(cam.id, k["width"], k["height"], k["fx"], k["fy"], k["cx"], k["cy"],
                  world_from_camera=cam.world_from_camera, min_range=cam.min_range,
                  max_range=cam.max_range, sensor=cam.sensor)
