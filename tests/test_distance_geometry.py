"""Geometry of the depth-space distance against independent truths:

- R3–R5 vs the exact Euclidean distance to one pixel's convex frustum (SLSQP on the
  quadratic program, itself checked by dense sampling of the frustum's faces);
- the region of surveillance R6 far off the optical axis vs the projection of a dense
  sampling of the sphere of radius rho, and vs a whole-image scan.
"""

import math

import numpy as np
import pytest
from scipy.optimize import minimize

from depthguard.camera import Camera
from depthguard.distance import DistanceWorkspace
from depthguard.distance.reference import depth_space_distance_numpy
from depthguard.distance.window import ball_row_span, paper_window, surveillance_window
from depthguard.transforms import look_at


def frustum_constraints(cam, u, v, do, zfar):
    """Linear inequalities A q >= b of the frustum of pixel (u, v) from do to zfar (camera frame)."""
    a1, a2 = (u - 0.5 - cam.cx) / cam.fx, (u + 0.5 - cam.cx) / cam.fx
    b1, b2 = (v - 0.5 - cam.cy) / cam.fy, (v + 0.5 - cam.cy) / cam.fy
    A = np.array([[1, 0, -a1], [-1, 0, a2], [0, 1, -b1], [0, -1, b2], [0, 0, 1], [0, 0, -1]], float)
    b = np.array([0, 0, 0, 0, do, -zfar], float)
    return A, b, (a1, a2, b1, b2)


def exact_frustum_distance(P, A, b, q0):
    """min |q - P| subject to A q >= b: a convex QP, solved by SLSQP from a feasible start."""
    res = minimize(lambda q: np.sum((q - P) ** 2), q0, jac=lambda q: 2 * (q - P), method="SLSQP",
                   constraints=[{"type": "ineq", "fun": lambda q: A @ q - b, "jac": lambda q: A}],
                   options={"ftol": 1e-16, "maxiter": 500})
    q = res.x
    assert np.all(A @ q - b >= -1e-9), "optimiser left the frustum"
    return float(np.linalg.norm(q - P))


def sampled_frustum_distance(P, cam, u, v, do, zfar, n=120):
    """Minimum distance from P to a dense grid on the frustum's five faces (an upper bound)."""
    s = np.linspace(-0.5, 0.5, n)
    z = np.linspace(do, zfar, 4 * n)
    pts = []
    for side in (-0.5, 0.5):          # the four side faces, as rays through the pixel's border
        px, zz = np.meshgrid(u + side + 0 * s, z)
        py, _ = np.meshgrid(v + s, z)
        pts.append(np.stack([(px - cam.cx) * zz / cam.fx, (py - cam.cy) * zz / cam.fy, zz], -1).reshape(-1, 3))
        px, _ = np.meshgrid(u + s, z)
        py, _ = np.meshgrid(v + side + 0 * s, z)
        pts.append(np.stack([(px - cam.cx) * zz / cam.fx, (py - cam.cy) * zz / cam.fy, zz], -1).reshape(-1, 3))
    gx, gy = np.meshgrid(u + s, v + s)  # the base at do
    pts.append(np.stack([(gx - cam.cx) * do / cam.fx, (gy - cam.cy) * do / cam.fy, 0 * gx + do], -1).reshape(-1, 3))
    return float(np.min(np.linalg.norm(np.concatenate(pts) - P, axis=1)))


def test_r3_r5_against_exact_point_to_frustum_distance():
    """R3-R5 give the distance to a point of the frustum, so D >= D_exact, and
    D <= D_exact / cos(phi) + delta (phi: widest ray of the pixel; delta: the pixel's
    footprint at do when dp < do) — the approximation stated in depth_space_distance."""
    rng = np.random.default_rng(11)
    cam = Camera("c", 80, 60, 45.0, 48.0, 39.5, 29.5, min_range=0.3, max_range=6.0)  # wide: 83 x 64 deg
    ws = DistanceWorkspace(cam, 1)
    checked = excess = 0
    worst_ratio = 1.0
    for trial in range(150):
        u, v = int(rng.integers(0, cam.width)), int(rng.integers(0, cam.height))
        do = float(np.float32(rng.uniform(0.6, 2.5)))
        depth = np.zeros(cam.shape, np.float32)
        depth[v, u] = do
        ws.set_depth(depth, invalid="free")          # only this pixel's frustum is an obstacle
        ds = np.array([u + rng.normal(0, 6), v + rng.normal(0, 6), do + rng.uniform(-0.5, 0.8)])
        ds[2] = max(ds[2], 0.2)
        P = cam.depth_space_to_camera(ds[None])[0]
        res = ws.query(P[None], rho=50.0, method="min")      # identity pose: world = camera frame
        D = float(res.distance[0])
        zfar = do + 30.0
        A, b, (a1, a2, b1, b2) = frustum_constraints(cam, u, v, do, zfar)
        q0 = P + D * res.direction[0] if D > 0 else P
        D_exact = exact_frustum_distance(P, A, b, q0)
        if trial < 25:      # the optimiser itself against dense sampling of the faces
            D_samp = sampled_frustum_distance(P, cam, u, v, do, do + 3.0)
            assert D_exact <= D_samp + 1e-9
            assert D_samp - D_exact < 0.02 * max(do, 1.0)
        cos_phi = 1.0 / math.sqrt(1 + max(a1 * a1, a2 * a2) + max(b1 * b1, b2 * b2))
        delta = do * math.hypot(1 / cam.fx, 1 / cam.fy) if ds[2] < do else 0.0
        assert D_exact <= D + 1e-7
        assert D <= D_exact / cos_phi + delta + 1e-7
        if D_exact < 1e-9:
            assert D < 1e-9                 # inside the frustum: both 0
        checked += 1
        excess += D - D_exact > 1e-4
        if D_exact > 1e-3:
            worst_ratio = max(worst_ratio, D / D_exact)
    assert checked == 150
    assert excess > 10                  # the approximation is visible, so the bound is exercised
    assert worst_ratio > 1.05


def test_r3_r5_is_exact_for_an_on_axis_pixel_beside_the_point():
    """Pixel straddling the optical axis, P level with its gray area: the slice at dp is the
    nearest (the side faces are nearly parallel to the axis), so R5 = exact to 1e-6."""
    cam = Camera("c", 81, 61, 500.0, 500.0, 40.0, 30.0, min_range=0.3, max_range=6.0)
    ws = DistanceWorkspace(cam, 1)
    depth = np.zeros(cam.shape, np.float32)
    depth[30, 40] = 1.0
    ws.set_depth(depth, invalid="free")
    P = np.array([0.01, 0.004, 1.5])
    res = ws.query(P[None], rho=1.0, method="min")
    A, b, _ = frustum_constraints(cam, 40, 30, 1.0, 40.0)
    D_exact = exact_frustum_distance(P, A, b, P + res.distance[0] * res.direction[0])
    assert res.distance[0] == pytest.approx(D_exact, abs=1e-6)
    # by hand: at depth 1.5 the pixel spans x <= 0.5 * 1.5 / 500 = 0.0015, y <= 0.0015
    assert res.distance[0] == pytest.approx(math.hypot(0.01 - 0.0015, 0.004 - 0.0015), abs=1e-12)


def fibonacci_sphere(n):
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    th = np.pi * (1 + 5 ** 0.5) * i
    return np.stack([np.cos(th) * np.sin(phi), np.sin(th) * np.sin(phi), np.cos(phi)], -1)


KINECT = Camera("k", 640, 480, 525.0, 525.0, 319.5, 239.5, min_range=0.4, max_range=4.0)


@pytest.mark.parametrize("rho", [0.3, 0.4])
def test_window_contains_every_pixel_within_rho_far_off_axis(rho):
    """Points near and beyond the image corners: every pixel that the ball of radius rho
    projects into lies inside the R6 window; the paper's closed form misses some."""
    sphere = fibonacci_sphere(20000)
    paper_misses = 0
    for px in (-40.0, 3.0, 320.0, 636.0, 690.0):
        for py in (-30.0, 2.0, 240.0, 477.0, 520.0):
            for dp in (0.85, 1.5, 3.0):
                pc = KINECT.depth_space_to_camera(np.array([[px, py, dp]]))[0]
                u0, u1, v0, v1 = surveillance_window(pc[0], pc[1], pc[2], rho, KINECT.fx, KINECT.fy,
                                                     KINECT.cx, KINECT.cy, KINECT.min_range, 640, 480)
                Q = pc + rho * sphere                  # the ball's surface: its silhouette bounds the ball
                assert np.all(Q[:, 2] > 0)
                u = np.floor(Q[:, 0] * KINECT.fx / Q[:, 2] + KINECT.cx + 0.5)
                v = np.floor(Q[:, 1] * KINECT.fy / Q[:, 2] + KINECT.cy + 0.5)
                inside = (u >= 0) & (u < 640) & (v >= 0) & (v < 480)
                if not inside.any():
                    assert u0 > u1 or v0 > v1 or not (
                        (u >= u0) & (u <= u1) & (v >= v0) & (v <= v1)).any()
                    continue
                u, v = u[inside], v[inside]
                for vv in np.unique(v):         # the per-row refinement of the mean / hybrid scan
                    a0, a1 = ball_row_span(int(vv), pc[0], pc[1], pc[2], rho, KINECT.fx, KINECT.fy,
                                           KINECT.cx, KINECT.cy, u0, u1)
                    uu = u[v == vv]
                    assert a0 <= uu.min() and uu.max() <= a1, (px, py, dp, vv)
                assert u.min() >= u0 and u.max() <= u1 and v.min() >= v0 and v.max() <= v1, (px, py, dp)
                q0, q1, r0, r1 = paper_window(px, py, dp, rho, KINECT.fx, KINECT.fy, 640, 480)
                paper_misses += not (u.min() >= q0 and u.max() <= q1 and v.min() >= r0 and v.max() <= r1)
    assert paper_misses > 10     # the [fix]: the paper's window is too small


def test_windowed_kernel_equals_whole_image_scan_off_axis():
    """With obstacles all over a tilted scene, the R6 window loses no pixel within rho."""
    rng = np.random.default_rng(5)
    T = look_at([1.8, -1.2, 1.6], [0, 0, 0.4])
    cam = Camera("k", 320, 240, 262.5, 262.5, 159.5, 119.5, world_from_camera=T, min_range=0.4, max_range=4.0)
    v, u = np.mgrid[0:240, 0:320]
    depth = (1.2 + 0.8 * (u / 320) + 0.3 * np.sin(v / 7.0) + rng.normal(0, 0.01, (240, 320))).astype(np.float32)
    ws = DistanceWorkspace(cam, 40)
    ws.set_depth(depth)
    ds = np.c_[rng.choice([-15.0, 4.0, 315.0, 335.0], 40), rng.choice([-10.0, 3.0, 236.0, 250.0], 40),
               rng.uniform(0.9, 2.8, 40)]
    P = cam.depth_space_to_world(ds)
    for method in ("min", "mean", "hybrid"):
        res = ws.query(P, rho=0.4, method=method)
        D, V, C, O = depth_space_distance_numpy(cam, ws.d0, P, 0.4, method, window=False)
        np.testing.assert_array_equal(np.isinf(res.distance), np.isinf(D))
        fin = np.isfinite(D)
        assert fin.sum() > 20
        np.testing.assert_allclose(res.distance[fin], D[fin], atol=1e-9, rtol=0)
        np.testing.assert_allclose(res.direction, V, atol=1e-9, rtol=0)
        np.testing.assert_array_equal(res.count, C)
