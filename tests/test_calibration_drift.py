"""Drift watch in the monitor (R34): a camera bumped while running is untrusted within 1 s.

The frames come from the noisy simulator (Kinect v1 model) at the camera's **true** pose, while
the monitor keeps the rig's pose; the truth of "moved" is the rotation the test applies.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from depthguard.sources.sim_source import sim_world

from depthguard.calibration.refine import so3_exp
from depthguard.filtering.expected import ExpectedDepth
from depthguard.runtime.drift import MIN_JUDGED, DriftWatch
from depthguard.runtime.monitor import Monitor, warm_up
from depthguard.sim import load_cell
from depthguard.sources import SimulatedCamera
from depthguard.sources.frame import Frame

CAM_HZ = 30.0


@pytest.fixture(scope="module")
def cell():
    c = load_cell("flacco-cell")
    warm_up(c.rig, c.rig.monitor.with_changes(invalid="free"))
    return c


def turned(cam, axis: str, deg: float):
    """``cam`` turned by ``deg`` about its optical centre: ``pan`` about the world vertical, ``tilt``
    about its x axis, ``roll`` about its optical axis."""
    R = cam.world_from_camera[:3, :3]
    ax = {"pan": np.array([0.0, 0.0, 1.0]), "tilt": R[:, 0], "roll": R[:, 2]}[axis]
    T = cam.world_from_camera.copy()
    T[:3, :3] = so3_exp(ax * math.radians(deg)) @ R
    return cam.with_pose(T)


class Bench:
    """The monitor fed at its control rate (joints) and 30 Hz per camera (noisy frames of the still robot in
    the empty cell, each rendered by the camera's true pose ``self.true[cid]``)."""

    def __init__(self, cell, cfg):
        self.rig = cell.rig
        self.mon = Monitor(self.rig, cfg)
        self.q0 = np.asarray(self.rig.robot_q0, dtype=np.float64)
        self.meshes = list(self.rig.static_meshes()) + list(self.rig.robot.link_meshes(self.q0))
        self.true = {c.id: c for c in self.rig.cameras}
        self.sims: dict = {}
        self.k = 0
        self.next = {c.id: i * 0.37 / CAM_HZ for i, c in enumerate(self.rig.cameras)}
        self.reactions = []

    def frame(self, cid, tc):
        cam = self.true[cid]
        key = (cid, cam.key())
        if key not in self.sims:
            self.sims[key] = SimulatedCamera(cam, seed=5)
        return self.sims[key].capture(self.meshes, stamp=tc)

    def until(self, t_end):
        dt = self.mon.config.dt
        while self.k * dt <= t_end + 1e-9:
            t = self.k * dt
            self.mon.push_joints(t, self.q0)
            pushed = False
            for cid in self.next:
                while self.next[cid] <= t + 1e-9:
                    tc = self.next[cid]
                    self.next[cid] += 1.0 / CAM_HZ
                    self.mon.push_frame(Frame(cid, self.frame(cid, tc), tc))
                    pushed = True
            if pushed:
                self.mon.flush()
            self.reactions.append(self.mon.step(t))
            self.k += 1
        return self.reactions[-1]


def test_a_camera_turned_by_two_degrees_is_untrusted_and_the_robot_stopped_within_one_second(cell):
    # the watch runs per frame; a short resume ramp: the override starts at 0 and is 1 by 0.3 s
    cfg = cell.rig.monitor.with_changes(invalid="free", control_hz=100.0, resume_time=0.2)
    b = Bench(cell, cfg)
    try:
        r = b.until(0.3)
        assert "untrusted:cam1" not in r.reasons and r.override == 1.0, r.reasons
        assert r.cameras["cam1"].state == "fresh"
        t_bump = b.k * cfg.dt
        b.true["cam1"] = turned(cell.rig.camera("cam1"), "tilt", 2.0)          # bumped
        b.until(t_bump + 1.0)
        flagged = next(x for x in b.reactions if "untrusted:cam1" in x.reasons)
        stopped = next(x for x in b.reactions if x.t > t_bump and x.override == 0.0)
        assert flagged.t - t_bump <= 1.0 and stopped.t - t_bump <= 1.0, (flagged.t - t_bump, stopped.t - t_bump)
        msg = flagged.reasons["untrusted:cam1"]
        assert "cam1" in msg and "%" in msg                                     # names the camera and the residual
        assert flagged.cameras["cam1"].state == "untrusted" and flagged.cameras["cam0"].state == "fresh"
        assert flagged.to_dict()["cameras"]["cam1"]["state"] == "untrusted"
        assert "untrusted:cam0" not in b.reactions[-1].reasons                 # the other camera did not move
        # latched: it stays untrusted while the camera stays where it is
        assert "untrusted:cam1" in b.reactions[-1].reasons
        # the user accepts it as it is now: the stop reason goes; a further turn is flagged again
        b.mon.accept_camera("cam1")
        t_acc = b.k * cfg.dt
        b.until(t_acc + 0.5)
        assert all("untrusted:cam1" not in x.reasons for x in b.reactions if x.t > t_acc)
        b.true["cam1"] = turned(b.true["cam1"], "tilt", 2.0)
        t2 = b.k * cfg.dt
        b.until(t2 + 1.0)
        again = next(x for x in b.reactions if x.t > t2 and "untrusted:cam1" in x.reasons)
        assert again.t - t2 <= 1.0
        with pytest.raises(ValueError, match="not monitored"):
            b.mon.accept_camera("nope")
    finally:
        b.mon.close()


def test_a_camera_turned_by_a_fifth_of_a_degree_is_not_flagged(cell):
    # the watch runs per frame; a short resume ramp: the override starts at 0 and is 1 by 0.3 s
    cfg = cell.rig.monitor.with_changes(invalid="free", control_hz=100.0, resume_time=0.2)
    b = Bench(cell, cfg)
    try:
        b.true["cam0"] = turned(cell.rig.camera("cam0"), "tilt", 0.2)
        b.true["cam1"] = turned(cell.rig.camera("cam1"), "roll", 0.2)
        b.until(1.0)
        assert all(not any(k.startswith("untrusted:") for k in x.reasons) for x in b.reactions)
        assert all(d["judged"] >= 25 for d in b.mon.drift().values()), b.mon.drift()
    finally:
        b.mon.close()


@pytest.mark.parametrize("cell_name", ["flacco-cell", "ur3-cell"])
def test_drift_statistic_two_degrees_flagged_a_fifth_not_about_each_axis(cell_name):
    """The statistic alone (no monitor), every camera, three axes: 2 deg exceeds the threshold
    (2 %) in every frame of the scene's people moving, a pan about the vertical included (the
    cells' rooms have walls: measured 4-25 % of the pixels for a pan, where an earlier form of
    this test exempted every pan); 0.2 deg never does."""
    c = load_cell(cell_name)
    rig = c.rig
    times = np.linspace(0.0, c.scene.duration, 5, endpoint=False)
    for cam in rig.cameras[:2]:
        dw = DriftWatch(cam, ExpectedDepth(cam, rig.robot, rig.static_meshes()).static)
        for axis in ("pan", "tilt", "roll"):
            for deg in (0.2, 2.0):
                sim = SimulatedCamera(turned(cam, axis, deg), seed=2)
                shares = np.array([dw.statistic(sim.capture(c.scene.meshes_at(float(t), robot=True)[0],
                                                            stamp=float(t)))[0] for t in times])
                if deg == 0.2:
                    assert np.all(shares < dw.share_limit / 2), (cam.id, axis, shares)
                else:
                    assert np.all(shares > dw.share_limit), (cam.id, axis, shares)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_drift_counts_equal_numpy_twin_at_the_limits(dtype):
    """The worker's compiled drift statistic counts what the plain-numpy twin counts, on frames
    with samples exactly at and one float step around both limits (float32 limits against a
    float32 or float64 frame), NaN, +-inf, zeros, and a frame too occluded to judge (nan)."""
    rig = load_cell("flacco-cell").rig
    cam = rig.cameras[0]
    static = ExpectedDepth(cam, None, rig.static_meshes()).static
    dw = DriftWatch(cam, static)
    rng = np.random.default_rng(3)
    idx, S = dw.index, dw.index.size
    assert S > 1000
    for trial in range(5):
        d = static.astype(np.float64) + rng.normal(0.0, 0.01, static.shape)
        flat = d.reshape(-1)
        pick = rng.permutation(S)
        k = S // 12
        flat[idx[pick[:k]]] = dw.far_limit[pick[:k]]                                        # at: not far
        flat[idx[pick[k:2 * k]]] = np.nextafter(dw.far_limit[pick[k:2 * k]], np.float32(np.inf))  # far
        flat[idx[pick[2 * k:3 * k]]] = dw.near_limit[pick[2 * k:3 * k]]                     # at: seen
        flat[idx[pick[3 * k:4 * k]]] = np.nextafter(dw.near_limit[pick[3 * k:4 * k]], np.float32(0))  # occluded
        flat[idx[pick[4 * k:4 * k + 50]]] = np.nan
        flat[idx[pick[4 * k + 50:4 * k + 100]]] = np.inf
        flat[idx[pick[4 * k + 100:4 * k + 150]]] = -np.inf
        flat[idx[pick[4 * k + 150:4 * k + 200]]] = 0.0
        if trial == 4:
            flat[idx[pick[MIN_JUDGED // 2:]]] = 0.1                              # all but a few occluded
        d = d.astype(dtype)
        got, want = dw.statistic(d), dw.statistic_numpy(d)
        assert got[1] == want[1] and (got[0] == want[0] or (got[0] != got[0] and want[0] != want[0])), (got, want)
        assert (got[0] != got[0]) == (trial == 4)
        if trial < 4:                    # the limits' samples counted as the module docstring says
            assert 0 < got[0] < 1


def test_no_frame_of_the_scene_of_people_moving_comes_near_the_drift_threshold(cell):
    """The suite's slice of the soak below: flacco-cell's whole scene (reach, carry, shadow, hidden
    hand: 32 s) every quarter second, noisy frames of both cameras at their rig poses through the
    watch the monitor builds (its settings, the static scene's expected depth): every frame is
    judged and stays under half the threshold (measured: at most 0.11 % against 2 %), so no run of
    frames can flag a camera; the watch never flags."""
    from depthguard.runtime.drift import MIN_JUDGED

    cfg = cell.rig.monitor
    assert cfg.drift_watch and cell.scene.duration == 32.0
    times = np.arange(0.0, cell.scene.duration, 0.25)
    for cam in cell.rig.cameras:
        dw = DriftWatch(cam, ExpectedDepth(cam, cell.rig.robot, cell.rig.static_meshes()).static,
                        k_sigma=cfg.drift_sigma, share=cfg.drift_share, frames=cfg.drift_frames)
        sim = SimulatedCamera(cam, seed=3)
        shares = []
        for t in times:
            depth = sim.capture(cell.scene.meshes_at(float(t), robot=True)[0], stamp=float(t))
            share, n = dw.statistic(depth)
            assert n >= MIN_JUDGED, (cam.id, t, n)
            shares.append(share)
            assert not dw.update(depth, float(t)), (cam.id, t, dw.message)
        assert max(shares) < dw.share_limit / 2, (cam.id, max(shares))
        assert dw.judged == len(times) and not dw.untrusted


@pytest.mark.soak          # make soak: the cell's whole 32 s scene through the monitor (about 1.5 min on a quiet 2-core machine)
def test_the_whole_scene_of_people_moving_raises_no_false_alarm():
    """Every situation of flacco-cell's scene once (reach, carry, shadow, hidden hand: 32 s), at
    30 Hz with noise: no camera is flagged. (It ran 60 s: the second half replays the same
    motions with other noise, at twice the suite's time.)"""
    from depthguard.runtime import runner
    from depthguard.sources.base import open_joints, open_source

    c = load_cell("flacco-cell")
    ctx: dict = {}
    src = open_source("sim:flacco-cell:seed=3", c.rig, ctx)
    js = open_joints("sim", c.rig, ctx)
    world = sim_world(ctx)
    untrusted = []
    cfg = c.rig.monitor.with_changes(control_hz=100.0)     # the drift watch runs on the frames, not the cycles
    with Monitor(c.rig, cfg, sinks=[world.on_reaction,
                                     lambda r: untrusted.extend(k for k in r.reasons if k.startswith("untrusted"))]
                 ) as mon:
        runner.run(mon, [src], js, duration=c.scene.duration + 0.5, fast=True)
        drift = mon.drift()
    assert c.scene.duration == 32.0
    assert untrusted == []
    assert all(d["judged"] > 800 for d in drift.values()), drift         # 32.5 s x 30 Hz, judged
