"""Scenes: people (arm IK, keyframes, carrying), props, robot paths, and the C-arm model."""

import math

import numpy as np
import pytest

from depthguard.geometry.primitives import Box, Sphere
from depthguard.sim import CArm, CArmPose, Carry, JointPath, Key, Person, Prop, Scene
from depthguard.sim.carm import CARM_LIMITS
from depthguard.transforms import pose


def person(**kw):
    keys = kw.pop("keys", [Key(0.0, (0.0, 0.0), 0.0), Key(2.0, (1.0, 0.0), math.pi / 2, right=(1.3, 0.5, 1.2))])
    return Person("p", keys, **kw)


def part(prims, name):
    return next(p for p in prims if p.name == name)


def test_arm_reaches_a_reachable_target_with_true_limb_lengths():
    pp = person()
    pose2 = pp.pose_at(2.0)
    S, E, H = pp.arm_points(pose2, "right")
    sh = pp.shape
    np.testing.assert_allclose(H, [1.3, 0.5, 1.2], atol=1e-9)
    assert np.linalg.norm(E - S) == pytest.approx(sh.upper_arm, abs=1e-9)
    assert np.linalg.norm(H - E) == pytest.approx(sh.forearm, abs=1e-9)
    assert E[2] < (S[2] + H[2]) / 2 + 1e-9  # elbow down
    hand = part(pp.primitives(2.0), "p/right_hand")
    np.testing.assert_allclose(hand.world_from_local[:3, 3], [1.3, 0.5, 1.2], atol=1e-9)


def test_unreachable_target_stretches_the_arm_towards_it():
    pp = person(keys=[Key(0.0, (0.0, 0.0), 0.0, left=(3.0, 3.0, 1.4))])
    S, E, H = pp.arm_points(pp.pose_at(0.0), "left")
    reach = pp.shape.upper_arm + pp.shape.forearm
    assert np.linalg.norm(H - S) == pytest.approx(0.999 * reach, rel=1e-9)
    u = (np.array([3.0, 3.0, 1.4]) - S) / np.linalg.norm(np.array([3.0, 3.0, 1.4]) - S)
    np.testing.assert_allclose((H - S) / np.linalg.norm(H - S), u, atol=1e-9)


def test_keyframes_interpolate_and_hold():
    pp = person()
    assert pp.pose_at(-1.0).xy.tolist() == [0.0, 0.0]
    assert pp.pose_at(1.0).xy.tolist() == pytest.approx([0.5, 0.0])  # eased, symmetric midpoint
    assert pp.pose_at(1.0).heading == pytest.approx(math.pi / 4)
    assert pp.pose_at(5.0).xy.tolist() == [1.0, 0.0]
    step = person(interp="step")
    assert step.pose_at(1.9).xy.tolist() == [0.0, 0.0]
    # the torso stands on the floor at the keyed position, facing the heading
    torso = part(pp.primitives(2.0), "p/torso")
    R = torso.world_from_local[:3, :3]
    np.testing.assert_allclose(R[:, 0], [0.0, 1.0, 0.0], atol=1e-12)
    lowest = min(p.bounds()[0, 2] for p in pp.primitives(2.0))
    assert lowest == pytest.approx(0.0, abs=1e-3)
    top = max(p.bounds()[1, 2] for p in pp.primitives(2.0))
    assert top == pytest.approx(pp.shape.height, abs=2e-3)


def test_presence_window():
    pp = person(present=(1.0, 3.0))
    assert pp.primitives(0.5) == [] and pp.primitives(3.0) == []
    assert len(pp.primitives(2.0)) == 11  # 2 legs, torso, neck, head, 2 x (upper arm, forearm, hand)


def test_carried_prop_follows_the_hand_then_stays_where_released():
    keys = [Key(0.0, (0.0, 0.0), 0.0, right=(0.4, -0.2, 1.0)), Key(4.0, (2.0, 1.0), 1.0, right=(2.3, 1.1, 1.0)),
            Key(6.0, (0.0, 0.0), 0.0)]
    pp = Person("p", keys, carries=[Carry("box", "right", 1.0, 4.0, (0.0, 0.0, -0.1))])
    box = Prop("box", Box(size=(0.2, 0.2, 0.1)), pose(t=[5.0, 5.0, 0.05]))
    sc = Scene([Sphere(radius=0.1, world_from_local=pose(t=[9, 9, 9]), name="ball")], people=[pp], props=[box])
    np.testing.assert_allclose(sc.prop_pose("box", 0.5), box.pose0)
    for t in (1.0, 2.5, 3.9):
        want = pp.hand_frame(t, "right") @ pose(t=[0, 0, -0.1])
        np.testing.assert_allclose(sc.prop_pose("box", t), want, atol=1e-12)
    released = pp.hand_frame(4.0, "right") @ pose(t=[0, 0, -0.1])
    np.testing.assert_allclose(sc.prop_pose("box", 5.5), released, atol=1e-12)
    np.testing.assert_allclose(released[:3, 3], [2.3, 1.1, 0.9], atol=1e-9)
    prim = part(sc.obstacles_at(5.5), "box")
    np.testing.assert_allclose(prim.world_from_local, released, atol=1e-12)
    names = sc.meshes_at(2.0)[1]
    assert names[0] == "ball" and "box" in names and "p/head" in names


def test_scene_checks_its_script():
    with pytest.raises(ValueError, match="unknown prop"):
        Scene(people=[Person("p", [Key(0, (0, 0))], carries=[Carry("nothing", "left", 0, 1)])])
    with pytest.raises(ValueError, match="unique"):
        Scene(people=[Person("p", [Key(0, (0, 0))]), Person("p", [Key(0, (0, 0))])])
    with pytest.raises(ValueError, match="hand"):
        Person("p", [Key(0, (0, 0))], carries=[Carry("b", "middle", 0, 1)])


def test_joint_path_interpolates_linear_and_step():
    jp = JointPath([(0.0, [0, 0]), (2.0, [1, -2])])
    np.testing.assert_allclose(jp(1.0), [0.5, -1.0])
    np.testing.assert_allclose(jp(-1), [0, 0])
    np.testing.assert_allclose(jp(9), [1, -2])
    st = JointPath([(0.0, [0, 0]), (2.0, [1, -2])], interp="step")
    np.testing.assert_allclose(st(1.99), [0, 0])
    np.testing.assert_allclose(st(2.0), [1, -2])
    with pytest.raises(ValueError, match="same number"):
        JointPath([(0, [0]), (1, [0, 1])])


# ------------------------------------------------------------------- C-arm
def part_centre(carm, p, name):
    return next(x for x in carm.primitives(p) if x.name == f"carm/{name}").world_from_local[:3, 3]


def test_carm_axes_meet_at_the_isocentre():
    carm = CArm()
    iso = carm.isocentre(CArmPose())
    det0 = part_centre(carm, CArmPose(), "detector")
    src0 = part_centre(carm, CArmPose(), "source")
    # zero pose: beam vertical, detector above, source below the isocentre
    np.testing.assert_allclose(det0 - iso, [0, 0, 0.50], atol=1e-12)
    np.testing.assert_allclose(src0 - iso, [0, 0, -0.55], atol=1e-12)
    rng = np.random.default_rng(1)
    for _ in range(20):
        q = rng.uniform(carm.q_min, carm.q_max)
        q[3] = 0.0
        p = CArmPose.from_array(q)
        det, src = part_centre(carm, p, "detector"), part_centre(carm, p, "source")
        np.testing.assert_allclose(carm.isocentre(p), iso)
        assert np.linalg.norm(det - iso) == pytest.approx(0.50, abs=1e-12)
        assert np.linalg.norm(src - iso) == pytest.approx(0.55, abs=1e-12)
        # source, isocentre and detector stay on one line (the beam)
        np.testing.assert_allclose(np.cross(det - iso, src - iso), 0, atol=1e-12)


def test_carm_propeller_and_orbit_turn_the_beam_in_their_planes():
    carm = CArm()
    iso = carm.isocentre(CArmPose())
    a = math.radians(30)
    # propeller turns about the horizontal axis along the L-arm (x at larm 0): beam stays in the y-z plane
    d = part_centre(carm, CArmPose(propeller=a), "detector") - iso
    np.testing.assert_allclose(d, 0.5 * np.array([0, -math.sin(a), math.cos(a)]), atol=1e-12)
    # C-arc (orbital) turns in the C plane (x-z at zero pose)
    d = part_centre(carm, CArmPose(carc=a), "detector") - iso
    np.testing.assert_allclose(d, 0.5 * np.array([math.sin(a), 0, math.cos(a)]), atol=1e-12)
    # L-arm turns the support around the vertical axis; longitudinal translates along the rail (x)
    s0 = part_centre(carm, CArmPose(), "support") - iso
    s1 = part_centre(carm, CArmPose(larm=math.pi / 2), "support") - iso
    np.testing.assert_allclose(s1, [-s0[1], s0[0], s0[2]], atol=1e-12)
    t = part_centre(carm, CArmPose(longitudinal=-0.4), "support") - part_centre(carm, CArmPose(), "support")
    np.testing.assert_allclose(t, [-0.4, 0, 0], atol=1e-12)


def test_carm_pose_names_limits_and_robot_like_api():
    p = CArmPose.degrees(larm=10, propeller=-20, carc=5, longitudinal=0.3)
    np.testing.assert_allclose(CArmPose.from_array(p.as_array()).as_array(), p.as_array())
    with pytest.raises(ValueError, match="carc"):
        CArmPose.degrees(carc=80).check()
    with pytest.raises(ValueError, match="4 values"):
        CArmPose.from_array([0, 0])
    carm = CArm()
    assert carm.dof == 4 and carm.joint_names == ("larm", "propeller", "carc", "longitudinal")
    assert carm.q_min[2] == CARM_LIMITS["carc"][0]
    ms = carm.link_meshes(p.as_array())
    assert len(ms) == len(carm.link_mesh_names) == len(carm.primitives(p))
    # every part's surface is within its own primitive's zero level set
    for prim, m in zip(carm.primitives(p), ms):
        assert np.abs(prim.sdf(m.vertices)).max() < 1e-9


def test_carm_padding_contains_the_offset_volume(rng):
    carm = CArm()
    q = CArmPose.degrees(larm=30, propeller=20, carc=-10).as_array()
    exact = carm.collision_primitives(q)
    padded = carm.collision_primitives(q, padding=0.05)
    # points within 5 cm of the machine lie inside the padded volume
    from depthguard.sim.ground_truth import true_distance
    pts = rng.uniform([-1.5, -1.5, 0.0], [1.5, 1.5, 2.5], (20000, 3))
    near = true_distance(exact, pts) <= 0.05
    assert near.sum() > 200
    assert (true_distance(padded, pts[near]) == 0).all()
    with pytest.raises(ValueError, match="padding"):
        carm.collision_primitives(q, padding=-1)


def test_walking_swings_the_legs_above_the_floor():
    walker = Person("w", [Key(0.0, (0.0, 0.0), 0.0), Key(4.0, (4.0, 0.0), 0.0)])
    still = Person("s", [Key(0.0, (0.0, 0.0), 0.0)])
    assert still.leg_swing(1.3) == 0.0
    swings = [walker.leg_swing(t) for t in np.linspace(1.0, 3.0, 41)]
    assert max(swings) > 0.2 and min(swings) < -0.2 and max(np.abs(swings)) <= math.radians(25) + 1e-12
    for t in np.linspace(0.5, 3.5, 13):
        prims = walker.primitives(t)
        assert min(p.bounds()[0, 2] for p in prims) >= -1e-9  # feet never sink into the floor
        legs = [p for p in prims if p.name.endswith("_leg")]
        a, b = (np.array(p.segment()) for p in legs)
        # the two feet mirror each other about the hips' vertical (opposite phase)
        fa, fb = a[np.argmin(a[:, 2])], b[np.argmin(b[:, 2])]
        hip_x = walker.pose_at(t).xy[0]
        assert (fa[0] - hip_x) == pytest.approx(-(fb[0] - hip_x), abs=1e-9)


def test_primitives_are_those_of_the_pose_also_when_kept_for_a_still_person():
    """``primitives(t)`` keeps the last solids while the pose does not change (a person who stands
    or holds a reach); every answer equals the solids built afresh from the pose at ``t``."""
    p = Person("p", [Key(0.0, (0.0, 0.0), 0.0), Key(1.0, (0.0, 0.0), 0.0),
                     Key(2.0, (0.0, 0.0), 0.0, right=(0.4, -0.2, 1.2)), Key(3.0, (1.0, 0.0), 0.3)])
    pts = np.random.default_rng(0).uniform(-1.0, 1.5, (200, 3))
    from depthguard.geometry import sdf_union
    seen = []
    for t in (0.1, 0.5, 0.9, 1.5, 1.6, 2.5, 2.5, 2.6, 3.5, 4.0):
        got = p.primitives(t)
        pose_t = p.pose_at(t)
        fresh = p.primitives_at(pose_t, p.leg_swing(t, pose_t))
        assert [g.name for g in got] == [f.name for f in fresh]
        np.testing.assert_array_equal(sdf_union(got, pts), sdf_union(fresh, pts))
        seen.append(got)
    assert seen[0][0] is seen[1][0] is seen[2][0]          # standing still: kept
    assert seen[3][0] is not seen[4][0]                    # reaching: new solids


def _prop_pose_reference(scene, name, t):
    """The props' pose as first written (a second implementation): every carry begun by ``t``
    applied in time order, the last one winning."""
    T = scene.props[name].pose0
    events = sorted(((c.t0, c, p) for p in scene.people for c in p.carries if c.prop == name), key=lambda e: e[0])
    for t0, c, p in events:
        if t < t0:
            break
        T = p.hand_frame(min(t, c.t1), c.hand) @ c.offset_matrix()
    return T


def _arm_reference(person, p, side):
    """A person's arm (shoulder, elbow, hand) as first written: ``np.linalg.norm``, a body frame
    and pole made afresh (a second implementation of ``Person._arm_points``)."""
    sh = person.shape
    T = person.body_frame(p.xy, p.heading)
    R, o = T[:3, :3], T[:3, 3]
    S = R @ sh.shoulder(side) + o
    target = getattr(p, side)
    if target is None:
        target = R @ sh.rest_hand(side) + o
    L1, L2 = sh.upper_arm, sh.forearm
    d_vec = np.asarray(target, float) - S
    d = float(np.linalg.norm(d_vec))
    u = d_vec / d if d > 1e-9 else R @ np.array([0.0, 0.0, -1.0])
    d = min(max(d, abs(L1 - L2) + 0.05), 0.999 * (L1 + L2))
    a = (L1 * L1 - L2 * L2 + d * d) / (2 * d)
    h = math.sqrt(max(L1 * L1 - a * a, 0.0))
    s = 1.0 if side == "left" else -1.0
    pole = R @ np.array([-0.2, 0.5 * s, -1.0])
    w = pole - (pole @ u) * u
    nw = np.linalg.norm(w)
    w = w / nw if nw > 1e-9 else R @ np.array([0.0, s, 0.0])
    return S, S + a * u + h * w, S + d * u


@pytest.mark.parametrize("name", ["flacco-cell", "ur3-cell"])
def test_posing_memos_give_the_bits_of_the_plain_computation(name):
    """Over each built-in cell's script (people walking, reaching, carrying a prop, putting it
    down): the props' solids (a prop's pose kept while it lies still) and the arms (the body
    frame made once per pose, norms as sqrt of the dot) equal, to the bit, the plain computation
    done afresh at every time."""
    from depthguard.sim import load_cell

    scene = load_cell(name).scene
    assert scene.props and any(p.carries for p in scene.people)
    still = moved = 0
    for t in np.linspace(0.0, scene.duration, 240, endpoint=False):
        t = float(t)
        prims = {p.name: p for p in scene.dynamic_at(t)}
        for pname, prop in scene.props.items():
            T = _prop_pose_reference(scene, pname, t) @ prop.shape.world_from_local
            got = prims[pname].world_from_local
            assert got.tobytes() == T.tobytes(), (pname, t)
        for person in scene.people:
            if not person.is_present(t):
                continue
            p = person.pose_at(t)
            for side in ("left", "right"):
                for a, b in zip(person.arm_points(p, side), _arm_reference(person, p, side)):
                    assert a.tobytes() == b.tobytes(), (person.name, side, t)
            moved += 1
        still += 1
    assert moved > 100 and still == 240


def test_the_local_mesh_cache_is_bounded_and_keeps_what_is_in_use():
    """A scene keeps at most ``MESH_CACHE_SIZE`` local meshes (a shape that varies per frame
    would grow the cache without end over a long run), the least recently used going first; a
    shape still in use is served from the cache (the same mesh object)."""
    from depthguard.geometry.primitives import Box
    from depthguard.sim import scene as scene_mod

    sc = scene_mod.Scene([], name="cache")
    kept = Box.from_bounds([0, 0, 0], [0.1, 0.1, 0.1], name="kept")
    first = sc._local_mesh(kept)
    for i in range(3 * scene_mod.MESH_CACHE_SIZE):
        sc._local_mesh(Box.from_bounds([0, 0, 0], [0.2 + 1e-3 * i, 0.1, 0.1], name="varying"))
        assert sc._local_mesh(kept) is first                   # in use: never evicted, never rebuilt
    assert len(sc._mesh_cache) <= scene_mod.MESH_CACHE_SIZE
    assert np.allclose(first.vertices.max(axis=0), [0.05, 0.05, 0.05])   # the box's own local mesh


def test_joint_path_is_the_searchsorted_formula():
    """``JointPath`` (keys found by bisect on floats) against its former numpy arithmetic
    (``np.searchsorted``, numpy scalars): the same bits at random times, on and between keys."""
    rng = np.random.default_rng(3)
    keys = [(float(t), rng.normal(size=6)) for t in np.cumsum(rng.uniform(0.2, 2.0, 7))]
    for interp in ("linear", "step"):
        jp = JointPath(keys, interp=interp)
        ts, qs = np.array([t for t, _ in keys]), np.stack([q for _, q in keys])
        times = np.concatenate([rng.uniform(ts[0] - 1, ts[-1] + 1, 500), ts])
        for t in times:
            if t <= ts[0]:
                want = qs[0]
            elif t >= ts[-1]:
                want = qs[-1]
            else:
                i = int(np.searchsorted(ts, t, side="right")) - 1
                s = (t - ts[i]) / (ts[i + 1] - ts[i])
                s = s * s * (3 - 2 * s)
                want = qs[i] if interp == "step" else (1 - s) * qs[i] + s * qs[i + 1]
            assert jp(float(t)).tobytes() == want.tobytes()
            assert jp(t).tobytes() == want.tobytes()            # a numpy scalar time too
