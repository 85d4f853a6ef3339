"""Returns beyond the rated range and small gaps of invalid pixels (R25, R28, R32).

- A finite measurement ``m > max_range`` (a real sensor's return beyond its rated range,
  simulated up to the model's ``return_range``) is "free up to ``max_range``, unknown
  behind" in the product's two distance paths (one camera, depth grid); ``invalid="free"``
  keeps it free, as before.
- The small-gap rule (``gap_px``): an invalid run of at most ``gap_px`` pixels along a row or
  column, bounded by returns, is unknown from the nearer end's depth, not from ``min_range``.
- The kernels against their numpy twins.
"""

from __future__ import annotations

import numpy as np
import pytest

import depthguard as dg
from depthguard.distance import depth_space_distance
from depthguard.distance import kernels as DK
from depthguard.distance.api import DistanceWorkspace
from depthguard.distance.gaps import GapBuffers, check_gap_px, gap_depth, gap_depth_numpy
from depthguard.distance.reference import obstacle_start_depth_numpy
from depthguard.distance.silhouette import dilate_robot_depth_numpy
from depthguard.fusion import depth_grid_kernels
from depthguard.fusion import depth_grid_ref as ref
from depthguard.fusion.depth_grid import DepthGridMap
from depthguard.geometry.primitives import Box
from depthguard.render import render_depth
from depthguard.sensors import intrinsics_for
from depthguard.sources import SimulatedCamera
from depthguard.transforms import look_at


@pytest.fixture
def rng():
    return np.random.default_rng(20261123)


def _cam(name="c0", w=160, h=120, f=130.0, rmin=0.4, rmax=4.0):
    """Looks along +z from the origin (x right, y down in the image)."""
    return dg.Camera(id=name, width=w, height=h, fx=f, fy=f, cx=(w - 1) / 2, cy=(h - 1) / 2,
                     world_from_camera=look_at(np.zeros(3), np.array([0.0, 0.0, 2.0]), np.array([0.0, -1.0, 0.0])),
                     min_range=rmin, max_range=rmax)


def _on_ray(cam, u, v, depth):
    """World points at depth ``depth`` (m) on the rays of pixels ``(u, v)`` (arrays)."""
    u, v = np.broadcast_arrays(np.asarray(u, float), np.asarray(v, float))
    ds = np.stack([u.ravel(), v.ravel(), np.full(u.size, float(depth))], axis=1)
    return cam.depth_space_to_world(ds)


def _random_depth(rng, H, W, rmin=0.4, rmax=4.0):
    """Depths with every kind of pixel: valid, beyond the rated range, 0, NaN, inf, too near,
    short and long runs of invalid pixels."""
    d = rng.uniform(rmin, rmax + 3.0, (H, W)).astype(np.float32)
    d[rng.random((H, W)) < 0.25] = 0.0
    d[rng.random((H, W)) < 0.03] = np.nan
    d[rng.random((H, W)) < 0.02] = np.inf
    d[rng.random((H, W)) < 0.02] = rmin * 0.5
    d[rng.random((H, W)) < 0.02] = rmax * 4.0                # beyond what any sensor returns
    if H > 6 and W > 6:
        d[rng.integers(0, H), :] = 0.0                       # a whole invalid row
        d[:, rng.integers(0, W)] = 0.0
        v, u = rng.integers(0, H - 3), rng.integers(0, W - 3)
        d[v:v + 3, u:u + 2] = 0.0
    return d


# ------------------------------------------------------------------ the gap kernel
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_gap_kernel_equals_numpy_twin(rng, dtype):
    for it in range(120):
        H, W = (int(x) for x in rng.integers(1, 30, 2))
        d = _random_depth(rng, H, W).astype(dtype)
        n = int(rng.integers(0, 5))
        out = np.full((H + 2, W + 3), -7.0)                  # buffers may be larger than the image
        gap_depth(d, 0.4, 4.0, n, out)
        want = gap_depth_numpy(d, 0.4, 4.0, n)
        np.testing.assert_array_equal(out[:H, :W], want)
        if n == 0:
            assert not want.any()
        # only invalid pixels get a gap depth, never beyond max_range nor below min_range
        with np.errstate(invalid="ignore"):
            end = np.isfinite(d) & (d > 0) & (d >= 0.4) & (d <= 3.0 * 4.0)   # a return (RETURN_LIMIT_FACTOR)
        assert not want[end].any()
        g = want[want > 0]
        assert np.all((g >= 0.4) & (g <= 4.0))


def test_gap_kernel_hand_checked():
    d = np.full((5, 12), 2.0, np.float32)
    d[2, 3:5] = 0.0                 # 2-px row gap between 2.0 and 2.0
    d[2, 5] = 1.5                   # ... its right end nearer
    d[2, 7:10] = np.nan             # 3-px row gap between 2.0 and 2.0; each pixel's column is a 1-px gap too
    d[0, 0:2] = 0.0                 # touches the left border: not bounded along the row
    d[:, 11] = 0.0                  # a whole column at the border: no gap either way
    g2 = gap_depth_numpy(d, 0.4, 4.0, 2)
    assert g2[2, 3] == g2[2, 4] == 1.5            # the nearer end (the columns would say 2.0)
    assert np.all(g2[2, 7:10] == 2.0)             # via the columns (1-px runs between rows 1 and 3)
    assert g2[0, 0] == 0.0 and g2[0, 1] == 0.0    # border on the left and above: unbounded
    assert not g2[:, 11].any()                    # the border column: unbounded both ways
    assert np.count_nonzero(g2) == 5
    d3 = np.full((3, 12), 3.0, np.float32)
    d3[:, 3:6] = 0.0                              # 3-px gap in every row, columns unbounded
    assert not gap_depth_numpy(d3, 0.4, 4.0, 2)[:, 3:6].any()
    assert np.all(gap_depth_numpy(d3, 0.4, 4.0, 3)[:, 3:6] == 3.0)
    d3[1, 2] = 9.0                                # an end beyond the rated range counts as max_range
    d3[1, 6] = 5.0
    assert np.all(gap_depth_numpy(d3, 0.4, 4.0, 3)[1, 3:6] == 4.0)
    out = np.empty((3, 12))
    gap_depth(d3, 0.4, 4.0, 3, out)
    np.testing.assert_array_equal(out, gap_depth_numpy(d3, 0.4, 4.0, 3))


def test_gap_buffers_and_errors():
    b = GapBuffers((10, 12))
    d = np.zeros((8, 9), np.float32)
    assert b.gaps(d, 0.4, 4.0, 2).shape == (8, 9)
    with pytest.raises(ValueError, match="exceeds"):
        b.gaps(np.zeros((11, 5), np.float32), 0.4, 4.0, 2)
    for bad in (-1, 1.5, True, "2", None):
        with pytest.raises(ValueError, match="gap_px"):
            check_gap_px(bad)
    assert check_gap_px(np.int64(3)) == 3


# ------------------------------------------------------------------ per-pixel states vs twins
def test_frame_state_and_start_depth_equal_twins_with_beyond_range_and_gaps(rng):
    cam = _cam()
    H, W = cam.shape
    robot = np.zeros((H, W), np.float32)
    robot[30:70, 50:100] = rng.uniform(0.5, 6, (40, 50))
    for it in range(3):
        depth = _random_depth(rng, H, W)
        for n_sil in (0, 3):
            # in the robot render's dtype, as the product's silhouette buffers hold it (a minimum of
            # float32 values: exact); frame_state then has the signatures the worker compiles (R29)
            sil = dilate_robot_depth_numpy(robot, n_sil).astype(robot.dtype) if n_sil else None
            for n_gap in (0, 1, 2, 3):
                gaps = gap_depth_numpy(depth, cam.min_range, cam.max_range, n_gap) if n_gap else None
                for inv, rf in (("unknown", False), ("unknown", True), ("free", True), ("free", False)):
                    free = np.empty((H, W))
                    kind = np.empty((H, W), dtype=np.int8)
                    depth_grid_kernels.frame_state(depth, robot, True, cam.min_range, cam.max_range, 0.03, inv == "free", rf,
                                  free, kind, sil if inv == "unknown" else None,
                                  gaps if inv == "unknown" else None)
                    f2, k2 = ref.frame_state_numpy(cam, depth, robot, 0.03, inv, rf, silhouette_px=n_sil,
                                                   gap_px=n_gap)
                    np.testing.assert_array_equal(free, f2)
                    np.testing.assert_array_equal(kind, k2)
                ws = DistanceWorkspace(cam)
                for inv in ("unknown", "free"):
                    for mode in ("drop", "shadow"):
                        ws.set_depth(depth, robot, invalid=inv, robot_mode=mode, robot_offset=0.03,
                                     silhouette_px=n_sil, gap_px=n_gap)
                        want = obstacle_start_depth_numpy(depth, robot, cam.min_range, cam.max_range, inv,
                                                          mode, 0.03, silhouette_px=n_sil, gap_px=n_gap)
                        np.testing.assert_array_equal(ws.d0, want)
        # the grid's per-pixel states through set_frames equal the twin
        grid = DepthGridMap([cam], cam.id, 0.5, 4.5, 0.05, cache=False)
        grid.set_frames({cam.id: depth}, {cam.id: robot}, robot_offset=0.03, invalid="unknown", silhouette_px=3,
                        gap_px=2)
        f2, k2 = ref.frame_state_numpy(cam, depth, robot, 0.03, "unknown", silhouette_px=3, gap_px=2)
        np.testing.assert_array_equal(grid._pfree, f2)
        np.testing.assert_array_equal(grid._pkind, k2)
    # invalid="free": beyond-range returns are free, exactly as an invalid pixel was before
    d = np.full((H, W), 6.0, np.float32)
    free = np.empty((H, W))
    kind = np.empty((H, W), np.int8)
    depth_grid_kernels.frame_state(d, robot, False, cam.min_range, cam.max_range, 0.03, True, False, free, kind, None, None)
    assert np.all(np.isinf(free)) and np.all(kind == depth_grid_kernels.KIND_UNKNOWN)
    d0 = np.empty((H, W))
    DK.obstacle_start_depth(d, robot, False, cam.min_range, cam.max_range, DK.INVALID_FREE, DK.ROBOT_DROP,
                            0.03, d0, DK.NO_SILHOUETTE[robot.dtype], DK.NO_GAP)
    assert np.all(np.isinf(d0))


def test_start_depth_is_one_compiled_signature_whatever_the_options(rng):
    """Silhouette and gaps off are empty arrays, not None: every combination of the options
    (and the robot or none) runs one compiled variant of the kernel per image dtype (each
    variant is a compilation on a fresh clone's empty cache)."""
    import numba

    cam = _cam()
    depth = _random_depth(rng, *cam.shape).astype(np.float32)
    robot = np.zeros(cam.shape, np.float32)
    robot[30:70, 50:100] = 2.0
    ws = DistanceWorkspace(cam)
    for rd in (None, robot):
        for n_sil in (0, 2):
            for n_gap in (0, 2):
                ws.set_depth(depth, rd, silhouette_px=n_sil, gap_px=n_gap)
    f32 = numba.typeof(depth)
    sigs = [s for s in DK.obstacle_start_depth.signatures if s[0] == f32 and s[1] == f32]
    assert len(sigs) == 1, sigs
    for s in DK.obstacle_start_depth.signatures:              # never None nor an omitted argument
        assert all(isinstance(t, numba.types.Array) for t in s[9:]), s


def test_gap_px_zero_is_todays_state(rng):
    cam = _cam()
    depth = _random_depth(rng, *cam.shape)
    a, b = DistanceWorkspace(cam), DistanceWorkspace(cam)
    a.set_depth(depth)
    b.set_depth(depth, gap_px=0)
    np.testing.assert_array_equal(a.d0, b.d0)
    d0 = np.empty(cam.shape)
    DK.obstacle_start_depth(depth, a._no_robot, False, cam.min_range, cam.max_range, DK.INVALID_UNKNOWN,
                            DK.ROBOT_DROP, 0.03, d0, DK.NO_SILHOUETTE[a._no_robot.dtype], DK.NO_GAP)
    np.testing.assert_array_equal(a.d0, d0)
    # the rule only frees space: every start depth with gap_px = 3 is >= the one with 0
    c = DistanceWorkspace(cam)
    c.set_depth(depth, gap_px=3)
    assert np.all(c.d0 >= a.d0)
    with pytest.raises(ValueError, match="gap_px"):
        c.set_depth(depth, gap_px=-1)


# ------------------------------------------------------------------ beyond the rated range
def _kinect():
    intr = intrinsics_for("kinect_v1")
    return dg.Camera(id="k", world_from_camera=look_at(np.zeros(3), np.array([0.0, 0.0, 2.0]),
                                                        np.array([0.0, -1.0, 0.0])),
                     sensor="kinect_v1", **intr)


def test_wall_at_5m_seen_by_a_kinect_single_camera():
    """A wall at 5 m (beyond the Kinect's rated 4 m, within its ~8 m of returns): the rays
    are free up to 4 m, unknown behind. Points between the camera and 4 m - rho see nothing;
    a point at 3.8 m sees the unknown 0.2 m ahead; a point at 4.5 m lies in unknown space
    (distance 0, not observed). With invalid="free" nothing at all."""
    cam = _kinect()
    assert cam.max_range == 4.0
    wall = Box(size=(40, 40, 0.1), world_from_local=np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 5.05],
                                                               [0, 0, 0, 1]], float))
    ideal = render_depth(cam, [wall.mesh()])
    measured = SimulatedCamera(cam, seed=1).measure(ideal, stamp=0.0)
    assert (measured > cam.max_range).mean() > 0.99          # returns beyond the rated range
    u = np.array([100.0, 319.5, 500.0])
    v = np.array([80.0, 239.5, 400.0])
    for depth in (ideal, measured):
        pts = {z: _on_ray(cam, u, v, z) for z in (0.5, 1.0, 2.0, 3.0, 3.55, 3.8, 4.5)}
        for z in (0.5, 1.0, 2.0, 3.0, 3.55):
            r = depth_space_distance(cam, depth, pts[z], rho=0.4, method="min", invalid="unknown")
            assert np.all(np.isinf(r.distance)), (z, r.distance)     # free up to 4 m
            assert np.all(r.observed)
        r = depth_space_distance(cam, depth, pts[3.8], rho=0.4, method="min", invalid="unknown")
        np.testing.assert_allclose(r.distance, 0.2, atol=1e-3)      # the unknown starts at 4 m (R3-R5: >= exact)
        r = depth_space_distance(cam, depth, pts[4.5], rho=0.4, method="min", invalid="unknown")
        assert np.all(r.distance == 0) and not r.observed.any()     # in unknown space, unjudged
        for z in (1.0, 3.8, 4.5):
            f = depth_space_distance(cam, depth, pts[z], rho=0.4, method="min", invalid="free")
            assert np.all(np.isinf(f.distance))
    # the same wall with the old meaning (no return: 0) is unknown from min_range on
    none = np.zeros_like(ideal)
    r = depth_space_distance(cam, none, _on_ray(cam, u, v, 2.0), rho=0.4, method="min", invalid="unknown")
    assert np.all(r.distance == 0)


def test_an_image_in_millimetres_is_no_return_not_free_space():
    """A wall 2 m away written in millimetres (2000.0 read as metres): far beyond any sensor's
    returns (RETURN_LIMIT_FACTOR x max_range), so no return — unknown from the near range —
    never "free up to max_range". A point 1 m in front of the camera is in unknown space,
    with one camera and in the depth grid."""
    from depthguard.camera import RETURN_LIMIT_FACTOR

    cam = _kinect()
    wall = Box(size=(40, 40, 0.1), world_from_local=np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 2.05],
                                                               [0, 0, 0, 1]], float))
    metres = render_depth(cam, [wall.mesh()])
    millimetres = (metres * 1000.0).astype(np.float32)
    assert millimetres.min() > RETURN_LIMIT_FACTOR * cam.max_range
    pts = _on_ray(cam, np.array([319.5]), np.array([239.5]), 1.0)
    ok = depth_space_distance(cam, metres, pts, rho=0.4, method="min", invalid="unknown")
    assert np.isinf(ok.distance[0]) and ok.observed[0]                       # control: metres are free
    bad = depth_space_distance(cam, millimetres, pts, rho=0.4, method="min", invalid="unknown")
    assert bad.distance[0] == 0.0                                             # unknown, an obstacle
    g = DepthGridMap([cam], principal=cam.id, d_min=0.5, d_max=3.5, delta_d=0.01, cache=False)
    assert np.isinf(g.distance({cam.id: metres}, pts, rho=0.4, method="min").distance[0])
    assert g.distance({cam.id: millimetres}, pts, rho=0.4, method="min").distance[0] < 0.02


def test_wall_at_5m_in_the_depth_grid():
    """The same in the depth grid (one camera, grid to 4.6 m): free cells up to 4 m; a cell
    from 4 m on is an obstacle (unknown, nobody to clear it); invalid="free": nothing."""
    cam = _kinect()
    depth = np.full(cam.shape, 5.0, np.float32)
    grid = DepthGridMap([cam], cam.id, 0.5, 4.6, 0.02, cache=False)
    u = np.array([100.0, 319.5, 500.0])
    v = np.array([80.0, 239.5, 400.0])
    for z in (1.0, 2.0, 3.5):
        r = grid.distance({cam.id: depth}, _on_ray(cam, u, v, z), rho=0.4, method="min")
        assert np.all(np.isinf(r.distance)), (z, r.distance)
    r = grid.distance({cam.id: depth}, _on_ray(cam, u, v, 3.8), rho=0.4, method="min")
    np.testing.assert_allclose(r.distance, 0.2, atol=0.021)         # slice boundary at 4.0 (+- a cell)
    r = grid.distance({cam.id: depth}, _on_ray(cam, u, v, 4.3), rho=0.4, method="min")
    assert np.all(r.distance < 0.03)
    f = grid.distance({cam.id: depth}, _on_ray(cam, u, v, 3.8), rho=0.4, method="min", invalid="free")
    assert np.all(np.isinf(f.distance))


def test_beyond_range_in_another_camera_clears_cells_in_front_of_max_range():
    """The principal's invalid pixels (unknown from min_range) are cleared by a second camera
    whose returns lie beyond its rated range: it has seen the space free up to max_range."""
    c0 = _cam("c0", rmax=4.0)
    c1 = dg.Camera(id="c1", width=160, height=120, fx=130.0, fy=130.0, cx=79.5, cy=59.5,
                   world_from_camera=look_at(np.array([1.5, 0.0, 0.0]), np.array([0.0, 0.0, 2.0]),
                                             np.array([0.0, -1.0, 0.0])),
                   min_range=0.4, max_range=4.0)
    grid = DepthGridMap([c0, c1], "c0", 0.5, 4.0, 0.02, cache=False)
    P = _on_ray(c0, [79.5], [59.5], 1.5)
    d0 = np.zeros(c0.shape, np.float32)                      # principal: nothing (dark, or no return)
    far = np.full(c1.shape, 6.0, np.float32)                 # c1: returns beyond its rated range
    none = np.zeros(c1.shape, np.float32)
    r_far = grid.distance({"c0": d0, "c1": far}, P, rho=0.4, method="min")
    r_none = grid.distance({"c0": d0, "c1": none}, P, rho=0.4, method="min")
    assert r_none.distance[0] < 0.03                         # nobody clears: unknown around P
    assert r_far.distance[0] > 0.1                           # c1 has seen the space around P free


# ------------------------------------------------------------------ the small-gap rule
def _wall_with_gap(cam, gap_cols, z=2.0):
    depth = np.full(cam.shape, z, np.float32)
    depth[:, gap_cols] = 0.0
    return depth


@pytest.mark.parametrize("gap_px", [2, 3])
def test_two_pixel_gap_in_a_flat_wall(gap_px):
    """A 2-px gap (two invalid columns) in a flat wall at 2 m: with gap_px >= 2 the gap's
    rays are unknown from the wall's depth (2 m), not from min_range: a point 1 m in front
    of the wall on those rays sees nothing within rho; with gap_px = 0 it is in unknown space."""
    cam = _cam()
    depth = _wall_with_gap(cam, [80, 81])
    P = _on_ray(cam, [80.0, 81.0, 80.0], [20.0, 60.0, 100.0], 1.0)
    P_near = _on_ray(cam, [80.0], [60.0], 1.8)
    for mode in ("drop", "shadow"):
        off = depth_space_distance(cam, depth, P, rho=0.4, method="min", robot_mode=mode)
        on = depth_space_distance(cam, depth, P, rho=0.4, method="min", robot_mode=mode, gap_px=gap_px)
        assert np.all(off.distance == 0)
        assert np.all(np.isinf(on.distance))
        near = depth_space_distance(cam, depth, P_near, rho=0.4, method="min", gap_px=gap_px)
        np.testing.assert_allclose(near.distance, 0.2, atol=1e-4)       # the wall (and the gap) at 2 m
        f = depth_space_distance(cam, depth, P, rho=0.4, method="min", invalid="free", gap_px=gap_px)
        assert np.all(np.isinf(f.distance))
    grid = DepthGridMap([cam], cam.id, 0.5, 3.0, 0.02, cache=False)
    g_off = grid.distance({cam.id: depth}, P, rho=0.4, method="min")
    g_on = grid.distance({cam.id: depth}, P, rho=0.4, method="min", gap_px=gap_px)
    assert np.all(g_off.distance < 0.03) and np.all(np.isinf(g_on.distance))
    free, kind = ref.frame_state_numpy(cam, depth, gap_px=gap_px)
    assert np.all(free[:, 80:82] == 2.0) and np.all(kind[:, 80:82] == depth_grid_kernels.KIND_UNKNOWN)


def test_ten_pixel_gap_stays_unknown_from_min_range():
    """A 10-px gap (a dark object ~15 cm wide at 2 m) is no small gap: its rays stay unknown
    from min_range (R28), with any gap_px up to 9."""
    cam = _cam()
    depth = _wall_with_gap(cam, list(range(75, 85)))
    P = _on_ray(cam, [75.0, 79.0, 84.0], [60.0, 60.0, 60.0], 1.0)
    for gap_px in (0, 2, 3, 9):
        r = depth_space_distance(cam, depth, P, rho=0.4, method="min", gap_px=gap_px)
        assert np.all(r.distance == 0), gap_px
    free, _ = ref.frame_state_numpy(cam, depth, gap_px=3)
    assert np.all(free[:, 75:85] == cam.min_range)
    grid = DepthGridMap([cam], cam.id, 0.5, 3.0, 0.02, cache=False)
    assert np.all(grid.distance({cam.id: depth}, P, rho=0.4, method="min", gap_px=3).distance < 0.03)


def test_gap_between_near_and_far_takes_the_near_end():
    """Edge dropout between a box at 1.5 m and the wall at 2.5 m: the gap is free up to 1.5 m
    (the nearer end), unknown behind it: a point at 1.6 m on the gap's ray reads 0."""
    cam = _cam()
    depth = np.full(cam.shape, 2.5, np.float32)
    depth[:, :80] = 1.5
    depth[:, 80:82] = 0.0
    on_gap = _on_ray(cam, [80.0, 81.0], [60.0, 60.0], 1.6)
    r = depth_space_distance(cam, depth, on_gap, rho=0.4, method="min", gap_px=2)
    assert np.all(r.distance == 0)
    before = _on_ray(cam, [80.0, 81.0], [60.0, 60.0], 1.0)
    r = depth_space_distance(cam, depth, before, rho=0.4, method="min", gap_px=2)
    assert np.all(r.distance > 0.4 - 1e-9) or np.all(np.isinf(r.distance))


def test_grid_set_frames_reloads_when_gap_px_changes():
    cam = _cam()
    depth = _wall_with_gap(cam, [80, 81])
    P = _on_ray(cam, [80.0], [60.0], 1.0)
    grid = DepthGridMap([cam], cam.id, 0.5, 3.0, 0.02, cache=False)
    grid.set_frames({cam.id: depth}, gap_px=2)
    on = grid.query(P, rho=0.4, method="min").distance.copy()
    grid.set_frames({cam.id: depth}, gap_px=0, changed=[])
    off = grid.query(P, rho=0.4, method="min").distance.copy()
    assert np.isinf(on[0]) and off[0] < 0.03
    with pytest.raises(ValueError, match="gap_px"):
        grid.set_frames({cam.id: depth}, gap_px=1.0)
