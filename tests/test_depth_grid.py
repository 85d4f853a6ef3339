"""Depth grid map (SPEC §3, R10–R12): kernels vs numpy twins, compact vs explicit map,
cache, errors, robot volume, several principals, and the safety property on random scenes."""

from __future__ import annotations

import numpy as np
import pytest

import depthguard as dg
from depthguard.fusion import depth_grid_capsules, depth_grid_kernels
from depthguard.fusion import depth_grid_ref as ref
from depthguard.fusion.depth_grid import DepthGridMap
from depthguard.fusion.depth_grid_multi import MultiPrincipalDepthGrid
from depthguard.geometry.primitives import Box, Capsule, Sphere, sdf_union
from depthguard.render import render_depth
from depthguard.transforms import look_at

W, H, F = 160, 120, 130.0


def _cam(name, eye, target=(0, 0, 0), w=W, h=H, f=F):
    return dg.Camera(id=name, width=w, height=h, fx=f, fy=f, cx=(w - 1) / 2, cy=(h - 1) / 2,
                     world_from_camera=look_at(np.asarray(eye, float), np.asarray(target, float)),
                     min_range=0.3, max_range=8.0)


def _T(x, y, z):
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T


def _room():
    """Walls, floor and ceiling of a 7 x 7 x 4 m room (so that every ray sees something)."""
    return [Box(size=(7, 7, 0.1), world_from_local=_T(0, 0, -1.05)),
            Box(size=(7, 7, 0.1), world_from_local=_T(0, 0, 3.0)),
            Box(size=(0.1, 7, 4.2), world_from_local=_T(3.5, 0, 1)),
            Box(size=(0.1, 7, 4.2), world_from_local=_T(-3.5, 0, 1)),
            Box(size=(7, 0.1, 4.2), world_from_local=_T(0, 3.5, 1)),
            Box(size=(7, 0.1, 4.2), world_from_local=_T(0, -3.5, 1))]


def _scene(rng, n_cams):
    prims = _room()
    for _ in range(rng.integers(2, 5)):
        c = rng.uniform(-0.7, 0.7, 3)
        if rng.random() < 0.5:
            prims.append(Box(size=tuple(rng.uniform(0.1, 0.4, 3)), world_from_local=_T(*c)))
        else:
            prims.append(Sphere(radius=float(rng.uniform(0.08, 0.2)), world_from_local=_T(*c)))
    az0 = rng.uniform(0, 2 * np.pi)
    cams = []
    for k in range(n_cams):
        az = az0 + 2 * np.pi * k / n_cams + rng.uniform(-0.4, 0.4)
        r = rng.uniform(2.4, 2.9)
        eye = (r * np.cos(az), r * np.sin(az), rng.uniform(0.6, 1.8))
        cams.append(_cam(f"c{k}", eye, rng.uniform(-0.15, 0.15, 3)))
    meshes = [p.mesh() for p in prims]
    depths = {c.id: render_depth(c, meshes) for c in cams}
    return prims, cams, depths


def _eps(cam, points, rho, delta_d):
    """Discretisation bound (R25): two pixel-footprint diagonals (the sampled surface
    can sit a pixel away from the true nearest point, and the reported point is a
    frustum point of its pixel) plus one cell diagonal, at depth dp + rho."""
    d = cam.world_to_camera(points)[:, 2] + rho
    pix = d * np.hypot(1 / cam.fx, 1 / cam.fy)
    return 2 * pix + np.sqrt(pix ** 2 + delta_d ** 2)


def _with_robot(prims, cams):
    """A "robot" of two capsule links through joints ``a, b, c``, rendered into every camera
    with the scene (``depths``) and alone (``rdepths``, for R9 removal), and its padded
    volume ``caps`` (R12)."""
    a, b, c = np.array([-0.3, 0.5, -0.4]), np.array([0.2, 0.4, 0.5]), np.array([0.6, -0.1, 0.6])
    links = [Capsule.between(a, b, 0.08), Capsule.between(b, c, 0.06)]
    rdepths = {cam.id: render_depth(cam, [lk.mesh() for lk in links]) for cam in cams}
    depths = {cam.id: render_depth(cam, [p.mesh() for p in prims] + [lk.mesh() for lk in links])
              for cam in cams}
    return a, b, c, depths, rdepths, [Capsule.between(a, b, 0.12), Capsule.between(b, c, 0.1)]


def _twin(grid, depths, points, rho, method, robot_depths=None, capsules=None, invalid="unknown"):
    rd = robot_depths or {}
    pf, pk = ref.frame_state_numpy(grid.principal, depths[grid.principal.id], rd.get(grid.principal.id),
                                   invalid=invalid)
    kf = [ref.frame_state_numpy(c, depths[c.id], rd.get(c.id), invalid=invalid)[0] for c in grid.others]
    return ref.grid_distances_numpy(grid.principal, grid.others, pf, pk, kf, grid.d_min, grid.delta_d,
                                    grid.n_d, points, rho, method, capsules)


# ------------------------------------------------------------------ kernels vs twins
def test_frame_state_equals_twin(rng):
    cam = _cam("c0", (2.5, 0, 1))
    depth = rng.uniform(0.1, 9.0, cam.shape).astype(np.float32)
    depth[rng.random(cam.shape) < 0.1] = 0.0
    depth[rng.random(cam.shape) < 0.05] = np.nan
    robot = np.where(rng.random(cam.shape) < 0.3, rng.uniform(0.5, 6, cam.shape), 0).astype(np.float32)
    for inv, rf in (("unknown", False), ("free", True)):
        free = np.empty(cam.shape)
        kind = np.empty(cam.shape, dtype=np.int8)
        depth_grid_kernels.frame_state(depth, robot, True, cam.min_range, cam.max_range, 0.03, inv == "free", rf, free, kind,
                                         None, None)
        f2, k2 = ref.frame_state_numpy(cam, depth, robot, 0.03, inv, rf)
        np.testing.assert_array_equal(free, f2)
        np.testing.assert_array_equal(kind, k2)


@pytest.mark.parametrize("method,seed,n_cams", [("min", 7, 3), ("mean", 7, 3), ("hybrid", 7, 3),
                                                 ("hybrid", 8, 2), ("min", 9, 2)])
def test_grid_kernel_equals_numpy_twin(method, seed, n_cams):
    """The kernels (per-frame obstacle runs with pyramid shortcuts and capsule
    intervals, per-cycle run lookup) give exactly the twin's answer (every cell
    classified at once, no shortcut)."""
    rng = np.random.default_rng(seed)
    prims, cams, depths = _scene(rng, n_cams)
    a, b, c, depths, rdepths, caps = _with_robot(prims, cams)
    grid = DepthGridMap(cams, "c0", 1.0, 4.6, 0.03, cache=False)
    P = np.vstack([rng.uniform(-0.8, 0.8, (10, 3)), (a + b) / 2, b, (b + c) / 2, c])
    res = grid.distance(depths, P, 0.4, method, rdepths, robot_capsules=caps)
    d, v, o, c = _twin(grid, depths, P, 0.4, method, rdepths, caps)
    np.testing.assert_allclose(res.distance, d, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(res.count, c)
    np.testing.assert_array_equal(res.observed, o)
    ok = np.isfinite(d) & (d > 1e-6)
    np.testing.assert_allclose(res.direction[ok], v[ok], atol=1e-7)
    assert np.isfinite(d).sum() >= 5           # the comparison is not vacuous


def test_reach_band_gives_the_same_answers():
    """Restricting the per-frame work to a box holding the rho-balls changes nothing for
    points inside it; gray cells outside it count as obstacles (safe)."""
    rng = np.random.default_rng(11)
    prims, cams, depths = _scene(rng, 2)
    grid = DepthGridMap(cams, "c0", 1.0, 4.6, 0.03, cache=False)
    P = rng.uniform(-0.7, 0.7, (16, 3))
    full = grid.distance(depths, P, 0.4, "hybrid")
    box = (P.min(0) - 0.45, P.max(0) + 0.45)
    part = grid.distance(depths, P, 0.4, "hybrid", reach=box)
    np.testing.assert_array_equal(full.distance, part.distance)
    np.testing.assert_array_equal(full.direction, part.direction)
    assert np.isfinite(full.distance).sum() >= 3
    # the reach as capsules (spheres around the points, radius rho + a margin)
    spheres = (np.repeat(P[:, None, :], 2, axis=1), np.full(len(P), 0.42))
    part2 = grid.distance(depths, P, 0.4, "hybrid", reach=spheres)
    np.testing.assert_array_equal(full.distance, part2.distance)
    np.testing.assert_array_equal(full.direction, part2.direction)
    far = grid.distance(depths, P, 0.4, "hybrid", reach=(np.full(3, 5.0), np.full(3, 6.0)))
    assert np.all(far.distance <= full.distance)


def test_capsule_intervals_match_centre_test(rng):
    """Per-pixel capsule intervals (analytic ray-capsule) agree with ``Capsule.sdf`` at the
    cells' centres (R12: a cell whose centre is in the padded volume is never an obstacle),
    on random capsules, including cells that straddle the surface."""
    cam = _cam("c0", (2.5, 0, 1), w=40, h=30, f=32.0)
    dd = 0.02
    g = np.arange(int(1.5 / dd), int(3.8 / dd))
    tested = straddling = 0
    for _ in range(4):
        a0, b0 = rng.uniform(-0.3, 0.3, 3), rng.uniform(-0.3, 0.3, 3)
        cap = Capsule.between(a0, b0, rng.uniform(0.1, 0.3))
        a, b = cap.segment()
        caps = np.r_[a, b, cap.radius][None]
        cc = np.concatenate([caps[:, :3] @ cam.R.T + cam.t, caps[:, 3:6] @ cam.R.T + cam.t, caps[:, 6:]], 1)
        lo = np.zeros((30, 40, depth_grid_capsules.MAX_CAPS_PER_PIXEL))
        hi = np.zeros_like(lo)
        n = np.zeros((30, 40), dtype=np.int64)
        depth_grid_capsules.capsule_intervals(cc, 1, np.array([[0, 39, 0, 29]]), cam.fx, cam.fy, cam.cx, cam.cy, 30, 40, lo, hi, n,
                                              np.array([0, 29, 0, 39]))
        for v in range(0, 30, 2):
            for u in range(0, 40, 2):
                d1 = g * dd
                dm = d1 + dd / 2
                centres = cam.depth_space_to_world(np.stack([np.full_like(dm, u), np.full_like(dm, v), dm], 1))
                sd = cap.sdf(centres)
                inside = sd <= 0
                by_int = (n[v, u] >= 1) & (lo[v, u, 0] <= dm) & (dm <= hi[v, u, 0])
                sure = np.abs(sd) > 1e-9                      # not on the surface to rounding
                np.testing.assert_array_equal(inside[sure], by_int[sure])
                by_cell = np.array([depth_grid_capsules.cell_in_capsules(cc, 1, cam.fx, cam.fy, cam.cx, cam.cy, u, v, x, x + dd)
                                    for x in d1])
                np.testing.assert_array_equal(inside[sure], by_cell[sure])
                corners = ref.cell_corners_world(cam, u, v, d1, d1 + dd)
                csd = cap.sdf(corners.reshape(-1, 3)).reshape(-1, 8)
                straddling += int((inside & np.any(csd > 0, axis=1)).sum())
                tested += int(inside.sum())
    assert tested > 200 and straddling > 10


def test_capsule_intervals_keep_every_pixel(rng):
    """:func:`capsule_intervals` over its projected boxes leaves out only pixels whose ray misses
    the capsule: every pixel of the image gets exactly the interval the ray-capsule solution gives
    it alone (``_ray_capsule``, no box), for capsules near and far, off to the side, large and
    thin, spheres and one around the camera (R12). A box one pixel too narrow fails it."""
    cam = _cam("c0", (2.5, 0, 1), w=48, h=36, f=40.0)
    caps = [Capsule.between(rng.uniform(-0.6, 0.6, 3), rng.uniform(-0.6, 0.6, 3), rng.uniform(0.02, 0.4))
            for _ in range(8)]
    caps.append(Capsule.between(np.array([2.4, 0.0, 1.0]), np.array([2.6, 0.1, 1.0]), 0.3))   # the camera inside
    caps.append(Capsule.between(np.array([0.0, 2.0, 1.0]), np.array([0.5, 2.5, 2.0]), 0.2))   # near the edge
    for c in rng.uniform(-0.5, 0.5, (4, 3)):        # spheres
        caps.append(Capsule.between(c, c + 1e-9, rng.uniform(0.15, 0.5)))
    rows = []
    for c in caps:
        a, b = c.segment()
        rows.append(np.r_[a @ cam.R.T + cam.t, b @ cam.R.T + cam.t, c.radius])
    cc = np.ascontiguousarray(rows)
    nc = len(cc)
    boxes = np.zeros((nc, 4), dtype=np.int64)
    depth_grid_capsules.capsule_boxes(cc, nc, cam.fx, cam.fy, cam.cx, cam.cy, 36, 48, boxes)
    M = depth_grid_capsules.MAX_CAPS_PER_PIXEL
    lo, hi = np.zeros((36, 48, M)), np.zeros((36, 48, M))
    n = np.zeros((36, 48), dtype=np.int64)
    depth_grid_capsules.capsule_intervals(cc, nc, boxes, cam.fx, cam.fy, cam.cx, cam.cy, 36, 48, lo, hi, n,
                                          np.array([0, 35, 0, 47]))
    hits = 0
    for v in range(36):
        for u in range(48):
            want = [depth_grid_capsules._ray_capsule.py_func((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, cc[c])
                    for c in range(nc)]
            want = [w for w in want if w[0] <= w[1]]
            assert n[v, u] == min(len(want), M + 1), (u, v)
            k = min(len(want), M)
            np.testing.assert_array_equal(lo[v, u, :k], [w[0] for w in want[:k]])
            np.testing.assert_array_equal(hi[v, u, :k], [w[1] for w in want[:k]])
            hits += len(want)
    assert hits > 500


def test_capsule_intervals_in_turn_count_the_capsules_each_ray_meets(rng):
    """:func:`capsule_intervals` called again and again on the same buffers (a monitor's builds:
    only the last call's box is cleared) leaves every pixel's count the number of capsules its ray
    meets (the analytic ray-capsule solution, no box), while the robot moves from one side of the image to the other, leaves it and has no
    capsule in view; the box it keeps is the union of the call's boxes (R12)."""
    cam = _cam("c0", (2.5, 0, 1), w=48, h=36, f=40.0)
    M = depth_grid_capsules.MAX_CAPS_PER_PIXEL
    lo, hi = np.zeros((36, 48, M)), np.zeros((36, 48, M))
    n = np.zeros((36, 48), dtype=np.int64)
    written = np.array([0, 35, 0, 47])
    seen = set()
    for centre in ((-0.5, -0.4, 0.0), (0.5, 0.4, 0.2), (0.0, 0.0, 0.0), (0.0, 9.0, 0.0), (0.3, -0.5, 0.1)):
        c = np.array(centre)
        caps = [Capsule.between(c + rng.uniform(-0.2, 0.2, 3), c + rng.uniform(-0.2, 0.2, 3), rng.uniform(0.03, 0.15))
                for _ in range(3)]
        cc = np.ascontiguousarray([np.r_[k.segment()[0] @ cam.R.T + cam.t, k.segment()[1] @ cam.R.T + cam.t, k.radius]
                                   for k in caps])
        boxes = np.zeros((3, 4), dtype=np.int64)
        depth_grid_capsules.capsule_boxes(cc, 3, cam.fx, cam.fy, cam.cx, cam.cy, 36, 48, boxes)
        depth_grid_capsules.capsule_intervals(cc, 3, boxes, cam.fx, cam.fy, cam.cx, cam.cy, 36, 48, lo, hi, n, written)
        # every pixel's count is the number of capsules its ray meets (the ray-capsule solution
        # per pixel, no box): a count the last call left outside this call's boxes fails it
        want = np.array([[sum(1 for c in range(3) if (lambda w: w[0] <= w[1])(depth_grid_capsules._ray_capsule.py_func(
            (u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, cc[c]))) for u in range(48)] for v in range(36)])
        np.testing.assert_array_equal(n, np.minimum(want, M + 1))
        inside = (boxes[:, 0] <= boxes[:, 1]) & (boxes[:, 2] <= boxes[:, 3])
        if inside.any():
            b = boxes[inside]
            assert list(written) == [b[:, 2].min(), b[:, 3].max(), b[:, 0].min(), b[:, 1].max()]
        else:
            assert written[1] < written[0]
        seen.add(bool((n > 0).any()))
    assert seen == {True, False}


# ------------------------------------------------------------------ compact vs explicit map
def test_compact_map_equals_explicit_table():
    """R11: the on-the-fly footprint (corner rays in k) equals the explicit table built
    from sampled cell points projected with Camera.world_to_depth_space."""
    p = _cam("p", (2.5, -0.3, 1.0), w=16, h=12, f=13.0)
    k1 = _cam("k1", (0.2, 2.6, 1.3), w=20, h=15, f=16.0)
    k2 = _cam("k2", (-2.2, -1.0, 0.7), w=20, h=15, f=16.0)
    grid = DepthGridMap([p, k1, k2], "p", 1.2, 3.8, 0.25, cache=False)
    table = ref.explicit_map_numpy(p, [k1, k2], grid.d_min, grid.delta_d, grid.n_d)
    n_seen = 0
    for cam in (k1, k2):
        t = table[cam.id]
        i = 0
        for gy in range(12):
            for gx in range(16):
                for gd in range(grid.n_d):
                    pix, ds, de = grid.cell_pixels(cam.id, gx, gy, gd)
                    assert bool(t["seen"][gy, gx, gd]) == (len(pix) > 0)
                    if len(pix):
                        n_seen += 1
                        np.testing.assert_array_equal(pix, t["pixels"][i])
                        assert ds == pytest.approx(t["dstart"][gy, gx, gd], abs=1e-12)
                        assert de == pytest.approx(t["dend"][gy, gx, gd], abs=1e-12)
                    i += 1
    assert n_seen > 500


def test_paper_setup_size_and_build(tmp_path):
    """640x480x343 with one extra camera: bytes <= 1 GB, cached (its build time is the bench's
    ``depthgrid.build_s``)."""
    cams = [dg.Camera(id=f"k{i}", width=640, height=480, fx=525, fy=525, cx=319.5, cy=239.5,
                      world_from_camera=look_at(np.array(e, float), np.zeros(3)))
            for i, e in enumerate([(2.0, -2.0, 1.3), (2.0, 2.0, 1.3)])]
    g = DepthGridMap(cams, "k0", 0.2882, 0.2882 + 3.43, 0.01, cache_dir=tmp_path)
    assert g.shape == (480, 640, 343)
    assert g.nbytes <= 1e9
    g2 = DepthGridMap(cams, "k0", 0.2882, 0.2882 + 3.43, 0.01, cache_dir=tmp_path)
    assert g2.from_cache and np.array_equal(g2.rays, g.rays)


def test_cache_key_rebuild_and_corrupt_file(tmp_path):
    a = _cam("a", (2.5, 0, 1))
    b = _cam("b", (0, 2.5, 1))
    g1 = DepthGridMap([a, b], "a", 1.0, 4.0, 0.05, cache_dir=tmp_path)
    assert not g1.from_cache and g1.cache_path.exists()
    assert DepthGridMap([a, b], "a", 1.0, 4.0, 0.05, cache_dir=tmp_path).from_cache
    # a moved camera is another rig: another key, a fresh build with other rays
    b2 = b.with_pose(look_at(np.array([0.1, 2.5, 1.0]), np.zeros(3)))
    g3 = DepthGridMap([a, b2], "a", 1.0, 4.0, 0.05, cache_dir=tmp_path)
    assert not g3.from_cache and g3.key != g1.key and not np.allclose(g3.rays, g1.rays)
    # other grid parameters: another key
    assert DepthGridMap([a, b], "a", 1.0, 4.0, 0.04, cache_dir=tmp_path).key != g1.key
    # a corrupt file is rebuilt, not trusted
    g1.cache_path.write_bytes(b"not an npz file")
    g4 = DepthGridMap([a, b], "a", 1.0, 4.0, 0.05, cache_dir=tmp_path)
    assert not g4.from_cache and np.array_equal(g4.rays, g1.rays)
    # a valid npz holding other numbers under the same name is rebuilt too
    np.savez(g1.cache_path, key=np.array(g1.key), rays=g1.rays[:, :-1], origins=g1.origins)
    assert not DepthGridMap([a, b], "a", 1.0, 4.0, 0.05, cache_dir=tmp_path).from_cache


def test_bad_input_raises_value_error():
    a = _cam("a", (2.5, 0, 1))
    b = _cam("b", (0, 2.5, 1))
    with pytest.raises(ValueError, match="principal"):
        DepthGridMap([a, b], "zz", 1, 4, 0.05, cache=False)
    with pytest.raises(ValueError, match="delta_d"):
        DepthGridMap([a, b], "a", 1, 4, 0.0, cache=False)
    with pytest.raises(ValueError, match="d_max"):
        DepthGridMap([a, b], "a", 4, 1, 0.05, cache=False)
    with pytest.raises(ValueError, match="unique"):
        DepthGridMap([a, a], "a", 1, 4, 0.05, cache=False)
    g = DepthGridMap([a, b], "a", 1, 4, 0.05, cache=False)
    z = np.zeros(a.shape, np.float32)
    with pytest.raises(ValueError, match="principal"):
        g.distance({"b": z}, np.zeros((1, 3)))
    with pytest.raises(ValueError, match="unknown camera"):
        g.distance({"a": z, "q": z}, np.zeros((1, 3)))
    with pytest.raises(ValueError, match="shape"):
        g.distance({"a": np.zeros((3, 3), np.float32)}, np.zeros((1, 3)))
    with pytest.raises(ValueError, match="method"):
        g.distance({"a": z}, np.zeros((1, 3)), method="median")
    with pytest.raises(ValueError, match="rho"):
        g.distance({"a": z}, np.zeros((1, 3)), rho=-1)
    with pytest.raises(ValueError, match="query"):
        DepthGridMap([a, b], "a", 1, 4, 0.05, cache=False).query(np.zeros((1, 3)))


# ------------------------------------------------------------------ semantics
def test_shadow_cleared_and_hidden_object_found():
    """Two cameras at 90 degrees: a box hides space from cam a; cam b sees it free
    (distance grows to the true one), and an object behind the box from a is found by b."""
    a = _cam("a", (2.6, 0, 0.3))
    b = _cam("b", (0, 2.6, 0.3))
    occluder = Box(size=(0.1, 0.4, 0.4), world_from_local=_T(1.2, 0, 0))
    hidden = Sphere(radius=0.1, world_from_local=_T(-0.5, 0, 0))
    prims = _room() + [occluder]
    P = np.array([[0.0, 0.0, 0.0]])        # behind the occluder from a, 1.1 m from it
    for scene in (prims, prims + [hidden]):
        meshes = [p.mesh() for p in scene]
        depths = {c.id: render_depth(c, meshes) for c in (a, b)}
        one = DepthGridMap([a], "a", 1.0, 4.6, 0.02, cache=False).distance({"a": depths["a"]}, P, 0.6, "min")
        two = DepthGridMap([a, b], "a", 1.0, 4.6, 0.02, cache=False).distance(depths, P, 0.6, "min")
        truth = sdf_union(scene, P)
        assert one.distance[0] < 0.05                 # one camera: P sits in the gray area
        eps = _eps(a, P, 0.6, 0.02)
        if truth[0] > 0.6:
            assert np.isinf(two.distance[0])          # shadow cleared by b
        else:
            assert truth[0] - eps[0] <= two.distance[0] <= truth[0] + eps[0]


def test_missing_other_camera_is_safe():
    """A frame missing from a non-principal camera clears nothing (R27): same as one camera."""
    rng = np.random.default_rng(3)
    prims, cams, depths = _scene(rng, 2)
    P = rng.uniform(-0.6, 0.6, (8, 3))
    g2 = DepthGridMap(cams, "c0", 1.0, 4.6, 0.03, cache=False)
    g1 = DepthGridMap(cams[:1], "c0", 1.0, 4.6, 0.03, cache=False)
    r_missing = g2.distance({"c0": depths["c0"]}, P, 0.4, "min")
    r_one = g1.distance({"c0": depths["c0"]}, P, 0.4, "min")  # one camera: nothing to confirm with
    np.testing.assert_array_equal(r_missing.distance, r_one.distance)
    r_two = g2.distance(depths, P, 0.4, "min")
    assert np.all(r_two.distance >= r_one.distance)   # fusion only removes gray area


def test_robot_volume_never_an_obstacle_for_its_points():
    """A robot link seen by both cameras: without its volume its own control point
    reads ~0 (unknown behind the removed link); with the padded capsule it reads no obstacle."""
    a = _cam("a", (2.6, 0, 0.3))
    b = _cam("b", (0, 2.6, 0.3))
    link = Capsule.between([0, 0, -0.3], [0, 0, 0.4], 0.06)
    meshes = [p.mesh() for p in _room()] + [link.mesh()]
    depths = {c.id: render_depth(c, meshes) for c in (a, b)}
    rd = {c.id: render_depth(c, [link.mesh()]) for c in (a, b)}
    g = DepthGridMap([a, b], "a", 1.0, 4.6, 0.02, cache=False)
    P = np.array([[0, 0, 0.0], [0, 0, 0.2]])
    bare = g.distance(depths, P, 0.4, "min", rd)
    assert np.all(bare.distance < 0.1)
    padded = g.distance(depths, P, 0.4, "min", rd,
                        robot_capsules=[Capsule.between([0, 0, -0.3], [0, 0, 0.4], 0.06 + 0.06)])
    assert np.all(np.isinf(padded.distance))


# ------------------------------------------------------------------ several principals
def test_multi_principal_covers_what_no_single_camera_sees():
    """Two cameras looking at two different halves of a room: no camera sees
    everything; each point is evaluated with a camera that sees it."""
    a = _cam("a", (0.0, -2.8, 0.5), target=(-1.5, 0.5, 0.0))
    b = _cam("b", (0.0, 2.8, 0.5), target=(1.5, -0.5, 0.0))
    s1 = Sphere(radius=0.15, world_from_local=_T(-1.6, 0.3, 0))
    s2 = Box(size=(0.3, 0.3, 0.3), world_from_local=_T(1.6, -0.3, 0))
    prims = _room() + [s1, s2]
    meshes = [p.mesh() for p in prims]
    depths = {c.id: render_depth(c, meshes) for c in (a, b)}
    P = np.array([[-1.6, 0.3, 0.3], [1.6, -0.3, 0.32], [-1.3, 0.6, -0.1], [1.25, 0.0, 0.1]])
    assert not np.all(a.in_view(P)) and not np.all(b.in_view(P))
    single = DepthGridMap([a, b], "a", 0.5, 6.0, 0.03, cache=False).distance(depths, P, 0.4, "min")
    assert not single.observed.all()
    multi = MultiPrincipalDepthGrid([a, b], 0.5, 6.0, 0.03, cache=False)
    who = multi.principal_for(P, 0.4)
    assert set(who) == {0, 1}
    res = multi.distance(depths, P, 0.4, "min")
    assert res.observed.all()
    truth = sdf_union(prims, P)
    eps = np.array([_eps([a, b][w], P[i:i + 1], 0.4, 0.03)[0] for i, w in enumerate(who)])
    assert np.all(res.distance <= truth + eps)
    assert np.all(np.isfinite(res.distance))
    # both sides: each point's answer is exactly the plain-numpy twin's with the principal chosen
    # for it (a grid answering 0 or inf everywhere fails here)
    for w, cam in enumerate((a, b)):
        mine = who == w
        d, _v, o, _c = _twin(multi.maps[cam.id], depths, P[mine], 0.4, "min")
        np.testing.assert_allclose(res.distance[mine], d, rtol=1e-9, atol=1e-12)
        assert np.all(o)
    assert np.all(res.distance > 0.05)          # the points are 0.15 m or more from everything


# ------------------------------------------------------------------ property on random scenes
@pytest.mark.slow
def test_property_random_scenes():
    """R25: reported <= true + eps for every point (principal sees the rho-cube: the
    paper's assumption 1); where every camera sees the point, >= 95 % also >= true - eps."""
    rho, dd = 0.4, 0.03
    n_upper = n_lower = n_lower_ok = 0
    for seed in range(10):
        rng = np.random.default_rng(100 + seed)
        prims, cams, depths = _scene(rng, int(rng.integers(2, 5)))
        grid = DepthGridMap(cams, "c0", 0.6, 5.0, dd, cache=False)
        P = rng.uniform(-0.9, 0.9, (80, 3))
        truth = sdf_union(prims, P)
        P, truth = P[truth > 0.02], truth[truth > 0.02]
        corners = (P[:, None, :] + rho * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1)
                                                    for z in (-1, 1)])[None]).reshape(-1, 3)
        in_p = cams[0].in_view(corners).reshape(-1, 8).all(1)
        P, truth = P[in_p], truth[in_p]
        res = grid.distance(depths, P, rho, "hybrid")
        eps = _eps(cams[0], P, rho, dd)
        rep = np.where(np.isfinite(res.distance), res.distance, np.inf)
        tr = np.where(truth <= rho, truth, np.inf)
        assert np.all(rep <= tr + eps), (seed, rep, tr)
        n_upper += len(P)
        # points every camera sees (in view and not occluded)
        seen = np.ones(len(P), bool)
        for c in cams:
            ds = c.world_to_depth_space(P)
            u, v = c.pixel_of(ds[:, 0], ds[:, 1])
            inv = c.in_view(P)
            d = np.where(inv, depths[c.id][np.clip(v, 0, c.height - 1), np.clip(u, 0, c.width - 1)], 0)
            seen &= inv & (d >= ds[:, 2])
        ok = (np.minimum(rep, rho) >= np.minimum(truth, rho) - eps)[seen]
        n_lower += ok.size
        n_lower_ok += ok.sum()
    assert n_upper >= 100
    assert n_lower >= 50 and n_lower_ok >= 0.95 * n_lower, (n_lower_ok, n_lower)
    print(f"property: {n_upper} points upper bound ok; lower bound {n_lower_ok}/{n_lower}")


@pytest.mark.parametrize("seed,n_cams", [(21, 2), (22, 3)])
def test_lazy_columns_equal_eager_runs(seed, n_cams):
    """The lazy per-frame work (cells classified on first use, memoised per pixel with a
    frame stamp) gives exactly the eager answer (every column's runs at set_frames), for
    several queries within a frame (memo reused, new points needing new slices, the same
    points again, points moved a little), on one thread (classify while looking up, or
    first for a new frame) and two (classify first), after a new frame and after a change
    of the robot's volume."""
    rng = np.random.default_rng(seed)
    prims, cams, depths = _scene(rng, n_cams)
    a, b, c, depths, rdepths, caps = _with_robot(prims, cams)
    lazy = DepthGridMap(cams, "c0", 1.0, 4.6, 0.03, cache=False)
    eager = DepthGridMap(cams, "c0", 1.0, 4.6, 0.03, cache=False)
    n_found = 0
    for frame in range(2):
        if frame == 1:                        # a new frame: one camera sees an extra sphere
            extra = Sphere(radius=0.15, world_from_local=_T(*rng.uniform(-0.5, 0.5, 3)))
            depths[cams[1].id] = _with_robot(prims + [extra], cams[1:2])[3][cams[1].id]
        lazy.set_frames(depths, rdepths, robot_capsules=caps)
        eager.set_frames(depths, rdepths, robot_capsules=caps, lazy=False)
        assert lazy.lazy and not eager.lazy
        assert np.all(eager._nruns < 8)       # no run merging in the eager form: exact comparison
        for q in range(6):
            if q < 4:
                P = np.vstack([rng.uniform(-0.8, 0.8, (6, 3)), a + (b - a) * rng.random(), c])
            elif q == 5:                      # the points move a little (a control cycle later)
                P = P + rng.normal(0.0, 0.01, P.shape)
            # q == 4: the same points again: every column they need is memoised
            if frame == 1 and q == 5:         # the robot's volume changes within the frame
                caps = [Capsule.between(a + 0.02, b + 0.02, 0.12), Capsule.between(b + 0.02, c + 0.02, 0.1)]
                lazy.set_robot_capsules(caps)
                eager.set_frames(depths, rdepths, robot_capsules=caps, lazy=False)
            method = ("hybrid", "min", "mean", "hybrid", "hybrid", "hybrid")[q]
            # threads: the default (first query of frame 0: classify on all threads, then look up
            # on one), one thread chosen by the caller (first query of frame 1), two (q == 2)
            threads = 2 if q == 2 else (1 if (frame == 1 and q == 0) else None)
            r1 = lazy.query(P, 0.4, method, threads=threads).copy()
            r2 = eager.query(P, 0.4, method).copy()
            np.testing.assert_array_equal(r1.distance, r2.distance)
            np.testing.assert_array_equal(r1.direction, r2.direction)
            np.testing.assert_array_equal(r1.count, r2.count)
            np.testing.assert_array_equal(r1.observed, r2.observed)
            n_found += int(np.isfinite(r1.distance).sum())
    assert n_found >= 10                      # the comparison is not vacuous


def test_frames_of_changed_cameras_only_give_the_same_answers():
    """``set_frames(..., changed=[id])`` (the other cameras keep their loaded states) answers
    exactly like loading every camera and like the eager runs, through new frames of another
    camera and of the principal, a camera that stops delivering and comes back, with the
    robot's volume moving at every load (the other cameras' memoised clearings outlive it,
    ``depth_grid_memo``); a camera left out of ``changed`` really keeps its old frame (the
    skip is not a no-op)."""
    rng = np.random.default_rng(5)
    prims, cams, depths = _scene(rng, 3)
    a, b, c, depths, rdepths, caps = _with_robot(prims, cams)
    full = DepthGridMap(cams, "c0", 1.0, 4.6, 0.03, cache=False)
    part = DepthGridMap(cams, "c0", 1.0, 4.6, 0.03, cache=False)
    stale = DepthGridMap(cams, "c0", 1.0, 4.6, 0.03, cache=False)
    eager = DepthGridMap(cams, "c0", 1.0, 4.6, 0.03, cache=False)
    P = np.vstack([rng.uniform(-0.6, 0.6, (12, 3)), a + (b - a) * 0.5, c])
    joints = (a, b, c)
    frames = dict(depths)
    differs = False
    for step, cid in enumerate([None, "c1", "c0", "c2", "drop c2", "back c2"]):
        changed = None
        if cid in ("c0", "c1", "c2"):
            ball = Sphere(radius=0.2, world_from_local=_T(*rng.uniform(-0.4, 0.4, 3)))
            cam = next(k for k in cams if k.id == cid)
            frames[cid] = _with_robot(prims + [ball], [cam])[3][cid]
            changed = [cid]
        elif cid == "drop c2":
            frames.pop("c2")
            changed = []
        elif cid == "back c2":
            frames["c2"] = depths["c2"]
            changed = []                          # a camera that had no frame is loaded regardless
        shift = 0.015 * step                      # the robot moved between two loads
        caps = [Capsule.between(joints[0] + shift, joints[1] + shift, 0.12),
                Capsule.between(joints[1] + shift, joints[2] + shift, 0.1)]
        full.set_frames(frames, rdepths, robot_capsules=caps)
        part.set_frames(frames, rdepths, robot_capsules=caps, changed=changed)
        stale.set_frames(frames, rdepths, robot_capsules=caps, changed=None if step == 0 else [])
        eager.set_frames(frames, rdepths, robot_capsules=caps, lazy=False)
        assert np.all(eager._nruns < 8)           # no run merging in the eager form: exact comparison
        r1, r2, r3, r4 = (g.query(P, 0.4, "hybrid").copy() for g in (full, part, stale, eager))
        for r in (r2, r4):
            np.testing.assert_array_equal(r1.distance, r.distance)
            np.testing.assert_array_equal(r1.direction, r.direction)
            np.testing.assert_array_equal(r1.observed, r.observed)
        differs |= not np.array_equal(r1.distance, r3.distance)
    assert differs
    with pytest.raises(ValueError, match="changed names unknown"):
        part.set_frames(frames, rdepths, robot_capsules=caps, changed=["nope"])


def test_capsule_boxes_kernel_equals_numpy_twin(rng):
    """The capsules' pixel boxes (numba) equal the plain-numpy twin on random capsules,
    including ones that reach behind the principal camera (the whole image)."""
    p = _cam("p", (2.5, -0.3, 1.0), w=64, h=48, f=50.0)
    g = DepthGridMap([p], principal="p", d_min=0.5, d_max=4.0, delta_d=0.05, cache=False)
    for _ in range(50):
        n = int(rng.integers(1, 12))
        a = rng.uniform(-3.0, 3.0, (n, 3))
        b = a + rng.uniform(-0.5, 0.5, (n, 3))
        caps = np.concatenate([a, b, rng.uniform(0.01, 0.3, (n, 1))], axis=1)
        np.testing.assert_array_equal(g._capsule_boxes(caps).copy(), g._capsule_boxes_numpy(caps))
