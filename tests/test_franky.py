"""``--sink franky:`` and ``--joints franky:`` against franky-sim (PyPI ``franky-sim``, written by
others: an FR3 simulated in MuJoCo behind a server that speaks the libfranka network protocol),
driven by franky (PyPI ``franky-control``) as on a real robot (R27, R30, R31).

The truth is the simulator's own joint state (``robot.inner_state``, read after every physics
step), not what franky says. Under load the simulator runs slower than real time (measured
180-250 steps/s of its 1 kHz here); the checks use its velocities, not wall-clock durations.
"""

from __future__ import annotations

import copy
import subprocess
import sys
import threading
import time
import types

import numpy as np
import pytest

pytest.importorskip("franky", reason="franky-control (extra depthguard[franka]) drives the robot")
pytest.importorskip("franky_sim", reason="franky-sim (test extra) is the simulated FR3")

from depthguard.runtime.franky_sink import FrankySink, open_franky_sink  # noqa: E402
from depthguard.sim import load_cell  # noqa: E402
from depthguard.sources.base import open_joints  # noqa: E402
from depthguard.sources.joints import JointSourceError  # noqa: E402
from depthguard.transport.franky_link import FrankyError  # noqa: E402


@pytest.fixture
def fr3():
    """A franky-sim FR3 on a free loopback address; ``truth``: (monotonic s, q, dq) after each step.

    One per test, not per module: franky-sim steps its physics in real time whether a client is
    connected or not (measured 0.53 cores while idle), and a simulator kept alive between this
    module's tests ran beside the other test process's tests — beside a real-time test running
    "alone" too (tests/conftest.py), whose monitor then had half a core less than it thought."""
    from franky_sim import SimulationServer
    from franky_sim.mujoco_simulator import MujocoSimulator

    with MujocoSimulator(enable_visualization=False) as sim:
        robot = sim.add_robot()
        truth: list = []
        lock = threading.Lock()

        def record(_sim):
            st = robot.inner_state
            with lock:
                truth.append((time.monotonic(), np.array(st.q, dtype=float), np.array(st.dq, dtype=float)))

        sim.register_post_step_callback(record)
        with SimulationServer(sim) as server:
            server.run_async()
            yield types.SimpleNamespace(host=robot.hostname, truth=truth, lock=lock, robot=robot)


def _window(fr3, a, b):
    with fr3.lock:
        rows = [x for x in fr3.truth if a <= x[0] < b]
    return np.array([x[1] for x in rows]), np.array([np.abs(x[2]).max() for x in rows])


def _drive_for(sink, scale, seconds):
    """The monitor's side: a reaction every 10 ms with ``speed_scale`` for ``seconds`` of the wall clock."""
    start = time.monotonic()
    while time.monotonic() - start < seconds:
        sink(types.SimpleNamespace(speed_scale=scale))
        time.sleep(0.01)


def _drive(sink, fr3, scale, steps, fast=None, wall_s=60.0):
    """The monitor's side: a reaction every 10 ms with ``speed_scale`` until franky-sim has made
    ``steps`` physics steps (ms of its time: under load it runs at a fraction of real time, and a
    phase timed by the wall clock then left the robot mid-way: a stop judged after 1.5 s of the
    wall clock was 0.3 s into its tail), or once a joint moves faster than ``fast`` rad/s;
    (start, end) monotonic."""
    start = time.monotonic()
    with fr3.lock:
        n0 = len(fr3.truth)
    while time.monotonic() - start < wall_s:
        sink(types.SimpleNamespace(speed_scale=scale))
        time.sleep(0.01)
        with fr3.lock:
            if len(fr3.truth) - n0 >= steps or (fast is not None and np.abs(fr3.truth[-1][2]).max() > fast):
                break
    return start, time.monotonic()


@pytest.mark.slow
def test_sink_slows_stops_and_resumes_the_path_as_franky_sim_reports(fr3):
    home = np.array(fr3.robot.inner_state.q, dtype=float)
    far = home + np.array([1.4, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    sink = FrankySink(fr3.host, np.array([home, far]))
    try:
        full = _drive(sink, fr3, 1.0, 3000, fast=1.5)                 # until joint 1 is past 1.5 rad/s
        slow = _drive(sink, fr3, 0.1, 1500)
        stop = _drive(sink, fr3, 0.0, 1500)
        resume = _drive(sink, fr3, 1.0, 1500)
        _, v_full = _window(fr3, full[0], full[1])
        _, v_slow = _window(fr3, slow[0], slow[1])
        q_stop, v_stop = _window(fr3, stop[0], stop[1])
        _, v_res = _window(fr3, resume[0], resume[1])
        # franky-sim's joint velocities: moving, slower at 0.1, zero when stopped, moving again.
        # Slowing down brakes with the robot's full deceleration: from > 1.5 rad/s to 0.1 of joint
        # 1's velocity limit (2.62 rad/s, the FR3's data sheet) within 0.7 s of franky-sim's time
        # (0.43 s measured; 1.38 s when franky's one factor also scaled the deceleration)
        assert v_full.max() > 1.5, v_full.max()
        assert 0.05 < v_slow[700:].max() < 1.1 * 0.1 * 2.62, (v_slow[700:].max(), v_full.max())
        assert v_stop[-500:].max() < 2e-3, v_stop[-500:].max()       # the last 0.5 s of franky-sim's time
        assert np.ptp(q_stop[-500:], axis=0).max() < 1e-3            # standing: the joints do not move
        assert v_res.max() > 0.5, v_res.max()
        kinds = [k for _t, k, _i, _f in sink.legs]
        assert "stop" in kinds and kinds[kinds.index("stop") + 1] == "leg"
        assert {round(f, 2) for _t, k, _i, f in sink.legs if k == "leg"} >= {1.0, 0.1}
        # the monitor goes silent: no reaction for more than 0.1 s stops the robot (R27)
        silent = time.monotonic()
        end = silent + 30.0
        while len(_window(fr3, silent, end)[1]) < 1500 and time.monotonic() < end:   # 1.5 s of the simulator's time
            time.sleep(0.1)
        _, v_silent = _window(fr3, silent, end)
        assert len(v_silent) >= 1500 and v_silent[-100:].max() < 2e-3, (len(v_silent), v_silent[-100:].max())
        assert any("no reaction from the monitor" in e and "R27" in e for _t, e in sink.events)
        assert sink.lost is None
    finally:
        sink.close()


def test_the_sink_tells_ssm_the_legs_full_speed(fr3):
    """``commanded_qd``: towards the waypoint the robot goes to (the next one where it stands at
    it), the joint with the farthest to go, relative to its limit, at its limit (by hand); the
    monitor takes it once attached (R33)."""
    home = np.array(fr3.robot.inner_state.q, dtype=float)
    far = home + np.array([1.4, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    sink = FrankySink(fr3.host, np.array([home, far]))
    try:
        assert sink.index == 0                                       # no reaction yet: it stands at home
        assert np.allclose(sink.commanded_qd(home), [2.62, 0, 0, 0, 0, 0, 0])          # at home: on to far
        q = home + np.array([0.7, 0.35, 0.0, 0.0, 0.0, 1.5, 0.0])
        expected = -np.array([0.7, 0.35, 0.0, 0.0, 0.0, 1.5, 0.0]) / max(0.7 / 2.62, 0.35 / 2.62, 1.5 / 4.18)
        assert np.allclose(sink.commanded_qd(q), expected)                              # back to home
        assert np.isclose(np.abs(expected[5]), 4.18)                 # joint 6 limits this one
        monitor = types.SimpleNamespace(commanded_qd=None)
        sink.attach(monitor)
        assert np.allclose(monitor.commanded_qd(q), expected)
    finally:
        sink.close()


def test_joints_are_franky_sims_stamped_on_arrival_with_the_robot_time(fr3):
    rig = load_cell("flacco-cell").rig                  # 7 joints, limits that hold the FR3's home
    t0 = time.time()
    src = open_joints(f"franky:{fr3.host}", rig, {})
    try:
        time.sleep(1.0)
        states = src.states_until(time.time())
        t1 = time.time()
        q_true = _window(fr3, time.monotonic() - 0.5, time.monotonic() + 1)[0]
    finally:
        src.close()
    assert len(states) > 20 and src.rejected == 0
    stamps = np.array([s for s, _q in states])
    assert np.all(np.diff(stamps) > 0) and t0 <= stamps[0] and stamps[-1] <= t1      # host clock, on arrival
    robot_t = np.array([r for _h, r in src.robot_stamps])
    assert np.all(np.diff(robot_t) > 0)                                             # the robot's own clock, kept
    assert np.abs(states[-1][1] - q_true[-1]).max() < 1e-3                          # what the simulator holds


def test_bad_robots_are_refused_in_one_sentence(fr3, tmp_path):
    rig = load_cell("flacco-cell").rig
    with pytest.raises(JointSourceError, match=r"the rig's robot .* has 6"):          # another joint count
        open_joints(f"franky:{fr3.host}", load_cell("ur3-cell").rig, {})
    narrow = copy.deepcopy(rig)
    narrow.robot.q_max[3] = -1.7                                                     # the FR3 stands at -1.57
    with pytest.raises(JointSourceError, match=r"do not fit the rig: joint 4 = -1.57.* outside its limits"):
        open_joints(f"franky:{fr3.host}", narrow, {})
    path = tmp_path / "path.csv"
    path.write_text("0,0,0,-1.5,0,1.5,0.7\n0,0,0,-1.5,0,1.5,3.5\n")
    with pytest.raises(FrankyError, match=r"waypoint 2, joint 7 = 3.5 is outside the rig's limits"):
        open_franky_sink(f"{fr3.host},path={path}", rig=rig)
    with pytest.raises(FrankyError, match=r"give the path"):
        open_franky_sink(fr3.host, rig=rig)
    with pytest.raises(FrankyError, match=r"no Franka robot answers at 127.0.0.3:1337"):
        open_franky_sink(f"127.0.0.3,path={path}")


def test_a_robot_that_leaves_the_rigs_limits_is_said_and_its_joints_go_stale(fr3, capsys):
    """The robot's states fit the rig at open, then no longer (here: the rig's limit of joint 4
    moved past where the FR3 stands): no state is used, one line says why, the joints go stale."""
    rig = copy.deepcopy(load_cell("flacco-cell").rig)
    src = open_joints(f"franky:{fr3.host}", rig, {})
    try:
        time.sleep(0.3)
        assert src.states_until(time.time()) and src.rejected == 0
        rig.robot.q_max[3] = -1.7                                          # the FR3 stands at -1.57
        time.sleep(0.1)
        src.states_until(time.time())                                      # what came before the change
        n = src.received
        time.sleep(1.0)
        assert src.received == n and src.rejected >= 2 and not src.states_until(time.time() + 1.0)
        assert "joint 4 = -1.57" in src.last_error
    finally:
        src.close()
    said = [x for x in capsys.readouterr().err.splitlines() if "joint state refused" in x]
    assert len(said) == 1 and "R27" in said[0], said


@pytest.mark.slow
@pytest.mark.parametrize("args, words", [
    (["--sink", "franky:127.0.0.3,path={path}"], "no Franka robot answers at 127.0.0.3:1337"),
    (["--sink", "franky:127.0.0.3"], "give the path the robot runs"),
    (["--joints", "franky:127.0.0.3"], "no Franka robot answers at 127.0.0.3:1337"),   # beside sim: followed
])
def test_monitor_refuses_a_bad_franka_in_one_line(tmp_path, args, words):
    path = tmp_path / "path.csv"
    path.write_text("0,0,0,-1.5,0,1.5,0.7\n0.2,0,0,-1.5,0,1.5,0.7\n")
    res = subprocess.run([sys.executable, "-m", "depthguard.cli", "monitor", "--cell", "flacco-cell", "--out",
                          str(tmp_path / "o"), *[a.format(path=path) for a in args]],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 2, (res.stdout, res.stderr)
    assert words in res.stderr and "Traceback" not in res.stderr


@pytest.mark.slow
def test_a_lost_robot_is_said_and_the_joints_go_stale(fr3):
    """The simulator's server goes away while the path runs: the sink says so (R27) and the
    joint source stops giving states (the monitor then stops on stale joints)."""
    from franky_sim import SimulationServer
    from franky_sim.mujoco_simulator import MujocoSimulator

    rig = load_cell("flacco-cell").rig
    with MujocoSimulator(enable_visualization=False) as sim:
        robot = sim.add_robot()
        server = SimulationServer(sim)
        server.__enter__()
        server.run_async()
        home = np.array(robot.inner_state.q, dtype=float)
        sink = FrankySink(robot.hostname, np.array([home, home + [0.5, 0, 0, 0, 0, 0, 0]]))
        src = open_joints(f"franky:{robot.hostname}", rig, {})
        try:
            _drive_for(sink, 1.0, 1.0)
            assert src.received > 0 and sink.lost is None
            server.__exit__(None, None, None)
            _drive_for(sink, 1.0, 3.0)
            n = src.received
            time.sleep(0.5)
            assert sink.lost is not None and "R27" in sink.lost, sink.events
            assert src.received == n                                   # no state comes any more
        finally:
            src.close()
            sink.close()
