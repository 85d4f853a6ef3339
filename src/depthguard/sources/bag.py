"""A ROS 2 bag as a source: frames ``bag:PATH`` and joint states ``bag:PATH`` (R31).

``PATH`` is a rosbag2 directory (``metadata.yaml`` + ``.mcap`` or ``.db3``) or one
``.mcap`` file (e.g. written by another MCAP tool). Read with ``rosbags``; no ROS needed.

**Topics.** Camera ``ID`` of the rig reads the depth ``sensor_msgs/msg/Image`` on its
``topic:`` (rig file), by default ``/ID/depth/image_rect_raw``, and its
``sensor_msgs/msg/CameraInfo`` on the sibling ``camera_info`` topic
(``/ID/depth/camera_info``). Joint states are ``sensor_msgs/msg/JointState`` on
``/joint_states`` (or the bag's only JointState topic), matched to the rig robot's
joints **by name** (extra joints are ignored). Depth decoding: :mod:`depthguard.transport.ros_messages`;
16-bit depth is ``value x depth_scale`` metres, the camera's ``depth_scale:`` in the rig
(default 0.001: millimetres; a RealSense D405 records 0.0001). The drivers' layouts (realsense-ros,
Orbbec, Azure Kinect; which topics are depth, ``P`` for an ``image_rect`` topic): :mod:`depthguard.sources.bag_layouts`.

**Time.** The header stamp is the capture time; the bag's own log time (when the
recorder received the message) is not used. Frames and joint states are served in
header-stamp order; the monitor's clock starts at the smallest stamp.

**One pass.** The frame and joint sources of a run share one reading of the bag in bag
order (:class:`~depthguard.sources.bag_stream.BagPass`: each zstd chunk is decompressed
once); images wait in a re-order window of :data:`~depthguard.sources.bag_stream.REORDER_WINDOW_S`
and are decoded when served, so memory stays bounded whatever the bag's length. The result
is a pure function of the bag: two ``--fast`` replays give the same log byte for byte.

**Checks.**

- when the source opens (:class:`BagError`, one sentence): the path is not a bag; the file is
  truncated; a rig camera's image topic or its CameraInfo topic has no message; no JointState topic.
- as the bag is read (:class:`BagError` from ``first_stamp`` / ``frames_until`` /
  ``states_until``; it stops the replay: the frames before it were checked): a CameraInfo that
  disagrees with the rig's intrinsics or has distortion — never a frame with the wrong
  intrinsics; a damaged chunk; a camera whose first images are all unusable, or that has no
  usable frame in the whole bag; JointStates that never name all the robot's joints.
- skipped and counted (:meth:`BagFrames.counters`, in the monitor's summary): a frame with an
  unknown encoding, the wrong size or the wrong amount of data; a frame or joint state whose
  stamp repeats one of its camera / of the joints (``repeated_stamp``), or that arrives more than
  the re-order window after newer stamps (``late``); a frame served before any CameraInfo of its
  camera was read (``before_camera_info``); a JointState lacking one of the robot's joints or
  outside its limits; Image topics of cameras that are not in the rig (``not_in_rig``, not read).
  Stamps that arrive out of order within the window are put in order (counted as ``reordered``).
"""

from __future__ import annotations

import math
from functools import partial
from pathlib import Path

import numpy as np

from depthguard.transport import ros_messages as rosmsg
from depthguard.sources.bag_replay import INTRINSICS_TOL_PX, _ImageEntry  # noqa: F401 (for the live ROS 2 source)
from depthguard.sources.bag_replay import (BagConsumer, BagError, BagReplay, camera_depth_scale, check_camera_info,
                                           default_topic, info_topic, open_bag, sdk_recording_hint)
from depthguard.sources.bag_stream import StampQueue
from depthguard.sources.base import register_joints, register_source
from depthguard.sources.frame import Frame

__all__ = ["BagError", "BagReplay", "BagFrames", "BagJoints", "default_topic", "info_topic", "open_bag",
           "camera_depth_scale", "image_problem", "INTRINSICS_TOL_PX"]

#: the monitor serves a frame at a control time t when stamp <= t + this (a stamp rounded to the ns)
STAMP_SLACK_S = 1e-9
#: a camera whose first this many images are all unusable (encoding, size, data) is an error at once
FIRST_IMAGES_CHECKED = 3
#: ``first_stamp`` reads at most this far (s of stamps) past the first frame for each camera's first one
START_WAIT_S = 2.0
_UNUSABLE = ("unknown_encoding", "wrong_size", "wrong_data_length", "undecodable")
_NOT_SKIPS = ("reordered", "not_in_rig")


def image_problem(encoding: str, height: int, width: int, step: int, nbytes: int, cam) -> str | None:
    """Why a depth image of rig camera ``cam`` cannot be used (``unknown_encoding``, ``wrong_size``,
    ``wrong_data_length``), or ``None``."""
    if encoding not in rosmsg.DEPTH_ENCODINGS:
        return "unknown_encoding"
    if (height, width) != (cam.height, cam.width):
        return "wrong_size"
    item = np.dtype(rosmsg.DEPTH_ENCODINGS[encoding][0]).itemsize
    if step < width * item or nbytes != step * height:
        return "wrong_data_length"
    return None


class BagFrames(BagConsumer):
    """Frame source ``bag:PATH`` (module docstring): the rig cameras' depth frames in stamp order.

    ``first_stamp``: the smallest stamp served (s; reads the start of the bag); ``skipped``:
    frames not served so far; ``camera_ids``: the rig's cameras.
    """

    def __init__(self, replay: BagReplay, rig):
        self._rig = rig
        self._cams = {c.id: c for c in rig.cameras}
        self._order = {c.id: i for i, c in enumerate(rig.cameras)}
        self._scale = {c.id: camera_depth_scale(rig, c.id) for c in rig.cameras}
        self._topics = {c.id: rig.topics.get(c.id) or default_topic(c.id) for c in rig.cameras}
        self.camera_ids = list(rig.camera_ids)
        images = replay.topic_counts(rosmsg.MSG["Image"])
        infos = replay.topic_counts(rosmsg.MSG["CameraInfo"])
        for cid, topic in self._topics.items():
            if topic not in images and replay.is_sdk_recording():
                raise BagError(f"bag {replay.path}: {sdk_recording_hint(replay.path)}")
            if topic not in images:
                raise BagError(f"bag {replay.path}: camera {cid}: no Image on {topic} (image topics in the bag: "
                               f"{', '.join(sorted(images)) or 'none'}); set the camera's topic: in the rig")
            if info_topic(topic) not in infos:
                raise BagError(f"bag {replay.path}: camera {cid}: no CameraInfo on {info_topic(topic)} (the "
                               f"intrinsics of {topic} cannot be checked; record camera_info beside the depth image)")
        self._not_in_rig = {f"not_in_rig:{t}": n for t, n in images.items() if t not in self._topics.values()}
        self._start(replay)

    def _reset(self) -> None:
        self._queues = {cid: StampQueue(f"camera {cid}") for cid in self._cams}
        self._read = {cid: 0 for cid in self._cams}
        self._served = {cid: 0 for cid in self._cams}
        self._info_ok = {cid: False for cid in self._cams}

    def _routes(self, reader) -> dict:
        by_image = {t: cid for cid, t in self._topics.items()}
        by_info = {info_topic(t): cid for cid, t in self._topics.items()}
        routes = {}
        for c in reader.connections:
            if c.msgtype == rosmsg.MSG["Image"] and c.topic in by_image:
                routes[c.id] = partial(self._on_image, by_image[c.topic])
            elif c.msgtype == rosmsg.MSG["CameraInfo"] and c.topic in by_info:
                routes[c.id] = partial(self._on_info, by_info[c.topic])
        return routes

    def queues(self) -> list[StampQueue]:
        return list(self._queues.values())

    def own_counts(self) -> dict:
        return {**self._not_in_rig, **self.counts}

    # --------------------------------------------------------- routing (the pass's lock held)
    def _on_image(self, cid: str, con, raw) -> None:
        if self._detached or self._closed:
            return
        self._read[cid] += 1
        try:
            msg = rosmsg.deserialize(raw, con.msgtype)
            stamp = rosmsg.stamp_s(msg.header.stamp)
        except Exception:  # noqa: BLE001 - a message that does not decode is counted, not used
            self.counts[f"undecodable:{cid}"] += 1
            return
        reason = image_problem(str(msg.encoding), int(msg.height), int(msg.width), int(msg.step), len(msg.data),
                               self._cams[cid])
        q = self._queues[cid]
        newest = q.newest
        if reason is None:
            reason = self._pass.offer(q, stamp, msg, len(raw))
        if reason is not None:
            self.counts[f"{reason}:{cid}"] += 1
            self._early_check(cid)
        elif stamp < newest:
            self.counts[f"reordered:{cid}"] += 1

    def _on_info(self, cid: str, con, raw) -> None:
        if self._detached or self._closed:
            return
        try:
            msg = rosmsg.deserialize(raw, con.msgtype)
        except Exception:  # noqa: BLE001 - counted; frames wait for a CameraInfo that decodes
            self.counts[f"undecodable:{con.topic}"] += 1
            return
        check_camera_info(self.replay.path, self._cams[cid], con.topic, rosmsg.stamp_s(msg.header.stamp), msg,
                          image_topic=self._topics[cid])
        self._info_ok[cid] = True

    @staticmethod
    def _problem(e: _ImageEntry, cam) -> str | None:
        """:func:`image_problem` of an image entry (kept for the live ROS 2 source)."""
        return image_problem(e.encoding, e.height, e.width, e.step, e.nbytes, cam)

    def _reasons(self, cid: str) -> str:
        return ", ".join(f"{k.split(':')[0]} {v}" for k, v in sorted(self.counts.items()) if k.endswith(":" + cid))

    def _early_check(self, cid: str) -> None:
        """The first images of a camera all unusable: the topic is not a depth image of this camera."""
        bad = sum(self.counts.get(f"{r}:{cid}", 0) for r in _UNUSABLE)
        if self._queues[cid].accepted == 0 and self._served[cid] == 0 and bad >= FIRST_IMAGES_CHECKED \
                and bad == self._read[cid]:
            raise BagError(f"bag {self.replay.path}: camera {cid}: none of the {bad} images read so far on "
                           f"{self._topics[cid]} can be used ({self._reasons(cid)})")

    def _check_end(self) -> None:
        if self._pass.ended and not self._detached:
            for cid, q in self._queues.items():
                if q.accepted == 0 or (len(q) == 0 and self._served[cid] == 0):
                    raise BagError(f"bag {self.replay.path}: camera {cid}: none of the {self._read[cid]} images on "
                                   f"{self._topics[cid]} can be used ({self._reasons(cid) or 'none read'})")

    # --------------------------------------------------------- serving
    @property
    def first_stamp(self) -> float:
        def every_camera_started() -> bool:       # each camera has a frame, or START_WAIT_S of bag went by
            return all(q.accepted for q in self._queues.values()) or \
                self._pass.watermark >= self._held_head() + START_WAIT_S
        return self._first_stamp(every_camera_started)

    @property
    def skipped(self) -> int:
        return sum(v for k, v in self.counts.items() if not k.startswith(_NOT_SKIPS))

    def frames_until(self, t: float) -> list[Frame]:
        """The frames with stamp <= ``t`` (s) not given yet, in stamp order, decoded now."""
        if self._closed:
            return []
        limit = t + STAMP_SLACK_S
        p = self._locked_pass()
        try:
            p.advance(lambda: p.watermark >= limit)
            if self._held_head() > limit and not p.ended:
                return []                       # nothing due (most control cycles)
            due = [(stamp, self._order[cid], arrival, cid, msg)
                   for cid, q in self._queues.items() for stamp, arrival, msg in q.pop_until(limit)]
            info_ok = dict(self._info_ok)
            due.sort(key=lambda x: x[:3])
            for _s, _o, _a, cid, _m in due:
                if info_ok[cid]:
                    self._served[cid] += 1
                else:
                    self.counts[f"before_camera_info:{cid}"] += 1
            if p.ended:
                self._check_end()
        finally:
            p.lock.release()
        out = []
        for stamp, _o, _a, cid, msg in due:
            if not info_ok[cid]:
                continue
            cam = self._cams[cid]
            try:
                depth = rosmsg.depth_from_image(msg, expect_shape=(cam.height, cam.width), scale=self._scale[cid])
            except Exception as exc:  # noqa: BLE001 - a frame that cannot be read is skipped and counted, never a crash
                with p.lock:
                    self.counts[f"undecodable:{cid}"] += 1
                self.lost = self.lost or f"bag {self.replay.path}: frame of {cid} at {stamp:.9f}: {exc}"
                continue
            out.append(Frame(cid, depth, stamp))
        return out


class BagJoints(BagConsumer):
    """Joint source ``bag:PATH``: the robot's ``JointState`` s by name, in stamp order (module docstring).

    ``first_stamp``: the smallest stamp served (s; reads the start of the bag)."""

    def __init__(self, replay: BagReplay, rig, topic: str | None = None):
        from depthguard.sources.joints import _robot

        self._robot = _robot(rig)
        self._names = list(self._robot.joint_names)
        topics = sorted(replay.topic_counts(rosmsg.MSG["JointState"]))
        if topic is None:
            topic = "/joint_states" if "/joint_states" in topics else (topics[0] if len(topics) == 1 else None)
        if topic is None or topic not in topics:
            raise BagError(f"bag {replay.path}: no JointState topic to use (JointState topics: "
                           f"{', '.join(topics) or 'none'}; the default is /joint_states)")
        self.topic = topic
        self._lo = np.asarray(self._robot.q_min, dtype=np.float64) - 1e-9   # check_joint_state's limits
        self._hi = np.asarray(self._robot.q_max, dtype=np.float64) + 1e-9
        self._index: tuple = ((), None)       # (names of the last message, where the robot's joints are in it)
        self._start(replay)

    def _reset(self) -> None:
        self._queue = StampQueue(f"the joint states on {getattr(self, 'topic', '?')}")
        self._example: list | None = None

    def _routes(self, reader) -> dict:
        return {c.id: self._on_state for c in reader.connections
                if c.msgtype == rosmsg.MSG["JointState"] and c.topic == self.topic}

    def queues(self) -> list[StampQueue]:
        return [self._queue]

    def _on_state(self, con, raw) -> None:
        from depthguard.sources.joints import JointSourceError, check_joint_state

        if self._detached or self._closed:
            return
        try:
            stamp, names, pos = rosmsg.joint_state_fields(raw)
        except rosmsg.RosMessageError:
            try:                                 # what the direct reading does not know, rosbags may
                msg = rosmsg.deserialize(raw, con.msgtype)
                stamp, names, pos = rosmsg.stamp_s(msg.header.stamp), list(msg.name), msg.position
            except Exception:  # noqa: BLE001 - counted, not used
                self.counts[f"undecodable:{con.topic}"] += 1
                return
        if self._example is None:
            self._example = list(names)
        try:
            q = self._values(names, pos)
        except rosmsg.RosMessageError:
            q = None
        if q is None:
            self.counts["joints_partial"] += 1
            return
        if not (math.isfinite(stamp) and ((q >= self._lo) & (q <= self._hi)).all()):   # NaN fails too
            try:                                # the shared check, for its reason (and the same verdict)
                stamp, q = check_joint_state(self._robot, stamp, q)
            except JointSourceError:
                self.counts["joints_invalid"] += 1
                return
        newest = self._queue.newest
        reason = self._pass.offer(self._queue, stamp, q, 8 * q.size + 64)
        if reason is not None:
            self.counts[f"joints_{reason}"] += 1
        elif stamp < newest:
            self.counts["joints_reordered"] += 1

    def _values(self, names: list[str], position) -> np.ndarray | None:
        """The robot's joint positions (robot order) from a JointState's ``names`` and ``position``,
        ``None`` when one is missing (``joint_state_values``; the lookup is kept while the names repeat)."""
        if names != self._index[0]:
            index = {n: i for i, n in enumerate(names)}
            self._index = (list(names), None if not all(n in index for n in self._names)
                           else np.array([index[n] for n in self._names], dtype=np.intp))
        pos = np.asarray(position, dtype=np.float64)
        if len(names) != pos.size:
            raise rosmsg.RosMessageError(f"JointState has {len(names)} names and {pos.size} positions")
        where = self._index[1]
        return None if where is None else pos[where]

    def _check_end(self) -> None:
        if self._pass.ended and not self._detached and self._queue.accepted == 0:
            raise BagError(f"bag {self.replay.path}: no JointState on {self.topic} names all of the robot "
                           f"{self._robot.name}'s joints {self._names} within their limits "
                           f"(the first names {self._example or []})")

    @property
    def first_stamp(self) -> float:
        return self._first_stamp(lambda: True)

    def states_until(self, t: float) -> list[tuple[float, np.ndarray]]:
        """The joint states with stamp <= ``t`` (s) not given yet, in stamp order."""
        if self._closed:
            return []
        limit = t + STAMP_SLACK_S
        p = self._locked_pass()
        try:
            p.advance(lambda: p.watermark >= limit)
            out = [(stamp, q) for stamp, _a, q in self._queue.pop_until(limit)]
            if p.ended:
                self._check_end()
        finally:
            p.lock.release()
        return out


def _replay(argument: str, context: dict) -> BagReplay:
    if not argument:
        raise BagError("the bag source needs a path: bag:PATH (a rosbag2 directory or an .mcap file)")
    key = "bag:" + str(Path(argument).resolve())
    if key not in context or context[key].reader is None:
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
