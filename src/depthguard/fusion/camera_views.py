"""The other cameras' per-pixel states read where they lie, not copied (R11, R12, R36; issue 29).

The depth grid's kernels read, for every other camera ``k``, its free depths ``(H_k, W_k)``
float32 m, rounded down (:mod:`~depthguard.fusion.free32`;
:func:`~depthguard.fusion.depth_grid_kernels.cell_cleared` and the memo's runs) and its min / max
pyramids, flat at the grid's level offsets (:func:`~depthguard.fusion.depth_grid_state.pyramid_layout`). A camera's state is made on its
worker (:class:`~depthguard.fusion.depth_grid_state.CameraState`) and never written again; the
build used to copy it into one ``(K, Hk, Wk)`` array and two ``(K, size)`` arrays — 3.3 MB of a
640x480 camera, 0.47 ms per frame of another camera on the fusion's serial path (the bench's
flacco-cell builds, 2026-11-27), three of every four builds of ur3-cell.

:class:`CameraViews` is instead a table per kind: row ``k`` of ``free`` is ``(address, rows,
row length)`` and of ``pmin`` / ``pmax`` ``(address, length)``, int64, of the arrays camera ``k``
is read from — the state's own, or the grid's buffers where the build worked the state out —
and it **holds those arrays** until row ``k`` is pointed elsewhere, so their memory stays
theirs: a worker's pool (:mod:`depthguard.frame_pool`) gives a set out again only when nothing
refers to it. The kernels turn a row into an array view with :func:`camera_free` /
:func:`camera_pyramid` (numba's ``carray`` at that address: no copy, no allocation, one
compiled signature for any number of cameras, as the ``(K, …)`` arrays had). Only a
:class:`CameraViews` makes the rows, from arrays it checks (C-contiguous float32 of the
shapes it records), so a kernel never reads outside memory it holds.
"""

from __future__ import annotations

import numpy as np
from numba import carray, njit, types

from depthguard.fusion.free32 import FREE_DTYPE
from numba.core import cgutils
from numba.extending import intrinsic

__all__ = ["CameraViews", "camera_free", "camera_pyramid", "readable"]


@intrinsic
def _address(typingctx, addr):
    """An int64 address as the void pointer ``carray`` takes."""
    if not isinstance(addr, types.Integer):
        return None

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], cgutils.voidptr_t)

    return types.voidptr(addr), codegen


@njit(cache=True, inline="always")
def camera_free(table, k):
    """Camera ``k``'s free depths: the ``(rows, row length)`` float32 array (m) row ``k`` of
    ``table`` (a :attr:`CameraViews.free`, (K, 3) int64) points at."""
    return carray(_address(table[k, 0]), (table[k, 1], table[k, 2]), np.float32)


@njit(cache=True, inline="always")
def camera_pyramid(table, k):
    """Camera ``k``'s flat pyramid (``(length,)`` float32 m) row ``k`` of ``table`` (a
    :attr:`CameraViews.pmin` / ``pmax``, (K, 2) int64) points at."""
    return carray(_address(table[k, 0]), (table[k, 1],), np.float32)


def readable(a) -> bool:
    """``a`` is an array a kernel can read in place through :class:`CameraViews` (C-contiguous
    float32, :data:`~depthguard.fusion.free32.FREE_DTYPE`); :meth:`CameraViews.point` refuses anything else."""
    return type(a) is np.ndarray and a.dtype == FREE_DTYPE and a.flags.c_contiguous


def _address_of(a: np.ndarray) -> int:
    return a.__array_interface__["data"][0]


class CameraViews:
    """The tables of ``n`` other cameras' arrays (module docstring). ``free`` (max(n, 1), 3),
    ``pmin`` / ``pmax`` (max(n, 1), 2) int64; every row points at a held array once
    :meth:`point` has been called for it (the grid points each at its own buffers first)."""

    __slots__ = ("free", "pmin", "pmax", "_held")

    def __init__(self, n: int):
        m = max(int(n), 1)
        self.free = np.zeros((m, 3), dtype=np.int64)
        self.pmin = np.zeros((m, 2), dtype=np.int64)
        self.pmax = np.zeros((m, 2), dtype=np.int64)
        self._held: list = [None] * m

    def point(self, k: int, free: np.ndarray, pmin: np.ndarray, pmax: np.ndarray) -> None:
        """Row ``k`` reads ``free`` (rows, row length) and ``pmin`` / ``pmax`` (length,), all
        C-contiguous float32 (``ValueError`` otherwise); they are held until the row is pointed
        elsewhere. The caller must not write into them while a kernel may read them."""
        for name, a, nd in (("free", free, 2), ("pmin", pmin, 1), ("pmax", pmax, 1)):
            if not (readable(a) and a.ndim == nd):
                raise ValueError(f"camera {k}'s {name} must be a C-contiguous {nd}-D float32 array "
                                 f"(got {getattr(a, 'shape', a)!r} {getattr(a, 'dtype', '')})")
        if pmin.shape != pmax.shape:
            raise ValueError(f"camera {k}'s pyramids differ in length ({pmin.shape[0]}, {pmax.shape[0]})")
        self._held[k] = (free, pmin, pmax)
        self.free[k, 0] = _address_of(free)
        self.free[k, 1] = free.shape[0]
        self.free[k, 2] = free.shape[1]
        self.pmin[k, 0] = _address_of(pmin)
        self.pmin[k, 1] = pmin.shape[0]
        self.pmax[k, 0] = _address_of(pmax)
        self.pmax[k, 1] = pmax.shape[0]

    def arrays(self, k: int) -> tuple:
        """``(free, pmin, pmax)``: the arrays row ``k`` reads (None before :meth:`point`)."""
        return self._held[k]

    # an address is only valid for the arrays this object holds: a copy, deep copy or pickle
    # points its rows at the arrays it holds itself, never at the original's memory
    def __copy__(self) -> "CameraViews":
        return CameraViews._of(list(self._held))

    def __deepcopy__(self, memo) -> "CameraViews":
        import copy

        return CameraViews._of(copy.deepcopy(self._held, memo))

    def __reduce__(self):
        return CameraViews._of, (list(self._held),)

    @staticmethod
    def _of(held: list) -> "CameraViews":
        out = CameraViews(len(held))
        for k, arrays in enumerate(held):
            if arrays is not None:
                out.point(k, *arrays)
        return out
