"""Depth-space distance for one camera (SPEC §2, R3–R9, R26, R28): kernels vs numpy twins,
and hand-checked expectations for observed / inf / invalid pixels / robot removal."""

import math
import tracemalloc

import numpy as np
import pytest

import depthguard as dg
from depthguard.camera import Camera
from depthguard.distance import DistanceWorkspace, depth_space_distance
from depthguard.distance.reference import (depth_space_distance_numpy, obstacle_start_depth_numpy,
                                           surveillance_window_numpy)
from depthguard.distance.window import surveillance_window
from depthguard.transforms import look_at

# ---------------------------------------------------------------- helpers


def random_camera(rng, i=0):
    W = int(rng.integers(30, 120))
    H = int(rng.integers(24, 90))
    f = rng.uniform(0.6, 1.6) * W
    eye = rng.uniform(-2, 2, 3) + [0, 0, 2]
    T = look_at(eye, rng.uniform(-0.5, 0.5, 3), up=(0, 0, 1))
    return Camera(f"r{i}", W, H, f * rng.uniform(0.9, 1.1), f * rng.uniform(0.9, 1.1),
                  rng.uniform(0.3, 0.7) * (W - 1), rng.uniform(0.3, 0.7) * (H - 1),
                  world_from_camera=T, min_range=float(rng.uniform(0.1, 0.5)), max_range=4.0)


def random_depth(rng, cam):
    """Smooth surfaces with holes: zeros, NaN, too near, too far."""
    H, W = cam.shape
    v, u = np.mgrid[0:H, 0:W]
    d = 1.0 + 1.5 * rng.random() + 0.6 * np.sin(u / rng.uniform(3, 15)) * np.cos(v / rng.uniform(3, 15))
    d += rng.normal(0, 0.02, d.shape)
    r = rng.random(d.shape)
    d[r < 0.05] = 0.0
    d[(r >= 0.05) & (r < 0.07)] = np.nan
    d[(r >= 0.07) & (r < 0.08)] = 0.05          # nearer than min_range
    d[(r >= 0.08) & (r < 0.09)] = 9.0           # beyond max_range
    return d.astype(np.float32)


def random_robot_depth(rng, cam, depth):
    """A robot blob: part of it is what the camera measures, part is hidden by a nearer object."""
    H, W = cam.shape
    rd = np.zeros(cam.shape, np.float32)
    u0, v0 = int(rng.integers(0, W // 2)), int(rng.integers(0, H // 2))
    rd[v0:v0 + H // 3, u0:u0 + W // 3] = rng.uniform(0.8, 1.5)
    seen = rd > 0
    depth = depth.copy()
    depth[seen] = rd[seen] + rng.normal(0, 0.01, seen.sum())
    hand = seen & (rng.random(cam.shape) < 0.2)
    depth[hand] = rd[hand] - 0.2                 # something in front of the robot
    return rd, depth


def random_points(rng, cam, n):
    """Depth-space samples over and beyond the image, some behind the camera."""
    ds = np.c_[rng.uniform(-0.3, 1.3, n) * cam.width, rng.uniform(-0.3, 1.3, n) * cam.height,
               rng.uniform(0.05, 3.5, n)]
    P = cam.depth_space_to_world(ds)
    P[: n // 10] = cam.camera_to_world(np.c_[rng.uniform(-1, 1, (n // 10, 2)), rng.uniform(-0.5, 0.0, n // 10)])
    return P


def assert_same(res, ref, tol=1e-9):
    D, V, C, O = ref
    np.testing.assert_array_equal(np.isinf(res.distance), np.isinf(D))
    fin = np.isfinite(D)
    np.testing.assert_allclose(res.distance[fin], D[fin], rtol=0, atol=tol)
    np.testing.assert_allclose(res.direction, V, rtol=0, atol=tol)
    np.testing.assert_array_equal(res.count, C)
    np.testing.assert_array_equal(res.observed, O)


AXIS = Camera("axis", 64, 48, 50.0, 50.0, 31.5, 23.5, min_range=0.4, max_range=4.0)  # identity pose


def at_pixel(px, py, dp):
    """World point (identity pose) with depth-space coordinates (px, py, dp)."""
    return AXIS.depth_space_to_world(np.array([[px, py, dp]]))


# ----------------------------------------------------- kernels vs numpy twins


@pytest.mark.parametrize("seed", range(6))
def test_kernels_equal_numpy_twins(seed):
    rng = np.random.default_rng(seed)
    cam = random_camera(rng, seed)
    depth = random_depth(rng, cam)
    rd, depth_r = random_robot_depth(rng, cam, depth)
    if seed % 2:                                     # float64 images (.npy) take the same path
        depth, depth_r, rd = depth.astype(np.float64), depth_r.astype(np.float64), rd.astype(np.float64)
    P = random_points(rng, cam, 60)
    ws = DistanceWorkspace(cam, max_points=8)        # grows to 60 on the first query
    for invalid in ("unknown", "free"):
        for robot, mode in ((None, "drop"), (rd, "drop"), (rd, "shadow")):
            img = depth if robot is None else depth_r
            ws.set_depth(img, robot, invalid=invalid, robot_mode=mode, robot_offset=0.03)
            d0 = obstacle_start_depth_numpy(img, robot, cam.min_range, cam.max_range, invalid, mode, 0.03)
            np.testing.assert_array_equal(ws.d0, d0)
            for method in ("min", "mean", "hybrid"):
                rho = float(rng.uniform(0.1, 0.6))
                res = ws.query(P, rho=rho, method=method)
                assert_same(res, depth_space_distance_numpy(cam, d0, P, rho, method))
    # the test is not vacuous: finite distances, zeros and infs all occur
    assert np.isfinite(res.distance).any() and np.isinf(res.distance).any()


def test_window_kernel_equals_twin():
    rng = np.random.default_rng(7)
    for i in range(200):
        cam = random_camera(rng, i)
        pc = np.r_[rng.uniform(-2, 2, 2), rng.uniform(0.05, 4)]
        r = float(rng.uniform(0.05, 0.8))
        got = surveillance_window(pc[0], pc[1], pc[2], r, cam.fx, cam.fy, cam.cx, cam.cy,
                                  cam.min_range, cam.width, cam.height)
        assert tuple(got) == surveillance_window_numpy(pc, r, cam)


def test_min_scan_finds_the_brute_force_minimum_in_clutter():
    """The outward ring scan with a shrinking window equals a plain minimum over the whole image."""
    rng = np.random.default_rng(3)
    cam = Camera("c", 200, 150, 160.0, 160.0, 99.5, 74.5, min_range=0.3, max_range=5.0)
    depth = rng.uniform(0.5, 2.5, cam.shape).astype(np.float32)    # every pixel a different depth
    ws = DistanceWorkspace(cam)
    ws.set_depth(depth)
    P = random_points(rng, cam, 300)
    res = ws.query(P, rho=0.5, method="min")
    D, V, C, O = depth_space_distance_numpy(cam, ws.d0, P, 0.5, "min", window=False)
    assert_same(res, (D, V, C, O))
    assert (np.isfinite(D) & (D > 0)).sum() > 100


# --------------------------------------------------- hand-checked expectations


def test_plane_in_front_hand_checked():
    """Wall at z = 3 facing the camera; P on the optical axis, which runs along a pixel corner."""
    depth = np.full(AXIS.shape, 3.0, np.float32)
    P = np.array([[0.0, 0.0, 2.7], [0.0, 0.0, 1.0]])
    for method in ("min", "hybrid"):
        res = depth_space_distance(AXIS, depth, P, rho=0.4, method=method)
        assert res.distance[0] == pytest.approx(0.3, abs=1e-12)          # straight ahead
        np.testing.assert_allclose(res.direction[0], [0, 0, 1], atol=1e-12)  # symmetric pixels
        assert math.isinf(res.distance[1])                                 # wall 2 m away > rho
        np.testing.assert_array_equal(res.direction[1], 0.0)
        np.testing.assert_array_equal(res.observed, [True, True])
    mean = depth_space_distance(AXIS, depth, P, rho=0.4, method="mean")
    assert 0.3 < mean.distance[0] <= 0.4          # averages over the pixels within rho
    np.testing.assert_allclose(mean.direction[0], [0, 0, 1], atol=1e-12)
    # the count is the number of pixels whose nearest frustum point lies within rho:
    # lateral offset of pixel edge k pixels away at depth 3: k * 3/50; sqrt(0.09 + a^2 + b^2) <= 0.4
    k = np.arange(-20, 20)
    off = np.where(k < 0, (-k - 1), k) * 3.0 / 50.0     # distance of pixel (31.5 + k..) edge
    want = int(((0.09 + off[:, None] ** 2 + off[None, :] ** 2) <= 0.16).sum())
    assert mean.count[0] == want


def test_gray_area_behind_a_box_is_obstacle():
    """P hidden behind a surface (in its gray area) is observed and at distance 0."""
    depth = np.full(AXIS.shape, 3.0, np.float32)
    depth[20:28, 28:36] = 1.0                     # a box face at 1 m
    P = at_pixel(31.5, 23.5, 1.3)                 # behind the face
    res = depth_space_distance(AXIS, depth, P, rho=0.4, method="min")
    assert res.distance[0] == 0.0 and res.observed[0]
    np.testing.assert_array_equal(res.direction[0], 0.0)
    # beside the shadow, level with it: lateral distance to the shadow's edge at depth 1.3
    P = at_pixel(40.0, 23.5, 1.3)                 # shadow spans px in [27.5, 35.5]
    res = depth_space_distance(AXIS, depth, P, rho=0.4, method="min")
    assert res.distance[0] == pytest.approx((40.0 - 35.5) * 1.3 / 50.0, abs=1e-12)
    np.testing.assert_allclose(res.direction[0], [-1, 0, 0], atol=1e-12)


def test_observed_hand_checked():
    depth = np.full(AXIS.shape, 3.0, np.float32)
    P = np.array([
        [0.0, 0.0, 1.0],      # in view
        [0.0, 0.0, 0.3],      # nearer than min_range 0.4
        [0.0, 0.0, 5.0],      # beyond max_range 4
        [0.0, 0.0, -1.0],     # behind the camera
        [1.0, 0.0, 1.0],      # px = 81.5 > 63.5: outside the image
        [-0.63, 0.0, 1.0],    # px = 0: first column, inside
        [0.645, 0.0, 1.0],    # px = 63.75: just beyond the last column's right edge 63.5
    ])
    res = depth_space_distance(AXIS, depth, P, rho=0.4)
    np.testing.assert_array_equal(res.observed, [True, False, False, False, False, True, False])
    assert math.isinf(res.distance[3]) and not res.observed[3]
    # beyond max_range a point behind the wall lies in the gray area: distance 0, yet unobserved
    assert res.distance[2] == 0.0 and not res.observed[2]


def test_point_outside_image_still_sees_edge_frusta():
    """A point just beside the image is unobserved, but frusta at the image edge within rho count."""
    depth = np.full(AXIS.shape, 1.0, np.float32)
    P = at_pixel(66.0, 23.5, 1.2)                 # 2.5 px right of the last pixel's edge at 63.5
    res = depth_space_distance(AXIS, depth, P, rho=0.4, method="min")
    assert not res.observed[0]
    assert res.distance[0] == pytest.approx(2.5 * 1.2 / 50.0, abs=1e-12)


@pytest.mark.parametrize("bad", [0.0, np.nan, np.inf, 0.2])
def test_invalid_pixel_policies_hand_checked(bad):
    """R28: an invalid pixel (0, NaN, inf, nearer than min_range). (A finite return beyond
    max_range is free up to max_range: tests/test_gaps_beyond_range.py.)"""
    depth = np.full(AXIS.shape, 3.0, np.float32)
    depth[20, 10] = bad
    P_behind = at_pixel(10.0, 20.0, 1.0)          # on that pixel's ray, 1 m away
    P_near = at_pixel(10.0, 20.0, 0.3)            # on the ray, nearer than min_range = 0.4
    P = np.r_[P_behind, P_near]
    res = depth_space_distance(AXIS, depth, P, rho=0.4, method="min", invalid="unknown")
    # unknown: the whole ray from min_range on is obstacle; P_behind is in it
    assert res.distance[0] == 0.0 and res.observed[0]
    # P_near: nearest frustum point at depth 0.4 with the clamp at px = 10, py = 20 (R3-R5)
    v = np.array([(10 - 31.5) * 0.1 / 50, (20 - 23.5) * 0.1 / 50, 0.1])
    assert res.distance[1] == pytest.approx(np.linalg.norm(v), abs=1e-12)
    np.testing.assert_allclose(res.direction[1], v / np.linalg.norm(v), atol=1e-12)
    assert not res.observed[1]
    free = depth_space_distance(AXIS, depth, P, rho=0.4, method="min", invalid="free")
    assert np.all(np.isinf(free.distance))        # the wall at 3 m is beyond rho of both
    np.testing.assert_array_equal(free.observed, [True, False])


def test_robot_removal_hand_checked():
    """R9: wall at 2 m; the robot's link face at 1 m covers rows 20-27, cols 28-35."""
    depth = np.full(AXIS.shape, 2.0, np.float32)
    rd = np.zeros(AXIS.shape, np.float32)
    rd[20:28, 28:36] = 1.0
    depth[20:28, 28:36] = 1.0 + 0.01              # measured robot, within the 0.03 m offset
    P_link = at_pixel(31.5, 23.5, 1.05)           # control point inside the link
    P_front = at_pixel(31.5, 23.5, 0.8)           # a point in front of the robot, same ray
    P = np.r_[P_link, P_front]
    rho = 1.5
    plain = depth_space_distance(AXIS, depth, P, rho=rho, method="min")
    assert plain.distance[0] == 0.0               # sees its own link: self distance 0
    drop = depth_space_distance(AXIS, depth, P, rho=rho, method="min", robot_depth=rd)
    # robot pixels gone, and with them the wall pixels they hide: the nearest wall frusta are
    # the pixels just beside the patch, 4 pixels = 4 * 2/50 m off P's ray at depth 2 (P's ray
    # runs along a pixel corner): D = hypot(0.95, 0.16), four symmetric candidates
    assert drop.distance[0] == pytest.approx(math.hypot(0.95, 0.16), abs=1e-12)
    assert drop.direction[0, 2] == pytest.approx(0.95 / math.hypot(0.95, 0.16), abs=1e-9)
    assert math.hypot(*drop.direction[0, :2]) == pytest.approx(0.16 / math.hypot(0.95, 0.16), abs=1e-9)
    assert drop.distance[1] == pytest.approx(math.hypot(1.2, 0.16), abs=1e-12)
    shadow = depth_space_distance(AXIS, depth, P, rho=rho, method="min", robot_depth=rd,
                                  robot_mode="shadow")
    assert shadow.distance[0] == 0.0              # free up to 1 m, unknown behind: P is inside
    assert shadow.distance[1] == pytest.approx(0.2, abs=1e-12)     # the robot's face ahead
    np.testing.assert_allclose(shadow.direction[1], [0, 0, 1], atol=1e-12)

    # a hand at 0.9 m in front of the robot (0.9 < 1.0 - 0.03) is kept as obstacle
    depth[21, 29] = 0.9
    P_hand = at_pixel(29.0, 21.0, 1.05)           # a control point behind the hand
    res = depth_space_distance(AXIS, depth, np.r_[P_hand, P_front], rho=rho, method="min", robot_depth=rd)
    assert res.distance[0] == 0.0
    # P_front (px = 31.5, py = 23.5, dp = 0.8) to the hand pixel [28.5, 29.5] x [20.5, 21.5] at 0.9
    h = float(np.float32(0.9))                    # as stored in the float32 image
    v = np.array([(29.5 - 31.5) * h / 50, (21.5 - 23.5) * h / 50, h - 0.8])
    assert res.distance[1] == pytest.approx(np.linalg.norm(v), abs=1e-12)
    np.testing.assert_allclose(res.direction[1], v / np.linalg.norm(v), atol=1e-12)


def test_no_obstacle_is_inf_not_a_number():
    depth = np.zeros(AXIS.shape, np.float32)
    res = depth_space_distance(AXIS, depth, [[0, 0, 1.0]], rho=0.4, invalid="free")
    assert math.isinf(res.distance[0]) and res.observed[0] and res.count[0] == 0
    res = depth_space_distance(AXIS, depth, [[0, 0, 1.0]], rho=0.4)   # unknown: obstacle everywhere
    assert res.distance[0] == 0.0


def test_world_frame_direction():
    """A rotated camera: the direction comes back in the world frame."""
    T = look_at([0, 0, 3], [0, 0, 0], up=(0, 1, 0))           # looking down -z
    cam = Camera("down", 64, 48, 50.0, 50.0, 31.5, 23.5, world_from_camera=T, min_range=0.4, max_range=4.0)
    depth = np.full(cam.shape, 3.0, np.float32)                # the floor z = 0
    res = depth_space_distance(cam, depth, [[0, 0, 0.25]], rho=0.4, method="min")
    assert res.distance[0] == pytest.approx(0.25, abs=1e-12)
    np.testing.assert_allclose(res.direction[0], [0, 0, -1], atol=1e-12)


# --------------------------------------------------------------- API checks


def test_public_name_and_bad_input():
    assert dg.depth_space_distance is depth_space_distance
    assert dg.DistanceResult.__name__ == "DistanceResult"
    depth = np.full(AXIS.shape, 3.0, np.float32)
    with pytest.raises(ValueError, match="method"):
        depth_space_distance(AXIS, depth, [[0, 0, 1]], method="max")
    with pytest.raises(ValueError, match="rho"):
        depth_space_distance(AXIS, depth, [[0, 0, 1]], rho=0)
    with pytest.raises(ValueError, match="shape"):
        depth_space_distance(AXIS, depth, np.zeros((4, 2)))
    with pytest.raises(ValueError, match="finite"):
        depth_space_distance(AXIS, depth, [[0, np.nan, 1]])
    with pytest.raises(ValueError, match="expected"):
        depth_space_distance(AXIS, depth[:10], [[0, 0, 1]])
    with pytest.raises(ValueError, match="robot_depth"):
        depth_space_distance(AXIS, depth, [[0, 0, 1]], robot_depth=np.zeros((3, 3), np.float32))
    with pytest.raises(ValueError, match="invalid"):
        depth_space_distance(AXIS, depth, [[0, 0, 1]], invalid="ignore")
    with pytest.raises(ValueError, match="robot_mode"):
        depth_space_distance(AXIS, depth, [[0, 0, 1]], robot_mode="keep")
    with pytest.raises(ValueError, match="set_depth"):
        DistanceWorkspace(AXIS).query([[0, 0, 1]])


def test_workspace_query_does_not_allocate():
    rng = np.random.default_rng(0)
    ws = DistanceWorkspace(AXIS, max_points=32)
    ws.set_depth(rng.uniform(0.5, 3, AXIS.shape).astype(np.float32))
    P = np.ascontiguousarray(random_points(rng, AXIS, 32))
    for method in ("min", "mean", "hybrid"):
        ws.query(P, 0.4, method)                     # compile / warm
    tracemalloc.start()
    for _ in range(50):
        for method in ("min", "mean", "hybrid"):
            res = ws.query(P, 0.4, method)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert peak < 8_000                               # a few small Python objects, no arrays
    r1 = ws.query(P, 0.4, "min")
    assert np.shares_memory(r1.distance, res.distance)   # the same buffers every call


@pytest.mark.slow
def test_self_removal_with_the_ur3_cell():
    """R9 with a real robot: the UR3 rendered into the camera by the helper removes the robot's
    own pixels; the result equals the distance to the static scene alone with those pixels
    ignored (an image built without the robot), and the control points stop seeing their links."""
    from depthguard.distance.self_removal import robot_depth
    from depthguard.render import render_depth
    from depthguard.sim import load_cell

    cell = load_cell("ur3-cell")
    robot, q = cell.scene.robot, cell.scene.robot_q(0.0)
    meshes, names = cell.scene.meshes_at(0.0, robot=True)
    static = [m for m, n in zip(meshes, names) if not n.startswith("robot/")]
    cps = robot.control_point_positions(q)
    best = None
    for cam in cell.rig.cameras:
        rd = robot_depth(cam, robot, q)
        if best is None or (rd > 0).sum() > (best[1] > 0).sum():
            best = (cam, rd)
    cam, rd = best
    assert (rd > 0).sum() > 500
    measured = render_depth(cam, meshes)
    with pytest.raises(ValueError, match="joint"):
        robot_depth(cam, robot, q[:-1])

    plain = depth_space_distance(cam, measured, cps, rho=0.4, method="min", invalid="free")
    removed = depth_space_distance(cam, measured, cps, rho=0.4, method="min", invalid="free", robot_depth=rd)
    seen = cam.in_view(cps)
    assert seen.sum() >= 3
    assert np.sum(plain.distance[seen] == 0.0) >= 2          # without removal: own links at 0
    assert np.all(removed.distance[seen] > 0.0)               # with removal: never the own link

    # independent construction: the static scene alone, robot pixels made invalid and ignored
    alone = render_depth(cam, static)
    alone[(rd > 0) & (measured >= rd - 0.03)] = 0.0     # R9's rule; in front of the robot: kept
    ref = depth_space_distance(cam, alone, cps, rho=0.4, method="min", invalid="free")
    np.testing.assert_array_equal(np.isinf(ref.distance), np.isinf(removed.distance))
    fin = np.isfinite(ref.distance)
    np.testing.assert_allclose(removed.distance[fin], ref.distance[fin], atol=1e-9)
