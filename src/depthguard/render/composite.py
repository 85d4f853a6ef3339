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

__all__ = ["nearest_depth", "copy_depth_rows"]


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


def copy_depth_rows(dst: np.ndarray, dst_spans: np.ndarray, src: np.ndarray, src_spans: np.ndarray) -> np.ndarray:
    """``dst`` (H, W) float32 becomes ``src`` (H, W) float32, bit for bit, touching only the pixels
    of the rows' spans (``(H, 2)`` int32, per row ``[a, b)``; ``(0, 0)`` = none) of both: each
    image must be 0 outside its spans — a :class:`~depthguard.render.Renderer`'s depth and its
    ``spans`` are (R16) — and ``dst_spans`` becomes ``src_spans``. A robot covering 1-3 % of a
    640x480 image is copied in that share of a whole-image copy (issue 29: ``numpy.copyto`` of the
    image was 0.11-0.16 ms a frame on the camera worker). Returns ``dst``."""
    if not (dst.shape == src.shape and dst.ndim == 2 and dst.dtype == src.dtype
            and dst_spans.shape == src_spans.shape == (dst.shape[0], 2)):
        raise ValueError(f"images {dst.shape} {src.shape} and spans {dst_spans.shape} {src_spans.shape} "
                         "do not match")
    _copy_rows_kernel(dst, dst_spans, src, src_spans)
    return dst


@numba.njit(cache=True, nogil=True)
def _copy_rows_kernel(dst, dst_spans, src, src_spans):
    H = dst.shape[0]
    for v in range(H):
        a = src_spans[v, 0]
        b = src_spans[v, 1]
        if b <= a:
            a = 0
            b = 0
        for u in range(dst_spans[v, 0], min(dst_spans[v, 1], a)):    # dst's pixels outside src's span
            dst[v, u] = 0.0
        for u in range(max(dst_spans[v, 0], b), dst_spans[v, 1]):
            dst[v, u] = 0.0
        for u in range(a, b):
            dst[v, u] = src[v, u]
        dst_spans[v, 0] = a
        dst_spans[v, 1] = b
