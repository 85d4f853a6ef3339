"""The simulated cameras of a real-time run, each on its own thread (R29, issue 29).

A real camera delivers on its own, whatever the others do. :meth:`SimFrames.camera_streams
<depthguard.sources.sim_source.SimFrames.camera_streams>` gives one :class:`CameraStream` per
camera; the runner (:mod:`depthguard.runtime.runner`) renders each on its own thread, asleep
until :meth:`CameraStream.wake_at`, so that a frame's render starts at its capture (up to the
joint tick after it) and never waits behind another camera's render. A stream's frames are
those of :meth:`SimFrames.frames_each <depthguard.sources.sim_source.SimFrames.frames_each>`
for its camera alone, the same bits (``tests/test_sim_camera_threads.py``).
"""

from __future__ import annotations

import math

import numpy as np

from depthguard.sim.posed import PosedMeshes

__all__ = ["CameraStream"]


class _Counts:
    """Frames a camera did not render: ``skipped`` behind real time, ``unposed`` (no robot state)."""

    def __init__(self):
        self.skipped = 0
        self.unposed = 0


class CameraStream:
    """One camera of a :class:`~depthguard.sources.sim_source.SimFrames` on its own thread (R29).

    ``frames_each(t)`` is ``SimFrames.frames_each`` for this camera alone (the same frames: its
    captures due by ``t``, each rendered at its capture time with the robot where it was then;
    behind by more than a period in real time, the latest due only); :meth:`wake_at` is when the
    next one can be rendered. Its buffers (the posed people and props) are its own: one thread per
    stream."""

    def __init__(self, frames, index: int):
        self.frames, self.index = frames, int(index)
        self.camera_id = frames.camera_ids[index]
        self.counts = _Counts()
        self._posed = PosedMeshes(frames.world.scene, alone=frames.world.alone)
        self._cameras = (self.index,)

    def render(self, camera_id: str, t: float, q: np.ndarray) -> np.ndarray:
        """``SimFrames.render`` with this stream's buffers."""
        return self.frames._render(camera_id, t, q, self._posed)

    def frames_each(self, t: float):
        """This camera's frames captured by ``t`` (s, the run's clock) not returned yet, one at a time."""
        return self.frames._frames_each(t, self._cameras, self.counts, self.render)

    def wake_at(self) -> float:
        """The run's clock (s) at which this camera's next frame can be rendered: its capture time,
        up to the joint tick at or after it (the robot's pose at the capture is interpolated
        between the ticks around it, never extrapolated: R30). A followed robot's states come
        when they come: the capture time alone."""
        world = self.frames.world
        tc = self.frames.schedule.next[self.index]
        if world.followed is None:
            dt = 1.0 / world.joint_hz
            tc = max(tc, math.ceil(tc / dt - 1e-9) * dt)
        return world.origin + tc
