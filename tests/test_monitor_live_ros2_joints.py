"""Simulated cameras with live ROS 2 joint states end on Ctrl-C with their summary (issue 33
item 13: ``monitor --cell flacco-cell --joints ros2:`` never ended, ignored Ctrl-C and SIGTERM and
grew about 20 MB/s). The joints come from a ROS 2 node written from rmw_zenoh's design
(``ros2_peer.ForeignNode``, payloads by ``mcap_ros2``) through a real Zenoh router on loopback;
the zenoh: joint source with SIGTERM is ``test_monitor_live_joints``."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time

import pytest

from ros2_peer import ForeignNode, router  # noqa: F401  (router: the fixture)
from test_monitor_live_joints import _fused_in_log

DG = [sys.executable, "-m", "depthguard.cli"]


@pytest.mark.slow
def test_simulated_cameras_with_ros2_joints_fuse_and_stop_on_ctrl_c_with_a_summary(router, tmp_path):  # noqa: F811
    from depthguard.sim.cells import load_cell

    rig = load_cell("flacco-cell").rig
    q0 = [float(x) for x in load_cell("flacco-cell").scene.robot_q(0.0)]
    out = tmp_path / "o"
    node = ForeignNode(router)
    stop = threading.Event()

    def publish():                                   # a robot driver's /joint_states, ~200 Hz, wall clock
        while not stop.is_set():
            node.joints(time.time(), rig.robot.joint_names, q0)
            time.sleep(0.005)

    th = threading.Thread(target=publish, daemon=True)
    th.start()
    proc = subprocess.Popen(DG + ["monitor", "--cell", "flacco-cell", "--joints", "ros2:", "--ros2-router", router,
                                  "--out", str(out), "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    log = out / "log.jsonl"
    try:
        end = time.monotonic() + 600                 # a condition with a generous deadline, not a sleep
        while time.monotonic() < end and proc.poll() is None and not _fused_in_log(log):
            time.sleep(0.2)
        assert proc.poll() is None, proc.communicate()
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        stop.set()
        th.join(2)
        node.close()
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] is True and "interrupted" in stdout
    assert summary["sources"]["joints"] == "ros2:"
    assert summary["cycles"] == len(log.read_text().splitlines()) > 200
    first_t = json.loads(log.read_text().splitlines()[0])["t"]
    assert abs(first_t - time.time()) < 600                          # the run's clock is the wall clock
    cams = summary["stats"]["cameras"]
    assert set(cams) == {"cam0", "cam1"} and all(c["fused"] > 0 for c in cams.values()), cams
