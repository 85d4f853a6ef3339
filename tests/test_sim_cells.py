"""The built-in cells: their geometry against the papers' set-ups (analytic and rendered checks)."""

import itertools
import math

import numpy as np
import pytest

from depthguard.render import render_depth
from depthguard.sim import list_cells, load_cell
from depthguard.sim.ground_truth import MeshSolid, occupancy


@pytest.fixture(scope="module")
def cells():
    return {name: load_cell(name) for name in list_cells()}


def test_every_cell_loads_with_rig_scene_and_situations(cells):
    assert set(cells) == {"flacco-walls", "flacco-cell", "ur3-cell", "c-arm-room"}
    for name, c in cells.items():
        assert c.rig.cameras and c.description and c.situations
        for s in c.situations.values():
            scene, t = c.scene_for(s.name)
            meshes, names = scene.meshes_at(t)
            assert len(meshes) == len(names) > 0
            assert len(scene.robot_q(t)) == (0 if scene.robot is None else scene.robot.dof)
    with pytest.raises(ValueError, match="situations: robot_alone"):
        cells["flacco-cell"].scene_for("nope")
    with pytest.raises(ValueError, match="built-in cells"):
        load_cell("no-such-cell")


# ------------------------------------------------------------- flacco-walls
def nearest_obstacle(scene, p):
    obs = scene.obstacles_at(0.0)
    d = {o.name: float(o.sdf(np.atleast_2d(p))[0]) for o in obs}
    return min(d, key=d.get), d


def test_flacco_walls_nearest_obstacle_switches_at_x_0_1572(cells):
    scene = cells["flacco-walls"].scene
    assert nearest_obstacle(scene, [0.1562, 0.4, 0.2])[0] == "wall"
    assert nearest_obstacle(scene, [0.1582, 0.4, 0.2])[0] == "table"
    for x in np.linspace(-0.5, 0.5, 41):
        name, d = nearest_obstacle(scene, [x, 0.4, 0.2])
        assert name == ("wall" if x < 0.1572 else "table")
        # analytic: wall face y = 0.37 (x <= 0) or its edge (x > 0); table plane at z = 0.04
        wall = 0.03 if x <= 0 else math.hypot(x, 0.03)
        assert scene.true_distance(np.array([[x, 0.4, 0.2]]), 0.0)[0] == pytest.approx(min(wall, 0.16), abs=1e-12)
    # the switch point by bisection, against the paper's 0.1572
    lo, hi = 0.1, 0.2
    for _ in range(40):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if nearest_obstacle(scene, [mid, 0.4, 0.2])[0] == "wall" else (lo, mid)
    assert lo == pytest.approx(0.1572, abs=5e-5)


def test_flacco_walls_camera_sees_the_x0_face_but_not_the_y037_face(cells):
    c = cells["flacco-walls"]
    cam = c.rig.camera("cam0")
    assert cam.sensor == "kinect_v1"
    meshes, names = c.scene.meshes_at(0.0)
    depth, labels = render_depth(cam, meshes, labels=True)
    wall = names.index("wall")
    # points of the x = 0 face (slightly inside its edges): seen, labelled wall, at their own depth
    yy, zz = np.meshgrid(np.linspace(0.335, 0.365, 4), np.linspace(0.06, 0.48, 12))
    face_x0 = np.c_[np.zeros(yy.size), yy.ravel(), zz.ravel()]
    ds = cam.world_to_depth_space(face_x0)
    u, v = cam.pixel_of(ds[:, 0], ds[:, 1])
    assert cam.in_view(face_x0).all()
    assert (labels[v, u] == wall).all()
    np.testing.assert_allclose(depth[v, u], ds[:, 2], atol=0.01)
    # the y = 0.37 face: the camera is on its inner side (y < 0.37), so it faces away, and no pixel
    # shows a surface point of it (a wall pixel whose back-projection lies on y = 0.37)
    assert cam.position[1] < 0.37
    pts = cam.depth_to_points(np.where(labels == wall, depth, 0).astype(np.float32))
    assert len(pts) > 50
    on_face = (np.abs(pts[:, 1] - 0.37) < 1e-3) & (pts[:, 0] < -0.005) & (pts[:, 2] < 0.495)
    assert not on_face.any()
    # the wall pixels are on the x = 0 face or the top face, nothing else
    ok = (np.abs(pts[:, 0]) < 0.003) | (np.abs(pts[:, 2] - 0.5) < 0.003)
    assert ok.mean() > 0.99


# -------------------------------------------------------------- flacco-cell
def test_flacco_cell_rig_matches_the_paper(cells):
    c = cells["flacco-cell"]
    rig = c.rig
    assert rig.robot.name == "lwr4" and rig.robot.dof == 7
    np.testing.assert_allclose(rig.workspace.lo, [-1.5, -1.5, -0.5])
    np.testing.assert_allclose(rig.workspace.hi, [1.5, 1.5, 1.5])
    c0, c1 = rig.camera("cam0"), rig.camera("cam1")
    assert np.linalg.norm(c0.position - c1.position) == pytest.approx(4.0, abs=0.3)
    assert c0.position[1] < 0 < c1.position[1]  # principal on the right, seen from the front (+x)
    # the robot is in view of both cameras
    q = c.scene.robot_q(1.0)
    cps = rig.robot.control_point_positions(q)
    assert c0.in_view(cps).all() and c1.in_view(cps).all()


def robot_surface_points(scene, t):
    return np.concatenate([m.vertices for m in scene.robot.link_meshes(scene.robot_q(t))])


def test_flacco_cell_shadow_situation(cells):
    c = cells["flacco-cell"]
    scene, t = c.scene_for("shadow")
    person = [p for p in scene.obstacles_at(t) if p.name.startswith("operator/")]
    # far from the robot: every robot surface point more than 0.5 m from the person
    from depthguard.sim.ground_truth import true_distance
    assert true_distance(person, robot_surface_points(scene, t)).min() > 0.5
    # and between the principal camera and the robot: the person hides robot pixels in cam0
    cam = c.rig.camera("cam0")
    meshes, names = scene.meshes_at(t)
    _, lab = render_depth(cam, meshes, labels=True)
    robot_only, _ = scene.meshes_at(t)[0][len(names) - len(scene.robot.link_mesh_names):], None
    d_robot = render_depth(cam, robot_only)
    hidden_by_person = (d_robot > 0) & np.isin(lab, [i for i, n in enumerate(names) if n.startswith("operator/")])
    assert hidden_by_person.sum() > 200
    # cam1 sees the person beside the robot, not in front of it
    cam1 = c.rig.camera("cam1")
    _, lab1 = render_depth(cam1, meshes, labels=True)
    d_robot1 = render_depth(cam1, robot_only)
    hidden1 = (d_robot1 > 0) & np.isin(lab1, [i for i, n in enumerate(names) if n.startswith("operator/")])
    assert hidden1.sum() < 0.1 * hidden_by_person.sum()


def test_flacco_cell_hidden_hand_situation(cells):
    c = cells["flacco-cell"]
    scene, t = c.scene_for("hidden_hand")
    meshes, names = scene.meshes_at(t)
    hand = next(p for p in scene.obstacles_at(t) if p.name == "operator/right_hand")
    centre = hand.world_from_local[:3, 3]
    robot_ids = [i for i, n in enumerate(names) if n.startswith("robot/")]
    # close behind the robot
    from depthguard.sim.ground_truth import true_distance
    assert true_distance([hand], robot_surface_points(scene, t)).min() < 0.15
    for cid, seen in (("cam0", False), ("cam1", True)):
        cam = c.rig.camera(cid)
        depth, lab = render_depth(cam, meshes, labels=True)
        ds = cam.world_to_depth_space(centre[None])[0]
        u, v = cam.pixel_of(ds[0], ds[1])
        if seen:
            assert names[lab[v, u]] == "operator/right_hand"
        else:
            assert lab[v, u] in robot_ids and depth[v, u] < ds[2] - hand.radius


def test_flacco_cell_reach_and_carry_are_scripted_right(cells):
    c = cells["flacco-cell"]
    scene, t = c.scene_for("reach")
    ee = c.rig.robot.control_point_positions(scene.robot_q(t))[0]
    hand = next(p for p in scene.obstacles_at(t) if p.name == "operator/right_hand")
    gap = np.linalg.norm(hand.world_from_local[:3, 3] - ee)
    assert 0.05 < gap < 0.1
    # the box is put down on the robot table (top z = 0) and rests there afterwards
    box = next(p for p in scene.obstacles_at(21.0) if p.name == "box")
    assert box.bounds()[0, 2] == pytest.approx(0.0, abs=0.01)
    assert scene.robot_q(0.0) is not None and c.scene_for("robot_alone")[1] < scene.people[0].present[0]


# ----------------------------------------------------------------- ur3-cell
def test_ur3_cell(cells):
    c = cells["ur3-cell"]
    rig = c.rig
    assert rig.robot.name == "ur3" and len(rig.cameras) == 4
    assert {cam.sensor for cam in rig.cameras} == {"realsense_d435"}
    assert all(cam.shape == (480, 640) for cam in rig.cameras)
    ring = next(o for o in c.scene.static if o.name == "ring_fixture")
    assert isinstance(ring, MeshSolid) and ring.watertight
    # the mesh was scaled from millimetres: 120 mm across, standing on the table top
    b = ring.bounds()
    assert b[1, 0] - b[0, 0] == pytest.approx(0.12, abs=1e-3) and b[0, 2] == pytest.approx(0.8, abs=1e-6)
    scene = c.scene
    _, t = c.scene_for("arm_reaching")
    hand = next(p for p in scene.obstacles_at(t) if p.name == "operator/right_hand").world_from_local[:3, 3]
    assert rig.workspace.contains(hand[None])[0] and hand[1] > -0.4  # over the table
    _, t = c.scene_for("box_placed")
    box = next(p for p in scene.obstacles_at(t) if p.name == "box")
    assert box.bounds()[0, 2] == pytest.approx(0.80, abs=0.005)  # resting on the table top
    _, t = c.scene_for("robot_alone")
    assert not any(p.name.startswith("operator/") for p in scene.obstacles_at(t))


# --------------------------------------------------------------- c-arm-room
def test_carm_room_has_the_papers_contents(cells):
    c = cells["c-arm-room"]
    rig = c.rig
    assert len(rig.cameras) == 21 and {cam.sensor for cam in rig.cameras} == {"tof"}
    np.testing.assert_allclose(rig.workspace.hi - rig.workspace.lo, [4.0, 4.0, 2.5])
    assert [s for s in c.situations] == [f"setup{i}" for i in range(1, 7)]
    names = {p.name.split("/")[0] for p in c.scene.obstacles_at(c.time_of("setup1"))}
    for want in ("table_top", "monitor", "light", "patient", "doctor", "nurse1", "nurse2",
                 "cabinet_1", "cabinet_2", "cabinet_3"):
        assert want in names
    # the setups differ in C-arm pose
    qs = [c.scene.robot_q(s.time) for s in c.situations.values()]
    assert len({tuple(np.round(q, 6)) for q in qs}) == 6
    for q in qs:
        assert (q >= c.robot.q_min).all() and (q <= c.robot.q_max).all()
    # every camera sits inside the room, not inside an obstacle
    for cam in rig.cameras:
        assert rig.workspace.contains(cam.position[None])[0]
        assert c.scene.true_distance(cam.position[None], 0.0)[0] > 0.02


def test_carm_room_setups_are_collision_free(cells):
    """Nothing overlaps the C-arm, and people stand clear of the furniture, in every setup."""
    c = cells["c-arm-room"]
    lo, hi = c.rig.workspace.lo, c.rig.workspace.hi
    for s in c.situations.values():
        groups = {}
        for p in c.scene.obstacles_at(s.time):
            groups.setdefault(p.name.split("/")[0], []).append(p)
        groups["carm"] = c.scene.robot_primitives(s.time)
        occ = {g: occupancy(ps, lo, hi, 0.04) for g, ps in groups.items()}
        movers = {"carm", "doctor", "nurse1", "nurse2"}  # furniture touches furniture by design
        clashes = [(a, b) for a, b in itertools.combinations(occ, 2)
                   if {a, b} & movers and {a, b} != {"patient", "doctor"} and (occ[a] & occ[b]).any()]
        assert not clashes, (s.name, clashes)


@pytest.mark.parametrize("name", ["flacco-cell", "ur3-cell", "c-arm-room"])
def test_every_camera_sees_the_scene_and_the_machine(cells, name):
    """Noiseless renders of the first situation: each camera sees the cell, most see the robot."""
    from depthguard.sources import SimSource

    c = cells[name]
    t = list(c.situations.values())[0].time
    frames = SimSource(c, noiseless=True).frames(t, labels=True)
    names = c.scene.meshes_at(t)[1]
    robot_ids = np.array([i for i, n in enumerate(names) if n.startswith("robot/")])
    sees_robot = 0
    for cid, f in frames.items():
        assert (f.depth > 0).mean() > 0.3, cid
        sees_robot += int(np.isin(f.labels, robot_ids).sum() > 100)
    assert sees_robot >= 0.75 * len(frames)


def test_robot_joint_override_and_ground_truth_excludes_the_robot(cells):
    c = cells["flacco-cell"]
    scene, t = c.scene_for("robot_alone")
    q = scene.robot_q(t) + 0.3
    m_script, names = scene.meshes_at(t)
    m_q, _ = scene.meshes_at(t, q=q)
    i = names.index("robot/link7")
    np.testing.assert_allclose(m_q[i].vertices, c.rig.robot.link_meshes(q)[c.rig.robot.link_mesh_names.index("link7")].vertices)
    assert not np.allclose(m_q[i].vertices, m_script[i].vertices)
    # the robot is not an obstacle: its control points have positive true distance ...
    cps = c.rig.robot.control_point_positions(scene.robot_q(t))
    assert (scene.true_distance(cps, t) > 0.05).all()
    # ... but it is in the occupancy when asked for
    lo, hi = np.array([-0.8, -0.8, 0.0]), np.array([0.8, 0.8, 1.2])
    without = scene.occupancy(lo, hi, 0.04, t)
    with_robot = scene.occupancy(lo, hi, 0.04, t, robot=True)
    assert (with_robot & ~without).sum() > 20 and not (without & ~with_robot).any()
    with pytest.raises(ValueError, match="7 joint values"):
        scene.meshes_at(t, q=[0.0, 1.0])


@pytest.mark.parametrize("name", ["flacco-cell", "ur3-cell"])
def test_people_never_walk_through_furniture_or_the_robot(cells, name):
    """Along the whole script, no surface point of a person lies inside furniture or the robot."""
    scene = cells[name].scene
    for t in np.arange(0.0, scene.duration + 1e-9, 0.25):
        obs = scene.obstacles_at(t)
        body = [p for p in obs if "/" in p.name]
        if not body:
            continue
        others = [p for p in obs if "/" not in p.name and p.name != "box"] + scene.robot_primitives(t)
        pts = np.concatenate([p.mesh().vertices for p in body])
        pts = pts[pts[:, 2] > scene.people[0].floor_z + 0.02]  # the soles stand on the floor
        for o in others:  # only points inside the obstacle's bounding box can be inside it
            lo, hi = o.bounds()
            near = np.all((pts >= lo - 0.01) & (pts <= hi + 0.01), axis=1)
            if near.any():
                assert o.sdf(pts[near]).min() > 0.0, (t, o.name)
