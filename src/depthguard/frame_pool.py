"""Frame buffers reused once nobody holds them (issue 29, R36): a camera worker's products, the
simulator's robot images (:meth:`~depthguard.sources.camera_sim.CameraSim.robot_image`). At the
package's top, below the sources and the runtime that use it.

A camera's worker (:class:`~depthguard.runtime.ingest.CameraWorker`) hands each frame on as a
:class:`~depthguard.runtime.ingest.CameraProduct`: the robot rendered at the capture joints
(H, W) float32 m and the frame's per-pixel state (``free`` float64 m, ``kind`` int8, at the
camera's pixel or the principal's binned one). Made in fresh memory, a 640x480 frame of a
camera other than the principal faults in about 620 new pages (the 2.4 MB ``free``): measured
on a worker thread, 2 of its 6 ms per frame. :class:`BufferPool` keeps a few sets of these
arrays per camera and gives a set out again only when **nothing else refers to any array of
it**: not the worker's newest product, not a product a reader still holds (the fusion's build,
the free-space map, the live view), not a depth grid that reads a camera's state in place
until that camera's next frame (:meth:`~depthguard.fusion.depth_grid.DepthGridMap.set_frames`,
:mod:`~depthguard.fusion.camera_views`), nor a view of one of them. The test is CPython's reference count of each array (``sys.getrefcount``):
every holder of an array or of a view of it counts, and a reference can only be made from
another, so a set seen unreferenced on the worker's thread cannot be taken up by another
thread before the worker writes into it. No release call is needed from the readers.

A set in use by others is skipped; when every set is held, a new one is made (the pool keeps
up to ``cap`` sets, beyond that a set is made for the one frame and left to the garbage
collector: the behaviour before the pool). Steady state with two grids: the front and back
grids' states of the camera, the newest product, the frame being made — four sets per camera.
"""

from __future__ import annotations

import sys

import numpy as np

__all__ = ["BufferPool", "DEFAULT_CAP"]

#: sets kept per pool (a camera); beyond it a set is made per frame
DEFAULT_CAP = 6


def _refs(a) -> int:
    return sys.getrefcount(a)


def _probe_refs() -> int:
    """The count :func:`_refs` gives for an array held by a pool's set alone."""
    entry = [np.empty(1)]
    return _refs(entry[0])


#: the reference count of an array that only its set (a list) holds, seen through :func:`_refs`
_ALONE = _probe_refs()


class BufferPool:
    """Sets of preallocated arrays of one layout at a time (module docstring).

    ``take(layout)`` -> a list of new-or-recycled arrays, one per ``(shape, dtype)`` of
    ``layout`` (their content is the previous frame's or uninitialised: the caller writes every
    element it uses). A new layout (another bin, another camera shape) drops the kept sets.
    Counters: ``made`` sets allocated (kept or not), ``reused`` sets given out again,
    ``overflow`` sets made beyond ``cap``.
    """

    def __init__(self, cap: int = DEFAULT_CAP):
        if int(cap) < 1:
            raise ValueError(f"a buffer pool keeps at least one set (got cap={cap!r})")
        self.cap = int(cap)
        self._layout: tuple | None = None
        self._given = None                # the layout object last given, whose key is _layout
        self._sets: list[list[np.ndarray]] = []
        self.made = 0
        self.reused = 0
        self.overflow = 0

    @staticmethod
    def _unheld(arrays: list) -> bool:
        for i in range(len(arrays)):
            if _refs(arrays[i]) != _ALONE:
                return False
        return True

    def take(self, layout) -> list[np.ndarray]:
        """Arrays of ``layout`` (a tuple of ``(shape, dtype)``) that nothing outside the pool
        refers to; the returned list is the caller's (its arrays stay the pool's, for reuse
        once the caller and everyone it gave them to dropped them)."""
        if layout is self._given:          # a caller's one tuple per role, frame after frame
            key = self._layout
        else:
            key = tuple((tuple(int(n) for n in shape), np.dtype(dt)) for shape, dt in layout)
            if key != self._layout:
                self._layout, self._sets = key, []
            # (kept only for a tuple of tuples: nothing in it can change while the pool holds it)
            self._given = layout if isinstance(layout, tuple) and all(type(sh) is tuple for sh, _ in layout) else None
        for arrays in self._sets:
            if self._unheld(arrays):
                self.reused += 1
                return list(arrays)
        fresh = [np.empty(shape, dtype=dt) for shape, dt in key]
        self.made += 1
        if len(self._sets) < self.cap:
            self._sets.append(fresh)
        else:
            self.overflow += 1
        return list(fresh)

    @property
    def kept(self) -> int:
        """Sets the pool holds now."""
        return len(self._sets)
