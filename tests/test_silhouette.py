"""Invalid pixels at the robot's silhouette (R9, R28, R32): the dilation kernel vs its numpy
twin, the per-pixel states of both distance paths vs their twins, an analytic ring of
dropout around a rendered robot sphere, a "dark person" (all pixels invalid) next to the
robot in the two-camera depth grid, and the availability of the robot alone in the
built-in cells (slow)."""

from __future__ import annotations

import numpy as np
import pytest

import depthguard as dg
from depthguard.config import PRODUCT_ROBOT_OFFSET
from depthguard.distance import depth_space_distance
from depthguard.distance import kernels as DK
from depthguard.distance.api import DistanceWorkspace
from depthguard.distance.reference import obstacle_start_depth_numpy
from depthguard.distance.silhouette import (SilhouetteBuffers, dilate_robot_depth,
                                            dilate_robot_depth_numpy)
from depthguard.fusion import depth_grid_kernels
from depthguard.fusion import depth_grid_ref as ref
from depthguard.fusion.depth_grid import DepthGridMap
from depthguard.geometry.primitives import Box, Sphere
from depthguard.render import render_depth
from depthguard.transforms import look_at

GAP_PX = 3      # the small-gap rule's choice (tests/test_gaps_beyond_range.py, distance/gaps.py)


@pytest.fixture
def rng():
    return np.random.default_rng(20240611)


def _T(x, y, z):
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T


def _cam(name="c0", eye=(0.0, 0.0, 0.0), target=(0.0, 0.0, 2.0), w=160, h=120, f=130.0):
    return dg.Camera(id=name, width=w, height=h, fx=f, fy=f, cx=(w - 1) / 2, cy=(h - 1) / 2,
                     world_from_camera=look_at(np.asarray(eye, float), np.asarray(target, float),
                                               np.array([0.0, 1.0, 0.0])),
                     min_range=0.3, max_range=8.0)


def _chebyshev_to_mask(mask: np.ndarray) -> np.ndarray:
    """(H, W) int: Chebyshev pixel distance to the nearest True of ``mask`` (brute force)."""
    vv, uu = np.nonzero(mask)
    H, W = mask.shape
    gv, gu = np.mgrid[0:H, 0:W]
    d = np.full((H, W), 10 ** 6)
    for v, u in zip(vv, uu):
        d = np.minimum(d, np.maximum(np.abs(gv - v), np.abs(gu - u)))
    return d


# ------------------------------------------------------------------ the dilation kernel
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_dilate_equals_numpy_twin_on_random_images(rng, dtype):
    for it in range(150):
        H, W = (int(x) for x in rng.integers(1, 40, 2))
        density = rng.choice([0.0, 0.01, 0.1, 0.5, 1.0])
        rd = np.where(rng.random((H, W)) < density, rng.uniform(0.3, 5.0, (H, W)), 0.0).astype(dtype)
        if it % 5 == 0:
            rd[rng.random((H, W)) < 0.1] = np.nan          # NaN is no robot
        if it % 7 == 0:
            rd[rng.random((H, W)) < 0.1] = -1.0            # neither is a negative depth
        n = int(rng.integers(0, 7))
        tmp = np.full((H + 3, W + 2), 9.0, dtype)          # buffers may be larger than the image
        out = np.full((H + 3, W + 2), 9.0, dtype)
        dilate_robot_depth(rd, n, tmp, out)
        np.testing.assert_array_equal(out[:H, :W], dilate_robot_depth_numpy(rd, n))


def test_dilate_edge_cases():
    tmp = np.zeros((6, 8))
    out = np.zeros((6, 8))
    rd = np.zeros((6, 8))
    rd[0, 0], rd[5, 7], rd[2, 3] = 1.5, 2.5, np.nan         # robot touching two corners
    dilate_robot_depth(rd, 0, tmp, out)                    # n = 0: the positive depths themselves
    np.testing.assert_array_equal(out, np.where(rd > 0, rd, 0.0))
    dilate_robot_depth(rd, 2, tmp, out)
    want = np.zeros((6, 8))
    want[:3, :3] = 1.5
    want[3:, 5:] = 2.5
    np.testing.assert_array_equal(out, want)
    np.testing.assert_array_equal(out, dilate_robot_depth_numpy(rd, 2))
    dilate_robot_depth(np.zeros((6, 8)), 3, tmp, out)      # no robot at all
    assert not out.any()
    big = np.full((6, 8), 2.0)
    big[3, 4] = 1.0
    dilate_robot_depth(big, 50, tmp, out)                  # window larger than the image
    assert np.all(out == 1.0)
    # the smallest depth of the window wins (the safe side)
    rd = np.zeros((5, 5))
    rd[2, 0], rd[2, 4] = 3.0, 2.0
    dilate_robot_depth(rd, 2, tmp[:5, :5], out[:5, :5])
    assert out[2, 2] == 2.0 and out[2, 1] == 3.0 and out[2, 3] == 2.0 and out[0, 0] == 3.0


def test_silhouette_buffers_and_errors():
    buf = SilhouetteBuffers((4, 5))
    rd32 = np.zeros((4, 5), np.float32)
    rd32[1, 1] = 1.25
    got = buf.dilate(rd32, 1)
    assert got.dtype == np.float32 and got.shape == (4, 5) and got[0, 0] == np.float32(1.25)
    with pytest.raises(ValueError, match="exceeds the buffers"):
        buf.dilate(np.zeros((5, 5)), 1)
    cam = _cam()
    ws = DistanceWorkspace(cam)
    for bad in (-1, 1.5, True, "4", None):
        with pytest.raises(ValueError, match="silhouette_px"):
            ws.set_depth(np.ones(cam.shape, np.float32), robot_depth=np.zeros(cam.shape), silhouette_px=bad)
    grid = DepthGridMap([cam], "c0", 0.5, 3.0, 0.05, cache=False)
    with pytest.raises(ValueError, match="silhouette_px"):
        grid.set_frames({"c0": np.ones(cam.shape, np.float32)}, silhouette_px=-2)


# ------------------------------------------------------------------ per-pixel states vs twins
def test_frame_state_and_start_depth_equal_twins(rng):
    cam = _cam()
    H, W = cam.shape
    depth = rng.uniform(0.1, 9.0, (H, W)).astype(np.float32)
    depth[rng.random((H, W)) < 0.2] = 0.0
    depth[rng.random((H, W)) < 0.05] = np.nan
    robot = np.zeros((H, W), np.float32)
    robot[30:70, 50:100] = rng.uniform(0.5, 6, (40, 50))
    robot[0:5, 0:8] = 1.0                                   # touching the border
    for n in (0, 1, 4):
        # in the robot render's dtype, as the product's silhouette buffers hold it (a minimum of float32
        # values: exact); frame_state then has the signature the worker compiles (R29)
        sil = dilate_robot_depth_numpy(robot, n).astype(robot.dtype) if n else None
        for inv, rf in (("unknown", False), ("unknown", True), ("free", True), ("free", False)):
            free = np.empty((H, W))
            kind = np.empty((H, W), dtype=np.int8)
            depth_grid_kernels.frame_state(depth, robot, True, cam.min_range, cam.max_range, 0.03, inv == "free", rf,
                          free, kind, sil, None)
            f2, k2 = ref.frame_state_numpy(cam, depth, robot, 0.03, inv, rf, silhouette_px=n)
            np.testing.assert_array_equal(free, f2)
            np.testing.assert_array_equal(kind, k2)
        ws = DistanceWorkspace(cam)
        for inv in ("unknown", "free"):
            for mode in ("drop", "shadow"):
                ws.set_depth(depth, robot, invalid=inv, robot_mode=mode, robot_offset=0.03, silhouette_px=n)
                want = obstacle_start_depth_numpy(depth, robot, cam.min_range, cam.max_range, inv, mode,
                                                  0.03, silhouette_px=n)
                np.testing.assert_array_equal(ws.d0, want)
    # silhouette_px = 0 is today's state exactly; valid pixels never change with n
    ws0, ws4 = DistanceWorkspace(cam), DistanceWorkspace(cam)
    ws0.set_depth(depth, robot)
    ws4.set_depth(depth, robot, silhouette_px=4)
    valid = np.isfinite(depth) & (depth >= cam.min_range) & (depth <= cam.max_range)
    np.testing.assert_array_equal(ws0.d0[valid], ws4.d0[valid])
    d0 = np.empty((H, W))
    DK.obstacle_start_depth(depth, robot, True, cam.min_range, cam.max_range, DK.INVALID_UNKNOWN,
                            DK.ROBOT_DROP, PRODUCT_ROBOT_OFFSET, d0, DK.NO_SILHOUETTE[robot.dtype], DK.NO_GAP)        # set_depth's default offset (R9)
    np.testing.assert_array_equal(ws0.d0, d0)


# ------------------------------------------------------------------ analytic ring of dropout
N_SIL = 3


@pytest.fixture
def ring_scene():
    """A robot sphere (r = 0.25 m at 2 m) in front of a wall at 3 m, one camera. Two frames:
    ``depth`` with the pixels 1..N_SIL px outside the silhouette invalid, ``depth_far`` with
    a ring N_SIL+1..N_SIL+3 px out invalid instead."""
    cam = _cam()
    sphere = Sphere(radius=0.25, world_from_local=_T(0, 0, 2.0), segments=48)
    wall = Box(size=(20, 20, 0.1), world_from_local=_T(0, 0, 3.05))
    rd = render_depth(cam, [sphere.mesh()])
    depth = render_depth(cam, [sphere.mesh(), wall.mesh()]).copy()
    cheb = _chebyshev_to_mask(rd > 0)
    near_ring = (cheb >= 1) & (cheb <= N_SIL)
    far_ring = (cheb >= N_SIL + 1) & (cheb <= N_SIL + 3)
    depth_far = depth.copy()
    depth[near_ring] = 0.0
    depth_far[far_ring] = 0.0
    return cam, sphere, rd, depth, depth_far, near_ring, far_ring


def _points_on(cam, mask, depth_m, step=7):
    vv, uu = np.nonzero(mask)
    sel = slice(None, None, step)
    ds = np.stack([uu[sel].astype(float), vv[sel].astype(float), np.full(len(uu[sel]), depth_m)], axis=1)
    return cam.depth_space_to_world(ds)


def test_ring_single_camera(ring_scene):
    cam, sphere, rd, depth, depth_far, near_ring, far_ring = ring_scene
    dr_max = float(rd[rd > 0].max())
    front = _points_on(cam, near_ring, 1.2)      # in front of the robot, on the ring's rays
    behind = _points_on(cam, near_ring, dr_max + 0.05)
    far_front = _points_on(cam, far_ring, 1.2)
    for mode in ("drop", "shadow"):
        kw = dict(rho=0.4, method="min", robot_depth=rd, invalid="unknown", robot_mode=mode, robot_offset=0.03)
        off = depth_space_distance(cam, depth, front, silhouette_px=0, **kw)
        on = depth_space_distance(cam, depth, front, silhouette_px=N_SIL, **kw)
        assert np.all(off.distance == 0)                    # unknown from min_range: inside the frustum
        # the ring is robot: free up to the robot (>= 0.55 m ahead); the wall is 1.8 m away
        assert np.all(on.distance > 0.4) and np.all(np.isinf(on.distance))
        # farther than N_SIL px: still unknown from min_range, with or without the rule
        far = depth_space_distance(cam, depth_far, far_front, silhouette_px=N_SIL, **kw)
        assert np.all(far.distance == 0)
        b = depth_space_distance(cam, depth, behind, silhouette_px=N_SIL, **kw)
        if mode == "shadow":
            assert np.all(b.distance == 0)                  # unknown behind the robot's depth
        else:
            assert np.all(np.isinf(b.distance))             # "drop": as a robot pixel (R9, paper §3.5)


def test_ring_depth_grid_one_camera(ring_scene):
    """In the grid (nothing can clear the principal's gray cells here) the ring is free in front
    of the smallest robot depth around it and an obstacle behind; far rays stay unknown."""
    cam, sphere, rd, depth, depth_far, near_ring, far_ring = ring_scene
    grid = DepthGridMap([cam], "c0", 0.5, 3.5, 0.02, cache=False)
    drd = dilate_robot_depth_numpy(rd, N_SIL)
    vv, uu = np.nonzero(near_ring)
    dmin_ring = float(drd[near_ring].min())
    front = _points_on(cam, near_ring, 1.2)
    kw = dict(rho=0.4, method="min", robot_depths={"c0": rd}, invalid="unknown", robot_offset=0.03)
    off = grid.distance({"c0": depth}, front, silhouette_px=0, **kw)
    on = grid.distance({"c0": depth}, front, silhouette_px=N_SIL, **kw)
    assert np.all(off.distance < 0.03)                      # in an unknown cell (discretisation)
    # free up to drd >= dmin_ring: no obstacle nearer than the robot's depth minus the point's
    assert np.all(on.distance >= min(0.4, dmin_ring - 1.2 - 0.03) - 1e-9)
    far = grid.distance({"c0": depth_far}, _points_on(cam, far_ring, 1.2), silhouette_px=N_SIL, **kw)
    assert np.all(far.distance < 0.03)
    behind = grid.distance({"c0": depth}, _points_on(cam, near_ring, float(drd[near_ring].max()) + 0.1),
                           silhouette_px=N_SIL, **kw)
    assert np.all(behind.distance < 0.03)                   # unknown behind the robot (R9)
    # changed= caching: the option is part of what forces a reload
    grid.set_frames({"c0": depth}, {"c0": rd}, silhouette_px=N_SIL)
    grid.set_frames({"c0": depth}, {"c0": rd}, silhouette_px=0, changed=[])
    np.testing.assert_array_equal(grid.query(front, rho=0.4, method="min").distance, off.distance)
    grid.set_frames({"c0": depth}, {"c0": rd}, silhouette_px=N_SIL, changed=[])
    np.testing.assert_array_equal(grid.query(front, rho=0.4, method="min").distance, on.distance)


# ------------------------------------------------------------------ a dark person next to the robot
@pytest.mark.parametrize("gap_px", [0, GAP_PX])
def test_dark_person_next_to_robot_is_an_obstacle_in_the_grid(gap_px):
    """A person whose pixels are ALL invalid (dark clothing), standing next to the robot, is
    still reported at (about) its true distance or nearer (R25, R28) with the silhouette rule
    (and the small-gap rule, returns beyond the rated range, the cell's room);
    the bound allows the grid's discretisation plus the silhouette_px ring's footprint."""
    from depthguard.sim import load_cell
    from depthguard.sim import ground_truth as gt
    from depthguard.evaluation.closed_loop.loop import _depth_span
    from depthguard.sources import SimulatedCamera

    cell = load_cell("flacco-cell")
    rig, scene = cell.rig, cell.scene
    robot = rig.robot
    cams = list(rig.cameras)
    t = 6.4
    q = scene.robot_q(t)
    P = robot.control_point_positions(q)
    ee = P[0]
    n_sil = 4
    d_min, d_max = _depth_span(cams[0], rig.workspace)
    grid = DepthGridMap(cams, cams[0].id, d_min, d_max, 0.01)
    caps = robot.collision_segments(q, 0.05)
    static = [p.mesh() for p in scene.static]
    ab, radii = robot.collision_segments(q, 0.0)
    axis_pts = (ab[:, :1, :] + np.linspace(0, 1, 21)[None, :, None] * (ab[:, 1:, :] - ab[:, :1, :]))
    tried = 0
    for offset in ((0.0, 0.0, 0.68), (0.32, 0.0, 0.0), (-0.32, 0.0, 0.0), (0.0, 0.32, 0.0), (0.0, -0.32, 0.0),
                   (0.25, 0.25, 0.0), (-0.25, 0.25, 0.0), (0.25, -0.25, 0.0), (-0.25, -0.25, 0.0)):
        # a 0.3 x 0.3 x 1 m "torso" above or beside the end effector, its face ~0.15 m away
        c = ee + np.asarray(offset)
        person = Box(size=(0.3, 0.3, 1.0), world_from_local=_T(*c))
        clearance = person.sdf(axis_pts.reshape(-1, 3)).reshape(axis_pts.shape[:2]) - radii[:, None]
        if clearance.min() < 0.08:
            continue            # inside the robot's padded volume: excluded by design (R12, R25)
        tried += 1
        depths, rds = {}, {}
        for cam in cams:
            rd = render_depth(cam, robot.link_meshes(q))
            ideal, labels = render_depth(cam, static + robot.link_meshes(q) + [person.mesh()], labels=True)
            d = SimulatedCamera(cam, seed=3).measure(ideal, stamp=t)
            person_px = labels == len(static) + len(robot.link_meshes(q))
            assert person_px.any()
            d = np.where(person_px, np.float32(0.0), d)      # dark clothing: no return at all
            depths[cam.id], rds[cam.id] = d, rd
        true = gt.true_distance([person] + list(scene.static), P)
        res = grid.distance(depths, P, rho=0.4, method="min", robot_depths=rds, robot_capsules=caps,
                            robot_offset=0.08, invalid="unknown", silhouette_px=n_sil, gap_px=gap_px)
        cam0 = cams[0]
        z = cam0.world_to_camera(P)[:, 2]
        cell_diag = np.hypot(0.01, z * np.hypot(1 / cam0.fx, 1 / cam0.fy))
        ring = n_sil * z / cam0.fx * np.sqrt(2)
        near = true < 0.4
        assert near.any()
        assert np.all(np.isfinite(res.distance[near])), (offset, res.distance, true)
        assert np.all(res.distance[near] <= true[near] + cell_diag[near] + ring[near] + 1e-6), \
            (offset, res.distance, true)
    assert tried >= 2


def test_dark_person_in_front_of_the_wall_is_an_obstacle():
    """A person in dark clothing (every pixel invalid) standing near the robot in front of the
    lab room's walls (which return beyond the Kinects' rated range): the pixels around the
    person say "free up to 4 m", the person's own pixels stay unknown from min_range, so every
    camera alone and the grid report the person at its true distance or nearer, with all the
    rules on (silhouette_px = 4, gap_px, beyond-range returns) (R25, R28)."""
    from depthguard.sim import load_cell
    from depthguard.sim import ground_truth as gt
    from depthguard.evaluation.closed_loop.loop import _depth_span
    from depthguard.sources import SimulatedCamera

    cell = load_cell("flacco-cell")
    rig, scene = cell.rig, cell.scene
    robot = rig.robot
    cams = list(rig.cameras)
    t = 0.0
    q = scene.robot_q(t)
    P = robot.control_point_positions(q)
    d_min, d_max = _depth_span(cams[0], rig.workspace)
    grid = DepthGridMap(cams, cams[0].id, d_min, d_max, 0.01)
    caps = robot.collision_segments(q, 0.05)
    static = [p.mesh() for p in scene.static]
    ab, radii = robot.collision_segments(q, 0.0)
    axis_pts = (ab[:, :1, :] + np.linspace(0, 1, 21)[None, :, None] * (ab[:, 1:, :] - ab[:, :1, :]))
    floor = -0.85
    tried = 0
    for xy in ((-0.75, 0.0), (-0.6, 0.45), (-0.55, -0.5), (0.0, 0.75), (0.2, -0.7)):
        # a 0.45 x 0.3 x 1.75 m dark person standing on the floor, seen against the far walls
        person = Box(size=(0.3, 0.45, 1.75), world_from_local=_T(xy[0], xy[1], floor + 0.875))
        clearance = person.sdf(axis_pts.reshape(-1, 3)).reshape(axis_pts.shape[:2]) - radii[:, None]
        true = gt.true_distance([person] + list(scene.static), P)
        if clearance.min() < 0.08 or not (true < 0.4).any():
            continue
        tried += 1
        depths, rds = {}, {}
        for cam in cams:
            rd = render_depth(cam, robot.link_meshes(q))
            ideal, labels = render_depth(cam, static + robot.link_meshes(q) + [person.mesh()], labels=True)
            d = SimulatedCamera(cam, seed=5).measure(ideal, stamp=t)
            person_px = labels == len(static) + len(robot.link_meshes(q))
            d = np.where(person_px, np.float32(0.0), d)
            assert (d > cam.max_range).mean() > 0.3            # the walls return beyond 4 m
            depths[cam.id], rds[cam.id] = d, rd
        near = true < 0.4
        cam0 = cams[0]
        z = cam0.world_to_camera(P)[:, 2]
        slack = np.hypot(0.01, z * np.hypot(1 / cam0.fx, 1 / cam0.fy)) + 4 * z / cam0.fx * np.sqrt(2) + 1e-6
        res = grid.distance(depths, P, rho=0.4, method="min", robot_depths=rds, robot_capsules=caps,
                            robot_offset=0.08, invalid="unknown", silhouette_px=4, gap_px=GAP_PX)
        assert np.all(res.distance[near] <= true[near] + slack[near]), (xy, res.distance, true)
        for cam in cams:
            r1 = depth_space_distance(cam, depths[cam.id], P, rho=0.4, method="min", robot_depth=rds[cam.id],
                                      invalid="unknown", robot_offset=0.08, silhouette_px=4, gap_px=GAP_PX)
            zc = cam.world_to_camera(P)[:, 2]
            ring = 4 * zc / cam.fx * np.sqrt(2) + 1e-6
            seen = near & r1.observed
            assert np.all(r1.distance[seen] <= true[seen] + ring[seen]), (cam.id, xy, r1.distance, true)
    assert tried >= 2


# ------------------------------------------------------------------ availability (R32)
def _robot_alone_errors(name: str, n_poses: int, silhouette_px: int, gap_px: int = 0):
    """Per cell: (single camera, grid) arrays of sensed - true distance (m) of every control
    point over the poses, the robot alone with noise and the product's defaults (inf = nothing
    within rho)."""
    from depthguard.sim import load_cell
    from depthguard.sim import ground_truth as gt
    from depthguard.evaluation.closed_loop.loop import _depth_span
    from depthguard.sources import SimulatedCamera

    cell = load_cell(name)
    rig, scene = cell.rig, cell.scene
    robot = rig.robot
    cams = list(rig.cameras)
    d_min, d_max = _depth_span(cams[0], rig.workspace)
    grid = DepthGridMap(cams, cams[0].id, d_min, d_max, 0.01)
    static = [p.mesh() for p in scene.static]
    statics = {c.id: render_depth(c, static) for c in cams}
    single, fused = [], []
    for t in np.linspace(0.0, scene.duration, n_poses, endpoint=False):
        q = scene.robot_q(t)
        P = robot.control_point_positions(q)
        true = gt.true_distance(list(scene.static), P)
        depths, rds = {}, {}
        for cam in cams:
            rd = render_depth(cam, robot.link_meshes(q))
            st = statics[cam.id]
            ideal = np.where((rd > 0) & ((st == 0) | (rd < st)), rd, st).astype(np.float32)
            depths[cam.id] = SimulatedCamera(cam, seed=0).measure(ideal, stamp=t)
            rds[cam.id] = rd
        r1 = depth_space_distance(cams[0], depths[cams[0].id], P, rho=0.4, method="min",
                                  robot_depth=rds[cams[0].id], invalid="unknown", robot_offset=0.08,
                                  silhouette_px=silhouette_px, gap_px=gap_px)
        rg = grid.distance(depths, P, rho=0.4, method="min", robot_depths=rds,
                           robot_capsules=robot.collision_segments(q, 0.05), robot_offset=0.08,
                           invalid="unknown", silhouette_px=silhouette_px, gap_px=gap_px)
        single.append(r1.distance - np.minimum(true, 0.4))
        fused.append(rg.distance - np.minimum(true, 0.4))
    return np.concatenate(single), np.concatenate(fused)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["flacco-cell", "ur3-cell"])
def test_robot_alone_silhouette_rule_helps_and_stays_conservative(name):
    """R32 as far as the silhouette rule reaches: with silhouette_px = 4 no control point sees
    a false obstacle nearer than with 0 (the rule only frees space); the remaining false
    obstacles come from rays without return beside the robot (these wall-less cells) and
    the robot's shadow, which stay unknown by design (the report of this change)."""
    s0, g0 = _robot_alone_errors(name, 8, 0)
    s4, g4 = _robot_alone_errors(name, 8, 4)
    assert np.all(s4 >= s0 - 1e-9) and np.all(g4 >= g0 - 1e-9)
    assert s4.min() > s0.min()


@pytest.mark.slow
@pytest.mark.parametrize("name", ["flacco-cell", "ur3-cell"])
def test_robot_alone_single_camera_never_sees_itself_with_all_rules(name):
    """R32 for the one-camera distance: in the cells' rooms, with returns beyond the rated
    range, silhouette_px = 4 and gap_px = GAP_PX, no control point of the robot alone is
    reported more than 5 cm nearer than min(true distance to the fixed scene, rho). The grid
    (reported, not asserted: the robot's shadow in the other cameras, whose pixel box of a
    cell behind the robot touches its outline, still confirms cells) only improves."""
    s0, g0 = _robot_alone_errors(name, 12, 4, 0)
    s3, g3 = _robot_alone_errors(name, 12, 4, GAP_PX)
    assert s3.min() >= -0.05, s3.min()
    assert np.all(s3 >= s0 - 1e-9) and np.all(g3 >= g0 - 1e-9)
