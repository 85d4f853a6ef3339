"""Simulated cameras with live joint states (issue 33 item 13, R27, R29): the simulator runs on
the run's clock (the wall clock when a joint source is live), its catch-up is bounded, and the
run ends on its duration or on SIGTERM with its summary written."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import threading
import time
import uuid

import numpy as np
import pytest

from depthguard.sources.sim_source import SimFrames, SimWorld

DG = [sys.executable, "-m", "depthguard.cli"]


def test_a_world_far_behind_computes_at_most_its_span_of_joint_ticks():
    """60 s asked at once: the world jumps ahead and keeps the last 5 s (2500 ticks at 500 Hz)
    instead of computing and returning 30 001 states; its newest state is the tick due at 60 s."""
    world = SimWorld("flacco-cell", alone=True, noiseless=True)
    new = world.advance(60.0)
    assert len(new) == world.states.maxlen == 2500
    assert new[-1][0] == pytest.approx(60.0) and new[0][0] == pytest.approx(60.0 - 2499 / 500)
    assert world.skipped_ticks == 30001 - 2500
    assert np.all(np.diff([s for s, _ in new]) > 0)


def test_the_simulator_stamps_on_the_run_clock_it_is_given():
    """start_clock(T) with T a wall clock: joint states and frames are stamped T + their
    simulated time, and the robot is where the scene puts it at that simulated time."""
    world = SimWorld("flacco-cell", alone=True, noiseless=True)
    frames = SimFrames(world)
    T = 1.7e9 + 0.25
    frames.start_clock(T)
    out = frames.frames_until(T + 0.1005)         # a wall clock's float resolution is 2.4e-7 s
    assert {f.camera_id for f in out} == set(frames.camera_ids)
    assert all(T - 1e-6 <= f.stamp <= T + 0.1005 for f in out)
    stamps = [s for s, _ in world.states]
    assert len(stamps) == 51 and stamps[0] == T and stamps[-1] == pytest.approx(T + 0.1, abs=1e-6)
    q_end = dict(world.states)[stamps[-1]]
    np.testing.assert_allclose(q_end, world.scene.robot_q(0.1), atol=1e-9)   # unobstructed: tau = t


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _fused_in_log(log, cycles: int = 200) -> bool:
    """More than ``cycles`` cycles logged and the last one's grid holds a frame of each camera (fused)."""
    if not log.exists():
        return False
    with open(log, "rb") as fh:
        lines = fh.read().splitlines()
    if len(lines) <= cycles:
        return False
    try:
        last = json.loads(lines[-2])                  # the last one may be half written
    except ValueError:
        return False
    return all(c["age_s"] is not None for c in last["cameras"].values())


@pytest.mark.slow
@pytest.mark.realtime
def test_simulated_cameras_with_zenoh_joints_fuse_and_stop_on_sigterm_with_a_summary(tmp_path):
    """`monitor --cell flacco-cell --joints zenoh:KEY` with a publisher of the robot's joints on
    the wall clock (loopback): the simulated frames meet the live joints (frames fused), and
    SIGTERM ends the run with its summary written (it used to hang, ignore SIGTERM and grow)."""
    import zenoh

    from depthguard.transport.settings import zenoh_config
    from depthguard.sim.cells import load_cell

    port = _free_port()
    key = f"test/{uuid.uuid4().hex}/joints"
    q0 = [float(x) for x in load_cell("flacco-cell").scene.robot_q(0.0)]
    out = tmp_path / "o"
    proc = subprocess.Popen(DG + ["monitor", "--cell", "flacco-cell", "--joints", f"zenoh:{key}",
                                  "--zenoh-listen", f"tcp/127.0.0.1:{port}", "--out", str(out), "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    stop = threading.Event()
    session = None

    def publish():
        pub = session.declare_publisher(key)
        while not stop.is_set():
            pub.put(json.dumps({"stamp": time.time(), "q": q0}))
            time.sleep(0.005)

    th = threading.Thread(target=publish, daemon=True)
    log = out / "log.jsonl"
    try:
        end = time.monotonic() + 600
        while time.monotonic() < end and proc.poll() is None and not log.exists():
            time.sleep(0.2)                    # the monitor listens: its joint source is open
        session = zenoh.open(zenoh_config(["tcp/127.0.0.1:0"], [f"tcp/127.0.0.1:{port}"]))
        th.start()
        while time.monotonic() < end and proc.poll() is None:
            if _fused_in_log(log):            # both cameras' frames met the live joints: what is checked
                break
            time.sleep(0.2)
        assert proc.poll() is None, proc.communicate()
        proc.send_signal(signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        stop.set()
        if th.is_alive():
            th.join(2)
        if session is not None:
            session.close()
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] is True and "interrupted" in stdout
    assert summary["cycles"] == len((out / "log.jsonl").read_text().splitlines()) > 100
    first_t = json.loads((out / "log.jsonl").read_text().splitlines()[0])["t"]
    assert abs(first_t - time.time()) < 600                          # the run's clock is the wall clock
    cams = summary["stats"]["cameras"]
    assert set(cams) == {"cam0", "cam1"} and all(c["fused"] > 0 for c in cams.values()), cams


@pytest.mark.slow
@pytest.mark.realtime
def test_simulated_cameras_with_silent_zenoh_joints_end_on_their_duration_and_stop_the_robot(tmp_path):
    """No publisher: the run ends after --duration with the robot stopped for want of joint states."""
    out = tmp_path / "o"
    res = subprocess.run(DG + ["monitor", "--cell", "flacco-cell", "--joints", f"zenoh:test/{uuid.uuid4().hex}",
                               "--duration", "3", "--out", str(out), "--quiet"],
                         capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] is False
    assert summary["run_time_s"] == pytest.approx(3.0, abs=0.05)
    assert summary["override_min"] == 0.0
    # stopped from the start (R27: no joint state ever), not ramped down from full speed
    assert summary["stopped_s"] == pytest.approx(summary["run_time_s"], abs=0.05)
    assert all(c["fused"] == 0 for c in summary["stats"]["cameras"].values())
