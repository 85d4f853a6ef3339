"""Joint states of a Franka FR3 through franky: ``--joints franky:HOST`` (R27, R30, R31).

Reads the robot state (``q``, rad, and the robot's own ``time``) of the run's franky link
(:mod:`depthguard.transport.franky_link`, shared with ``--sink franky:HOST``) ``frequency``
(250) times a second on a thread of its own. Each state is stamped on this host's wall clock
(``time.time()``, s) when it is read — a live source, like ``ur-rtde:`` — and the robot's
``time`` is kept beside it (``robot_stamps``: the newest 10000 ``(host stamp, robot time s)``
pairs); a state whose robot time did not advance is not given twice.

Checks: the rig's robot must have the FR3's 7 joints, and the first state must lie within the
rig's joint limits — otherwise the source refuses to open with one sentence. A later state
outside the limits is not used (``rejected``; ``last_error`` until a state is used again; said
in one log line): the joints go stale and the monitor stops the robot (R27). An address that
does not answer on port 1337 within 2 s is refused at open. When reading fails (the
connection is lost), the source says so (``lost``); no state comes, the joints go stale, the
robot stops (R27). Beside ``sim:`` frames the simulated cameras follow this robot: they render
it at its states (:class:`~depthguard.sources.sim_source.FollowedJoints`), on the wall clock —
the closed loop of ``--cell fr3-cell`` with franky-sim or a real FR3 (docs/ROBOTS.md).
"""

from __future__ import annotations

import threading
import time
from collections import deque

import numpy as np

from depthguard.progress import log
from depthguard.sources.base import register_joints
from depthguard.sources.joints import JointSourceError, _robot, check_joint_state
from depthguard.sources.sim_source import follow_beside_simulator
from depthguard.sources.stamped_queue import StampedQueue
from depthguard.transport.franky_link import FRANKA_DOF, FrankyError, link_for, parse_host

__all__ = ["FrankyJoints"]


class FrankyJoints:
    """Live joint states of an FR3 (module docstring). ``received``, ``rejected``,
    ``out_of_order``: counters; ``first_stamp`` is ``None``; ``done`` only once closed."""

    live = True
    first_stamp = None

    def __init__(self, host: str, rig, frequency: float = 250.0):
        self._robot = _robot(rig)
        what = f"--joints franky:{host}"
        if self._robot.dof != FRANKA_DOF:
            raise JointSourceError(f"{what}: a Franka reports {FRANKA_DOF} joints, the rig's robot "
                                   f"{self._robot.name} has {self._robot.dof}: use the rig of this robot")
        self.host, self.period = host, 1.0 / float(frequency)
        self.received = self.rejected = self.out_of_order = self.overflow = 0
        self.last_error: str | None = None
        self.robot_stamps: deque[tuple[float, float]] = deque(maxlen=10000)
        self._lost: str | None = None
        self._closed = False
        self._queue = StampedQueue(8192)
        try:
            self.link = link_for(host)
        except FrankyError as exc:
            raise JointSourceError(str(exc)) from None
        try:
            q, _dq, _t = self.link.joint_state()
            check_joint_state(self._robot, time.time(), q)
        except JointSourceError as exc:
            self.link.release()
            raise JointSourceError(f"{what}: the robot's joints do not fit the rig: {exc}") from None
        except Exception as exc:  # noqa: BLE001 - libfranka's errors
            self.link.release()
            raise JointSourceError(f"{what}: no robot state ({type(exc).__name__}: {exc})") from None
        self._last_robot_t = -np.inf
        self._thread = threading.Thread(target=self._run, daemon=True, name="franky-joints")
        self._thread.start()

    def _run(self) -> None:
        while not self._closed:
            try:
                q, _dq, robot_t = self.link.joint_state()
            except Exception as exc:  # noqa: BLE001 - a lost connection: said once, the joints go stale
                if self._lost is None:
                    self._lost = (f"franky {self.host}: joint states lost ({type(exc).__name__}: {exc}); the joints "
                                  "go stale and the robot is stopped (R27)")
                    log(self._lost)
                time.sleep(0.5)
                continue
            if self._lost is not None:
                self._lost = None
                log(f"franky {self.host}: joint states back")
            if robot_t > self._last_robot_t:
                self._last_robot_t = robot_t
                self._offer(time.time(), robot_t, q)
            time.sleep(self.period)

    def _offer(self, host_stamp: float, robot_t: float, q) -> None:
        try:
            stamp, arr = check_joint_state(self._robot, host_stamp, q)
        except (ValueError, TypeError) as exc:
            self.rejected += 1
            if self.last_error is None:                  # said once until a state is used again
                log(f"franky {self.host}: joint state refused ({exc}); the joints go stale and the robot is "
                    "stopped (R27)")
            self.last_error = f"franky {self.host}: {exc}"
            return
        self.last_error = None
        self.received += 1
        self.robot_stamps.append((stamp, float(robot_t)))
        what = self._queue.offer(stamp, (stamp, arr))
        if what == "out_of_order":
            self.out_of_order += 1
        elif what is not None:
            self.overflow += 1              # the oldest waiting state dropped (a run that does not read them)

    def states_until(self, t: float) -> list[tuple[float, np.ndarray]]:
        """The received states with host stamp <= ``t`` (s) not given yet, in stamp order."""
        return self._queue.until(t)

    @property
    def done(self) -> bool:
        return self._closed

    @property
    def lost(self) -> str | None:
        return self._lost

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._thread.join(2.0)
        self.link.release()


@register_joints("franky")
def open_franky_joints(argument: str, rig, context: dict) -> FrankyJoints:
    """Factory of ``franky:HOST``."""
    try:
        host = parse_host(argument, "--joints franky")
    except FrankyError as exc:
        raise JointSourceError(str(exc)) from None
    return follow_beside_simulator(FrankyJoints(host, rig), f"franky:{host}", context)    # sim: cameras follow it
