"""Another camera's free depths in float32, rounded down (issue 29, :mod:`depthguard.fusion.free32`).

Truths: float32 itself (numpy's conversion and ``nextafter``: a value is never stored above
itself, and at most two float32 steps below), the plain-numpy twin of the per-pixel state
(:func:`~depthguard.fusion.depth_grid_ref.frame_state_numpy`) rounded down by the plain-numpy
:func:`free_down32`, and a grid given the same state in float64 (a camera unit's, decoded from
the network) — the same answers, bit for bit.
"""

from __future__ import annotations

import numpy as np
import pytest

import depthguard as dg
from depthguard.fusion import depth_grid_ref as ref
from depthguard.fusion.depth_grid import DepthGridMap
from depthguard.fusion.depth_grid_state import CameraState, StateMaker, StateOptions
from depthguard.fusion.free32 import FREE_DTYPE, free_down32, round_down_into


def _values(rng) -> np.ndarray:
    """float64 free depths of every sort: float32 ones, ones between two float32, range limits
    that float32 does not hold (0.3, 0.2, 4.1), 0, inf, tiny and large ones."""
    exact = rng.uniform(0.1, 12.0, 400).astype(np.float32).astype(np.float64)
    between = rng.uniform(0.1, 12.0, 400)
    return np.concatenate([exact, between, [0.0, np.inf, 0.3, 0.2, 4.1, 1e-30, 3e5, 1.0, 2.0 ** -20]])


def test_rounded_down_never_above_and_at_most_two_steps_below():
    f = _values(np.random.default_rng(1))
    r = free_down32(f)
    assert r.dtype == np.float32
    assert (r.astype(np.float64) <= f).all()                         # never farther than the float64 value
    finite = np.isfinite(f) & (f > 0)
    two_below = np.nextafter(np.nextafter(f[finite].astype(np.float32), np.float32(0)), np.float32(0))
    assert (r[finite] >= two_below).all()                            # (a float32 step: 0.24 um at 2 m)
    exact = f.astype(np.float32).astype(np.float64) == f
    np.testing.assert_array_equal(r[exact], f[exact].astype(np.float32))   # a float32 stays itself
    assert r[np.isinf(f)][0] == np.inf and r[f == 0.0][0] == 0.0
    assert np.float64(r[f == 0.3][0]) < 0.3 and np.float64(r[f == 4.1][0]) < 4.1


def test_the_kernel_rounds_as_its_numpy_twin():
    f = _values(np.random.default_rng(2)).reshape(-1, 1) * np.ones((1, 3))
    out = np.full((f.shape[0] + 2, 5), -1.0, np.float32)             # a larger buffer: the top-left is written
    round_down_into(np.ascontiguousarray(f), out)
    np.testing.assert_array_equal(out[:f.shape[0], :3].view(np.int32), free_down32(f).view(np.int32))
    assert (out[f.shape[0]:] == -1.0).all() and (out[:, 3:] == -1.0).all()


def _cam(w, h, f=130.0, cid="c"):
    return dg.Camera(id=cid, width=w, height=h, fx=f, fy=f, cx=(w - 1) / 2, cy=(h - 1) / 2)


@pytest.mark.parametrize("robot_free, invalid", [(False, "unknown"), (True, "unknown"), (False, "free")])
def test_another_cameras_state_is_the_twins_rounded_down(robot_free, invalid):
    """:meth:`StateMaker.make` with pyramids (a camera other than the principal) writes float32:
    the plain-numpy state rounded down, bit for bit, with the same kinds, on an image holding
    invalid pixels (free up to ``min_range`` = 0.3 m, which float32 does not hold), returns beyond
    the rated range, the robot and its silhouette, and small gaps."""
    from tests.test_state_fused import _images

    rng = np.random.default_rng(7)
    H, W = 61, 87
    cam = _cam(W, H)
    depth, robot = _images(rng, H, W, np.float32)
    opts = StateOptions(0.03, invalid, "free" if robot_free else "unknown", 4, 3)
    st = StateMaker(cam).make(depth, robot, opts, robot_free, pyramids=True)
    assert st.free.dtype == FREE_DTYPE and st.pmin.dtype == FREE_DTYPE and st.pmax.dtype == FREE_DTYPE
    free64, kind = ref.frame_state_numpy(cam, depth, robot, 0.03, invalid, robot_free, 4, 3)
    np.testing.assert_array_equal(st.free.view(np.int32), free_down32(free64).view(np.int32))
    np.testing.assert_array_equal(st.kind, kind)
    if invalid == "unknown":
        lowered = st.free.astype(np.float64) < free64
        assert lowered.any() and (free64[lowered] == cam.min_range).any()   # min_range, rounded down


def test_a_float64_state_of_another_camera_answers_as_the_workers_float32():
    """A camera unit's state comes decoded in float64: the grid rounds it down into its own
    float32 buffer, and answers every query as a grid given the worker's float32 state of the same
    frame (with its pyramids), bit for bit; both count the state as used."""
    from test_depth_grid import _scene, _with_robot
    from test_depth_grid_state import _noisy

    rng = np.random.default_rng(11)
    prims, cams, _d = _scene(rng, 2)
    _a, _b, _c, depths, rdepths, caps = _with_robot(prims, cams)
    depths = _noisy(rng, depths)
    depths[cams[1].id][10:18, 20:28] = 0.0           # a hole wider than gap_px: free up to min_range (0.3 m)
    c0, c1 = cams[0].id, cams[1].id
    opts = StateOptions(0.03, "unknown", "unknown", 4, 3)
    kw = dict(robot_offset=0.03, invalid="unknown", robot_in_others="unknown", silhouette_px=4, gap_px=3,
              robot_capsules=caps)
    worker = {c.id: StateMaker(c).make(depths[c.id], rdepths[c.id], opts, pyramids=c.id != c0) for c in cams}
    free64, kind = ref.frame_state_numpy(cams[1], depths[c1], rdepths[c1], 0.03, "unknown", False, 4, 3)
    unit = dict(worker)
    unit[c1] = CameraState(free64, kind, opts, False)
    assert (free64 != worker[c1].free.astype(np.float64)).any()         # (min_range: rounded down in float32)
    a = DepthGridMap(cams, c0, 1.0, 4.6, 0.03, cache=False)
    b = DepthGridMap(cams, c0, 1.0, 4.6, 0.03, cache=False)
    a.set_frames(depths, rdepths, states=worker, **kw)
    b.set_frames(depths, rdepths, states=unit, **kw)
    assert a.states_used == b.states_used == 2
    assert b._views.arrays(0)[0].base is b._kfree                       # rounded down into its own buffer
    H, W = cams[1].shape
    np.testing.assert_array_equal(b._views.arrays(0)[0][:H, :W], worker[c1].free)
    pts = rng.uniform((-0.8, -0.8, 0.2), (0.8, 0.8, 1.6), (400, 3))       # around the objects and the robot
    ra = a.query(pts, rho=0.5, method="hybrid", threads=1)
    rb = b.query(pts, rho=0.5, method="hybrid", threads=1)
    assert np.isfinite(ra.distance).any()
    np.testing.assert_array_equal(ra.distance, rb.distance)
    np.testing.assert_array_equal(ra.direction, rb.direction)
    np.testing.assert_array_equal(ra.observed, rb.observed)
