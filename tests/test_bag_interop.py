"""Bags that other ROS 2 tools read and write (R31).

- What depthguard records is decoded by an independent reader (``mcap`` + ``mcap_ros2``'s
  decoder, with the message definitions embedded in the file), and the values are the
  frames, intrinsics, joint states and camera poses that went in.
- depthguard reads an ``.mcap`` written by an independent writer (``mcap_ros2.writer``) whose
  message definitions are written out here by hand from the ROS 2 interfaces: depth in
  ``16UC1`` and ``32FC1`` (NaN = no return), CameraInfo, JointState, TF.
"""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.sim import load_cell
from depthguard.sources.bag import BagFrames, BagJoints, BagReplay
from depthguard.sources.bag_record import BagRecorder, optical_frame
from depthguard.sources.frame import Frame
from depthguard.transforms import quat_to_matrix
from ros_defs import IMAGE_DEF, INFO_DEF, JOINT_DEF, TF_DEF, _stamp

mcap_reader = pytest.importorskip("mcap.reader", reason="the mcap package (test extra) is the independent reader")
mcap_decoder = pytest.importorskip("mcap_ros2.decoder", reason="mcap-ros2-support (test extra) decodes CDR")
mcap_writer = pytest.importorskip("mcap_ros2.writer", reason="mcap-ros2-support (test extra) writes the foreign bag")


@pytest.fixture(scope="module")
def rig():
    return load_cell("flacco-cell").rig


def _depth(cam, k: int) -> np.ndarray:
    rng = np.random.default_rng(k)
    d = rng.uniform(0.5, 3.5, size=(cam.height, cam.width)).astype(np.float32)
    d[rng.random(d.shape) < 0.1] = 0.0                      # no measurement
    return d


def test_the_independent_reader_decodes_everything_depthguard_records(rig, tmp_path):
    out = tmp_path / "rec"
    frames = [Frame(c.id, _depth(c, 10 * k + i), 0.1 * k + 0.01 * i) for k in range(3) for i, c in enumerate(rig.cameras)]
    states = [(0.002 * k, np.asarray(rig.robot_q0) + 0.001 * k) for k in range(200)]
    with BagRecorder(out, rig) as rec:
        for s, q in states:
            rec.write_joints(s, q)
        for f in frames:
            rec.write_frame(f)
        path = rec.mcap_file()
    seen: dict[str, list] = {}
    with open(path, "rb") as fh:
        reader = mcap_reader.make_reader(fh, decoder_factories=[mcap_decoder.DecoderFactory()])
        chunks = {c.compression for c in reader.get_summary().chunk_indexes}
        for schema, channel, message, msg in reader.iter_decoded_messages():
            seen.setdefault(channel.topic, []).append((schema.name, message.log_time, msg))
    assert chunks == {"zstd"}
    cams = {c.id: c for c in rig.cameras}
    for cid, cam in cams.items():
        imgs = seen[f"/{cid}/depth/image_rect_raw"]
        infos = seen[f"/{cid}/depth/camera_info"]
        mine = [f for f in frames if f.camera_id == cid]
        assert len(imgs) == len(infos) == len(mine)
        for (name, log_time, img), (_n, _lt, info), f in zip(imgs, infos, mine):
            assert name == "sensor_msgs/msg/Image" and img.encoding == "16UC1" and img.header.frame_id == optical_frame(cid)
            assert img.header.stamp.sec + img.header.stamp.nanosec * 1e-9 == pytest.approx(f.stamp, abs=1e-9)
            assert log_time == round(f.stamp * 1e9)
            mm = np.frombuffer(bytes(img.data), dtype="<u2").reshape(img.height, img.width)
            np.testing.assert_array_equal(mm, np.rint(f.depth.astype(np.float64) * 1000).astype(np.uint16))
            assert (info.width, info.height) == (cam.width, cam.height)
            np.testing.assert_allclose(np.reshape(info.k, (3, 3)), [[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1]])
            assert not np.any(info.d)
    js = seen["/joint_states"]
    assert len(js) == len(states)
    for (_n, _lt, m), (s, q) in zip(js, states):
        assert list(m.name) == list(rig.robot.joint_names)
        np.testing.assert_allclose(m.position, q, atol=0)
    (_n, _lt, tf), = seen["/tf_static"]
    for tr in tf.transforms:
        cam = cams[tr.child_frame_id.replace("_depth_optical_frame", "")]
        r, t = tr.transform.rotation, tr.transform.translation
        T = np.eye(4)
        T[:3, :3] = quat_to_matrix(np.array([r.x, r.y, r.z, r.w]))
        T[:3, 3] = (t.x, t.y, t.z)
        assert tr.header.frame_id == "world"
        np.testing.assert_allclose(T, cam.world_from_camera, atol=1e-9)


# message definitions as ROS 2 ships them (concatenated with their dependencies, as rosbag2 embeds them)
def write_foreign_bag(path, rig, n_frames=4, joints=50, info=True, encodings=("16UC1", "32FC1"), extra=None):
    """An .mcap written by mcap_ros2.writer; returns the depths written per camera (float64 m)."""
    written: dict[str, list] = {}
    with open(path, "wb") as fh:
        w = mcap_writer.Writer(fh)
        s_img, s_info = w.register_msgdef("sensor_msgs/msg/Image", IMAGE_DEF), w.register_msgdef("sensor_msgs/msg/CameraInfo", INFO_DEF)
        s_js, s_tf = w.register_msgdef("sensor_msgs/msg/JointState", JOINT_DEF), w.register_msgdef("tf2_msgs/msg/TFMessage", TF_DEF)
        w.write_message("/tf_static", s_tf, {"transforms": [
            {"header": {"stamp": _stamp(0), "frame_id": "world"}, "child_frame_id": "cam0_optical",
             "transform": {"translation": {"x": 1.0, "y": 2.0, "z": 3.0}, "rotation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}}]},
            log_time=0, publish_time=0)
        names = list(rig.robot.joint_names)
        for k in range(joints):
            s = 0.01 * k
            q = np.asarray(rig.robot_q0) + 0.001 * k
            w.write_message("/joint_states", s_js, {"header": {"stamp": _stamp(s), "frame_id": ""}, "name": ["gripper"] + names,
                                                     "position": [0.0] + q.tolist(), "velocity": [], "effort": []},
                            log_time=round(s * 1e9) + 10**6, publish_time=round(s * 1e9))
        for k in range(n_frames):
            for cam, enc in zip(rig.cameras, encodings):
                s = 0.1 * k + 0.05
                d = _depth(cam, 100 + 10 * k).astype(np.float64)
                if enc == "16UC1":
                    values = np.rint(d * 1000).astype("<u2")
                    truth = values / 1000.0
                else:
                    values = d.astype("<f4")
                    values[d == 0] = np.nan                      # REP 117: no return
                    truth = np.where(d == 0, 0.0, values.astype(np.float64))
                written.setdefault(cam.id, []).append((s, truth))
                hdr = {"stamp": _stamp(s), "frame_id": f"{cam.id}_optical"}
                w.write_message(f"/{cam.id}/depth/image_rect_raw", s_img,
                                {"header": hdr, "height": cam.height, "width": cam.width, "encoding": enc,
                                 "is_bigendian": 0, "step": cam.width * values.itemsize, "data": values.tobytes()},
                                log_time=round(s * 1e9) + 3 * 10**7, publish_time=round(s * 1e9))
                if info:
                    w.write_message(f"/{cam.id}/depth/camera_info", s_info,
                                    {"header": hdr, "height": cam.height, "width": cam.width, "distortion_model": "plumb_bob",
                                     "d": [0.0] * 5, "k": [cam.fx, 0, cam.cx, 0, cam.fy, cam.cy, 0, 0, 1],
                                     "r": [1.0, 0, 0, 0, 1, 0, 0, 0, 1], "p": [cam.fx, 0, cam.cx, 0, 0, cam.fy, cam.cy, 0, 0, 0, 1, 0],
                                     "binning_x": 0, "binning_y": 0,
                                     "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False}},
                                    log_time=round(s * 1e9) + 3 * 10**7, publish_time=round(s * 1e9))
        if extra is not None:
            extra(w, s_img, s_info)
        w.finish()
    return written


def test_depthguard_reads_a_bag_of_the_independent_writer(rig, tmp_path):
    path = tmp_path / "foreign.mcap"
    written = write_foreign_bag(path, rig)
    replay = BagReplay(path)
    frames, joints = BagFrames(replay, rig), BagJoints(replay, rig)
    assert frames.first_stamp == pytest.approx(0.05) and joints.first_stamp == 0.0
    got = frames.frames_until(10.0)
    assert frames.done and len(got) == 8 and frames.skipped == 0
    for cid, items in written.items():
        mine = [f for f in got if f.camera_id == cid]
        assert [f.stamp for f in mine] == pytest.approx([s for s, _ in items], abs=1e-9)
        for f, (_s, truth) in zip(mine, items):
            assert f.depth.dtype == np.float32
            np.testing.assert_allclose(f.depth, truth, atol=1e-6)
            assert np.all((f.depth == 0) == (truth == 0))        # NaN and 0 mm are "no measurement"
    states = joints.states_until(10.0)
    assert len(states) == 50
    for k, (s, q) in enumerate(states):                            # by name: the gripper is left out
        assert s == pytest.approx(0.01 * k, abs=1e-9)
        np.testing.assert_allclose(q, np.asarray(rig.robot_q0) + 0.001 * k)
    assert [(stamp, static, tr.child_frame_id) for stamp, static, tr in replay.tf] == [(0.0, True, "cam0_optical")]
    frames.close()
    joints.close()
