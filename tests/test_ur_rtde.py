"""``ur-rtde:`` (R27, R31): the speed slider sink and the joint source, with the real client of the
PyPI package ``ur-rtde`` (``rtde_io``, ``rtde_receive``, written by others) against
``tests/rtde_server.py`` — an RTDE peer written from the published protocol description, NOT a
UR controller. The server records every slider value it receives and knows its joints at every
time of its clock: those are the truths here.

The ur-rtde Python bindings connect to port 30004 only, so each server listens on its own
loopback address ``127.x.y.z:30004``.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest

from rtde_server import ServerProcess, free_loopback_host

pytestmark = pytest.mark.skipif(importlib.util.find_spec("rtde_io") is None,
                                reason="the ur-rtde package is not installed (pip install 'depthguard[ur]')")


@pytest.fixture
def server():
    srv = ServerProcess(free_loopback_host(), lifetime_s=600)
    yield srv
    srv.stop()


def _feed(sink, values, dt=0.002):
    for v in values:
        sink(SimpleNamespace(speed_scale=v))
        time.sleep(dt)


def _wait(pred, timeout=5.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.02)
    return False


@pytest.mark.slow
def test_a_stop_sends_exactly_zero_and_a_resume_starts_at_the_floor(server):
    from depthguard.runtime.ur_sink import UrSpeedSlider

    sink = UrSpeedSlider(server.host, resume_hold_s=0.1, stale_s=2.0)   # the watchdog has its own test
    try:
        _feed(sink, [0.6] * 150)                  # 0.3 s at 0.6: 0 first (a new connection), the floor, then 0.6
        _feed(sink, [0.004] * 100)                # below the floor: a stop, never rounded up
        _feed(sink, [0.9] * 150)                  # resume
        assert _wait(lambda: server.sliders and server.sliders[-1][1] == 0.9)
        values = [v for _, v in server.sliders]
        t = [s for s, _ in server.sliders]
        # the server's joints halted while the slider was 0: the phase did not move
        i0 = values.index(0.0, 1)
        stop_span = (t[i0], t[i0 + 1])
        assert server.call("phase_at", stop_span[1]) == pytest.approx(server.call("phase_at", stop_span[0]), abs=1e-12)
    finally:
        sink.close()
    values = [v for _, v in server.sliders]
    compact = [v for k, v in enumerate(values) if k == 0 or v != values[k - 1]]
    assert compact == [0.0, 0.01, 0.6, 0.0, 0.01, 0.9, 0.0]       # ... and close sets 0
    assert all(v == 0.0 or v >= 0.01 for v in values)             # never between 0 and the floor
    # the floor is held resume_hold_s before the slider follows
    t = [s for s, _ in server.sliders]
    k = values.index(0.9)
    assert t[k] - t[k - 1] >= 0.1 - 0.01


def test_no_reaction_for_longer_than_stale_s_sets_the_slider_to_zero(server):
    from depthguard.runtime.ur_sink import UrSpeedSlider

    sink = UrSpeedSlider(server.host, stale_s=0.1)
    try:
        _feed(sink, [1.0] * 200)
        assert _wait(lambda: server.slider == 1.0)
        time.sleep(0.4)                               # the monitor went silent
        assert server.slider == 0.0
        assert any("no reaction from the monitor" in e for _, e in sink.events)
    finally:
        sink.close()


@pytest.mark.slow
def test_a_lost_server_is_said_and_the_slider_is_zero_first_when_it_is_back():
    from depthguard.runtime.ur_sink import UrSpeedSlider

    host = free_loopback_host()
    srv = ServerProcess(host, lifetime_s=60)
    sink = UrSpeedSlider(host, retry_s=0.3)
    try:
        _feed(sink, [0.7] * 200)
        assert _wait(lambda: srv.slider == 0.7)
        srv.stop()
        _feed(sink, [0.7] * 300, dt=0.005)
        assert sink.lost is not None and "connection lost" in sink.lost and "R27" in sink.lost
        srv = ServerProcess(host, lifetime_s=60)
        end = time.monotonic() + 15
        while time.monotonic() < end and not (srv.sliders and srv.sliders[-1][1] == 0.7):
            _feed(sink, [0.7] * 10, dt=0.01)
        values = [v for _, v in srv.sliders]
        assert sink.lost is None and values[0] == 0.0 and values[-1] == 0.7
    finally:
        sink.close()
        srv.stop()


def test_bad_addresses_are_one_sentence():
    from depthguard.runtime.sink_specs import open_sink

    with pytest.raises(ValueError, match="unknown scheme 'franka'.*ur-rtde"):
        open_sink("franka:1.2.3.4")
    with pytest.raises(ValueError, match="port 30004 only"):
        open_sink("ur-rtde:127.0.0.1:1234")
    with pytest.raises(ValueError, match="cannot reach the robot"):
        open_sink(f"ur-rtde:{free_loopback_host()}")        # nothing listens there


def test_a_joint_address_that_does_not_answer_is_one_sentence():
    from depthguard.sim import load_cell
    from depthguard.sources.base import open_joints

    rig = load_cell("ur3-cell").rig
    with pytest.raises(ValueError, match="cannot reach the robot at 127.*:30004"):
        open_joints(f"ur-rtde:{free_loopback_host()}", rig)
    with pytest.raises(ValueError, match="port 30004 only"):
        open_joints("ur-rtde:127.0.0.1:9", rig)


@pytest.mark.slow
def test_joints_of_the_robot_are_stamped_on_arrival_and_equal_the_servers(server):
    from depthguard.sim import load_cell
    from depthguard.sources.base import open_joints

    rig = load_cell("ur3-cell").rig
    src = open_joints(f"ur-rtde:{server.host}", rig)
    try:
        time.sleep(0.5)
        states = src.states_until(time.time())
        pairs = list(src.robot_stamps)
    finally:
        src.close()
    assert len(states) > 30                                     # 125 Hz for 0.5 s
    stamps = [s for s, _ in states]
    assert all(b > a for a, b in zip(stamps, stamps[1:]))
    assert abs(stamps[-1] - time.time()) < 1.0                   # the host's wall clock
    robot = dict(pairs)
    for s, q in states[:: max(1, len(states) // 10)]:
        truth, _ = server.joints_at(robot[s])                    # the server's q at its own timestamp
        np.testing.assert_allclose(q, truth, atol=1e-12)


@pytest.mark.slow
def test_the_joints_tell_ssm_the_programs_speed_whatever_the_slider(server):
    """``commanded_qd`` (R33): the measured joint velocity over the slider times the limiter, as the
    server's program runs at slider 1 — ``a 2 pi c cos(2 pi phase)`` at the state's own timestamp,
    by hand — at a slider of 0.3; held while the slider is 0; the monitor takes it once attached."""
    from depthguard.runtime.ur_sink import UrSpeedSlider
    from depthguard.sim import load_cell
    from depthguard.sources.base import open_joints

    rig = load_cell("ur3-cell").rig
    src = open_joints(f"ur-rtde:{server.host}", rig)
    sink = UrSpeedSlider(server.host, resume_hold_s=0.05, stale_s=2.0)
    a, c = np.array([0.6, 0.3, 0.3, 0.2, 0.2, 0.4]), 0.1                # the server's defaults
    try:
        _feed(sink, [0.3] * 300)                                         # 0.6 s: 0, the floor, then 0.3
        assert _wait(lambda: server.sliders and server.sliders[-1][1] == 0.3)
        time.sleep(0.2)
        stamp, nominal = src.nominal
        truth = a * 2.0 * np.pi * c * np.cos(2.0 * np.pi * server.call("phase_at", stamp))
        _, moving = server.joints_at(stamp)                              # what the robot did: 0.3 of it
        np.testing.assert_allclose(nominal, truth, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(moving, 0.3 * truth, rtol=1e-9, atol=1e-12)
        monitor = SimpleNamespace(commanded_qd=None)
        src.attach(monitor)
        assert monitor.commanded_qd(None) is src.nominal[1]
        _feed(sink, [0.0] * 100)                                         # stopped: the last velocity held
        assert _wait(lambda: server.sliders[-1][1] == 0.0)
        time.sleep(0.2)
        held_at = src.nominal[0]
        stop_at = server.sliders[-1][0]
        assert held_at <= stop_at + 0.01 and src.received > 100
    finally:
        sink.close()
        src.close()


def test_a_robot_outside_the_rig_is_refused_in_one_sentence():
    from depthguard.sim import load_cell
    from depthguard.sources.base import open_joints

    with ServerProcess(free_loopback_host(), q0=(0.0, -1.2, 3.5, -1.4, -1.57, 0.0), lifetime_s=60) as srv:
        with pytest.raises(ValueError, match=r"do not fit the rig: joint 3 = .* outside its limits"):
            open_joints(f"ur-rtde:{srv.host}", load_cell("ur3-cell").rig)
        with pytest.raises(ValueError, match="reports 6 joints, the rig's robot lwr4 has 7"):
            open_joints(f"ur-rtde:{srv.host}", load_cell("flacco-cell").rig)


def _on_path(q, q0, amplitude):
    """True when ``q`` lies on the server's path ``q0 + amplitude * s`` for one s in [-1, 1]."""
    s = (q[0] - q0[0]) / amplitude[0]
    return abs(s) <= 1 + 1e-9 and np.allclose(q, np.asarray(q0) + np.asarray(amplitude) * s, atol=1e-5)


@pytest.mark.slow
def test_the_slider_follows_the_monitors_override_as_a_person_reaches_in_and_leaves(server):
    """flacco-cell from ``reach`` (the hand 7 cm from the end effector, withdrawn 10-11.5 s), the
    monitor in ``ssm`` mode: its speed scale drops to a stop and comes back; the slider the
    server received follows it. The fast run is deterministic: stopped until 2.0 s, a resume cut
    short at 2.04 s, then back to 1.0 at 2.77 s; 3 s of it show all of that (4 s did, in 113 s)."""
    from depthguard.runtime.monitor import Monitor
    from depthguard.runtime.runner import run
    from depthguard.runtime.ur_sink import UrSpeedSlider
    from depthguard.sim import load_cell
    from depthguard.sources.base import open_joints, open_source

    rig = load_cell("flacco-cell").rig
    cfg = rig.monitor.model_copy(update={"reaction": "ssm", "ssm": rig.monitor.ssm.model_copy(update={"range": 0.8})})
    ctx: dict = {}
    frames, joints = open_source("sim:flacco-cell:reach", rig, ctx), open_joints("sim", rig, ctx)
    log = []
    sink = UrSpeedSlider(server.host, stale_s=5.0)      # a fast run may pause longer than 0.1 s between cycles
    received = []

    def record(r):
        log.append((time.monotonic(), float(r.speed_scale)))
    mon = Monitor(rig, cfg, sinks=[record, sink])
    try:
        run(mon, [frames], joints, duration=3.0, fast=True)
        time.sleep(0.2)
        received = [v for _, v in server.sliders]
    finally:
        mon.close()
        frames.close()
        joints.close()
    scales = [s for _, s in log]
    assert min(scales) < 0.3 and scales[-1] == 1.0, (min(scales), scales[-1])     # the monitor slowed, resumed
    targets = {sink.target(s) for s in scales}
    assert received and set(received) <= targets | {0.0, 0.01}           # every value was an override sent on
    first_low = next(i for i, v in enumerate(received) if 0.0 < v < 0.5)
    assert received[-1] == 1.0 and first_low < len(received) - 1      # dropped, then came back to 1
    assert [v for _, v in server.sliders][-1] == 0.0                   # close: the slider is 0


@pytest.mark.slow
def test_the_monitor_runs_on_the_robots_joints_and_a_lost_robot_stops_it_with_a_reason():
    from depthguard.runtime.monitor import Monitor
    from depthguard.runtime.runner import run
    from depthguard.sim import load_cell
    from depthguard.sources.base import open_joints

    rig = load_cell("ur3-cell").rig
    options = dict(q0=tuple(float(v) for v in rig.robot_q0), amplitude=(0.5, 0.3, 0.3, 0.2, 0.2, 0.4))
    srv = ServerProcess(free_loopback_host(), lifetime_s=60, **options)
    records = []
    stopper = threading.Timer(2.0, srv.stop)                  # the robot goes away 2 s after the first cycle

    def record(r):
        if not records:
            stopper.start()
        records.append(r.to_dict())
    mon = Monitor(rig, rig.monitor, sinks=[record])
    joints = open_joints(f"ur-rtde:{srv.host}", rig)
    try:
        run(mon, [], joints, duration=3.5)
    finally:
        stopper.cancel()
        mon.close()
        joints.close()
        srv.stop()
    t0 = records[0]["t"]
    before = [r for r in records if 0.5 < r["t"] - t0 < 1.9]
    ages = [r["joints_age_s"] for r in before]
    assert before and None not in ages
    # fresh (within joints_stale_s = 50 ms) in most cycles; a loaded machine delays a few states
    assert sum(a < 0.05 for a in ages) >= 0.8 * len(ages), sorted(ages)[-10:]
    assert all(_on_path(r["q"], options["q0"], options["amplitude"]) for r in before)   # the server's joints
    assert len({tuple(r["q"]) for r in before}) > 20                                     # moving along its path
    after = [r for r in records if r["t"] - t0 > 2.5]
    assert after and all("stale:joints" in r["reasons"] and r["override"] == 0.0 for r in after[-50:])
    assert joints.lost is not None and "joint states lost" in joints.lost and "R27" in joints.lost


@pytest.mark.slow
@pytest.mark.parametrize("args, words", [
    (["--sink", "franka:1.2.3.4"], "the scheme must be one of"),
    (["--sink", "ur-rtde:{host}"], "cannot reach the robot at"),
    (["--joints", "ur-rtde:{host}"], "cannot reach the robot at"),      # beside sim: it is followed, if it answers
    (["--sink", "ur-rtde:{host}", "--fast"], "run in real time"),
])
def test_monitor_refuses_a_bad_robot_in_one_line(tmp_path, args, words):
    host = free_loopback_host()                          # nothing listens there
    res = subprocess.run([sys.executable, "-m", "depthguard.cli", "monitor", "--cell", "ur3-cell", "--out",
                          str(tmp_path / "o"), *[a.format(host=host) for a in args]],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 2, (res.stdout, res.stderr)
    assert words in res.stderr and "Traceback" not in res.stderr
