"""Voxels of the camera units as a monitor input: distance to the voxel box (R25), the robot's
own volume, per-camera stamps (R27).

Truth: analytic boxes, the plain-numpy twin, and points sampled inside the voxels.
"""

import math
import threading

import numpy as np
import pytest

from depthguard.runtime.voxel_input import VoxelObstacles, bucket, voxel_nearest, voxel_nearest_numpy


def _out(m):
    return np.full(m, np.inf), np.zeros((m, 3))


def test_analytic_box_distances():
    vo = VoxelObstacles()
    vo.push("u0", [[0.0, 0.0, 0.0]], 0.2, 3.0)         # the cube [-0.1, 0.1]^3
    P = np.array([[0.5, 0.0, 0.0],                       # in front of a face: 0.4 along -x
                  [0.5, 0.5, 0.0],                       # beside an edge: to (0.1, 0.1, z)
                  [0.4, -0.5, 0.3],                      # beyond a corner: to (0.1, -0.1, 0.1)
                  [0.05, -0.02, 0.09],                   # inside: 0, no direction
                  [2.0, 0.0, 0.0],                       # beyond rho: untouched
                  [0.0, 0.0, 0.3]])                      # already nearer to something else
    D, V = _out(len(P))
    D[5] = 0.1
    V[5] = [0.0, 1.0, 0.0]
    st = vo.nearest(P, 1.0, D, V)
    assert st == {"u0": 3.0}
    np.testing.assert_allclose(D, [0.4, 0.4 * math.sqrt(2), math.sqrt(0.3 ** 2 + 0.4 ** 2 + 0.2 ** 2), 0.0,
                                   math.inf, 0.1], rtol=0, atol=1e-12)
    np.testing.assert_allclose(V[0], [-1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(V[1], [-1 / math.sqrt(2), -1 / math.sqrt(2), 0], atol=1e-12)
    np.testing.assert_allclose(V[2], np.array([-0.3, 0.4, -0.2]) / math.sqrt(0.29), atol=1e-12)
    np.testing.assert_array_equal(V[3], 0.0)
    np.testing.assert_array_equal(V[4], 0.0)
    np.testing.assert_array_equal(V[5], [0.0, 1.0, 0.0])
    # exactly rho away counts; a hair beyond does not
    D, V = _out(2)
    vo.nearest(np.array([[0.5, 0, 0], [0.5 + 1e-9, 0, 0]]), 0.4, D, V)
    assert D[0] == pytest.approx(0.4) and D[1] == math.inf


def test_box_distance_is_a_lower_bound_of_everything_in_the_voxel(rng):
    """Conservative (R25): never farther than any point inside the voxel, and tight (the
    nearest sampled points of the box come within the sampling's resolution)."""
    s = 0.05
    centres = rng.uniform(-0.5, 0.5, (30, 3))
    P = rng.uniform(-0.8, 0.8, (40, 3))
    vo = VoxelObstacles()
    vo.push("u", centres, s, 0.0)
    D, V = _out(len(P))
    vo.nearest(P, 10.0, D, V)
    inside = centres[:, None, :] + rng.uniform(-s / 2, s / 2, (30, 2000, 3))
    d_true = np.linalg.norm(inside.reshape(-1, 3)[None] - P[:, None], axis=2).min(axis=1)
    assert np.all(D <= d_true + 1e-12)
    assert np.all(d_true - D < 0.02)
    # the direction points at the box's nearest point
    outside = D > 0
    tgt = P[outside] + D[outside, None] * V[outside]
    gap = np.min(np.max(np.abs(tgt[:, None] - centres[None]), axis=2), axis=1)
    np.testing.assert_allclose(gap, s / 2, atol=1e-9)


def _capsules(rng, n):
    a = rng.uniform(-0.4, 0.4, (n, 3))
    b = a + rng.uniform(-0.3, 0.3, (n, 3))
    b[0] = a[0]                                      # a degenerate capsule: a sphere
    return np.stack([a, b], axis=1), rng.uniform(0.05, 0.15, n)


@pytest.mark.parametrize("rho", [0.1, 0.3, 5.0])
def test_kernel_matches_numpy_twin(rng, rho):
    for _ in range(5):
        centres = rng.uniform(-0.6, 0.6, (400, 3))
        P = rng.uniform(-0.7, 0.7, (12, 3))
        seg, rad = _capsules(rng, 6)
        half = 0.5 * rng.choice([0.01, 0.02, 0.05])
        D0 = np.where(rng.random(12) < 0.3, rng.uniform(0, 0.3, 12), np.inf)
        Da, Va = D0.copy(), np.zeros((12, 3))
        Db, Vb = D0.copy(), np.zeros((12, 3))
        for cell in (0.05, 0.16, 10.0):                # many cells, the default, one cell
            Da, Va = D0.copy(), np.zeros((12, 3))
            c, start, lo, hi = bucket(centres, 2 * half, cell)
            used = voxel_nearest(P, c, half, rho, seg, rad, Da, Va, start, lo, hi)
            voxel_nearest_numpy(P, centres, half, rho, seg, rad, Db, Vb)
            np.testing.assert_array_equal(Da, Db)
            np.testing.assert_allclose(Va, Vb, rtol=0, atol=1e-15)
            assert 0 < used <= len(centres)
            assert np.any(Da < D0)
            Db, Vb = D0.copy(), np.zeros((12, 3))


def test_robot_own_voxels_do_not_count():
    vo = VoxelObstacles()
    s = 0.02
    # a capsule along x from 0 to 0.5, radius 0.05 (+ padding): voxels along it are the robot's
    seg = np.array([[[0.0, 0.0, 0.5], [0.5, 0.0, 0.5]]])
    rad = np.array([0.06])
    own = np.array([[x, 0.0, 0.5] for x in np.arange(0.0, 0.5, s)] + [[0.25, 0.0, 0.55]])
    vo.push("u", own, s, 1.0)
    P = np.array([[0.25, 0.0, 0.5]])                # a control point on the robot
    D, V = _out(1)
    vo.nearest(P, 0.5, D, V, robot_capsules=(seg, rad))
    assert D[0] == math.inf
    # a hand just outside the padded capsule counts
    vo.push("u2", [[0.25, 0.0, 0.5 + 0.07]], s, 1.0)
    D, V = _out(1)
    st = vo.nearest(P, 0.5, D, V, robot_capsules=(seg, rad))
    assert D[0] == pytest.approx(0.07 - s / 2) and st == {"u": 1.0, "u2": 1.0}
    np.testing.assert_allclose(V[0], [0, 0, 1], atol=1e-12)
    # without the capsules the robot's own voxels stop everything
    D, V = _out(1)
    vo.nearest(P, 0.5, D, V)
    assert D[0] == 0.0


def test_sets_replaced_whole_per_camera_and_stamps():
    vo = VoxelObstacles()
    vo.push("a", [[1.0, 0, 0]], 0.02, 1.0)
    vo.push("b", [[0, 1.0, 0]], 0.05, 2.0)
    vo.push("a", np.zeros((0, 3)), 0.02, 1.5)       # camera a sees nothing any more
    P = np.zeros((1, 3))
    D, V = _out(1)
    assert vo.nearest(P, 2.0, D, V) == {"a": 1.5, "b": 2.0}
    assert D[0] == pytest.approx(1.0 - 0.025)       # only b's voxel is left
    vo.remove("b")
    D, V = _out(1)
    assert vo.nearest(P, 2.0, D, V) == {"a": 1.5} and D[0] == math.inf
    for bad in (dict(centres=[[1, 2]], voxel_size=0.02, stamp=0.0),
                dict(centres=[[np.nan, 0, 0]], voxel_size=0.02, stamp=0.0),
                dict(centres=[[0, 0, 0]], voxel_size=0.0, stamp=0.0),
                dict(centres=[[0, 0, 0]], voxel_size=0.02, stamp=math.inf)):
        with pytest.raises(ValueError):
            vo.push("a", **bad)
    assert vo.get("a").stamp == 1.5                 # a refused push leaves the old set
    with pytest.raises(ValueError, match="out_distance"):
        vo.nearest(P, 1.0, np.zeros(2), np.zeros((2, 3)))


def test_push_from_another_thread_while_querying(rng):
    """Every query sees one whole set: the distance is that of the set whose stamp it returns."""
    vo = VoxelObstacles()
    sets = [np.full((200, 3), 0.1 * (k + 1)) for k in range(5)]
    vo.push("u", sets[0], 0.02, 0.0)
    stop = threading.Event()

    def writer():
        k = 0
        while not stop.is_set():
            k = (k + 1) % 5
            vo.push("u", sets[k], 0.02, float(k))
    th = threading.Thread(target=writer)
    th.start()
    try:
        P = np.zeros((1, 3))
        allowed = {k: np.linalg.norm(np.full(3, 0.1 * (k + 1))) - 0.01 * math.sqrt(3) for k in range(5)}
        for _ in range(2000):
            D, V = _out(1)
            st = vo.nearest(P, 1.0, D, V)
            assert abs(D[0] - allowed[int(st["u"])]) < 1e-9
    finally:
        stop.set()
        th.join()
    assert vo.pushed > 1
