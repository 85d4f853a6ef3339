"""Simulated cameras and the simulated source: rendering + noise, determinism, frames."""

import math

import numpy as np
import pytest

from depthguard.sources.sim_source import sim_world

from depthguard.camera import Camera
from depthguard.geometry.primitives import Box, Sphere
from depthguard.render import render_depth
from depthguard.sensors import SENSOR_MODELS, intrinsics_for
from depthguard.sim import Scene, load_cell
from depthguard.sources import Frame, SimSource, SimulatedCamera
from depthguard.transforms import look_at, pose


def small_cam(sensor="realsense_d435", w=424, h=240):
    return Camera("c", world_from_camera=look_at([2.0, 0.0, 1.0], [0, 0, 0.5]), sensor=sensor,
                  **intrinsics_for(sensor, w, h))


def scene_meshes():
    return [Box(size=(0.6, 0.6, 1.0), world_from_local=pose(t=[0, 0, 0.5])).mesh(),
            Sphere(radius=0.2, world_from_local=pose(t=[0.5, 0.5, 1.0])).mesh(),
            Box(size=(30, 30, 0.02), world_from_local=pose(t=[0, 0, -0.01])).mesh()]


def test_noiseless_capture_is_the_rendered_depth_within_range():
    cam = small_cam()
    ideal = render_depth(cam, scene_meshes())
    got = SimulatedCamera(cam, noiseless=True).capture(scene_meshes())
    hr = SENSOR_MODELS[cam.sensor].returns_to(cam.max_range)      # the D435 returns to 10 m
    inside = (ideal >= cam.min_range) & (ideal <= hr)
    assert inside.sum() > 1000 and (ideal > hr).any()  # the floor runs out of range
    assert ((ideal > cam.max_range) & (ideal <= hr)).any()   # and beyond the rated range first
    np.testing.assert_array_equal(got[inside], ideal[inside])
    assert (got[~inside] == 0).all() and got.dtype == np.float32


def test_noisy_capture_is_near_the_rendered_depth_and_deterministic():
    cam = small_cam()
    meshes = scene_meshes()
    ideal = render_depth(cam, meshes)
    a = SimulatedCamera(cam, seed=3).capture(meshes, stamp=1.5)
    b = SimulatedCamera(cam, seed=3).capture(meshes, stamp=1.5)
    c = SimulatedCamera(cam, seed=3).capture(meshes, stamp=1.6)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    both = (a > 0) & (ideal > 0)
    err = (a - ideal)[both]
    z = ideal[both]
    m = SimulatedCamera(cam).model
    sigma = m.sigma_a + m.sigma_z2 * z ** 2
    assert np.mean(np.abs(err) < 5 * sigma) > 0.99
    # the camera's own stream (no stamp) advances: two captures differ, and replay with the seed
    s1 = SimulatedCamera(cam, seed=4)
    x1, x2 = s1.capture(meshes), s1.capture(meshes)
    s2 = SimulatedCamera(cam, seed=4)
    assert not np.array_equal(x1, x2)
    np.testing.assert_array_equal(s2.capture(meshes), x1)


def test_model_comes_from_the_camera_and_bad_models_are_rejected():
    assert SimulatedCamera(small_cam("tof", 320, 240)).model.name == "tof"
    cam = Camera("x", 64, 48, 50.0, 50.0, 31.5, 23.5)
    assert SimulatedCamera(cam).model.name == "ideal"
    with pytest.raises(ValueError, match="unknown sensor model"):
        SimulatedCamera(cam, model="kinect_v9")


def test_sim_source_frames_of_a_cell():
    cell = load_cell("flacco-walls")
    src = SimSource(cell, seed=1)
    frames = src.frames(0.0, labels=True)
    assert set(frames) == {"cam0"}
    f = frames["cam0"]
    assert isinstance(f, Frame) and f.camera_id == "cam0" and f.stamp == 0.0
    assert f.depth.shape == (480, 640) and f.depth.dtype == np.float32
    names = cell.scene.meshes_at(0.0)[1]
    assert {names[i] for i in np.unique(f.labels) if i >= 0} == {"table", "wall"}
    # the frame is a pure function of (seed, camera, t)
    np.testing.assert_array_equal(SimSource(cell, seed=1).frames(0.0)["cam0"].depth, f.depth)
    # noiseless frames equal the rendered depth
    ideal = render_depth(cell.rig.camera("cam0"), cell.scene.meshes_at(0.0)[0])
    nf = SimSource(cell, noiseless=True).frames(0.0)["cam0"].depth
    np.testing.assert_array_equal(nf[ideal > 0.4], ideal[ideal > 0.4])


def test_sim_source_needs_a_scene():
    with pytest.raises(ValueError, match="rig= and scene="):
        SimSource(rig=load_cell("flacco-walls").rig)
    cell = load_cell("flacco-walls")
    src = SimSource(rig=cell.rig, scene=Scene([]), noiseless=True)
    assert (src.frames(0.0)["cam0"].depth == 0).all()  # nothing to see


@pytest.mark.slow  # loads two cells and renders
def test_bench_group_quick_rows():
    from depthguard.evaluation.bench import BenchContext
    from depthguard.evaluation.bench.sim import sim_group

    rows = {r.name: r for r in sim_group(BenchContext(quick=True, repeats=3))}
    assert set(rows) == {"sim.noise.kinect_640x480_ms", "sim.ur3_cell.frames_4x640x480_ms", "sim.ur3_cell.frame_cpu_ms",
                         "sim.ur3_cell.person_cpu_ms", "sim.ur3_cell.sim_frame_cpu_ms",
                         "sim.c_arm_room.occupancy_10cm_ms"}
    for r in rows.values():
        assert r.value > 0 and r.peer and r.peer_value > 0 and r.unit == "ms"


@pytest.mark.parametrize("name", sorted(SENSOR_MODELS))
def test_presets_have_square_pixels_and_their_nominal_field_of_view(name):
    """Real depth sensors have square pixels: fx == fy in every mode, and in the native
    mode (the one closest to the data sheet) both fields of view lie within 4 degrees."""
    m = SENSOR_MODELS[name]
    for w, h in m.resolutions:
        k = intrinsics_for(name, w, h)
        assert k["fx"] == k["fy"] > 0
        assert (k["cx"], k["cy"]) == ((w - 1) / 2, (h - 1) / 2)
    errors = []
    for w, h in m.resolutions:
        k = intrinsics_for(name, w, h)
        hfov = 2 * math.degrees(math.atan(w / 2 / k["fx"]))
        vfov = 2 * math.degrees(math.atan(h / 2 / k["fy"]))
        errors.append(max(abs(hfov - m.hfov_deg), abs(vfov - m.vfov_deg)))
    assert min(errors) <= 4.0, errors


def test_a_simulator_behind_real_time_skips_frames_and_counts_them():
    """``sim:`` in a real-time run (``skip_behind``): a camera more than a period behind the
    run's clock renders only the newest frame due and counts the others
    (``counters()["skipped_behind_real_time"]``, in the monitor's summary); without it every
    frame due is rendered, in order."""
    from depthguard.sources.base import open_joints, open_source

    rendered = {}
    for behind in (False, True):
        ctx = {}
        rig = load_cell("flacco-cell").rig
        src = open_source("sim:flacco-cell:alone:noiseless", rig, ctx)
        joints = open_joints("sim", rig, ctx)
        src.skip_behind = behind
        joints.states_until(0.0)
        first = src.frames_until(0.0)
        joints.states_until(0.25)
        late = src.frames_until(0.25)                 # 0.25 s late: 7 or 8 periods per camera
        period = 1.0 / sim_world(ctx).camera_hz
        assert [f.stamp for f in first] == [0.0, 0.0]
        per_camera = {c: [f.stamp for f in late if f.camera_id == c] for c in src.camera_ids}
        if behind:
            assert all(len(s) == 1 for s in per_camera.values()), per_camera       # the newest due only
            assert all(s[0] == rendered[c][-1] for c, s in per_camera.items())
            assert all(0.25 - period < s[0] <= 0.25 for s in per_camera.values())
            # every frame due but the newest was skipped, and counted
            assert src.counters()["skipped_behind_real_time"] == sum(len(s) - 1 for s in rendered.values())
            # what depthguard monitor's live line and last line say (sources without the count add 0)
            from depthguard.cli.monitor import _skipped_behind
            assert _skipped_behind([src, joints]) == src.counters()["skipped_behind_real_time"] > 0
        else:
            assert all(len(s) >= 7 and s == sorted(s) for s in per_camera.values()), per_camera
            assert src.counters()["skipped_behind_real_time"] == 0
            rendered = per_camera


def test_sim_joint_states_come_once_each_in_order_whoever_moves_the_robot():
    """``sim`` joints: every tick ``k / joint_hz`` up to the asked time, once, in order, whether
    the joint source or the frame source moved the robot there first, and over more than the
    world's 5 s of kept history (the source looks back only to the last state it returned)."""
    from depthguard.sources.base import open_joints, open_source

    ctx = {}
    rig = load_cell("ur3-cell").rig
    frames = open_source("sim:ur3-cell:alone:noiseless", rig, ctx)
    joints = open_joints("sim", rig, ctx)
    world = sim_world(ctx)
    hz = world.joint_hz
    rng = np.random.default_rng(3)
    got, t = [], 0.0
    while t < 7.0:
        t += float(rng.uniform(0.0, 0.05))
        if rng.random() < 0.3:
            world.advance(t + float(rng.uniform(0.0, 0.01)))   # as the frame source does before rendering
        got += joints.states_until(t)
    stamps = np.array([s for s, _ in got])
    assert np.allclose(stamps, np.arange(len(stamps)) / hz, atol=1e-9)
    assert stamps[-1] <= t + 1e-9 and stamps[-1] > t - 1.0 / hz - 1e-9
    assert all(q.shape == (rig.robot.dof,) and np.all(np.isfinite(q)) for _, q in got)
    frames.close()


def test_sim_joints_tell_ssm_the_paths_speed_while_the_robot_is_slowed():
    """``commanded_qd`` of the ``sim`` joints (R33): the cell's path's joint velocity at the robot's
    path time — a central difference of ``scene.robot_q`` by hand — while the robot, slowed to
    0.3 by the reaction, moves at 0.3 of it; the monitor takes it once attached."""
    from types import SimpleNamespace

    from depthguard.sources.base import open_joints, open_source

    ctx = {}
    rig = load_cell("ur3-cell").rig
    frames = open_source("sim:ur3-cell:alone:noiseless", rig, ctx)       # the cell's world, its path
    frames.close()
    joints = open_joints("sim", rig, ctx)
    world = sim_world(ctx)
    dof, big = rig.robot.dof, np.full(rig.robot.dof, 1e3)
    joints.start_clock(0.0)
    world.on_reaction(SimpleNamespace(override=0.3, speed_scale=0.3, qd_min=-big, qd_max=big))
    states = joints.states_until(4.0)
    tau, h = world.robot_sim.tau, 1e-4
    truth = (world.scene.robot_q(tau + h) - world.scene.robot_q(tau - h)) / (2 * h)
    assert np.abs(truth).max() > 0.05 and world.robot_sim.rate == pytest.approx(0.3)
    np.testing.assert_allclose(world.commanded_qd(), truth, atol=0.01 * np.abs(truth).max())
    (t0, q0), (t1, q1) = states[-2], states[-1]
    np.testing.assert_allclose((q1 - q0) / (t1 - t0), 0.3 * truth, atol=0.01 * np.abs(truth).max())
    monitor = SimpleNamespace(commanded_qd=None)
    joints.attach(monitor)
    assert monitor.commanded_qd(None) is world.qd_nominal and world.qd_nominal.shape == (dof,)


def test_a_warmed_up_simulator_delivers_the_same_frames():
    """``SimFrames.warm_up`` (a real-time run calls it before its clock starts) renders and drops
    a frame per camera; each frame's noise is drawn from its own stamp's generator, so every
    frame after it is the same, bit for bit, as without it."""
    from depthguard.sources.sim_source import SimFrames, SimWorld

    runs = []
    for warm in (False, True):
        frames = SimFrames(SimWorld("flacco-cell", seed=5))
        if warm:
            frames.warm_up()
        runs.append([(f.camera_id, f.stamp, f.depth) for k in range(1, 11) for f in frames.frames_until(k * 0.03)])
    assert len(runs[0]) == len(runs[1]) >= 18
    for (c0, s0, d0), (c1, s1, d1) in zip(*runs):
        assert (c0, s0) == (c1, s1) and np.array_equal(d0, d1)


def test_frame_rng_is_default_rng_of_its_seed_sequence():
    """``frame_rng`` draws what ``np.random.default_rng(SeedSequence((seed, crc32(camera),
    stamp in µs)))`` draws (its documented seeding)."""
    import zlib

    from depthguard.sources.simulated import frame_rng

    for seed, cam, stamp in [(0, "camA", 0.0), (7, "cam0", 12.345678), (2 ** 40 + 3, "x", 1e6 + 0.5)]:
        key = [seed & 0xFFFFFFFF, zlib.crc32(cam.encode()), int(round(stamp * 1e6)) & 0xFFFFFFFFFFFF]
        want = np.random.default_rng(np.random.SeedSequence(key))
        got = frame_rng(seed, cam, stamp)
        assert got.integers(0, 1 << 40, 8).tolist() == want.integers(0, 1 << 40, 8).tolist()
        assert got.random(5).tobytes() == want.random(5).tobytes()


def test_the_world_path_is_the_scene_path_bit_for_bit():
    """issue 29: SimWorld keeps its path's last answers; every value is the scene's own
    ``robot_q``, bit for bit, for every cell's path, at its
    keys, between them, before and after them, and asked again (copies: a caller may keep one)."""
    from depthguard.sources.sim_source import SimWorld

    for cell in ("ur3-cell", "flacco-cell"):
        world = SimWorld(cell, alone=True, noiseless=True)
        ts = world.scene.robot_path._t
        rng = np.random.default_rng(5)
        taus = np.concatenate([ts, ts + 1e-9, ts - 1e-9, rng.uniform(-1.0, float(ts[-1]) * 2.5, 400), [0.0, -3.0]])
        for tau in [float(x) for x in taus] * 2:
            ref_tau = tau % world._path_end if world._path_end > 0 else tau
            a, b = world._path_q(tau), world.scene.robot_q(ref_tau)
            assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), (cell, tau)
            a[:] = 99.0                                # the memo hands out copies
            assert world._path_q(tau).tobytes() == b.tobytes()


def test_the_robot_obeys_the_newest_reaction_before_its_next_tick_without_the_lock():
    """issue 29: on_reaction (the control thread) never takes the world's lock; the robot ticks with
    the newest reaction given before the tick, as an ObeyingRobot that obeys at once (the truth)."""
    from types import SimpleNamespace

    from depthguard.sim.obeying_robot import ObeyingRobot, PathFollower
    from depthguard.sources.sim_source import SimWorld

    world = SimWorld("ur3-cell", alone=True, noiseless=True)
    dof = world.robot.dof
    truth = ObeyingRobot(PathFollower(world.scene.robot_q if world._path_end <= 0 else
                                      (lambda tau: world.scene.robot_q(tau % world._path_end))), dof, tau=world.start)
    rng = np.random.default_rng(11)
    t = 0.0
    world.advance(t)
    for k in range(300):
        for _ in range(int(rng.integers(0, 3))):       # none, one or two reactions between ticks
            k_ = float(rng.choice([0.0, 0.3, 1.0]))
            r = SimpleNamespace(override=k_, speed_scale=k_, qd_min=-rng.random(dof) * 2, qd_max=rng.random(dof) * 2)
            with world._lock:                           # held by a renderer: the hand-off does not wait
                world.on_reaction(r)
            truth.obey(r)
        t += 1.0 / world.joint_hz
        new = world.advance(t)
        assert len(new) == 1
        q = truth.step(1.0 / world.joint_hz)
        assert new[0][1].tobytes() == q.tobytes(), k


def test_frames_each_renders_one_frame_at_a_time_in_capture_order():
    """issue 29: the real-time pump takes the simulator's frames one by one (``frames_each``): the
    same frames as ``frames_until`` in capture order, each rendered only when asked for."""
    from depthguard.sources.sim_source import SimFrames, SimWorld

    a, b = SimFrames(SimWorld("ur3-cell", seed=2)), SimFrames(SimWorld("ur3-cell", seed=2))
    renders = []
    render = b.render
    b.render = lambda cid, tc, q: (renders.append(cid), render(cid, tc, q))[1]
    t = 0.2                                        # every camera has several captures due
    want = a.frames_until(t)
    it = b.frames_each(t)
    first = next(it)
    assert len(renders) == 1                       # the first frame is out before the others are made
    got = [first, *it]
    assert len(want) >= 8 and [f.stamp for f in want] == sorted(f.stamp for f in want)
    assert [(f.camera_id, f.stamp) for f in got] == [(f.camera_id, f.stamp) for f in want]
    assert all(np.array_equal(x.depth, y.depth) for x, y in zip(got, want))
