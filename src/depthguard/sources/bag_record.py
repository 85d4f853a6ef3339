"""Write what sources deliver as a ROS 2 bag (MCAP, zstd chunks): ``depthguard record`` (R31).

Per rig camera ``ID``: ``sensor_msgs/msg/Image`` (``16UC1`` millimetres by default —
in the camera's ``depth_scale`` units when the rig gives one, so that ``bag:`` reads it
back with the same rig — or ``32FC1`` metres) on ``/ID/depth/image_rect_raw`` and its
``sensor_msgs/msg/CameraInfo`` on ``/ID/depth/camera_info`` (one per frame, same
stamp, frame ``ID_depth_optical_frame``: z forward, x right, y down);
``sensor_msgs/msg/JointState`` on ``/joint_states`` (the robot's joint names);
each camera's pose in the world frame (``world``) on ``/tf_static``
(``tf2_msgs/msg/TFMessage``, offered with TRANSIENT_LOCAL durability as ROS 2
latches it). Header stamps are capture times; the MCAP log time of each message
is its header stamp too (a recording has no separate receive time).

The bag is a rosbag2 directory (``metadata.yaml`` + one ``.mcap``) written with
rosbags; zstd in STORAGE mode compresses whole chunks, which every MCAP reader
decodes. The directory must not exist (nothing is overwritten).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from depthguard.sources.bag import BagError, camera_depth_scale, default_topic, info_topic
from depthguard.transport import ros_messages as rosmsg

__all__ = ["BagRecorder", "optical_frame", "WORLD_FRAME"]

WORLD_FRAME = "world"


def optical_frame(camera_id: str) -> str:
    return f"{camera_id}_depth_optical_frame"


def _qos(transient_local: bool):
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    zero = QosTime(0, 0)
    return [Qos(QosHistory.KEEP_LAST, 1 if transient_local else 10, QosReliability.RELIABLE,
                QosDurability.TRANSIENT_LOCAL if transient_local else QosDurability.VOLATILE,
                zero, zero, QosLiveliness.AUTOMATIC, zero, False)]


class BagRecorder:
    """Records frames and joint states of ``rig`` into the new bag directory ``path`` (module docstring).

    ``frames`` / ``states``: messages written; ``clipped``: 16UC1 pixels beyond 65535 depth
    units (65.535 m at the default millimetres, ``depth_scale`` of the camera) written as 0
    (no measurement). Use as a context manager or call :meth:`close`.
    """

    def __init__(self, path: str | Path, rig, encoding: str = "16UC1", start: float = 0.0, compress: bool = True):
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

        self.path = Path(path)
        if self.path.exists():
            raise BagError(f"--out {self.path} exists already; a recording never overwrites one (choose a new name)")
        if encoding not in ("16UC1", "32FC1"):
            raise BagError(f"depth encoding {encoding!r}: record 16UC1 (mm) or 32FC1 (m)")
        if not self.path.parent.is_dir():
            raise BagError(f"--out {self.path}: the folder {self.path.parent} does not exist")
        self.rig, self.encoding = rig, encoding
        self._writer = Writer(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
        if compress:                    # zstd chunks (False: plain chunks, e.g. for the fuzzer's seeds)
            self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        self._writer.open()
        ts = rosmsg.TYPESTORE
        self._img, self._info = {}, {}
        for cam in rig.cameras:
            topic = rig.topics.get(cam.id) or default_topic(cam.id)
            self._img[cam.id] = self._writer.add_connection(topic, rosmsg.MSG["Image"], typestore=ts,
                                                            offered_qos_profiles=_qos(False))
            self._info[cam.id] = self._writer.add_connection(info_topic(topic), rosmsg.MSG["CameraInfo"], typestore=ts,
                                                             offered_qos_profiles=_qos(False))
        self._joints = None
        if rig.robot is not None:
            self._joints = self._writer.add_connection("/joint_states", rosmsg.MSG["JointState"], typestore=ts,
                                                       offered_qos_profiles=_qos(False))
        tf_con = self._writer.add_connection("/tf_static", rosmsg.MSG["TFMessage"], typestore=ts,
                                             offered_qos_profiles=_qos(True))
        transforms = [rosmsg.transform_stamped(start, WORLD_FRAME, optical_frame(c.id), c.world_from_camera)
                      for c in rig.cameras]
        tf = ts.types[rosmsg.MSG["TFMessage"]](transforms=transforms)
        self._writer.write(tf_con, rosmsg.stamp_ns(start), rosmsg.serialize(tf))
        self.frames = 0
        self.states = 0
        self.clipped = 0
        self.raw_bytes = 0          # bytes of the depth images as uncompressed 16-bit pixels

    def write_frame(self, frame) -> None:
        """One depth frame (``Frame``: (H, W) float32 metres, 0 = none) and its CameraInfo."""
        if frame.camera_id not in self._img:
            raise BagError(f"frame of camera {frame.camera_id!r}: not a camera of rig {self.rig.name!r}")
        if not math.isfinite(frame.stamp) or frame.stamp < 0:
            raise BagError(f"frame of {frame.camera_id}: stamp {frame.stamp!r} cannot be a ROS time")
        cam = self.rig.camera(frame.camera_id)
        scale = camera_depth_scale(self.rig, cam.id)      # the rig's depth units (None: mm), as bag: reads them
        if self.encoding == "16UC1":
            d = np.asarray(frame.depth)
            self.clipped += int(np.count_nonzero(d > 65535 * (scale or 0.001)))
        img = rosmsg.image_from_depth(frame.depth, frame.stamp, optical_frame(cam.id), self.encoding, scale=scale)
        info = rosmsg.camera_info_for(cam, frame.stamp, optical_frame(cam.id))
        ns = rosmsg.stamp_ns(frame.stamp)
        self._writer.write(self._img[cam.id], ns, rosmsg.serialize(img))
        self._writer.write(self._info[cam.id], ns, rosmsg.serialize(info))
        self.frames += 1
        self.raw_bytes += cam.width * cam.height * 2

    def write_joints(self, stamp: float, q) -> None:
        """One joint state ``q`` (dof,) of the rig robot, named by its joint names."""
        if self._joints is None:
            raise BagError(f"rig {self.rig.name!r} has no robot: joint states cannot be named")
        msg = rosmsg.joint_state(stamp, self.rig.robot.joint_names, q)
        self._writer.write(self._joints, rosmsg.stamp_ns(stamp), rosmsg.serialize(msg))
        self.states += 1

    def mcap_file(self) -> Path:
        return next(self.path.glob("*.mcap"))

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def record_sources(recorder: BagRecorder, frame_sources: list, joint_source, duration: float | None,
                   dt: float = 0.002, stop=None, progress=None) -> float:
    """Pull every source at ``t = t0 + k dt`` and write what it returns, until ``duration`` s, all
    sources done or ``stop`` (a ``threading.Event``) is set; returns the seconds recorded.

    Recordings and the simulator are pulled as fast as possible (the simulator's robot, with no
    monitor to obey, follows its path at full speed); a live source (``live = True``) on the wall
    clock, in real time. ``progress(t)`` is called every 5 s of recorded time.
    """
    import time

    srcs = [s for s in [*frame_sources, joint_source] if s is not None]
    live = any(getattr(s, "live", False) for s in srcs)
    firsts = [float(f) for f in (getattr(s, "first_stamp", None) for s in srcs) if f is not None]
    t0 = time.time() if live else (min(firsts) if firsts else 0.0)
    wall0 = time.monotonic()
    k, t, next_report = 0, t0, t0 + 5.0
    while stop is None or not stop.is_set():
        t = t0 + k * dt
        if duration is not None and t - t0 > duration + 1e-12:
            break
        if live:
            wait = (t - t0) - (time.monotonic() - wall0)
            if wait > 0:
                time.sleep(wait)
        if joint_source is not None:
            for stamp, q in joint_source.states_until(t):
                recorder.write_joints(stamp, q)
        frames = [f for s in frame_sources for f in s.frames_until(t)]
        for f in sorted(frames, key=lambda f: f.stamp):
            recorder.write_frame(f)
        if progress is not None and t >= next_report:
            progress(t - t0)
            next_report = t + 5.0
        if frame_sources and all(s.done for s in frame_sources) and (joint_source is None or joint_source.done):
            break
        k += 1
    return t - t0
