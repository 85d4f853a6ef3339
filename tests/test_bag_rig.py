"""``depthguard rig from-bag`` (R2, R31): the cameras of a bag (CameraInfo + TF) become a rig
with the right intrinsics, poses and topics; the robot comes from /robot_description; what a
bag cannot say (the workspace) is left commented, so the draft does not load until filled in."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from depthguard.cli import app
from depthguard.rig import Rig, RigError
from depthguard.sim import load_cell
from depthguard.sources.bag_record import BagRecorder
from depthguard.sources.frame import Frame

mcap_writer = pytest.importorskip("mcap_ros2.writer", reason="mcap-ros2-support (test extra) writes the foreign bag")
from conftest import PRISMATIC_URDF  # noqa: E402
from ros_defs import INFO_DEF, TF_DEF, _stamp  # noqa: E402

WORKSPACE = {"min": [-1.0, -1.0, -0.5], "max": [1.0, 1.0, 1.5]}


def _draft(bag, out, *args):
    res = CliRunner().invoke(app, ["rig", "from-bag", str(bag), "--out", str(out), *args])
    assert res.exit_code == 0, res.output
    return out.read_text()


def test_a_recorded_cell_comes_back_as_its_rig(tmp_path):
    truth = load_cell("flacco-cell").rig
    bag = tmp_path / "bag"
    with BagRecorder(bag, truth) as rec:
        for c in truth.cameras:
            rec.write_frame(Frame(c.id, np.full((c.height, c.width), 2.0, np.float32), 0.01))
    text = _draft(bag, tmp_path / "draft.yaml")
    with pytest.raises(RigError, match="workspace: required field is missing"):
        Rig.load(tmp_path / "draft.yaml")                       # undecided: not guessed
    assert "# workspace:" in text and "# robot:" in text and "# range:" in text
    data = yaml.safe_load(text)
    rig = Rig.from_dict({**data, "workspace": WORKSPACE})
    assert rig.camera_ids == truth.camera_ids
    for c in truth.cameras:
        d = rig.camera(c.id)
        assert (d.width, d.height, d.fx, d.fy, d.cx, d.cy) == (c.width, c.height, c.fx, c.fy, c.cx, c.cy)
        np.testing.assert_allclose(d.world_from_camera, c.world_from_camera, atol=1e-9)
        assert rig.topics[c.id] == f"/{c.id}/depth/image_rect_raw"


def _rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def _tf(parent, child, T, quat=None):
    # quaternion (x, y, z, w): given, or that of a rotation about z by the angle of T
    a = math.atan2(T[1, 0], T[0, 0])
    x, y, z, w = quat if quat is not None else (0.0, 0.0, math.sin(a / 2), math.cos(a / 2))
    return {"header": {"stamp": _stamp(0.0), "frame_id": parent}, "child_frame_id": child,
            "transform": {"translation": {"x": T[0, 3], "y": T[1, 3], "z": T[2, 3]},
                          "rotation": {"x": x, "y": y, "z": z, "w": w}}}


def test_a_foreign_bag_gives_cameras_through_the_tf_chain_and_the_robot_from_its_description(tmp_path):
    world_base = _rz(0.3)
    world_base[:3, 3] = (0.5, -0.2, 0.8)
    base_link = _rz(-1.1)
    base_link[:3, 3] = (0.1, 0.4, 0.3)
    link_optical = np.array([[0, 0, 1, 0.02], [-1, 0, 0, 0], [0, -1, 0, 0.01], [0, 0, 0, 1.0]])   # REP 103 -> optical
    rail = _rz(0.7)
    rail[:3, 3] = (0.0, 0.0, 0.05)
    path = tmp_path / "foreign.mcap"
    string_def = "string data"
    with open(path, "wb") as fh:
        w = mcap_writer.Writer(fh)
        s_info, s_tf = w.register_msgdef("sensor_msgs/msg/CameraInfo", INFO_DEF), w.register_msgdef("tf2_msgs/msg/TFMessage", TF_DEF)
        s_img = w.register_msgdef("sensor_msgs/msg/Image", __import__("test_bag_interop").IMAGE_DEF)
        s_str = w.register_msgdef("std_msgs/msg/String", string_def)
        w.write_message("/robot_description", s_str, {"data": PRISMATIC_URDF}, log_time=0)
        w.write_message("/tf_static", s_tf, {"transforms": [_tf("world", "base", world_base),
                                                             _tf("camera_link", "camera_depth_optical_frame", link_optical, (-0.5, 0.5, -0.5, 0.5)),
                                                             _tf("world", "rail", rail)]}, log_time=0)
        w.write_message("/tf", s_tf, {"transforms": [_tf("base", "camera_link", base_link)]}, log_time=1)
        hdr = {"stamp": _stamp(0.0), "frame_id": "camera_depth_optical_frame"}
        w.write_message("/camera/depth/image_rect_raw", s_img, {"header": hdr, "height": 4, "width": 6, "encoding": "16UC1",
                                                                "is_bigendian": 0, "step": 12, "data": bytes(48)}, log_time=2)
        w.write_message("/camera/depth/camera_info", s_info, {
            "header": hdr, "height": 4, "width": 6, "distortion_model": "plumb_bob", "d": [0.0] * 5,
            "k": [5.0, 0, 2.5, 0, 5.5, 1.5, 0, 0, 1], "r": [1.0, 0, 0, 0, 1, 0, 0, 0, 1],
            "p": [5.0, 0, 2.5, 0, 0, 5.5, 1.5, 0, 0, 0, 1, 0], "binning_x": 0, "binning_y": 0,
            "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False}}, log_time=2)
        w.finish()
    out = tmp_path / "cell.yaml"
    text = _draft(path, out)
    assert (tmp_path / "cell.urdf").read_text() == PRISMATIC_URDF
    data = yaml.safe_load(text)
    rig = Rig.from_dict({**data, "workspace": WORKSPACE}, source=out)
    cam = rig.camera("camera")
    assert (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy) == (6, 4, 5.0, 5.5, 2.5, 1.5)
    np.testing.assert_allclose(cam.world_from_camera, world_base @ base_link @ link_optical, atol=1e-12)
    assert rig.topics == {"camera": "/camera/depth/image_rect_raw"}
    assert rig.robot is not None and rig.robot.dof == 4
    np.testing.assert_allclose(rig.robot.base, rail, atol=1e-12)
