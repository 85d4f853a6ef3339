"""Joint states of a Universal Robots arm through RTDE: ``--joints ur-rtde:HOST`` (R27, R30, R31).

Reads ``actual_q`` (and the robot's ``timestamp``, ``actual_qd``, ``speed_scaling`` and
``target_speed_fraction``) with ``rtde_receive.RTDEReceiveInterface``
of the ``ur-rtde`` package (extra ``depthguard[ur]``), in a child process
(:mod:`depthguard.transport.ur_rtde_worker`). Each state is stamped on this host's wall clock
(``time.time()``, s) when it arrives — a live source, like ``zenoh:`` — and the robot's own
``timestamp`` (s since the controller started) is kept beside it for the record
(``robot_stamps``: the newest 10000 ``(host stamp, robot timestamp)`` pairs).

Checks: the rig's robot must have the UR's 6 joints, and the first state must lie within the
rig's joint limits — otherwise the source refuses to open with one sentence (a robot that is
not the rig's is never guessed at). A later state outside the limits is not used (``rejected``;
``last_error`` until a state is used again; said in one log line): the joints then go stale
and the monitor stops the robot (R27). An address that does not answer on port 30004 within
2 s is refused at open. A lost connection is said (``lost``), retried every second; meanwhile
no state comes, the joints go stale, the robot stops (R27). Beside ``sim:`` frames the
simulated cameras follow this robot: they render it at its states
(:class:`~depthguard.sources.sim_source.FollowedJoints`), on the wall clock.

What speed scale 1 means (R33, :meth:`UrRtdeJoints.attach`): the program runs in the robot's
controller, which scales it by the speed slider times its own trajectory limiter
(``target_speed_fraction`` x ``speed_scaling``, what UR's ROS 2 driver publishes as its speed
scaling). The program's joint velocity at scale 1 is the measured one divided by that
product (:meth:`~UrRtdeJoints.commanded_qd`), held while the product is below 0.05 (a robot
slowed to nearly nothing says little of its program; it goes on at the held velocity when it
resumes). Speed and separation monitoring then scales the program's speed, not the speed the
slider already slowed.
"""

from __future__ import annotations

import json
import threading
import time
from collections import deque

import numpy as np

from depthguard.progress import log
from depthguard.transport.ur_rtde_worker import UrError, Worker, check_reachable, missing_package, parse_address
from depthguard.sources.base import register_joints
from depthguard.sources.joints import JointSourceError, _robot, check_joint_state
from depthguard.sources.sim_source import follow_beside_simulator
from depthguard.sources.stamped_queue import StampedQueue

__all__ = ["UrRtdeJoints"]

UR_DOF = 6


class UrRtdeJoints:
    """Live joint states of a UR robot (module docstring). ``received``, ``rejected``,
    ``out_of_order``, ``overflow``: counters; ``first_stamp`` is ``None``; ``done`` only once closed."""

    live = True
    first_stamp = None

    def __init__(self, host: str, rig, frequency: float = 125.0, first_state_timeout_s: float = 5.0,
                 retry_s: float = 1.0):
        self._robot = _robot(rig)
        what = f"--joints ur-rtde:{host}"
        if self._robot.dof != UR_DOF:
            raise JointSourceError(f"{what}: a UR robot reports {UR_DOF} joints, the rig's robot "
                                   f"{self._robot.name} has {self._robot.dof}: use the rig of this robot")
        missing = missing_package()
        if missing:
            raise JointSourceError(missing)
        self.host, self.frequency, self.retry_s = host, float(frequency), float(retry_s)
        self.received = self.rejected = self.out_of_order = self.overflow = 0
        self.last_error: str | None = None
        self.robot_stamps: deque[tuple[float, float]] = deque(maxlen=10000)
        self._lost: str | None = None
        self._closed = False
        self._queue = StampedQueue(8192)
        #: ``(robot timestamp s, (6,) rad/s)``: the program's joint velocity at speed scale 1, from
        #: the newest state whose scaling was at least :attr:`SCALING_FLOOR` (None: none yet)
        self.nominal: tuple[float, np.ndarray] | None = None
        self._zero_qd = np.zeros(UR_DOF)
        self._first = threading.Event()
        self._first_error: str | None = None
        try:
            check_reachable(host, what)
            self._worker = self._connect()
        except UrError as exc:
            raise JointSourceError(str(exc)) from None
        if not self._first.wait(first_state_timeout_s):
            self._worker.close()
            raise JointSourceError(f"{what}: connected, but no joint state came within {first_state_timeout_s:g} s")
        if self._first_error is not None:
            self._worker.close()
            raise JointSourceError(f"{what}: the robot's joints do not fit the rig: {self._first_error}")
        self._retry = threading.Thread(target=self._keep_connected, daemon=True, name="ur-rtde-joints-retry")
        self._retry.start()

    def _connect(self) -> Worker:
        return Worker("receive", self.host, on_line=self._on_line, on_end=self._on_end, frequency=self.frequency)

    #: the speed slider times the trajectory limiter below which the program's velocity is held
    SCALING_FLOOR = 0.05

    def attach(self, monitor) -> None:
        """The monitor's SSM takes the program's speed at scale 1 (:meth:`commanded_qd`, R33)."""
        monitor.commanded_qd = self.commanded_qd

    def commanded_qd(self, q=None) -> np.ndarray:
        """(6,) rad/s: the program's joint velocity at speed scale 1 (module docstring), zeros before
        the robot was seen moving at a scaling >= :attr:`SCALING_FLOOR`. ``q`` is not read: the
        controller's program is where the robot is. Never written by the caller."""
        nominal = self.nominal
        return self._zero_qd if nominal is None else nominal[1]

    def _on_line(self, line: str) -> None:
        try:
            host_stamp, robot_stamp, q, qd, scaling = json.loads(line)
            stamp, arr = check_joint_state(self._robot, host_stamp, q)
            qd = np.asarray(qd, dtype=np.float64)
            if qd.shape != (UR_DOF,) or not np.all(np.isfinite(qd)) or not np.isfinite(scaling):
                raise ValueError(f"joint velocities {qd.tolist()} at a speed scaling of {scaling} are not "
                                 f"{UR_DOF} finite values")
        except (ValueError, TypeError) as exc:
            self.rejected += 1
            if self.last_error is None and self._first.is_set():     # said once until a state is used again
                log(f"ur-rtde {self.host}: joint state refused ({exc}); the joints go stale and the robot is "
                    "stopped (R27)")
            self.last_error = f"ur-rtde {self.host}: {exc}"
            if not self._first.is_set():
                self._first_error = str(exc)
                self._first.set()
            return
        self.last_error = None
        self.received += 1
        self.robot_stamps.append((stamp, float(robot_stamp)))
        if scaling >= self.SCALING_FLOOR:
            self.nominal = (float(robot_stamp), qd / float(scaling))       # a new array: readers keep theirs
        what = self._queue.offer(stamp, (stamp, arr))
        if what == "out_of_order":
            self.out_of_order += 1
        elif what is not None:
            self.overflow += 1              # the oldest waiting state dropped (a run that does not read them)
        self._first.set()

    def _on_end(self, reason: str) -> None:
        if self._closed:
            return
        self._lost = (f"ur-rtde {self.host}: joint states lost ({reason}); the joints go stale and the robot "
                      f"is stopped (R27) until the connection is back")
        log(self._lost)

    def _keep_connected(self) -> None:
        while not self._closed:
            time.sleep(self.retry_s)
            if self._lost is None or self._closed:
                continue
            try:
                check_reachable(self.host, "ur-rtde joints", 0.5)
                worker = self._connect()
            except UrError:
                continue
            old, self._worker = self._worker, worker
            old.close()
            self._lost = None
            log(f"ur-rtde {self.host}: joint states back")

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
        self._worker.close()


@register_joints("ur-rtde")
def open_ur_rtde_joints(argument: str, rig, context: dict) -> UrRtdeJoints:
    """Factory of ``ur-rtde:HOST[:30004]``."""
    try:
        host = parse_address(argument, "--joints ur-rtde")
    except UrError as exc:
        raise JointSourceError(str(exc)) from None
    return follow_beside_simulator(UrRtdeJoints(host, rig), f"ur-rtde:{host}", context)    # sim: cameras follow it
