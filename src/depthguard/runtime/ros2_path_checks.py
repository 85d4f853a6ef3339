"""``depthguard check-path`` over ROS 2: a ``trajectory_msgs/JointTrajectory`` in, the verdict out (R22, R37; issue 30).

A topic pair on the node of the run (wire contract: :mod:`depthguard.transport.ros2_zenoh`),
under a namespace (default ``/depthguard``):

- ``<ns>/check_path/request`` — subscribed, ``trajectory_msgs/msg/JointTrajectory``: the planned
  path. ``joint_names`` must be the robot's joints, in its order or any permutation of it (the
  positions are reordered; an empty list means the robot's order); each point's
  ``time_from_start`` is its stamp (s from the trajectory's start) and its ``positions`` its
  joints (rad). Velocities, accelerations and efforts are not used.
- ``<ns>/check_path/verdict`` — published, ``std_msgs/msg/String``, one per request, never
  silence: the JSON object of ``depthguard check-path --json``
  (:meth:`~depthguard.control.path_check.PathVerdict.as_dict`: ``verdict`` safe / maybe /
  unsafe, ``first_not_safe``, ``reasons``, ``segments`` with ``t0``, ``t1`` in s from the
  trajectory's start) plus ``request_stamp`` (the request's ``header.stamp`` in s, so a client
  matches its verdict: give each request a distinct stamp) and ``request_frame_id``. A refused
  trajectory (names that are not the robot's joints, a wrong joint count, times not
  increasing, joints outside limits, NaN, fewer than 2 points) gets ``verdict`` ``"refused"``
  and ``error``: one line naming the waypoint (0-based). Reliable, volatile, depth 10.

The checks run on a thread of their own (never on Zenoh's callback thread, which also
delivers the joint states), in the order received, against the monitor's newest map
(:meth:`~depthguard.runtime.monitor_paths.MonitorPaths.check_path`; the map is started if it is off).
"""

from __future__ import annotations

import json
import math
import queue
import threading

import numpy as np

from depthguard.transport.ros2_zenoh import Ros2Error, check_topic

__all__ = ["REQUEST_TYPE", "VERDICT_TYPE", "Ros2PathChecks", "trajectory_path"]

REQUEST_TYPE = "trajectory_msgs/msg/JointTrajectory"
VERDICT_TYPE = "std_msgs/msg/String"
_BACKLOG = 16


def trajectory_path(msg, robot) -> tuple[np.ndarray, np.ndarray]:
    """A ``JointTrajectory`` -> ``(stamps (n,) s, q (n, dof) rad)`` in the robot's joint order
    (module docstring), checked by :func:`~depthguard.control.path_check.validate_path`;
    ``ValueError`` (one line, naming the waypoint) otherwise."""
    from depthguard.control.path_check import validate_path

    want = list(robot.joint_names)
    names = [str(n) for n in msg.joint_names]
    if not names:
        names = want
    if sorted(names) != sorted(want) or len(set(names)) != len(names):
        raise ValueError(f"joint_names {names} are not the joints of {robot.name} ({want}, in any order)")
    order = [names.index(n) for n in want]
    if len(msg.points) < 2:
        raise ValueError(f"a path needs at least 2 waypoints, got {len(msg.points)}")
    stamps = np.empty(len(msg.points))
    q = np.empty((len(msg.points), len(want)))
    for i, p in enumerate(msg.points):
        pos = np.asarray(p.positions, dtype=np.float64).reshape(-1)
        if len(pos) != len(names):
            raise ValueError(f"waypoint {i}: {len(pos)} positions for {len(names)} joint_names")
        q[i] = pos[order]
        stamps[i] = p.time_from_start.sec + p.time_from_start.nanosec * 1e-9
    return validate_path(stamps, q, robot)


class Ros2PathChecks:
    """Answers ``<ns>/check_path/request`` on ``<ns>/check_path/verdict`` (module docstring) with
    ``monitor``'s path check. ``node``: an acquired
    :class:`~depthguard.transport.ros2_zenoh.Ros2Node` (released at :meth:`close`);
    ``answered``: verdicts sent (refusals included)."""

    def __init__(self, node, monitor, namespace: str = "/depthguard"):
        from depthguard.runtime.ros2_sink import _register_wire
        from depthguard.transport.ros2_zenoh import WIRE

        self.node, self.monitor = node, monitor
        self.answered = 0
        self._q: queue.Queue = queue.Queue(maxsize=_BACKLOG)
        try:
            ns = check_topic(namespace).rstrip("/")
            _register_wire()
            self._string = WIRE.types[VERDICT_TYPE]
            self.request_topic, self.verdict_topic = f"{ns}/check_path/request", f"{ns}/check_path/verdict"
            self._pub = node.publisher(self.verdict_topic, VERDICT_TYPE, depth=10)
            self._thread = threading.Thread(target=self._run, name="depthguard-ros2-check-path", daemon=True)
            self._thread.start()
            self._sub = node.subscribe(self.request_topic, REQUEST_TYPE, self._on_request, depth=10)
        except Exception:
            node.release()
            raise

    def _on_request(self, msg, _stamp_ns) -> None:
        try:
            self._q.put_nowait(msg)
        except queue.Full:
            self._answer(msg, None, f"refused: {_BACKLOG} requests are waiting; send fewer at once")

    def _run(self) -> None:
        while True:
            msg = self._q.get()
            if msg is None:
                return
            if getattr(self.monitor, "_closed", False):     # the run ends: its map is gone
                self._answer(msg, None, "refused: the monitor is closing")
                continue
            try:
                t, q = trajectory_path(msg, self.monitor.robot)
                verdict = self.monitor.check_path(t, q)
            except ValueError as exc:
                self._answer(msg, None, str(exc))
            except Exception as exc:  # noqa: BLE001 - a request that breaks the check still gets its answer
                self._answer(msg, None, f"{type(exc).__name__}: {exc}")
            else:
                self._answer(msg, verdict.as_dict(), None)

    def _answer(self, msg, verdict: dict | None, error: str | None) -> None:
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        out = {"request_stamp": stamp, "request_frame_id": str(msg.header.frame_id)}
        out.update(verdict if verdict is not None else {"verdict": "refused", "error": error})
        if isinstance(out.get("map_stamp"), float) and not math.isfinite(out["map_stamp"]):
            out["map_stamp"] = None                  # JSON has no NaN (no map yet)
        try:
            self._pub.publish(self._string(data=json.dumps(out)))
            self.answered += 1
        except Exception as exc:  # noqa: BLE001 - closed while answering: counted, never a crash
            self.node.count(f"unanswered:{self.request_topic}", f"{self.verdict_topic}: {exc}")

    def close(self) -> None:
        if self._sub is None:
            return
        self._sub.close()
        self._sub = None
        self._q.put(None)
        self._thread.join(timeout=5.0)
        self._pub.close()
        self.node.release()


def open_path_checks(context: dict, monitor, namespace: str = "/depthguard") -> Ros2PathChecks:
    """The responder on the run's node (shared with ``ros2:`` sources and sinks through ``context``)."""
    from depthguard.transport.ros2_zenoh import node_for

    if monitor.robot is None:
        raise Ros2Error("check_path over ROS 2 needs a rig with a robot")
    return Ros2PathChecks(node_for(context), monitor, namespace)
