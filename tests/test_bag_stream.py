"""The bag replay reads the bag once, in bag order, with bounded memory (R31).

- every zstd chunk is decompressed once per replay (counted against the chunk index that
  the independent ``mcap`` reader reads from the file);
- the images held to put stamps in order stay within the re-order window, whatever the
  bag's length;
- what is served does not depend on how the sources are pulled (500 Hz cycles or all at once);
- a frame too late for the window is skipped and counted, one within it is put in order;
- a bad CameraInfo in the middle of a long bag stops the replay with a clear error before any
  frame stamped after it is served;
- a frame source opened but never read (a view's check) does not hold the bag's images.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from depthguard.rig import Rig
from depthguard.sources import bag_stream
from depthguard.sources.bag import BagError, BagFrames, BagJoints, BagReplay
from depthguard.sources.bag_record import BagRecorder
from depthguard.sources.frame import Frame

mcap_reader = pytest.importorskip("mcap.reader", reason="the mcap package (test extra) is the independent reader")
mcap_writer = pytest.importorskip("mcap_ros2.writer", reason="mcap-ros2-support (test extra) writes the foreign bags")
from ros_defs import IMAGE_DEF, INFO_DEF, JOINT_DEF, _stamp  # noqa: E402 - after the skip

RIG = """name: stream-cell
workspace: {min: [-0.6, -0.6, 0.0], max: [0.6, 0.6, 1.0]}
robot: {name: ur3}
cameras:
  - {id: camA, width: 160, height: 120, fx: 150.0, fy: 150.0, cx: 79.5, cy: 59.5, range: [0.2, 6.0],
     pose: {look_at: {eye: [1.6, 0.1, 1.4], target: [0.0, 0.0, 0.5]}}}
  - {id: camB, width: 160, height: 120, fx: 150.0, fy: 150.0, cx: 79.5, cy: 59.5, range: [0.2, 6.0],
     pose: {look_at: {eye: [-1.6, 0.1, 1.4], target: [0.0, 0.0, 0.5]}}}
"""
CAM_HZ, JOINT_HZ, SECONDS = 30.0, 500.0, 4.0


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    path = tmp_path_factory.mktemp("rig") / "rig.yaml"
    path.write_text(RIG)
    return Rig.load(path)


@pytest.fixture(scope="module")
def recorded(rig, tmp_path_factory):
    """A 4 s bag as ``record`` writes it (zstd chunks): noisy depth (it does not compress away)."""
    path = tmp_path_factory.mktemp("bag") / "bag"
    rng = np.random.default_rng(7)
    events = [(k / JOINT_HZ, None) for k in range(int(SECONDS * JOINT_HZ))]
    events += [(0.004 + i * 0.011 + k / CAM_HZ, c) for i, c in enumerate(rig.cameras) for k in range(int(SECONDS * CAM_HZ))]
    events.sort(key=lambda e: e[0])
    with BagRecorder(path, rig) as rec:
        for stamp, cam in events:
            if cam is None:
                rec.write_joints(stamp, np.asarray(rig.robot_q0) + 0.01 * math.sin(stamp))
            else:
                rec.write_frame(Frame(cam.id, rng.uniform(0.3, 5.0, (cam.height, cam.width)).astype(np.float32), stamp))
    return path


def _replay(path, rig, dt=0.002, watch=None):
    """Pull as the fast runner does; returns (frames, states, counters)."""
    replay = BagReplay(path)
    frames, joints = BagFrames(replay, rig), BagJoints(replay, rig)
    t0 = min(frames.first_stamp, joints.first_stamp)
    got_f, got_j = [], []
    k = 0
    while not (frames.done and joints.done):
        t = t0 + k * dt if dt else math.inf
        got_j += joints.states_until(t)
        got_f += frames.frames_until(t)
        if watch is not None:
            watch(frames)
        k += 1
    counters = frames.counters()
    frames.close()
    joints.close()
    return got_f, got_j, counters


def test_each_chunk_is_decompressed_once(rig, recorded, monkeypatch):
    from rosbags.rosbag2 import storage_mcap

    with open(next(recorded.glob("*.mcap")), "rb") as fh:
        chunks = len(mcap_reader.make_reader(fh).get_summary().chunk_indexes)
    assert chunks >= 5                                              # the bag spans many chunks
    calls = []
    real = storage_mcap.DECOMPRESSORS["zstd"]
    monkeypatch.setitem(storage_mcap.DECOMPRESSORS, "zstd", lambda data, size: calls.append(size) or real(data, size))
    frames, states, counters = _replay(recorded, rig)
    assert len(frames) == 2 * int(SECONDS * CAM_HZ) and len(states) == int(SECONDS * JOINT_HZ) and counters == {}
    assert len(calls) == chunks


def test_the_images_held_stay_within_the_reorder_window(rig, recorded):
    held = []
    frames, _states, _c = _replay(recorded, rig, watch=lambda f: held.append(sum(q.nbytes for q in f.queues())))
    one = 160 * 120 * 2 + 200                                        # one image message, bytes
    window = (bag_stream.REORDER_WINDOW_S + 0.05) * CAM_HZ * 2      # images of both cameras in the window
    assert 0 < max(held) <= (window + 2) * one
    assert max(held) < 0.2 * len(frames) * one                      # far from the whole bag


def test_what_is_served_does_not_depend_on_how_it_is_pulled(rig, recorded):
    a_f, a_j, a_c = _replay(recorded, rig, dt=0.002)
    b_f, b_j, b_c = _replay(recorded, rig, dt=0.0)                  # everything in one call
    assert [(f.camera_id, f.stamp) for f in a_f] == [(f.camera_id, f.stamp) for f in b_f]
    assert all(np.array_equal(x.depth, y.depth) for x, y in zip(a_f, b_f))
    assert [s for s, _q in a_j] == [s for s, _q in b_j] and a_c == b_c
    stamps = [f.stamp for f in a_f]
    assert stamps == sorted(stamps)


# ----------------------------------------------------------------- foreign bags, out of order
def _img(cam, s, mm=1500):
    values = np.full((cam.height, cam.width), mm, dtype="<u2")
    return {"header": {"stamp": _stamp(s), "frame_id": cam.id}, "height": cam.height, "width": cam.width,
            "encoding": "16UC1", "is_bigendian": 0, "step": cam.width * 2, "data": values.tobytes()}


def _info(cam, s, fx=None):
    fx = cam.fx if fx is None else fx
    return {"header": {"stamp": _stamp(s), "frame_id": cam.id}, "height": cam.height, "width": cam.width,
            "distortion_model": "plumb_bob", "d": [0.0] * 5, "k": [fx, 0, cam.cx, 0, cam.fy, cam.cy, 0, 0, 1],
            "r": [1.0, 0, 0, 0, 1, 0, 0, 0, 1], "p": [fx, 0, cam.cx, 0, 0, cam.fy, cam.cy, 0, 0, 0, 1, 0],
            "binning_x": 0, "binning_y": 0, "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False}}


def _foreign(path, rig, seconds=3.0, extra=(), bad_info_at=None):
    """Joints at 100 Hz and both cameras at 10 Hz in stamp order, then ``extra`` (topic kind, camera, stamp)
    messages inserted in bag order just after the message stamped ``after``."""
    msgs = [(0.01 * k, "js", None, 0.01 * k) for k in range(int(seconds * 100))]
    for cam in rig.cameras:
        for k in range(int(seconds * 10)):
            msgs += [(0.1 * k + 0.005, "img", cam, 0.1 * k + 0.005), (0.1 * k + 0.006, "info", cam, 0.1 * k + 0.005)]
    for after, kind, cam, stamp in extra:
        msgs.append((after + 1e-6, kind, cam, stamp))
    msgs.sort(key=lambda m: m[0])
    with open(path, "wb") as fh:
        w = mcap_writer.Writer(fh)
        sch = {"img": w.register_msgdef("sensor_msgs/msg/Image", IMAGE_DEF),
               "info": w.register_msgdef("sensor_msgs/msg/CameraInfo", INFO_DEF),
               "js": w.register_msgdef("sensor_msgs/msg/JointState", JOINT_DEF)}
        for i, (_order, kind, cam, s) in enumerate(msgs):
            if kind == "js":
                topic, msg = "/joint_states", {"header": {"stamp": _stamp(s), "frame_id": ""},
                                               "name": list(rig.robot.joint_names), "position": list(map(float, rig.robot_q0)),
                                               "velocity": [], "effort": []}
            elif kind == "img":
                topic, msg = f"/{cam.id}/depth/image_rect_raw", _img(cam, s, mm=1000 + round(s * 1000))
            else:
                bad = bad_info_at is not None and cam.id == "camA" and abs(s - bad_info_at) < 1e-6
                topic, msg = f"/{cam.id}/depth/camera_info", _info(cam, s, fx=300.0 if bad else None)
            w.write_message(topic, sch[kind], msg, log_time=i, publish_time=i)
        w.finish()
    return path


def test_a_frame_later_than_the_window_is_skipped_and_one_within_it_is_put_in_order(rig, tmp_path):
    cam = rig.camera("camA")
    w = bag_stream.REORDER_WINDOW_S
    extra = [(2.0, "img", cam, 2.0 - 2 * w - 0.0123),     # arrives 2 windows after its stamp: too late
             (2.0, "img", cam, 2.0 - 0.5 * w - 0.0123)]   # half a window late: put in order
    path = _foreign(tmp_path / "late.mcap", rig, extra=extra)
    frames, _states, counters = _replay(path, rig)
    stamps = [round(f.stamp, 6) for f in frames if f.camera_id == "camA"]
    assert round(2.0 - 0.5 * w - 0.0123, 6) in stamps and round(2.0 - 2 * w - 0.0123, 6) not in stamps
    assert stamps == sorted(stamps) and len(stamps) == 31
    assert counters == {"late:camA": 1, "reordered:camA": 1}


def test_a_bad_camera_info_in_the_middle_stops_the_replay_before_its_frames(rig, tmp_path):
    path = _foreign(tmp_path / "bad.mcap", rig, seconds=3.0, bad_info_at=2.005)
    replay = BagReplay(path)
    frames, joints = BagFrames(replay, rig), BagJoints(replay, rig)
    t0 = min(frames.first_stamp, joints.first_stamp)          # the start of the bag is fine
    served = []
    with pytest.raises(BagError, match=r"camera_info at stamp 2.005000000 disagrees with camera camA of the rig: fx=300"):
        for k in range(2000):
            joints.states_until(t0 + 0.002 * k)
            served += frames.frames_until(t0 + 0.002 * k)
    assert served and max(f.stamp for f in served) < 2.005       # it came mid-replay, before its frames
    with pytest.raises(BagError, match="disagrees"):             # and stays: the other source gets it too
        joints.states_until(10.0)


def test_a_frame_source_never_read_does_not_hold_the_bags_images(rig, recorded, monkeypatch):
    monkeypatch.setattr(bag_stream, "IDLE_BUDGET_BYTES", 100_000)
    replay = BagReplay(recorded)
    frames, joints = BagFrames(replay, rig), BagJoints(replay, rig)     # a view opens both, reads the joints
    states = joints.states_until(math.inf)
    assert len(states) == int(SECONDS * JOINT_HZ)
    assert sum(q.nbytes for q in frames.queues()) <= 100_000
    got = frames.frames_until(math.inf)                                 # read later: it reads the bag again
    assert len(got) == 2 * int(SECONDS * CAM_HZ) and frames.counters() == {}
    frames.close()
    joints.close()


def test_joint_states_read_directly_equal_rosbags_decoding():
    """The replay reads JointState's stamp, names and positions from the CDR bytes itself; rosbags'
    own decoder is the truth, over random messages in both byte orders (names repeating or not,
    frame ids and arrays of every length, so every alignment)."""
    import random

    from depthguard.transport import ros_messages as rosmsg

    make = rosmsg.TYPESTORE.types["sensor_msgs/msg/JointState"]
    rng = random.Random(5)
    pool = [[f"joint_{i}" for i in range(k)] for k in range(8)] + [["gripper", "a", "bb"]]
    for _ in range(600):
        names = rng.choice(pool) if rng.random() < 0.6 else \
            ["".join(rng.choice("abxyz_é") for _ in range(rng.randint(0, 9))) for _ in range(rng.randint(0, 9))]
        msg = make(header=rosmsg.header(rng.uniform(0, 2e9), "f" * rng.randint(0, 7)), name=names,
                   position=np.array([rng.uniform(-4, 4) for _ in range(rng.choice([len(names), rng.randint(0, 5)]))]),
                   velocity=np.array([rng.uniform(-1, 1) for _ in range(rng.randint(0, 3))]), effort=np.zeros(rng.randint(0, 2)))
        for little in (True, False):
            raw = bytes(rosmsg.TYPESTORE.serialize_cdr(msg, msg.__msgtype__, little_endian=little))
            truth = rosmsg.deserialize(raw, msg.__msgtype__)
            stamp, got_names, positions = rosmsg.joint_state_fields(raw)
            assert stamp == rosmsg.stamp_s(truth.header.stamp) and got_names == list(truth.name)
            assert positions.dtype == np.float64 and np.array_equal(positions, truth.position)
            for broken in (raw[: rng.randint(0, 16)], b"\x00\x07" + raw[2:]):    # cut in the header; not plain CDR
                with pytest.raises(rosmsg.RosMessageError):
                    rosmsg.joint_state_fields(broken)
