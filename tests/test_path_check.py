"""Path verdicts per segment (R22, R37) on hand-built maps; the truth is analytic contact geometry.

Truth: the robot's capsules as :class:`depthguard.geometry.Capsule` (their own ``sdf``, not the
sweep kernel's distance) at poses ten times denser than the checker's samples: a segment whose
dense poses bring the padded robot within half a voxel diagonal of an occupied voxel's centre
must not be safe; a segment whose dense poses all stay farther than that plus the sample spacing
must be safe (the sweep is not more conservative than its documented pad). The numba kernel and
its numpy twin agree on random maps. A bad path names its waypoint.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from depthguard.control.path_check import (FREE, OCCUPIED, UNKNOWN, STILL, _samples, check_path_states,
                                           sample_path, sample_path_numpy, sweep_states, sweep_states_numpy,
                                           touched_mask, validate_path)
from depthguard.geometry.voxel_grid import VoxelGrid
from depthguard.sim import load_cell

S = 0.05
PAD = 0.03


@pytest.fixture(scope="module")
def robot():
    return load_cell("ur3-cell").rig.robot


@pytest.fixture(scope="module")
def path(robot):
    q0 = np.asarray(load_cell("ur3-cell").rig.robot_q0, float)
    Q = np.linspace(q0, q0 + np.array([1.2, 0.3, -0.4, 0.0, 0.5, 0.0]), 21)
    return np.linspace(0.0, 2.0, 21), Q


def grid_of(robot, Q):
    """A box around every pose of the path (so that nothing leaves it)."""
    A = np.concatenate([np.stack([c.segment()[0] for c in robot.collision_capsules(q)]) for q in Q])
    return VoxelGrid(A.min(0) - 0.6, A.max(0) + 0.6, S)


def dense_clearance(robot, Q, centre, per_segment=20, pad=PAD):
    """Per segment: min over dense poses of the padded robot's sdf at ``centre`` (m)."""
    out = []
    for i in range(len(Q) - 1):
        d = math.inf
        for f in np.linspace(0.0, 1.0, per_segment + 1):
            caps = robot.collision_capsules(Q[i] + f * (Q[i + 1] - Q[i]), pad)
            d = min(d, min(float(c.sdf(centre[None])[0]) for c in caps))
        out.append(d)
    return np.array(out)


@pytest.mark.parametrize("which", [9, 13, 17])
def test_an_occupied_voxel_on_the_way_makes_exactly_the_near_segments_not_safe(robot, path, which):
    t, Q = path
    grid = grid_of(robot, Q)
    # a voxel near the end effector's axis end at waypoint `which`, outside the start volume
    tip = robot.collision_capsules(Q[which])[-1].segment()[1]
    ijk = tuple(int(x) for x in np.floor((tip - grid.lo) / S))
    state = np.zeros(grid.shape, np.uint8)
    state[ijk] = OCCUPIED
    centre = grid.lo + (np.array(ijk) + 0.5) * S
    assert not touched_mask(grid.shape, grid.lo, S, robot, Q[0], PAD + S)[ijk]     # not the start volume
    v = check_path_states(state, grid.lo, S, robot, t, Q, padding=PAD)
    clear = dense_clearance(robot, Q, centre)
    hd = S * math.sqrt(3) / 2
    got = np.array([s.verdict for s in v.segments])
    assert np.all(got[clear <= hd] == "unsafe"), (clear, got)           # never safe in contact
    assert np.all(got[clear > hd + S] == "safe"), (clear, got)          # pad of the sweep: a quarter voxel
    assert v.verdict == "unsafe"
    assert int(np.argmax(clear <= hd + S)) <= v.first_not_safe <= int(np.argmax(clear <= hd))
    assert all(v.segments[i].voxel == ijk for i in np.nonzero(got == "unsafe")[0])


def test_a_known_scene_voxel_is_met_with_the_scene_padding(robot, path):
    """Issue 30: a voxel of the known scene (``known``) is touched with ``scene_padding`` in place of
    ``padding``: not safe where the robot padded by ``scene_padding`` comes within half a voxel
    diagonal of its centre, safe where it stays a sample spacing farther — while the same voxel
    seen by the cameras keeps the full padding."""
    t, Q = path
    grid = grid_of(robot, Q)
    tip = robot.collision_capsules(Q[13])[-1].segment()[1]
    ijk = tuple(int(x) for x in np.floor((tip - grid.lo) / S))
    state = np.zeros(grid.shape, np.uint8)
    state[ijk] = OCCUPIED
    known = np.zeros(grid.shape, bool)
    known[ijk] = True
    centre = grid.lo + (np.array(ijk) + 0.5) * S
    hd = S * math.sqrt(3) / 2
    big = 0.15                                     # the robot's padding; the scene's is 1 cm
    seen = np.array([s.verdict for s in check_path_states(state, grid.lo, S, robot, t, Q, padding=big).segments])
    cad = check_path_states(state, grid.lo, S, robot, t, Q, padding=big, known=known, scene_padding=0.01)
    got = np.array([s.verdict for s in cad.segments])
    clear = dense_clearance(robot, Q, centre, pad=0.01)
    assert np.all(got[clear <= hd] == "unsafe"), (clear, got)
    assert np.all(got[clear > hd + S] == "safe"), (clear, got)
    assert (got == "safe").sum() > (seen == "safe").sum()          # the case is really there
    assert set(np.nonzero(got != "safe")[0]) <= set(np.nonzero(seen != "safe")[0])


def test_unknown_gives_maybe_occupied_wins_and_free_map_is_safe(robot, path):
    t, Q = path
    grid = grid_of(robot, Q)
    free = np.zeros(grid.shape, np.uint8)
    assert check_path_states(free, grid.lo, S, robot, t, Q, padding=PAD).verdict == "safe"
    unknown = np.full(grid.shape, UNKNOWN, np.uint8)
    v = check_path_states(unknown, grid.lo, S, robot, t, Q, padding=PAD)
    assert v.verdict == "maybe" and {s.verdict for s in v.segments} <= {"safe", "maybe"}
    start = touched_mask(grid.shape, grid.lo, S, robot, Q[0], PAD + S)      # the excluded start volume
    for sv in v.segments:        # safe in unknown space only while the robot stays in its start volume
        inside = not np.any(touched_mask(grid.shape, grid.lo, S, robot, Q[sv.index + 1], PAD) & ~start)
        assert (sv.verdict == "safe") <= inside
    assert v.segments[-1].verdict == "maybe"
    both = unknown.copy()
    tip = robot.collision_capsules(Q[10])[-1].segment()[1]
    both[tuple(np.floor((tip - grid.lo) / S).astype(int))] = OCCUPIED
    v = check_path_states(both, grid.lo, S, robot, t, Q, padding=PAD)
    assert v.segments[9].verdict == "unsafe" and v.segments[-1].verdict == "maybe"


def test_leaving_the_box_is_unknown(robot, path):
    t, Q = path
    grid = grid_of(robot, Q)
    small = VoxelGrid(grid.lo, grid.lo + (np.array(grid.shape) // 2) * S, S)
    v = check_path_states(np.zeros(small.shape, np.uint8), small.lo, S, robot, t, Q, padding=PAD)
    assert v.verdict == "maybe" and any(s.outside for s in v.segments)


def test_start_volume_is_excluded_and_touched_mask_matches_capsule_sdf(robot, path):
    t, Q = path
    grid = grid_of(robot, Q)
    m = touched_mask(grid.shape, grid.lo, S, robot, Q[0], PAD)
    truth = grid.touched_by(robot.collision_capsules(Q[0], PAD))     # VoxelGrid's own rule, Capsule.sdf
    assert np.array_equal(m, truth)
    state = np.where(m, OCCUPIED, FREE).astype(np.uint8)           # something inside the robot at the start
    v = check_path_states(state, grid.lo, S, robot, t[:2], Q[:2], padding=0.0, exclude=m)
    assert v.verdict == "safe"


def test_kernel_equals_numpy_twin_on_random_maps(robot, path):
    t, Q = path
    grid = grid_of(robot, Q)
    rng = np.random.default_rng(3)
    A, B, R, seg = sample_path(robot, Q, 0.25 * S, PAD)
    for p in (0.0005, 0.005, 0.05):
        state = rng.choice(np.array([0, 1, 2], np.uint8), size=grid.shape, p=[1 - 2 * p, p, p])
        ex = rng.random(grid.shape) < 0.01
        kn = rng.random(grid.shape) < 0.3              # known-scene voxels, touched with less padding
        dp = 0.5 * PAD
        n = len(Q) - 1
        w, f, o = np.zeros(n, np.uint8), np.zeros(n, np.int64), np.zeros(n, bool)
        sweep_states(state, ex, kn, dp, grid.lo, S, A, B, R, seg, n, w, f, o)
        w2, f2, o2 = sweep_states_numpy(state, ex, kn, dp, grid.lo, S, A, B, R, seg, n)
        assert np.array_equal(w, w2) and np.array_equal(o, o2)
        assert np.all(state.ravel()[f[f >= 0]] == w[f >= 0])


def test_sampler_kernel_equals_its_numpy_twin_bit_for_bit(robot, path):
    """The one-call sampler (forward kinematics, reach, resampling, pads, the still capsules in
    numba) gives the numpy twin's samples exactly, and the capsules it calls still are those whose
    axis ends move no more than STILL along the path."""
    _, Q = path
    for move in (0.25 * S, 0.02):
        A, B, R, seg, moving = _samples(robot, Q, move, PAD)
        A2, B2, R2, seg2 = sample_path_numpy(robot, Q, move, PAD)
        for x, y in ((A, A2), (B, B2), (R, R2), (seg, seg2)):
            assert x.shape == y.shape and np.array_equal(x, y)
        still = np.max(np.abs(np.concatenate([A2 - A2[:1], B2 - B2[:1]], axis=0)), axis=(0, 2)) <= STILL
        assert np.array_equal(moving, ~still) and still.any() and not still.all()


def test_samples_move_at_most_a_quarter_voxel(robot, path):
    _, Q = path
    A, B, R, seg = sample_path(robot, Q, 0.25 * S, PAD)
    same = seg[1:] == seg[:-1]
    step = np.max(np.linalg.norm(np.concatenate([A, B], 1)[1:] - np.concatenate([A, B], 1)[:-1], axis=2), axis=1)
    assert np.all(step[same] <= 0.25 * S + 1e-9)
    pad = R[:, 0] - R[:, 0].min() + 0.0
    assert np.all(R - np.array([c.radius for c in robot.capsules]) >= PAD - 1e-12)
    assert pad.max() <= 0.5 * 1.05 * 0.25 * S + 1e-9


@pytest.mark.parametrize("mutate, message", [
    (lambda t, q: (t, q[:, :5]), "waypoint 0: 5 joints"),
    (lambda t, q: (np.r_[t[:3], t[2], t[4:]], q), "waypoint 3: stamp"),
    (lambda t, q: (t, np.where(np.arange(len(q))[:, None] == 4, q + np.r_[10.0, 0, 0, 0, 0, 0], q)),
     "waypoint 4: joint 0"),
    (lambda t, q: (t, np.where(np.arange(len(q))[:, None] == 6, np.nan, q)), "waypoint 6: joints"),
    (lambda t, q: (np.where(np.arange(len(t)) == 2, np.inf, t), q), "waypoint 2: stamp inf"),
])
def test_a_bad_path_names_its_waypoint(robot, path, mutate, message):
    t, q = mutate(*path)
    with pytest.raises(ValueError, match=message):
        validate_path(t, q, robot)
