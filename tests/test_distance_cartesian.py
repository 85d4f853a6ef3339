"""The Cartesian baseline (R8): hand-checked point-to-point distance, brute force = k-d tree,
and the occlusion it misses (which the depth-space distance sees)."""

import math

import numpy as np
import pytest

from depthguard.camera import Camera
from depthguard.distance import depth_space_distance
from depthguard.distance.cartesian import CartesianBaseline, cartesian_distance
from depthguard.transforms import look_at

AXIS = Camera("axis", 64, 48, 50.0, 50.0, 31.5, 23.5, min_range=0.4, max_range=4.0)


def test_wall_in_front_hand_checked():
    """Wall at z = 2: pixel centres at x, y = (k + 1/2) * 2/50 around the optical axis, so the
    nearest back-projected points to (0, 0, 1.8) are 0.04/2 off the axis in x and y."""
    depth = np.full(AXIS.shape, 2.0, np.float32)
    P = np.array([[0.0, 0.0, 1.8], [0.0, 0.0, 1.0]])
    for search in ("kdtree", "brute"):
        res = cartesian_distance(AXIS, depth, P, rho=0.4, search=search)
        assert res.distance[0] == pytest.approx(math.sqrt(0.2 ** 2 + 0.02 ** 2 + 0.02 ** 2), abs=1e-12)
        assert res.direction[0, 2] == pytest.approx(0.2 / res.distance[0], abs=1e-12)
        assert math.isinf(res.distance[1])           # 1 m away > rho
        np.testing.assert_array_equal(res.observed, [True, True])
    # the depth-space distance takes the pixel's frustum: straight ahead, 0.2
    ds = depth_space_distance(AXIS, depth, P, rho=0.4, method="min")
    assert ds.distance[0] == pytest.approx(0.2, abs=1e-12)


def test_brute_equals_kdtree_and_a_plain_search():
    rng = np.random.default_rng(4)
    T = look_at([1.5, -1.0, 1.4], [0, 0, 0.3])
    cam = Camera("c", 120, 90, 100.0, 100.0, 59.5, 44.5, world_from_camera=T, min_range=0.4, max_range=4.0)
    depth = rng.uniform(1.0, 2.5, cam.shape).astype(np.float32)
    depth[rng.random(cam.shape) < 0.1] = 0.0
    cb = CartesianBaseline(cam)
    cb.set_depth(depth)
    P = cam.depth_space_to_world(np.c_[rng.uniform(0, 120, 50), rng.uniform(0, 90, 50), rng.uniform(0.8, 2.6, 50)])
    a = cb.query(P, rho=0.3, search="kdtree")
    b = cb.query(P, rho=0.3, search="brute")
    np.testing.assert_array_equal(np.isinf(a.distance), np.isinf(b.distance))
    fin = np.isfinite(a.distance)
    assert fin.sum() > 20
    np.testing.assert_allclose(a.distance[fin], b.distance[fin], atol=1e-12)
    # independent: every valid pixel back-projected, nearest within rho and within dp +- rho
    cloud = cam.depth_to_points(depth)
    zc = cam.world_to_camera(cloud)[:, 2]
    for i, p in enumerate(P):
        dp = cam.world_to_camera(p[None])[0, 2]
        sel = (zc >= dp - 0.3) & (zc <= dp + 0.3)
        d = np.linalg.norm(cloud[sel] - p, axis=1)
        want = d.min() if len(d) and d.min() <= 0.3 else np.inf
        assert a.distance[i] == pytest.approx(want, abs=1e-9) if np.isfinite(want) else math.isinf(a.distance[i])


def test_cartesian_misses_the_occluded_side():
    """A box face at 1 m; a point hidden 5 cm behind it. The point cloud only holds the face,
    so the baseline reports 5 cm or more; the depth-space distance reports 0 (gray area)."""
    depth = np.full(AXIS.shape, 3.0, np.float32)
    depth[14:34, 22:42] = 1.0
    P = np.array([[0.0, 0.0, 1.05]])
    cart = cartesian_distance(AXIS, depth, P, rho=0.4)
    assert cart.distance[0] >= 0.05
    assert depth_space_distance(AXIS, depth, P, rho=0.4, method="min").distance[0] == 0.0


def test_bad_input():
    cb = CartesianBaseline(AXIS)
    with pytest.raises(ValueError, match="set_depth"):
        cb.query([[0, 0, 1]])
    cb.set_depth(np.full(AXIS.shape, 2.0, np.float32))
    with pytest.raises(ValueError, match="search"):
        cb.query([[0, 0, 1]], search="octree")
    with pytest.raises(ValueError, match="rho"):
        cb.query([[0, 0, 1]], rho=-1)
