"""16-bit depth in the camera's own units (R31): ``depth_scale`` of a rig camera.

A ROS Image does not say what one unit of 16UC1 / mono16 depth is. Millimetres are the
convention (and the default); a RealSense D405 counts 0.1 mm — read as millimetres, every
distance would come out 10 times too far (a silent wrong answer, on the unsafe side).
The truth here: a bag written by the independent writer (``mcap_ros2.writer``) in 0.1 mm
units, and the RealSense SDK's own recorder and playback of the same units.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from depthguard.cli import app
from depthguard.rig import Rig, RigError
from depthguard.sources.bag import BagFrames, BagJoints, BagReplay

mcap_writer = pytest.importorskip("mcap_ros2.writer", reason="mcap-ros2-support (test extra) writes the foreign bag")
from ros_defs import IMAGE_DEF, INFO_DEF, JOINT_DEF, _stamp  # noqa: E402 - after the skip

RIG = {"name": "d405-cell", "workspace": {"min": [-0.6, -0.6, 0.0], "max": [0.6, 0.6, 1.0]}, "robot": {"name": "ur3"},
       "cameras": [{"id": cid, "width": 64, "height": 48, "fx": 60.0, "fy": 60.0, "cx": 31.5, "cy": 23.5,
                    "range": [0.07, 0.5], "pose": {"look_at": {"eye": [x, 0.1, 1.4], "target": [0.0, 0.0, 0.5]}}}
                   for cid, x in (("camA", 1.6), ("camB", -1.6))]}


def _rig(**scales):
    data = yaml.safe_load(yaml.safe_dump(RIG))
    for cam in data["cameras"]:
        if cam["id"] in scales:
            cam["depth_scale"] = scales[cam["id"]]
    return Rig.from_dict(data)


def _units(k: int) -> np.ndarray:
    """A D405-like image in 0.1 mm units: 7..50 cm, some pixels without a measurement."""
    rng = np.random.default_rng(k)
    v = rng.integers(700, 5000, size=(48, 64)).astype("<u2")
    v[rng.random(v.shape) < 0.1] = 0
    return v


def _write(path, rig, encodings=("16UC1", "mono16"), n=3, images=None):
    with open(path, "wb") as fh:
        w = mcap_writer.Writer(fh)
        s_img, s_info = w.register_msgdef("sensor_msgs/msg/Image", IMAGE_DEF), w.register_msgdef("sensor_msgs/msg/CameraInfo", INFO_DEF)
        s_js = w.register_msgdef("sensor_msgs/msg/JointState", JOINT_DEF)
        i = 0
        for k in range(n):
            s = 0.1 * k + 0.01
            w.write_message("/joint_states", s_js, {"header": {"stamp": _stamp(s), "frame_id": ""},
                                                    "name": list(rig.robot.joint_names), "velocity": [], "effort": [],
                                                    "position": list(map(float, rig.robot_q0))}, log_time=i, publish_time=i)
            for cam, enc in zip(rig.cameras, encodings):
                values = _units(10 * k + len(cam.id)) if images is None else images[(cam.id, k)]
                hdr = {"stamp": _stamp(s), "frame_id": f"{cam.id}_optical"}
                w.write_message(f"/{cam.id}/depth/image_rect_raw", s_img,
                                {"header": hdr, "height": cam.height, "width": cam.width, "encoding": enc, "is_bigendian": 0,
                                 "step": cam.width * values.itemsize, "data": values.tobytes()}, log_time=i + 1, publish_time=i + 1)
                w.write_message(f"/{cam.id}/depth/camera_info", s_info,
                                {"header": hdr, "height": cam.height, "width": cam.width, "distortion_model": "plumb_bob",
                                 "d": [0.0] * 5, "k": [cam.fx, 0, cam.cx, 0, cam.fy, cam.cy, 0, 0, 1],
                                 "r": [1.0, 0, 0, 0, 1, 0, 0, 0, 1], "p": [cam.fx, 0, cam.cx, 0, 0, cam.fy, cam.cy, 0, 0, 0, 1, 0],
                                 "binning_x": 0, "binning_y": 0,
                                 "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False}},
                                log_time=i + 2, publish_time=i + 2)
                i += 3
        w.finish()
    return path


def _frames(path, rig):
    replay = BagReplay(path)
    frames = BagFrames(replay, rig)
    try:
        return frames.frames_until(math.inf)
    finally:
        frames.close()


@pytest.mark.parametrize("bad", [0.0, -0.001, 0.1, float("nan"), 1e-7])
def test_a_depth_scale_outside_what_a_depth_camera_counts_is_refused(bad):
    with pytest.raises(RigError, match=r"cameras\[0\]\.depth_scale: .*1e-6\.\.0\.01"):
        _rig(camA=bad)


def test_a_bag_in_tenths_of_a_millimetre_reads_right_with_its_depth_scale(tmp_path):
    """16UC1 and mono16 in 0.1 mm units (as a D405 writes them), by the independent writer."""
    d405 = _rig(camA=1e-4, camB=1e-4)
    path = _write(tmp_path / "d405.mcap", d405)
    got = _frames(path, d405)
    assert len(got) == 6
    for f in got:
        k = round((f.stamp - 0.01) / 0.1)
        truth = _units(10 * k + len(f.camera_id)).astype(np.float64) * 1e-4        # metres, exact
        assert f.depth.dtype == np.float32
        np.testing.assert_allclose(f.depth, truth, rtol=6e-8, atol=0)               # float32 rounding only
        assert np.all((f.depth == 0) == (truth == 0)) and 0.07 <= f.depth[f.depth > 0].min()
    as_mm = _frames(path, _rig())                                                    # the default: millimetres
    for f, g in zip(got, as_mm):
        valid = f.depth > 0
        np.testing.assert_allclose(g.depth[valid] / f.depth[valid], 10.0, rtol=1e-6)   # what the field prevents


def test_the_scale_is_per_camera_and_32fc1_stays_metres(tmp_path):
    rig = _rig(camA=1e-4, camB=1e-4)
    metres = {("camB", k): (_units(k) * 1e-3).astype("<f4") for k in range(3)}     # 32FC1: metres whatever the scale
    images = {**{("camA", k): _units(k) for k in range(3)}, **metres}
    got = _frames(_write(tmp_path / "mixed.mcap", rig, encodings=("16UC1", "32FC1"), images=images), rig)
    for f in got:
        k = round((f.stamp - 0.01) / 0.1)
        expect = _units(k) * (1e-4 if f.camera_id == "camA" else 1e-3)
        np.testing.assert_allclose(f.depth, expect, rtol=1e-6)
    one = _rig(camA=1e-4)                                                              # camB: the default (mm)
    got = _frames(_write(tmp_path / "two.mcap", one), one)
    for f in got:
        k = round((f.stamp - 0.01) / 0.1)
        expect = _units(10 * k + len(f.camera_id)) * (1e-4 if f.camera_id == "camA" else 1e-3)
        np.testing.assert_allclose(f.depth, expect, rtol=6e-8)


def test_record_writes_the_rigs_units_and_the_bag_source_reads_them_back(tmp_path):
    """``record`` with a D405 rig keeps its 0.1 mm (a mm bag read at 0.1 mm would be 10 times too near)."""
    from depthguard.sources.bag_record import BagRecorder
    from depthguard.sources.frame import Frame

    rig = _rig(camA=1e-4)
    depth = {c.id: np.round(_units(3) * 1e-4, 4).astype(np.float32) for c in rig.cameras}
    with BagRecorder(tmp_path / "rec", rig) as rec:
        rec.write_joints(0.0, rig.robot_q0)
        rec.write_joints(1.0, rig.robot_q0)
        for c in rig.cameras:
            rec.write_frame(Frame(c.id, depth[c.id], 0.5))
    replay = BagReplay(tmp_path / "rec")
    frames, joints = BagFrames(replay, rig), BagJoints(replay, rig)
    got = {f.camera_id: f.depth for f in frames.frames_until(1.0)}
    np.testing.assert_allclose(got["camA"], depth["camA"], atol=0.5e-4 + 1e-7)     # 0.1 mm kept
    np.testing.assert_allclose(got["camB"], depth["camB"], atol=0.5e-3 + 1e-7)     # mm: the default
    assert np.abs(got["camA"] - depth["camA"]).max() < 1e-4 < np.abs(got["camB"] - depth["camB"]).max()
    frames.close()
    joints.close()


def test_rig_from_bag_leaves_the_depth_scale_to_fill_in(tmp_path):
    rig = _rig()
    path = _write(tmp_path / "d405.mcap", rig, encodings=("16UC1", "32FC1"))
    out = tmp_path / "draft.yaml"
    res = CliRunner().invoke(app, ["rig", "from-bag", str(path), "--out", str(out)])
    assert res.exit_code == 0, res.output
    text = out.read_text()
    blocks = text.split("  - id: ")
    cam_a, cam_b = (next(b for b in blocks if b.startswith(c)) for c in ("camA", "camB"))
    assert "# depth_scale: 0.001" in cam_a and "D405" in cam_a                    # 16UC1: its units are not in the bag
    assert "depth_scale" not in cam_b                                             # 32FC1 is metres
    data = yaml.safe_load(text)
    for c, truth in zip(data["cameras"], RIG["cameras"]):
        c.setdefault("pose", truth["pose"])                                       # no TF in this bag: poses by hand
    drafted = Rig.from_dict({**data, "workspace": RIG["workspace"], "robot": RIG["robot"]})
    assert drafted.depth_scales == {}                                             # commented: not guessed


def test_the_realsense_sdk_and_the_bag_source_agree_on_tenths_of_a_millimetre(tmp_path):
    """The same z16 values in 0.1 mm units: recorded and played back by the SDK (``realsense-file:``,
    depth = z16 x the device's depth units) and read from a ROS 2 bag with ``depth_scale: 0.0001``."""
    from depthguard.sources.realsense_device import RealSenseUnavailable, import_sdk

    try:
        import_sdk()
    except RealSenseUnavailable as exc:
        pytest.skip(f"RealSense SDK not importable here: {exc}")
    from depthguard.sources.base import open_source
    from depthguard.sources.realsense_device import record_depth

    rig = _rig(camA=1e-4, camB=1e-4)
    cam = rig.camera("camA")
    shots = [(_units(10 * k + 4) * 1e-4, 100.0 + k / 30) for k in range(3)]
    rec = record_depth(tmp_path / "a.db3", shots, cam, serial="405", units=1e-4, period_s=0.01)
    src = open_source(f"realsense-file:camA={tmp_path / 'a.db3'}", rig)
    try:
        sdk, t = [], src.first_stamp
        while not src.done and t < src.first_stamp + 30:
            sdk += src.frames_until(t)
            t += 1 / 90
        sdk += src.frames_until(math.inf)
    finally:
        src.close()
    assert len(sdk) == 3
    images = {("camA", k): rec["z16"][k] for k in range(3)} | {("camB", k): rec["z16"][k] for k in range(3)}
    bag = [f for f in _frames(_write(tmp_path / "b.mcap", rig, images=images), rig) if f.camera_id == "camA"]
    for a, b in zip(sdk, bag):
        assert a.depth.shape == b.depth.shape
        np.testing.assert_allclose(b.depth, a.depth, rtol=1.2e-7, atol=0)           # one float32 rounding apart
        assert np.all((a.depth == 0) == (b.depth == 0))
