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
    return K.cell_cleared(grid._views.free[sl], grid.rays[sl], grid.origins[sl], grid._kint[sl], 1, u, v,
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
            M._camera_stretch(grid._views.free, grid._views.pmin, grid._views.pmax, grid._koff, grid._kdims,
                              grid.rays, grid.origins, grid._kint, nk, k, u, v, g0, nd - 1, grid.d_min, grid.delta_d,
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
                blocked = M._centre_blocks(grid._views.free, grid.rays, grid.origins, grid._kint, k, u, v,
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


def test_gray_stretch_asks_a_new_frame_only_what_no_valid_memo_clears():
    """``gray_stretch`` after camera 0's new frame (its memo dropped, camera 1's kept): every
    cell's class is the rule's (an obstacle iff no camera clears it, ``cell_cleared`` per
    camera), and camera 0 evaluates none of the cells camera 1's memo knows it clears (the
    cameras with valid bits are applied first), while it still evaluates every other cell."""
    rng, grid = _grid(33)
    H, W, nd = grid.shape
    nk = len(grid.others)
    assert nk == 2
    nw = (nd + 63) // 64
    kmemo = M.new_memo(nk, H, W, nw)
    kver, kstamp, kdone, kclr = kmemo
    obits = np.zeros((H, W, nw), dtype=np.uint64)
    cbits = np.zeros((H, W, nw), dtype=np.uint64)
    bits = lambda x: np.unpackbits(x.view(np.uint8), bitorder="little")[:nd].astype(bool)  # noqa: E731
    n_skipped = n_obst = 0
    for u, v in _columns(rng, grid, 40):
        g0 = int(rng.integers(0, nd // 2))
        args = (grid._views.free, grid._views.pmin, grid._views.pmax, grid._koff, grid._kdims, grid.rays,
                grid.origins, grid._kint, nk, grid.d_min, grid.delta_d, kmemo, obits, cbits)
        M.gray_stretch(u, v, g0, nd - 1, *args)        # both cameras' bits for their frames
        kver[0] += 1                                    # camera 0 loads a new frame
        obits[v, u] = 0
        cbits[v, u] = 0
        M.gray_stretch(u, v, g0, nd - 1, *args)
        clr = np.array([[g >= g0 and _cleared_by(grid, k, u, v, g) for g in range(nd)] for k in range(nk)])
        want_obst = (np.arange(nd) >= g0) & ~clr[0] & ~clr[1]
        np.testing.assert_array_equal(bits(obits[v, u]), want_obst, err_msg=f"column {(u, v)}")
        np.testing.assert_array_equal(bits(cbits[v, u]), np.arange(nd) >= g0)
        # camera 1's memo holds the cells camera 0 left to it on the first call (not those both clear)
        known1 = clr[1] & ~clr[0]
        asked = bits(kdone[0, v, u])
        np.testing.assert_array_equal(asked, (np.arange(nd) >= g0) & ~known1, err_msg=f"column {(u, v)}")
        n_skipped += int(known1.sum())
        n_obst += int(want_obst.sum())
    assert n_skipped >= 200 and n_obst >= 200, (n_skipped, n_obst)   # both kinds of cell met
