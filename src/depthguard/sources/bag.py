"""A ROS 2 bag as a source: frames ``bag:PATH`` and joint states ``bag:PATH`` (R31).

``PATH`` is a rosbag2 directory (``metadata.yaml`` + ``.mcap`` or ``.db3``) or one
``.mcap`` file (e.g. written by another MCAP tool). Read with ``rosbags``; no ROS needed.

**Topics.** Camera ``ID`` of the rig reads the depth ``sensor_msgs/msg/Image`` on its
``topic:`` (rig file), by default ``/ID/depth/image_rect_raw``, and its
``sensor_msgs/msg/CameraInfo`` on the sibling ``camera_info`` topic
(``/ID/depth/camera_info``). Joint states are ``sensor_msgs/msg/JointState`` on
``/joint_states`` (or the bag's only JointState topic), matched to the rig robot's
joints **by name** (extra joints are ignored). Depth decoding: :mod:`depthguard.sources.ros_messages`.

**Time.** The header stamp is the capture time; the bag's own log time (when the
recorder received the message) is not used. Frames and joint states are served in
header-stamp order; the monitor's clock starts at the smallest stamp.

**Checks when the bag opens** (a first pass reads every message; images are not decoded):

- errors (:class:`BagError`, one sentence): the path is not a bag; the file is truncated or
  damaged; a rig camera's image topic or its CameraInfo is missing; a CameraInfo disagrees
  with the rig's intrinsics or has distortion (never a frame with the wrong intrinsics);
  a camera has no usable frame; the JointState messages never name all the robot's joints.
- skipped and counted (:meth:`BagReplay.counters`, in the monitor's summary): a frame with an
  unknown encoding, the wrong size or the wrong amount of data; a frame or joint state
  whose stamp repeats an earlier one of its camera / of the joints; a JointState lacking one
  of the robot's joints or outside its limits; Image topics of cameras that are not in the rig.
  Stamps that arrive out of order are put in order (counted as ``reordered``).

**Replay.** A second pass streams the images in bag order and decodes each when it is
due (a small buffer re-orders them by stamp), so memory stays bounded; joint states
and camera infos are held from the first pass. The result is a pure function of the
bag: two ``--fast`` replays give the same log byte for byte.
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from depthguard.sources.base import register_joints, register_source
from depthguard.sources.frame import Frame
from depthguard.sources import ros_messages as rosmsg

__all__ = ["BagError", "BagReplay", "BagFrames", "BagJoints", "default_topic", "info_topic", "open_bag"]

#: the monitor serves a frame at a control time t when stamp <= t + this (a stamp rounded to the ns)
STAMP_SLACK_S = 1e-9
#: intrinsics of a CameraInfo and of the rig agree within this many pixels
INTRINSICS_TOL_PX = 1e-3


class BagError(ValueError):
    """A bag that cannot be used as asked (the message names the bag, topic and reason)."""


def default_topic(camera_id: str) -> str:
    """The depth Image topic of a camera without a ``topic:`` (and the one ``record`` writes)."""
    return f"/{camera_id}/depth/image_rect_raw"


def info_topic(image_topic: str) -> str:
    """The CameraInfo topic beside an image topic (image_transport's convention)."""
    return image_topic.rsplit("/", 1)[0] + "/camera_info"


def open_bag(path: str | Path):
    """An opened ``rosbags.rosbag2.Reader``; :class:`BagError` for a missing, truncated or
    damaged bag."""
    from rosbags.rosbag2 import Reader

    p = Path(path)
    if not p.exists():
        raise BagError(f"bag {p} does not exist")
    if p.is_file() and p.suffix.lower() not in (".mcap", ".db3"):
        raise BagError(f"bag {p}: a bag is a rosbag2 directory or one .mcap / .db3 file")
    if p.is_dir() and not (p / "metadata.yaml").is_file():
        raise BagError(f"bag {p}: a directory without metadata.yaml is not a rosbag2 bag "
                       "(give the .mcap file itself)")
    try:
        reader = Reader(p)
        reader.open()
    except Exception as exc:  # noqa: BLE001 - rosbags raises its own error types
        raise BagError(f"bag {p} cannot be read: {exc} (truncated or damaged? a killed recorder leaves "
                       "an unfinished file: `mcap recover` or `ros2 bag reindex` repairs it)") from None
    return reader


@dataclass
class _ImageEntry:
    stamp: float
    topic: str
    conn: int
    ordinal: int            # index of the message among its connection's messages
    encoding: str
    height: int
    width: int
    step: int
    nbytes: int
    bigendian: bool


class BagReplay:
    """One opened bag and what its first pass found (module docstring), shared by the frame and
    joint sources of a run (``context["bag:" + path]``).

    ``images[topic]``: image entries in bag order; ``infos[topic]``: ``[(stamp, msg)]``;
    ``joint_msgs[topic]``: ``[(stamp, msg)]``; ``tf``: ``[(stamp, static, TransformStamped)]``;
    ``strings[topic]``: ``std_msgs/msg/String`` payloads (``/robot_description``).
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.reader = open_bag(self.path)
        self.images: dict[str, list[_ImageEntry]] = defaultdict(list)
        self.infos: dict[str, list] = defaultdict(list)
        self.joint_msgs: dict[str, list] = defaultdict(list)
        self.tf: list = []
        self.strings: dict[str, list[str]] = defaultdict(list)
        self.counts: dict[str, int] = defaultdict(int)
        self._scan()

    def _scan(self) -> None:
        counter: dict[int, int] = defaultdict(int)
        wanted = {rosmsg.MSG[k] for k in ("Image", "CameraInfo", "JointState", "TFMessage", "String")}
        conns = [c for c in self.reader.connections if c.msgtype in wanted]
        try:
            for con, _logtime, raw in self.reader.messages(connections=conns):
                i = counter[con.id]
                counter[con.id] += 1
                try:
                    msg = rosmsg.deserialize(raw, con.msgtype)
                except Exception:  # noqa: BLE001 - a message that does not decode is counted, not used
                    self.counts[f"undecodable:{con.topic}"] += 1
                    continue
                if con.msgtype == rosmsg.MSG["Image"]:
                    self.images[con.topic].append(_ImageEntry(
                        rosmsg.stamp_s(msg.header.stamp), con.topic, con.id, i, str(msg.encoding), int(msg.height),
                        int(msg.width), int(msg.step), int(len(msg.data)), bool(msg.is_bigendian)))
                elif con.msgtype == rosmsg.MSG["CameraInfo"]:
                    self.infos[con.topic].append((rosmsg.stamp_s(msg.header.stamp), msg))
                elif con.msgtype == rosmsg.MSG["JointState"]:
                    self.joint_msgs[con.topic].append((rosmsg.stamp_s(msg.header.stamp), msg))
                elif con.msgtype == rosmsg.MSG["TFMessage"]:
                    for tr in msg.transforms:
                        self.tf.append((rosmsg.stamp_s(tr.header.stamp), con.topic == "/tf_static", tr))
                elif con.msgtype == rosmsg.MSG["String"]:
                    self.strings[con.topic].append(str(msg.data))
        except Exception as exc:  # noqa: BLE001 - a damaged chunk in the middle of the file
            self.close()
            raise BagError(f"bag {self.path} cannot be read to its end: {type(exc).__name__}: {exc} "
                           "(truncated or damaged?)") from None

    def image_stream(self, conns: set[int]):
        """``(conn id, ordinal, raw)`` of the image messages of ``conns``, in bag order."""
        counter: dict[int, int] = defaultdict(int)
        chosen = [c for c in self.reader.connections if c.id in conns]
        for con, _logtime, raw in self.reader.messages(connections=chosen):
            i = counter[con.id]
            counter[con.id] += 1
            yield con.id, i, raw

    def counters(self) -> dict:
        return dict(sorted(self.counts.items()))

    def close(self) -> None:
        if self.reader is not None:
            self.reader.close()
            self.reader = None


def _check_infos(replay: BagReplay, cam, topic: str) -> None:
    """Every CameraInfo of ``cam`` must be usable and agree with the rig (else :class:`BagError`)."""
    itopic = info_topic(topic)
    infos = replay.infos.get(itopic, [])
    if not infos:
        raise BagError(f"bag {replay.path}: camera {cam.id}: no CameraInfo on {itopic} (the intrinsics of "
                       f"{topic} cannot be checked; record camera_info beside the depth image)")
    for stamp, msg in infos:
        try:
            k = rosmsg.intrinsics_from_camera_info(msg)
        except rosmsg.RosMessageError as exc:
            raise BagError(f"bag {replay.path}: {itopic} at stamp {stamp:.9f}: {exc}") from None
        rig_k = {"width": cam.width, "height": cam.height, "fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy}
        bad = [f"{n}={k[n]:.6g} (rig {v:.6g})" for n, v in rig_k.items() if abs(k[n] - v) > INTRINSICS_TOL_PX]
        if bad:
            raise BagError(f"bag {replay.path}: {itopic} at stamp {stamp:.9f} disagrees with camera {cam.id} of the "
                           f"rig: {', '.join(bad)}; draft the rig from the bag (`depthguard rig from-bag`) or fix it")


class BagFrames:
    """Frame source ``bag:PATH`` (module docstring): the rig cameras' depth frames in stamp order.

    ``first_stamp``: the smallest stamp served (s); ``skipped``: frames not served.
    """

    def __init__(self, replay: BagReplay, rig):
        self.replay = replay
        self._rig = rig
        topics = {c.id: rig.topics.get(c.id) or default_topic(c.id) for c in rig.cameras}
        counts = replay.counts
        entries: list[tuple[float, str, _ImageEntry]] = []
        for cam in rig.cameras:
            topic = topics[cam.id]
            if topic not in replay.images:
                found = sorted(replay.images) or ["none"]
                raise BagError(f"bag {replay.path}: camera {cam.id}: no Image on {topic} (image topics in the bag: "
                               f"{', '.join(found)}); set the camera's topic: in the rig")
            _check_infos(replay, cam, topic)
            seen: set[float] = set()
            last = -math.inf
            kept = []
            for e in replay.images[topic]:
                reason = self._problem(e, cam)
                if reason is None and e.stamp in seen:
                    reason = "repeated_stamp"
                if reason is not None:
                    counts[f"{reason}:{cam.id}"] += 1
                    continue
                if e.stamp < last:
                    counts[f"reordered:{cam.id}"] += 1
                last = max(last, e.stamp)
                seen.add(e.stamp)
                kept.append(e)
            if not kept:
                raise BagError(f"bag {replay.path}: camera {cam.id}: none of the {len(replay.images[topic])} images "
                               f"on {topic} can be used ({self._reasons(cam.id)})")
            entries += [(e.stamp, cam.id, e) for e in kept]
        for t in sorted(set(replay.images) - set(topics.values())):
            counts[f"not_in_rig:{t}"] += len(replay.images[t])
        order = {c.id: i for i, c in enumerate(rig.cameras)}
        entries.sort(key=lambda x: (x[0], order[x[1]], x[2].ordinal))
        self._entries = entries
        self.camera_ids = list(rig.camera_ids)
        self.first_stamp = entries[0][0]
        self._want = {(e.conn, e.ordinal) for _s, _c, e in entries}
        self._stream = None
        self._buffer: dict[tuple[int, int], bytes] = {}
        self._next = 0
        self._closed = False
        self.lost = None

    def _reasons(self, cam_id: str) -> str:
        return ", ".join(f"{k.split(':')[0]} {v}" for k, v in self.replay.counts.items() if k.endswith(":" + cam_id))

    @staticmethod
    def _problem(e: _ImageEntry, cam) -> str | None:
        if e.encoding not in rosmsg.DEPTH_ENCODINGS:
            return "unknown_encoding"
        if (e.height, e.width) != (cam.height, cam.width):
            return "wrong_size"
        item = np.dtype(rosmsg.DEPTH_ENCODINGS[e.encoding][0]).itemsize
        if e.step < e.width * item or e.nbytes != e.step * e.height:
            return "wrong_data_length"
        return None

    @property
    def skipped(self) -> int:
        return sum(v for k, v in self.replay.counts.items() if not k.startswith(("reordered", "not_in_rig")))

    @property
    def done(self) -> bool:
        return self._closed or self._next >= len(self._entries)

    def _raw(self, key: tuple[int, int]) -> bytes:
        if self._stream is None:
            self._stream = self.replay.image_stream({c for c, _o in self._want})
        while key not in self._buffer:
            conn, i, raw = next(self._stream)
            if (conn, i) in self._want:
                self._buffer[(conn, i)] = raw
        return self._buffer.pop(key)

    def frames_until(self, t: float) -> list[Frame]:
        """The frames with stamp <= ``t`` (s) not given yet, in stamp order, decoded now."""
        out = []
        while not self._closed and self._next < len(self._entries) and self._entries[self._next][0] <= t + STAMP_SLACK_S:
            stamp, cid, e = self._entries[self._next]
            self._next += 1
            try:
                msg = rosmsg.deserialize(self._raw((e.conn, e.ordinal)), rosmsg.MSG["Image"])
                depth = rosmsg.depth_from_image(msg, expect_shape=(e.height, e.width))
            except Exception as exc:  # noqa: BLE001 - a frame that cannot be read is skipped and counted, never a crash
                self.replay.counts[f"undecodable:{cid}"] += 1
                self.lost = self.lost or f"bag {self.replay.path}: frame of {cid} at {stamp:.9f}: {exc}"
                continue
            out.append(Frame(cid, depth, stamp))
        return out

    def counters(self) -> dict:
        """What was skipped, re-ordered or ignored, by ``reason:camera`` (or ``not_in_rig:topic``)."""
        return self.replay.counters()

    def close(self) -> None:
        self._closed = True
        self._buffer.clear()
        self._stream = None
        self.replay.close()


class BagJoints:
    """Joint source ``bag:PATH``: the robot's ``JointState`` s by name, in stamp order (module docstring)."""

    def __init__(self, replay: BagReplay, rig, topic: str | None = None):
        from depthguard.sources.joints import JointSourceError, _robot, check_joint_state

        robot = _robot(rig)
        self.replay = replay
        topics = sorted(replay.joint_msgs)
        if topic is None:
            topic = "/joint_states" if "/joint_states" in topics else (topics[0] if len(topics) == 1 else None)
        if topic is None or topic not in replay.joint_msgs:
            raise BagError(f"bag {replay.path}: no JointState topic to use (JointState topics: "
                           f"{', '.join(topics) or 'none'}; the default is /joint_states)")
        names = list(robot.joint_names)
        counts = replay.counts
        states: list[tuple[float, np.ndarray]] = []
        seen: set[float] = set()
        last = -math.inf
        for stamp, msg in replay.joint_msgs[topic]:
            try:
                q = rosmsg.joint_state_values(msg, names)
            except rosmsg.RosMessageError:
                q = None
            if q is None:
                counts["joints_partial"] += 1
                continue
            try:
                stamp, q = check_joint_state(robot, stamp, q)
            except JointSourceError:
                counts["joints_invalid"] += 1
                continue
            if stamp in seen:
                counts["joints_repeated_stamp"] += 1
                continue
            if stamp < last:
                counts["joints_reordered"] += 1
            last = max(last, stamp)
            seen.add(stamp)
            states.append((stamp, q))
        if not states:
            example = list(replay.joint_msgs[topic][0][1].name) if replay.joint_msgs[topic] else []
            raise BagError(f"bag {replay.path}: no JointState on {topic} names all of the robot {robot.name}'s "
                           f"joints {names} within their limits (the first names {example})")
        states.sort(key=lambda s: s[0])
        self._states = states
        self.first_stamp = states[0][0]
        self._next = 0
        self._closed = False
        self.lost = None

    def states_until(self, t: float) -> list[tuple[float, np.ndarray]]:
        out = []
        while not self._closed and self._next < len(self._states) and self._states[self._next][0] <= t + STAMP_SLACK_S:
            s, q = self._states[self._next]
            out.append((s, q.copy()))
            self._next += 1
        return out

    @property
    def done(self) -> bool:
        return self._closed or self._next >= len(self._states)

    def counters(self) -> dict:
        return self.replay.counters()

    def close(self) -> None:
        self._closed = True
        self.replay.close()


def _replay(argument: str, context: dict) -> BagReplay:
    if not argument:
        raise BagError("the bag source needs a path: bag:PATH (a rosbag2 directory or an .mcap file)")
    key = "bag:" + str(Path(argument).resolve())
    if key not in context:
        context[key] = BagReplay(argument)
    return context[key]


@register_source("bag")
def open_bag_frames(argument: str, rig, context: dict) -> BagFrames:
    """Factory of the frame source ``bag:PATH`` (the opened bag is shared through ``context``)."""
    return BagFrames(_replay(argument, context), rig)


@register_joints("bag")
def open_bag_joints(argument: str, rig, context: dict) -> BagJoints:
    """Factory of the joint source ``bag:PATH`` (``bag:PATH#TOPIC`` picks a JointState topic)."""
    path, _, topic = argument.partition("#")
    return BagJoints(_replay(path, context), rig, topic or None)
