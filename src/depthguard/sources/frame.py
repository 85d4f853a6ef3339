"""One depth image from one camera at one time (the unit every source yields)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Frame"]


@dataclass(frozen=True, eq=False)
class Frame:
    """A depth frame.

    camera_id : the rig camera that took it.
    depth : (H, W) float32 metres, 0 = no measurement.
    stamp : capture time, seconds (scene time for simulated sources).
    labels : optional (H, W) int32 ground-truth owner of each pixel (simulation
        only; index into the scene's mesh names, -1 = nothing).
    """

    camera_id: str
    depth: np.ndarray
    stamp: float
    labels: np.ndarray | None = None
