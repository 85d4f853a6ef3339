"""The other cameras' free depths in float32, rounded down (R11, R12; issue 29).

A camera other than the principal confirms the principal's cells through its per-pixel free
depth (the depth up to which each ray is free, m) and the min / max pyramids of it. They are
the largest arrays a frame makes — 2.5 MB and 1.6 MB of float64 for a 640x480 camera, written
by the camera's worker and read again by the build — and held in **float32** they take half the
memory traffic. Nearly every free depth is a float32 already (a measured depth, a rendered robot
depth, ``inf``, 0); the few that are not (the camera's ``min_range`` / ``max_range``, a float64
image's depths) are **rounded down**, so that a camera never says a ray is free farther than it
measured: it clears a cell only where the float64 state would, never where it would not (the
safe side, by less than a float32 unit in the last place — 0.24 µm at 2 m).

:func:`as_free` is the rule inside the kernels (a float32 array gets the rounded-down value, a
float64 one the value as it is); :func:`free_down32` its plain-numpy twin; :func:`round_down_into`
the kernel that takes a float64 state (a camera unit's, decoded from the network, or one a
caller hands in) into the float32 the grid reads.
"""

from __future__ import annotations

import numpy as np
from numba import njit, types
from numba.extending import overload

__all__ = ["FREE_DTYPE", "as_free", "free_down32", "round_down_into"]

#: the dtype of another camera's free depths and pyramids
FREE_DTYPE = np.float32

#: a float64 free depth ``f > 0`` that float32 rounds up is stored as ``float32(f * DOWN)``:
#: ``f`` less 1 to 2 float32 units, rounded to the nearest float32, is below ``f`` (module
#: docstring) — at most one unit lower than the largest float32 below ``f``
DOWN = 1.0 - 2.0 ** -23


def as_free(f, out):
    """The free depth ``f`` (float64 m, >= 0 or inf) as array ``out`` holds it: float32 rounded
    down (never above ``f``), else ``f`` itself. The Python form (the kernels compile the
    overload below)."""
    if np.asarray(out).dtype == np.float32:
        return free_down32(np.float64(f))[()]
    return f


@overload(as_free)
def _as_free(f, out):
    if isinstance(out, types.Array) and out.dtype == types.float32:
        def down(f, out):
            r = np.float32(f)
            return r if np.float64(r) <= f else np.float32(f * DOWN)   # a select: stays vectorised
        return down

    def same(f, out):
        return f
    return same


def free_down32(free) -> np.ndarray:
    """The plain-numpy twin of :func:`as_free` into float32: ``free`` (any shape) float m ->
    float32 of that shape, each value the float32 itself where it is one, else rounded down
    as the kernels do (bit for bit)."""
    f = np.asarray(free, dtype=np.float64)
    r = f.astype(np.float32)
    up = r.astype(np.float64) > f
    if np.any(up):
        r[up] = (f[up] * DOWN).astype(np.float32)
    return r


@njit(cache=True, nogil=True)
def round_down_into(src, dst):
    """The top-left ``(H, W)`` of ``dst`` (>= H, >= W) float32 = ``src`` (H, W) float64 free
    depths, rounded down (:func:`as_free`); the shapes are the caller's to check."""
    for v in range(src.shape[0]):
        for u in range(src.shape[1]):
            dst[v, u] = as_free(src[v, u], dst)
