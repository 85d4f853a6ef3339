"""Robot model (R9, R16): geometry and capsules, control points, URDF loading details, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.geometry import Capsule, Mesh
from depthguard.robot import ControlPoint, available_robots, fit_capsule, load_robot
from depthguard.robot.capsules import point_segment_distance
from depthguard.transforms import pose, rot_x



@pytest.fixture(scope="module")
def lwr():
    return load_robot("lwr4")


@pytest.fixture(scope="module")
def ur3():
    return load_robot("ur3")


def _surface_samples(m: Mesh, n: int, rng) -> np.ndarray:
    """Vertices plus ``n`` area-weighted random points on the triangles."""
    v, f = m.vertices, m.faces
    A, B, C = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area = np.linalg.norm(np.cross(B - A, C - A), axis=1)
    idx = rng.choice(len(f), n, p=area / area.sum())
    u = rng.random((n, 2))
    flip = u.sum(1) > 1
    u[flip] = 1 - u[flip]
    return np.vstack([v, A[idx] + u[:, :1] * (B[idx] - A[idx]) + u[:, 1:] * (C[idx] - A[idx])])


# ------------------------------------------------------------------ geometry
def test_ur3_has_the_real_collision_meshes(ur3):
    assert ur3.link_mesh_names[:7] == ("base_link", "shoulder_link", "upper_arm_link", "forearm_link",
                                       "wrist_1_link", "wrist_2_link", "wrist_3_link")
    meshes = ur3.link_meshes(ur3.q_home)
    assert len(meshes) == len(ur3.link_mesh_names)
    assert sum(len(m.faces) for m in meshes) > 20000          # the STLs, not a stand-in
    # the upper arm mesh spans the 0.24365 m upper-arm length (+ housings)
    ext = np.ptp(ur3.local_link_meshes()["upper_arm_link"].vertices, axis=0)
    assert 0.30 < ext.max() < 0.34


@pytest.mark.parametrize("which", ["ur3", "lwr4"])
def test_link_meshes_face_outward(which, ur3, lwr, rng):
    """Embree rays from outside: the first face hit faces the ray (back-face culling keeps it)."""
    pytest.importorskip("embreex")
    import trimesh

    robot = {"ur3": ur3, "lwr4": lwr}[which]
    for ln, m in robot.local_link_meshes().items():
        t = trimesh.Trimesh(m.vertices, m.faces, process=False)
        c, size = t.bounds.mean(0), np.ptp(t.bounds, 0)
        d = rng.normal(size=(3000, 3))
        origins = c + 2 * np.linalg.norm(size) * d / np.linalg.norm(d, axis=1)[:, None]
        dirs = c + rng.uniform(-0.5, 0.5, (3000, 3)) * size - origins
        dirs /= np.linalg.norm(dirs, axis=1)[:, None]
        _, ray, tri = t.ray.intersects_location(origins, dirs, multiple_hits=False)
        assert len(ray) > 1000, ln
        facing_away = np.einsum("ij,ij->i", t.face_normals[tri], dirs[ray]) > 0
        assert facing_away.mean() < 1e-3, f"{ln}: {facing_away.mean():.2%} of visible faces wound inward"


@pytest.mark.parametrize("which", ["ur3", "lwr4"])
def test_capsules_cover_link_meshes_at_random_q(which, ur3, lwr, rng):
    """Every vertex and surface sample of each link's mesh lies inside that link's capsules (world)."""
    robot = {"ur3": ur3, "lwr4": lwr}[which]
    for q in rng.uniform(-np.pi, np.pi, size=(3, robot.dof)):
        q = np.clip(q, robot.q_min, robot.q_max)
        caps = robot.collision_capsules(q)
        meshes = robot.link_meshes(q)
        for ln, m in zip(robot.link_mesh_names, meshes):
            mine = [c for c, lc in zip(caps, robot.capsules) if lc.link == ln]
            assert mine, f"{ln} has no capsule"
            pts = _surface_samples(m, 4000, rng)
            sd = np.min([c.sdf(pts) for c in mine], axis=0)      # Capsule.sdf: exact, geometry module
            assert sd.max() <= 1e-4, f"{which} {ln}: a mesh point lies {sd.max() * 1e3:.2f} mm outside"


def test_ur3_capsules_are_tight(ur3):
    """Each capsule touches its mesh within 6 mm somewhere (no capsule is grossly oversized)."""
    meshes = ur3.local_link_meshes()
    for c in ur3.capsules:
        v = meshes[c.link].vertices
        gap = c.radius - point_segment_distance(v, c.a, c.b)
        assert gap.min() < 0.006, f"{c.name}: nearest vertex {gap.min() * 1e3:.1f} mm inside the surface"
        assert c.radius <= 0.08


def test_lwr4_is_sized_like_the_real_arm(lwr):
    caps = lwr.collision_capsules(np.zeros(7))
    for c in caps:
        a, b = c.segment()
        np.testing.assert_allclose([a[0], a[1], b[0], b[1]], 0, atol=1e-12)   # on the axis at q = 0
    top = max(max(c.segment()[0][2], c.segment()[1][2]) + c.radius for c in caps)
    np.testing.assert_allclose(top, 1.1785, atol=1e-9)                          # flange height
    assert all(0.035 <= c.radius <= 0.075 for c in caps)
    low = min(min(c.segment()[0][2], c.segment()[1][2]) - c.radius for c in caps)
    assert abs(low) < 1e-9                                                     # stands on the base plane


def test_collision_capsules_padding_and_base(ur3):
    T = pose(rot_x(0.3), [1.0, 2.0, 0.5])
    q = ur3.q_home
    plain = ur3.collision_capsules(q)
    padded = ur3.with_base(T).collision_capsules(q, padding=0.05)
    assert len(plain) == len(padded) == len(ur3.capsules)
    for a, b in zip(plain, padded):
        assert isinstance(b, Capsule)
        assert b.radius == pytest.approx(a.radius + 0.05)
        for pa, pb in zip(a.segment(), b.segment()):
            np.testing.assert_allclose(T[:3, :3] @ pa + T[:3, 3], pb, atol=1e-12)
    with pytest.raises(ValueError, match="padding"):
        ur3.collision_capsules(q, padding=-0.1)


@pytest.mark.parametrize("which", ["ur3", "lwr"])
def test_collision_segments_are_the_link_poses_applied_to_the_capsules(which, ur3, lwr, rng):
    """The capsules' world end points (one compiled posing, issue 29) are each capsule's link-frame
    end points under its link's pose, by numpy here (``link_pose``), and the arrays are the
    caller's: writing into one changes nothing the model returns next."""
    robot = {"ur3": ur3, "lwr": lwr}[which]
    for _ in range(5):
        q = rng.uniform(-np.pi, np.pi, robot.dof)
        ab, r = robot.collision_segments(q, 0.02)
        for k, c in enumerate(robot.capsules):
            T = robot.link_pose(q, c.link)
            for n, p in enumerate((c.a, c.b)):
                np.testing.assert_allclose(ab[k, n], T[:3, :3] @ np.asarray(p) + T[:3, 3], rtol=0, atol=1e-12)
            assert r[k] == c.radius + 0.02
        ab[:] = np.nan
        r[:] = np.nan
        ab2, r2 = robot.collision_segments(q, 0.02)
        assert np.isfinite(ab2).all() and np.isfinite(r2).all()


@pytest.mark.parametrize("which", ["ur3", "lwr"])
def test_posed_once_the_render_and_the_capsules_are_the_same_bits(which, ur3, lwr, rng):
    """A camera worker poses the links once a frame (``forward`` into its data) and hands the poses
    to the render's vertices and the capsules (issue 29): ``render_vertices_at`` and
    ``segments_at`` give, bit for bit, what ``render_link_vertices`` and ``collision_segments``
    give from the joints; poses that are not the model's (L, 4, 4) float64 are refused."""
    robot = {"ur3": ur3, "lwr": lwr}[which]
    data = robot.create_data()
    n = sum(len(m.vertices) for m in robot.render_link_topology(None))
    for _ in range(4):
        q = rng.uniform(-np.pi, np.pi, robot.dof)
        robot.forward(q, data)
        want = robot.render_link_vertices(q, None, np.empty((n, 3))).copy()
        np.testing.assert_array_equal(robot.render_vertices_at(data.link_poses, None, np.empty((n, 3))), want)
        ab, r = robot.collision_segments(q, 0.01)
        ab2, r2 = robot.segments_at(data.link_poses, 0.01)
        np.testing.assert_array_equal(ab2, ab)
        np.testing.assert_array_equal(r2, r)
    L = len(robot.link_names)
    for bad in (data.link_poses[:-1], data.link_poses.astype(np.float32), np.zeros((L, 4, 4, 1)),
                np.asfortranarray(np.zeros((L, 4, 4)))[:, ::1], data.link_poses.tolist()):
        with pytest.raises(ValueError, match="poses"):
            robot.segments_at(bad)
        with pytest.raises(ValueError, match="poses"):
            robot.render_vertices_at(bad, None, np.empty((n, 3)))


def test_fit_capsule_contains_random_clouds(rng):
    for _ in range(20):
        pts = rng.normal(size=(200, 3)) * rng.uniform(0.01, 0.3, 3) + rng.uniform(-1, 1, 3)
        a, b, r = fit_capsule(pts)
        assert point_segment_distance(pts, a, b).max() <= r + 1e-12
        # and not much bigger than the cloud: radius at most half the largest extent
        assert r <= 0.5 * np.linalg.norm(np.ptp(pts, axis=0)) + 1e-12


# ------------------------------------------------------------------ control points
def test_control_points_ee_first(lwr, ur3):
    assert lwr.control_points[0].link == "link7" and np.allclose(lwr.control_points[0].offset, 0)
    assert ur3.control_points[0].link == "tool0"
    assert 6 <= len(ur3.control_points) <= 8
    q = ur3.q_home
    np.testing.assert_allclose(ur3.control_point_positions(q)[0], ur3.link_pose(q, "tool0")[:3, 3], atol=1e-12)
    # each link control point lies inside the robot's capsules (it is on the arm, not beside it)
    for robot in (lwr, ur3):
        q = robot.q_home
        P = robot.control_point_positions(q)[1:]
        sd = np.min([c.sdf(P) for c in robot.collision_capsules(q)], axis=0)
        assert np.all(sd < 0)


def test_with_control_points_and_immutability(ur3):
    new = ur3.with_control_points([{"name": "ee", "link": "tool0", "offset": [0, 0, 0.1], "radius": 0.05},
                                   ControlPoint("elbow", "forearm_link", np.zeros(3), 0.05)])
    assert len(new.control_points) == 2 and len(ur3.control_points) == 8
    q = ur3.q_home
    T = ur3.link_pose(q, "tool0")
    np.testing.assert_allclose(new.control_point_positions(q)[0], T[:3, :3] @ [0, 0, 0.1] + T[:3, 3])
    assert new.control_point_jacobians(q).shape == (2, 3, 6)
    with pytest.raises(ValueError, match="unknown link 'nope'"):
        ur3.with_control_points([{"name": "x", "link": "nope"}])
    with pytest.raises(ValueError, match="offset"):
        ur3.with_control_points([{"name": "x", "link": "tool0", "offset": [0, 0]}])
    with pytest.raises(ValueError, match="at least one"):
        ur3.with_control_points([])
    with pytest.raises(ValueError):
        ur3.q_home[0] = 1.0
    with pytest.raises(ValueError):
        ur3.control_points[0].offset[0] = 1.0
    with pytest.raises(AttributeError, match="immutable"):
        ur3.base = np.eye(4)
    moved = ur3.with_base(pose(rot_x(0.1)))
    with pytest.raises(AttributeError, match="immutable"):
        moved.q_home = np.zeros(6)
    np.testing.assert_allclose(ur3.base, np.eye(4))


# ------------------------------------------------------------------ bad input
def test_unknown_robot_lists_known_names():
    with pytest.raises(ValueError) as e:
        load_robot("kuka_kr1000")
    for n in available_robots():
        assert n in str(e.value)
    assert set(available_robots()) >= {"lwr4", "ur3"}


def test_wrong_q_names_expected_dof(lwr):
    with pytest.raises(ValueError, match="7 joint values"):
        lwr.link_poses(np.zeros(6))
    with pytest.raises(ValueError, match="7 joint values"):
        lwr.forward(np.zeros(8), lwr.create_data())
    with pytest.raises(ValueError, match="finite"):
        lwr.control_point_positions([0, 0, np.nan, 0, 0, 0, 0])
    with pytest.raises(ValueError, match="finite"):
        lwr.forward(np.array([0, 0, 0, np.inf, 0, 0, 0]), lwr.create_data())
    with pytest.raises(ValueError, match="unknown link"):
        lwr.point_jacobian(np.zeros(7), "flange", [0, 0, 0])
    with pytest.raises(ValueError, match="p_local"):
        lwr.point_jacobian(np.zeros(7), 3, [0, 0])


def test_bad_base(lwr):
    with pytest.raises(ValueError, match="base pose"):
        lwr.with_base(np.diag([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(ValueError, match="base pose"):
        load_robot("ur3", base=np.eye(3))


def test_bad_urdfs(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_robot(str(tmp_path / "missing.urdf"))
    junk = tmp_path / "junk.urdf"
    junk.write_text("this is not <xml")
    with pytest.raises(ValueError, match="junk.urdf"):
        load_robot(str(junk))
    bad = tmp_path / "broken.urdf"
    bad.write_text("<robot name='x'><link name='a'/><joint name='j' type='revolute'><parent link='a'/>"
                   "<child link='b'/></joint></robot>")
    with pytest.raises(ValueError, match="unknown child link 'b'"):
        load_robot(str(bad))
    two_roots = tmp_path / "roots.urdf"
    two_roots.write_text("<robot name='x'><link name='a'/><link name='b'/></robot>")
    with pytest.raises(ValueError, match="one root"):
        load_robot(str(two_roots))
    floating = tmp_path / "floating.urdf"
    floating.write_text("<robot name='x'><link name='a'/><link name='b'/><joint name='f' type='floating'>"
                        "<parent link='a'/><child link='b'/></joint></robot>")
    with pytest.raises(ValueError, match="floating"):
        load_robot(str(floating))
    nomesh = tmp_path / "nomesh.urdf"
    nomesh.write_text("<robot name='x'><link name='a'><collision><geometry><mesh filename='package://nopkg/m.stl'/>"
                      "</geometry></collision></link></robot>")
    with pytest.raises(FileNotFoundError, match="nopkg"):
        load_robot(str(nomesh))


def test_urdf_tip_choice_and_branches(tmp_path):
    two_arms = tmp_path / "two.urdf"
    two_arms.write_text("""<robot name='y'><link name='root'/><link name='l'/><link name='r'/>
      <joint name='jl' type='revolute'><parent link='root'/><child link='l'/><axis xyz='0 0 1'/>
        <limit lower='-1' upper='1' velocity='1' effort='1'/></joint>
      <joint name='jr' type='revolute'><parent link='root'/><child link='r'/><axis xyz='0 1 0'/>
        <limit lower='-1' upper='1' velocity='1' effort='1'/></joint></robot>""")
    with pytest.raises(ValueError, match="tip="):
        load_robot(str(two_arms))
    r = load_robot(str(two_arms), tip="r")
    assert r.joint_names == ("jr",) and r.link_names == ("root", "r")


def test_package_uri_resolution(tmp_path):
    import trimesh

    pkg = tmp_path / "mypkg"
    (pkg / "meshes").mkdir(parents=True)
    (pkg / "urdf").mkdir()
    trimesh.creation.box(extents=[0.1, 0.2, 0.3]).export(pkg / "meshes" / "box.stl")
    (pkg / "urdf" / "r.urdf").write_text(
        "<robot name='p'><link name='a'><collision><origin xyz='0 0 1'/><geometry>"
        "<mesh filename='package://mypkg/meshes/box.stl' scale='2 2 2'/></geometry></collision></link>"
        "<link name='b'><visual><geometry><mesh filename='../meshes/box.stl'/></geometry></visual></link>"
        "<joint name='j' type='prismatic'><parent link='a'/><child link='b'/><axis xyz='0 0 1'/>"
        "<limit lower='0' upper='1' velocity='0.1' effort='1'/></joint></robot>")
    r = load_robot(str(pkg / "urdf" / "r.urdf"))
    a, b = r.local_link_meshes()["a"], r.local_link_meshes()["b"]
    np.testing.assert_allclose(a.bounds, [[-0.1, -0.2, 0.7], [0.1, 0.2, 1.3]], atol=1e-9)
    np.testing.assert_allclose(b.bounds, [[-0.05, -0.1, -0.15], [0.05, 0.1, 0.15]], atol=1e-9)
    assert len(a.vertices) == 8            # STL triangle soup welded
    # fitted capsules cover the meshes; the default control points are the tip and the moving link
    caps = r.collision_capsules(np.array([0.5]))
    pts = np.vstack([m.vertices for m in r.link_meshes(np.array([0.5]))])
    assert np.min([c.sdf(pts) for c in caps], axis=0).max() <= 1e-9
    assert [c.name for c in r.control_points] == ["ee", "b"]


def test_prismatic_urdf_primitive_geometry(tmp_path, prismatic_urdf):
    p = tmp_path / "s.urdf"
    p.write_text(prismatic_urdf)
    r = load_robot(str(p))
    assert r.link_mesh_names == ("rail", "carriage", "arm", "hand")
    np.testing.assert_allclose(r.local_link_meshes()["arm"].bounds, [[0, -0.02, -0.02], [0.3, 0.02, 0.02]])
