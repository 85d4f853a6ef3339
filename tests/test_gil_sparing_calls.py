"""Compiled calls that replace numpy and ctypes calls for the GIL's sake (issue 29): each of those
gave the GIL away and waited to take it back in a real-time run. ``thread_settings`` against
numba's own API, the depth grid's query making no ctypes call into numba's layer, and the kernels
that replace numpy copies against those copies."""

from __future__ import annotations

import threading

import numba
import numba.np.ufunc.parallel as layer
import numpy as np
import pytest

from depthguard.fusion.depth_grid import DepthGridMap
from depthguard.fusion.depth_grid_lazy import tile_min
from depthguard.fusion.depth_grid_kernels import TILE
from depthguard.numba_threads import NUMBA_NUM_THREADS, thread_settings
from tests.test_depth_grid import _scene, _with_robot


def test_thread_settings_read_and_set_what_numba_reads_and_sets_per_thread():
    n0, c0 = numba.get_num_threads(), numba.get_parallel_chunksize()
    try:
        assert thread_settings(0, -1) == (n0, c0)                     # leaves both
        assert (numba.get_num_threads(), numba.get_parallel_chunksize()) == (n0, c0)
        assert thread_settings(1, 7) == (n0, c0)
        assert (numba.get_num_threads(), numba.get_parallel_chunksize()) == (1, 7)
        numba.set_num_threads(NUMBA_NUM_THREADS)
        numba.set_parallel_chunksize(3)
        assert thread_settings(0, 0) == (NUMBA_NUM_THREADS, 3)        # numba's own settings read back
        assert numba.get_parallel_chunksize() == 0
        seen = {}

        def other():                          # another thread: its own settings, untouched by ours
            seen["before"] = thread_settings(1, 5)
            seen["after"] = (numba.get_num_threads(), numba.get_parallel_chunksize())

        t = threading.Thread(target=other)
        t.start()
        t.join()
        assert seen["after"] == (1, 5)
        assert (numba.get_num_threads(), numba.get_parallel_chunksize()) == (NUMBA_NUM_THREADS, 0)
        with pytest.raises(ValueError):
            thread_settings(NUMBA_NUM_THREADS + 1, -1)
    finally:
        numba.set_num_threads(n0)
        numba.set_parallel_chunksize(c0)


def test_the_grid_query_makes_no_ctypes_call_into_numbas_layer(monkeypatch):
    """Each ctypes call gives the GIL away (module docstring): a query, the frame's first (which
    classifies its cells) and a later one, on every thread choice, calls none; the thread count
    and chunk size are the caller's again afterwards."""
    rng = np.random.default_rng(5)
    prims, cams, _ = _scene(rng, 3)
    a, b, c, depths, rdepths, caps = _with_robot(prims, cams)
    grid = DepthGridMap(cams, "c0", 1.0, 4.6, 0.03, cache=False)
    pts = np.array([a, b, c, (a + b) / 2], dtype=np.float64)
    many = np.tile(pts, (5, 1))                                      # >= PARALLEL_MIN_POINTS
    before = numba.get_num_threads(), numba.get_parallel_chunksize()
    calls = []
    for name in ("_get_num_threads", "_set_num_threads", "_get_parallel_chunksize", "_set_parallel_chunksize"):
        real = getattr(layer, name)
        monkeypatch.setattr(layer, name, lambda *args, _name=name, _real=real: (calls.append(_name), _real(*args))[1])
    answers = []
    for points, threads in ((pts, None), (pts, 1), (pts, 2), (many, None)):
        grid.set_frames(depths, rdepths, robot_capsules=caps)
        first = grid.query(points, rho=0.5, threads=threads).distance.copy()
        again = grid.query(points, rho=0.5, threads=threads).distance.copy()
        np.testing.assert_array_equal(first, again)
        answers.append(first[:len(pts)])
    assert calls == []
    for x in answers[1:]:
        np.testing.assert_array_equal(x, answers[0])                 # the same answers on any thread count
    assert (numba.get_num_threads(), numba.get_parallel_chunksize()) == before


def test_tile_min_equals_numpy_twin():
    rng = np.random.default_rng(3)
    for H, W in ((48, 64), (45, 61), (1, 1)):
        pfree = rng.uniform(0.2, 5.0, (H, W))
        pfree[rng.random((H, W)) < 0.1] = np.inf
        ty, tx = -(-H // TILE), -(-W // TILE)
        tmin = np.full((ty, tx), -1.0)
        tile_min(pfree, tmin)
        padded = np.full((ty * TILE, tx * TILE), np.inf)
        padded[:H, :W] = pfree
        np.testing.assert_array_equal(tmin, padded.reshape(ty, TILE, tx, TILE).min(axis=(1, 3)))


def test_posed_render_vertices_equal_the_posed_meshes_and_a_short_buffer_is_refused():
    """``render_link_vertices`` (one compiled posing) against ``p @ R.T + t`` of each link's pose
    from forward kinematics (numpy, within rounding), the same bits as ``render_link_meshes``; an
    output buffer too short, of another dtype or not C-contiguous is a ValueError, never a write
    past its end."""
    from depthguard.sim import load_cell

    robot = load_cell("ur3-cell").rig.robot
    q = np.random.default_rng(2).uniform(-1.0, 1.0, robot.dof)
    topo = robot.render_link_topology(None)
    n = sum(len(m.vertices) for m in topo)
    got = robot.render_link_vertices(q, None, np.empty((n + 5, 3)))
    assert got.shape == (n, 3)
    poses = robot.link_poses(q)
    want = np.concatenate([m.vertices @ poses[k, :3, :3].T + poses[k, :3, 3]
                           for k, m in zip(robot._mesh_link, topo)])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(got, np.concatenate([m.vertices for m in robot.render_link_meshes(q, None)]))
    for bad in (np.empty((n - 1, 3)), np.empty((n, 3), np.float32), np.empty((3, n)).T):
        with pytest.raises(ValueError, match="out must be"):
            robot.render_link_vertices(q, None, bad)
