"""Fuzz targets for ROS 2 input (R31, R35): the messages and the bag files the ``bag:`` source reads.

Both start from inputs depthguard writes itself and feed the mutated copies to the
code that reads a user's recordings (:mod:`depthguard.fuzz` runs them like the others):

* ``ros`` — one serialised message, tagged by its first byte (``I`` ``sensor_msgs/Image``
  16UC1, ``F`` Image 32FC1, ``C`` ``CameraInfo``, ``J`` ``JointState``). A message that
  rosbags cannot deserialise is refused, as the bag source counts it (``undecodable``);
  one that deserialises goes through depthguard's converter
  (:func:`~depthguard.transport.ros_messages.depth_from_image`,
  :func:`~depthguard.transport.ros_messages.intrinsics_from_camera_info`,
  :func:`~depthguard.transport.ros_messages.joint_state_values`), which must return a valid
  value — a depth image (H, W) float32, finite, >= 0; finite intrinsics — or raise
  ``ValueError`` with a sentence.
* ``bag`` — a whole MCAP bag file (two cameras, a robot's joint states, CameraInfo, TF;
  one seed with zstd chunks as ``record`` writes them, one with plain chunks):
  opening it (:class:`~depthguard.sources.bag.BagReplay`), its frame and joint sources
  and every frame and joint state they serve. Each frame must have its camera's shape
  and valid depth; each joint state the robot's dof and finite values; anything else a
  :class:`~depthguard.sources.bag.BagError` (a ``ValueError``) with a sentence.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

__all__ = ["ros_target", "bag_target"]

_RIG = """name: fuzz-bag-cell
workspace: {min: [-0.6, -0.6, 0.0], max: [0.6, 0.6, 1.0]}
robot: {name: ur3}
cameras:
  - id: camA
    width: 16
    height: 12
    fx: 15.0
    fy: 15.0
    cx: 7.5
    cy: 5.5
    range: [0.2, 6.0]
    pose: {look_at: {eye: [1.6, 0.1, 1.4], target: [0.0, 0.0, 0.5]}}
  - id: camB
    width: 16
    height: 12
    fx: 15.0
    fy: 15.0
    cx: 7.5
    cy: 5.5
    range: [0.2, 6.0]
    pose: {look_at: {eye: [-1.6, 0.1, 1.4], target: [0.0, 0.0, 0.5]}}
"""


def _rig(work: Path):
    from depthguard.rig import Rig

    path = work / "rig.yaml"
    path.write_text(_RIG)
    return Rig.load(path)


def _depth(rng: np.random.Generator, cam) -> np.ndarray:
    d = rng.uniform(0.5, 3.0, (cam.height, cam.width)).astype(np.float32)
    d[0, :3] = 0.0                                     # a few pixels with no measurement
    return d


def _check_depth(out, shape=None) -> None:
    if (not isinstance(out, np.ndarray) or out.dtype != np.float32 or out.ndim != 2
            or not np.isfinite(out).all() or (out < 0).any() or (shape is not None and out.shape != shape)):
        raise AssertionError(f"a bad depth image came out ({getattr(out, 'dtype', type(out))}, "
                             f"{getattr(out, 'shape', None)})")


def ros_target(work: Path):
    from depthguard.transport import ros_messages as rosmsg

    rig = _rig(work)
    cam = rig.cameras[0]
    rng = np.random.default_rng(0)
    d = _depth(rng, cam)
    types = {b"I": rosmsg.MSG["Image"], b"F": rosmsg.MSG["Image"], b"C": rosmsg.MSG["CameraInfo"],
             b"J": rosmsg.MSG["JointState"]}
    seeds = [b"I" + rosmsg.serialize(rosmsg.image_from_depth(d, 1.0, "camA", "16UC1")),
             b"F" + rosmsg.serialize(rosmsg.image_from_depth(d, 1.0, "camA", "32FC1")),
             b"C" + rosmsg.serialize(rosmsg.camera_info_for(cam, 1.0, "camA")),
             b"J" + rosmsg.serialize(rosmsg.joint_state(1.0, rig.robot.joint_names, rig.robot_q0))]
    names = list(rig.robot.joint_names)

    def case(data: bytes):
        msgtype = types.get(data[:1])
        if msgtype is None:
            raise ValueError("not a message of this corpus (unknown tag)")
        try:
            msg = rosmsg.deserialize(data[1:], msgtype)
        except Exception as exc:  # noqa: BLE001 - as the bag source: counted as undecodable, never used
            raise ValueError(f"undecodable {msgtype}: {type(exc).__name__}") from None
        if msgtype == rosmsg.MSG["Image"]:
            _check_depth(rosmsg.depth_from_image(msg))
        elif msgtype == rosmsg.MSG["CameraInfo"]:
            k = rosmsg.intrinsics_from_camera_info(msg)
            if not all(math.isfinite(float(v)) for v in k.values()):
                raise AssertionError(f"non-finite intrinsics came out: {k}")
        else:
            q = rosmsg.joint_state_values(msg, names)
            if q is not None and (q.shape != (len(names),) or q.dtype != np.float64):
                raise AssertionError(f"joint values of the wrong shape came out: {q.shape}")
        return True
    return seeds, case, None


def bag_target(work: Path):
    from depthguard.sources.bag import BagFrames, BagJoints, BagReplay
    from depthguard.sources.bag_record import BagRecorder
    from depthguard.sources.frame import Frame

    rig = _rig(work)
    rng = np.random.default_rng(1)
    seeds = []
    for compress in (True, False):          # zstd chunks as recorded, and plain ones (mutations reach the records)
        rec = BagRecorder(work / f"seed-{compress}", rig, compress=compress)
        try:
            for k in range(20):
                rec.write_joints(0.01 * k, np.asarray(rig.robot_q0) + 0.001 * k)
            for k in range(4):
                for cam in rig.cameras:
                    rec.write_frame(Frame(cam.id, _depth(rng, cam), 0.01 + 0.04 * k))
        finally:
            rec.close()
        seeds.append(rec.mcap_file().read_bytes())
    path = work / "b.mcap"
    shapes = {c.id: (c.height, c.width) for c in rig.cameras}
    dof = rig.robot.dof

    def case(data: bytes):
        path.write_bytes(data)
        replay = BagReplay(path)
        try:
            frames = BagFrames(replay, rig)
            joints = BagJoints(replay, rig)
            for f in frames.frames_until(math.inf):
                _check_depth(f.depth, shapes[f.camera_id])
                if not math.isfinite(f.stamp):
                    raise AssertionError(f"a frame with stamp {f.stamp!r} came out")
            for stamp, q in joints.states_until(math.inf):
                if not (math.isfinite(stamp) and np.shape(q) == (dof,) and np.isfinite(q).all()):
                    raise AssertionError(f"a bad joint state came out at {stamp!r}")
        finally:
            replay.close()
        return True
    return seeds, case, None
