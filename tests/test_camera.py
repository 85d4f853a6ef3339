"""Camera model and depth space (R1): round trips, pixel convention, analytic projections."""

import math

import numpy as np
import pytest

import depthguard as dg
from depthguard.transforms import look_at, quat_to_matrix, matrix_to_quat, rot_z


def random_camera(rng, w=640, h=480):
    eye = rng.uniform(-3, 3, 3)
    target = rng.uniform(-0.5, 0.5, 3)
    return dg.Camera(id="c", width=w, height=h, fx=rng.uniform(300, 700), fy=rng.uniform(300, 700),
                     cx=rng.uniform(0, w - 1), cy=rng.uniform(0, h - 1),
                     world_from_camera=look_at(eye, target), min_range=0.1, max_range=10.0)


def test_round_trip_world_depth_space_world(rng):
    for _ in range(20):
        cam = random_camera(rng)
        P = rng.uniform(-2, 2, (500, 3))
        ds = cam.world_to_depth_space(P)
        front = ds[:, 2] > 1e-3
        back = cam.depth_space_to_world(ds[front])
        assert np.abs(back - P[front]).max() < 1e-9


def test_projection_matches_hand_computation():
    # camera at origin looking along world +x, y down = world -z
    T = look_at([0, 0, 0], [1, 0, 0])
    cam = dg.Camera(id="c", width=640, height=480, fx=500.0, fy=400.0, cx=319.5, cy=239.5, world_from_camera=T)
    # world (2, -0.5, 0.25): camera x = right = world -y -> +0.5 ; camera y = down = world -z -> -0.25 ; z = 2
    ds = cam.world_to_depth_space([[2.0, -0.5, 0.25]])[0]
    assert ds[2] == pytest.approx(2.0)
    assert ds[0] == pytest.approx(0.5 * 500 / 2 + 319.5)
    assert ds[1] == pytest.approx(-0.25 * 400 / 2 + 239.5)


def test_pixel_centres_at_integers():
    cam = dg.Camera(id="c", width=4, height=3, fx=1.0, fy=1.0, cx=1.5, cy=1.0)
    u, v = cam.pixel_of(np.array([-0.5, -0.49, 0.49, 0.5, 3.49]), np.array([0.0, 0.0, 0.0, 0.0, 0.0]))
    assert u.tolist() == [0, 0, 0, 1, 3]  # pixel u covers [u - 1/2, u + 1/2)


def test_depth_is_z_not_ray_length():
    cam = dg.Camera(id="c", width=64, height=48, fx=50.0, fy=50.0, cx=31.5, cy=23.5)
    depth = np.full(cam.shape, 2.0, dtype=np.float32)   # a fronto-parallel plane at z = 2
    pts = cam.depth_to_points(depth, frame="camera")
    assert np.allclose(pts[:, 2], 2.0)
    corner = pts[0]
    assert np.linalg.norm(corner) > 2.0                 # the ray to the corner is longer


def test_depth_to_points_world_reprojects_to_its_pixels(rng):
    cam = random_camera(rng, 80, 60)
    depth = rng.uniform(0.5, 3.0, cam.shape).astype(np.float32)
    depth[5, 7] = 0.0
    depth[6, 8] = np.nan
    pts = cam.depth_to_points(depth)
    assert len(pts) == cam.width * cam.height - 2
    ds = cam.world_to_depth_space(pts)
    u, v = cam.pixel_of(ds[:, 0], ds[:, 1])
    vv, uu = np.nonzero(np.isfinite(depth) & (depth > 0))
    assert np.array_equal(u, uu) and np.array_equal(v, vv)
    assert np.allclose(ds[:, 2], depth[vv, uu], atol=1e-6)


def test_fov_of_known_intrinsics():
    cam = dg.Camera(id="c", width=640, height=480, fx=320.0, fy=240.0, cx=319.5, cy=239.5)
    assert cam.hfov == pytest.approx(2 * math.atan(1.0))
    assert cam.vfov == pytest.approx(2 * math.atan(1.0))


def test_in_view():
    cam = dg.Camera(id="c", width=100, height=100, fx=50.0, fy=50.0, cx=49.5, cy=49.5, min_range=0.5, max_range=3)
    P = np.array([[0, 0, 1.0], [0, 0, 0.2], [0, 0, 4.0], [5.0, 0, 1.0], [0, 0, -1.0]])
    assert cam.in_view(P).tolist() == [True, False, False, False, False]


@pytest.mark.parametrize("kw,match", [
    (dict(fx=0.0), "focal length"),
    (dict(fy=-3.0), "focal length"),
    (dict(cx=700.0), "principal point"),
    (dict(cy=-2.0), "principal point"),
    (dict(width=0), "width"),
    (dict(min_range=5.0, max_range=1.0), "range"),
    (dict(world_from_camera=np.diag([1.0, 1.0, -1.0, 1.0])), "determinant"),
    (dict(world_from_camera=np.diag([1.0, 2.0, 1.0, 1.0])), "orthonormal"),
    (dict(fx=float("nan")), "finite"),
])
def test_bad_cameras_raise_clear_errors(kw, match):
    base = dict(id="c", width=640, height=480, fx=500.0, fy=500.0, cx=319.5, cy=239.5)
    base.update(kw)
    with pytest.raises(dg.CameraError, match=match):
        dg.Camera(**base)


def test_camera_is_immutable():
    cam = dg.Camera(id="c", width=64, height=48, fx=50.0, fy=50.0, cx=31.5, cy=23.5)
    with pytest.raises(Exception):
        cam.fx = 3.0
    with pytest.raises(ValueError):
        cam.world_from_camera[0, 0] = 2.0


def test_quaternion_round_trip(rng):
    for _ in range(50):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        R = quat_to_matrix(q)
        assert np.allclose(R.T @ R, np.eye(3), atol=1e-12) and np.linalg.det(R) > 0
        q2 = matrix_to_quat(R)
        assert min(np.abs(q2 - q).max(), np.abs(q2 + q).max()) < 1e-9
    assert np.allclose(quat_to_matrix([0, 0, np.sin(0.25), np.cos(0.25)]), rot_z(0.5))
    with pytest.raises(ValueError, match="unit norm"):
        quat_to_matrix([0, 0, 0, 2.0])


def test_look_at_points_z_at_target():
    T = look_at([1, 2, 3], [0, 0, 0])
    z = T[:3, 2]
    assert np.allclose(z, -np.array([1, 2, 3]) / np.linalg.norm([1, 2, 3]))
    assert T[:3, 1] @ np.array([0, 0, 1.0]) < 0  # image y points down
