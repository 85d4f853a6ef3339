"""Camera frames of the simulated closed loop, from capture to delivery (R15, R27).

A real depth camera hands a frame to the computer some time after it was
exposed: the Kinect v1 needs at least one frame period (33 ms at 30 Hz) to
read out and compute its disparity image, and USB transfer and the driver
add more. :class:`CameraPipeline` models that **latency**: a frame captured
at simulated time ``t`` (the scene and the robot as they are at ``t``) is
delivered to the distance computation at ``t + latency``; until then the
control loop works with the frames it already has.

With ``latency > 0`` the frames are simulated on a second thread (one
worker, one numba thread; the kernels release the GIL) while the control
cycles go on; the loop waits for a frame only if it is not ready at its
delivery time. Each frame is a pure function of its capture time and
joints, so the run is the same, bit for bit, however the threads are
scheduled. With ``latency == 0`` a frame is simulated and delivered at once,
in the loop's own thread; so it is, with the latency still applied, when
numba's threading layer cannot be entered from two threads at once
(:func:`threadsafe_numba`).

Before the first cycle (``start``) every camera delivers at ``t = 0`` the
frame it captured at ``-latency`` with the robot at rest in its start
posture: the cameras run before the robot starts, so the loop never begins
without data.
"""

from __future__ import annotations

import time
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Callable

import numba
import numpy as np

__all__ = ["CameraPipeline", "threadsafe_numba"]


def _one_numba_thread():
    numba.set_num_threads(1)       # the camera thread keeps to its core


@numba.njit(parallel=True, cache=True)
def _touch(x):
    for i in numba.prange(x.shape[0]):
        x[i] = i


def threadsafe_numba() -> bool:
    """True when numba's threading layer may be entered from two Python threads at once
    (``omp``, ``tbb``); the ``workqueue`` fallback aborts the process if it is."""
    try:
        layer = numba.threading_layer()
    except ValueError:                   # not chosen until the first parallel launch
        _touch(np.zeros(2))
        layer = numba.threading_layer()
    return layer in ("omp", "tbb")


class CameraPipeline:
    """Frames in flight between capture and delivery (module docstring).

    ``simulate(i, t, q) -> (depth (H, W) float32, robot_depth (H, W) float32,
    robot_seconds, scene_seconds)`` simulates camera ``i``'s frame captured at
    ``t`` with joints ``q`` (it must not keep references to ``q``; the
    returned images must be new arrays). ``timing``: the loop's wall-time
    dict; ``self_removal`` and ``camera_sim`` get the simulation's own
    seconds, ``camera_wait`` the time the loop waited for a late frame.
    """

    def __init__(self, simulate: Callable, camera_ids: list[str], latency: float, timing: dict,
                 threaded: bool = True):
        latency = float(latency)
        if not (np.isfinite(latency) and latency >= 0.0):
            raise ValueError(f"camera latency must be >= 0 s, got {latency!r}")
        self.simulate = simulate
        self.camera_ids = list(camera_ids)
        self.latency = latency
        self.timing = timing
        timing.setdefault("camera_wait", 0.0)
        self._pending: deque = deque()     # (t_deliver, i, t_capture, q_capture, Future | result)
        self._pool = (ThreadPoolExecutor(max_workers=1, thread_name_prefix="depthguard-cameras",
                                         initializer=_one_numba_thread)
                      if latency > 0.0 and threaded else None)

    @property
    def threaded(self) -> bool:
        """Whether the frames are simulated on the camera thread."""
        return self._pool is not None

    def start(self, q0: np.ndarray, cameras=None) -> None:
        """Frames captured at ``-latency`` with the robot at ``q0``, delivered at ``t = 0``
        (nothing to do without latency: the loop's first cycle captures and delivers)."""
        if self.latency == 0.0:
            return
        for i in range(len(self.camera_ids)) if cameras is None else cameras:
            q = np.array(q0, dtype=np.float64)
            self._pending.append((0.0, i, -self.latency, q, self.simulate(i, -self.latency, q)))

    def capture(self, i: int, t: float, q: np.ndarray) -> None:
        """Camera ``i`` captures a frame at ``t`` with the robot at ``q``."""
        q = np.array(q, dtype=np.float64)
        if self._pool is None:                 # simulated now, delivered after the latency
            job = self.simulate(i, t, q)
        else:
            job = self._pool.submit(self.simulate, i, t, q)
        self._pending.append((t + self.latency, i, t, q, job))

    def deliver(self, t: float):
        """Yield ``(i, camera id, t_capture, q_capture, depth, robot_depth)`` for every frame
        due at or before ``t``, in capture order."""
        while self._pending and self._pending[0][0] <= t + 1e-9:
            _, i, t_cap, q_cap, job = self._pending.popleft()
            if isinstance(job, Future):
                w0 = time.perf_counter()
                job = job.result()
                self.timing["camera_wait"] += time.perf_counter() - w0
            depth, robot_depth, t_robot, t_scene = job
            self.timing["self_removal"] += t_robot
            self.timing["camera_sim"] += t_scene
            yield i, self.camera_ids[i], t_cap, q_cap, depth, robot_depth

    def close(self) -> None:
        """Drop the frames still in flight and stop the worker."""
        for *_, job in self._pending:
            if isinstance(job, Future):
                job.cancel()
        self._pending.clear()
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
