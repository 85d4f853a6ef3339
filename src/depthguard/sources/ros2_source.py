"""Live ROS 2 topics as sources, through Zenoh: frames ``ros2:`` and joint states ``ros2:[TOPIC]`` (R27, R31).

The cell's ROS 2 nodes run with ``RMW_IMPLEMENTATION=rmw_zenoh_cpp`` and a Zenoh router;
depthguard joins as a node ``/depthguard`` (a Zenoh client of that router, wire contract in
:mod:`depthguard.transport.ros2_zenoh`; router and domain from ``monitor --ros2-router``,
``--ros2-domain``). Topics are the bag source's (``docs/BAGS.md``): camera ``ID`` reads its
``topic:`` of the rig (default ``/ID/depth/image_rect_raw``, ``sensor_msgs/msg/Image`` in
``16UC1`` / ``mono16`` mm or ``32FC1`` m) and the sibling ``camera_info``; joint states are
``sensor_msgs/msg/JointState`` on ``/joint_states`` (or ``ros2:TOPIC``), matched to the
robot's joints by name. Decoding and checks are the bag source's own
(:func:`~depthguard.transport.ros_messages.depth_from_image`, :func:`~depthguard.sources.bag.image_problem`,
:func:`~depthguard.transport.ros_messages.intrinsics_from_camera_info`,
:func:`~depthguard.sources.joints.check_joint_state`).

**Time.** The header stamp is the capture time, on the wall clock of the cell (ROS time;
synchronise the machines). The sources are ``live``: a real-time run runs on ``time.time()``.

**Never a frame with the wrong intrinsics.** A frame is used only if the newest CameraInfo
of its camera received before it agrees with the rig (width, height, fx, fy, cx, cy within
0.001 px, zero distortion). Frames before any CameraInfo, or after one that disagrees, are
skipped and counted; so is every bad message. Counters (``counters()``, in the monitor's
summary) by ``reason:camera`` or ``reason:topic``:

- ``no_camera_info``, ``camera_info_refused`` (disagrees with the rig or unusable; the
  message says why in ``last_error``), ``unknown_encoding``, ``wrong_size``,
  ``wrong_data_length``, ``undecodable`` — frames (camera ids);
- ``out_of_order`` — a frame or joint state not newer than the last one used;
- ``overflow`` — the oldest frames or joint states dropped because nobody took them;
- ``joints_partial``, ``joints_invalid`` — JointStates lacking a robot joint / outside limits;
- ``wrong_type``, ``bad_attachment``, ``undecodable``, ``rejected`` — samples (topics),
  from :class:`~depthguard.transport.ros2_zenoh.Ros2Subscription`.
"""

from __future__ import annotations

import threading

import numpy as np

from depthguard.sources.bag import INTRINSICS_TOL_PX, camera_depth_scale, default_topic, image_problem, info_topic
from depthguard.sources.base import register_joints, register_source
from depthguard.sources.frame import Frame
from depthguard.sources.joints import JointSourceError, _robot, check_joint_state
from depthguard.sources.stamped_queue import StampedQueue
from depthguard.transport import ros_messages as rosmsg
from depthguard.transport.ros2_zenoh import Ros2Error, check_topic, node_for

__all__ = ["Ros2Frames", "Ros2Joints", "MAX_PENDING_FRAMES", "MAX_PENDING_STATES"]

#: frames per camera waiting to be taken (a monitor takes them every few ms)
MAX_PENDING_FRAMES = 8
#: joint states waiting to be taken: 1 s of a 1 kHz driver, 5 s at 200 Hz. A live run starts
#: with what came in while the monitor started (seconds of states): a deeper queue made the
#: run's first cycles drain a backlog of old states and refuse the new frames as "future"
MAX_PENDING_STATES = 1000


class Ros2Frames:
    """Frame source ``ros2:``: the rig cameras' depth images from live ROS 2 topics (module docstring)."""

    live = True           # stamps on the wall clock: the run's clock is then too
    first_stamp = None

    def __init__(self, node, rig):
        self.node = node
        self.rig = rig
        self._lock = threading.Lock()
        self._closed = False
        self._subs = []
        self.camera_ids = list(rig.camera_ids)
        self._cams = {c.id: c for c in rig.cameras}
        self._order = {c: i for i, c in enumerate(self.camera_ids)}
        self._queues = {c: StampedQueue(MAX_PENDING_FRAMES) for c in self.camera_ids}   # the monitor uses the newest
        self._info_ok: dict[str, bool] = {}
        self.frames = {c: 0 for c in self.camera_ids}
        self.lost = None
        try:
            self.topics = {c.id: check_topic(rig.topics.get(c.id) or default_topic(c.id)) for c in rig.cameras}
            for cid, topic in self.topics.items():
                self._subs.append(node.subscribe(info_topic(topic), rosmsg.MSG["CameraInfo"],
                                                 lambda msg, _ns, c=cid: self._on_info(c, msg)))
                self._subs.append(node.subscribe(topic, rosmsg.MSG["Image"],
                                                 lambda msg, _ns, c=cid: self._on_image(c, msg)))
        except Exception:
            self.close()
            raise

    @property
    def max_pending(self) -> int:
        """Frames per camera waiting to be taken (default ``MAX_PENDING_FRAMES``; one more drops
        the oldest, counted ``overflow``)."""
        return next(iter(self._queues.values())).max_pending if self._queues else MAX_PENDING_FRAMES

    @max_pending.setter
    def max_pending(self, n: int) -> None:
        if int(n) < 1:
            raise ValueError(f"max_pending must be >= 1 (got {n!r})")
        for q in self._queues.values():
            q.max_pending = int(n)

    def _on_info(self, cid: str, msg) -> None:
        cam = self._cams[cid]
        try:
            k = rosmsg.intrinsics_from_camera_info(msg)
            rig_k = {"width": cam.width, "height": cam.height, "fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy}
            bad = [f"{n}={k[n]:.6g} (rig {v:.6g})" for n, v in rig_k.items() if abs(k[n] - v) > INTRINSICS_TOL_PX]
            if bad:
                raise rosmsg.RosMessageError(f"disagrees with camera {cid} of the rig: {', '.join(bad)}")
        except rosmsg.RosMessageError as exc:
            if self._info_ok.get(cid) is not False:
                self.node.count(f"camera_info_refused:{cid}",
                                f"CameraInfo of {cid} at {rosmsg.stamp_s(msg.header.stamp):.9f}: {exc}; its frames "
                                "are not used until a CameraInfo agrees with the rig")
            self._info_ok[cid] = False
            return
        self._info_ok[cid] = True

    def _on_image(self, cid: str, msg) -> None:
        cam = self._cams[cid]
        ok = self._info_ok.get(cid)
        if ok is not True:
            self.node.count(f"{'no_camera_info' if ok is None else 'camera_info_refused'}:{cid}")
            return
        stamp = rosmsg.stamp_s(msg.header.stamp)
        problem = image_problem(str(msg.encoding), int(msg.height), int(msg.width), int(msg.step),
                                int(len(msg.data)), cam)
        if problem is not None:
            self.node.count(f"{problem}:{cid}", f"frame of {cid} at {stamp:.9f}: {problem.replace('_', ' ')} "
                                                f"({msg.encoding}, {msg.width}x{msg.height}, step {msg.step}, "
                                                f"{len(msg.data)} bytes)")
            return
        try:
            depth = rosmsg.depth_from_image(msg, expect_shape=(cam.height, cam.width),
                                            scale=camera_depth_scale(self.rig, cid))     # the rig's depth units
        except rosmsg.RosMessageError as exc:
            self.node.count(f"undecodable:{cid}", f"frame of {cid} at {stamp:.9f}: {exc}")
            return
        if self._closed:
            return
        what = self._queues[cid].offer(stamp, Frame(cid, depth, stamp))
        if what is not None:
            self.node.count(f"{what}:{cid}")
        if what != "out_of_order":
            with self._lock:
                self.frames[cid] += 1

    def frames_until(self, t: float) -> list[Frame]:
        """The frames received with stamp <= ``t`` (s) not given yet, in stamp order."""
        out = [f for q in self._queues.values() for f in q.until(t)]
        out.sort(key=lambda f: (f.stamp, self._order[f.camera_id]))
        return out

    @property
    def done(self) -> bool:
        return self._closed

    def counters(self) -> dict:
        """What was received and not used, by reason (module docstring); joints' too."""
        return self.node.counters()

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
        for s in self._subs:
            s.close()
        self.node.release()


class Ros2Joints:
    """Joint source ``ros2:[TOPIC]``: the robot's joints by name from live ``JointState`` s."""

    live = True
    first_stamp = None
    lost = None

    def __init__(self, node, rig, topic: str = "/joint_states"):
        self.node = node
        self._queue = StampedQueue(MAX_PENDING_STATES)
        self._lock = threading.Lock()
        self.states = 0
        self._closed = False
        try:
            self.robot = _robot(rig)
            self.names = list(self.robot.joint_names)
            self.topic = check_topic(topic)
            self._sub = node.subscribe(self.topic, rosmsg.MSG["JointState"], lambda msg, _ns: self._on_state(msg))
        except Exception:
            node.release()
            raise

    def _on_state(self, msg) -> None:
        stamp = rosmsg.stamp_s(msg.header.stamp)
        try:
            q = rosmsg.joint_state_values(msg, self.names)
        except rosmsg.RosMessageError as exc:
            self.node.count("joints_invalid", f"{self.topic} at {stamp:.9f}: {exc}")
            return
        if q is None:
            self.node.count("joints_partial", f"{self.topic} at {stamp:.9f}: names {list(msg.name)} lack one of "
                                              f"the robot's joints {self.names}")
            return
        try:
            stamp, q = check_joint_state(self.robot, stamp, q)
        except JointSourceError as exc:
            self.node.count("joints_invalid", f"{self.topic} at {stamp:.9f}: {exc}")
            return
        what = self._queue.offer(stamp, (stamp, q))
        if what is not None:
            self.node.count(f"joints_{what}")
        if what != "out_of_order":
            with self._lock:
                self.states += 1

    def states_until(self, t: float) -> list[tuple[float, np.ndarray]]:
        """The received states with stamp <= ``t`` (s) not given yet, in stamp order."""
        return self._queue.until(t)

    @property
    def done(self) -> bool:
        return self._closed

    def counters(self) -> dict:
        return self.node.counters()

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._sub.close()
        self.node.release()


@register_source("ros2")
def open_ros2_frames(argument: str, rig, context: dict) -> Ros2Frames:
    """Factory of ``ros2:`` (topics from the rig; router and domain from ``context``)."""
    if argument:
        raise Ros2Error(f"ros2:{argument}: the frame source takes no argument (the cameras' topics come from the "
                        "rig's topic:, the router and domain from --ros2-router / --ros2-domain)")
    return Ros2Frames(node_for(context), rig)


@register_joints("ros2")
def open_ros2_joints(argument: str, rig, context: dict) -> Ros2Joints:
    """Factory of ``ros2:[TOPIC]`` (default ``/joint_states``)."""
    return Ros2Joints(node_for(context), rig, argument or "/joint_states")
