"""One camera's clearing as the memo evaluates it (R12, ``depth_grid_memo``) against the cell rule
of ``depth_grid_kernels`` applied cell by cell (the 8-corner footprint of each cell)."""

from __future__ import annotations

import numpy as np

from depthguard.fusion import depth_grid_kernels as K
from depthguard.fusion import depth_grid_memo as M
from depthguard.fusion.depth_grid import DepthGridMap
from tests.test_depth_grid import _scene, _with_robot


def _grid(seed, n_cams=3):
    rng = np.random.default_rng(seed)
    prims, cams, depths = _scene(rng, n_cams)
    a, b, c, depths, rdepths, caps = _with_robot(prims, cams)
    grid = DepthGridMap(cams, "c0", 1.0, 4.6, 0.03, cache=False)
    grid.set_frames(depths, rdepths, robot_capsules=caps, lazy=False)
    return rng, grid


def _cleared_by(grid, k, u, v, g):
    """The rule (``cell_cleared`` for camera ``k`` alone) on cell ``g`` of column ``(u, v)``,
    its depths ``d_min + [g, g + 1] * delta_d``."""
    sl = slice(k, k + 1)
    return K.cell_cleared(grid._kfree[sl], grid.rays[sl], grid.origins[sl], grid._kint[sl], 1, u, v,
                          grid.d_min + g * grid.delta_d, grid.d_min + (g + 1) * grid.delta_d)


def _columns(rng, grid, n):
    H, W, _ = grid.shape
    return [(int(u), int(v)) for u, v in zip(rng.integers(0, W, n), rng.integers(0, H, n))]


def test_camera_stretch_equals_the_cell_rule():
    """``_camera_stretch`` (pyramid stretch tests, shared cross-sections, the centre shortcut)
    sets exactly the bits of the cell rule applied to every cell, for every other camera."""
    rng, grid = _grid(31)
    H, W, nd = grid.shape
    nk = len(grid.others)
    nw = (nd + 63) // 64
    kdone = np.zeros((nk, H, W, nw), dtype=np.uint64)
    kclr = np.zeros((nk, H, W, nw), dtype=np.uint64)
    n_clear = n_conf = 0
    for u, v in _columns(rng, grid, 40):
        g0 = int(rng.integers(0, nd // 2))
        for k in range(nk):
            M._camera_stretch(grid._kfree, grid._kpmin, grid._kpmax, grid._koff, grid._kdims, grid.rays,
                              grid.origins, grid._kint, nk, k, u, v, g0, nd - 1, grid.d_min, grid.delta_d,
                              kdone, kclr)
            done = np.unpackbits(kdone[k, v, u].view(np.uint8), bitorder="little")[:nd].astype(bool)
            got = np.unpackbits(kclr[k, v, u].view(np.uint8), bitorder="little")[:nd].astype(bool)
            want = np.array([g >= g0 and _cleared_by(grid, k, u, v, g) for g in range(nd)])
            np.testing.assert_array_equal(done, np.arange(nd) >= g0)
            np.testing.assert_array_equal(got, want, err_msg=f"column {(u, v)} camera {k}")
            n_clear += int(want.sum())
            n_conf += int((~want[g0:]).sum())
    assert n_clear >= 500 and n_conf >= 500, (n_clear, n_conf)      # both classes met


def test_centre_shortcut_only_on_cells_the_camera_does_not_clear():
    """``_centre_blocks`` concludes only for cells the rule says camera ``k`` does not clear, and
    it does conclude for most of those cells that ``k`` sees whole (the shortcut is not idle)."""
    rng, grid = _grid(32)
    H, W, nd = grid.shape
    n_blocked = n_seen_conf = n_blocked_seen = 0
    for u, v in _columns(rng, grid, 60):
        for k in range(len(grid.others)):
            for g in range(nd):
                blocked = M._centre_blocks(grid._kfree, grid.rays, grid.origins, grid._kint, k, u, v,
                                           grid.d_min + (g + 0.5) * grid.delta_d)
                cleared = _cleared_by(grid, k, u, v, g)
                assert not (blocked and cleared), (u, v, k, g)
                seen = K.cell_footprint(grid.rays, grid.origins, grid._kint, k, u, v, grid.d_min + g * grid.delta_d,
                                        grid.d_min + (g + 1) * grid.delta_d)[0]
                n_blocked += blocked
                if seen and not cleared:
                    n_seen_conf += 1
                    n_blocked_seen += blocked
    assert n_seen_conf >= 1000 and n_blocked_seen >= 0.5 * n_seen_conf, (n_blocked_seen, n_seen_conf, n_blocked)
