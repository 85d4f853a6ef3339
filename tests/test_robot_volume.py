"""The robot's own volume over several capture poses (robot.volume.robot_volume, R9, R12):
every pose's padded capsules and every sweep between two poses lie inside it — checked by
sampling points, against the capsule distance computed here from scratch."""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.robot.volume import robot_volume
from depthguard.sim import load_cell


def _segment_distance(p, a, b):
    """(N,) distance of points p (N, 3) to segment a-b (3,)."""
    ab = b - a
    t = np.clip(((p - a) @ ab) / max(float(ab @ ab), 1e-300), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def _inside(points, segs, radii):
    d = np.stack([_segment_distance(points, s[0], s[1]) - r for s, r in zip(segs, radii)])
    return d.min(axis=0) <= 1e-9


def _capsule_samples(rng, ab, r, n):
    """n points per capsule, on and inside its surface."""
    out = []
    for (a, b), rad in zip(ab, r):
        t = rng.random(n)[:, None]
        dirs = rng.normal(size=(n, 3))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        out.append(a + t * (b - a) + dirs * rad * rng.random(n)[:, None] ** (1 / 3))
    return np.concatenate(out)


@pytest.mark.parametrize("n_poses", [1, 2, 3])
def test_volume_holds_every_pose_and_every_sweep(n_poses):
    robot = load_cell("flacco-cell").rig.robot
    rng = np.random.default_rng(n_poses)
    q0 = np.asarray(load_cell("flacco-cell").rig.robot_q0, dtype=np.float64)
    padding = 0.07
    for _ in range(5):
        poses = [q0 + rng.normal(0.0, 0.05, q0.shape) for _ in range(n_poses)]   # ~1 m/s over 30 ms
        segs, radii = robot_volume(robot, poses, padding)
        assert len(segs) == len(robot.collision_segments(q0)[1])                 # one pose's capsules
        for i, qi in enumerate(poses):
            ab, r = robot.collision_segments(qi, padding)
            assert _inside(_capsule_samples(rng, ab, r, 200), segs, radii).all(), f"pose {i} not held"
            for qj in poses[i + 1:]:
                # the sweep: the robot's links moved linearly in joint space between the poses
                for s in np.linspace(0.0, 1.0, 7):
                    ab_s, r_s = robot.collision_segments((1 - s) * qi + s * qj, padding)
                    pts = _capsule_samples(rng, ab_s, r_s, 50)
                    # joint-space interpolation bends the links' paths: allow the bend, measured
                    ends = np.stack([(1 - s) * robot.collision_segments(qi, padding)[0]
                                     + s * robot.collision_segments(qj, padding)[0]])
                    bend = float(np.linalg.norm(ab_s - ends[0], axis=2).max())
                    assert _inside(pts, segs, radii + bend).all()
        # and not much more: the growth is the largest end point displacement, no larger
        if n_poses > 1:
            ab0, r0 = robot.collision_segments(poses[0], padding)
            grow = radii - r0
            disp = np.max([np.linalg.norm(robot.collision_segments(q, padding)[0] - ab0, axis=2).max(axis=1)
                           for q in poses[1:]], axis=0)
            np.testing.assert_allclose(grow, disp, rtol=1e-12, atol=1e-12)


def test_cached_poses_give_the_same_volume():
    """With a cache (the fusion worker's), a pose array seen before reuses its capsules: the
    volume equals the one computed afresh; a new array with other joints, or another padding,
    is computed again."""
    robot = load_cell("flacco-cell").rig.robot
    rng = np.random.default_rng(9)
    qa, qb = rng.uniform(robot.q_min, robot.q_max), rng.uniform(robot.q_min, robot.q_max)
    cache: dict = {}
    for poses, pad in (([qa, qb], 0.07), ([qa, qb], 0.07), ([qb, qa.copy() + 0.1], 0.07), ([qa, qb], 0.05)):
        got = robot_volume(robot, poses, pad, cache)
        want = robot_volume(robot, poses, pad)
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_array_equal(got[1], want[1])
    assert len(cache) == 3          # qa, qb, the new array; qa and qb again at 0.05 replace their entries


def test_unpadded_capsules_made_elsewhere_give_the_same_volume_without_kinematics():
    """The camera worker's unpadded capsules at a pose (``unpadded``, issue 29) give the volume
    bit for bit as the forward kinematics at that pose does, and the kinematics is not run for
    that pose again (counted); a pose without them is computed as before."""
    robot = load_cell("flacco-cell").rig.robot
    rng = np.random.default_rng(11)
    qa, qb, qc = (rng.uniform(robot.q_min, robot.q_max) for _ in range(3))
    calls = []
    real = robot.collision_segments

    class Counting:
        def __getattr__(self, name):
            return getattr(robot, name)

        def collision_segments(self, q, padding=0.0):
            calls.append(padding)
            return real(q, padding)

    made = [real(qa, 0.0), None, real(qc, 0.0)]
    for pad in (0.07, 0.05):
        calls.clear()
        cache: dict = {}
        got = robot_volume(Counting(), [qa, qb, qc], pad, cache, unpadded=made)
        want = robot_volume(robot, [qa, qb, qc], pad)
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_array_equal(got[1], want[1])
        assert calls == [pad]           # only qb, which came without capsules
        got = robot_volume(Counting(), [qa, qb, qc], pad, None, unpadded=made)
        np.testing.assert_array_equal(got[1], want[1])


def test_grid_takes_the_volume_in_the_principal_frame_and_refuses_a_bad_one():
    """``DepthGridMap.set_robot_capsules``: the capsules of ``robot_volume`` (arrays, the compiled
    path) land in the principal camera's frame as ``R a + t`` computed here with numpy, give the
    same per-pixel intervals as the same capsules handed as ``Capsule`` objects (the other path),
    and a capsule with a non-finite end point or a negative radius is refused with a clear error."""
    from depthguard.fusion.depth_grid import DepthGridMap
    from depthguard.geometry import Capsule

    cell = load_cell("flacco-cell")
    robot, cams = cell.rig.robot, cell.rig.cameras
    segs, radii = robot_volume(robot, [np.zeros(robot.dof)], 0.05)
    grid = DepthGridMap(cams, cams[0].id, 0.5, 4.0, 0.05, cache=False)
    grid.set_robot_capsules((segs, radii))
    P = cams[0]
    R, t = np.linalg.inv(P.world_from_camera)[:3, :3], np.linalg.inv(P.world_from_camera)[:3, 3]
    want = np.concatenate([segs[:, 0] @ R.T + t, segs[:, 1] @ R.T + t, radii[:, None]], axis=1)
    np.testing.assert_allclose(grid._caps, want, rtol=0, atol=1e-12)
    assert grid._ncaps == len(radii)
    n_in, lo, hi = grid._cap_n.copy(), grid._cap_lo.copy(), grid._cap_hi.copy()
    assert n_in.sum() > 100                        # the robot is in the principal's view
    grid.set_robot_capsules([Capsule.between(a, b, r) for (a, b), r in zip(segs, radii)])
    np.testing.assert_array_equal(grid._cap_n, n_in)
    np.testing.assert_allclose(grid._cap_lo[n_in > 0], lo[n_in > 0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(grid._cap_hi[n_in > 0], hi[n_in > 0], rtol=0, atol=1e-9)
    caps_before = grid._caps.copy()
    moved = segs + 0.1                             # a valid first capsule, then a bad last one
    nan_last = moved.copy()
    nan_last[-1, 1, 2] = np.nan
    neg_last = radii.copy()
    neg_last[-1] = -0.01
    for bad_seg, bad_r in ((moved, neg_last), (nan_last, radii)):
        with pytest.raises(ValueError, match="finite end points and radii >= 0"):
            grid.set_robot_capsules((bad_seg, bad_r))
        np.testing.assert_array_equal(grid._caps, caps_before)       # nothing stored is lost
