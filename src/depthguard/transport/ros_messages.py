"""ROS 2 messages to and from depthguard values, with rosbags' typestore (R31).

No ROS installation is needed: ``rosbags`` serialises CDR and knows the
message definitions of ROS 2 Humble (:data:`TYPESTORE`).

Depth images (``sensor_msgs/msg/Image``) -> (H, W) float32 metres, 0 = no measurement:

- ``16UC1`` and ``mono16``: unsigned integers in units of ``scale`` metres (the rig camera's
  ``depth_scale``; default 0.001 = millimetres, the ROS convention (REP 118); a RealSense
  D405 counts 0.0001 m, as its SDK's depth units say); 0 = no measurement;
- ``32FC1``: metres (REP 117; ``scale`` does not apply); NaN, +inf and -inf (no return, too
  far, too near) become 0 = no measurement, so that they count as unknown space, never as free.

Any other encoding, a ``step`` smaller than a row, or ``data`` whose length is not
``step * height`` raises :class:`RosMessageError` (the bag source skips and
counts such a frame).

**Distortion** (decision, documented in ``docs/BAGS.md``): depthguard's cameras
are ideal pinholes (R1). A ``CameraInfo`` whose distortion coefficients are not
all zero is refused with a clear error rather than undistorted: resampling a
depth image blends foreground and background at depth edges (flying pixels),
and a wrong blend would put obstacles where there are none or remove real ones.
RealSense depth streams are published rectified with zero distortion (model
``plumb_bob`` or ``brown_conrady``, coefficients 0), so they pass.

Stamps: ``builtin_interfaces/msg/Time`` <-> float seconds, rounded to the nanosecond.
"""

from __future__ import annotations

import math
import struct

import numpy as np
from rosbags.typesys import Stores, get_typestore

__all__ = ["TYPESTORE", "RosMessageError", "DEPTH_ENCODINGS", "stamp_s", "time_msg", "header",
           "depth_from_image", "scale_depth", "image_from_depth", "intrinsics_from_camera_info", "camera_info_for",
           "joint_state", "joint_state_values", "joint_state_fields", "transform_stamped", "matrix_from_transform",
           "serialize", "deserialize", "MSG"]

TYPESTORE = get_typestore(Stores.ROS2_HUMBLE)
_T = TYPESTORE.types

#: the message types used here, by short name
MSG = {
    "Image": "sensor_msgs/msg/Image",
    "CameraInfo": "sensor_msgs/msg/CameraInfo",
    "JointState": "sensor_msgs/msg/JointState",
    "TFMessage": "tf2_msgs/msg/TFMessage",
    "String": "std_msgs/msg/String",
    "Float64": "std_msgs/msg/Float64",
    "MarkerArray": "visualization_msgs/msg/MarkerArray",
}
#: encoding -> (numpy dtype of one value, metres per unit by default)
DEPTH_ENCODINGS = {"16UC1": (np.uint16, 1e-3), "mono16": (np.uint16, 1e-3), "32FC1": (np.float32, 1.0)}


class RosMessageError(ValueError):
    """A ROS message that depthguard cannot use (the message says which field and why)."""


def serialize(msg) -> bytes:
    return bytes(TYPESTORE.serialize_cdr(msg, msg.__msgtype__))


def deserialize(raw: bytes | memoryview, msgtype: str):
    return TYPESTORE.deserialize_cdr(raw, msgtype)


def stamp_s(t) -> float:
    """A ``builtin_interfaces/msg/Time`` in float seconds."""
    return float(t.sec) + float(t.nanosec) * 1e-9


def time_msg(seconds: float):
    """Float seconds as ``builtin_interfaces/msg/Time`` (nanoseconds rounded; ``ValueError`` for
    a non-finite or negative time, which a ROS stamp cannot hold)."""
    if not math.isfinite(seconds) or seconds < 0:
        raise RosMessageError(f"stamp {seconds!r} s cannot be a ROS time (finite, >= 0)")
    ns = int(round(seconds * 1e9))
    return _T["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def stamp_ns(seconds: float) -> int:
    """Float seconds as integer nanoseconds (the MCAP log time)."""
    t = time_msg(seconds)
    return int(t.sec) * 1_000_000_000 + int(t.nanosec)


def header(seconds: float, frame_id: str):
    return _T["std_msgs/msg/Header"](stamp=time_msg(seconds), frame_id=frame_id)


# ----------------------------------------------------------------- depth
def depth_from_image(msg, expect_shape: tuple[int, int] | None = None, scale: float | None = None) -> np.ndarray:
    """``sensor_msgs/msg/Image`` -> (H, W) float32 metres, 0 = no measurement (module docstring).

    ``scale``: metres per unit of a 16-bit image (``None``: 0.001, millimetres); ignored for 32FC1."""
    enc = str(msg.encoding)
    if enc not in DEPTH_ENCODINGS:
        raise RosMessageError(f"depth encoding {enc!r} is not one of {', '.join(DEPTH_ENCODINGS)}")
    dtype, unit = DEPTH_ENCODINGS[enc]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    if h <= 0 or w <= 0:
        raise RosMessageError(f"image size {w}x{h} is empty")
    if expect_shape is not None and (h, w) != tuple(expect_shape):
        raise RosMessageError(f"image is {w}x{h}, the camera is {expect_shape[1]}x{expect_shape[0]}")
    item = np.dtype(dtype).itemsize
    if step < w * item:
        raise RosMessageError(f"step {step} is smaller than a row of {w} x {item} bytes")
    data = np.asarray(msg.data, dtype=np.uint8)
    if data.size != step * h:
        raise RosMessageError(f"data has {data.size} bytes, step x height = {step * h}")
    order = ">" if msg.is_bigendian else "<"
    rows = data.reshape(h, step)[:, :w * item]
    values = np.ascontiguousarray(rows).view(np.dtype(dtype).newbyteorder(order)).reshape(h, w)
    if dtype is np.uint16:
        return scale_depth(values, unit if scale is None else scale)
    depth = values.astype(np.float32)
    depth[~np.isfinite(depth)] = 0.0            # NaN / +-inf: no measurement (unknown, never free)
    depth[depth < 0] = 0.0
    return depth


def scale_depth(values: np.ndarray, scale: float) -> np.ndarray:
    """Integer depth (H, W) in units of ``scale`` m -> float32 metres (0 stays 0).

    When ``1 / scale`` is a whole number (0.001 -> 1000, 0.0001 -> 10000) the value is divided
    by it: the float32 nearest to the exact quotient, for every 16-bit value; otherwise it is
    multiplied in float64 and rounded once to float32."""
    per_m = 1.0 / float(scale)
    if per_m == round(per_m):
        return values.astype(np.float32) / np.float32(per_m)
    return (values.astype(np.float64) * float(scale)).astype(np.float32)


def image_from_depth(depth: np.ndarray, stamp: float, frame_id: str, encoding: str = "16UC1",
                     scale: float | None = None):
    """(H, W) float metres (0 = no measurement) -> ``Image`` in ``16UC1`` (units of ``scale`` m,
    default 0.001 = mm, rounded; beyond 65535 units or non-finite -> 0) or ``32FC1`` (metres; 0 stays 0)."""
    d = np.asarray(depth, dtype=np.float64)
    if d.ndim != 2:
        raise RosMessageError(f"a depth image is 2-D (got shape {d.shape})")
    h, w = d.shape
    if encoding in ("16UC1", "mono16"):
        per_m = 1.0 / (DEPTH_ENCODINGS[encoding][1] if scale is None else float(scale))
        units = np.where(np.isfinite(d) & (d > 0), np.rint(d * per_m), 0.0)
        units[units > 65535] = 0.0
        values = units.astype("<u2")
    elif encoding == "32FC1":
        values = np.where(np.isfinite(d) & (d > 0), d, 0.0).astype("<f4")
    else:
        raise RosMessageError(f"cannot write depth as {encoding!r} (16UC1, mono16 or 32FC1)")
    data = np.frombuffer(values.tobytes(), dtype=np.uint8)
    return _T[MSG["Image"]](header=header(stamp, frame_id), height=h, width=w, encoding=encoding,
                            is_bigendian=0, step=w * values.itemsize, data=data)


# ------------------------------------------------------------ camera info
def intrinsics_from_camera_info(msg) -> dict:
    """``CameraInfo`` -> ``{"width", "height", "fx", "fy", "cx", "cy", "frame_id"}``.

    Refused (:class:`RosMessageError`): an empty size, a non-positive or non-finite focal
    length, non-zero distortion (module docstring), binning or a region of interest that
    is not the whole image (the image would not be the one the K matrix describes).
    """
    w, h = int(msg.width), int(msg.height)
    if w <= 0 or h <= 0:
        raise RosMessageError(f"CameraInfo size {w}x{h} is empty")
    k = np.asarray(msg.k, dtype=np.float64)
    fx, fy, cx, cy = k[0], k[4], k[2], k[5]
    if not (np.isfinite([fx, fy, cx, cy]).all() and fx > 0 and fy > 0):
        raise RosMessageError(f"CameraInfo K has no valid focal lengths (fx={fx}, fy={fy})")
    d = np.asarray(msg.d, dtype=np.float64)
    if d.size and np.any(d != 0.0):
        raise RosMessageError(
            f"CameraInfo has non-zero distortion ({msg.distortion_model}, d={[round(float(x), 6) for x in d]}); "
            "depthguard uses rectified depth only: publish the rectified depth (e.g. RealSense "
            "depth/image_rect_raw) or rectify it before recording")
    bx, by = int(msg.binning_x), int(msg.binning_y)
    if bx > 1 or by > 1:
        raise RosMessageError(f"CameraInfo binning {bx}x{by} is not supported (record unbinned images)")
    roi = msg.roi
    if int(roi.width) not in (0, w) or int(roi.height) not in (0, h) or int(roi.x_offset) or int(roi.y_offset):
        raise RosMessageError("CameraInfo has a region of interest that is not the whole image")
    return {"width": w, "height": h, "fx": float(fx), "fy": float(fy), "cx": float(cx), "cy": float(cy),
            "frame_id": str(msg.header.frame_id)}


def camera_info_for(camera, stamp: float, frame_id: str):
    """``CameraInfo`` of a depthguard :class:`~depthguard.camera.Camera` (ideal pinhole, no distortion)."""
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    k = np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1], dtype=np.float64)
    p = np.array([fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0], dtype=np.float64)
    roi = _T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return _T[MSG["CameraInfo"]](header=header(stamp, frame_id), height=camera.height, width=camera.width,
                                 distortion_model="plumb_bob", d=np.zeros(5, dtype=np.float64), k=k,
                                 r=np.eye(3, dtype=np.float64).ravel(), p=p, binning_x=0, binning_y=0, roi=roi)


# ----------------------------------------------------------- joint states
def joint_state(stamp: float, names, q):
    """``JointState`` with positions ``q`` (dof,) for joints ``names``."""
    empty = np.zeros(0, dtype=np.float64)
    return _T[MSG["JointState"]](header=header(stamp, ""), name=list(names),
                                 position=np.asarray(q, dtype=np.float64), velocity=empty, effort=empty)


def joint_state_values(msg, names) -> np.ndarray | None:
    """The positions of joints ``names`` (robot order) in a ``JointState``, or ``None`` when the
    message lacks one of them (a partial state, e.g. a gripper's own topic). ``RosMessageError``
    when ``name`` and ``position`` differ in length."""
    got = list(msg.name)
    pos = np.asarray(msg.position, dtype=np.float64)
    if len(got) != pos.size:
        raise RosMessageError(f"JointState has {len(got)} names and {pos.size} positions")
    index = {n: i for i, n in enumerate(got)}
    if not all(n in index for n in names):
        return None
    return np.array([pos[index[n]] for n in names], dtype=np.float64)


_LAST_NAMES: tuple[bytes, tuple] = (b"", ())    # the names section last read and its names (joint_state_fields)


def joint_state_fields(raw: bytes | memoryview) -> tuple[float, list[str], np.ndarray]:
    """``(stamp s, names, positions (n,) float64)`` of a CDR-serialised ``JointState``, read
    directly (a replay reads hundreds per second; building the whole message costs more than
    the rest of its handling). ``velocity`` and ``effort`` are not read.
    :class:`RosMessageError` for bytes that are not such a message (plain CDR, either byte order)."""
    global _LAST_NAMES
    buf = memoryview(raw).cast("B")
    size = len(buf)
    if size < 12 or buf[0] != 0 or buf[1] not in (0, 1):
        raise RosMessageError("not a plain CDR message (encapsulation header)")
    end = "<" if buf[1] == 1 else ">"
    u32 = struct.Struct(end + "I")
    try:
        sec, nanosec = struct.unpack_from(end + "iI", buf, 4)
        pos = 12
        (n,) = u32.unpack_from(buf, pos)                        # header.frame_id, NUL included
        pos += 4 + n
        pos = 4 + ((pos - 4 + 3) & ~3)
        (count,) = u32.unpack_from(buf, pos)
        pos += 4
        if count > (size - pos) // 5:
            raise RosMessageError(f"JointState claims {count} names in {size} bytes")
        seen, seen_names = _LAST_NAMES                 # a robot's states repeat their names: bytes compared
        if seen and buf[pos - 4:pos - 4 + len(seen)] == seen:
            names = list(seen_names)
            pos += len(seen) - 4
        else:
            start, names = pos - 4, []
            for _ in range(count):
                pos = 4 + ((pos - 4 + 3) & ~3)
                (n,) = u32.unpack_from(buf, pos)
                pos += 4
                if n < 1 or pos + n > size or buf[pos + n - 1] != 0:
                    raise RosMessageError("JointState name is not a terminated string")
                names.append(bytes(buf[pos:pos + n - 1]).decode("utf-8"))
                pos += n
            _LAST_NAMES = (bytes(buf[start:pos]), tuple(names))    # 4-aligned: the same bytes wherever they are
        pos = 4 + ((pos - 4 + 3) & ~3)
        (count,) = u32.unpack_from(buf, pos)
        pos += 4
        if count:
            pos = 4 + ((pos - 4 + 7) & ~7)
        if pos + 8 * count > size:
            raise RosMessageError(f"JointState claims {count} positions in {size} bytes")
        positions = np.frombuffer(buf, dtype=np.dtype(end + "f8"), count=count, offset=pos).astype(np.float64)
    except (struct.error, UnicodeDecodeError, ValueError) as exc:
        if isinstance(exc, RosMessageError):
            raise
        raise RosMessageError(f"JointState does not parse: {exc}") from None
    return float(sec) + float(nanosec) * 1e-9, names, positions


# -------------------------------------------------------------------- TF
def transform_stamped(stamp: float, parent: str, child: str, matrix: np.ndarray):
    """``geometry_msgs/msg/TransformStamped``: the pose of ``child`` in ``parent`` (4x4)."""
    from depthguard.transforms import matrix_to_quat

    T = np.asarray(matrix, dtype=np.float64)
    qx, qy, qz, qw = (float(v) for v in matrix_to_quat(T[:3, :3]))
    tr = _T["geometry_msgs/msg/Transform"](
        translation=_T["geometry_msgs/msg/Vector3"](x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3])),
        rotation=_T["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw))
    return _T["geometry_msgs/msg/TransformStamped"](header=header(stamp, parent), child_frame_id=child, transform=tr)


def matrix_from_transform(tf) -> np.ndarray:
    """A ``geometry_msgs/msg/Transform`` as a 4x4 rigid matrix (quaternion normalised; a zero or
    non-finite one raises :class:`RosMessageError`)."""
    from depthguard.transforms import quat_to_matrix

    r, t = tf.rotation, tf.translation
    q = np.array([r.x, r.y, r.z, r.w], dtype=np.float64)
    n = float(np.linalg.norm(q))
    if not (math.isfinite(n) and n > 1e-9) or not np.isfinite([t.x, t.y, t.z]).all():
        raise RosMessageError(f"transform has an invalid rotation {q.tolist()} or translation")
    T = np.eye(4)
    T[:3, :3] = quat_to_matrix(q / n)
    T[:3, 3] = (t.x, t.y, t.z)
    return T
