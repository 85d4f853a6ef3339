"""ROS 2 over Zenoh (R31): depthguard's keys, liveliness tokens, attachment and payloads against
rmw_zenoh's contract, through a real Zenoh router (a router-mode session of eclipse-zenoh).

The truths are independent of depthguard's code: the expected strings are written here from
the examples of rmw_zenoh's ``docs/design.md`` (Jazzy); the attachment is decoded with
``struct`` and with zenoh's own deserialiser (``zenoh.ext.z_deserialize``); payloads are
decoded and encoded with ``mcap_ros2`` (depthguard uses rosbags) from message definitions
written out by hand (``ros_defs.py`` and below). The "ROS camera node" that feeds the source
(:class:`ForeignNode`) is written here from the design doc, not with depthguard's module.
No ROS 2 can be installed here: nothing is tried against real ROS 2 nodes (docs/ROS2.md).
"""

from __future__ import annotations

import json
import math
import struct
import time

import numpy as np
import pytest

zenoh = pytest.importorskip("zenoh", reason="eclipse-zenoh is the transport")
mcap_dynamic = pytest.importorskip("mcap_ros2._dynamic", reason="mcap-ros2-support (test extra) is the independent CDR codec")

from ros_defs import _stamp  # noqa: E402
from ros2_peer import (FLOAT64_DEF, MARKERS_DEF, REACTION_DEF, ForeignNode, client, decoder, free_port,  # noqa: E402,F401
                       router, tokens, wait_for)  # router: a pytest fixture

from depthguard.transport import ros2_zenoh as rz  # noqa: E402

# --- from rmw_zenoh docs/design.md (Jazzy), "Graph Cache" / "Topic" examples, verbatim
DESIGN_STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
DESIGN_NODE = "@ros2_lv/0/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
DESIGN_PUB = ("@ros2_lv/0/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/"
              "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,7:,:,:,,")

# ------------------------------------------------------------------ the contract, as strings
def test_keys_tokens_and_hash_are_the_design_docs_examples():
    assert rz.type_hash("std_msgs/msg/String") == DESIGN_STRING_HASH           # rosbags' hash_rihs01
    assert rz.topic_key(0, "/chatter", "std_msgs/msg/String") == "0/chatter/std_msgs::msg::dds_::String_/" + DESIGN_STRING_HASH
    assert rz.node_token(0, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "listener") == DESIGN_NODE
    assert rz.entity_token(0, "8b20917502ee955ac4476e0266340d5c", 0, 10, "MP", "talker", "/chatter",
                           "std_msgs/msg/String", rz.qos_chunk(reliable=True, depth=7)) == DESIGN_PUB
    assert rz.qos_chunk(reliable=False, depth=5) == "2::,5:,:,:,,"               # sensor-data QoS: best effort (2)
    assert rz.qos_chunk(depth=42) == "::,:,:,:,,"           # every value the default: all empty
    assert rz.topic_key(7, "/cam0/depth/image_rect_raw", "sensor_msgs/msg/Image") == \
        "7/cam0/depth/image_rect_raw/sensor_msgs::msg::dds_::Image_/" + rz.type_hash("sensor_msgs/msg/Image")
    for bad in ("chatter", "/", "/a//b", "/a/", "/1a", "/a b", "/a/*"):
        with pytest.raises(rz.Ros2Error):
            rz.check_topic(bad)
    # the definitions depthguard sends are Humble's and Jazzy's alike (equal hashes = equal definitions)
    from depthguard.transport import ros_messages as rosmsg
    for t in ("sensor_msgs/msg/Image", "sensor_msgs/msg/CameraInfo", "sensor_msgs/msg/JointState",
              "std_msgs/msg/Float64", "visualization_msgs/msg/MarkerArray"):
        assert rosmsg.TYPESTORE.hash_rihs01(t) == rz.type_hash(t)


def test_attachment_bytes_follow_the_spec():
    gid = bytes(range(100, 116))
    raw = rz.encode_attachment(5, 1_700_000_000_123_456_789, gid)
    assert len(raw) == 33
    assert struct.unpack("<qqB16s", raw) == (5, 1_700_000_000_123_456_789, 16, gid)
    import zenoh.ext as zext
    assert zext.z_deserialize(tuple[zext.Int64, zext.Int64, bytes], zenoh.ZBytes(raw)) == (5, 1_700_000_000_123_456_789, gid)
    assert rz.decode_attachment(zext.z_serialize((zext.Int64(-3), zext.Int64(9), gid)).to_bytes()) == (-3, 9, gid)
    for bad in (raw[:20], raw + b"x", raw[:16] + b"\x0f" + gid[:15], b""):
        with pytest.raises(rz.Ros2Error):
            rz.decode_attachment(bad)


def test_node_with_no_router_is_one_clear_error():
    with pytest.raises(rz.Ros2Error, match="no Zenoh router answers at tcp/127.0.0.1"):
        rz.Ros2Node(router=f"tcp/127.0.0.1:{free_port()}", connect_timeout_s=0.5)


# ------------------------------------------------------------------ the sink on the wire
def test_sink_keys_tokens_attachment_and_payloads_through_a_router(router):
    from depthguard.runtime.ros2_sink import Ros2Sink
    from depthguard.sim import load_cell

    rig = load_cell("flacco-cell").rig
    spy = client(router)
    samples: list = []
    sub = spy.declare_subscriber("3/depthguard/**", lambda s: samples.append(
        (str(s.key_expr), s.payload.to_bytes(), None if s.attachment is None else s.attachment.to_bytes())))
    node = rz.Ros2Node(router=router, domain=3).acquire()
    sink = Ros2Sink(node, rig.robot, namespace="/depthguard", marker_hz=30.0)
    zid = str(node.session.info.zid())
    h = {t: rz.type_hash(t) for t in ("std_msgs/msg/Float64", "visualization_msgs/msg/MarkerArray",
                                      "depthguard_msgs/msg/Reaction")}
    expected = {
        f"@ros2_lv/3/{zid}/0/0/NN/%/%/depthguard",
        f"@ros2_lv/3/{zid}/0/1/MP/%/%/depthguard/%depthguard%override/std_msgs::msg::dds_::Float64_/"
        f"{h['std_msgs/msg/Float64']}/::,10:,:,:,,",
        f"@ros2_lv/3/{zid}/0/2/MP/%/%/depthguard/%depthguard%reaction/depthguard_msgs::msg::dds_::Reaction_/"
        f"{h['depthguard_msgs/msg/Reaction']}/::,10:,:,:,,",
        f"@ros2_lv/3/{zid}/0/3/MP/%/%/depthguard/%depthguard%markers/visualization_msgs::msg::dds_::MarkerArray_/"
        f"{h['visualization_msgs/msg/MarkerArray']}/::,10:,:,:,,",
        # the joint_trajectory_controller's speed scaling: reliable, TRANSIENT_LOCAL (durability 1), depth 1
        f"@ros2_lv/3/{zid}/0/4/MP/%/%/depthguard/%joint_trajectory_controller%speed_scaling_input/"
        f"control_msgs::msg::dds_::SpeedScalingFactor_/{rz.type_hash('control_msgs/msg/SpeedScalingFactor')}/:1:,1:,:,:,,"}
    assert wait_for(lambda: tokens(spy, 3) == expected), tokens(spy, 3)
    time.sleep(0.2)
    reactions = _reactions(rig)
    t_before = time.time_ns()
    for r in reactions:
        sink(r)
    assert wait_for(lambda: len(samples) >= 2 * len(reactions) + 2)
    t_after = time.time_ns()
    by_key: dict[str, list] = {}
    for key, payload, att in samples:
        by_key.setdefault(key, []).append((payload, att))
    assert set(by_key) == {f"3/depthguard/override/std_msgs::msg::dds_::Float64_/{h['std_msgs/msg/Float64']}",
                           f"3/depthguard/reaction/depthguard_msgs::msg::dds_::Reaction_/{h['depthguard_msgs/msg/Reaction']}",
                           f"3/depthguard/markers/visualization_msgs::msg::dds_::MarkerArray_/"
                           f"{h['visualization_msgs/msg/MarkerArray']}"}
    gids = set()
    for key, items in by_key.items():
        for k, (_payload, att) in enumerate(items):
            assert len(att) == 33
            seq, stamp, n, gid = struct.unpack("<qqB16s", att)
            assert seq == k + 1 and n == 16 and t_before <= stamp <= t_after
            gids.add(gid)
    assert len(gids) == 3                                     # one GID per publisher
    f64, rdec, mdec = decoder("std_msgs/msg/Float64", FLOAT64_DEF), decoder("depthguard_msgs/msg/Reaction", REACTION_DEF), \
        decoder("visualization_msgs/msg/MarkerArray", MARKERS_DEF)
    overrides = [f64(p).data for p, _a in by_key[next(k for k in by_key if "/override/" in k)]]
    assert overrides == [r.override for r in reactions]
    recs = [rdec(p) for p, _a in by_key[next(k for k in by_key if "/reaction/" in k)]]
    for msg, r in zip(recs, reactions):
        assert msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9 == pytest.approx(r.t, abs=1e-9)
        assert list(msg.observed) == list(r.observed) and list(msg.names) == list(r.names)
        assert list(msg.within_rho) == list(np.isfinite(r.distance))            # "nothing within rho" is a flag
        assert list(msg.reason_keys) == list(r.reasons)
    markers = [mdec(p) for p, _a in by_key[next(k for k in by_key if "/markers/" in k)]]
    assert len(markers) == 2                                   # 30 Hz over 0.04 s of reactions: at 0 and at 0.034 s
    grey = [m for m in markers[0].markers if m.ns == "control_points" and m.color.r == pytest.approx(0.6)]
    assert len(grey) == int((~reactions[0].observed & ~reactions[0].is_watch).sum())   # cannot judge = grey
    sink.close()
    assert wait_for(lambda: tokens(spy, 3) == set())          # closing the last user closes the node: tokens gone
    sub.undeclare()
    spy.close()


def _reactions(rig):
    """20 reactions of a monitor on the simulated flacco-cell: obstacles, points it cannot judge."""
    from depthguard.runtime.monitor import Monitor
    from depthguard.sources.base import open_joints, open_source

    out = []
    ctx: dict = {}
    frames, joints = open_source("sim:flacco-cell:reach", rig, ctx), open_joints("sim", rig, ctx)
    with Monitor(rig, rig.monitor) as mon:
        for k in range(20):
            t = 0.002 * k
            for s, q in joints.states_until(t):
                mon.push_joints(s, q)
            for f in frames.frames_until(t):
                mon.push_frame(f)
            mon.flush()
            out.append(mon.step(t))
    frames.close()
    joints.close()
    assert any(np.isfinite(r.distance).any() for r in out)
    return out


# ------------------------------------------------------------------ the source: good and bad messages
def test_source_uses_good_frames_and_counts_every_bad_message(router):
    from depthguard.sim import load_cell
    from depthguard.sources.base import open_joints, open_source

    rig = load_cell("flacco-cell").rig
    cam0, cam1 = rig.cameras
    ctx = {"ros2_router": router, "ros2_domain": 0}
    frames = open_source("ros2:", rig, ctx)
    joints = open_joints("ros2:", rig, ctx)
    ros = ForeignNode(router)
    assert wait_for(lambda: sum("/MS/" in k for k in tokens(ros.session)) == 5)   # 2 x (image, info) + joints
    h, w = cam0.height, cam0.width
    mm = (np.arange(h * w).reshape(h, w) % 3000 + 500).astype("<u2")
    metres = (mm.astype(np.float64) / 1000.0).astype("<f4")
    metres[0, :5] = np.nan                                    # REP 117: no return -> unknown (0)
    ros.image(cam0, 10.00, mm, "16UC1")                       # before any CameraInfo
    time.sleep(0.2)
    ros.info(cam0, 10.01)
    ros.info(cam1, 10.01)
    time.sleep(0.2)
    ros.image(cam0, 10.02, mm, "16UC1")                       # good
    ros.image(cam1, 10.02, metres, "32FC1")                   # good
    ros.image(cam0, 10.03, mm, "mono16")                      # good
    ros.image(cam0, 10.04, mm.astype(np.uint8), "rgb8")       # unknown encoding
    ros.image(cam0, 10.05, mm[:100], "16UC1")                 # wrong size
    ros.image(cam0, 10.06, mm, "16UC1", data=mm.tobytes()[:-2])  # wrong amount of data
    ros.image(cam0, 10.03, mm, "16UC1")                       # not newer than the last frame used
    img_key = ros.key("/cam0/depth/image_rect_raw", "sensor_msgs/msg/Image")
    ros.put(img_key, b"\x00\x01\x00\x00garbage")              # garbage CDR
    ros.put(img_key, ros.enc["Image"]({"header": {"stamp": _stamp(10.07), "frame_id": ""}, "height": h, "width": w,
                                       "encoding": "16UC1", "is_bigendian": 0, "step": 2 * w, "data": mm.tobytes()}),
            attachment=None)                                  # no attachment
    ros.put(img_key, b"\x00\x01\x00\x00", attachment=b"\x01" * 30)   # attachment of 30 bytes
    ros.put(ros.key("/cam0/depth/image_rect_raw", "sensor_msgs/msg/CompressedImage"), b"\x00\x01\x00\x00")   # wrong type
    ros.put(ros.key("/cam0/depth/image_rect_raw", "sensor_msgs/msg/Image", "RIHS01_" + "0" * 64), b"")   # other definition
    time.sleep(0.2)
    ros.info(cam0, 10.08, fx=cam0.fx + 1.0)                   # intrinsics that are not the rig's
    time.sleep(0.2)
    ros.image(cam0, 10.09, mm, "16UC1")                       # after it: refused
    time.sleep(0.2)
    ros.info(cam0, 10.10, d=(0.1, 0, 0, 0, 0))                # distortion: refused too
    ros.info(cam0, 10.11)                                     # agrees again
    time.sleep(0.2)
    ros.image(cam0, 10.12, mm, "16UC1")                       # good again
    names = list(rig.robot.joint_names)
    q = np.asarray(rig.robot_q0, dtype=np.float64)
    ros.joints(10.0, ["gripper"] + names[::-1], [0.5] + list(q[::-1]))   # other order, an extra joint: by name
    ros.joints(10.1, names[:-1], q[:-1])                      # partial
    bad_q = q.copy()
    bad_q[0] = rig.robot.q_max[0] + 1.0
    ros.joints(10.2, names, bad_q)                            # outside the limits
    ros.joints(9.9, names, q)                                 # older than the last used
    ros.joints(10.3, names, q + 0.01)
    want = {"no_camera_info:cam0": 1, "unknown_encoding:cam0": 1, "wrong_size:cam0": 1, "wrong_data_length:cam0": 1,
            "out_of_order:cam0": 1, "undecodable:/cam0/depth/image_rect_raw": 1,
            "bad_attachment:/cam0/depth/image_rect_raw": 2, "wrong_type:/cam0/depth/image_rect_raw": 2,
            "camera_info_refused:cam0": 2, "joints_partial": 1, "joints_invalid": 1, "joints_out_of_order": 1}
    assert wait_for(lambda: frames.counters() == want and frames.frames["cam0"] == 3 and joints.states == 2), \
        json.dumps(frames.counters()) + str(frames.frames) + str(joints.states)
    got = frames.frames_until(10.2)
    assert [(f.camera_id, f.stamp) for f in got] == [("cam0", 10.02), ("cam1", 10.02), ("cam0", 10.03), ("cam0", 10.12)]
    np.testing.assert_allclose(got[0].depth, mm.astype(np.float64) / 1000.0, rtol=6e-8, atol=0)   # float32 rounding
    assert got[0].depth.dtype == np.float32
    truth1 = np.where(np.isnan(metres), 0.0, metres)
    np.testing.assert_array_equal(got[1].depth, truth1)
    assert (got[1].depth[0, :5] == 0).all()
    states = joints.states_until(11.0)
    assert [s for s, _q in states] == [10.0, 10.3]
    np.testing.assert_allclose(states[0][1], q)
    np.testing.assert_allclose(states[1][1], q + 0.01)
    assert frames.frames_until(11.0) == [] and not frames.done
    frames.close()
    joints.close()
    assert frames.done and joints.done
    assert wait_for(lambda: not any("/depthguard" in k for k in tokens(ros.session)))
    ros.close()


def test_ros2_frame_source_argument_and_fast_mode_are_refused(router, tmp_path):
    from typer.testing import CliRunner

    from depthguard.cli.app import app
    from depthguard.sim import load_cell
    from depthguard.sources.base import open_source

    with pytest.raises(rz.Ros2Error, match="takes no argument"):
        open_source("ros2:/cam0", load_cell("flacco-cell").rig, {"ros2_router": router})
    res = CliRunner().invoke(app, ["monitor", "--cell", "flacco-cell", "--source", "ros2:", "--fast",
                                   "--ros2-router", router, "--out", str(tmp_path / "x"), "--quiet"])
    assert res.exit_code == 2 and "without --fast" in res.output


def test_joint_states_waiting_are_bounded_to_the_newest(router):
    """A live run starts with the states received while the monitor started: the source keeps
    the newest MAX_PENDING_STATES (R27: never a backlog of old joints), the rest counted."""
    from depthguard.sim import load_cell
    from depthguard.sources.base import open_joints
    from depthguard.sources.ros2_source import MAX_PENDING_STATES

    rig = load_cell("flacco-cell").rig
    joints = open_joints("ros2:", rig, {"ros2_router": router, "ros2_domain": 0})
    ros = ForeignNode(router)
    try:
        assert wait_for(lambda: any("/MS/" in k and "joint_states" in k for k in tokens(ros.session)))
        n = MAX_PENDING_STATES + 500
        q0 = np.asarray(rig.robot_q0, dtype=np.float64)
        for k in range(n):
            ros.joints(100.0 + 0.005 * k, rig.robot.joint_names, q0)
        assert wait_for(lambda: joints.states == n, 20.0), joints.states
        got = joints.states_until(math.inf)
        assert len(got) == MAX_PENDING_STATES <= 1000
        assert got[0][0] == pytest.approx(100.0 + 0.005 * (n - MAX_PENDING_STATES), abs=1e-6)   # the newest kept
        assert got[-1][0] == pytest.approx(100.0 + 0.005 * (n - 1), abs=1e-6)
        assert joints.counters().get("joints_overflow") == n - MAX_PENDING_STATES
    finally:
        joints.close()
        ros.close()


def test_trajectory_path_reorders_permuted_joints_and_refuses_bad_ones():
    """check_path over ROS 2 (R22): a JointTrajectory whose joint_names are a permutation of the
    robot's gives back exactly the path in the robot's order (truth: the path it was made from);
    empty names mean the robot's order; unknown or repeated names, a wrong number of positions and
    a NaN are refused with one line (the waypoint named where there is one)."""
    from depthguard.runtime.ros2_path_checks import REQUEST_TYPE, trajectory_path
    from depthguard.sim import load_cell
    from depthguard.transport.ros2_zenoh import WIRE

    robot = load_cell("ur3-cell").rig.robot
    T = WIRE.types
    names = list(robot.joint_names)
    rng = np.random.default_rng(3)
    Q = rng.uniform(np.asarray(robot.q_min) * 0.5, np.asarray(robot.q_max) * 0.5, (4, robot.dof))
    stamps = np.array([0.0, 0.25, 1.5, 2.0])
    perm = list(rng.permutation(robot.dof))

    def msg(jn, QQ, tt=stamps):
        pts = [T["trajectory_msgs/msg/JointTrajectoryPoint"](
            positions=np.ascontiguousarray(qq, float), velocities=np.zeros(0), accelerations=np.zeros(0), effort=np.zeros(0),
            time_from_start=T["builtin_interfaces/msg/Duration"](sec=int(x), nanosec=int(round((x % 1) * 1e9))))
            for qq, x in zip(QQ, tt)]
        m = T[REQUEST_TYPE](header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=0, nanosec=0),
                                                            frame_id=""), joint_names=jn, points=pts)
        return WIRE.deserialize_cdr(WIRE.serialize_cdr(m, REQUEST_TYPE), REQUEST_TYPE)     # as it arrives

    t, q = trajectory_path(msg([names[k] for k in perm], Q[:, perm]), robot)
    np.testing.assert_array_equal(q, Q)
    np.testing.assert_allclose(t, stamps, atol=1e-9)
    np.testing.assert_array_equal(trajectory_path(msg([], Q), robot)[1], Q)
    with pytest.raises(ValueError, match="not the joints of"):
        trajectory_path(msg(names[:-1] + [names[0]], Q), robot)
    with pytest.raises(ValueError, match="not the joints of"):
        trajectory_path(msg(names[:-1] + ["wrist_9"], Q), robot)
    with pytest.raises(ValueError, match="^waypoint 2: 5 positions"):
        trajectory_path(msg(names, [Q[0], Q[1], Q[2, :5], Q[3]]), robot)
    bad = Q.copy()
    bad[1, 4] = np.nan
    with pytest.raises(ValueError, match="^waypoint 1:"):
        trajectory_path(msg(names, bad), robot)
    with pytest.raises(ValueError, match="at least 2 waypoints"):
        trajectory_path(msg(names, Q[:1], stamps[:1]), robot)
