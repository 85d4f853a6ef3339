"""A camera's share of the depth grid build (R36): the frame's per-pixel state made off the
build (on the camera's worker) equals the numpy twin of R9/R28/R32, gives the grid exactly the
answers of a build that works it out itself, and is never used when made with other settings."""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.fusion import depth_grid_ref as ref
from depthguard.fusion.depth_grid import DepthGridMap
from depthguard.fusion.depth_grid_state import StateMaker, StateOptions
from depthguard.geometry.primitives import Sphere

from test_depth_grid import _T, _scene, _with_robot


def _noisy(rng, depths):
    """Dropouts and flying pixels on the rendered frames, as a real sensor gives them."""
    out = {}
    for cid, d in depths.items():
        d = d.copy()
        d[rng.random(d.shape) < 0.05] = 0.0
        d[rng.random(d.shape) < 0.01] = np.nan
        out[cid] = d
    return out


def test_state_equals_numpy_twin(rng):
    """The state of :class:`StateMaker` is R9/R28 of the plain-numpy twin, pixel for pixel, for
    both roles (robot pixels free up to the robot, or confirming nothing)."""
    prims, cams, depths = _scene(rng, 2)
    _a, _b, _c, depths, rdepths, _caps = _with_robot(prims, cams)
    depths = _noisy(rng, depths)
    cam = cams[1]
    maker = StateMaker(cam)
    for robot_free in (False, True):
        for invalid in ("unknown", "free"):
            st = maker.make(depths[cam.id], rdepths[cam.id], StateOptions(0.03, invalid, "unknown", 0, 0),
                            robot_free)
            free, kind = ref.frame_state_numpy(cam, depths[cam.id], rdepths[cam.id], 0.03, invalid, robot_free)
            np.testing.assert_array_equal(st.free, free)
            np.testing.assert_array_equal(st.kind, kind)


def test_states_made_off_the_build_give_the_same_answers():
    """A grid loaded with each frame's state made by the camera (``states=``) answers exactly like
    one that works the states out itself, through frames of the principal and of another camera
    with the product's rules (silhouette, small gaps); a state made with other settings (another
    robot offset, the other role) is not copied in — the answers stay right — and a stale state
    (of an older frame) would change them, so the comparison is not a no-op."""
    rng = np.random.default_rng(11)
    prims, cams, depths = _scene(rng, 3)
    a, b, c, depths, rdepths, caps = _with_robot(prims, cams)
    depths = _noisy(rng, depths)
    own = DepthGridMap(cams, "c0", 1.0, 4.6, 0.03, cache=False)
    shared = DepthGridMap(cams, "c0", 1.0, 4.6, 0.03, cache=False)
    makers = {cam.id: StateMaker(cam) for cam in cams}
    opts = StateOptions(0.03, "unknown", "unknown", 4, 3)
    kw = dict(robot_offset=0.03, invalid="unknown", robot_in_others="unknown", silhouette_px=4, gap_px=3)
    P = np.vstack([rng.uniform(-0.6, 0.6, (12, 3)), a + (b - a) * 0.5, c])
    frames = dict(depths)
    states = {cid: makers[cid].make(frames[cid], rdepths[cid], opts) for cid in frames}
    used = 0
    for step, cid in enumerate([None, "c1", "c0", "c2", "c1"]):
        changed = None
        if cid is not None:
            ball = Sphere(radius=0.2, world_from_local=_T(*rng.uniform(-0.4, 0.4, 3)))
            cam = next(k for k in cams if k.id == cid)
            frames[cid] = _noisy(rng, _with_robot(prims + [ball], [cam])[3])[cid]
            states[cid] = makers[cid].make(frames[cid], rdepths[cid], opts)
            changed = [cid]
        own.set_frames(frames, rdepths, robot_capsules=caps, changed=changed, **kw)
        shared.set_frames(frames, rdepths, robot_capsules=caps, changed=changed, states=states, **kw)
        assert shared.states_used == used + (3 if changed is None else 1)
        used = shared.states_used
        r1, r2 = (g.query(P, 0.4, "hybrid").copy() for g in (own, shared))
        np.testing.assert_array_equal(r1.distance, r2.distance)
        np.testing.assert_array_equal(r1.direction, r2.direction)
        np.testing.assert_array_equal(r1.observed, r2.observed)
    # made with other settings: not used
    other = {cid: makers[cid].make(frames[cid], rdepths[cid], opts._replace(robot_offset=0.2)) for cid in frames}
    other["c1"] = makers["c1"].make(frames["c1"], rdepths["c1"], opts, robot_free=True)
    shared.set_frames(frames, rdepths, robot_capsules=caps, states=other, **kw)
    assert shared.states_used == used
    np.testing.assert_array_equal(shared.query(P, 0.4, "hybrid").distance, own.query(P, 0.4, "hybrid").distance)
    # an older frame's state changes the answers: the states really are what the grid loads
    old = {cid: makers[cid].make(depths[cid], rdepths[cid], opts) for cid in depths}
    shared.set_frames(frames, rdepths, robot_capsules=caps, states=old, **kw)
    assert not np.array_equal(shared.query(P, 0.4, "hybrid").distance, own.query(P, 0.4, "hybrid").distance)


def test_pyramids_made_with_the_state_are_the_grids():
    """The other cameras' min / max pyramids made with their state (``pyramids=True``) are the ones
    the grid builds itself, level for level, and are read in place instead of built."""
    rng = np.random.default_rng(3)
    prims, cams, depths = _scene(rng, 3)
    _a, _b, _c, depths, rdepths, caps = _with_robot(prims, cams)
    depths = _noisy(rng, depths)
    opts = StateOptions(0.03, "unknown", "unknown", 4, 3)
    kw = dict(robot_offset=0.03, invalid="unknown", robot_in_others="unknown", silhouette_px=4, gap_px=3)
    own = DepthGridMap(cams, "c0", 1.0, 4.6, 0.03, cache=False)
    shared = DepthGridMap(cams, "c0", 1.0, 4.6, 0.03, cache=False)
    states = {c.id: StateMaker(c).make(depths[c.id], rdepths[c.id], opts, pyramids=c.id != "c0") for c in cams}
    own.set_frames(depths, rdepths, robot_capsules=caps, **kw)
    shared.set_frames(depths, rdepths, robot_capsules=caps, states=states, **kw)
    assert shared.pyramids_used == 2 and own.pyramids_used == 0
    for k, c in enumerate(shared.others):        # what the kernels read: the states' own pyramids
        _f, pmin, pmax = shared._views.arrays(k)
        assert pmin is states[c.id].pmin and pmax is states[c.id].pmax
        n = len(pmin)
        lo = shared._koff[k, 1]                   # level 0 is never read
        np.testing.assert_array_equal(own._kpmin[k, lo:n], pmin[lo:])
        np.testing.assert_array_equal(own._kpmax[k, lo:n], pmax[lo:])
        assert own._views.arrays(k)[1].base is own._kpmin
    # level 1 is the 2x2 block minimum of the state's free depth (an independent check of the layout)
    free = states["c1"].free
    h, w = free.shape
    lv1 = states["c1"].pmin[h * w: h * w + (h // 2) * (w // 2)].reshape(h // 2, w // 2)
    np.testing.assert_array_equal(lv1, free.reshape(h // 2, 2, w // 2, 2).min(axis=(1, 3)))


@pytest.mark.slow
def test_bench_share_rows_in_quick_mode():
    """``depthguard bench --only share`` (the build's CPU with the cameras' states beside the build
    working them out) gives finite rows with their peer (no speed asserted: the bench's)."""
    from depthguard.evaluation.bench import BenchContext, run

    rows = {r.name: r for r in run(["share"], BenchContext(quick=True, repeats=3))}
    for cell in ("flacco-cell", "ur3-cell"):
        build = rows[f"share.build_cpu_ms.{cell}"]
        assert np.isfinite(build.value) and build.value > 0 and build.peer_value > 0
        assert rows[f"share.state_cpu_ms.{cell}"].value > 0 and rows[f"share.state_cpu_ms.{cell}"].peer_value > 0
