"""Cameras whose share of the depth grid build is made by their camera units (issue 29 point 3, R20, R36).

A camera listed in the rig's ``monitor: state_cameras`` has no frames at the monitor: its
camera unit (``depthguard node --states``) removes the robot at the frame's capture joints,
makes the frame's :class:`~depthguard.fusion.depth_grid_state.CameraState` with the monitor's
state options (they reach the unit in the fusion server's settings) and publishes it
(:mod:`depthguard.transport.state_wire`). The ``units:`` source decodes it and the monitor
hands it here (``Monitor.push_state``): a :class:`UnitWorker` stands where a local camera's
:class:`~depthguard.runtime.ingest.CameraWorker` would, and its product carries the state, the
capture stamp and the joints the unit used, so the fusion builds with it exactly as with a local
camera's state (the robot's padded volume at those joints too). The monitor renders nothing
for such a camera; the distances equal those of a monitor that had the same frames and joints.

A state is **refused** (counted by reason in ``refusals``, the sentence in ``last_refusal``;
the camera then goes stale as for a refused frame, R27) when it was made with other options
than this monitor's (``options``), for the other role (``role``: ``robot_in_others="free"``
makes a principal's state differ from another camera's), at another image size (``shape``),
with joints of another robot (``joints``: length, finite, within the joint limits), or when it
is not newer than the state in use (``out_of_order``). The build is never handed a state it
would not copy in: the product's depth is a placeholder at the camera's ``min_range``
everywhere, so that a build that worked the state out of it anyway (which these checks
exclude) would see an obstacle in front of the camera, never free space.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np

from depthguard.fusion.depth_grid_state import CameraState, StateOptions
from depthguard.runtime.ingest import CameraProduct

__all__ = ["UnitWorker", "UnitStateInput"]


class UnitWorker:
    """Stands for a camera worker of a camera whose unit makes its state (module docstring).

    ``cam`` the rig's camera; ``robot`` the rig's robot (joint count and limits);
    ``expected()`` -> ``(StateOptions, robot_free)`` as the monitor's build will load this camera,
    or None (one camera: no grid); ``on_product(camera_id)`` is called after each accepted state.
    """

    drift = None               # a unit's camera has no drift watch here (its frames are the unit's)
    scene_change = None

    def __init__(self, cam, robot, expected, on_product):
        self.camera = cam
        self.id = cam.id
        self.robot = robot
        self.expected = expected
        self.on_product = on_product
        self.lock = threading.Lock()
        self.product: CameraProduct | None = None
        self.frames = 0
        self.dropped = 0
        self.refusals: dict[str, int] = {}
        self.last_refusal: str | None = None
        self._version = 0
        # the placeholder frame (module docstring): never read while the checks hold
        self._placeholder = np.full(cam.shape, np.float32(cam.min_range), dtype=np.float32)
        self._placeholder.flags.writeable = False

    @property
    def refused(self) -> int:
        return sum(self.refusals.values())

    def idle(self) -> bool:
        return True            # accepted on the caller's thread: nothing waits here

    def close(self, timeout: float = 0.0) -> None:
        pass

    def _refuse(self, key: str, message: str) -> bool:
        with self.lock:
            self.refusals[key] = self.refusals.get(key, 0) + 1
            self.last_refusal = f"camera {self.id}: unit state {message}"
        return False

    def accept(self, st, pushed_at: float) -> bool:
        """Take a decoded :class:`~depthguard.transport.state_wire.UnitState` of this camera: True
        when it became the camera's product, False when refused (counted, module docstring)."""
        cam = self.camera
        if st.camera != self.id:
            return self._refuse("wrong_camera", f"names camera {st.camera!r}")
        if st.free.shape != cam.shape:
            return self._refuse("shape", f"of {st.free.shape[1]}x{st.free.shape[0]} px, the rig's camera is "
                                         f"{cam.width}x{cam.height}")
        want = self.expected()
        if want is None:
            return self._refuse("no_grid", "not used: the monitor has one camera (no depth grid)")
        options, robot_free = want
        got = StateOptions(*st.options)
        if got != options:
            return self._refuse("options", f"made with {tuple(got)}, the monitor's options are {tuple(options)} "
                                           f"(robot_offset, invalid, robot_in_others, silhouette_px, gap_px): "
                                           f"the unit must take the server's settings")
        if bool(st.robot_free) != bool(robot_free):
            return self._refuse("role", f"made with robot_free={st.robot_free}, this camera's role in the grid "
                                        f"needs {robot_free} (the principal changed?)")
        q = np.asarray(st.q, dtype=np.float64)
        r = self.robot
        if (len(q) != r.dof or not np.all(np.isfinite(q))
                or np.any(q < np.asarray(r.q_min) - 1e-9) or np.any(q > np.asarray(r.q_max) + 1e-9)):
            return self._refuse("joints", f"with joints {np.round(q, 4).tolist()}: not {r.dof} finite values "
                                          f"within the robot's joint limits")
        stamp = float(st.stamp)
        if not math.isfinite(stamp):
            return self._refuse("bad_stamp", f"stamp {stamp!r} is not finite")
        with self.lock:
            newest = self.product.stamp if self.product is not None else -math.inf
            if stamp <= newest:
                self.refusals["out_of_order"] = self.refusals.get("out_of_order", 0) + 1
                self.last_refusal = (f"camera {self.id}: unit state at {stamp:.6f} s is not newer than the "
                                     f"state in use ({newest:.6f} s)")
                return False
            self._version += 1
            state = CameraState(st.free, st.kind, options, bool(robot_free))
            self.product = CameraProduct(self._placeholder, None, stamp, q, pushed_at, self._version, state)
            self.frames += 1
        self.on_product(self.id)
        return True


class UnitStateInput:
    """The monitor's input of unit states (a mixin of :class:`~depthguard.runtime.monitor.Monitor`:
    its ``_workers``, ``_state_options`` and ``config``)."""

    def _unit_expected(self, cid: str):
        """``(StateOptions, robot_free)`` the build will load camera ``cid``'s state with, or None."""
        want = self._state_options(cid)
        return None if want is None else (want[0], want[1])

    def push_state(self, state) -> bool:
        """A decoded unit state (:class:`~depthguard.transport.state_wire.UnitState`) of one of
        ``state_cameras``; any thread. True when it is the camera's product now; False when
        refused (counted on the camera's worker, or in ``unit_states_unmonitored`` for a camera
        that is not a monitored state camera)."""
        w = self._workers.get(state.camera)
        if not isinstance(w, UnitWorker):
            self.unit_states_unmonitored = getattr(self, "unit_states_unmonitored", 0) + 1
            self.unit_states_last_refusal = (f"unit state of camera {state.camera!r}, which is not among the "
                                             f"monitored state_cameras {list(self.config.state_cameras)}")
            return False
        return w.accept(state, time.perf_counter())
