"""``bag:`` and ROS 1 bags (issue 31, item 5): most recordings in circulation are ROS 1 ``.bag``.

``bag:`` reads ROS 2 bags. A ROS 1 bag of a driver (realsense-ros 1's topics, written
with ``rosbags``' ROS 1 writer and the ROS 1 message definitions) is one line that
says so and names the converter; converted as that line says (``rosbags-convert``,
run as a user runs it) it plays through ``bag:`` with every frame, its depth and its
stamps as written. A truncated ROS 1 bag is one line saying it cannot be read.
"""

from __future__ import annotations

import dataclasses
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from depthguard.sim import load_cell
from depthguard.sources.bag import BagError, BagFrames, BagReplay

rosbag1 = pytest.importorskip("rosbags.rosbag1")
from rosbags.typesys import Stores, get_typestore  # noqa: E402

RIG = load_cell("flacco-cell").rig
CAM = RIG.camera("cam0")
T0 = 1700000000.25


def write_ros1(path: Path, n: int = 4) -> list[np.ndarray]:
    """``n`` depth images of cam0 at 30 Hz (16UC1, mm) and their CameraInfo on realsense-ros's ROS 1
    topics ``/cam0/depth/image_rect_raw`` and ``/cam0/depth/camera_info``; the images written."""
    ts = get_typestore(Stores.ROS1_NOETIC)
    T = ts.types
    images = []
    with rosbag1.Writer(path) as w:
        img_c = w.add_connection("/cam0/depth/image_rect_raw", "sensor_msgs/msg/Image", typestore=ts)
        info_c = w.add_connection("/cam0/depth/camera_info", "sensor_msgs/msg/CameraInfo", typestore=ts)
        for i in range(n):
            s = T0 + i / 30
            stamp = T["builtin_interfaces/msg/Time"](sec=int(s), nanosec=round((s - int(s)) * 1e9))
            header = T["std_msgs/msg/Header"](seq=i, stamp=stamp, frame_id="cam0_depth_optical_frame")
            mm = np.full((CAM.height, CAM.width), 900 + 10 * i, dtype="<u2")
            mm[::7, ::5] = 0                                        # holes: no measurement
            images.append(mm)
            img = T["sensor_msgs/msg/Image"](header=header, height=CAM.height, width=CAM.width, encoding="16UC1",
                                             is_bigendian=0, step=CAM.width * 2,
                                             data=np.frombuffer(mm.tobytes(), dtype=np.uint8))
            roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
            k = np.array([CAM.fx, 0, CAM.cx, 0, CAM.fy, CAM.cy, 0, 0, 1], dtype=np.float64)
            p = np.array([CAM.fx, 0, CAM.cx, 0, 0, CAM.fy, CAM.cy, 0, 0, 0, 1, 0], dtype=np.float64)
            info = T["sensor_msgs/msg/CameraInfo"](header=header, height=CAM.height, width=CAM.width,
                                                   distortion_model="plumb_bob", D=np.zeros(5), K=k,
                                                   R=np.eye(3).ravel(), P=p, binning_x=0, binning_y=0, roi=roi)
            ns = round(s * 1e9)
            w.write(img_c, ns, ts.serialize_ros1(img, "sensor_msgs/msg/Image"))
            w.write(info_c, ns, ts.serialize_ros1(info, "sensor_msgs/msg/CameraInfo"))
    return images


def test_a_ros1_bag_is_one_line_naming_the_converter_and_plays_once_converted(tmp_path):
    path = tmp_path / "d435_ros1.bag"
    images = write_ros1(path)
    with pytest.raises(BagError) as err:
        BagReplay(path)
    msg = str(err.value)
    assert "ROS 1 bag" in msg and "rosbags-convert --src" in msg and "\n" not in msg
    # convert as the line says, with the converter's own command
    cmd = msg[msg.index("rosbags-convert"):msg.index(" (installed")].replace("DIR", str(tmp_path / "ros2"))
    argv = shlex.split(cmd)
    argv[0] = str(Path(sys.executable).with_name("rosbags-convert"))
    r = subprocess.run(argv, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    frames = BagFrames(BagReplay(tmp_path / "ros2"), dataclasses.replace(RIG, cameras=[CAM]))
    got = []
    try:
        while not frames.done:
            got.extend(frames.frames_until(float("inf")))
    finally:
        frames.close()
    assert [f.stamp for f in got] == pytest.approx([T0 + i / 30 for i in range(len(images))], abs=1e-9)
    for f, mm in zip(got, images):
        np.testing.assert_allclose(f.depth, mm.astype(np.float64) / 1000, rtol=1e-6)


def test_a_truncated_ros1_bag_is_one_line_saying_it_cannot_be_read(tmp_path):
    path = tmp_path / "whole.bag"
    write_ros1(path, n=6)
    cut = tmp_path / "cut.bag"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(BagError, match=r"ROS 1 bag .*cannot be read .*truncated") as err:
        BagReplay(cut)
    assert "\n" not in str(err.value)
