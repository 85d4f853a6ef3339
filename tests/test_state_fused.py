"""The camera worker's fused state pass (issue 29): :func:`frame_state_fused` (through
:func:`state_into`) gives, bit for bit, the arrays of the unfused passes it replaced (the dilated
robot depth and the small-gap depth as whole images, then ``frame_state`` / ``frame_state_binned``)
and of the plain-numpy twin of R9/R28/R32, on images with every kind of pixel: dropout runs and
single holes (the small-gap rule), invalid pixels next to the robot (the silhouette rule), NaN,
inf, returns beyond the rated range, a robot touching the border, NaN / inf / negative robot
depths, odd image sizes, float32 and float64 images."""

from __future__ import annotations

import numpy as np
import pytest

import depthguard as dg
from depthguard.distance.gaps import GapBuffers
from depthguard.distance.silhouette import SilhouetteBuffers
from depthguard.fusion import depth_grid_ref as ref
from depthguard.fusion.depth_grid_kernels import build_pyramids
from depthguard.fusion.depth_grid_state import (StateMaker, StateOptions, bin_state_numpy, pyramid_layout,
                                                pyramid_levels, state_into, state_into_unfused, state_pyramids)


def _cam(w, h, f=130.0):
    return dg.Camera(id="c", width=w, height=h, fx=f, fy=f, cx=(w - 1) / 2, cy=(h - 1) / 2)


def _images(rng, H, W, dtype):
    """A depth image with every kind of pixel, and a robot depth image."""
    depth = rng.uniform(0.6, 7.0, (H, W))
    depth[rng.random((H, W)) < 0.04] = 0.0                       # single holes
    for _ in range(12):                                          # dropout runs (gaps of 1-5 px) and blobs
        v, u = rng.integers(0, H), rng.integers(0, W)
        depth[v, u:u + rng.integers(1, 6)] = 0.0
        depth[v:v + rng.integers(1, 6), u] = np.nan
    depth[rng.random((H, W)) < 0.01] = np.inf
    depth[rng.random((H, W)) < 0.01] = rng.uniform(8.0, 14.0)   # beyond the rated range (and beyond its limit)
    depth[rng.random((H, W)) < 0.01] = 0.1                       # nearer than min_range
    # a far wall past the rated range (6 m; flacco-cell's room past a Kinect's 4 m): a band of rows
    # returning beyond it, some beyond its limit (3 x 6 m), with holes; values at both limits
    band = depth[H // 2:H // 2 + H // 5]
    band[...] = rng.uniform(6.0, 19.0, band.shape)
    band[rng.random(band.shape) < 0.05] = 0.0
    band[0, :4] = (6.0, 18.0, np.nextafter(18.0, 19.0), np.nextafter(6.0, 7.0))
    robot = np.zeros((H, W))
    v0, u0 = H // 4, W // 3
    robot[v0:v0 + H // 3, u0:u0 + W // 4] = rng.uniform(0.5, 6.0, (H // 3, W // 4))
    robot[0:3, W - 5:] = 1.5                                     # touching the border
    robot[v0 + 2, u0 + 2] = np.nan
    robot[v0 + 3, u0 + 3] = np.inf
    robot[v0 + 4, u0 + 4] = -1.0
    # a dark object over the robot's outline: invalid pixels within silhouette_px of it
    depth[v0 - 3:v0 + 6, u0 - 4:u0 + 9] = 0.0
    # the robot seen where it is rendered, on part of it
    near = (robot > 0) & np.isfinite(robot) & (rng.random((H, W)) < 0.5)
    depth[near] = robot[near] + rng.uniform(-0.05, 0.05, near.sum())
    return depth.astype(dtype), robot.astype(dtype)


@pytest.mark.parametrize("shape", [(120, 160), (61, 87)])
# float64 images compile the fused parallel kernel once more (~150 s on a fresh clone): a soak
# (`make soak`), not `make test`; the frames a worker passes are float32
@pytest.mark.parametrize("dtype", [np.float32, pytest.param(np.float64, marks=[pytest.mark.slow, pytest.mark.soak])])
def test_fused_state_equals_unfused_passes_and_numpy_twin(shape, dtype):
    rng = np.random.default_rng(7 + shape[1])
    H, W = shape
    cam = _cam(W, H)
    depth, robot = _images(rng, H, W, dtype)
    sil, gaps = SilhouetteBuffers(cam.shape), GapBuffers(cam.shape)
    checked = 0
    for n_sil, n_gap in ((4, 3), (0, 3), (2, 0), (0, 0), (7, 5)):
        for invalid, robot_free in (("unknown", False), ("unknown", True), ("free", False)):
            opts = StateOptions(0.03, invalid, "unknown", n_sil, n_gap)
            for rd in (robot, None):
                want_f, want_k = ref.frame_state_numpy(cam, depth, rd, 0.03, invalid, robot_free, n_sil, n_gap)
                for b in (1, 2, 3, 4):
                    hb, wb = -(-H // b), -(-W // b)
                    f1, k1 = np.full((hb, wb), -7.0), np.full((hb, wb), 9, np.int8)
                    f2, k2 = np.full((hb, wb), -7.0), np.full((hb, wb), 9, np.int8)
                    state_into(cam, depth, rd, opts, robot_free, sil, gaps, f1, k1, b)
                    state_into_unfused(cam, depth, rd, opts, robot_free, sil, gaps, f2, k2, b)
                    np.testing.assert_array_equal(f1, f2)
                    np.testing.assert_array_equal(k1, k2)
                    tf, tk = (want_f, want_k) if b == 1 else bin_state_numpy(want_f, want_k, b)
                    np.testing.assert_array_equal(f1, tf)
                    np.testing.assert_array_equal(k1, tk)
                    checked += 1
    assert checked == 5 * 3 * 2 * 4
    # the images do exercise both rules: the silhouette and the gaps change the state
    opts_on, opts_off = StateOptions(0.03, "unknown", "unknown", 4, 3), StateOptions(0.03, "unknown", "unknown", 0, 0)
    on, off = np.empty((H, W)), np.empty((H, W))
    kon, koff = np.empty((H, W), np.int8), np.empty((H, W), np.int8)
    state_into(cam, depth, robot, opts_on, False, sil, gaps, on, kon)
    state_into(cam, depth, robot, opts_off, False, sil, gaps, off, koff)
    assert ((kon == 1) & (koff == 2)).sum() > 10                 # silhouette: unknown -> robot
    assert ((kon == 2) & (on > cam.min_range) & (on < cam.max_range) & (off == cam.min_range)).sum() > 10  # gaps


def test_fused_state_in_a_wider_buffer_and_robot_free_everywhere():
    """The state written into the top-left of buffers wider than the image (the grid's
    buffers are sized for its largest camera), and an image that is all robot or all invalid."""
    rng = np.random.default_rng(3)
    cam = _cam(40, 30)
    # the fused pass with scratch buffers wider than the image, as the grid's (sized for its largest
    # camera); the unfused reference with its camera's own, as StateMaker's (wider ones would hand
    # its kernels non-contiguous views: two signatures compiled for this test alone, 11 CPU-s)
    sil, gaps = SilhouetteBuffers((50, 70)), GapBuffers((50, 70))
    sil_ref, gaps_ref = SilhouetteBuffers((30, 40)), GapBuffers((30, 40))
    depth, robot = _images(rng, 30, 40, np.float32)
    all_robot = np.full((30, 40), 2.0, np.float32)
    all_invalid = np.zeros((30, 40), np.float32)
    opts = StateOptions(0.03, "unknown", "unknown", 4, 3)
    for d, rd in ((depth, robot), (depth, all_robot), (all_invalid, robot), (all_invalid, all_robot)):
        for b in (1, 2, 4):
            f1, k1 = np.full((50, 70), -7.0), np.full((50, 70), 9, np.int8)
            f2, k2 = np.full((50, 70), -7.0), np.full((50, 70), 9, np.int8)
            state_into(cam, d, rd, opts, False, sil, gaps, f1, k1, b)
            state_into_unfused(cam, d, rd, opts, False, sil_ref, gaps_ref, f2, k2, b)
            np.testing.assert_array_equal(f1, f2)
            np.testing.assert_array_equal(k1, k2)
            hb, wb = -(-30 // b), -(-40 // b)
            assert (f1[hb:, :] == -7.0).all() and (f1[:, wb:] == -7.0).all() and (f1[:hb, :wb] != -7.0).all()


@pytest.mark.parametrize("shape", [(48, 64), (61, 87), (45, 1), (1, 7), (1, 1), (33, 32)])
def test_state_pyramids_equal_build_pyramids_and_the_blocks(shape):
    """The worker's pyramids (:func:`state_pyramids`, what :meth:`StateMaker.make` writes with
    ``pyramids=True``) are :func:`build_pyramids`' bit for bit, and level ``l`` holds the min / max
    of the aligned ``2^l x 2^l`` blocks of the state (clipped at an odd border), computed here by
    numpy from the state itself; level 0 is left as it was (neither writes it) unless it is the only one."""
    rng = np.random.default_rng(11 + shape[1])
    H, W = shape
    free = rng.uniform(0.3, 6.0, (H, W))
    free[rng.random((H, W)) < 0.1] = np.inf
    free[rng.random((H, W)) < 0.1] = 0.3
    levels = pyramid_levels(H, W)
    offs, dims, size = pyramid_layout(H, W, levels)
    got = [np.full(size, -9.0) for _ in range(2)]
    want = [np.full(size, -9.0) for _ in range(2)]
    state_pyramids(free, H, W, got[0], got[1], offs, dims, 1)
    build_pyramids(free, H, W, want[0], want[1], offs, dims)
    np.testing.assert_array_equal(got[0].view(np.int64), want[0].view(np.int64))
    np.testing.assert_array_equal(got[1].view(np.int64), want[1].view(np.int64))
    for lv in range(levels):
        s, (h, w) = 2 ** lv, dims[lv]
        pmin = got[0][offs[lv]:offs[lv] + h * w].reshape(h, w)
        pmax = got[1][offs[lv]:offs[lv] + h * w].reshape(h, w)
        if lv == 0 and levels > 1:
            assert (pmin == -9.0).all() and (pmax == -9.0).all()
            continue
        bmin = np.array([[free[v * s:v * s + s, u * s:u * s + s].min() for u in range(w)] for v in range(h)])
        bmax = np.array([[free[v * s:v * s + s, u * s:u * s + s].max() for u in range(w)] for v in range(h)])
        np.testing.assert_array_equal(pmin, bmin)
        np.testing.assert_array_equal(pmax, bmax)
    if H >= 16 and W >= 16:                           # and StateMaker.make writes them with the state
        cam = _cam(W, H)
        depth, robot = _images(rng, H, W, np.float32)
        st = StateMaker(cam).make(depth, robot, StateOptions(0.03, "unknown", "unknown", 4, 3), pyramids=True)
        ref_min, ref_max = np.empty(size), np.empty(size)
        build_pyramids(st.free, H, W, ref_min, ref_max, offs, dims)
        np.testing.assert_array_equal(st.pmin[offs[1]:], ref_min[offs[1]:])
        np.testing.assert_array_equal(st.pmax[offs[1]:], ref_max[offs[1]:])


def test_level1_with_the_state_checks_its_arrays():
    """``state_into``'s ``level1`` (the pyramids' level 1 written with the state) is refused, with a
    sentence and nothing written, when it is not at bin 1 or its arrays cannot hold level 1;
    given right, level 1 is the blocks' min / max of the state it wrote (numpy here)."""
    H, W = 31, 45
    cam = _cam(W, H)
    depth, robot = _images(np.random.default_rng(3), H, W, np.float32)
    opts = StateOptions(0.03, "unknown", "unknown", 4, 3)
    offs, dims, size = pyramid_layout(H, W, pyramid_levels(H, W))
    f32 = np.float32                       # (another camera's state and pyramids: free32)
    free, kind = np.full((H, W), -5.0, f32), np.zeros((H, W), np.int8)
    free64 = np.full((H, W), -5.0)
    bufs = (SilhouetteBuffers((H, W)), GapBuffers((H, W)))
    for out, bad in [(free, dict(level1=(np.zeros(size, f32), np.zeros(size, f32), int(offs[1])), bin=2)),
                     (free, dict(level1=(np.zeros(int(offs[1]) + 10, f32), np.zeros(int(offs[1]) + 10, f32),
                                         int(offs[1])))),
                     (free, dict(level1=(np.zeros(size, f32), np.zeros(size - 1, f32), int(offs[1])))),
                     (free, dict(level1=(np.zeros(size), np.zeros(size), int(offs[1])))),          # float64 pyramids
                     (free64, dict(level1=(np.zeros(size, f32), np.zeros(size, f32), int(offs[1]))))]:  # float64 state
        with pytest.raises(ValueError, match="level1"):
            state_into(cam, depth, robot, opts, False, *bufs, out, kind, **bad)
        assert (out == -5.0).all()
    with pytest.raises(ValueError, match="out_free"):
        state_into(cam, depth, robot, opts, False, *bufs, np.zeros((H, W), np.float16), kind)
    pmin, pmax = np.full(size, -9.0, f32), np.full(size, -9.0, f32)
    state_into(cam, depth, robot, opts, False, *bufs, free, kind, level1=(pmin, pmax, int(offs[1])))
    h, w = dims[1]
    pad = np.pad(free, ((0, 2 * h - H), (0, 2 * w - W)), mode="edge")
    blocks = pad.reshape(h, 2, w, 2)
    np.testing.assert_array_equal(pmin[offs[1]:offs[1] + h * w].reshape(h, w), blocks.min(axis=(1, 3)))
    np.testing.assert_array_equal(pmax[offs[1]:offs[1] + h * w].reshape(h, w), blocks.max(axis=(1, 3)))
    assert (pmin[:offs[1]] == -9.0).all() and (pmin[offs[1] + h * w:] == -9.0).all()


@pytest.mark.parametrize("dtype,shape", [(np.float32, (48, 64)), (np.float64, (48, 64)), (np.float32, (45, 61)), (np.float32, (97, 129))])
def test_units_counts_equal_numpy_twin_at_the_limits(dtype, shape):
    """The worker's units check counts in one compiled loop what numpy counted on the sample
    (every ``UNITS_STEP``-th pixel), including pixels exactly at and one float step around both limits (numpy
    compares a float32 image with the limit rounded to float32), NaN, inf and negative values."""
    from depthguard.camera import RETURN_LIMIT_FACTOR
    from depthguard.depth_io import (NEAR_LIMIT_M, UNITS_STEP, UnitsCheck, _units_counts, _units_counts_numpy,
                                     depth_units_problem)

    H, W = shape                  # (45, 61): the sample's last row and column on the image's edge
    cam = dg.Camera(id="c", width=W, height=H, fx=50.0, fy=50.0, cx=31.5, cy=23.5, min_range=0.3,
                    max_range=8.0)
    s = UNITS_STEP
    sample = (-(-H // s), -(-W // s))
    far, near = RETURN_LIMIT_FACTOR * 8.0, min(0.3, NEAR_LIMIT_M)
    rng = np.random.default_rng(5)
    for share_far in (0.0, 0.3, 0.7):
        d = rng.uniform(0.5, 7.0, (H, W))
        d[rng.random(d.shape) < share_far] = 1000.0                # millimetres read as metres
        edge = []
        for lim in (far, near):
            x = dtype(lim)
            edge += [x, np.nextafter(x, dtype(0)), np.nextafter(x, dtype(np.inf)), lim]
        d[::s, ::s].flat[:len(edge)] = edge              # in the sample
        d[::s, ::s][rng.random(sample) < 0.1] = np.nan
        d[::s, ::s][rng.random(sample) < 0.05] = np.inf
        d[::s, ::s][rng.random(sample) < 0.05] = -1.0
        d[-1, -1] = 1000.0 if (H - 1) % s == 0 and (W - 1) % s == 0 else d[-1, -1]   # the last sampled pixel
        d = d.astype(dtype)
        got = _units_counts(d, s, dtype(far), dtype(near))
        want = _units_counts_numpy(d[::s, ::s], far, near)
        assert tuple(int(x) for x in got) == want
        assert (depth_units_problem(d, cam) is None) == (share_far < 0.5)
        assert UnitsCheck(cam)(d) == depth_units_problem(d, cam)    # the worker's, limits made once


def test_units_check_says_what_depth_units_problem_says():
    """:class:`~depthguard.depth_io.UnitsCheck` (a camera worker's, its limits worked out once) gives
    :func:`~depthguard.depth_io.depth_units_problem`'s sentence or None on every kind of frame:
    metres, millimetres read as metres, metres in a millimetre PNG, no return at all, and frames it
    does not count itself (integer millimetres, a nested list)."""
    from depthguard.depth_io import UnitsCheck, depth_units_problem

    cam = dg.Camera(id="c", width=64, height=48, fx=50.0, fy=50.0, cx=31.5, cy=23.5, min_range=0.3,
                    max_range=8.0)
    rng = np.random.default_rng(3)
    metres = rng.uniform(0.5, 7.0, cam.shape)
    frames = [metres.astype(np.float32), metres, (metres * 1000).astype(np.float32), (metres / 1000),
              np.zeros(cam.shape, np.float32), (metres * 1000).astype(np.uint16), metres.tolist()]
    check = UnitsCheck(cam)
    said = [check(f) for f in frames]
    assert said == [depth_units_problem(f, cam) for f in frames]
    assert said[0] is None and said[1] is None and said[4] is None
    assert "millimetres" in said[2] and "hold metres" in said[3] and said[5] is not None


def test_robot_spans_leave_the_state_unchanged():
    """The state made with the robot depth's rows' spans (the camera worker passes its renderer's:
    the robot's pixels are looked for within them alone) is, bit for bit, the state of the unfused
    passes, with spans that fit each row's robot pixels, that hold more, and whole rows; on a
    robot lying diagonally, whose rows each cover a small part of its box (the silhouette's row
    pass is worked out near each row's robot pixels). Spans that leave robot pixels out change
    the state (the check can fail)."""
    rng = np.random.default_rng(5)
    H, W = 90, 120
    cam = _cam(W, H)
    depth, _ = _images(rng, H, W, np.float32)
    robot = np.zeros((H, W), np.float32)
    for v in range(10, 80):                          # a diagonal arm 6-9 px wide
        u = 10 + v
        robot[v, u:u + 6 + v % 4] = rng.uniform(0.8, 3.0, 6 + v % 4)
    robot[40, 100] = 2.0                             # a lone pixel to the right of the arm
    depth[robot > 0] = 0.0                           # invalid pixels on and next to the robot
    depth[::7, 30:110] = 0.0
    sil, gaps = SilhouetteBuffers(cam.shape), GapBuffers(cam.shape)
    tight = np.zeros((H, 2), np.int32)
    for v in range(H):
        cols = np.flatnonzero(robot[v] > 0)
        if cols.size:
            tight[v] = (cols[0], cols[-1] + 1)
    loose = tight.copy()
    loose[:, 0] = np.maximum(loose[:, 0] - 5, 0)
    loose[:, 1] = np.minimum(np.where(loose[:, 1] > 0, loose[:, 1] + 5, 30), W)
    whole = np.zeros((H, 2), np.int32)
    whole[:, 1] = W
    opts = StateOptions(0.03, "unknown", "unknown", 4, 3)
    for b in (1, 2, 3, 4):                           # every pass reads the robot within the spans alone
        hb, wb = -(-H // b), -(-W // b)
        want_f, want_k = np.empty((hb, wb)), np.empty((hb, wb), np.int8)
        state_into_unfused(cam, depth, robot, opts, False, sil, gaps, want_f, want_k, b)
        assert (want_k == 1).sum() > 50 // b
        for spans in (tight, loose, whole, None):
            f, k = np.full((hb, wb), -7.0), np.full((hb, wb), 9, np.int8)
            state_into(cam, depth, robot, opts, False, sil, gaps, f, k, b, robot_spans=spans)
            np.testing.assert_array_equal(f, want_f)
            np.testing.assert_array_equal(k, want_k)
        cut = tight.copy()
        cut[40] = (0, 0)                             # row 40's robot pixels left out
        f, k = np.full((hb, wb), -7.0), np.full((hb, wb), 9, np.int8)
        state_into(cam, depth, robot, opts, False, sil, gaps, f, k, b, robot_spans=cut)
        assert not (np.array_equal(f, want_f) and np.array_equal(k, want_k))
    with pytest.raises(ValueError, match="robot_spans"):
        state_into(cam, depth, robot, opts, False, sil, gaps, f, k, 4, robot_spans=tight[:-1])


def test_maker_with_the_renderers_spans_is_state_into_for_every_role():
    """A camera worker's :meth:`StateMaker.make` (float32 frames, the renderer's spans, pooled
    buffers: ``state_into``'s checks and constants worked out once per options and role, issue 29)
    writes, bit for bit, :func:`state_into`'s state — principal binned, another camera with and
    without its pyramids (those :func:`build_pyramids`'), options changing from frame to frame
    (the constants follow them); and a frame of another shape is refused as before."""
    rng = np.random.default_rng(9)
    H, W = 90, 120
    cam = _cam(W, H)
    depth, robot = _images(rng, H, W, np.float32)
    spans = np.zeros((H, 2), np.int32)
    for v in range(H):
        cols = np.flatnonzero(robot[v] != 0)
        if cols.size:
            spans[v] = (cols[0], cols[-1] + 1)
    robot = np.where(spans[:, :1] <= np.arange(W), robot, 0).astype(np.float32)   # 0 outside the spans
    robot = np.where(np.arange(W) < spans[:, 1:], robot, 0).astype(np.float32)
    maker, sil, gaps = StateMaker(cam), SilhouetteBuffers(cam.shape), GapBuffers(cam.shape)
    levels = pyramid_levels(H, W)
    offs, dims, size = pyramid_layout(H, W, levels)
    checked = 0
    for opts in (StateOptions(0.03, "unknown", "unknown", 4, 3), StateOptions(0.05, "free", "unknown", 0, 0),
                 StateOptions(0.03, "unknown", "unknown", 2, 0), StateOptions(0.03, "unknown", "unknown", 4, 3)):
        for robot_free in (False, True):
            for pyramids, b in ((False, 2), (True, 1), (False, 1), (False, 3)):
                out = [np.full(sh, -7, dt) for sh, dt in maker.layout(pyramids, b)]
                st = maker.make(depth, robot, opts, robot_free, pyramids, b, out=out, robot_spans=spans)
                hb, wb = -(-H // b), -(-W // b)
                # (another camera's with its pyramids in float32, rounded down: the layout's dtype)
                f, k = np.full((hb, wb), -7.0, out[0].dtype), np.full((hb, wb), 9, np.int8)
                state_into(cam, depth, robot, opts, robot_free, sil, gaps, f, k, b, robot_spans=spans)
                np.testing.assert_array_equal(st.free, f)
                np.testing.assert_array_equal(st.kind, k)
                assert st.free is out[0] and st.bin == b and st.options == opts
                if pyramids:
                    pmin, pmax = np.full(size, -9.0, out[2].dtype), np.full(size, -9.0, out[3].dtype)
                    build_pyramids(f, H, W, pmin, pmax, offs, dims)
                    np.testing.assert_array_equal(st.pmin[offs[1]:], pmin[offs[1]:])
                    np.testing.assert_array_equal(st.pmax[offs[1]:], pmax[offs[1]:])
                    assert st.levels == levels
                checked += 1
    assert checked == 4 * 2 * 4 and len(maker._constants) == 3 * 2 * 3
    with pytest.raises(ValueError, match="shape"):
        maker.make(depth[:-1], robot[:-1], opts, False, False, 2, robot_spans=spans[:-1])
