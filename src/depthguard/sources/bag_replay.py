"""An opened ROS 2 bag: its index, its whole-bag overview and the shared pass (R31).

:class:`BagReplay` is what the ``bag:`` sources of one run share (:mod:`depthguard.sources.bag`
describes the sources, their topics and their checks); :func:`open_bag` opens a bag with
``rosbags`` and turns its failures into one :class:`BagError` sentence — among them the
recordings that are not ROS 2 bags of a driver (:func:`other_recording`): a ROS 1 ``.bag``
(``bag:`` reads ROS 2; ``rosbags-convert`` converts a driver's ROS 1 bag) and a RealSense SDK
recording, ROS 1 ``.bag`` or ROS 2 ``.db3`` (topics ``/device_0/...``: ``realsense-file:`` plays it).
"""

from __future__ import annotations

import math
import threading
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

from depthguard.sources.bag_stream import BagPass
from depthguard.transport import ros_messages as rosmsg

__all__ = ["BagError", "BagReplay", "BagConsumer", "default_topic", "info_topic", "open_bag", "camera_depth_scale",
           "check_camera_info"]

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


def camera_depth_scale(rig, camera_id: str) -> float | None:
    """Metres per unit of camera ``camera_id``'s 16-bit depth (its rig ``depth_scale:``), or
    ``None`` for the encoding's default (0.001: millimetres)."""
    return (getattr(rig, "depth_scales", None) or {}).get(camera_id)


def is_sdk_recording(topics) -> bool:
    """True for the topics of a RealSense SDK recording (``/file_version`` and ``/device_0/...``),
    whichever its container."""
    topics = set(topics)
    return "/file_version" in topics and any(t.startswith("/device_0/") for t in topics)


def sdk_recording_hint(path) -> str:
    """What to do with a RealSense SDK recording given to ``bag:``."""
    return (f"it is a RealSense SDK recording (topics /device_0/...), not a ROS 2 driver's bag: play it with "
            f"--source realsense-file:{path}")


def other_recording(p: Path) -> str | None:
    """The reason a file given to ``bag:`` is not a ROS 2 bag it can read, when it is a ROS 1 bag
    (``#ROSBAG V2.0``: a RealSense SDK recording, or a ROS 1 driver's bag), else None."""
    try:
        with open(p, "rb") as f:
            head = f.read(13)
    except OSError:
        return None
    if not head.startswith(b"#ROSBAG V2.0"):
        return None
    try:
        from rosbags.rosbag1 import Reader

        with Reader(p) as r:
            topics = [c.topic for c in r.connections]
    except Exception as exc:  # noqa: BLE001 - rosbags raises its own error types
        return (f"it is a ROS 1 bag (bag: reads ROS 2 bags) and cannot be read ({exc}; truncated or damaged? "
                "a recorder killed before it closed the file leaves it without its index)")
    if is_sdk_recording(topics):
        return sdk_recording_hint(p)
    return (f"it is a ROS 1 bag; bag: reads ROS 2 bags: convert it with rosbags-convert --src {p} --dst DIR "
            "(installed with depthguard) and give bag:DIR")


def open_bag(path: str | Path):
    """An opened ``rosbags.rosbag2.Reader``; :class:`BagError` for a missing, truncated or
    damaged bag."""
    from rosbags.rosbag2 import Reader

    p = Path(path)
    if not p.exists():
        raise BagError(f"bag {p} does not exist")
    other = other_recording(p) if p.is_file() else None
    if other is not None:
        raise BagError(f"bag {p}: {other}")
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


def check_camera_info(path, cam, itopic: str, stamp: float, msg, image_topic: str | None = None) -> None:
    """A CameraInfo of rig camera ``cam`` must be usable and agree with the rig (else :class:`BagError`);
    for a rectified ``image_topic`` its ``P`` is what must agree (:mod:`~depthguard.sources.bag_layouts`)."""
    from depthguard.sources.bag_layouts import camera_intrinsics

    try:
        k = camera_intrinsics(image_topic, msg)
    except rosmsg.RosMessageError as exc:
        raise BagError(f"bag {path}: {itopic} at stamp {stamp:.9f}: {exc}") from None
    rig_k = {"width": cam.width, "height": cam.height, "fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy}
    bad = [f"{n}={k[n]:.6g} (rig {v:.6g})" for n, v in rig_k.items() if abs(k[n] - v) > INTRINSICS_TOL_PX]
    if bad:
        raise BagError(f"bag {path}: {itopic} at stamp {stamp:.9f} disagrees with camera {cam.id} of the "
                       f"rig: {', '.join(bad)}; draft the rig from the bag (`depthguard rig from-bag`) or fix it")


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
    """One opened bag, shared by the frame and joint sources of a run (``context["bag:" + path]``).

    ``topic_counts(msgtype)``: ``{topic: messages}`` from the bag's index (nothing is read).
    Whole-bag overview, read on first use by one pass of its own (``rig from-bag``):
    ``images[topic]``: image entries in bag order; ``infos[topic]``: ``[(stamp, msg)]``;
    ``joint_msgs[topic]``: ``[(stamp, msg)]``; ``tf``: ``[(stamp, static, TransformStamped)]``;
    ``strings[topic]``: ``std_msgs/msg/String`` payloads (``/robot_description``).
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.reader = open_bag(self.path)
        self.counts: dict[str, int] = defaultdict(int)
        self._overview: dict | None = None
        self._shared: BagPass | None = None
        self._passes: list[BagPass] = []    # every pass opened (closed with the bag)
        self._consumers: list = []          # every source opened on the bag (their counts stay after close)
        self._open: list = []               # those not closed yet
        self._lock = threading.Lock()

    # ----------------------------------------------------------- index
    def is_sdk_recording(self) -> bool:
        """True for a RealSense SDK recording (:func:`is_sdk_recording`)."""
        if self.reader is None:
            self.reader = open_bag(self.path)
        return is_sdk_recording(c.topic for c in self.reader.connections)

    def topic_counts(self, msgtype: str) -> dict[str, int]:
        if self.reader is None:
            self.reader = open_bag(self.path)
        out: dict[str, int] = defaultdict(int)
        for c in self.reader.connections:
            if c.msgtype == msgtype:
                out[c.topic] += int(c.msgcount)
        return {t: n for t, n in out.items() if n > 0}

    # ----------------------------------------------------------- shared pass
    def join(self, consumer, routes_of) -> BagPass:
        """Subscribe ``consumer`` to the shared pass (``routes_of(reader) -> {conn id: handler}``),
        or to a pass of its own when the shared one has started reading."""
        with self._lock:
            if consumer not in self._consumers:
                self._consumers.append(consumer)
            if consumer not in self._open:
                self._open.append(consumer)
            if self._shared is None or self._shared.started:
                first = self._shared is None and self.reader is not None     # the first pass reads with ours
                self._shared = BagPass(self.reader if first else open_bag(self.path), f"bag {self.path}", BagError,
                                       owns_reader=not first)
                self._passes.append(self._shared)
            self._shared.subscribe(consumer, routes_of(self._shared.reader))
            return self._shared

    def leave(self, consumer, bag_pass: BagPass | None) -> None:
        """``consumer`` is closed: close its pass when nobody else reads it, the bag with the last one."""
        if bag_pass is not None and bag_pass.unsubscribe(consumer):
            bag_pass.close()
        with self._lock:
            if consumer in self._open:
                self._open.remove(consumer)
            last = not self._open
        if last:
            self.close()

    def counters(self) -> dict:
        out = dict(self.counts)
        for c in list(self._consumers):
            out.update(c.own_counts())
        return dict(sorted((k, v) for k, v in out.items() if v))

    # ----------------------------------------------------------- whole-bag overview
    @property
    def images(self) -> dict:
        return self._scan()["images"]

    @property
    def infos(self) -> dict:
        return self._scan()["infos"]

    @property
    def joint_msgs(self) -> dict:
        return self._scan()["joint_msgs"]

    @property
    def tf(self) -> list:
        return self._scan()["tf"]

    @property
    def strings(self) -> dict:
        return self._scan()["strings"]

    def _scan(self) -> dict:
        if self._overview is not None:
            return self._overview
        view = {"images": defaultdict(list), "infos": defaultdict(list), "joint_msgs": defaultdict(list),
                "tf": [], "strings": defaultdict(list)}
        counter: dict[int, int] = defaultdict(int)
        wanted = {rosmsg.MSG[k] for k in ("Image", "CameraInfo", "JointState", "TFMessage", "String")}
        reader = open_bag(self.path)
        try:
            conns = [c for c in reader.connections if c.msgtype in wanted]
            for con, _logtime, raw in (reader.messages(connections=conns) if conns else ()):
                i = counter[con.id]
                counter[con.id] += 1
                try:
                    msg = rosmsg.deserialize(raw, con.msgtype)
                except Exception:  # noqa: BLE001 - a message that does not decode is counted, not used
                    self.counts[f"undecodable:{con.topic}"] += 1
                    continue
                self._file(view, con, i, msg)
        except Exception as exc:  # noqa: BLE001 - a damaged chunk in the middle of the file
            raise BagError(f"bag {self.path} cannot be read to its end: {type(exc).__name__}: {exc} "
                           "(truncated or damaged?)") from None
        finally:
            reader.close()
        self._overview = view
        return view

    @staticmethod
    def _file(view: dict, con, i: int, msg) -> None:
        if con.msgtype == rosmsg.MSG["Image"]:
            view["images"][con.topic].append(_ImageEntry(
                rosmsg.stamp_s(msg.header.stamp), con.topic, con.id, i, str(msg.encoding), int(msg.height),
                int(msg.width), int(msg.step), int(len(msg.data)), bool(msg.is_bigendian)))
        elif con.msgtype == rosmsg.MSG["CameraInfo"]:
            view["infos"][con.topic].append((rosmsg.stamp_s(msg.header.stamp), msg))
        elif con.msgtype == rosmsg.MSG["JointState"]:
            view["joint_msgs"][con.topic].append((rosmsg.stamp_s(msg.header.stamp), msg))
        elif con.msgtype == rosmsg.MSG["TFMessage"]:
            for tr in msg.transforms:
                view["tf"].append((rosmsg.stamp_s(tr.header.stamp), con.topic == "/tf_static", tr))
        elif con.msgtype == rosmsg.MSG["String"]:
            view["strings"][con.topic].append(str(msg.data))

    def close(self) -> None:
        with self._lock:
            passes, self._passes, self._shared = self._passes, [], None
        for p in passes:
            p.close()
        if self.reader is not None:
            self.reader.close()
            self.reader = None


class BagConsumer:
    """What the ``bag:`` frame and joint sources share: their pass, their counts, pulling, closing.

    Subclasses (:class:`~depthguard.sources.bag.BagFrames`, ``BagJoints``) define
    ``_routes(reader)``, ``queues()``, ``_reset()`` and ``_check_end()``."""

    def _start(self, replay: BagReplay) -> None:
        self.replay = replay
        self.counts: dict[str, int] = defaultdict(int)
        self.pulled = False          # has pulled once (a consumer that never did may be detached)
        self._detached = False
        self._closed = False
        self.lost = None
        self._first: float | None = None
        self._reset()
        self._pass: BagPass | None = replay.join(self, self._routes)

    def own_counts(self) -> dict:
        return dict(self.counts)

    def detach(self) -> None:
        """Called by the pass (lock held): drop what is held; a later pull reads the bag again."""
        self._detached = True
        for q in self.queues():
            q.clear()

    def _locked_pass(self) -> BagPass:
        """The consumer's pass with its lock taken (the caller releases it); a consumer that was
        detached joins a pass of its own first."""
        while True:
            if self._detached:
                old = self._pass
                if old is not None and old.unsubscribe(self):
                    old.close()
                self.counts.clear()
                self._reset()
                self._detached = False
                self._pass = self.replay.join(self, self._routes)
            p = self._pass
            p.lock.acquire()
            if not self._detached and p is self._pass:
                self.pulled = True
                return p
            p.lock.release()

    def _held_head(self) -> float:
        return min((q.head() for q in self.queues()), default=math.inf)

    def _first_stamp(self, ready) -> float:
        if self._first is None:
            p = self._locked_pass()
            try:
                p.advance(lambda: self._held_head() <= p.watermark and ready())
                self._check_end()
                self._first = self._held_head()
            finally:
                p.lock.release()
        return self._first

    @property
    def done(self) -> bool:
        p = self._pass
        return self._closed or (p is not None and p.ended and not self._detached
                                and all(len(q) == 0 for q in self.queues()))

    def counters(self) -> dict:
        """What was skipped, re-ordered or ignored (module docstring), of every source of the bag."""
        return self.replay.counters()

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        for q in self.queues():
            q.clear()
        self.replay.leave(self, self._pass)
