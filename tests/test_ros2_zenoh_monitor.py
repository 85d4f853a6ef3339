"""The monitor fed through ``ros2:`` (R29, R31): the same frames and joint states, once pushed
directly and once sent as ROS 2 messages (by a publisher written from rmw_zenoh's design doc,
payloads encoded by ``mcap_ros2``) through a real Zenoh router, give the same reactions; and
``depthguard monitor --source ros2: --ros2`` runs in real time against that router and
publishes its overrides where a ROS 2 subscriber finds them.

The frames are the simulator's (flacco-cell, a person reaching), open loop, in whole
millimetres (16UC1, as ROS depth drivers send them).
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from ros2_peer import (REACTION_DEF, FLOAT64_DEF, ForeignNode, check_frames_used_live, client, decoder,  # noqa: F401
                       router, tokens, wait_for)

from depthguard.runtime.monitor import Monitor
from depthguard.runtime.runner import run
from depthguard.sim import load_cell
from depthguard.sources.base import open_joints, open_source
from depthguard.sources.frame import Frame
from depthguard.transport.ros2_zenoh import type_hash

DURATION = 0.5


class Listed:
    """Frames or joint states from a list, by stamp; never done (like a live source)."""

    def __init__(self, items, stamp):
        self.items, self.stamp, self.camera_ids = list(items), stamp, ["cam0", "cam1"]

    def frames_until(self, t):
        out = [x for x in self.items if self.stamp(x) <= t]
        self.items = [x for x in self.items if self.stamp(x) > t]
        return out

    states_until = frames_until
    done = False
    lost = None

    def close(self):
        pass


@pytest.fixture(scope="module")
def recorded():
    """The simulator's frames (mm, uint16) and joint states over DURATION s, open loop."""
    rig = load_cell("flacco-cell").rig
    ctx: dict = {}
    fs, js = open_source("sim:flacco-cell:reach", rig, ctx), open_joints("sim", rig, ctx)
    frames, states = [], []
    for k in range(int(round(DURATION / 0.002)) + 1):
        t = 0.002 * k
        states += js.states_until(t)
        frames += [(f.camera_id, f.stamp, np.rint(f.depth.astype(np.float64) * 1000.0).astype("<u2"))
                   for f in fs.frames_until(t)]
    fs.close()
    js.close()
    return rig, frames, states


def _log(rig, frame_sources, joint_source, extra_sinks=()) -> list[dict]:
    records = []
    mon = Monitor(rig, rig.monitor, sinks=[lambda r: records.append(r.to_dict()), *extra_sinks])
    try:
        run(mon, frame_sources, joint_source, duration=DURATION, fast=True)
    finally:
        mon.close()
    return records


def test_monitor_through_ros2_gives_the_reactions_of_the_frames_pushed_directly(recorded, router):
    from depthguard.runtime.ros2_sink import Ros2Sink
    from depthguard.transport.ros2_zenoh import node_for

    rig, frames, states = recorded
    mm = np.float32(1000.0)

    def ros_time(s: float) -> float:                  # a stamp as builtin_interfaces/Time carries it (sec, nanosec)
        ns = round(s * 1e9)
        return float(ns // 10**9) + float(ns % 10**9) * 1e-9

    direct = _log(rig, [Listed([Frame(c, v.astype(np.float32) / mm, ros_time(s)) for c, s, v in frames], lambda f: f.stamp)],
                  Listed([(ros_time(s), q) for s, q in states], lambda s: s[0]))

    ctx = {"ros2_router": router, "ros2_domain": 0}
    src, jsrc = open_source("ros2:", rig, ctx), open_joints("ros2:", rig, ctx)
    src.max_pending = len(frames)                     # everything is sent before the run takes it
    sink = Ros2Sink(node_for(ctx), rig.robot)
    spy = client(router)
    got: list[bytes] = []
    sub = spy.declare_subscriber(f"0/depthguard/reaction/depthguard_msgs::msg::dds_::Reaction_/"
                                 f"{type_hash('depthguard_msgs/msg/Reaction')}", lambda s: got.append(s.payload.to_bytes()))
    ros = ForeignNode(router)
    assert wait_for(lambda: sum("/MS/" in k for k in tokens(ros.session)) == 5)
    for cam in rig.cameras:
        ros.info(cam, 0.0)
    time.sleep(0.3)                                   # the CameraInfo first (a frame before it is skipped)
    for cid, stamp, values in frames:
        ros.image(rig.camera(cid), stamp, values, "16UC1")
    for stamp, q in states:
        ros.joints(stamp, rig.robot.joint_names, q)
    assert wait_for(lambda: sum(src.frames.values()) == len(frames) and jsrc.states == len(states), 20.0), \
        (src.frames, jsrc.states, src.counters())
    try:
        through = _log(rig, [src], jsrc, [sink])
    finally:
        src.close()
        jsrc.close()
    assert src.counters() == {}                       # nothing refused on the way
    assert len(direct) == len(through) == int(round(DURATION / 0.002)) + 1
    assert through == direct                          # the same reactions, to the bit
    assert direct[-1]["cameras"]["cam0"]["frames"] > 5 and any(p["distance"] is not None for p in direct[-1]["points"])
    assert len({p["distance"] for r in direct for p in r["points"]}) > 20   # the distances change as the person moves
    # and the ROS 2 subscriber got every reaction (decoded by mcap_ros2)
    # (20 s: under the whole suite on 2 cores the last of them came after the 5 s default once)
    assert wait_for(lambda: len(got) == len(through), 20.0), (len(got), len(through))
    dec = decoder("depthguard_msgs/msg/Reaction", REACTION_DEF)
    for raw, rec in zip(got, through):
        msg = dec(raw)
        assert round(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9, 6) == rec["t"]
        assert msg.override == pytest.approx(rec["override"], abs=1e-6)
    sub.undeclare()
    spy.close()
    ros.close()


def test_cli_monitor_runs_live_on_ros2_topics_and_publishes_its_overrides(router, tmp_path):
    from depthguard.filtering.expected import ExpectedDepth

    rig = load_cell("flacco-cell").rig
    q0 = np.asarray(rig.robot_q0, dtype=np.float64)
    views = {c.id: np.rint(np.asarray(ExpectedDepth(c, rig.robot, rig.static_meshes()).known(q0)) * 1000).astype("<u2")
             for c in rig.cameras}
    ros = ForeignNode(router)
    spy = client(router)
    overrides: list[float] = []
    f64 = decoder("std_msgs/msg/Float64", FLOAT64_DEF)
    sub = spy.declare_subscriber(f"0/depthguard/override/std_msgs::msg::dds_::Float64_/{type_hash('std_msgs/msg/Float64')}",
                                 lambda s: overrides.append(f64(s.payload.to_bytes()).data))
    seen_tokens: set[str] = set()
    stop = threading.Event()

    def camera_node():                                 # a ROS camera driver and robot driver, live
        k = 0
        while not stop.is_set():
            now = time.time()
            ros.joints(now, rig.robot.joint_names, q0)
            if k % 6 == 0:                             # ~30 Hz, the rate the cell's cameras are judged by
                for cam in rig.cameras:
                    ros.info(cam, now)
                    ros.image(cam, now, views[cam.id], "16UC1")
                seen_tokens.update(tokens(ros.session))
            k += 1
            time.sleep(0.005)

    th = threading.Thread(target=camera_node, daemon=True)
    th.start()
    out = tmp_path / "run"
    try:
        try:
            res = subprocess.run([sys.executable, "-m", "depthguard.cli", "monitor", "--cell", "flacco-cell",
                                  "--source", "ros2:", "--ros2", "--ros2-router", router, "--duration", "3",
                                  "--quiet", "--out", str(out)], capture_output=True, text=True, timeout=240)
        finally:
            stop.set()
            th.join(5)
        _check_cli_run(res, out, overrides, seen_tokens)
    finally:                                           # a failed check must not leave sessions that hang pytest
        sub.undeclare()
        spy.close()
        ros.close()


def _check_cli_run(res, out, overrides, seen_tokens):
    assert res.returncode == 0, res.stderr
    log = [json.loads(x) for x in (out / "log.jsonl").read_text().splitlines()]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["sources"] == {"frames": ["ros2:"], "joints": "ros2:"}
    counts = summary["source_counts"]["ros2:"]
    # what came in while the monitor started waits in bounded queues, the oldest dropped
    assert set(counts) <= {"no_camera_info:cam0", "no_camera_info:cam1", "overflow:cam0", "overflow:cam1",
                           "joints_overflow"}, counts
    assert log[-1]["cameras"]["cam0"]["frames"] > 10 and log[-1]["cameras"]["cam1"]["frames"] > 10
    check_frames_used_live(log, summary)               # as they come, to the end (not "fresh": see there)
    # the ROS graph saw the monitor's node, its subscriptions and its publishers
    assert any(k.endswith("/NN/%/%/depthguard") for k in seen_tokens)
    assert any("/MS/%/%/depthguard/%cam0%depth%image_rect_raw/sensor_msgs::msg::dds_::Image_/" in k for k in seen_tokens)
    assert any("/MS/%/%/depthguard/%joint_states/sensor_msgs::msg::dds_::JointState_/" in k for k in seen_tokens)
    assert any("/MP/%/%/depthguard/%depthguard%override/std_msgs::msg::dds_::Float64_/" in k for k in seen_tokens)
    # every cycle's override went out (the sink publishes each; loopback drops none)
    assert wait_for(lambda: len(overrides) == len(log), 5.0), (len(overrides), len(log))
    assert overrides == pytest.approx([r["override"] for r in log], abs=1e-6)
