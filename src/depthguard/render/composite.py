"""Depth images of parts of a scene combined into the depth image of the whole (R16).

A z-buffer keeps, per pixel, the nearest surface of all triangles, and whether
a triangle covers a pixel (and at which depth) does not depend on the other
triangles. So the depth image of a scene is, per pixel, the nearest of the
depth images of any split of its meshes: rendering the static part once and
only the moving parts per frame gives the same image, bit for bit
(``tests/test_render.py``). 0 means "nothing hit" in every layer.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["nearest_depth"]


def nearest_depth(out: np.ndarray, layer: np.ndarray) -> np.ndarray:
    """``out`` (H, W) float32 becomes, per pixel, the nearer of ``out`` and ``layer`` (H, W),
    metres along the optical axis, 0 = nothing (so any hit beats 0); returns ``out``."""
    if out.shape != layer.shape or out.ndim != 2:
        raise ValueError(f"depth layers must be 2-D images of one shape, got {out.shape} and {layer.shape}")
    if out.dtype != np.float32:
        raise ValueError(f"out must be float32, got {out.dtype}")
    _nearest_kernel(out, layer)
    return out


@numba.njit(cache=True, nogil=True)
def _nearest_kernel(out, layer):
    H, W = out.shape
    for v in range(H):
        for u in range(W):
            z = layer[v, u]
            if z > 0.0 and (out[v, u] == 0.0 or z < out[v, u]):
                out[v, u] = z
