"""One depth image from one camera at one time (the unit every source yields)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Frame"]


@dataclass(frozen=True, eq=False)
class Frame:
    """A depth frame.

    camera_id : the rig camera that took it.
    depth : (H, W) float32 metres, 0 = no measurement. Handed over: the monitor keeps a float32
        C-contiguous array as it is, without a copy (its worker and the depth grid read it after
        ``push_frame`` returns), so a source must not write into it afterwards — every source of
        the package makes a new array per frame.
    stamp : capture time, seconds (scene time for simulated sources).
    labels : optional (H, W) int32 ground-truth owner of each pixel (simulation
        only; index into the scene's mesh names, -1 = nothing).
    """

    camera_id: str
    depth: np.ndarray
    stamp: float
    labels: np.ndarray | None = None
