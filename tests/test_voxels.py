"""Per-camera voxel filter (R17–R19) and multi-camera voting on synthetic images.

Truth: the plain-numpy twins (which back-project through Camera.depth_to_points),
analytic planes, and hand-built voting scenes.
"""

import math

import numpy as np
import pytest

from depthguard.camera import Camera
from depthguard.fusion import voxel_kernels
from depthguard.fusion.voxels import (FilterOffset, VoxelFilter, VoxelSet, pack_keys, regrid, union,
                                      unpack_keys, vote)
from depthguard.transforms import look_at, pose


def _cam(cid="c0", w=64, h=48, eye=(1.5, 0.2, 1.2), target=(0.0, 0.0, 0.5), f=60.0):
    return Camera(cid, w, h, f, f, (w - 1) / 2, (h - 1) / 2, world_from_camera=look_at(eye, target),
                  min_range=0.2, max_range=5.0)


def _sorted(keys, counts):
    keys = np.asarray(keys, dtype=np.int64)
    o = np.lexsort(keys.T[::-1])
    return keys[o], np.asarray(counts)[o]


def _random_images(rng, cam):
    H, W = cam.shape
    depth = rng.uniform(0.5, 3.0, (H, W)).astype(np.float32)
    # smooth patches so that voxels collect several points
    depth = np.repeat(np.repeat(depth[::8, ::8], 8, 0), 8, 1)[:H, :W].copy()
    depth += rng.normal(0, 0.01, depth.shape).astype(np.float32)
    expected = (depth + rng.uniform(-0.3, 0.3, depth.shape)).astype(np.float32)
    expected[rng.random(depth.shape) < 0.2] = 0.0
    depth[rng.random(depth.shape) < 0.05] = 0.0
    depth[rng.random(depth.shape) < 0.02] = np.nan
    depth[rng.random(depth.shape) < 0.02] = 7.0          # beyond max_range
    return depth, expected


@pytest.mark.parametrize("s,thr", [(0.01, 0.0), (0.02, 0.55), (0.05, 0.3), (0.1, 0.55)])
def test_kernel_matches_numpy_twin(rng, s, thr):
    cam = _cam()
    lo, hi = np.array([-1.0, -1.0, 0.0]), np.array([1.0, 1.0, 1.5])
    f = VoxelFilter(cam, (lo, hi), voxel_size=s, threshold=thr, offset=FilterOffset(0.02, 0.004))
    for _ in range(3):
        depth, expected = _random_images(rng, cam)
        got = f.filter(depth, expected=expected)
        ref_k, ref_c = voxel_kernels.filter_voxelize_numpy(cam, depth, expected, 0.02, 0.004, lo, hi, s, thr)
        gk, gc = _sorted(got.keys, got.counts)
        assert len(ref_k) > 0 or thr > 0
        np.testing.assert_array_equal(gk, ref_k)
        np.testing.assert_array_equal(gc, ref_c)
        keep = voxel_kernels.keep_mask_numpy(cam, depth, expected, 0.02, 0.004)
        assert got.n_kept == int(keep.sum())
        valid = np.isfinite(depth) & (depth >= cam.min_range) & (depth <= cam.max_range)
        assert got.n_invalid == int((~valid).sum())
    # the count grid is left clean: a second identical call gives the same answer
    a = f.filter(depth, expected=expected)
    b = f.filter(depth, expected=expected)
    np.testing.assert_array_equal(a.keys, b.keys)
    np.testing.assert_array_equal(a.counts, b.counts)


def test_fused_robot_depth_matches_combined_expected(rng):
    """The kernel's fused 'nearer of static and robot' equals the twin on the combined image."""
    cam = _cam()
    lo, hi = np.array([-1.0, -1.0, 0.0]), np.array([1.0, 1.0, 1.5])
    f = VoxelFilter(cam, (lo, hi), voxel_size=0.02, threshold=0.2, offset=FilterOffset(0.02, 0.004))
    depth, static = _random_images(rng, cam)
    robot = (depth + rng.uniform(-0.3, 0.3, depth.shape)).astype(np.float32)
    robot[rng.random(depth.shape) < 0.5] = 0.0
    n, n_kept, _ = voxel_kernels.filter_voxelize(
        depth, static, robot, cam.fx, cam.fy, cam.cx, cam.cy, f._Rwc, f._twc, cam.min_range, cam.max_range,
        0.02, 0.004, f._key_lo, f._dims, 0.02, lo, hi, f._cam_pos, f._ang_u, f._ang_v, 0.2,
        f._grid, f._touched, f._out_keys, f._out_counts)
    comb = voxel_kernels.combine_expected_numpy(static, robot)
    ref_k, ref_c = voxel_kernels.filter_voxelize_numpy(cam, depth, comb, 0.02, 0.004, lo, hi, 0.02, 0.2)
    gk, gc = _sorted(f._out_keys[:n], f._out_counts[:n])
    np.testing.assert_array_equal(gk, ref_k)
    np.testing.assert_array_equal(gc, ref_c)
    assert n_kept == int(voxel_kernels.keep_mask_numpy(cam, depth, comb, 0.02, 0.004).sum())
    # the combination rule itself, pixel by pixel
    st, rb = np.float32([0, 2, 2, 0, 3]), np.float32([0, 0, 1, 1, 4])
    np.testing.assert_array_equal(voxel_kernels.combine_expected_numpy(st, rb), [0, 2, 1, 1, 3])


def test_keep_rule_offset_grows_with_depth():
    """R17: kept iff d < e - (c + k e^2); where e == 0 any valid d is kept."""
    cam = Camera("c", 8, 1, 10.0, 10.0, 3.5, 0.0, world_from_camera=np.eye(4), min_range=0.2, max_range=8.0)
    off = FilterOffset(0.02, 0.01)
    e = np.array([[1.0, 1.0, 4.0, 4.0, 0.0, 2.0, 2.0, 0.0]], dtype=np.float32)
    # offsets: e=1 -> 0.03, e=4 -> 0.18, e=2 -> 0.06
    d = np.array([[0.96, 0.98, 3.80, 3.85, 3.0, 2.5, 0.0, np.nan]], dtype=np.float32)
    keep = voxel_kernels.keep_mask_numpy(cam, d, e, off.const, off.k)
    np.testing.assert_array_equal(keep[0], [True, False, True, False, True, False, False, False])
    f = VoxelFilter(cam, ([-10, -10, 0], [10, 10, 10]), voxel_size=0.1, threshold=0.0, offset=off)
    vs = f.filter(d, expected=e)
    assert vs.n_kept == 3 and vs.n_invalid == 2


def test_plane_voxels_and_density_noise_filter():
    """A fronto-parallel wall fills its voxels (count ~ n_max, kept at 0.55); isolated
    single-pixel specks in front of it hold ~1/n_max and are removed (R19)."""
    w, h, fpx = 320, 240, 300.0
    cam = Camera("c", w, h, fpx, fpx, (w - 1) / 2, (h - 1) / 2, world_from_camera=pose(None, [0, 0, 0]),
                 min_range=0.2, max_range=6.0)
    s = 0.05
    depth = np.full(cam.shape, 1.5, dtype=np.float32)
    rng = np.random.default_rng(1)
    vs_, us_ = rng.integers(20, h - 20, 30), rng.integers(20, w - 20, 30)
    depth[vs_, us_] = 0.75                                 # specks, half-way
    lo, hi = np.array([-3.0, -3.0, 0.1]), np.array([3.0, 3.0, 3.0])
    f = VoxelFilter(cam, (lo, hi), voxel_size=s, threshold=0.55, offset=FilterOffset(0.02, 0.0))
    out = f.filter(depth, expected=np.zeros(cam.shape, np.float32))
    z = out.keys[:, 2]
    assert set(np.unique(z)) == {int(math.floor(1.5 / s))}         # only the wall's layer survives
    # interior wall voxels hold about n_max points: (s f / d)^2 = 100 at 1.5 m
    nmax = voxel_kernels.density_max_count(cam, out.keys, s)
    interior = out.counts >= 0.9 * nmax
    assert interior.sum() > 0.5 * len(out)
    # the wall's voxel footprint: x range covered by the image at 1.5 m
    half_x = 1.5 * (w / 2) / fpx
    assert out.keys[:, 0].min() >= math.floor(-half_x / s) and out.keys[:, 0].max() <= math.floor(half_x / s)
    # with threshold 0 the specks come back as voxels in front of the wall
    f.configure(threshold=0.0)
    loose = f.filter(depth, expected=np.zeros(cam.shape, np.float32))
    assert np.any(loose.keys[:, 2] < int(math.floor(1.5 / s)))


def test_crop_and_settings_change(rng):
    cam = _cam()
    lo, hi = np.array([-0.2, -0.3, 0.4]), np.array([0.3, 0.2, 0.9])
    f = VoxelFilter(cam, (lo, hi), voxel_size=0.02, threshold=0.0)
    depth, expected = _random_images(rng, cam)
    expected[:] = 0
    for s in (0.02, 0.07, 0.01):
        f.configure(voxel_size=s)
        vs = f.filter(depth, expected=expected)
        assert vs.voxel_size == s
        assert np.all(vs.keys >= np.floor(lo / s)) and np.all(vs.keys <= np.floor(hi / s))
        # every voxel really holds kept points inside the box (numpy truth)
        p = cam.depth_to_points(depth)
        p = p[np.all((p >= lo) & (p < hi), axis=1)]
        truth = np.unique(np.floor(p / s).astype(np.int64), axis=0)
        np.testing.assert_array_equal(_sorted(vs.keys, vs.counts)[0], truth)
    for bad in (0.005, 0.2, float("nan")):
        with pytest.raises(ValueError, match="voxel size"):
            f.configure(voxel_size=bad)
    with pytest.raises(ValueError, match="threshold"):
        f.configure(threshold=1.5)
    with pytest.raises(ValueError, match="shape"):
        f.filter(np.zeros((3, 3), np.float32), expected=expected)


@pytest.mark.parametrize("footprint", [False, True])
def test_vote_kernel_matches_twin(rng, footprint):
    cams = [_cam("a"), _cam("b", eye=(-1.4, 0.5, 1.3)), _cam("c", eye=(0.2, -1.6, 1.0))]
    depths = [_random_images(rng, c)[0] for c in cams]
    for d in depths:                                   # a far background most voxels are in front of
        d[(d > 0) & (rng.random(d.shape) < 0.7)] = 4.0
    s = 0.04
    lows = rng.integers(-20, 20, (500, 3)) * s + np.array([0, 0, 0.8])
    margin = rng.uniform(0.0, 0.1, 500)
    table = np.stack([[c.fx, c.fy, c.cx, c.cy, c.width, c.height, c.min_range, c.max_range,
                       *c.R.reshape(-1), *c.t] for c in cams])
    stack = np.stack([np.nan_to_num(d, nan=0.0) for d in depths])
    out = np.zeros((500, 3), bool)
    voxel_kernels.vote_free(lows, s, stack, table, margin, footprint, out)
    ref = voxel_kernels.vote_free_numpy(cams, depths, lows, s, margin, footprint)
    np.testing.assert_array_equal(out, ref)
    assert 0 < out.sum() < out.size


def test_vote_drops_voxel_two_cameras_see_through():
    """Camera a reports two voxels; b and c look at a far wall through the first one,
    while the second one sits on b's and c's measured surfaces (not free) — it stays."""
    s = 0.05
    a = _cam("a", eye=(0.0, -2.0, 0.5), target=(0, 0, 0.5))
    b = _cam("b", eye=(2.0, 0.0, 0.5), target=(0, 0, 0.5))
    c = _cam("c", eye=(-2.0, 0.0, 0.5), target=(0, 0, 0.5))
    ghost, real = np.array([[0, 0, 10]]), np.array([[0, 10, 10]])   # centres (0.025, .025/.525, .525)
    vs = VoxelSet(np.concatenate([ghost, real]).astype(np.int32), np.array([50, 50], np.int32), s)
    depths = {}
    real_c = (real[0] + 0.5) * s
    for cam in (b, c):
        d = np.full(cam.shape, 4.5, np.float32)                      # far wall: the ghost is free
        px, py, dp = cam.world_to_depth_space(real_c)[0]
        u, v = int(math.floor(px + 0.5)), int(math.floor(py + 0.5))
        d[max(v - 3, 0):v + 4, max(u - 3, 0):u + 4] = dp             # b, c see the real object
        depths[cam.id] = d
    for rule in ("footprint", "centre"):
        out = vote({"a": vs}, [a, b, c], depths, min_free=2, offset=FilterOffset(0.02, 0.0), rule=rule)
        np.testing.assert_array_equal(out["a"].keys, real.astype(np.int32))
    # with only one other camera seeing through, the ghost stays (needs two)
    out1 = vote({"a": vs}, [a, b, c], {"b": depths["b"]}, min_free=2)
    assert len(out1["a"]) == 2
    with pytest.raises(ValueError, match="unknown cameras"):
        vote({"zz": vs}, [a, b], depths)


def test_regrid_is_conservative(rng):
    keys = rng.integers(-30, 30, (40, 3))
    for s_old, s_new in ((0.02, 0.05), (0.05, 0.02), (0.03, 0.03), (0.1, 0.01)):
        new = regrid(keys, s_old, s_new)
        newset = set(map(tuple, new.tolist()))
        pts = (keys[:, None, :] + rng.uniform(0, 1, (40, 50, 3))) * s_old
        for p in pts.reshape(-1, 3):
            assert tuple(np.floor(p / s_new).astype(int)) in newset
        # and not wasteful: each new voxel overlaps an old one
        lo_new, hi_new = new * s_new, (new + 1) * s_new
        ov = np.all((lo_new[:, None] < (keys[None] + 1) * s_old - 1e-12) &
                    (hi_new[:, None] > keys[None] * s_old + 1e-12), axis=2).any(axis=1)
        assert ov.all()


def test_pack_roundtrip_and_union(rng):
    keys = rng.integers(-(1 << 20), (1 << 20), (100, 3))
    np.testing.assert_array_equal(unpack_keys(pack_keys(keys)), keys)
    with pytest.raises(ValueError):
        pack_keys(np.array([[1 << 20, 0, 0]]))
    a = VoxelSet(np.array([[0, 0, 0], [1, 0, 0]], np.int32), np.ones(2, np.int32), 0.02)
    b = VoxelSet(np.array([[1, 0, 0], [2, 0, 0]], np.int32), np.ones(2, np.int32), 0.02)
    np.testing.assert_array_equal(union([a, b], 0.02), [[0, 0, 0], [1, 0, 0], [2, 0, 0]])
