"""A camera node with a joint stream removes the robot at each frame's capture joints (R20, R30).

Truth: the robot moves along a straight line in joint space and its joint states are
published every 20 ms (the payload of docs/MONITOR.md "Joint states over Zenoh"); a
frame is the noiseless expected depth of the known scene with the robot where it was at
the frame's stamp, between two states. With the joints interpolated at that stamp the
node finds nothing unknown; with the server's fixed joints (the fallback without a
stream) the robot at the wrong pose comes back as voxels. Zenoh on loopback only.
"""

import json
import time

import numpy as np
import pytest

from depthguard.distributed.server import FusionServer
from depthguard.transport import wire

from loopback import free_port, wait_until

KEY = "test/robot/joints"


@pytest.fixture(scope="module")
def cell():
    from depthguard.sim import load_cell
    return load_cell("ur3-cell")


def _trajectory(cell):
    # a joint stream 50 Hz or faster: the history's gap limit is the rig's joints_stale_s (50 ms)
    q_a = np.asarray(cell.scene.robot_q(0.0), dtype=float)
    q_b = np.asarray(cell.scene.robot_q(cell.time_of("arm_reaching")), dtype=float)
    assert np.abs(q_b - q_a).max() > 0.2
    return lambda s: q_a + np.clip(s, 0.0, 1.0) * (q_b - q_a)       # 1 s from q_a to q_b


class _Frames:
    """A node frame source serving given (depth, stamp) pairs, one per call."""

    def __init__(self):
        self.queue = []

    def __call__(self):
        return self.queue.pop(0)


@pytest.mark.multiprocess
@pytest.mark.timeout(180)
def test_node_removes_robot_at_interpolated_capture_joints(cell):
    import zenoh

    from depthguard.distributed.node import build_node
    from depthguard.filtering.expected import ExpectedDepth
    from depthguard.transport.settings import zenoh_config

    rig = cell.rig
    q_of = _trajectory(cell)
    ep = f"tcp/127.0.0.1:{free_port()}"
    cam_id = rig.cameras[0].id
    logs = []
    # the server's settings hold the fixed starting pose (the fallback without a joint stream)
    srv = FusionServer(rig.camera_ids, wire.Settings(threshold=0.1, joints=tuple(q_of(0.0))), listen=[ep]).start()
    streamed = build_node(None, cam_id, "sim", "ur3-cell", resolution=(424, 240), connect=[ep],
                          joints=f"zenoh:{KEY}", log=logs.append)
    fixed = build_node(None, cam_id, "sim", "ur3-cell", resolution=(424, 240), connect=[ep])
    pub = zenoh.open(zenoh_config(connect=[ep]))        # the robot side, connected to the server's endpoint
    try:
        for node in (streamed, fixed):
            node.declare_token()
            node.initialize(timeout=20)
        assert streamed.joint_source is not None and fixed.joint_source is None
        assert streamed.joint_wait_s == rig.monitor.joint_wait_s

        def publish(stamp):
            pub.put(KEY, json.dumps({"stamp": stamp, "q": q_of(stamp).tolist(), "seq": 1}))

        # wait until the stream reaches the node (a state long before the motion)
        def arrived():
            publish(-10.0)
            streamed._drain_joints()
            return streamed.history.newest_stamp == -10.0
        assert wait_until(arrived, 20.0, step=0.1)
        for k in range(51):                              # states at 0.00, 0.02, ..., 1.00 s
            publish(round(0.02 * k, 10))
        assert wait_until(lambda: (streamed._drain_joints(), streamed.history.newest_stamp)[1] == 1.0, 10.0)

        expected = ExpectedDepth(streamed.cam, rig.robot, rig.static_meshes())
        frames = {s: np.array(expected.known(q_of(s)), copy=True) for s in (0.55, 0.85)}
        unit = srv.units[cam_id]
        for s, depth in frames.items():
            for node in (streamed, fixed):
                node.source = _Frames()
                node.source.queue.append((depth, s))
            n_streamed = streamed.step()
            assert n_streamed is not None, streamed.last_skip
            np.testing.assert_allclose(streamed.q_used, q_of(s), atol=1e-9)   # interpolated at the capture stamp
            n_fixed = fixed.step()
            np.testing.assert_array_equal(fixed.q_used, q_of(0.0))            # the server's fixed pose
            assert n_streamed == 0, (s, n_streamed)
            print(s, n_streamed, n_fixed)
            assert n_fixed > 50, (s, n_fixed)                                 # the robot at the wrong pose
        # the server's joints are ignored by the node with a stream, even when they change
        srv.set_settings(joints=list(q_of(0.3)))
        streamed.source.queue.append((frames[0.55], 0.55 + 1e-6))
        assert streamed.step() == 0 and np.abs(streamed.q_used - q_of(0.55)).max() < 1e-4

        # frames outside the joint history: skipped, counted, logged once, nothing sent
        updates = unit.updates
        t0 = time.monotonic()
        for s in (1.5, 1.6, -0.5):          # after the newest state (waits joint_wait_s), before the oldest kept
            streamed.source.queue.append((frames[0.85], s))
            assert streamed.step() is None
        assert time.monotonic() - t0 < 2.0
        assert streamed.skipped == {"future": 2, "too_old": 1}
        assert unit.updates == updates
        assert sum("skipped" in m for m in logs) == 2          # once per reason
        # states arriving later make a frame within the history usable again
        for k in range(51, 86):                          # up to 1.70 s
            publish(round(0.02 * k, 10))
        streamed.source.queue.append((frames[0.85], 1.65))
        assert wait_until(lambda: (streamed._drain_joints(), streamed.history.newest_stamp)[1] == 1.7, 10.0)
        assert streamed.step() is not None and unit.updates == updates + 1
    finally:
        pub.close()
        streamed.close()
        fixed.close()
        srv.close()


def test_node_without_robot_refuses_a_joint_stream(tmp_path):
    from depthguard.distributed.node import build_node

    from small_rigs import write_rig

    with pytest.raises(ValueError, match="no robot"):
        build_node(str(write_rig(tmp_path / "rig.yaml")), "cam0", "pattern", joints="zenoh:x/y", connect=["tcp/127.0.0.1:1"])


@pytest.mark.multiprocess
@pytest.mark.timeout(180)
def test_node_with_certificates_takes_its_joint_stream_over_tls(cell, tmp_path):
    """R35 with R30: server, node and the robot side's publisher on mutual TLS with the cell's
    certificates; the node removes the robot at the joints interpolated at the capture stamp
    (nothing unknown left), as without certificates. A publisher without a certificate
    cannot reach the node's session: its states never arrive."""
    import zenoh

    from depthguard.distributed.node import build_node
    from depthguard.filtering.expected import ExpectedDepth
    from depthguard.transport.keys import init_authority, issue_admin, issue_node, load_identity
    from depthguard.transport.settings import zenoh_config

    rig = cell.rig
    q_of = _trajectory(cell)
    cam_id = rig.cameras[0].id
    init_authority(tmp_path / "ca")
    issue_node(cam_id, tmp_path / "ca", tmp_path / "node")
    issue_admin(tmp_path / "ca", tmp_path / "robot")              # the robot side's certificate
    port = free_port()
    ep = f"tls/127.0.0.1:{port}"
    srv = FusionServer(rig.camera_ids, wire.Settings(threshold=0.1, joints=tuple(q_of(0.0))), listen=[ep],
                       identity=load_identity(tmp_path / "ca")).start()
    node = build_node(None, cam_id, "sim", "ur3-cell", resolution=(424, 240), connect=[ep],
                      joints=f"zenoh:{KEY}", identity=load_identity(tmp_path / "node"))
    pub = zenoh.open(zenoh_config(connect=[ep], identity=load_identity(tmp_path / "robot")))
    stranger = zenoh.open(zenoh_config(connect=[f"tcp/127.0.0.1:{port}"]))
    try:
        node.declare_token()
        node.initialize(timeout=20)
        assert node.joint_source is not None

        def publish(session, stamp):
            session.put(KEY, json.dumps({"stamp": stamp, "q": q_of(stamp).tolist(), "seq": 1}))

        def arrived():
            publish(pub, -10.0)
            node._drain_joints()
            return node.history.newest_stamp == -10.0
        assert wait_until(arrived, 30.0, step=0.1)
        for _ in range(5):
            publish(stranger, 5.0)                       # no certificate: no link, never arrives
        for k in range(51):
            publish(pub, round(0.02 * k, 10))
        assert wait_until(lambda: (node._drain_joints(), node.history.newest_stamp)[1] == 1.0, 10.0)
        expected = ExpectedDepth(node.cam, rig.robot, rig.static_meshes())
        node.source = _Frames()
        node.source.queue.append((np.array(expected.known(q_of(0.55)), copy=True), 0.55))
        assert node.step() == 0, node.last_skip                         # the robot removed where it was
        np.testing.assert_allclose(node.q_used, q_of(0.55), atol=1e-9)
        time.sleep(0.5)
        node._drain_joints()
        assert node.history.newest_stamp == 1.0                          # the stranger's 5.0 never came
    finally:
        stranger.close()
        pub.close()
        node.close()
        srv.close()
