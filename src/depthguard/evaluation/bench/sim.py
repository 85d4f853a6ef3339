"""Bench group ``sim``: simulated frames and ground truth (issue 2 §6–7).

Rows (median milliseconds after a warm-up; the noise kernels run on the
default numba threads, the renders on one):

- ``sim.noise.kinect_640x480_ms``: the Kinect v1 model (disparity noise and
  quantisation, edge dropout, range) on one 640x480 image of random depths
  (every pixel an edge: the worst case). Peer: drawing the float32 standard
  normals of that image with numpy (the floor of any noise model).
- ``sim.ur3_cell.frames_4x640x480_ms``: ``SimSource.frames(t)`` of the
  ur3-cell — the scene's meshes at t, four D435 renders and their noise.
  Peer: the four renders alone (``Renderer.render``) on the same meshes.
- ``sim.ur3_cell.frame_cpu_ms``: CPU (``time.thread_time``, one numba thread) of one 640x480
  D435 frame of the ur3-cell besides its two renders — the static scene and the moving layers
  (robot, person) combined, the noise with a real-time run's normal bank, the invalid pixels as
  the ``sim:`` source has them (:class:`~depthguard.sources.layered.LayeredCamera`, with the
  layers' windows from their meshes as ``CameraSim`` gives them), median
  over frames of 2 s of the scene, each call right after its layers' renders. Peer: the former way on the same layers and generators
  (:func:`~depthguard.sources.layered.reference_frame`: copy, ``nearest_depth`` twice,
  ``apply_noise``, the policy on whole images), alternated; the frames must be bit-identical.
- ``sim.ur3_cell.person_cpu_ms``: CPU (``time.thread_time``, one numba thread) of the moving
  layer of one 640x480 D435 frame of the ur3-cell with the person reaching, each camera in turn:
  the people and props posed in place (:class:`~depthguard.sim.posed.PosedMeshes`), rendered
  where they lie (``Renderer.render_arrays``), the layer's spans as drawn. Peer: the former way
  on the same poses, alternated — ``Primitive.mesh()`` per part, ``Renderer.render`` of the
  list, the layer's window from its meshes and its spans scanned (``layer_window``,
  ``layer_spans``); the images and spans must be bit-identical. (Both posings use today's
  ``Person``, whose pose memo is part of the change: the peer understates the gain.)
- ``sim.ur3_cell.sim_frame_cpu_ms``: CPU (``time.thread_time``, one numba thread) per frame of the
  ``sim:ur3-cell`` source as a real-time run drives it (noise bank; ``frames_until`` every 5 ms
  of run time from 2 s, the robot's joint ticks included): per frame the people and props
  posed, the robot posed, its two layers rendered, composed with the static scene, noised and
  measured, the Python glue included — what the source's thread pays per frame (issue 29: goal
  <= 2.5 ms). Peer: the two layers' renders alone on the same frames (the same cameras, times
  and joints), the floor of this design.
- ``sim.c_arm_room.occupancy_5cm_ms``: ground-truth occupancy (R24) of the
  4 x 4 x 2.5 m room at 5 cm (80 x 80 x 50 voxels, centre rule), robot included
  (quick mode: 10 cm, ``occupancy_10cm_ms``).
  Peer: the same grid by brute force, every primitive's SDF on every voxel centre.

No paper quotes a figure for these steps.
"""

from __future__ import annotations

import numpy as np

from depthguard.evaluation.bench import BenchContext, BenchRow, group, time_call


@group("sim")
def sim_group(ctx: BenchContext) -> list[BenchRow]:
    from depthguard.render import Renderer
    from depthguard.sensors import sensor_model
    from depthguard.sim import load_cell
    from depthguard.sim.ground_truth import grid_shape, voxel_centres
    from depthguard.sources import SimSource
    from depthguard.sources.noise import NoiseWorkspace, apply_noise

    rows: list[BenchRow] = []
    reps = max(3, ctx.repeats if not ctx.quick else 3)

    # noise model alone
    m = sensor_model("kinect_v1")
    ideal = np.random.default_rng(ctx.seed).uniform(0.5, 4.5, (480, 640)).astype(np.float32)
    ideal[:, 300:340] = 1.0  # some depth edges
    ws, out = NoiseWorkspace(ideal.shape), np.empty(ideal.shape, np.float32)
    rng = np.random.default_rng(ctx.seed)
    t = time_call(lambda: apply_noise(ideal, m, 589.4, rng, ws=ws, out=out), reps)
    buf = np.empty(ideal.shape, np.float32)
    tp = time_call(lambda: rng.standard_normal(out=buf, dtype=np.float32), reps)
    rows.append(BenchRow("sim.noise.kinect_640x480_ms", float(np.median(t) * 1e3), "ms", None,
                         "numpy float32 normals 640x480", float(np.median(tp) * 1e3),
                         "disparity noise + 1/8 px quantisation + edge dropout + range"))

    # a whole simulated frame set of the ur3 cell
    cell = load_cell("ur3-cell")
    src = SimSource(cell, seed=ctx.seed)
    tt = cell.situations["arm_reaching"].time
    t = time_call(lambda: src.frames(tt), reps)
    meshes, _ = cell.scene.meshes_at(tt)
    rends = [Renderer(c) for c in cell.rig.cameras]
    tp = time_call(lambda: [r.render(meshes) for r in rends], reps)
    rows.append(BenchRow("sim.ur3_cell.frames_4x640x480_ms", float(np.median(t) * 1e3), "ms", None,
                         "4 renders alone", float(np.median(tp) * 1e3),
                         "scene meshes at t + render + D435 noise, 4 cameras"))

    rows.append(_frame_cpu_row(cell, 20 if ctx.quick else 60))
    rows.append(_person_cpu_row(cell, 10 if ctx.quick else 30))
    rows.append(_sim_frame_row(60 if ctx.quick else 240))

    # ground-truth occupancy of the c-arm room (quick mode: 10 cm voxels)
    room = load_cell("c-arm-room")
    vs = 0.1 if ctx.quick else 0.05
    lo, hi = room.rig.workspace.lo, room.rig.workspace.hi
    ts = room.situations["setup1"].time
    t = time_call(lambda: room.scene.occupancy(lo, hi, vs, ts, robot=True), max(2, reps // 3), warmup=1)
    prims = room.scene.obstacles_at(ts) + room.scene.robot_primitives(ts)

    def brute():
        lo_, _, n = grid_shape(lo, hi, vs)
        c = voxel_centres(lo_, vs, (0, 0, 0), n)
        d = np.full(len(c), np.inf)
        for p in prims:
            np.minimum(d, p.sdf(c), out=d)
        return (d <= 0).reshape(n)

    if not np.array_equal(brute(), room.scene.occupancy(lo, hi, vs, ts, robot=True)):
        raise AssertionError("sim bench: occupancy differs from the brute-force peer")
    tp = time_call(brute, 1 if ctx.quick else 3, warmup=0)
    n = grid_shape(lo, hi, vs)[2]
    rows.append(BenchRow(f"sim.c_arm_room.occupancy_{round(vs * 100)}cm_ms", float(np.median(t) * 1e3), "ms", None,
                         "every SDF on every voxel", float(np.median(tp) * 1e3),
                         f"{len(prims)} primitives, {n[0]}x{n[1]}x{n[2]} voxels, centre rule"))
    return rows


def _frame_cpu_row(cell, n: int) -> BenchRow:
    """``sim.ur3_cell.frame_cpu_ms`` (module docstring) over ``n`` frames of camera 0."""
    import time

    import numba

    from depthguard.filtering.expected import ExpectedDepth
    from depthguard.geometry.decimate import SIM_CELL
    from depthguard.render import Renderer
    from depthguard.sensors import sensor_model
    from depthguard.sources.layered import LayeredCamera, layer_window, reference_frame
    from depthguard.sources.noise import NormalBank
    from depthguard.sources.simulated import frame_rng

    cam = cell.rig.cameras[0]
    model = sensor_model(cam.sensor or "ideal")
    ex = ExpectedDepth(cam, cell.scene.robot, cell.scene.static_meshes, robot_cell=SIM_CELL)
    people = Renderer(cam)
    hi = model.returns_to(cam.max_range)
    layered = LayeredCamera(ex.static, model, cam.fx, cam.min_range, hi, cam.max_range, invalid="unknown")
    bank = NormalBank(0)
    scene = cell.scene
    pose = (np.ascontiguousarray(cam.R, dtype=np.float64), np.ascontiguousarray(cam.t, dtype=np.float64))
    win = np.empty(4, np.int64)

    robots = Renderer(cam)

    def layers(t):          # rendered just before the call, as in a shot (not timed)
        moving, _ = scene.moving_meshes_at(t)
        links = scene.robot.render_link_meshes(scene.robot_q(t), SIM_CELL)
        return robots.render(links)[0], (people.render(moving)[0] if moving else None), links, moving

    new, old = [], []
    previous = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        for rep in range(3):
            for k in range(n):
                t = 2.0 + 2.0 * k / n
                robot, person, links, moving = layers(t)
                c0 = time.thread_time()
                a = layered.frame(robot, person, frame_rng(0, cam.id, t), bank=bank,
                                  robot_window=layer_window(links, cam, robots.near, pose, win),
                                  person_window=layer_window(moving, cam, people.near, pose, win) if moving else None)
                c1 = time.thread_time()
                robot, person, _, _ = layers(t)
                c2 = time.thread_time()
                b = reference_frame(ex.static, robot, person, model, cam.fx, cam.min_range, hi, cam.max_range,
                                    frame_rng(0, cam.id, t), bank=bank)
                c3 = time.thread_time()
                if a.tobytes() != b.tobytes():
                    raise AssertionError(f"sim bench: the layered frame at t = {t} differs from the former way")
                if rep:
                    new.append(c1 - c0)
                    old.append(c3 - c2)
    finally:
        numba.set_num_threads(previous)
    return BenchRow("sim.ur3_cell.frame_cpu_ms", 1e3 * float(np.median(new)), "ms", None,
                    "the former way (copy, nearest_depth x2, apply_noise, policy)", 1e3 * float(np.median(old)),
                    f"{cam.id} 640x480 D435 besides its 2 renders: composite + noise (bank) + invalid policy, "
                    f"one numba thread, CPU, median of {len(new)}; bit-identical; goal <= 1.5 (issue 29)")


def _person_cpu_row(cell, n: int) -> BenchRow:
    """``sim.ur3_cell.person_cpu_ms`` (module docstring) over ``n`` times per camera."""
    import time

    import numba

    from depthguard.render import Renderer
    from depthguard.sim.posed import PosedMeshes
    from depthguard.sources.layered import layer_spans, layer_window

    scene = cell.scene
    t0 = cell.situations["arm_reaching"].time
    new, old = [], []
    previous = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        for cam in cell.rig.cameras:
            posed = PosedMeshes(scene)
            ra, rb = Renderer(cam), Renderer(cam)
            pose = (np.ascontiguousarray(cam.R, dtype=np.float64), np.ascontiguousarray(cam.t, dtype=np.float64))
            win = np.empty(4, np.int64)
            spans = np.zeros((cam.height, 2), np.int32)
            for rep in range(3):
                for k in range(n):
                    t = t0 + 2.0 * k / n
                    posed._last = None                   # pose again: each frame has its own time
                    c0 = time.thread_time()
                    pk = posed.at(t)
                    a = ra.render_arrays(pk.vertices, pk.faces, pk.mesh_off)[0]
                    c1 = time.thread_time()
                    pose_s, prims = _pose(scene, t)
                    c2 = time.thread_time()
                    meshes = [p.mesh() for p in prims]
                    b = rb.render(meshes)[0]
                    w = layer_window(meshes, cam, rb.near, pose, win)
                    layer_spans(b.view(np.uint32), spans, *(w or (0, cam.height, 0, cam.width)))
                    c3 = time.thread_time()
                    if a.tobytes() != b.tobytes() or ra.spans.tobytes() != spans.tobytes():
                        raise AssertionError(f"sim bench: the posed person at t = {t} differs from the former way")
                    if rep:
                        new.append(c1 - c0)
                        old.append(c3 - c2 + pose_s)
    finally:
        numba.set_num_threads(previous)
    return BenchRow("sim.ur3_cell.person_cpu_ms", 1e3 * float(np.median(new)), "ms", None,
                    "the former way (mesh() per part, render of the list, window + spans scanned)",
                    1e3 * float(np.median(old)),
                    f"the person and the box of one 640x480 D435 frame: posed in place + rendered + spans, "
                    f"one numba thread, CPU, median of {len(new)} over the 4 cameras; bit-identical")


def _pose(scene, t: float) -> tuple[float, list]:
    """``(CPU seconds, primitives)`` of posing the scene's people and props at ``t`` afresh
    (``dynamic_at``, the memos of the last time forgotten)."""
    import time

    for person in scene.people:
        person._pose_memo = None
        person._memo = None
    c0 = time.thread_time()
    prims = scene.dynamic_at(t)
    return time.thread_time() - c0, prims


def _sim_frame_row(n: int) -> BenchRow:
    """``sim.ur3_cell.sim_frame_cpu_ms`` (module docstring) over ``n`` frames of the 4 cameras."""
    import time

    import numba

    from depthguard.sources.sim_source import SimFrames, SimWorld

    world = SimWorld("ur3-cell")
    src = SimFrames(world)
    src.use_noise_bank()
    src.warm_up()
    sim = src.sim
    previous = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        t, cpu, frames = 2.0 - 0.1, 0.0, []
        src.frames_until(t)                     # the frames before 2 s, not timed
        while len(frames) < n:
            t += 0.005
            c0 = time.thread_time()
            got = src.frames_until(t)
            cpu += time.thread_time() - c0
            frames += got
        renders = []
        for f in frames:                        # the same frames' two layer renders, alone
            q = world.history.at(f.stamp)
            moving = src._posed.at(world.scene_time(f.stamp - world.origin))
            vw = sim._robot_vertices(q)
            c0 = time.thread_time()
            sim._robot[f.camera_id].render_arrays(vw, sim._robot_faces, sim._robot_off)
            if moving is not None:
                sim._moving[f.camera_id].render_arrays(moving.vertices, moving.faces, moving.mesh_off)
            renders.append(time.thread_time() - c0)
    finally:
        numba.set_num_threads(previous)
    return BenchRow("sim.ur3_cell.sim_frame_cpu_ms", 1e3 * cpu / len(frames), "ms", None,
                    "the two layers' renders alone", 1e3 * float(np.mean(renders)),
                    f"sim:ur3-cell source per 640x480 D435 frame, real-time settings (noise bank), one numba "
                    f"thread, thread CPU, mean of {len(frames)} frames (joint ticks and glue included); "
                    f"goal <= 2.5 (issue 29)")
