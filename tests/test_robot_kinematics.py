"""Robot kinematics (R14, R16): FK against yourdfpy and hand-computed poses, Jacobians against
finite differences, the numba kernel against its numpy twin, DH vs URDF for the UR3."""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.robot import load_robot, ur3_dh, ur3_urdf_path
from depthguard.robot.chain import forward_numpy, point_jacobian_numpy
from depthguard.transforms import pose, quat_to_matrix, rot_z

@pytest.fixture(scope="module")
def lwr():
    return load_robot("lwr4")


@pytest.fixture(scope="module")
def ur3():
    return load_robot("ur3")


@pytest.fixture(scope="module")
def slider(tmp_path_factory, prismatic_urdf):
    p = tmp_path_factory.mktemp("urdf") / "slider.urdf"
    p.write_text(prismatic_urdf)
    return load_robot(str(p)), p


def _random_q(robot, rng, n):
    lo = np.maximum(robot.q_min, -np.pi)
    hi = np.minimum(robot.q_max, np.pi)
    return rng.uniform(lo, hi, size=(n, robot.dof))


def _yourdfpy_fk_all(path, robot, q):
    import yourdfpy

    u = yourdfpy.URDF.load(str(path), build_scene_graph=True, load_meshes=False)
    assert list(u.actuated_joint_names) == list(robot.joint_names)
    u.update_cfg(q)
    root = robot.link_names[0]
    return np.stack([u.get_transform(frame_to=ln, frame_from=root) for ln in robot.link_names])


# ------------------------------------------------------------------ FK vs yourdfpy
def test_ur3_fk_matches_yourdfpy_every_link(ur3, rng):
    import yourdfpy

    u = yourdfpy.URDF.load(str(ur3_urdf_path()), build_scene_graph=True, load_meshes=False)
    assert list(u.actuated_joint_names) == list(ur3.joint_names)
    assert set(ur3.link_names) == {l.name for l in u.robot.links}   # the UR3 tree is one chain + fixed frames
    for q in _random_q(ur3, rng, 10):
        u.update_cfg(q)
        ours = ur3.link_poses(q)
        for k, ln in enumerate(ur3.link_names):
            ref = u.get_transform(frame_to=ln, frame_from="world")
            np.testing.assert_allclose(ours[k], ref, atol=1e-9, err_msg=ln)


def test_prismatic_urdf_fk_matches_yourdfpy(slider, rng):
    robot, path = slider
    assert robot.joint_names == ("slide", "turn", "lift", "wrist")
    assert robot.link_names[0] == "rail" and "tip" in robot.link_names
    np.testing.assert_allclose(robot.q_min[:3], [-0.4, -3, 0])
    assert robot.q_min[3] == -np.inf and robot.q_max[3] == np.inf       # continuous
    np.testing.assert_allclose(robot.qd_max[:3], [0.5, 1.0, 0.3])
    for q in _random_q(robot, rng, 5):
        np.testing.assert_allclose(robot.link_poses(q), _yourdfpy_fk_all(path, robot, q), atol=1e-9)


# ------------------------------------------------------------------ known LWR poses (by hand)
def test_lwr4_straight_up_at_zero(lwr):
    P = lwr.link_poses(np.zeros(7))
    flange = P[lwr.link_names.index("link7")]
    np.testing.assert_allclose(flange[:3, 3], [0, 0, 0.3105 + 0.4 + 0.39 + 0.078], atol=1e-12)
    np.testing.assert_allclose(flange[:3, :3], np.eye(3), atol=1e-12)
    # every joint origin on the z axis at the DH heights
    z = [0, 0.3105, 0.3105, 0.7105, 0.7105, 1.1005, 1.1005, 1.1785]
    np.testing.assert_allclose(P[:, :3, 3], np.c_[np.zeros((8, 2)), z], atol=1e-12)
    np.testing.assert_allclose(lwr.control_point_positions(np.zeros(7))[0], [0, 0, 1.1785], atol=1e-12)


def test_lwr4_elbow_and_shoulder_at_90_degrees(lwr):
    # by hand from the DH alphas: at q = 0, z1 = -y0, z3 = +y0, so joint 4 turns about +y and the
    # forearm + wrist (0.39 + 0.078) swing from +z to +x about the elbow at z = 0.7105
    q = np.zeros(7)
    q[3] = np.pi / 2
    np.testing.assert_allclose(lwr.link_pose(q, "link7")[:3, 3], [0.468, 0, 0.7105], atol=1e-12)
    np.testing.assert_allclose(lwr.link_pose(q, "link7")[:3, 2], [1, 0, 0], atol=1e-12)
    # joint 2 turns about -y: everything above the shoulder (0.868 m) falls to -x
    q = np.zeros(7)
    q[1] = np.pi / 2
    np.testing.assert_allclose(lwr.link_pose(q, "link7")[:3, 3], [-0.868, 0, 0.3105], atol=1e-12)
    # joint 1 then turns that about +z by 90 degrees: -x -> -y
    q[0] = np.pi / 2
    np.testing.assert_allclose(lwr.link_pose(q, "link7")[:3, 3], [0, -0.868, 0.3105], atol=1e-12)
    # shoulder -90 (upper arm to +x, elbow at (0.4, 0, 0.3105)), elbow +90 about +y: forearm points down
    q = np.zeros(7)
    q[1], q[3] = -np.pi / 2, np.pi / 2
    np.testing.assert_allclose(lwr.link_pose(q, "link7")[:3, 3], [0.4, 0, 0.3105 - 0.468], atol=1e-12)


def test_lwr4_limits_and_velocities(lwr):
    deg = np.pi / 180
    np.testing.assert_allclose(lwr.q_max, np.array([170, 120, 170, 120, 170, 120, 170]) * deg)
    np.testing.assert_allclose(lwr.q_min, -lwr.q_max)
    assert np.all((lwr.qd_max >= 110 * deg) & (lwr.qd_max <= 180 * deg))
    assert lwr.dof == 7 and len(lwr.control_points) == 9


# ------------------------------------------------------------------ DH vs URDF for the UR3
def test_ur3_dh_flange_equals_urdf_tool0(ur3, rng):
    """DH frame 0 = URDF ``base`` = ``base_link`` turned by Rz(pi); DH flange = ``tool0`` (pose)."""
    dh = ur3_dh()
    u_base = ur3.link_pose(np.zeros(6), "base")
    np.testing.assert_allclose(u_base, pose(rot_z(np.pi)), atol=1e-9)
    for q in _random_q(ur3, rng, 20):
        T_dh = dh.link_poses(q)[-1]
        T_urdf = ur3.link_pose(q, "tool0")
        np.testing.assert_allclose(T_dh[:3, 3], T_urdf[:3, 3], atol=1e-9)
        np.testing.assert_allclose(T_dh[:3, :3], T_urdf[:3, :3], atol=1e-9)


def test_ur3_dh_and_urdf_agree_on_a_moved_base(ur3, rng):
    T = pose(quat_to_matrix(np.array([0.1, -0.2, 0.3, 0.9]) / np.linalg.norm([0.1, -0.2, 0.3, 0.9])),
             [0.4, -0.2, 0.8])
    a, b = ur3.with_base(T), ur3_dh(base=T @ pose(rot_z(np.pi)))
    q = _random_q(ur3, rng, 1)[0]
    np.testing.assert_allclose(a.link_pose(q, "tool0"), b.link_poses(q)[-1], atol=1e-9)
    np.testing.assert_allclose(a.link_poses(q), T @ ur3.link_poses(q), atol=1e-12)


# ------------------------------------------------------------------ Jacobians vs finite differences
def _fd_jacobian(robot, q, link, p, h=1e-6):
    J = np.zeros((3, robot.dof))
    for j in range(robot.dof):
        dq = np.zeros(robot.dof)
        dq[j] = h
        J[:, j] = (robot.point_position(q + dq, link, p) - robot.point_position(q - dq, link, p)) / (2 * h)
    return J


@pytest.mark.parametrize("which", ["lwr4", "ur3", "slider"])
def test_jacobian_columns_match_central_differences(which, lwr, ur3, slider, rng):
    robot = {"lwr4": lwr, "ur3": ur3, "slider": slider[0]}[which]
    for q in _random_q(robot, rng, 3):
        J = robot.control_point_jacobians(q)
        for c, cp in enumerate(robot.control_points):
            np.testing.assert_allclose(J[c], _fd_jacobian(robot, q, cp.link, cp.offset), atol=1e-6,
                                       err_msg=f"{which} {cp.name}")
        for _ in range(3):  # random point on a random link
            k = int(rng.integers(robot.chain.n_links))
            p = rng.uniform(-0.2, 0.2, 3)
            np.testing.assert_allclose(robot.point_jacobian(q, k, p), _fd_jacobian(robot, q, k, p), atol=1e-6)


def test_jacobian_columns_zero_for_joints_after_the_link(lwr):
    J = lwr.point_jacobian(lwr.q_home, "link3", [0.0, 0.1, 0.0])
    assert np.all(J[:, 3:] == 0) and np.abs(J[:, :2]).max() > 0.01


# ------------------------------------------------------------------ kernel vs numpy twin
@pytest.mark.parametrize("which", ["lwr4", "ur3", "slider"])
def test_kernel_matches_numpy_twin(which, lwr, ur3, slider, rng):
    robot = {"lwr4": lwr, "ur3": ur3, "slider": slider[0]}[which]
    T = pose(rot_z(0.7), [0.1, 0.2, 0.3])
    robot = robot.with_base(T)
    data = robot.create_data()
    for q in _random_q(robot, rng, 4):
        robot.forward(q, data)
        poses, origins, axes = forward_numpy(robot.chain, q, T)
        np.testing.assert_allclose(data.link_poses, poses, atol=1e-12)
        np.testing.assert_allclose(data.joint_frames[:, 0], origins, atol=1e-12)
        np.testing.assert_allclose(data.joint_frames[:, 1], axes, atol=1e-12)
        for c, cp in enumerate(robot.control_points):
            k = robot.chain.link_index(cp.link)
            np.testing.assert_allclose(data.cp_positions[c], poses[k, :3, :3] @ cp.offset + poses[k, :3, 3],
                                       atol=1e-12)
            np.testing.assert_allclose(data.cp_jacobians[c],
                                       point_jacobian_numpy(robot.chain, q, k, cp.offset, T), atol=1e-12)


def test_forward_reuses_its_buffers(lwr):
    data = lwr.create_data()
    bufs = [data.link_poses, data.cp_positions, data.cp_jacobians]
    ptrs = [b.ctypes.data for b in bufs]
    lwr.forward(lwr.q_home, data)
    first = data.cp_positions.copy()
    lwr.forward(np.zeros(7), data)
    assert [b.ctypes.data for b in (data.link_poses, data.cp_positions, data.cp_jacobians)] == ptrs
    assert not np.allclose(first, data.cp_positions)
    np.testing.assert_allclose(data.cp_jacobians, lwr.control_point_jacobians(np.zeros(7)), atol=0)



def test_forward_into_writes_what_forward_writes_bit_for_bit(lwr, ur3, rng):
    """issue 29: the control cycle's forward kinematics with the arrays bound once
    (``RobotModel.forward_into``) gives ``forward``'s buffers exactly, into the data it was bound to;
    a non-finite joint returns False and leaves them untouched (``forward`` then raises)."""
    for robot in (lwr, ur3):
        ref, data = robot.create_data(), robot.create_data()
        fk = robot.forward_into(data)
        for q in _random_q(robot, rng, 20):
            robot.forward(q, ref)
            assert fk(q) is True
            for name in ("link_poses", "joint_frames", "cp_positions", "cp_jacobians"):
                assert np.array_equal(getattr(data, name), getattr(ref, name)), name
        before = data.cp_positions.copy()
        bad = q.copy()
        bad[1] = np.nan
        assert fk(bad) is False and np.array_equal(data.cp_positions, before)
        with pytest.raises(ValueError, match="finite"):
            robot.forward(bad, data)

# ------------------------------------------------------------------ DH tables
def _elementary(d, a, alpha, theta):
    Rz, Tz, Tx, Rx = np.eye(4), np.eye(4), np.eye(4), np.eye(4)
    Rz[:3, :3] = rot_z(theta)
    Tz[2, 3] = d
    Tx[0, 3] = a
    Rx[:3, :3] = np.array([[1, 0, 0], [0, np.cos(alpha), -np.sin(alpha)], [0, np.sin(alpha), np.cos(alpha)]])
    return Rz @ Tz @ Tx @ Rx


def test_dh_chain_is_the_product_of_dh_matrices(rng):
    """A SCARA-like table with offsets and a prismatic row: FK = prod Rz(th) Tz(d) Tx(a) Rx(al)."""
    from depthguard.robot import DHRow, RobotModel, dh_links, dh_transform
    from depthguard.robot.chain import Chain

    rows = [DHRow(d=0.4, a=0.25, alpha=0.0, theta=0.3), DHRow(d=0.0, a=0.2, alpha=np.pi, theta=-0.2),
            DHRow(d=0.05, a=0.0, alpha=0.0, theta=0.1, prismatic=True, lower=0, upper=0.3),
            DHRow(d=0.1, a=0.03, alpha=-np.pi / 2, theta=0.5)]
    for r in rows:
        np.testing.assert_allclose(dh_transform(r.d, r.a, r.alpha, 0.7), _elementary(r.d, r.a, r.alpha, 0.7),
                                   atol=1e-15)
    robot = RobotModel("scara", Chain(dh_links(rows)), control_points=[{"name": "ee", "link": "link4"}])
    for q in rng.uniform(-1, 1, size=(5, 4)):
        T = np.eye(4)
        expect = [T]
        for r, qi in zip(rows, q):
            T = T @ (_elementary(r.d + qi, r.a, r.alpha, r.theta) if r.prismatic
                     else _elementary(r.d, r.a, r.alpha, r.theta + qi))
            expect.append(T)
        np.testing.assert_allclose(robot.link_poses(q), np.stack(expect), atol=1e-12)
        J = robot.control_point_jacobians(q)[0]
        np.testing.assert_allclose(J, _fd_jacobian(robot, q, "link4", np.zeros(3)), atol=1e-6)
        np.testing.assert_allclose(J[:, 2], expect[2][:3, 2], atol=1e-12)   # prismatic column = z_2
