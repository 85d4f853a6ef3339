"""The static scene learned from the cameras (issue 31 points 1, 2, 4).

Truth: the CAD of flacco-cell rendered into each camera (the learned scene must reproduce it
within its band), the rotation the test gives a camera (drift), and a box the test puts in the
cell (a person standing still). Frames come from the noisy simulator (Kinect v1 model) at a
quarter of the cameras' resolution (160x120, same field of view) to keep the tests short; the
robot moves through them and is removed at each frame's joints.
"""

from __future__ import annotations

import dataclasses
import math
import statistics

import numpy as np
import pytest

from depthguard.filtering.expected import ExpectedDepth
from depthguard.filtering.scene_learner import SceneLearner, compare_with_cad
from depthguard.fusion.voxels import VoxelFilter
from depthguard.geometry.primitives import Box
from depthguard.learned_scene import LearnedSceneError, load, robust_depth, robust_depth_numpy, save
from depthguard.rig import Rig, RigError
from depthguard.runtime.drift import DriftWatch
from depthguard.runtime.scene_change import SceneChangeWatch
from depthguard.sim import load_cell
from depthguard.sources import SimulatedCamera


def small(cam, f=4):
    """``cam`` at 1/f of its resolution, same pose and field of view."""
    return dataclasses.replace(cam, width=cam.width // f, height=cam.height // f, fx=cam.fx / f, fy=cam.fy / f,
                               cx=(cam.cx + 0.5) / f - 0.5, cy=(cam.cy + 0.5) / f - 0.5)


def q_at(robot, q0, t):
    """A joint path through the cell (every joint swinging within its limits)."""
    lo, hi = np.asarray(robot.q_min), np.asarray(robot.q_max)
    amp = np.minimum(0.6, 0.4 * (hi - lo))
    return np.clip(q0 + amp * np.sin(2 * math.pi * t / 3.0 + np.arange(len(q0))), lo, hi)


@pytest.fixture(scope="module")
def setup():
    cell = load_cell("flacco-cell")
    rig = cell.rig
    cams = [small(c) for c in rig.cameras]
    rig = dataclasses.replace(rig, cameras=cams)
    cad = list(rig.static_meshes())
    q0 = np.asarray(rig.robot_q0, float)
    learned = {}
    for cam in cams:
        sim = SimulatedCamera(cam, seed=3)
        ln = SceneLearner(cam, rig.robot, max_frames=32)
        for k in range(40):                       # 4 s at 10 Hz, the robot moving
            t = k * 0.1
            q = q_at(rig.robot, q0, t)
            ln.add(sim.capture(cad + list(rig.robot.link_meshes(q)), stamp=t), q)
        learned[cam.id] = (ln.result(), ln.always_hidden())
    return rig, cad, q0, learned


def test_median_kernel_matches_its_twin_and_the_definition():
    rng = np.random.default_rng(1)
    stack = rng.uniform(0.5, 3.0, (9, 7, 11)).astype(np.float32)
    stack[rng.random(stack.shape) < 0.2] = 0.0          # no return
    stack[rng.random(stack.shape) < 0.2] = np.nan       # robot in front
    stack[:, 0, 0] = np.nan                             # always hidden
    stack[:, 0, 1] = 0.0                                # never returns
    a = robust_depth(stack, 0.5, 3)
    b = robust_depth_numpy(stack, 0.5, 3)
    for x, y in zip(a, b):
        np.testing.assert_allclose(x, y, rtol=1e-6, atol=1e-6)
    assert a[0][0, 0] == 0 and a[0][0, 1] == 0
    for (r, c) in [(3, 4), (5, 9), (6, 2)]:            # the definition, pixel by pixel
        col = stack[:, r, c]
        obs = col[np.isfinite(col)]
        ret = [float(v) for v in obs if v > 0]
        if len(ret) >= 3 and len(ret) >= 0.5 * len(obs):
            assert a[0][r, c] == pytest.approx(statistics.median(ret), abs=1e-6)
        else:
            assert a[0][r, c] == 0


def test_learned_scene_reproduces_the_cad(setup):
    rig, cad, _, learned = setup
    for cam in rig.cameras:
        sc, hidden = learned[cam.id]
        r = compare_with_cad(cam, sc, ExpectedDepth(cam, None, cad).static, hidden)
        seen = r["cad_pixels"] - r["hidden_by_robot"]
        assert r["cad_pixels"] > 3000
        assert r["within_band"] / seen >= 0.99, r        # every pixel the cameras could see
        assert r["off"] <= 0.002 * r["cad_pixels"], r
        # nothing is learned where the CAD has no surface within range (the cell has no walls)
        static = ExpectedDepth(cam, None, cad).static
        assert np.count_nonzero(sc.known & (static == 0)) <= 0.002 * static.size


def test_store_load_and_refuse_another_camera(setup, tmp_path):
    rig, _, _, learned = setup
    save(tmp_path / "s", {cid: sc for cid, (sc, _) in learned.items()}, {"source": "test"})
    back = load(tmp_path / "s", rig.cameras)
    for cid, (sc, _) in learned.items():
        np.testing.assert_array_equal(back[cid].depth, sc.depth)
        np.testing.assert_array_equal(back[cid].sigma, sc.sigma)
    cam = rig.cameras[0]
    T = cam.world_from_camera.copy()
    T[0, 3] += 0.01
    with pytest.raises(LearnedSceneError, match=f"camera {cam.id}: the rig's camera pose differs .* 10.0 mm"):
        load(tmp_path / "s", [cam.with_pose(T)])
    with pytest.raises(LearnedSceneError, match="learned at 160x120 and the rig's camera is 640x480"):
        load(tmp_path / "s", [dataclasses.replace(cam, width=640, height=480, fx=cam.fx * 4, fy=cam.fy * 4,
                                                  cx=319.5, cy=239.5)])
    with pytest.raises(LearnedSceneError, match="no scene.json"):
        load(tmp_path / "nothing", rig.cameras)


def test_rig_file_names_the_learned_scene(tmp_path):
    """``scene: {learned: DIR}`` loads with the rig; a moved camera makes the rig refuse to load."""
    cam_block = ("cameras:\n  - id: c0\n    width: 64\n    height: 48\n    fx: 60\n    fy: 60\n    cx: 31.5\n"
                 "    cy: 23.5\n    pose: {look_at: {eye: [0, 0, 2], target: [0, 0, 0], up: [0, 1, 0]}}\n")
    head = "workspace: {min: [-1, -1, 0], max: [1, 1, 1]}\nscene: {learned: learned}\n"
    (tmp_path / "r.yaml").write_text(head + cam_block)
    with pytest.raises(RigError, match="scene.learned: learned scene .*no scene.json"):
        Rig.load(tmp_path / "r.yaml")
    plain = Rig.from_dict(__import__("yaml").safe_load(cam_block + "workspace: {min: [-1, -1, 0], max: [1, 1, 1]}\n"))
    cam = plain.cameras[0]
    depth = np.full(cam.shape, 2.0, np.float32)
    from depthguard.learned_scene import LearnedScene
    save(tmp_path / "learned", {"c0": LearnedScene(cam, depth, np.full(cam.shape, 0.01, np.float32),
                                                   np.full(cam.shape, 5, np.uint16), 5)})
    r = Rig.load(tmp_path / "r.yaml")
    np.testing.assert_array_equal(r.learned_depth("c0"), depth)
    (tmp_path / "r.yaml").write_text(head + cam_block.replace("[0, 0, 2]", "[0, 0.05, 2]"))
    with pytest.raises(RigError, match="camera c0: the rig's camera pose differs from the one it was learned"):
        Rig.load(tmp_path / "r.yaml")


def test_expected_depth_nearer_surface_wins(setup):
    rig, cad, _, _ = setup
    cam = rig.cameras[0]
    only_cad = ExpectedDepth(cam, None, cad).static
    extra = np.zeros(cam.shape, np.float32)
    extra[10:20, 10:30] = 0.5                               # a new shelf, nearer than anything
    extra[30:40, 10:30] = 50.0                              # a far surface: the CAD stays where it has one
    both = ExpectedDepth(cam, None, cad, learned=extra).static
    truth = np.where(only_cad > 0, only_cad, extra)
    truth = np.where((extra > 0) & (only_cad > 0), np.minimum(extra, only_cad), truth)
    np.testing.assert_array_equal(both, truth)


def person_box(x=0.6, y=-0.6):
    return Box.from_bounds([x - 0.2, y - 0.15, 0.0], [x + 0.2, y + 0.15, 1.7], name="person").mesh()


def test_without_cad_the_filter_and_the_drift_watch_answer_as_with_cad(setup):
    rig, cad, q0, learned = setup
    ws = (rig.workspace.lo, rig.workspace.hi)
    person = person_box()
    for cam in rig.cameras:
        sc, _ = learned[cam.id]
        sim = SimulatedCamera(cam, seed=11)
        q = q_at(rig.robot, q0, 1.23)
        d = sim.capture(cad + list(rig.robot.link_meshes(q)) + [person], stamp=7.0)
        f_cad = VoxelFilter(cam, ws, static_meshes=cad, robot=rig.robot)
        f_learned = VoxelFilter(cam, ws, robot=rig.robot, learned=sc.depth)
        f_none = VoxelFilter(cam, ws, robot=rig.robot)
        a = {tuple(k) for k in f_cad.filter(d, q).keys}
        b = {tuple(k) for k in f_learned.filter(d, q).keys}
        n = {tuple(k) for k in f_none.filter(d, q).keys}
        assert len(n - a) > 0.3 * len(a)                      # the known scene matters here
        assert len(a ^ b) <= 0.05 * len(a | b), (len(a), len(b), len(a ^ b))
        # drift: a camera turned by 2 degrees is untrusted with either known scene, a still one with neither
        from test_calibration_drift import turned
        true_turned = turned(cam, "pan", 2.0)
        frames_turned = [SimulatedCamera(true_turned, seed=k).capture(cad, stamp=k) for k in range(3)]
        frames_still = [SimulatedCamera(cam, seed=k).capture(cad, stamp=k) for k in range(3)]
        for static, sigma in ((ExpectedDepth(cam, None, cad).static, None),
                              (ExpectedDepth(cam, None, (), learned=sc.depth).static, sc.sigma)):
            for frames, untrusted in ((frames_still, False), (frames_turned, True)):
                w = DriftWatch(cam, static, sigma=sigma, stride=1)
                for k, fr in enumerate(frames):
                    w.update(fr, float(k))
                assert w.untrusted is untrusted, (cam.id, untrusted, w.share)


def test_a_person_standing_still_stays_an_obstacle_and_is_said(setup):
    """A person stands still for 60 s after learning: the filter keeps them as an obstacle in every
    frame, the change watch says something new stays in their region, and the scene never learns them."""
    rig, cad, q0, learned = setup
    ws = (rig.workspace.lo, rig.workspace.hi)
    person = person_box()
    cam = rig.cameras[0]
    sc, _ = learned[cam.id]
    before = sc.depth.copy()
    f = VoxelFilter(cam, ws, robot=rig.robot, learned=sc.depth)
    watch = SceneChangeWatch(cam, sc, new_after_s=10.0, stride=1)
    sim = SimulatedCamera(cam, seed=2)
    ex = ExpectedDepth(cam, rig.robot)
    pd = ExpectedDepth(cam, None, [person]).static
    u, v = np.nonzero(pd > 0)[1], np.nonzero(pd > 0)[0]
    lo_c = person.bounds[0]
    hi_c = person.bounds[1]
    for t in range(0, 61, 2):                                  # one frame every 2 s for a minute
        q = q_at(rig.robot, q0, t * 0.37)
        d = sim.capture(cad + list(rig.robot.link_meshes(q)) + [person], stamp=float(t))
        vs = f.filter(d, q)
        centres = (vs.keys + 0.5) * vs.voxel_size
        on_person = np.all((centres >= lo_c - 0.05) & (centres <= hi_c + 0.05), axis=1)
        assert on_person.sum() >= 20, t                        # still an obstacle at every frame
        ch = watch.update(d, ex.robot(q), float(t))
        if t < 10:
            assert ch == []                                    # not yet a change: could be someone passing
    assert ch and all(c["kind"] == "new" for c in ch)
    # the regions said contain the person's pixels
    boxes = [c["box"] for c in ch]
    inside = [any(b[0] <= uu <= b[2] and b[1] <= vv <= b[3] for b in boxes) for uu, vv in zip(u, v)]
    assert np.mean(inside) > 0.5
    assert all(c["since"] == 0.0 for c in ch)
    np.testing.assert_array_equal(sc.depth, before)           # never learned


def test_something_gone_is_said(setup):
    """A fixture of the CAD taken away after learning: the watch says the learned scene is gone there."""
    rig, cad, q0, learned = setup
    cam = rig.cameras[0]
    sc, _ = learned[cam.id]
    # the object whose removal uncovers the most of a farther surface (the floor behind a table)
    full = ExpectedDepth(cam, None, cad).static
    gains = [np.count_nonzero(ExpectedDepth(cam, None, cad[:i] + cad[i + 1:]).static > full + 0.1)
             for i in range(len(cad))]
    i = int(np.argmax(gains))
    assert gains[i] > 100
    rest = cad[:i] + cad[i + 1:]
    watch = SceneChangeWatch(cam, sc, gone_after_s=1.0, stride=1)
    sim = SimulatedCamera(cam, seed=4)
    ch = []
    for k in range(4):
        ch = watch.update(sim.capture(rest, stamp=0.5 * k), None, 0.5 * k)
    assert any(c["kind"] == "gone" for c in ch)
    assert all(c["kind"] == "gone" for c in ch)


def test_calibration_check_with_the_learned_scene_as_with_cad(setup):
    """The calibration check's verdict with the learned scene in place of the CAD: good at the rig's
    pose, not good for a camera turned by 2 degrees (the truth: the turn the test applies), as the
    CAD's residual check says."""
    from depthguard.calibration.calibrate import calibrate_camera, fuse_frames
    from depthguard.calibration.residuals import residual_stats
    from depthguard.calibration.scene import StaticScene
    from test_calibration_drift import turned

    rig, cad, q0, learned = setup
    scene = StaticScene(cad)
    for cam in rig.cameras:
        sc, _ = learned[cam.id]
        for true_cam, good in ((cam, True), (turned(cam, "pan", 2.0), False)):
            frames = [SimulatedCamera(true_cam, seed=20 + k).capture(cad + list(rig.robot.link_meshes(q0)), stamp=k)
                      for k in range(3)]
            rd = ExpectedDepth(cam, rig.robot).robot(q0)
            # the CAD's residual check (its fit needs more pixels than these small images give)
            with_cad = residual_stats(cam, fuse_frames(frames), scene.view(cam).depth, rd)
            with_learned = calibrate_camera(cam, frames, None, rig.robot, [q0], refine=False,
                                            learned=sc.depth).before
            assert (with_cad.verdict == "good") is good, (cam.id, with_cad)
            assert (with_learned.verdict == "good") is good, (cam.id, with_learned)


def test_in_the_monitor_a_person_standing_still_for_a_minute_stays_an_obstacle(setup):
    """The monitor with the learned scene in place of the CAD and SSM measuring from what is not the
    known scene (``ssm.known_scene: muted``, where the known scene changes the answer): a person
    standing still beside the robot for 60 s after learning is in SSM's separation at every cycle
    (within 8 cm of the truth: the box's geometry, docs/SSM.md), and the monitor says from
    ``monitor.scene_change_new_s`` (here 5 s) on that something new has stayed there, in the
    ``scene_change_regions`` tiles (``Monitor.scene_changes``); the scene never learns them."""
    from depthguard.control.ssm import TERMS
    from depthguard.control.ssm_config import SSMConfig
    from depthguard.runtime.monitor import Monitor, warm_up
    from depthguard.sources.frame import Frame

    rig, cad, q0, learned = setup
    scenes = {cid: sc for cid, (sc, _) in learned.items()}
    before = {cid: sc.depth.copy() for cid, sc in scenes.items()}
    lrig = dataclasses.replace(rig.without_cad(), learned=scenes)
    cfg = lrig.monitor.with_changes(invalid="free", control_hz=2.0, camera_hz=2.0, reaction="ssm",
                                    ssm=SSMConfig(range=0.8, known_scene="muted"),
                                    scene_change_new_s=5.0, scene_change_regions=(2, 3))   # the watch's settings
    data = rig.robot.create_data()
    rig.robot.forward(q0, data)
    P = np.asarray(data.cp_positions)
    ee = P[-1]
    lo, hi = np.array([ee[0] + 0.35, ee[1] - 0.2, -0.85]), np.array([ee[0] + 0.65, ee[1] + 0.2, 1.0])
    true = np.linalg.norm(np.maximum(np.maximum(lo - P, P - hi), 0.0), axis=1)
    assert true.min() < 0.6
    person = Box.from_bounds(lo, hi, name="person").mesh()
    meshes = cad + list(rig.robot.link_meshes(q0)) + [person]
    sims = {c.id: SimulatedCamera(c, seed=9) for c in rig.cameras}
    warm_up(lrig, cfg)                                         # compiled before the monitor's clock matters
    mon = Monitor(lrig, cfg)
    said = []
    try:
        for k in range(121):                                   # a frame per camera every 0.5 s for 60 s
            t = 0.5 * k
            mon.push_joints(t, q0)
            for c in rig.cameras:
                mon.push_frame(Frame(c.id, sims[c.id].capture(meshes, stamp=t), t))
            mon.flush(timeout=60.0)
            r = mon.step(t)
            d = r.ssm[:, TERMS.index("D")]
            assert np.min(d) <= true.min() + 0.08, (t, d, true)     # the person is in SSM's separation
            ch = mon.scene_changes()
            if t < 5.0:                                        # scene_change_new_s
                assert ch == [], t
            else:
                assert ch and all(c["region"] in {f"r{i}c{j}" for i in range(2) for j in range(3)} for c in ch), t
            said.append(ch)
    finally:
        mon.close()
    assert said[-1] and {c["kind"] for c in said[-1]} == {"new"} and {c["camera"] for c in said[-1]} == set(scenes)
    for cid, sc in scenes.items():
        np.testing.assert_array_equal(sc.depth, before[cid])          # never learned


def test_the_scene_around_the_robots_base_and_near_the_range_end_is_learned(setup):
    """No margin around the base (no joint moves it): the CAD's pixels within 2 px outside its
    outline are learned, where a margin would have hidden them in every frame and the filter,
    with no robot rendered there, would keep the table there as an unknown object. Returns a
    little beyond the rated range are learned: the CAD's surfaces just past it are known."""
    from scipy.ndimage import binary_dilation

    from depthguard.filtering.scene_learner import base_silhouette

    rig, cad, q0, learned = setup
    for cam in rig.cameras:
        sc, hidden = learned[cam.id]
        static = ExpectedDepth(cam, None, cad).static
        base = base_silhouette(cam, rig.robot)
        # the ring outside the base's outline, where the moving links were 3+ px away in 3+ of the frames
        ex = ExpectedDepth(cam, rig.robot)
        clear = np.zeros(cam.shape, int)
        for k in range(40):
            moving = (ex.robot(q_at(rig.robot, q0, k * 0.1)) > 0) & ~base
            clear += ~binary_dilation(moving, iterations=3)
        ring = binary_dilation(base, iterations=2) & ~base & (static > 0) & (clear >= 3)
        assert ring.sum() > 20
        assert sc.known[ring].mean() >= 0.9, sc.known[ring].mean()
        past = (static > cam.max_range) & (static < 1.3 * cam.max_range) & ~hidden
        assert past.sum() > 20
        assert sc.known[past].mean() >= 0.9, sc.known[past].mean()
        at_cad = np.abs(sc.depth - static) <= sc.band()
        assert at_cad[past & sc.known].mean() >= 0.99, "learned past the range: the CAD's depth"
