"""Speed and separation monitoring (R33): formula (1) against hand computations, the inverse,
a robot moving away, Z_d against the pixel footprint and the noise model, the numba kernel
against the numpy twin, the protective stop's hysteresis, and the monitor's log."""

from __future__ import annotations

import math

import numpy as np
import pytest

from depthguard.camera import Camera
from depthguard.control import ssm_kernel
from depthguard.control.ssm import TERMS, SSMCameras, largest_scale, protective_distance, ssm_numpy, stopping, z_d
from depthguard.control.ssm_config import SSMConfig, intrusion_distance
from depthguard.control.ssm_runtime import SpeedSeparation


def test_intrusion_distance_iso13855():
    assert intrusion_distance(0.030) == pytest.approx(8 * (0.030 - 0.014))     # 0.128 m
    assert intrusion_distance(0.014) == 0.0 and intrusion_distance(0.010) == 0.0
    assert intrusion_distance(0.041) == 0.85
    with pytest.raises(ValueError):
        intrusion_distance(float("nan"))


def test_formula_every_term_nonzero_by_hand():
    cfg = SSMConfig(deceleration=2.0, brake_delay_s=0.05)
    # v_r = 0.5 m/s: T_s = 0.05 + 0.5/2 = 0.30 s; S_s = 0.5*0.05 + 0.25/4 = 0.0875 m
    t = protective_distance(D=0.9, v_h=1.6, v_r=0.5, T_r=0.1, C=0.128, Z_d=0.03, Z_r=0.01, cfg=cfg)
    assert t["T_s"] == pytest.approx(0.30)
    assert t["S_s"] == pytest.approx(0.0875)
    assert t["S_h"] == pytest.approx(1.6 * 0.40)            # 0.64
    assert t["S_r"] == pytest.approx(0.05)
    assert t["S_p"] == pytest.approx(0.64 + 0.05 + 0.0875 + 0.128 + 0.03 + 0.01)   # 0.9455 m
    for k in ("S_h", "S_r", "S_s", "C", "Z_d", "Z_r"):
        assert t[k] > 0


def test_stopping_table_interpolates_and_extends():
    cfg = SSMConfig(stop_model="table", stop_table={"speed": (0.0, 0.5, 1.0), "distance": (0.0, 0.05, 0.15),
                                                    "time": (0.1, 0.2, 0.35)})
    assert stopping(0.25, cfg) == pytest.approx((0.025, 0.15))
    assert stopping(1.5, cfg) == pytest.approx((0.25, 0.5))   # last segment extended
    with pytest.raises(ValueError):
        SSMConfig(stop_model="table")
    with pytest.raises(ValueError):
        SSMConfig(stop_model="table", stop_table={"speed": (0.1, 0.5), "distance": (0, 1), "time": (0, 1)})


@pytest.mark.parametrize("model", ["deceleration", "table"])
def test_inverse_is_the_largest_scale(model):
    """largest_scale gives S_p(s) = D exactly where it limits, and any larger s breaks it."""
    cfg = SSMConfig(deceleration=2.5, brake_delay_s=0.02) if model == "deceleration" else SSMConfig(
        stop_model="table", stop_table={"speed": (0.0, 0.3, 0.8), "distance": (0.0, 0.02, 0.12),
                                        "time": (0.05, 0.15, 0.4)})
    v0, T_r, C, Zd, Zr = 1.0, 0.08, 0.1, 0.04, 0.01
    for D in (0.45, 0.6, 0.75):
        s = largest_scale(D, v0, 1.6, T_r, C, Zd, Zr, cfg)
        assert 0.0 < s < 1.0
        assert protective_distance(D, 1.6, s * v0, T_r, C, Zd, Zr, cfg)["S_p"] == pytest.approx(D, abs=1e-9)
        assert protective_distance(D, 1.6, min(1.0, s + 1e-3) * v0, T_r, C, Zd, Zr, cfg)["S_p"] > D
    # too close even standing: stop; far enough at full speed: 1
    assert largest_scale(0.2, v0, 1.6, T_r, C, Zd, Zr, cfg) == 0.0
    assert largest_scale(5.0, v0, 1.6, T_r, C, Zd, Zr, cfg) == 1.0


def test_moving_away_is_not_slowed():
    cfg = SSMConfig()
    args = (1.6, 0.08, 0.1, 0.04, 0.01, cfg)
    D = 0.5
    assert largest_scale(D, +1.0, *args) < 0.5          # towards: slowed
    assert largest_scale(D, -1.0, *args) == 1.0         # away: not slowed
    t = protective_distance(D, 1.6, -1.0, 0.08, 0.1, 0.04, 0.01, cfg)
    assert t["S_r"] == 0.0 and t["S_s"] == 0.0 and t["T_s"] == 0.0


def _kinect(pose_z=0.0):
    T = np.eye(4)
    T[2, 3] = pose_z
    return Camera("k", 640, 480, 585.0, 585.0, 319.5, 239.5, T, 0.4, 4.0, "kinect_v1")


def test_zd_grows_with_footprint_and_noise():
    """Z_d at depth z = ½ cell diagonal (z/f, z/f, Δd) + 3 σ(z) + ½ disparity step, σ and the step
    from the Kinect v1 model (sigma_z2 = 0.0012, f b 2^3)."""
    cfg = SSMConfig()
    cams = SSMCameras.of([_kinect()], cfg)
    prev = 0.0
    for z in (0.5, 1.0, 2.0, 3.0, 4.0):
        w = z / 585.0
        step = z * z / (585.0 * 0.075 * 8)
        want = 0.5 * math.sqrt(2 * w * w + 0.01 ** 2) + 3 * 0.0012 * z * z + 0.5 * step
        got = z_d(z, cams.f[0], cams.sigma_a[0], cams.sigma_z2[0], cams.q[0], 0.01, 3.0)
        assert got == pytest.approx(want)
        assert got > prev
        prev = got
    assert z_d(3.0, cams.f[0], cams.sigma_a[0], cams.sigma_z2[0], cams.q[0], 0.01, 3.0) > 0.05   # ~5.6 cm at 3 m


def _random_case(rng, m=6, n=7):
    D = rng.uniform(0.2, 1.2, m)
    D[1] = np.inf                                         # nothing within range
    V = rng.normal(size=(m, 3))
    V /= np.linalg.norm(V, axis=1, keepdims=True)
    V[1] = 0.0
    P = rng.uniform(-0.5, 0.5, (m, 3)) + np.array([0.0, 0.0, 2.0])
    J = rng.normal(scale=0.4, size=(m, 3, n))
    qd = rng.normal(scale=0.5, size=n)
    return D, V, P, J, qd


@pytest.mark.parametrize("model", ["deceleration", "table"])
def test_kernel_matches_numpy_twin(model):
    cfg = SSMConfig(range=1.0, brake_delay_s=0.03) if model == "deceleration" else SSMConfig(
        range=1.0, stop_model="table", stop_table={"speed": (0.0, 0.4, 1.0), "distance": (0.0, 0.03, 0.2),
                                                   "time": (0.05, 0.2, 0.5)})
    cams = SSMCameras.of([_kinect(), _kinect(-0.5)], cfg)
    rng = np.random.default_rng(3)
    C, T_r, dd = 0.1, 0.07, 0.01
    for _ in range(20):
        D, V, P, J, qd = _random_case(rng)
        ref = ssm_numpy(D, V, P, J, qd, cams, cfg, T_r, C, dd)
        out = np.zeros((len(D), len(TERMS)))
        tab = (np.array(cfg.stop_table.speed), np.array(cfg.stop_table.distance), np.array(cfg.stop_table.time)) \
            if model == "table" else (np.zeros(2),) * 3
        kind = 1 if model == "table" else 0
        obs = np.ones(len(D), dtype=bool)
        s_min = ssm_kernel.limits(D, V, P, J, qd, obs, cfg.range, cams.R, cams.t, cams.f, cams.sigma_a,
                                  cams.sigma_z2, cams.q, dd, cfg.noise_sigmas, T_r, C, cfg.z_r, cfg.v_h,
                                  cfg.v_h_near, cfg.near_limit, False, cfg.v_h_floor, np.zeros(len(D)), kind,
                                  cfg.deceleration, cfg.brake_delay_s, *tab, out)
        ssm_kernel.terms_at(1.0, kind, cfg.deceleration, cfg.brake_delay_s, *tab, out)
        np.testing.assert_allclose(out, ref, rtol=1e-9, atol=1e-12)
        assert s_min == pytest.approx(ref[:, TERMS.index("limit")].min())


def test_nothing_in_range_counts_as_the_range_at_full_speed():
    cfg = SSMConfig(range=0.8)
    cams = SSMCameras.of([_kinect()], cfg)
    J = np.zeros((1, 3, 2))
    J[0, 0, 0] = 1.0                                      # joint 0 moves the point along x at 1 m/s per rad/s
    out = ssm_numpy(np.array([np.inf]), np.zeros((1, 3)), np.array([[0.0, 0.0, 2.0]]), J, np.array([0.3, 0.0]),
                    cams, cfg, 0.05, 0.1, 0.01)
    row = dict(zip(TERMS, out[0]))
    assert row["D"] == 0.8 and row["v_r"] == pytest.approx(0.3)   # |J q̇|, direction unknown


def test_protective_stop_hysteresis_and_ramp():
    cfg = SSMConfig(range=1.0, resume_scale=0.2, resume_hold_s=0.1, ramp_up_s=0.5)
    ss = SpeedSeparation(cfg, [_kinect()], 1, 1, 0.01, 3, 0.002)
    V = np.array([[1.0, 0.0, 0.0]])
    P = np.array([[0.0, 0.0, 2.0]])
    J = np.ones((1, 3, 1)) / math.sqrt(3)
    qd = np.array([math.sqrt(3) * 0.5])                   # 0.5 m/s along (1,1,1)/√3
    obs = np.ones(1, dtype=bool)
    dt = 0.002
    s, stop = ss.update(0.0, dt, np.array([0.1]), V, P, J, qd, obs, 0.03)
    assert stop and s == 0.0 and ss.stops == 1
    assert "ssm:p" in ss.reason(["p"])
    t = 0.0
    for _ in range(40):                                   # clear, but held for 0.1 s
        t += dt
        s, stop = ss.update(t, dt, np.array([5.0]), V, P, J, qd, obs, 0.03)
    assert stop and s == 0.0
    for _ in range(20):
        t += dt
        s, stop = ss.update(t, dt, np.array([5.0]), V, P, J, qd, obs, 0.03)
    assert not stop and 0.0 < s <= 0.04 + 1e-12          # ramping up by dt / 0.5 s per cycle
    assert ss.stops == 1
    # a point nobody can judge does not limit (the supervisor stops for it, R26)
    s_before = ss.scale
    s, stop = ss.update(t + dt, dt, np.array([0.1]), V, P, J, qd, np.zeros(1, dtype=bool), 0.03)
    assert not stop and s > s_before


def _feed_still(mon, rig, q0):
    """Joints standing at ``q0`` and each camera's frame of the known scene with the robot at it."""
    from depthguard.filtering.expected import ExpectedDepth
    from depthguard.sources.frame import Frame

    for j in range(3):
        mon.push_joints(j * 0.001, q0)
    for cid in mon.camera_ids:
        cam = rig.camera(cid)
        mon.push_frame(Frame(cid, np.array(ExpectedDepth(cam, rig.robot, rig.static_meshes()).known(q0)), 0.0))
    mon.flush()


def test_monitor_ssm_log_recomputes(tmp_path):
    """A monitor in ssm mode: the log's terms add up to S_p and the scale keeps D >= S_p."""
    from depthguard.runtime.monitor import Monitor, warm_up
    from depthguard.sim import load_cell

    rig = load_cell("flacco-cell").rig
    cfg = rig.monitor.with_changes(reaction="both", ssm={"range": 0.6})
    warm_up(rig, cfg)                        # numba compilation out of the way of flush()
    q0 = np.asarray(rig.robot_q0, dtype=np.float64)
    with Monitor(rig, cfg) as mon:
        _feed_still(mon, rig, q0)
        qd = np.full(rig.robot.dof, 0.4)
        r = mon.step(0.002, q0, qd=qd)
    d = r.to_dict()
    assert d["reaction_mode"] == "both" and 0.0 <= d["speed_scale"] <= 1.0
    s = d["ssm_scale"]
    for p in d["points"][:len(rig.robot.control_points)]:
        t = p["ssm"]
        assert t["S_p"] == pytest.approx(t["S_h"] + t["S_r"] + t["S_s"] + t["C"] + t["Z_d"] + t["Z_r"], abs=5e-6)
        assert t["S_h"] == pytest.approx(t["v_h"] * (t["T_r"] + t["T_s"]), abs=5e-6)
        assert t["T_r"] == pytest.approx(0.002 + 0.002 + 0.008)       # frame age + one period + controller
        if p["observed"] and not r.protective_stop:
            assert t["D"] >= t["S_p"] - 1e-6
        assert t["D"] == pytest.approx(p["distance"] if p["distance"] is not None else 0.6)
    assert s == pytest.approx(r.ssm_scale)


def test_monitor_takes_the_programs_velocity_from_commanded_qd():
    """``Monitor.commanded_qd`` (what knows the program sets it, R33): ``step`` without a ``qd``
    scales that velocity — each point's v_r is its velocity at ``q0`` moving by ``qd`` (forward
    kinematics differenced, not the Jacobian) along the logged direction, or its whole speed where
    nothing is within range — and without it the joints' measured rate (standing: 0)."""
    from depthguard.runtime.monitor import Monitor, warm_up
    from depthguard.sim import load_cell

    rig = load_cell("flacco-cell").rig
    cfg = rig.monitor.with_changes(reaction="ssm", ssm={"range": 0.6})
    warm_up(rig, cfg)
    q0 = np.asarray(rig.robot_q0, dtype=np.float64)
    qd = np.linspace(-0.6, 0.8, rig.robot.dof)
    asked = []
    with Monitor(rig, cfg) as mon:
        _feed_still(mon, rig, q0)
        given = mon.step(0.002, q0, qd=qd).to_dict()
        mon.commanded_qd = lambda q: (asked.append(np.array(q)), qd)[1]
        program = mon.step(0.004).to_dict()
        mon.commanded_qd = None
        measured = mon.step(0.006).to_dict()
    n = len(rig.robot.control_points)
    v_given = np.array([p["ssm"]["v_r"] for p in given["points"][:n]])
    v_program = np.array([p["ssm"]["v_r"] for p in program["points"][:n]])
    v_measured = np.array([p["ssm"]["v_r"] for p in measured["points"][:n]])
    assert len(asked) == 1 and np.array_equal(asked[0], q0)           # at the cycle's joints
    data, eps = rig.robot.create_data(), 1e-6
    rig.robot.forward(q0 + eps * qd, data)
    ahead = np.array(data.cp_positions)
    rig.robot.forward(q0 - eps * qd, data)
    xdot = (ahead - np.array(data.cp_positions)) / (2 * eps)            # (m, 3) m/s
    truth = [float(np.dot(p["direction"], x)) if p["direction"] is not None else float(np.linalg.norm(x))
             for p, x in zip(program["points"][:n], xdot)]
    assert np.abs(truth).max() > 0.05
    np.testing.assert_allclose(v_program, truth, atol=1e-5)
    np.testing.assert_allclose(v_given, truth, atol=1e-5)
    assert np.all(v_measured == 0.0)


def test_measured_vh_follows_the_approach_with_a_floor():
    """v_h measured: a distance shrinking at 1.3 m/s with the robot standing gives v_h -> 1.3;
    a receding obstacle gives the floor."""
    cfg = SSMConfig(range=3.0, v_h_mode="measured", v_h_floor=0.8)
    ss = SpeedSeparation(cfg, [_kinect()], 1, 1, 0.01, 3, 0.002)
    V = np.array([[1.0, 0.0, 0.0]])
    P = np.array([[0.0, 0.0, 2.0]])
    J = np.zeros((1, 3, 1))
    obs = np.ones(1, dtype=bool)
    dt, D = 0.002, 2.5
    for k in range(300):                                  # 0.6 s
        D -= 1.3 * dt
        ss.update(k * dt, dt, np.array([D]), V, P, J, np.zeros(1), obs, 0.03)
    assert ss.table[0, TERMS.index("v_h")] == pytest.approx(1.3, rel=0.02)
    for k in range(300):
        D += 0.5 * dt
        ss.update(1.0 + k * dt, dt, np.array([D]), V, P, J, np.zeros(1), obs, 0.03)
    assert ss.table[0, TERMS.index("v_h")] == pytest.approx(0.8)


def test_ground_truth_check_against_analytic_sphere():
    """SSMTruth on a sphere approaching a still point at 1 m/s: v_h,true = 1, and the margin is
    d - (v_h T_r + C + Z_r) by hand; a point moving towards it adds S_r and the stopping terms."""
    from depthguard.evaluation.closed_loop.ssm_truth import SSMTruth
    from depthguard.geometry.primitives import Sphere
    from depthguard.transforms import pose

    cfg = SSMConfig(deceleration=2.0)
    dt = 0.002
    truth = SSMTruth(cfg, dt)
    ball = Sphere(radius=0.1)
    table = np.zeros((1, len(TERMS)))
    table[0, TERMS.index("T_r")] = 0.05
    table[0, TERMS.index("C")] = 0.1
    table[0, TERMS.index("Z_r")] = 0.01
    table[0, TERMS.index("Z_d")] = 0.02
    P = np.zeros((1, 3))
    truth.check(P, np.zeros((1, 3)), [ball.at(pose(t=np.array([1.0 + dt, 0.0, 0.0])))], table, False)
    margin, bad, bad_zd = truth.check(P, np.zeros((1, 3)), [ball.at(pose(t=np.array([1.0, 0.0, 0.0])))],
                                      table, False)
    assert margin == pytest.approx(0.9 - (1.0 * 0.05 + 0.1 + 0.01), abs=1e-6) and not bad
    # the point moves towards the ball at 0.5 m/s: + S_r + S_s + v_h T_s
    truth.check(P, np.zeros((1, 3)), [ball.at(pose(t=np.array([0.3 + dt, 0.0, 0.0])))], table, False)
    margin, bad, bad_zd = truth.check(P, np.array([[0.5, 0.0, 0.0]]), [ball.at(pose(t=np.array([0.3, 0.0, 0.0])))],
                                      table, False)
    want = 0.2 - (1.0 * (0.05 + 0.25) + 0.5 * 0.05 + 0.0625 + 0.1 + 0.01)
    assert margin == pytest.approx(want, abs=1e-6) and bad and bad_zd
    _, bad, _ = truth.check(P, np.array([[0.5, 0.0, 0.0]]), [ball.at(pose(t=np.array([0.3 - dt, 0.0, 0.0])))],
                            table, True)
    assert not bad                                        # a protective stop in force is no violation


def test_closed_loop_reach_with_ssm_keeps_the_separation():
    """The person's hand approaches the end effector (reach, first 3 s) with reaction ssm: the
    robot slows and stops, the ground truth finds no cycle below S_p with the true hand speed
    while the robot moved, and the task falls behind the clock (it was slowed)."""
    from depthguard.control.ssm_config import SSMConfig
    from depthguard.evaluation.closed_loop.loop import LoopConfig
    from depthguard.evaluation.closed_loop.scenarios import run_scenario

    summary, res = run_scenario("reach", duration=3.0, config=LoopConfig(reaction="ssm", ssm=SSMConfig(range=0.8)),
                                write=False)
    assert not summary["collision"]
    assert int(res.ssm_violation.sum()) == 0
    assert res.ssm_scale.min() < 0.5                       # slowed by the approaching hand
    assert res.tau[-1] < 0.9 * res.t[-1]
    moving = ~res.protective_stop & (np.abs(res.qd).max(axis=1) > 1e-9)
    assert np.all(res.ssm_margin[moving] >= 0.0)


def test_z_d_uses_the_grids_cell_width():
    """With the depth grid's principal binned (``principal_bin`` b), a cell is b pixels wide:
    ``Z_d``'s footprint uses ``f / b``; the sensor's disparity step does not change."""
    from depthguard.control.ssm import SSMCameras, z_d
    from depthguard.control.ssm_config import SSMConfig
    from depthguard.sim.cells import load_cell

    cam = load_cell("flacco-cell").rig.cameras[0]
    one, two = SSMCameras.of([cam], SSMConfig(), 1), SSMCameras.of([cam], SSMConfig(), 2)
    assert two.f[0] == pytest.approx(one.f[0] / 2) and two.q[0] == one.q[0]
    z = 2.5
    w1, w2 = z / one.f[0], z / two.f[0]
    grow = 0.5 * (np.sqrt(2 * w2 ** 2 + 0.01 ** 2) - np.sqrt(2 * w1 ** 2 + 0.01 ** 2))
    assert (z_d(z, two.f[0], two.sigma_a[0], two.sigma_z2[0], two.q[0], 0.01, 3.0)
            - z_d(z, one.f[0], one.sigma_a[0], one.sigma_z2[0], one.q[0], 0.01, 3.0)) == pytest.approx(grow)
