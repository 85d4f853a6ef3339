"""Expected-depth renderer (R16) against independent truths: analytic geometry,
the plain-numpy twin, and Embree ray casting (embreex)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import depthguard as dg
from depthguard.geometry import Box, Capsule, Cylinder, Mesh, Sphere
from depthguard.render import Renderer, render_depth
from depthguard.render.raster_ref import render_depth_numpy
from depthguard.render.embree import EmbreeCaster
from depthguard.transforms import look_at


def camera(w=80, h=60, f=70.0, cx=None, cy=None, T=None, id="cam"):
    cx = (w - 1) / 2 if cx is None else cx
    cy = (h - 1) / 2 if cy is None else cy
    return dg.Camera(id, w, h, f, f, cx, cy, np.eye(4) if T is None else T)


def quad(corners) -> Mesh:
    """Two triangles a b c, a c d (winding as given)."""
    return Mesh(np.asarray(corners, float), np.array([[0, 1, 2], [0, 2, 3]], np.int32))


def pixel_rays(cam):
    """(H, W, 3) camera-frame rays through pixel centres, z = 1 (SPEC §1: centres at integers)."""
    v, u = np.mgrid[0:cam.height, 0:cam.width].astype(float)
    return np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], axis=-1)


# ------------------------------------------------------------------ analytic
def test_fronto_parallel_square_depth_and_coverage():
    cam = camera(w=80, h=60, f=70.0, cx=40.0, cy=30.0)
    d, X, Y = 2.0, 0.61, 0.37          # half sizes chosen so no pixel centre lies on an edge
    # wound so that its normal faces the camera (-z): seen from the front
    sq = quad([[-X, -Y, d], [-X, Y, d], [X, Y, d], [X, -Y, d]])
    depth, labels = render_depth(cam, [sq], labels=True)
    ray = pixel_rays(cam)
    inside = (np.abs(ray[..., 0] * d) < X) & (np.abs(ray[..., 1] * d) < Y)
    assert inside.sum() > 500
    np.testing.assert_array_equal(depth > 0, inside)
    np.testing.assert_array_equal(depth[inside], np.float32(d))
    np.testing.assert_array_equal(labels, np.where(inside, 0, -1))
    assert depth.dtype == np.float32 and labels.dtype == np.int32


def test_tilted_plane_is_perspective_correct():
    """Depth on a plane n·P = c through pixel ray z·r is z = c / (n·r): exact, not the
    screen-linear interpolation of z (which is off by centimetres here)."""
    T = look_at(np.array([0.3, -1.8, 1.2]), np.array([0.0, 0.0, 0.2]), np.array([0.0, 0.0, 1.0]))
    cam = camera(w=96, h=72, f=80.0, T=T)
    ground = quad([[-3, -3, 0.2], [3, -3, 0.2], [3, 3, 0.2], [-3, 3, 0.2]])   # normal +z, faces the camera
    depth = render_depth(cam, [ground])
    n_c = cam.R @ np.array([0.0, 0.0, 1.0])
    c_c = 0.2 - np.array([0.0, 0.0, 1.0]) @ cam.position               # plane n·Pw = 0.2 in the camera frame
    ray = pixel_rays(cam)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = c_c / (ray @ n_c)
        world = (ray * z[..., None]) @ cam.R + cam.position       # R^T (P_c - t) = R^T P_c + position
    expect = (z > 0) & (np.abs(world[..., 0]) < 3) & (np.abs(world[..., 1]) < 3)
    assert expect.sum() > 1000
    np.testing.assert_array_equal(depth > 0, expect)
    np.testing.assert_allclose(depth[expect], z[expect], rtol=1e-6)


def test_box_face_depth_and_labels():
    cam = camera(w=64, h=48, f=60.0, cx=32.0, cy=24.0)
    box = Box.from_bounds([-0.31, -0.23, 1.5], [0.29, 0.21, 1.9]).mesh()
    depth, labels = render_depth(cam, [box], labels=True)
    ray = pixel_rays(cam)
    inside = ((ray[..., 0] * 1.5 > -0.31) & (ray[..., 0] * 1.5 < 0.29)
              & (ray[..., 1] * 1.5 > -0.23) & (ray[..., 1] * 1.5 < 0.21))
    # the near face z = 1.5 is all the camera sees of this box (its sides are edge-on or hidden)
    np.testing.assert_array_equal(depth > 0, inside)
    np.testing.assert_array_equal(depth[inside], np.float32(1.5))
    np.testing.assert_array_equal(labels[inside], 0)


def test_sphere_silhouette_and_centre_depth():
    """UV sphere (inscribed polyhedron) of radius r at distance D on the optical axis:
    the pole vertex faces the camera, so the centre pixel has depth D - r exactly; the
    silhouette lies between the cones of the inscribed and the true sphere; every depth
    lies between the true sphere and the inscribed sphere of the polyhedron."""
    f, D, r, n = 120.0, 2.0, 0.4, 64
    cam = camera(w=121, h=121, f=f, cx=60.0, cy=60.0)
    T = np.eye(4)
    T[:3, 3] = [0, 0, D]
    sphere = Sphere(radius=r, segments=n, world_from_local=T).mesh()
    depth = render_depth(cam, [sphere])
    assert depth[60, 60] == pytest.approx(D - r, abs=1e-6)
    # every facet's circumscribed cap is narrower than one ring / one segment step
    r_in = r * np.cos(max(2 * np.pi / n, np.pi / 2 / (n // 4)))   # inside every facet plane
    ray = pixel_rays(cam)
    # angle between the ray and the optical axis vs the half-angle of the tangent cone
    ang = np.arctan(np.hypot(ray[..., 0], ray[..., 1]))
    out_true = ang > np.arcsin(r / D) + 1e-9
    in_inner = ang < np.arcsin(r_in / D) - 1e-9
    assert not np.any((depth > 0) & out_true)
    assert np.all(depth[in_inner] > 0)

    def sphere_entry(rad):  # first hit of the ray with a sphere of radius rad, as depth z
        rr = np.sum(ray * ray, axis=-1)
        b = D * ray[..., 2]
        disc = b * b - rr * (D * D - rad * rad)
        return (b - np.sqrt(np.maximum(disc, 0.0))) / rr

    z = depth[in_inner].astype(float)
    assert np.all(z >= sphere_entry(r)[in_inner] - 1e-6)
    assert np.all(z <= sphere_entry(r_in)[in_inner] + 1e-6)


# --------------------------------------------------------------- near plane
def test_triangle_crossing_near_plane_is_clipped_not_dropped():
    """A big triangle through the camera's near plane (vertices behind the camera): its
    visible part renders with the exact plane depth; nothing nearer than ``near``."""
    cam = camera(w=80, h=60, f=50.0)
    near = 0.9
    # plane z = 1 + 0.5 y (camera frame) through three points, two of them behind the camera
    P = np.array([[-4.0, -6.0, 0.0], [5.0, 3.0, 0.0], [-1.0, 5.0, 0.0]])
    P[:, 2] = 1.0 + 0.5 * P[:, 1]
    assert (P[:, 2] < 0).sum() == 1 and (P[:, 2] > near).sum() == 2
    faces = np.array([[0, 1, 2]], np.int32)
    depth = render_depth(cam, [(P, faces)], near=near, cull_back=False)
    ray = pixel_rays(cam)
    z = 1.0 / (1.0 - 0.5 * ray[..., 1])              # z = 1 + 0.5 y, y = z * ray_y
    hit = ray * z[..., None]
    # barycentric point-in-triangle test of the hit in the plane (x, y suffice: plane is a graph over x, y)
    a, b, c = P[:, :2]
    m = np.array([b - a, c - a]).T
    lam = np.linalg.solve(m, (hit[..., :2] - a).reshape(-1, 2).T).T.reshape(hit.shape[:2] + (2,))
    in_tri = (lam[..., 0] > 0) & (lam[..., 1] > 0) & (lam.sum(-1) < 1) & (z > 0)
    expect = in_tri & (z >= near)
    clipped = in_tri & (z < near)
    assert expect.sum() > 300 and clipped.sum() > 300     # the near plane cuts through the image
    # allow pixels whose centre lies within 1e-6 of the clipping line only
    ambiguous = np.abs(z - near) < 1e-6
    np.testing.assert_array_equal((depth > 0)[~ambiguous], expect[~ambiguous])
    np.testing.assert_allclose(depth[expect], z[expect], rtol=1e-6)
    assert depth[depth > 0].min() >= np.float32(near) * (1 - 1e-6)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_kernel_matches_numpy_twin(seed):
    """Random triangles around the camera, many crossing the near plane or behind it,
    culling on and off, and closed primitives: kernel == twin (depth within 1e-6 m,
    labels and faces identical)."""
    rng = np.random.default_rng(seed)
    T = look_at(rng.uniform(-1, 1, 3) + [0, -2.5, 1.0], np.zeros(3), np.array([0, 0, 1.0]))
    cam = camera(w=64, h=48, f=55.0, T=T)
    meshes = []
    for _ in range(25):  # triangles scattered around the camera position
        c = cam.position + rng.normal(size=3) * 1.2
        meshes.append((c + rng.normal(size=(3, 3)) * 0.6, np.array([[0, 1, 2]])))
    meshes.append(Sphere(radius=0.4, segments=16).mesh())
    meshes.append(Box(size=(0.3, 1.5, 0.2)).moved(look_at(np.array([0.3, 0.1, 0]), np.ones(3), np.array([0, 0, 1.0]))).mesh())
    for cull in (True, False):
        for par in (False, True):
            r = Renderer(cam, near=0.3, parallel=par)
            d, lab = r.render(meshes, cull_back=cull)
            d2, lab2, f2 = render_depth_numpy(cam, meshes, near=0.3, cull_back=cull)
            assert (d > 0).sum() > 200
            np.testing.assert_allclose(d, d2, rtol=0, atol=1e-6)
            np.testing.assert_array_equal(lab, lab2)
            np.testing.assert_array_equal(r.face_index(), f2)
        # a depth-only renderer (ids=False): the same depth bits and spans, no labels
        r, rd = Renderer(cam, near=0.3), Renderer(cam, near=0.3, ids=False)
        d, _ = r.render(meshes, cull_back=cull)
        dd, lab = rd.render(meshes, cull_back=cull)
        assert lab is None and rd.face_ids is None
        np.testing.assert_allclose(dd, render_depth_numpy(cam, meshes, near=0.3, cull_back=cull)[0], rtol=0, atol=1e-6)
        assert dd.tobytes() == d.tobytes() and np.array_equal(rd.spans, r.spans)


def test_renderers_reused_with_moving_meshes_match_the_twin():
    """One serial and one parallel renderer, each called again and again as meshes move and
    faces turn away: every call equals a fresh numpy render. (The parallel kernel once left a
    culled face's slot holding the previous call's triangle, drawn again from the 2nd call.)"""
    rng = np.random.default_rng(11)
    T = look_at(np.array([0.0, -2.5, 1.0]), np.zeros(3), np.array([0, 0, 1.0]))
    cam = camera(w=64, h=48, f=55.0, T=T)
    box = Box(size=(0.6, 0.3, 0.4))
    rs = [Renderer(cam, near=0.3), Renderer(cam, near=0.3, parallel=True)]
    depth_only = Renderer(cam, near=0.3, ids=False)     # the layers' renderer (no labels): the same depth
    for _ in range(6):
        axis = rng.normal(size=3)
        meshes = [box.moved(look_at(rng.uniform(-0.3, 0.3, 3), axis, np.array([0, 0, 1.0]))).mesh(),
                  Sphere(radius=0.2, segments=12).moved(look_at(rng.uniform(-0.5, 0.5, 3), axis,
                                                                np.array([0, 0, 1.0]))).mesh()]
        d2, lab2, _ = render_depth_numpy(cam, meshes, near=0.3)
        for r in rs:
            d, lab = r.render(meshes)
            np.testing.assert_allclose(d, d2, rtol=0, atol=1e-6)
            np.testing.assert_array_equal(lab, lab2)
        dd = depth_only.render(meshes)[0]
        np.testing.assert_allclose(dd, d2, rtol=0, atol=1e-6)
        assert dd.tobytes() == rs[0].depth.tobytes() and np.array_equal(depth_only.spans, rs[0].spans)


def test_shared_edges_no_cracks_no_double_draw():
    """A fan of triangles around a centre that is a pixel centre, with edges through pixel
    centres: every pixel inside the polygon is drawn exactly once (the top-left rule)."""
    cam = camera(w=41, h=41, f=40.0, cx=20.0, cy=20.0)
    n = 8
    ang = np.arange(n) * 2 * np.pi / n
    ring = np.stack([np.cos(ang), np.sin(ang), np.ones(n)], axis=1) * [0.4, 0.4, 1.0]
    V = np.vstack([[0.0, 0.0, 1.0], ring])
    F = np.array([[0, 1 + (i + 1) % n, 1 + i] for i in range(n)], np.int32)   # facing the camera
    # render each triangle alone: coverages must partition the union (no overlap, no gap)
    count = np.zeros(cam.shape, int)
    for f in F:
        count += render_depth(cam, [(V, f[None])]) > 0
    whole = render_depth(cam, [(V, F)]) > 0
    assert count.max() == 1
    np.testing.assert_array_equal(count == 1, whole)
    assert whole[20, 20] and whole[20, 28] and whole[12, 20]   # centre and points on axis-aligned edges


def test_top_left_rule_on_an_aligned_rectangle():
    """A rectangle whose edges run exactly through pixel centres, u in [10, 20], v in [5, 15]:
    the top-left rule takes its left column and top row, not its right column and bottom row,
    so it covers exactly 10 x 10 pixels (as on a GPU); its diagonal is drawn once."""
    cam = camera(w=32, h=24, f=10.0, cx=0.0, cy=0.0)
    for corners in ([[1.0, 0.5, 1.0], [1.0, 1.5, 1.0], [2.0, 1.5, 1.0], [2.0, 0.5, 1.0]],
                    [[2.0, 1.5, 1.0], [2.0, 0.5, 1.0], [1.0, 0.5, 1.0], [1.0, 1.5, 1.0]]):  # other diagonal
        depth = render_depth(cam, [quad(corners)])
        expect = np.zeros(cam.shape, bool)
        expect[5:15, 10:20] = True
        np.testing.assert_array_equal(depth > 0, expect)


# ---------------------------------------------------------------- culling
def test_back_face_culling():
    cam = camera()
    V = np.array([[-0.5, -0.5, 2.0], [0.5, -0.5, 2.0], [0.0, 0.5, 2.0]])
    away = np.array([[0, 1, 2]], np.int32)     # normal (b-a)x(c-a) = +z: faces away from the camera
    assert np.cross(V[1] - V[0], V[2] - V[0])[2] > 0
    toward = away[:, ::-1].copy()
    assert not np.any(render_depth(cam, [(V, away)]))
    on = render_depth(cam, [(V, away)], cull_back=False)
    assert (on > 0).sum() > 100
    np.testing.assert_array_equal(render_depth(cam, [(V, toward)]), on)


# ----------------------------------------------------------------- labels
@pytest.mark.parametrize("order", [(0, 1), (1, 0)])
def test_label_image_picks_the_nearer_mesh(order):
    cam = camera(w=80, h=60, f=70.0, cx=40.0, cy=30.0)
    near_sq = quad([[-0.51, -0.31, 1.0], [-0.51, 0.29, 1.0], [0.09, 0.29, 1.0], [0.09, -0.31, 1.0]])
    far_sq = quad([[-0.21, -0.41, 2.0], [-0.21, 0.39, 2.0], [0.81, 0.39, 2.0], [0.81, -0.41, 2.0]])
    meshes = [near_sq, far_sq] if order == (0, 1) else [far_sq, near_sq]
    i_near = order.index(0)
    depth, labels = render_depth(cam, meshes, labels=True)
    ray = pixel_rays(cam)
    in_near = (ray[..., 0] > -0.51) & (ray[..., 0] < 0.09) & (ray[..., 1] > -0.31) & (ray[..., 1] < 0.29)
    in_far = ((2 * ray[..., 0] > -0.21) & (2 * ray[..., 0] < 0.81)
              & (2 * ray[..., 1] > -0.41) & (2 * ray[..., 1] < 0.39))
    assert (in_near & in_far).sum() > 100
    np.testing.assert_array_equal(labels[in_near], i_near)
    np.testing.assert_array_equal(labels[in_far & ~in_near], 1 - i_near)
    np.testing.assert_array_equal(labels[~in_near & ~in_far], -1)
    np.testing.assert_array_equal(depth[in_near], np.float32(1.0))


# ---------------------------------------------------------- Renderer API
def test_renderer_reuses_buffers_and_grows():
    cam = camera()
    r = Renderer(cam)
    small = [Box(size=(0.2, 0.2, 0.2)).moved(_tz(2.0)).mesh()]
    big = [Sphere(radius=0.3, segments=48).moved(_tz(2.5)).mesh(), small[0]]
    d1, l1 = r.render(small)
    assert d1 is r.depth and l1 is r.labels
    ref1 = d1.copy()
    d2, l2 = r.render(big)                    # more triangles than allocated: buffers grow
    assert d2 is r.depth
    np.testing.assert_array_equal(d2, render_depth(cam, big))
    d3, _ = r.render(small)
    np.testing.assert_array_equal(d3, ref1)   # nothing left over from the bigger scene
    d4, l4 = r.render([])
    assert not d4.any() and np.all(l4 == -1)
    # a call reads out only its window and the last call's: nothing else may write the images
    for img in (d4, l4, r.face_ids):
        with pytest.raises(ValueError, match="read-only"):
            img[0, 0] = 1


def test_robot_render_bound_equals_a_fresh_render_and_the_twin():
    """ExpectedDepth.robot (the renderer bound to the clustered link meshes, the model writing
    their world vertices into its buffer) gives, frame after frame as the robot moves in and out
    of view, bit for bit the image of a fresh serial and parallel render of
    ``render_link_meshes(q)``; at a small resolution also the plain-numpy twin's."""
    from depthguard.filtering.expected import ExpectedDepth
    from depthguard.sim import load_cell

    rig = load_cell("ur3-cell").rig
    robot = rig.robot
    rng = np.random.default_rng(4)
    qs = [np.clip(robot.q_home + rng.uniform(-1.5, 1.5, robot.dof), robot.q_min, robot.q_max) for _ in range(4)]
    away = robot.with_base(_tz(50.0))            # far above every camera's view: an empty image
    for cam in rig.cameras[:2]:
        ex, ex_away = ExpectedDepth(cam, robot, []), ExpectedDepth(cam, away, [])
        rp = Renderer(cam, parallel=True)
        for q in qs + qs[:1] + qs[:1]:           # the same joints twice in a row: the image kept
            want = np.array(Renderer(cam).render(robot.render_link_meshes(q))[0], copy=True)
            assert (want > 0).sum() > 500
            got = ex.robot(q)
            assert np.array_equal(got, want)
            assert np.array_equal(rp.render(robot.render_link_meshes(q))[0], want)
            assert not ex_away.robot(q).any()
        assert not ex.robot(qs[0]).flags.writeable
    small = dg.Camera("small", 160, 120, 96.0, 96.0, 79.5, 59.5, rig.cameras[0].world_from_camera)
    ex = ExpectedDepth(small, robot, [])
    for q in qs[:2]:
        d2, _, _ = render_depth_numpy(small, robot.render_link_meshes(q))
        assert (d2 > 0).sum() > 100
        np.testing.assert_allclose(ex.robot(q), d2, rtol=0, atol=1e-6)


def test_inputs_accepted_and_rejected():
    trimesh = pytest.importorskip("trimesh")
    cam = camera()
    m = Box(size=(0.4, 0.4, 0.4)).moved(_tz(2.0)).mesh()
    tm = trimesh.Trimesh(m.vertices, m.faces, process=False)
    ref = render_depth(cam, [m])
    np.testing.assert_array_equal(render_depth(cam, [tm]), ref)
    np.testing.assert_array_equal(render_depth(cam, [(m.vertices.tolist(), m.faces.tolist())]), ref)
    np.testing.assert_array_equal(render_depth(cam, m), ref)            # a single mesh
    with pytest.raises(ValueError, match="near"):
        render_depth(cam, [m], near=0.0)
    with pytest.raises(ValueError, match=r"meshes\[1\].*face indices"):
        render_depth(cam, [m, (m.vertices, m.faces + 100)])
    with pytest.raises(ValueError, match=r"meshes\[0\].*vertices"):
        render_depth(cam, [(np.zeros((4, 2)), [[0, 1, 2]])])
    with pytest.raises(ValueError, match="Camera"):
        render_depth("cam0", [m])
    # a well-typed Mesh skips the Python checks: the kernel checks its values instead
    r = Renderer(cam)
    with pytest.raises(ValueError, match=r"meshes\[1\].*face indices"):
        r.render([m, Mesh(m.vertices, m.faces + np.int32(5))])
    bad_v = m.vertices.copy()
    bad_v[3, 1] = np.nan
    with pytest.raises(ValueError, match=r"meshes\[0\].*finite"):
        r.render([Mesh(bad_v, m.faces), m])
    assert not r.depth.any() and np.all(r.labels == -1)   # nothing half-drawn is left behind
    np.testing.assert_array_equal(r.render([m])[0], ref)


def _tz(z):
    T = np.eye(4)
    T[2, 3] = z
    return T


# ------------------------------------------------------------ Embree oracle
def _ids(labels, faces):
    return np.where(labels >= 0, labels.astype(np.int64) * (1 << 32) + faces, -1)


def _in_neighbourhood(values, img):
    """(H, W) bool: ``values[p]`` occurs in the 3x3 neighbourhood of p in ``img``."""
    H, W = img.shape
    pad = np.pad(img, 1, constant_values=-2)
    found = np.zeros((H, W), bool)
    for dv in range(3):
        for du in range(3):
            found |= pad[dv:dv + H, du:du + W] == values
    return found


def assert_matches_embree(cam, meshes, cull_back=True, near=0.01):
    """Depths agree within 0.1 mm where both show the same face of the same mesh. Where
    they show different faces, either the depths still agree (a shared edge, or coincident
    surfaces of two meshes) or each one's face is within one pixel in the other's image
    (silhouettes differ by at most one pixel along edges); such pixels must be rare.
    Returns the number of pixels that show the same face in both."""
    pytest.importorskip("embreex")
    r = Renderer(cam, near=near)
    depth, labels = r.render(meshes, cull_back=cull_back)
    ids = _ids(labels, r.face_index())
    de, le, fe = EmbreeCaster(cam).cast(meshes)
    ide = _ids(le, fe)
    assert (ids >= 0).sum() > 0.02 * ids.size, "scene barely visible: a weak test"
    dz = np.abs(depth.astype(float) - de)
    same = (ids == ide) & (ids >= 0)
    assert dz[same].max(initial=0.0) <= 1e-4, f"max |depth - embree| = {dz[same].max():.2e} m"
    both = (ids >= 0) & (ide >= 0)
    edge = (ids != ide) & ~(both & (dz <= 1e-4))      # a different surface, or a hit against none
    ok = _in_neighbourhood(ids, ide) & _in_neighbourhood(ide, ids)
    bad = edge & ~ok
    assert not bad.any(), (f"{bad.sum()} pixels differ from Embree by more than one pixel, "
                           f"e.g. (v, u) = {np.argwhere(bad)[:5].tolist()}")
    assert edge.sum() <= max(5, 1e-3 * (ids >= 0).sum()), f"{edge.sum()} pixels differ from Embree"
    return same.sum()


@pytest.mark.parametrize("seed", range(4))
def test_random_triangle_soup_matches_embree(seed):
    rng = np.random.default_rng(100 + seed)
    eye = rng.uniform([-1, -3, 0.5], [1, -2, 2])
    cam = camera(w=160, h=120, f=140.0, T=look_at(eye, rng.uniform(-0.3, 0.3, 3), np.array([0, 0, 1.0])))
    tris = []
    for _ in range(300):
        c = rng.uniform([-1.2, -1.2, -0.8], [1.2, 1.2, 1.2])
        tris.append((c + rng.normal(size=(3, 3)) * rng.uniform(0.05, 0.3), np.array([[0, 1, 2]])))
    assert assert_matches_embree(cam, tris, cull_back=False) > 3000


@pytest.mark.parametrize("seed", range(3))
def test_closed_primitives_match_embree(seed):
    rng = np.random.default_rng(200 + seed)
    eye = rng.uniform([-1, -3, 0.5], [1, -2, 2])
    cam = camera(w=160, h=120, f=120.0, T=look_at(eye, np.zeros(3), np.array([0, 0, 1.0])))
    prims = [Box.from_bounds([-2, -2, -0.62], [2, 2, -0.6])]
    for i in range(12):
        c = rng.uniform(-0.6, 0.6, 3)
        kind = i % 4
        if kind == 0:
            prims.append(Sphere(radius=rng.uniform(0.1, 0.3), segments=24).moved(_at(c)))
        elif kind == 1:
            prims.append(Box(size=tuple(rng.uniform(0.1, 0.5, 3))).moved(_at(c, rng)))
        elif kind == 2:
            prims.append(Capsule.between(c, c + rng.normal(size=3) * 0.3, rng.uniform(0.03, 0.1)))
        else:
            prims.append(Cylinder.between(c, c + rng.normal(size=3) * 0.3, rng.uniform(0.03, 0.1)))
    assert assert_matches_embree(cam, [p.mesh() for p in prims], cull_back=True) > 5000


def _at(c, rng=None):
    T = np.eye(4)
    if rng is not None:
        q = rng.normal(size=4)
        from depthguard.transforms import quat_to_matrix
        T[:3, :3] = quat_to_matrix(q / np.linalg.norm(q))
    T[:3, 3] = c
    return T


def _cells():
    try:
        from depthguard.sim import list_cells
    except ImportError:
        sim_init = Path(dg.__file__).parent / "sim" / "__init__.py"
        if sim_init.exists():
            raise
        return [pytest.param(None, marks=pytest.mark.skip(
            reason="depthguard.sim (load_cell, list_cells) does not exist yet"))]
    return list_cells()


@pytest.mark.parametrize("name", _cells())
def test_builtin_cells_match_embree(name):
    """Every camera of every built-in cell, the scene at t = 0 with the robot, culling on."""
    from depthguard.sim import load_cell

    cell = load_cell(name)
    meshes, names = cell.scene.meshes_at(0.0)
    assert len(meshes) == len(names) and meshes
    for cam in cell.rig.cameras:
        assert_matches_embree(cam, meshes, cull_back=True)


@pytest.mark.slow
def test_bench_group_quick_rows():
    """The ``render`` bench group (quick mode) yields its five rows, each with the Embree
    peer measured on the same frame (no speed is asserted: timings belong to the bench)."""
    from depthguard.evaluation.bench import BenchContext
    from depthguard.evaluation.bench.render import bench_render

    pytest.importorskip("embreex")

    rows = {r.name: r for r in bench_render(BenchContext(quick=True, repeats=3))}
    assert set(rows) == {"render.ur3_cell.640x480_ms", "render.ur3_cell.1280x720_ms",
                         "render.soup200k.640x480_ms", "render.ur3_cell.robot_640x480_ms",
                         "render.flacco_cell.robot_640x480_ms"}
    for r in rows.values():
        assert r.unit == "ms" and r.peer == "embree"
        assert np.isfinite(r.value) and r.value > 0
        assert np.isfinite(r.peer_value) and r.peer_value > 0


def test_composite_of_separate_renders_is_the_joint_render():
    """Static scene rendered once + people + robot rendered per frame, combined per pixel by
    ``nearest_depth``: bit for bit the image of all meshes rendered together (the closed loop's
    camera simulation relies on it)."""
    from depthguard.render import Renderer
    from depthguard.render.composite import nearest_depth
    from depthguard.sim import load_cell
    from depthguard.sim.people import Key, Person

    cell = load_cell("flacco-cell")
    robot = cell.rig.robot
    rng = np.random.default_rng(3)
    static = [p.mesh() for p in cell.scene.static]
    for cam in cell.rig.cameras:
        r_all, r_part = Renderer(cam), Renderer(cam)
        base = np.array(r_part.render(static)[0], copy=True)
        for _ in range(3):
            q = np.clip(robot.q_home + rng.uniform(-0.8, 0.8, robot.dof), robot.q_min, robot.q_max)
            arm = robot.link_meshes(q)
            xy = tuple(rng.uniform(-1.2, 0.2, 2))
            people = [p.mesh() for p in Person(name="p", keys=[Key(0.0, xy, 0.5)]).primitives(0.0)]
            want = np.array(r_all.render(static + people + arm)[0], copy=True)
            got = base.copy()
            nearest_depth(got, r_part.render(people)[0])
            nearest_depth(got, r_part.render(arm)[0])
            assert (want > 0).mean() > 0.3 and (want != base).sum() > 1000   # the arm / person show
            assert np.array_equal(got, want)
    with pytest.raises(ValueError, match="one shape"):
        nearest_depth(np.zeros((2, 3), np.float32), np.zeros((3, 2), np.float32))


def test_copy_depth_rows_over_spans_equals_a_whole_copy():
    """``copy_depth_rows`` into a buffer that held another robot image (and into a new one, its
    spans the whole rows) over the spans of both gives, frame after frame as the robot moves in
    and out of view, bit for bit ``numpy.copyto`` of the renderer's image, and the renderer's
    spans; spans that leave a drawn pixel out would not (the check can fail)."""
    from depthguard.filtering.expected import ExpectedDepth
    from depthguard.render.composite import copy_depth_rows
    from depthguard.sim import load_cell

    rig = load_cell("ur3-cell").rig
    robot = rig.robot
    rng = np.random.default_rng(11)
    qs = [np.clip(robot.q_home + rng.uniform(-1.5, 1.5, robot.dof), robot.q_min, robot.q_max) for _ in range(5)]
    cam = rig.cameras[0]
    H, W = cam.shape
    ex, away = ExpectedDepth(cam, robot, []), ExpectedDepth(cam, robot.with_base(_tz(50.0)), [])
    dst = rng.uniform(0.1, 5.0, (H, W)).astype(np.float32)      # a new buffer: anything in it
    spans = np.zeros((H, 2), np.int32)
    spans[:, 1] = W
    drawn = 0
    for e, q in [(ex, q) for q in qs] + [(away, qs[0]), (ex, qs[1]), (ex, qs[1])]:
        src = e.robot(q)
        copy_depth_rows(dst, spans, src, e.robot_spans)
        assert np.array_equal(dst.view(np.uint32), np.asarray(src).view(np.uint32))
        assert np.array_equal(spans, e.robot_spans)
        drawn += int((src > 0).sum())
    assert drawn > 5000
    # spans one pixel short on a row with robot pixels: that pixel is not copied
    src = ex.robot(qs[2])
    v = int(np.flatnonzero((src > 0).any(axis=1))[0])
    short = np.array(ex.robot_spans, copy=True)
    short[v, 1] -= 1
    dst2 = np.zeros((H, W), np.float32)
    copy_depth_rows(dst2, np.zeros((H, 2), np.int32), src, short)
    assert not np.array_equal(dst2, src)
    with pytest.raises(ValueError, match="do not match"):
        copy_depth_rows(dst, spans, np.zeros((2, 3), np.float32), spans)
