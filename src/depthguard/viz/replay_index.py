"""A recording's depth frames indexed by time, decoded on demand (``depthguard view DIR --bag BAG``, R31).

A 20 s bag of two 640 x 480 cameras holds 1.2 GB of depth: the replay never
loads it whole. :class:`BagDepth` reads the bag once to build, per rig
camera, the index of its images — ``stamps`` (n,) float64 s (header stamps,
the capture times, ascending) and ``log_ns`` (n,) int64 (the bag's log time
of each message, which the storage can seek to) — then decodes one image
when it is asked for, keeps the last ``cache`` decoded frames and forgets
the rest. Memory: 24 bytes per image of index, plus ``cache`` frames.

The same pass checks the bag as the ``bag:`` sources do, with their helpers
(:mod:`depthguard.sources.bag`): every rig camera has its image topic and a
CameraInfo that agrees with the rig's intrinsics
(:func:`~depthguard.sources.bag.check_camera_info`), and JointState messages
name all the robot's joints within their limits (by name, as ``BagJoints``).
A bag without them is refused with one sentence
(:class:`~depthguard.sources.bag.BagError`). Images are not decoded in this
pass: their header stamps are read from the first 12 bytes of the CDR data.

Which frame is shown at a log record: the one the monitor used, whose
capture stamp is the record's ``t - cameras[id].age_s`` (the log rounds both
to 1 us, :data:`STAMP_TOL_S`); a camera still ``waiting`` shows none.
:meth:`BagDepth.product` returns it as a
:class:`~depthguard.runtime.ingest.CameraProduct` — depth (H, W) float32 m
and the robot rendered at the joints of its capture (R30: interpolated from
the bag's joint states, never extrapolated) — which is what the live view
draws from a monitor's camera workers.
"""

from __future__ import annotations

import bisect
import math
import struct
import threading
from collections import OrderedDict
from pathlib import Path

import numpy as np

from depthguard.sources import bag as bag_source
from depthguard.sources.bag import BagError, default_topic, info_topic, open_bag
from depthguard.transport import ros_messages as rosmsg

__all__ = ["BagDepth", "STAMP_TOL_S", "header_stamp"]

#: a log record's frame stamp ``t - age_s`` matches a bag stamp within this (both rounded to 1 us in the log)
STAMP_TOL_S = 5e-6


def header_stamp(raw: bytes | memoryview) -> float:
    """The header stamp (s) of a CDR-serialised message that starts with a ``std_msgs/Header``
    (``sensor_msgs/msg/Image``): 4 bytes of encapsulation, then ``int32 sec``, ``uint32 nanosec``
    in the byte order the encapsulation names — read without decoding the image."""
    if len(raw) < 12:
        raise ValueError(f"message of {len(raw)} bytes is too short for a header")
    order = "<" if raw[1] & 1 else ">"                      # CDR_LE = 0x0001, CDR_BE = 0x0000
    sec, nsec = struct.unpack_from(order + "iI", raw, 4)
    return sec + nsec * 1e-9


class BagDepth:
    """The depth of ``bag`` for ``rig``'s cameras, indexed by time (module docstring).

    ``stamps[id]`` (n,) float64 s ascending, ``log_ns[id]`` (n,) int64 ns; ``joints``: a
    :class:`~depthguard.robot.joint_history.JointHistory` of every joint state of the bag;
    ``first_stamp`` / ``last_stamp`` s; ``decoded``: images decoded so far; ``cache``:
    frames kept decoded at most.
    """

    def __init__(self, bag: str | Path, rig, cache: int = 6):
        from depthguard.progress import stage

        self.path = Path(bag)
        self.rig = rig
        self.cache = max(1, int(cache))
        self._cams = {c.id: c for c in rig.cameras}
        self._topics = {c.id: rig.topics.get(c.id) or default_topic(c.id) for c in rig.cameras}
        self._lock = threading.Lock()
        self._frames: OrderedDict = OrderedDict()           # (camera, index) -> CameraProduct
        self._expected: dict = {}
        self.decoded = 0
        self.joints = None
        self._reader = open_bag(self.path)
        try:
            with stage(f"view: indexing {self.path}"):
                self._index()
        except BaseException:
            self.close()
            raise

    def _connections(self):
        """(image, CameraInfo, JointState) connections of the rig's cameras and robot; ``BagError`` when missing."""
        conns = self._reader.connections
        of = lambda kind: [c for c in conns if c.msgtype == rosmsg.MSG[kind]]     # noqa: E731
        images, infos, joints = of("Image"), of("CameraInfo"), of("JointState")
        for cid, topic in self._topics.items():
            if not any(c.topic == topic for c in images):
                found = sorted({c.topic for c in images}) or ["none"]
                raise BagError(f"bag {self.path}: camera {cid}: no Image on {topic} (image topics in the bag: "
                               f"{', '.join(found)}); set the camera's topic: in the rig")
            if not any(c.topic == info_topic(topic) for c in infos):
                raise BagError(f"bag {self.path}: camera {cid}: no CameraInfo on {info_topic(topic)} (the "
                               f"intrinsics of {topic} cannot be checked)")
        topics = sorted({c.topic for c in joints})
        joint_topic = "/joint_states" if "/joint_states" in topics else (topics[0] if len(topics) == 1 else None)
        if self.rig.robot is not None and joint_topic is None:
            raise BagError(f"bag {self.path}: no JointState topic to use (JointState topics: "
                           f"{', '.join(topics) or 'none'}; the default is /joint_states): the robot cannot be "
                           f"placed nor removed from the depth")
        wanted_img = set(self._topics.values())
        wanted_info = {info_topic(t) for t in wanted_img}
        return ([c for c in images if c.topic in wanted_img], [c for c in infos if c.topic in wanted_info],
                [c for c in joints if c.topic == joint_topic and self.rig.robot is not None])

    def _index(self) -> None:
        from depthguard.robot.joint_history import JointHistory
        from depthguard.sources.joints import JointSourceError, check_joint_state

        images, infos, joints = self._connections()
        cam_of_topic = {t: c for c, t in self._topics.items()}
        cam_of_info = {info_topic(t): c for c, t in self._topics.items()}
        self._conn = {c.id: c for c in images}
        found: dict[str, dict[float, tuple[int, int]]] = {cid: {} for cid in self._topics}
        robot = self.rig.robot
        states: dict[float, np.ndarray] = {}
        self.skipped: dict[str, int] = {}
        try:
            for con, log_ns, raw in self._reader.messages(connections=images + infos + joints):
                if con.msgtype == rosmsg.MSG["Image"]:
                    try:
                        stamp = header_stamp(raw)
                    except ValueError:
                        self.skipped["short_image"] = self.skipped.get("short_image", 0) + 1
                        continue
                    found[cam_of_topic[con.topic]].setdefault(stamp, (int(log_ns), con.id))   # repeated: the first
                elif con.msgtype == rosmsg.MSG["CameraInfo"]:
                    msg = rosmsg.deserialize(raw, con.msgtype)
                    cid = cam_of_info[con.topic]
                    bag_source.check_camera_info(self.path, self._cams[cid], con.topic, rosmsg.stamp_s(msg.header.stamp),
                                                 msg, image_topic=next(t for t, c in cam_of_topic.items() if c == cid))
                else:
                    msg = rosmsg.deserialize(raw, con.msgtype)
                    try:
                        q = rosmsg.joint_state_values(msg, robot.joint_names)
                        if q is not None:
                            stamp, q = check_joint_state(robot, rosmsg.stamp_s(msg.header.stamp), q)
                    except (rosmsg.RosMessageError, JointSourceError):
                        q = None
                    if q is None:
                        self.skipped["joints_unusable"] = self.skipped.get("joints_unusable", 0) + 1
                        continue
                    states.setdefault(stamp, q)
        except BagError:
            raise
        except Exception as exc:  # noqa: BLE001 - a damaged chunk, an undecodable message
            raise BagError(f"bag {self.path} cannot be read to its end: {type(exc).__name__}: {exc} "
                           "(truncated or damaged?)") from None
        if joints and not states:
            raise BagError(f"bag {self.path}: no JointState on {joints[0].topic} names all of the robot "
                           f"{robot.name}'s joints {list(robot.joint_names)} within their limits")
        if states:
            stamps = sorted(states)
            span = max(1.0, stamps[-1] - stamps[0] + 1.0)
            self.joints = JointHistory(robot.dof, span_s=span, capacity=len(stamps) + 16,
                                       max_gap_s=float(self.rig.monitor.joints_stale_s))
            for s in stamps:
                self.joints.push(s, states[s])
        self.stamps, self.log_ns, self._conn_of = {}, {}, {}
        for cid, entries in found.items():
            if not entries:
                raise BagError(f"bag {self.path}: camera {cid}: no image on {self._topics[cid]} can be read")
            keys = sorted(entries)
            self.stamps[cid] = np.array(keys, dtype=np.float64)
            self.log_ns[cid] = np.array([entries[k][0] for k in keys], dtype=np.int64)
            self._conn_of[cid] = np.array([entries[k][1] for k in keys], dtype=np.int64)
        self.first_stamp = min(s[0] for s in self.stamps.values())
        self.last_stamp = max(s[-1] for s in self.stamps.values())

    # ------------------------------------------------------------ lookup (no decoding)
    def index_of_stamp(self, camera_id: str, stamp: float) -> int | None:
        """The index of ``camera_id``'s image captured at ``stamp`` (within :data:`STAMP_TOL_S`), or None."""
        s = self.stamps[camera_id]
        i = int(np.searchsorted(s, stamp))
        best = [j for j in (i - 1, i) if 0 <= j < len(s) and abs(s[j] - stamp) <= STAMP_TOL_S]
        return min(best, key=lambda j: abs(s[j] - stamp)) if best else None

    def index_at(self, camera_id: str, t: float) -> int | None:
        """The index of ``camera_id``'s newest image captured at or before ``t`` (s), or None."""
        i = bisect.bisect_right(self.stamps[camera_id], t + 1e-9) - 1
        return i if i >= 0 else None

    def index_of_record(self, camera_id: str, snap) -> int | None:
        """The image the monitor used for ``camera_id`` in the log record ``snap`` (a
        :class:`~depthguard.viz.live_scene.Snapshot`): captured at ``t - age_s``; None while waiting."""
        st = snap.cameras.get(camera_id)
        if st is None or not math.isfinite(st["age_s"]) or camera_id not in self.stamps:
            return None
        return self.index_of_stamp(camera_id, snap.t - st["age_s"])

    # ------------------------------------------------------------ decoding on demand
    def depth(self, camera_id: str, i: int) -> np.ndarray:
        """(H, W) float32 m of ``camera_id``'s image ``i``, read from the bag now (``BagError`` if unreadable)."""
        stamp, log_ns = float(self.stamps[camera_id][i]), int(self.log_ns[camera_id][i])
        con = self._conn[int(self._conn_of[camera_id][i])]
        cam = self._cams[camera_id]
        with self._lock:
            for _con, _t, raw in self._reader.messages(connections=[con], start=log_ns, stop=log_ns + 1):
                if header_stamp(raw) != stamp:
                    continue
                try:
                    msg = rosmsg.deserialize(raw, rosmsg.MSG["Image"])
                    depth = rosmsg.depth_from_image(msg, expect_shape=(cam.height, cam.width),   # the rig's
                                                    scale=bag_source.camera_depth_scale(self.rig, camera_id))  # units
                except Exception as exc:  # noqa: BLE001 - named, never a crash of the view
                    raise BagError(f"bag {self.path}: image of {camera_id} at {stamp:.9f} s cannot be read: "
                                   f"{exc}") from None
                self.decoded += 1
                return depth
        raise BagError(f"bag {self.path}: image of {camera_id} at {stamp:.9f} s is gone (log time {log_ns} ns)")

    def capture_q(self, stamp: float) -> np.ndarray | None:
        """(dof,) rad: the joints at ``stamp`` interpolated from the bag (R30), None outside them."""
        from depthguard.robot.joint_history import OutsideHistory

        if self.joints is None:
            return None
        try:
            return self.joints.at(stamp)
        except OutsideHistory:
            return None

    def product(self, camera_id: str, i: int):
        """Image ``i`` of ``camera_id`` as a :class:`~depthguard.runtime.ingest.CameraProduct`
        (depth and the robot rendered at its capture joints; ``version`` = ``i + 1``), from the
        cache or decoded now; None when its capture joints are not in the bag (no robot to remove)."""
        from depthguard.filtering.expected import ExpectedDepth
        from depthguard.runtime.ingest import CameraProduct

        key = (camera_id, int(i))
        with self._lock:
            hit = self._frames.get(key)
            if hit is not None:
                self._frames.move_to_end(key)
                return hit
        stamp = float(self.stamps[camera_id][i])
        q = self.capture_q(stamp)
        if q is None and self.rig.robot is not None:
            return None
        depth = self.depth(camera_id, i)
        with self._lock:
            exp = self._expected.get(camera_id)
            if exp is None:
                exp = self._expected[camera_id] = ExpectedDepth(self._cams[camera_id], self.rig.robot,
                                                                self.rig.static_meshes())
            rd = np.array(exp.robot(q) if q is not None else exp.robot(()), dtype=np.float32, copy=True)
            prod = CameraProduct(depth, rd, stamp, q, 0.0, int(i) + 1)
            self._frames[key] = prod
            while len(self._frames) > self.cache:
                self._frames.popitem(last=False)
        return prod

    def products_of_record(self, snap, errors: list | None = None) -> dict:
        """camera id -> the :class:`CameraProduct` the monitor used in the record ``snap`` (None:
        waiting, not in the bag, or no capture joints). With ``errors``, an image that cannot be
        read adds its sentence there and gives None (the other cameras are still drawn);
        without, it raises ``BagError``."""
        out = {}
        for cid in self._cams:
            i = self.index_of_record(cid, snap)
            try:
                out[cid] = None if i is None else self.product(cid, i)
            except BagError as exc:
                if errors is None:
                    raise
                errors.append(str(exc))
                out[cid] = None
        return out

    def coverage(self, recording) -> tuple[int, int]:
        """``(found, asked)``: of the records' frames in use (``t - age_s``), how many this bag holds."""
        from depthguard.viz.live_scene import snapshot_of_record

        found = asked = 0
        for rec in recording.records:
            snap = snapshot_of_record(rec)
            for cid in self._cams:
                st = snap.cameras.get(cid)
                if st is None or not math.isfinite(st["age_s"]):
                    continue
                asked += 1
                found += self.index_of_record(cid, snap) is not None
        return found, asked

    def close(self) -> None:
        with self._lock:
            if self._reader is not None:
                self._reader.close()
                self._reader = None
            self._frames.clear()
