"""Motion verdicts (R22) on hand-built voxel maps: the truth is analytic contact geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from depthguard.control.motion_check import (Motion, check_motion, compare_verdicts, level_of,
                                             braking_distance)
from depthguard.geometry import Box, Capsule
from depthguard.geometry.voxel_grid import VoxelGrid
from depthguard.transforms import pose, rot_z

S_VOX = 0.05
GRID = VoxelGrid([-1.0, -1.0, 0.0], [3.0, 1.0, 1.0], S_VOX)


def wall_at(x0: float) -> np.ndarray:
    """Occupied voxels with x >= x0 (x0 on a voxel boundary)."""
    occ = np.zeros(GRID.shape, bool)
    i0 = int(round((x0 - GRID.lo[0]) / S_VOX))
    occ[i0:, :, :] = True
    return occ


def sliding_box(S: float) -> Motion:
    # a 0.3 m cube, front face at x = 0.15, moving along +x by u * S metres
    def at(u):
        return [Box(size=(0.3, 0.3, 0.3), world_from_local=pose(t=[u * S, 0.0, 0.5]))]
    return Motion("box x+", at)


@pytest.mark.parametrize("gap, expected", [(0.10, "S"), (0.30, "M"), (0.70, "L"), (1.30, "none")])
def test_translation_verdict_matches_analytic_contact(gap, expected):
    S = 0.2
    x0 = 0.15 + gap
    verdict = check_motion(wall_at(x0), GRID, sliding_box(S))
    assert verdict.level == expected
    u_true = gap / S  # the front face reaches the wall
    if expected != "none":
        # conservative: never later than the true contact, and not earlier than the
        # discretisation allows (voxel half-diagonal + sweep padding + one sample step)
        assert verdict.u_contact <= u_true + 1e-9
        assert verdict.u_contact >= u_true - (S_VOX * math.sqrt(3) / 2 + S_VOX) / S
    else:
        assert verdict.u_contact == math.inf


def test_rotation_verdict_matches_analytic_contact():
    # a 1 m rod rotating about the z axis through its end; S = 20 degrees
    S = math.radians(20.0)

    def at(u):
        R = pose(rot_z(u * S))
        return [Capsule.between([0.0, 0.0, 0.5], [1.0, 0.0, 0.5], radius=0.05).moved(R)]

    motion = Motion("rod rotation +", at)
    for ang_deg, expected in ((12.0, "S"), (32.0, "M"), (70.0, "L"), (115.0, "none")):
        # a post between radii 0.75 and 0.95 m, voxels with centres from angle ang_deg on
        occ = np.zeros(GRID.shape, bool)
        c = GRID.centres()
        a = math.radians(ang_deg)
        ang = np.arctan2(c[:, 1], c[:, 0])
        r = np.hypot(c[:, 0], c[:, 1])
        occ |= ((ang >= a) & (ang <= a + 0.3) & (r > 0.75) & (r < 0.95)).reshape(GRID.shape)
        v = check_motion(occ, GRID, motion)
        assert v.level == expected, (ang_deg, v)
        if expected != "none":
            # never later than the rod's axis reaching the voxel centres; not earlier than
            # the rod radius + voxel half-diagonal + sweep padding + one step allow at r = 0.75
            assert v.u_contact * S <= a
            assert v.u_contact * S >= a - (0.05 + S_VOX * math.sqrt(3) + S_VOX) / 0.75


def test_own_volume_is_not_a_contact():
    # the map still holds the machine (not freed): the default exclusion removes it
    S = 0.2
    occ = np.zeros(GRID.shape, bool)
    box = sliding_box(S).primitives_at(0.0)[0]
    occ |= (box.sdf(GRID.centres()) <= 0).reshape(GRID.shape)
    assert check_motion(occ, GRID, sliding_box(S)).level == "none"
    # but an explicit empty exclusion makes the machine collide with itself at once
    v = check_motion(occ, GRID, sliding_box(S), exclude=np.zeros(GRID.shape, bool))
    assert v.level == "S" and v.u_contact == 0.0


def test_level_thresholds_and_table4_labels():
    assert [level_of(u) for u in (0.0, 1.0, 1.01, 2.0, 2.01, 5.0, 5.01, math.inf)] == \
        ["S", "S", "M", "M", "L", "L", "none", "none"]
    # rows of the paper's table 4 (reconstruction, simulation, verdict)
    assert compare_verdicts("M", "L") == "ts"      # setup 2 Long
    assert compare_verdicts("M", "none") == "ts"   # setup 4 Prop
    assert compare_verdicts("S", "none") == "tts"  # setup 4 2x Prop
    assert compare_verdicts("S", "S") == "s"
    assert compare_verdicts("L", "M") == "u"       # reconstruction warns where truth slows down
    with pytest.raises(ValueError, match="verdict"):
        compare_verdicts("X", "S")


def test_braking_distance():
    assert braking_distance(0.2, 0.5) == pytest.approx(0.04)
    assert braking_distance(0.2, 0.5, reaction_time=0.1) == pytest.approx(0.06)
    with pytest.raises(ValueError):
        braking_distance(0.0, 1.0)


# ------------------------------------------------------------- robot-arm motions
def _ur3():
    from depthguard.robot import load_robot
    return load_robot("ur3")


@pytest.mark.slow
def test_joint_motion_moves_one_joint_by_u_times_S():
    from depthguard.control.motion_check import joint_motion
    robot = _ur3()
    q0 = np.array([0.0, -1.2, 1.0, -1.4, -1.57, 0.0])
    m = joint_motion(robot, q0, joint=0, sign=-1.0, braking=0.2)
    q = q0.copy()
    q[0] -= 2.5 * 0.2
    got = m.primitives_at(2.5)
    want = robot.collision_capsules(q)
    assert len(got) == len(want)
    for a, b in zip(got, want):
        assert np.allclose(np.asarray(a.segment()), np.asarray(b.segment()))
    with pytest.raises(ValueError, match="joint index"):
        joint_motion(robot, q0, joint=6, sign=1.0, braking=0.1)


@pytest.mark.slow
def test_cartesian_motion_follows_the_direction():
    from depthguard.control.motion_check import cartesian_motion
    robot = _ur3()
    q0 = np.array([0.3, -1.2, 1.2, -1.5, -1.57, 0.0])
    d = np.array([0.0, 0.6, 0.8])
    m = cartesian_motion(robot, q0, d, braking=0.05)
    # after u = 3 the end effector has moved 3 * 0.05 m along d; the joint path is internal,
    # so look at the last link's capsule, which moves (almost) rigidly with the end effector
    caps = m.primitives_at(3.0)
    ee_cap = np.asarray(caps[-1].segment()).mean(axis=0)
    ref = np.asarray(robot.collision_capsules(q0)[-1].segment()).mean(axis=0)
    assert np.allclose(ee_cap - ref, 0.15 * d, atol=0.01)
    with pytest.raises(ValueError, match="direction"):
        cartesian_motion(robot, q0, [0, 0, 0], braking=0.05)


@pytest.mark.slow
def test_robot_joint_motion_verdict_against_a_wall():
    # a UR3 base joint turning towards a wall of voxels: contact where the swept capsules
    # first reach the wall (truth: the capsules' exact sdf at the wall's voxel centres)
    from depthguard.control.motion_check import joint_motion
    robot = _ur3()
    grid = VoxelGrid([-0.8, -0.8, -0.2], [0.8, 0.8, 0.8], 0.04)
    q0 = np.array([0.0, -0.3, 0.0, -1.57, 0.0, 0.0])
    c = grid.centres()
    occ = ((c[:, 1] > 0.35) & (c[:, 0] > 0.0)).reshape(grid.shape)   # obstacle region
    S = np.deg2rad(10.0)
    m = joint_motion(robot, q0, joint=0, sign=1.0, braking=S)
    v = check_motion(occ, grid, m)
    # truth: smallest u at which some capsule comes within half a voxel diagonal (+ padding)
    # of an occupied centre, scanned finely
    occ_c = c[occ.ravel()]
    u_true = math.inf
    for u in np.linspace(0, 5, 501):
        caps = m.primitives_at(u)
        dmin = min(float(np.min(cp.sdf(occ_c))) for cp in caps)
        if dmin <= 0.0:
            u_true = u
            break
    assert math.isfinite(u_true) and u_true > 0.5    # the case has a contact ahead
    assert v.u_contact <= u_true + 1e-9               # never later than the real contact
    assert v.level == level_of(v.u_contact)
    # not earlier than the discretisation allows (half a diagonal + padding + a step) at the
    # lever arm of the part that reaches the wall (> 0.3 m from the base axis)
    assert v.u_contact * S >= u_true * S - (0.04 * math.sqrt(3) / 2 + 0.04) / 0.3
