"""Bad bags (R31, R30): each gives one clear error, or the frame is skipped and counted — never
a crash, never a frame used with the wrong intrinsics or the wrong joints.

The bags are written by the independent writer (``mcap_ros2.writer``); each test breaks one
thing of an otherwise good bag and checks what depthguard does with it.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from depthguard.sim import load_cell
from depthguard.sources.bag import BagError, BagFrames, BagJoints, BagReplay

mcap_writer = pytest.importorskip("mcap_ros2.writer", reason="mcap-ros2-support (test extra) writes the bad bags")
from ros_defs import IMAGE_DEF, INFO_DEF, JOINT_DEF, _stamp  # noqa: E402 - after the skip

DG = [sys.executable, "-m", "depthguard.cli"]


@pytest.fixture(scope="module")
def rig():
    return load_cell("flacco-cell").rig


def _image(cam, s, enc="16UC1", mm=1500, width=None, height=None, data=None):
    w, h = width or cam.width, height or cam.height
    values = np.full((h, w), mm, dtype="<u2") if enc != "32FC1" else np.full((h, w), mm / 1000, dtype="<f4")
    return {"header": {"stamp": _stamp(s), "frame_id": cam.id}, "height": h, "width": w, "encoding": enc,
            "is_bigendian": 0, "step": w * values.itemsize, "data": values.tobytes() if data is None else data}


def _info(cam, s, fx=None, d=(0.0,) * 5):
    fx = cam.fx if fx is None else fx
    return {"header": {"stamp": _stamp(s), "frame_id": cam.id}, "height": cam.height, "width": cam.width,
            "distortion_model": "plumb_bob", "d": list(d), "k": [fx, 0, cam.cx, 0, cam.fy, cam.cy, 0, 0, 1],
            "r": [1.0, 0, 0, 0, 1, 0, 0, 0, 1], "p": [fx, 0, cam.cx, 0, 0, cam.fy, cam.cy, 0, 0, 0, 1, 0],
            "binning_x": 0, "binning_y": 0, "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False}}


def good(rig, n=4):
    """``[(topic, type, message)]`` of a good bag: n frames per camera at 10 Hz, joints at 100 Hz."""
    msgs = []
    for k in range(int(n * 10)):
        msgs.append(("/joint_states", "js", {"header": {"stamp": _stamp(0.01 * k), "frame_id": ""},
                                             "name": list(rig.robot.joint_names), "position": list(map(float, rig.robot_q0)),
                                             "velocity": [], "effort": []}))
    for k in range(n):
        for cam in rig.cameras:
            msgs.append((f"/{cam.id}/depth/image_rect_raw", "img", _image(cam, 0.1 * k + 0.01)))
            msgs.append((f"/{cam.id}/depth/camera_info", "info", _info(cam, 0.1 * k + 0.01)))
    return msgs


def write(path, msgs):
    with open(path, "wb") as fh:
        w = mcap_writer.Writer(fh)
        schemas = {"img": w.register_msgdef("sensor_msgs/msg/Image", IMAGE_DEF),
                   "info": w.register_msgdef("sensor_msgs/msg/CameraInfo", INFO_DEF),
                   "js": w.register_msgdef("sensor_msgs/msg/JointState", JOINT_DEF)}
        for i, (topic, kind, msg) in enumerate(msgs):
            w.write_message(topic, schemas[kind], msg, log_time=i, publish_time=i)
        w.finish()
    return path


def _open(path, rig):
    replay = BagReplay(path)
    return BagFrames(replay, rig), BagJoints(replay, rig)


def _start(path, rig):
    """Open the sources and read the start of the bag, as the runner does before its first cycle."""
    frames, joints = _open(path, rig)
    return frames, joints, min(frames.first_stamp, joints.first_stamp)


def test_a_good_bag_serves_every_frame_and_counts_nothing(rig, tmp_path):
    frames, joints = _open(write(tmp_path / "good.mcap", good(rig)), rig)
    got = frames.frames_until(100.0)
    assert len(got) == 8 and frames.counters() == {} and frames.skipped == 0
    assert all(np.all(f.depth == np.float32(1.5)) for f in got)
    assert len(joints.states_until(100.0)) == 40


def test_missing_camera_info_is_an_error_naming_the_topic(rig, tmp_path):
    msgs = [m for m in good(rig) if m[0] != "/cam1/depth/camera_info"]
    with pytest.raises(BagError, match=r"camera cam1: no CameraInfo on /cam1/depth/camera_info"):
        _open(write(tmp_path / "b.mcap", msgs), rig)


@pytest.mark.parametrize("change, words", [
    (dict(fx=300.0), r"disagrees with camera cam0 of the rig: fx=300"),
    (dict(d=(0.1, 0.0, 0.0, 0.0, 0.0)), r"non-zero distortion"),
])
def test_a_camera_info_that_is_not_the_rigs_camera_is_an_error(rig, tmp_path, change, words):
    msgs = good(rig)
    cam = rig.camera("cam0")
    msgs.append(("/cam0/depth/camera_info", "info", _info(cam, 0.35, **change)))   # one bad, late in the bag
    with pytest.raises(BagError, match=words):
        _start(write(tmp_path / "b.mcap", msgs), rig)


def test_frames_with_an_unknown_encoding_or_the_wrong_size_are_skipped_and_counted(rig, tmp_path):
    cam = rig.camera("cam0")
    msgs = good(rig)
    msgs.append(("/cam0/depth/image_rect_raw", "img", _image(cam, 0.5, enc="rgb8")))
    msgs.append(("/cam0/depth/image_rect_raw", "img", _image(cam, 0.6, data=b"\x00" * 1000)))   # short data
    msgs.append(("/cam0/depth/image_rect_raw", "img", _image(cam, 0.7, width=320, height=240)))
    frames, _ = _open(write(tmp_path / "b.mcap", msgs), rig)
    got = frames.frames_until(100.0)
    assert len(got) == 8 and max(f.stamp for f in got if f.camera_id == "cam0") == pytest.approx(0.31)
    assert frames.counters() == {"unknown_encoding:cam0": 1, "wrong_data_length:cam0": 1, "wrong_size:cam0": 1}
    assert frames.skipped == 3


def test_a_camera_without_a_usable_frame_is_an_error(rig, tmp_path):
    msgs = [m for m in good(rig) if m[0] != "/cam1/depth/image_rect_raw"]
    cam = rig.camera("cam1")
    msgs += [("/cam1/depth/image_rect_raw", "img", _image(cam, 0.1 * k, enc="bgr8")) for k in range(3)]
    with pytest.raises(BagError, match=r"camera cam1: none of the 3 images .*\(unknown_encoding 3\)"):
        _start(write(tmp_path / "b.mcap", msgs), rig)


def test_stamps_out_of_order_are_put_in_order_and_repeated_ones_are_dropped(rig, tmp_path):
    cam = rig.camera("cam0")
    msgs = [m for m in good(rig) if m[0] != "/cam0/depth/image_rect_raw"]
    for s, mm in ((0.05, 1000), (0.25, 1200), (0.15, 1100), (0.15, 3000), (0.35, 1300)):
        msgs.append(("/cam0/depth/image_rect_raw", "img", _image(cam, s, mm=mm)))
    js = [m for m in msgs if m[0] == "/joint_states"]
    msgs.append(js[5])                                     # a joint state again, same stamp, other position
    msgs[-1] = ("/joint_states", "js", {**js[5][2], "position": [float(v) + 0.1 for v in rig.robot_q0]})
    frames, joints = _open(write(tmp_path / "b.mcap", msgs), rig)
    got = [f for f in frames.frames_until(100.0) if f.camera_id == "cam0"]
    assert [round(f.stamp, 6) for f in got] == [0.05, 0.15, 0.25, 0.35]
    assert [float(f.depth[0, 0]) for f in got] == pytest.approx([1.0, 1.1, 1.2, 1.3])   # the first of the two at 0.15
    c = frames.counters()
    assert c["reordered:cam0"] == 1 and c["repeated_stamp:cam0"] == 1 and c["joints_repeated_stamp"] == 1
    states = joints.states_until(100.0)
    assert len(states) == 40 and all(np.allclose(q, rig.robot_q0) for _s, q in states)   # never the other one


def test_a_camera_not_in_the_rig_is_counted_and_a_rig_camera_missing_is_an_error(rig, tmp_path):
    cam = rig.camera("cam0")
    msgs = good(rig) + [("/cam9/depth/image_rect_raw", "img", _image(cam, 0.2))]
    frames, _ = _open(write(tmp_path / "b.mcap", msgs), rig)
    assert frames.counters() == {"not_in_rig:/cam9/depth/image_rect_raw": 1} and frames.skipped == 0
    msgs = [m for m in good(rig) if not m[0].startswith("/cam1/")]
    with pytest.raises(BagError, match=r"camera cam1: no Image on /cam1/depth/image_rect_raw .*/cam0/depth/image_rect_raw"):
        _open(write(tmp_path / "c.mcap", msgs), rig)


def test_joint_states_that_do_not_name_the_robots_joints_are_an_error(rig, tmp_path):
    msgs = [m if m[0] != "/joint_states" else (m[0], m[1], {**m[2], "name": [f"j{i}" for i in range(7)]})
            for m in good(rig)]
    replay = BagReplay(write(tmp_path / "b.mcap", msgs))
    joints = BagJoints(replay, rig)                        # the topic is there: its messages are read first
    with pytest.raises(BagError, match=r"no JointState on /joint_states names all of the robot lwr4's joints"):
        joints.first_stamp


def test_a_truncated_bag_is_one_clear_line_from_the_cli(rig, tmp_path):
    path = write(tmp_path / "good.mcap", good(rig, n=20))
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size * 2 // 3])
    with pytest.raises(BagError, match="truncated"):
        BagReplay(cut)
    res = subprocess.run(DG + ["monitor", "--cell", "flacco-cell", "--source", f"bag:{cut}", "--joints", f"bag:{cut}",
                               "--fast", "--out", str(tmp_path / "run"), "--quiet"], capture_output=True, text=True, timeout=120)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert lines[-1].startswith("depthguard: error: bag ") and "truncated" in lines[-1] and "Traceback" not in res.stderr


def test_skipped_frames_are_in_the_monitors_summary(rig, tmp_path, monitor_kernels):
    cam = rig.camera("cam0")
    msgs = good(rig) + [("/cam0/depth/image_rect_raw", "img", _image(cam, 0.33, enc="rgb8"))]
    path = write(tmp_path / "b.mcap", msgs)
    out = tmp_path / "run"
    res = subprocess.run(DG + ["monitor", "--cell", "flacco-cell", "--source", f"bag:{path}",    # joints: the bag's
                               "--fast", "--out", str(out), "--quiet"], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["sources"]["joints"] == f"bag:{path}"
    assert summary["source_counts"][f"bag:{path}"] == {"unknown_encoding:cam0": 1}


def test_a_bag_with_wall_clock_stamps_plays_in_real_time_on_its_own_clock(rig, tmp_path):
    """Real bags are stamped with the epoch: the monitor's clock starts at the first stamp, and
    without --fast the bag plays as recorded (0.4 s of bag in about 0.4 s)."""
    from depthguard.runtime.monitor import Monitor, warm_up
    from depthguard.runtime.runner import run
    from depthguard.sources.base import open_joints, open_source

    warm_up(rig, rig.monitor)              # numba compilation (a cold cache) is not the run's time
    epoch = 1_700_000_000.0
    msgs = []
    for topic, kind, m in good(rig):
        s = m["header"]["stamp"]["sec"] + m["header"]["stamp"]["nanosec"] * 1e-9
        msgs.append((topic, kind, {**m, "header": {**m["header"], "stamp": _stamp(epoch + s)}}))
    path = write(tmp_path / "epoch.mcap", msgs)
    records = []
    ctx: dict = {}
    mon = Monitor(rig, rig.monitor, sinks=[records.append])
    try:
        stats, wall = run(mon, [open_source(f"bag:{path}", rig, ctx)], open_joints(f"bag:{path}", rig, ctx), fast=False)
    finally:
        mon.close()
    # the run's clock is the bag's: it starts at the first stamp (a joint state at +0). A cycle
    # comes when the control thread gets the core: on a loaded machine the first one is late,
    # so it is judged on the bag's own span (0.39 s), not against a few milliseconds
    ts = np.array([r.t for r in records])
    assert epoch <= ts[0] < epoch + 1.0                                   # the bag's clock, not 0 nor now
    assert np.all(np.diff(ts) > 0)                                        # in order
    # the last joint state is at +0.39 s: the run reaches it, and ends after the bag does (how
    # soon depends on the machine's load: the sources' threads see the end of the bag; the upper
    # bounds only say that it ends, a loaded machine must not fail them)
    assert 0.34 <= ts[-1] - epoch <= 0.39 + 1.0
    assert 0.34 <= wall <= 0.39 + 1.5                                     # real time, not as fast as possible
    # paced: never a cycle ahead of the bag's clock, so no more cycles than dt allows; a fast
    # run would step at every dt of bag time in a few ms of wall time
    dt = rig.monitor.dt
    assert len(ts) <= (ts[-1] - epoch) / dt + 1.01
    assert wall >= (ts[-1] - ts[0]) - 0.02                                # the bag's span took its time
    assert max(r.cameras["cam0"].frames for r in records[-5:]) >= 1       # frames reached the monitor
