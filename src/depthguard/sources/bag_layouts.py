"""The topic layouts of the common ROS 2 depth drivers, as ``bag:`` and ``rig from-bag`` read them (R31).

A driver publishes several ``sensor_msgs/msg/Image`` topics beside its depth: colour, infrared
(``mono16`` on some devices, the same encoding as 16-bit depth), depth re-projected into the
colour camera. Which of them are depth, which camera they belong to and which intrinsics the
image was taken with is decided here, from the topic names the drivers use (docs/BAGS.md
"Driver layouts"):

=====================  ===================================================  =====================================
driver                 depth image topics (a namespace before them)          CameraInfo
=====================  ===================================================  =====================================
realsense-ros 4.x      ``/camera/camera/depth/image_rect_raw``,              sibling ``camera_info``
                       ``/camera/camera/aligned_depth_to_color/image_raw``
OrbbecSDK_ROS2         ``/camera/depth/image_raw``                           sibling ``camera_info``
Azure_Kinect_ROS       ``/depth/image_raw``, ``/depth_to_rgb/image_raw``     sibling ``camera_info``
(rectified by          ``.../image_rect``                                    sibling; intrinsics from its ``P``
image_proc)
=====================  ===================================================  =====================================

**Depth** is an Image whose encoding is a depth encoding (``16UC1``, ``mono16``, ``32FC1``) and
whose stream folder (the name before the image's own) names depth (``depth``,
``aligned_depth_to_color``, ``depth_to_rgb``, ``depth_registered``...): infrared
(``ir``, ``infra1``), colour and ``rgb_to_depth`` are not.

**Intrinsics.** A raw image is described by ``K`` and must have no distortion (depthguard's
cameras are ideal pinholes, R1); so must realsense-ros's ``image_rect_raw`` (rectified on the
device, zero distortion). An image rectified in ROS (``image_rect``, image_proc's name) is
described by the ``P`` matrix of the same CameraInfo (ROS ``CameraInfo``: "P ... of the processed
(rectified) image"); its ``D`` belongs to the raw image and is not applied again.

**Cameras.** One physical camera may publish its depth twice (realsense-ros: ``depth`` and
``aligned_depth_to_color``; Azure Kinect: ``depth`` and ``depth_to_rgb``): :func:`depth_streams`
groups them by namespace; ``rig from-bag`` drafts the first (native depth) and names the others.
"""

from __future__ import annotations

import dataclasses
import re

import numpy as np

from depthguard.transport import ros_messages as rosmsg

__all__ = ["DRIVERS", "is_depth_topic", "is_rectified", "camera_intrinsics", "camera_id", "depth_streams", "stream_of"]

#: the driver layouts named in the docs: (driver, its depth image topics with its default namespace)
DRIVERS = (
    ("realsense-ros 4.x", ("/camera/camera/depth/image_rect_raw", "/camera/camera/aligned_depth_to_color/image_raw")),
    ("OrbbecSDK_ROS2", ("/camera/depth/image_raw",)),
    ("Azure_Kinect_ROS_Driver", ("/depth/image_raw", "/depth_to_rgb/image_raw")),
)
#: stream folders whose images are depth measured by another stream's camera (not the native depth)
_REPROJECTED = ("aligned", "to_rgb", "to_color", "registered")
_NOT_DEPTH = re.compile(r"(^|_)(rgb|color|colour|ir|infra\d*)_to_depth$")


def stream_of(topic: str) -> tuple[str, str, str]:
    """``(namespace, stream folder, image name)`` of an image topic:
    ``/camera/camera/depth/image_rect_raw`` -> ``("/camera/camera", "depth", "image_rect_raw")``."""
    parts = [p for p in topic.split("/") if p]
    name = parts[-1] if parts else ""
    stream = parts[-2] if len(parts) > 1 else ""
    return "/" + "/".join(parts[:-2]) if len(parts) > 2 else "/", stream, name


def is_depth_topic(topic: str, encodings) -> bool:
    """An Image topic holds depth: a depth encoding and a stream folder that names depth."""
    if not encodings or not set(encodings) <= set(rosmsg.DEPTH_ENCODINGS):
        return False
    _ns, stream, _name = stream_of(topic)
    return "depth" in stream.lower() and not _NOT_DEPTH.search(stream.lower())


def is_rectified(topic: str) -> bool:
    """The image was rectified in ROS (image_proc's ``image_rect``): its intrinsics are the CameraInfo's
    ``P``. realsense-ros's ``image_rect_raw`` is rectified on the device and published with zero
    distortion and ``P`` = ``K``: it keeps the strict check (``K``, distortion refused)."""
    name = stream_of(topic)[2]
    return name.startswith("image_rect") and name != "image_rect_raw"


def camera_intrinsics(image_topic: str | None, msg) -> dict:
    """:func:`~depthguard.transport.ros_messages.intrinsics_from_camera_info` of the CameraInfo ``msg``
    beside ``image_topic``: for a rectified image, the focal lengths and centre of ``P`` (px) and no
    distortion; else ``K`` and ``D`` as given (non-zero distortion is refused)."""
    if image_topic is None or not is_rectified(image_topic):
        return rosmsg.intrinsics_from_camera_info(msg)
    p = np.asarray(msg.p, dtype=np.float64).reshape(-1)
    if p.size != 12 or not np.isfinite(p).all() or p[0] <= 0 or p[5] <= 0:
        raise rosmsg.RosMessageError(f"CameraInfo P has no valid focal lengths for the rectified {image_topic} "
                                     f"(P={[float(x) for x in p]})")
    k = np.array([p[0], p[1], p[2], 0.0, p[5], p[6], 0.0, 0.0, 1.0])
    return rosmsg.intrinsics_from_camera_info(dataclasses.replace(msg, k=k, d=np.zeros(0)))


def _native_first(topic: str) -> tuple:
    stream = stream_of(topic)[1].lower()
    return (any(r in stream for r in _REPROJECTED), stream, topic)


def depth_streams(images: dict) -> tuple[dict[str, list[str]], list[str]]:
    """``({namespace: [depth topics, native depth first]}, [other image topics])`` of
    ``images`` (``{topic: set of encodings}``)."""
    groups: dict[str, list[str]] = {}
    others = []
    for topic, encodings in sorted(images.items()):
        if is_depth_topic(topic, encodings):
            groups.setdefault(stream_of(topic)[0], []).append(topic)
        else:
            others.append(topic)
    return {ns: sorted(t, key=_native_first) for ns, t in groups.items()}, others


def camera_id(topic: str) -> str:
    """A rig camera id for a depth topic: its namespace (repeated names once: realsense-ros's
    ``/camera/camera`` -> ``camera``; ``/left/camera`` -> ``left_camera``), else its stream folder
    (Azure Kinect at the root: ``depth``)."""
    ns, stream, _name = stream_of(topic)
    parts = [p for p in ns.split("/") if p]
    parts = [p for i, p in enumerate(parts) if i == 0 or p != parts[i - 1]]
    return re.sub(r"[^A-Za-z0-9_\-.]", "_", "_".join(parts) or stream) or "camera"
