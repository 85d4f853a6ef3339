"""The closed loop (R13–R15, R26, R27): trajectory, supervisor, and short scenario runs.

The scenario runs are marked slow: each simulates a few seconds of flacco-cell
with both Kinects fused by the depth grid map (Flacco 2015; the principal Kinect
alone, Flacco 2014's set-up, where stated) at 30 Hz with their noise model, and
the controller and the distances at 500 Hz. Truth: the scene's exact signed
distances (``sim.ground_truth``) to the robot's capsules.
"""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.evaluation.closed_loop.loop import LoopConfig, SafetySupervisor, stop_reasons
from depthguard.evaluation.closed_loop.trajectory import Hexagon


# ------------------------------------------------------------------ fast
def test_hexagon_passes_corners_at_speed():
    hx = Hexagon(center=(-0.6, 0.0, 0.6), radius=0.2, speed=0.4, accel=2.0)
    C = hx.corners
    # regular hexagon in the plane x = -0.6: all sides = radius
    assert np.allclose(C[:, 0], -0.6)
    assert np.allclose(np.linalg.norm(np.roll(C, -1, 0) - C, axis=1), 0.2)
    # side time = L/v + v/a = 0.5 + 0.2 s; corners reached at multiples of it, at rest
    assert hx.side_time == pytest.approx(0.7)
    for k in range(7):
        p, v = hx.at(k * 0.7)
        np.testing.assert_allclose(p, C[k % 6], atol=1e-12)
        assert np.linalg.norm(v) < 1e-9
    taus = np.linspace(0, hx.period, 4001)
    P = np.array([hx.at(t)[0] for t in taus])
    Vv = np.array([hx.at(t)[1] for t in taus])
    assert np.linalg.norm(Vv, axis=1).max() == pytest.approx(0.4)
    # velocity is the derivative of position (central differences)
    dP = (P[2:] - P[:-2]) / (taus[2] - taus[0])
    assert np.abs(dP - Vv[1:-1]).max() < 2e-3
    assert hx.path_distance(P).max() < 1e-12
    with pytest.raises(ValueError, match="radius"):
        Hexagon(radius=0.0)


def test_supervisor_ramps_and_reports():
    sup = SafetySupervisor(dt=0.002, stop_time=0.5, resume_time=1.0, k0=1.0)
    ks = [sup.update(0.002 * i, {"stale:cam1": "camera cam1 stale"}) for i in range(300)]
    # 1 -> 0 in stop_time / dt = 250 cycles, linear
    assert ks[0] == pytest.approx(1 - 1 / 250)
    assert ks[248] > 0.0 and ks[249] == 0.0
    ep = sup.episodes[0]
    assert ep["reason"] == "camera cam1 stale" and ep["t_start"] == 0.0
    assert ep["t_stopped"] == pytest.approx(0.002 * 249)
    k = [sup.update(0.6 + 0.002 * i, {}) for i in range(500)][-1]
    assert k == pytest.approx(1.0) and ep["t_end"] == pytest.approx(0.6)



def _ramp_and_episodes(k0, stop_time, resume_time, cycles):
    """The truth from R26/R27 alone, not from the supervisor's fields: the override falls by
    ``dt / stop_time`` in a cycle with a reason and rises by ``dt / resume_time`` in one without,
    within [0, 1]; an episode per reason key runs from the first cycle with it to the first
    without it, ``t_stopped`` the first cycle within it with the override at 0. ``cycles``:
    ``(t, dt, reasons)``; returns the overrides and the episodes in the order they began."""
    k, ks, episodes, open_ = k0, [], [], {}
    for t, dt, reasons in cycles:
        for key in [x for x in open_ if x not in reasons]:
            open_.pop(key)["t_end"] = round(t, 4)
        for key, msg in reasons.items():
            if key not in open_:
                open_[key] = {"reason": msg, "key": key, "t_start": round(t, 4), "t_end": None, "t_stopped": None}
                episodes.append(open_[key])
        k = max(0.0, k - dt / stop_time) if reasons else min(1.0, k + dt / resume_time)
        if k == 0.0:
            for ep in open_.values():
                if ep["t_stopped"] is None:
                    ep["t_stopped"] = round(t, 4)
        ks.append(k)
    return ks, episodes


def test_supervisor_ramps_and_episodes_follow_r26_r27_on_random_reason_sequences():
    """The override and the episodes over random runs of reasons, gaps and irregular dt (the
    usual cycle takes a shortcut, issue 29) against :func:`_ramp_and_episodes`."""
    rng = np.random.default_rng(29)
    keys = ["stale:camA", "stale:camB", "unobserved:ee", "stale:joints"]
    for k0 in (0.0, 1.0):
        sup = SafetySupervisor(dt=0.002, stop_time=0.05, resume_time=0.1, k0=k0)
        cycles, t = [], 0.0
        for i in range(3000):
            dt = float(rng.choice([0.002, 0.002, 0.0035, 0.0]))
            t += dt
            quiet = rng.random() < 0.7 if (i // 100) % 2 else rng.random() < 0.05
            cycles.append((t, dt, {} if quiet else {k: f"{k} holds" for k in keys if rng.random() < 0.5}))
        got = [sup.update(t, reasons, dt=dt) for t, dt, reasons in cycles]
        ks, episodes = _ramp_and_episodes(k0, 0.05, 0.1, cycles)
        assert np.allclose(got, ks, rtol=0.0, atol=1e-9)
        rise, fall = np.diff(got) > 0, np.diff(got) < 0
        assert rise.any() and fall.any() and min(got) == 0.0 and max(got) > 0.5      # ramps both ways, stops
        assert sup.episodes == episodes and len(episodes) > 10
        assert any(e["t_end"] is not None for e in episodes) and any(e["t_stopped"] is not None for e in episodes)


def test_supervisor_starts_stopped_and_ramps_up_only_once_nothing_stops_it():
    """R26/R27: before the first cycle without a stop reason nothing is known: the override is 0
    from the first cycle on (never a ramp down from full speed while blind), and it rises over
    ``resume_time`` only once no reason holds."""
    sup = SafetySupervisor(dt=0.002, stop_time=0.5, resume_time=1.0)
    blind = [sup.update(0.002 * i, {"stale:cam0": "camera cam0: none yet"}) for i in range(50)]
    assert max(blind) == 0.0
    seeing = [sup.update(0.1 + 0.002 * i, {}) for i in range(600)]
    assert seeing[0] == pytest.approx(1 / 500) and seeing[498] < 1.0 and seeing[499] == pytest.approx(1.0)
    assert all(b >= a for a, b in zip(seeing, seeing[1:]))
    with pytest.raises(ValueError, match="k0"):
        SafetySupervisor(dt=0.002, stop_time=0.5, resume_time=1.0, k0=1.5)


def test_stop_reasons_rules():
    names = ["ee", "wrist", "elbow"]
    D = np.array([np.inf, 0.0, 0.2])
    V = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    obs = np.array([True, True, False])
    r = stop_reasons(np.array([0.01, 0.2]), 0.1, ["cam0", "cam1"], obs, D, V, names)
    assert set(r) == {"stale:cam1", "unobserved:elbow", "inside:wrist"}
    assert "R27" in r["stale:cam1"] and "R26" in r["unobserved:elbow"]
    # inf = nothing within rho (zero direction there is fine); a fresh frame is fine
    r = stop_reasons(np.array([0.0, 0.099]), 0.1, ["cam0", "cam1"], np.ones(3, bool),
                     np.array([np.inf, 0.3, 0.2]), np.array([[0, 0, 0], [0, 1.0, 0], [1.0, 0, 0]]), names)
    assert r == {}


def test_stale_reasons_say_each_camera_and_limit_every_cycle():
    """The stale sentences (made once per camera and limit, issue 29) are the ones R27 asks for, for
    each camera, limit and 'no frame yet', however often and in whatever order they are asked."""
    ok = np.ones(2, bool), np.full(2, np.inf), np.zeros((2, 3))
    for _ in range(3):
        for limit in (0.1, 0.25, 0.1004):
            for ages, cams in (([0.3, np.inf], ["camA", "camB"]), ([np.inf, 0.3], ["camB", "camA"])):
                r = stop_reasons(np.array(ages), limit, cams, *ok, ["ee", "elbow"])
                said = {f"stale:{c}": (f"camera {c}: no frame yet - stale data (R27)" if a == np.inf else
                                       f"camera {c}: no frame for more than {round(limit * 1e3)} ms - stale data (R27)")
                        for a, c in zip(ages, cams)}
                assert r == said, (limit, ages, cams)


def test_loop_config_rejects_bad_values():
    with pytest.raises(ValueError, match="rho"):
        LoopConfig(rho=0.0)
    with pytest.raises(ValueError, match="fusion"):
        LoopConfig(fusion="magic")


# ------------------------------------------------------------------ closed loop (slow)
def _run(name, duration, fusion="grid", **cfg):
    from depthguard.evaluation.closed_loop.scenarios import run_scenario
    return run_scenario(name, duration=duration, config=LoopConfig(fusion=fusion, **cfg), write=False)


@pytest.mark.slow
def test_loop_tracks_hexagon_without_obstacles():
    # principal camera: with both cameras the space the robot hides from both stays
    # unknown (R9, R12) and near the end effector at times, so the robot reacts to it
    s, res = _run("empty", 2.0, fusion="single")
    # measured: 0.15 mm RMS (first-order CLIK at 500 Hz, k_p = 5/s), no reaction at all
    assert s["ee_tracking_rms_m"] < 1e-3
    assert s["ee_tracking_clear_share"] == 1.0
    assert s["safe_stops"] == [] and s["min_task_scale"] == 1.0
    assert s["ee_max_repulsion_m_s"] == 0.0
    assert not s["collision"]
    # the EE really goes round the hexagon: 2 s at 0.7 s per side covers more than 2 sides
    assert np.ptp(res.ee[:, 1]) > 0.15 and np.ptp(res.ee[:, 2]) > 0.15


@pytest.mark.slow
@pytest.mark.parametrize("name,duration", [("reach", 4.0), ("plate", 4.5), ("elbow", 5.0), ("shadow", 4.0)])
def test_scenarios_avoid_collision(name, duration):
    """Both cameras through the depth grid, distances at every 500 Hz cycle (R15)."""
    s, res = _run(name, duration)
    assert not s["collision"]
    assert s["min_true_distance_m"] > 0.0
    assert s["avoidance_rate_hz"] > 0 and res.D.shape[0] == round(duration * 500)
    if name == "shadow":
        assert np.min(res.gt_cp) > 0.4        # the person stays farther than rho from the robot
        return
    # the obstacle came within rho of the robot (ground truth) and the robot reacted
    assert np.min(res.gt_cp) < 0.4
    if name in ("reach", "plate"):
        assert s["ee_max_repulsion_m_s"] > 0.2
    if name == "elbow":
        # the elbow stayed clear while the EE kept tracking (limits, not repulsion)
        j = res.control_point_names.index("elbow")
        assert res.gt_cp[:, j].min() > 0.1
        assert s["ee_tracking_rms_all_m"] < 0.05


@pytest.mark.slow
def test_shadow_principal_camera_alone_sees_a_phantom():
    """One camera: the person stays farther than rho from every control point, yet its
    shadow (gray area) is reported near (Flacco 2015 fig. 8)."""
    s, res = _run("shadow", 4.0, fusion="single")
    assert not s["collision"]
    assert np.min(res.gt_cp) > 0.4
    assert np.min(res.D) < 0.2


@pytest.mark.slow
def test_camera_dropout_stops_and_says_why():
    from depthguard.evaluation.closed_loop.scenarios import run_scenario
    s, res = run_scenario("camera_dropout", duration=3.0, config=LoopConfig(fusion="grid"), write=False)
    assert s["stopped_at_end"]
    stops = s["safe_stops"]
    assert stops and "cam1" in stops[0]["reason"] and "R27" in stops[0]["reason"]
    # last frame at t <= 2.0, limit 3 periods = 0.1 s: the stop is requested at about 2.1 s
    assert 2.05 <= stops[0]["t_start"] <= 2.15
    assert stops[0]["t_stopped"] == pytest.approx(stops[0]["t_start"] + 0.5, abs=0.01)
    assert np.abs(res.qd[res.t > stops[0]["t_stopped"] + 0.01]).max() == 0.0


@pytest.mark.slow
def test_loop_results_do_not_depend_on_the_thread_count():
    """The loop runs numba (renders, the grid's frame work) on all threads by default: one and
    two threads give the same run, bit for bit, through a reaction to the person."""
    s1, r1 = _run("reach", 3.0, threads=1)
    s2, r2 = _run("reach", 3.0, threads=2)
    assert s1["ee_max_repulsion_m_s"] > 0.2          # the person came close: the grid was exercised
    for k in ("D", "q", "rep", "gt_robot", "observed"):
        assert np.array_equal(getattr(r1, k), getattr(r2, k)), k
    with pytest.raises(ValueError, match="threads"):
        LoopConfig(threads=0)
    # the frames were simulated on the camera thread and used one latency after capture
    cfg = LoopConfig()
    L, period, dt = cfg.latency, 1.0 / cfg.camera_hz, cfg.dt
    assert L == pytest.approx(period)
    assert r1.frame_age.min() >= L - 1e-9 and r1.frame_age.max() <= L + period + 2 * dt
    with pytest.raises(ValueError, match="camera_latency"):
        LoopConfig(camera_latency=-0.01)


@pytest.mark.slow
def test_latency_zero_uses_each_frame_at_its_capture_cycle():
    """Without latency a frame is used in the cycle it was captured (its age is below one camera
    period at every cycle), and the run reacts to the person as with latency."""
    s, res = _run("reach", 3.0, camera_latency=0.0)
    period = 1.0 / LoopConfig().camera_hz
    assert res.frame_age.min() == 0.0 and res.frame_age.max() < period + 2 * LoopConfig().dt
    assert s["ee_max_repulsion_m_s"] > 0.2 and not s["collision"]


def test_points_hold_robot_kernel_equals_twin_and_the_reasons():
    """issue 29: the control cycle asks the numba kernel whether a point gives a reason before it builds
    the sentences; kernel, plain-numpy twin and the reasons themselves agree on random cycles,
    with the edges (D = 0, -0, inf, NaN; zero and underflowing directions; unobserved points)."""
    from depthguard.control.supervisor import points_hold_robot, points_hold_robot_numpy

    rng = np.random.default_rng(5)
    names = [f"p{i}" for i in range(9)]
    held = 0
    for k in range(400):
        m = int(rng.integers(1, 10))
        D = rng.choice([np.inf, 0.0, -0.0, np.nan, 0.1, 0.3, 1e-9], size=m)
        V = rng.normal(size=(m, 3)) * rng.choice([1.0, 0.0, 1e-170], size=(m, 1))
        obs = rng.random(m) < (0.97 if k % 2 else 0.7)
        fast = points_hold_robot(obs, D, V)
        assert fast == points_hold_robot_numpy(obs, D, V)
        reasons = stop_reasons(np.zeros(1), 0.1, ["cam0"], obs, D, V, names[:m])
        slow = stop_reasons(np.zeros(1), 0.1, ["cam0"], list(obs), list(D), V.tolist(), names[:m])   # the old path
        assert reasons == slow and fast == bool(reasons)
        held += fast
    assert 0 < held < 400
