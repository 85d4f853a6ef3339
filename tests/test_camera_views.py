"""The other cameras' arrays as the depth grid's kernels read them (issue 29, R36):
:class:`~depthguard.fusion.camera_views.CameraViews` points a kernel at an array without copying
it, holds what it points at, and refuses what a kernel could not read in place.

Truth: numpy's own reading of the same arrays (sums and single elements), and reference counts /
weak references for what is held.
"""

from __future__ import annotations

import copy
import gc
import pickle
import weakref

import numpy as np
import pytest
from numba import njit

from depthguard.fusion.camera_views import CameraViews, camera_free, camera_pyramid


@njit(cache=True)
def _read(free, pmin, pmax, k, v, u, i):
    f = camera_free(free, k)
    s = 0.0
    for r in range(f.shape[0]):
        for c in range(f.shape[1]):
            s += f[r, c]
    return s, f[v, u], camera_pyramid(pmin, k)[i], camera_pyramid(pmax, k)[i], f.shape[0], f.shape[1]


def test_kernels_read_each_camera_where_it_lies():
    rng = np.random.default_rng(2)
    views = CameraViews(3)
    shapes = [(48, 64), (30, 41), (5, 7)]
    arrays = [tuple(rng.uniform(0, 5, n).astype(np.float32) for n in (s, 200 + k, 200 + k))
              for k, s in enumerate(shapes)]
    for k, (f, a, b) in enumerate(arrays):
        views.point(k, f, a, b)
    for k, (f, a, b) in enumerate(arrays):
        v, u, i = f.shape[0] - 1, f.shape[1] - 2, 199 + k
        s, x, lo, hi, h, w = _read(views.free, views.pmin, views.pmax, k, v, u, i)
        assert s == pytest.approx(f.astype(np.float64).sum(), rel=1e-12) and x == f[v, u] and (h, w) == f.shape
        assert lo == a[i] and hi == b[i]
    big = np.zeros((60, 80), np.float32)   # a grid's buffer larger than the camera: its rows are 80 long
    big[:30, :41] = arrays[1][0]
    views.point(1, big, *arrays[1][1:])
    assert _read(views.free, views.pmin, views.pmax, 1, 29, 40, 0)[1] == arrays[1][0][29, 40]


def test_views_hold_what_they_point_at_until_pointed_elsewhere():
    views = CameraViews(1)
    f, a, b = (np.ones(n, np.float32) for n in ((4, 4), 10, 10))
    refs = [weakref.ref(x) for x in (f, a, b)]
    views.point(0, f, a, b)
    del f, a, b
    gc.collect()
    assert all(r() is not None for r in refs)            # a worker's pool cannot give them out again
    views.point(0, *(np.zeros(n, np.float32) for n in ((2, 2), 3, 3)))
    gc.collect()
    assert all(r() is None for r in refs)


_F32 = np.float32


@pytest.mark.parametrize("free, pmin, why", [
    (np.ones((4, 4)), np.ones(8, _F32), "float64 free (another camera's free depths are float32)"),
    (np.ones((4, 4), _F32), np.ones(8), "float64 pyramid"),
    (np.ones((4, 8), _F32)[:, ::2], np.ones(8, _F32), "a strided view"),
    (np.ones(16, _F32), np.ones(8, _F32), "1-D free"),
    (np.ones((4, 4), _F32), np.ones((2, 4), _F32), "2-D pyramid"),
])
def test_what_a_kernel_cannot_read_in_place_is_refused(free, pmin, why):
    views = CameraViews(2)
    before = views.free.copy()
    with pytest.raises(ValueError, match="C-contiguous"):
        views.point(1, free, pmin, np.ones_like(pmin))
    assert np.array_equal(views.free, before), why          # nothing pointed at


def test_pyramids_of_two_lengths_are_refused():
    with pytest.raises(ValueError, match="differ in length"):
        CameraViews(1).point(0, np.ones((2, 2), _F32), np.ones(5, _F32), np.ones(6, _F32))


def test_a_copy_points_at_what_it_holds_itself():
    """A copy, deep copy or pickle of the views (a grid copied by a user) reads the arrays it holds,
    never the original's memory by its old address."""
    views = CameraViews(2)
    f, a, b = np.arange(12.0, dtype=_F32).reshape(3, 4), np.arange(5.0, dtype=_F32), np.arange(5.0, dtype=_F32) + 1
    views.point(0, f, a, b)
    for other in (copy.copy(views), copy.deepcopy(views), pickle.loads(pickle.dumps(views))):
        g, ga, gb = other.arrays(0)
        assert other.free[0, 0] == g.__array_interface__["data"][0]
        assert other.pmin[0, 0] == ga.__array_interface__["data"][0]
        assert other.pmax[0, 0] == gb.__array_interface__["data"][0]
        assert other.arrays(1) is None
        s, x, lo, hi, h, w = _read(other.free, other.pmin, other.pmax, 0, 2, 3, 4)
        assert (s, x, lo, hi, h, w) == (f.sum(), f[2, 3], a[4], b[4], 3, 4)
    assert copy.deepcopy(views).free[0, 0] != views.free[0, 0]      # its own arrays, not the original's


def test_a_deep_copied_grid_answers_like_the_original_whatever_becomes_of_its_memory():
    """A user's deep copy of a loaded depth grid (states read in place) answers the same queries
    bit for bit after the original's states are written over (as a worker's pool would reuse
    them): the copy reads its own arrays."""
    from depthguard.cli.warm_up import _flat_grid

    grid, points, cfg = _flat_grid("flacco-cell")
    assert grid.states_used == 1 + len(grid.others)            # the others' states are read in place
    rng = np.random.default_rng(5)
    q = np.concatenate([points, points[:1] + rng.normal(0.0, 0.25, (200, 3))])
    twin, probe = copy.deepcopy(grid), copy.deepcopy(grid)     # before any query: nothing memoised
    want = grid.query(q, rho=cfg.query_rho, method=cfg.method, threads=1).copy()
    for g in (grid, probe):                                     # the original's memory reused
        for k in range(len(g.others)):
            for a in g._views.arrays(k):
                a.fill(0.0)
    assert not np.array_equal(probe.query(q, rho=cfg.query_rho, method=cfg.method, threads=1).distance,
                              want.distance)                    # (the other camera's arrays matter)
    got = twin.query(q, rho=cfg.query_rho, method=cfg.method, threads=1)
    assert np.isfinite(want.distance).any()
    assert np.array_equal(got.distance, want.distance) and np.array_equal(got.direction, want.direction)
    assert np.array_equal(got.observed, want.observed)


def test_a_state_not_readable_in_place_is_worked_out_by_the_grid_and_gets_no_share():
    """Another camera's state in arrays a kernel cannot read in place (Fortran order, a strided
    pyramid): the grid works that camera's state out itself (the same answers as a grid given no
    states), and its worker's sharer makes no share rather than failing the frame."""
    from depthguard.cli.warm_up import _flat_grid, _flat_states
    from depthguard.fusion.depth_grid_share import CameraSharer, share_spec
    from depthguard.fusion.depth_grid_state import StateMaker, StateOptions

    own, points, cfg = _flat_grid("flacco-cell", states=False)
    grid, _, _ = _flat_grid("flacco-cell", states=False)
    d = float(np.float32(0.5 * (grid.d_min + grid.d_max)))
    states = _flat_states(grid, d, StateOptions.of(cfg))
    other = grid.others[0].id
    st = StateMaker(grid.others[0]).make(np.full(grid.others[0].shape, d, np.float32), None, StateOptions.of(cfg),
                                         pyramids=True)
    assert st.pmin is not None
    odd = st._replace(free=np.asfortranarray(st.free), pmin=np.repeat(st.pmin, 2)[::2],
                      pmax=np.repeat(st.pmax, 2)[::2])
    assert not odd.free.flags.c_contiguous and not odd.pmin.flags.c_contiguous
    states[other] = odd
    before = grid.states_used
    depths = {c.id: np.full((c.height, c.width), d, np.float32) for c in [grid.principal_full, *grid.others]}
    o = StateOptions.of(cfg)
    grid.set_frames(depths, robot_capsules=None, robot_offset=o.robot_offset, invalid=o.invalid,
                    robot_in_others=o.robot_in_others, silhouette_px=o.silhouette_px, gap_px=o.gap_px,
                    states=states)
    assert grid.states_used - before == 1                      # the principal's only
    assert grid._views.arrays(0)[0].base is grid._kfree        # worked out into the grid's own buffer
    spec = share_spec(grid, other)
    ask = (np.zeros(1, np.int64), np.full((1, spec.nw), np.uint64(1)))
    assert CameraSharer().make(spec, odd, ask) is None
    assert CameraSharer().make(spec, st, ask) is not None      # (the same state in place: a share)
    own.set_frames(depths, robot_capsules=None, robot_offset=o.robot_offset, invalid=o.invalid,
                   robot_in_others=o.robot_in_others, silhouette_px=o.silhouette_px, gap_px=o.gap_px)
    a = grid.query(points, rho=cfg.query_rho, method=cfg.method, threads=1).copy()
    b = own.query(points, rho=cfg.query_rho, method=cfg.method, threads=1)
    assert np.array_equal(a.distance, b.distance) and np.array_equal(a.observed, b.observed)
