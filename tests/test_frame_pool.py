"""The camera worker's buffer pool (issue 29): a frame's arrays are reused only once nothing refers
to them, so a depth grid that reads a principal's state in place, and a reader holding a product,
never see it overwritten; the worker's products are those of fresh arrays, bit for bit.

Truth: a second depth grid loaded with private copies of the same frames (it works the states
out itself, shares no array with the worker), the state made into new arrays by
:class:`~depthguard.fusion.depth_grid_state.StateMaker`, the robot rendered by a second
:class:`~depthguard.filtering.expected.ExpectedDepth`. A pool that ignores the references (the
test patches it so) fails the same checks: they are not vacuous.
"""

from __future__ import annotations

import hashlib
from typing import NamedTuple

import numpy as np
import pytest

from depthguard.frame_pool import BufferPool

LAYOUT = (((6, 5), np.float32), ((3, 3), np.float64), ((3, 3), np.int8))


def _addr(a) -> int:
    return a.__array_interface__["data"][0]


class _Holder(NamedTuple):
    free: np.ndarray


def test_a_set_is_given_out_again_only_when_nothing_refers_to_any_of_its_arrays():
    pool = BufferPool(cap=3)
    first = pool.take(LAYOUT)
    assert [a.shape for a in first] == [(6, 5), (3, 3), (3, 3)]
    assert [a.dtype for a in first] == [np.float32, np.float64, np.int8]
    home = [_addr(a) for a in first]
    # each way a reader may hold one array of the set keeps the whole set out of the pool
    holders = {"the array": lambda s: s[1], "a view": lambda s: s[0][2:, 1:], "a tuple": lambda s: _Holder(s[2]),
               "a memoryview": lambda s: memoryview(s[1])}
    for how, hold in holders.items():
        held = hold(first)
        del first
        other = pool.take(LAYOUT)
        assert not set(home) & {_addr(a) for a in other}, how
        del other
        del held                                   # released: the same memory comes back (recycled)
        first = pool.take(LAYOUT)
        assert [_addr(a) for a in first] == home, how
    assert pool.made == 2 and pool.kept == 2 and pool.reused == 7


def test_beyond_its_cap_the_pool_makes_sets_it_does_not_keep_and_a_new_layout_drops_the_kept():
    pool = BufferPool(cap=2)
    held = [pool.take(LAYOUT) for _ in range(4)]
    addrs = {_addr(s[0]) for s in held}
    assert len(addrs) == 4 and pool.made == 4 and pool.overflow == 2 and pool.kept == 2
    del held
    again = pool.take(LAYOUT)
    assert pool.made == 4 and pool.reused == 1
    del again
    pool.take((((7, 5), np.float32),))
    assert pool.kept == 1 and pool.made == 5
    with pytest.raises(ValueError, match="at least one set"):
        BufferPool(cap=0)


# ---------------------------------------------------------------------------- the worker and the grid
def _digest(*arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def _level1(cam) -> int:
    """Where level 1 starts in a camera's flat pyramids."""
    from depthguard.fusion.depth_grid_state import pyramid_layout, pyramid_levels

    return int(pyramid_layout(cam.height, cam.width, pyramid_levels(cam.height, cam.width))[0][1])


def _state_arrays(p) -> list:
    """A product's arrays: its depth, robot depth and state (with the pyramids where it has them)."""
    st = p.state
    return [p.depth, p.robot_depth, st.free, st.kind] + ([st.pmin, st.pmax] if st.pmin is not None else [])


@pytest.fixture(scope="module")
def cell_frames():
    """flacco-cell: noisy frames of both cameras along the robot's path (the monitor's settings)."""
    from depthguard.sim.cells import load_cell
    from depthguard.sources.sim_source import SimFrames, SimWorld

    cell = load_cell("flacco-cell")
    sim = SimFrames(SimWorld("flacco-cell", seed=0))
    frames = []
    for k in range(12):
        t = 8.5 + k / 15.0                              # the arm moves: every frame's state differs
        q = np.asarray(cell.scene.robot_q(t), dtype=np.float64)
        frames.append((t, q, {c.id: sim.render(c.id, t, q).copy() for c in cell.rig.cameras}))
    return cell, frames


class _Driver:
    """The monitor's camera workers and fusion build driven on the test's thread, frame by frame."""

    def __init__(self, cell):
        from depthguard.runtime.monitor import Monitor

        self.rig = cell.rig
        self.scene = cell.scene
        self.mon = Monitor(self.rig, self.rig.monitor)
        self.mon.fusion.close()            # builds happen when the test says (FusionWorker._build)
        self.jt = None
        self.kept = {}                     # (camera, version) -> private copies (depth, robot depth)
        self._truth = {}

    def frame(self, t, q, depths, cids):
        from depthguard.sources.frame import Frame

        if self.jt is None:
            self.jt = t - 0.5
        while self.jt <= t + 0.004:
            self.mon.push_joints(self.jt, np.asarray(self.scene.robot_q(self.jt), dtype=np.float64))
            self.jt += 0.002
        for cid in cids:
            w = self.mon._workers[cid]
            w._process(Frame(cid, depths[cid].copy(), t), 0.0)
            p = w.product
            assert p is not None and p.stamp == t, w.last_refusal
            self.kept[cid, p.version] = (p.depth.copy(), p.robot_depth.copy())

    def truth(self, buf):
        """A grid over ``buf``'s cameras loaded with private copies of the frames ``buf`` holds."""
        from depthguard.robot.volume import robot_volume

        cfg = self.mon.config
        if buf.camera_ids not in self._truth:
            self._truth[buf.camera_ids] = self.mon._make_grid(buf.camera_ids)
        grid = self._truth[buf.camera_ids]         # loaded whole each time (changed=None)
        frames = {c: self.kept[c, buf.versions[c]] for c in buf.camera_ids}
        caps = robot_volume(self.rig.robot, [buf.q_caps[c] for c in buf.camera_ids], cfg.robot_padding)
        grid.set_frames({c: f[0] for c, f in frames.items()}, {c: f[1] for c, f in frames.items()},
                        robot_offset=cfg.robot_offset, robot_capsules=caps, invalid=cfg.invalid,
                        robot_in_others=cfg.robot_in_others, silhouette_px=cfg.silhouette_px, gap_px=cfg.gap_px)
        return grid

    def same_answers(self, buf, points) -> bool:
        cfg = self.mon.config
        want = self.truth(buf).query(points, rho=cfg.query_rho, method=cfg.method)
        got = buf.grid.query(points, rho=cfg.query_rho, method=cfg.method)
        return bool(np.array_equal(got.distance, want.distance) and np.array_equal(got.direction, want.direction)
                    and np.array_equal(got.observed, want.observed))


def _scenario(cell, frames) -> list[bool]:
    """Two grids (front, back) each holding a principal state in place while the worker makes
    more frames; per check: does the grid still answer as its frames' private copies do."""
    d = _Driver(cell)
    try:
        fusion = d.mon.fusion
        p, o = d.mon.camera_ids[:2]
        rng = np.random.default_rng(0)
        ws = d.rig.workspace
        points = rng.uniform(ws.lo, ws.hi, (60, 3))
        checks = []
        d.frame(*frames[0], (p, o))
        assert fusion._build()
        a = fusion.front
        for k in (1, 2, 3):                         # the principal's frames come, no build
            d.frame(*frames[k], (p,))
        checks.append(d.same_answers(a, points))
        assert fusion._build()                      # into the other grid: a stays the back one
        b = fusion.front
        assert b is not a and fusion._back is a
        for k in (4, 5, 6, 7):
            d.frame(*frames[k], (p, o))
        checks.append(d.same_answers(a, points))
        checks.append(d.same_answers(b, points))
        assert fusion._build() and fusion.front is a
        for k in (8, 9, 10, 11):
            d.frame(*frames[k], (p,))
        checks.append(d.same_answers(a, points))
        checks.append(d.same_answers(b, points))
        pool = d.mon._workers[p].pool
        checks.append(pool.reused > 0 and pool.made <= pool.cap)
        return checks
    finally:
        d.mon.close()


def test_no_frame_buffer_is_overwritten_while_a_grid_reads_it(cell_frames, monkeypatch):
    """The front and back grids keep reading their principal's state in place (no copy) while
    the principal's worker makes 4 more frames each time; both grids answer exactly as grids
    loaded with private copies of their frames, and the pool recycled sets all the while. The
    same run with a pool that ignores references answers otherwise (the check can fail)."""
    cell, frames = cell_frames
    assert all(_scenario(cell, frames))
    monkeypatch.setattr(BufferPool, "_unheld", staticmethod(lambda arrays: True))
    assert not all(_scenario(cell, frames)[:-1])


def test_the_workers_products_are_those_of_new_arrays_and_held_products_keep_their_content(cell_frames):
    """Each product's robot depth is the robot rendered at its capture joints (a second renderer),
    its state that of StateMaker into new arrays, bit for bit; the frame's float32 depth is held
    as it came (no copy), a float64 one converted as numpy converts it; products a
    reader holds keep their content while the worker makes more."""
    from depthguard.filtering.expected import ExpectedDepth
    from depthguard.fusion.depth_grid_state import StateMaker
    from depthguard.sources.frame import Frame

    cell, frames = cell_frames
    d = _Driver(cell)
    try:
        held = []
        expected = {c.id: ExpectedDepth(c, cell.rig.robot, cell.rig.static_meshes()) for c in cell.rig.cameras}
        makers = {c.id: StateMaker(c) for c in cell.rig.cameras}
        d.jt = frames[0][0] - 0.5
        for k, (t, q, depths) in enumerate(frames):
            while d.jt <= t + 0.004:
                d.mon.push_joints(d.jt, np.asarray(cell.scene.robot_q(d.jt), dtype=np.float64))
                d.jt += 0.002
            for cid in d.mon.camera_ids:
                w = d.mon._workers[cid]
                src = depths[cid].copy() if k % 3 else depths[cid].astype(np.float64)
                w._process(Frame(cid, src, t), 0.0)
                p = w.product
                assert p.stamp == t, w.last_refusal
                if src.dtype == np.float32:
                    assert p.depth is src
                else:
                    np.testing.assert_array_equal(p.depth, np.array(src, dtype=np.float32))
                rd = np.array(expected[cid].robot(p.q), copy=True)
                np.testing.assert_array_equal(p.robot_depth, rd)
                st = makers[cid].make(np.array(src, dtype=np.float32), rd, *w.state_options())
                np.testing.assert_array_equal(p.state.free, st.free)
                np.testing.assert_array_equal(p.state.kind, st.kind)
                # another camera's min / max pyramids come with its state (the build copies them)
                assert (p.state.pmin is not None) == (cid != d.mon.camera_ids[0])
                if st.pmin is not None:                # level 0 is never written nor read
                    o = _level1(w.camera)
                    np.testing.assert_array_equal(p.state.pmin[o:], st.pmin[o:])
                    np.testing.assert_array_equal(p.state.pmax[o:], st.pmax[o:])
                if k % 2 == 0:
                    held.append((p, _digest(*_state_arrays(p))))
        for p, digest in held:
            assert _digest(*_state_arrays(p)) == digest
        assert all(w.pool.reused > 0 for w in d.mon._workers.values())
    finally:
        d.mon.close()


MIXED_RIG = """\
version: 1
name: mixed-resolutions
workspace: {min: [-1.0, -1.0, 0.0], max: [1.0, 1.0, 1.5]}
cameras:
  - {id: a, sensor: realsense_d435, width: 640, height: 480, pose: {look_at: {eye: [1.1, -0.9, 1.7], target: [0.0, 0.0, 0.85], up: [0, 0, 1]}}}
  - {id: b, sensor: realsense_d435, width: 640, height: 480, pose: {look_at: {eye: [1.1, 0.9, 1.7], target: [0.0, 0.0, 0.85], up: [0, 0, 1]}}}
  - {id: c, sensor: realsense_d435, width: 424, height: 240, pose: {look_at: {eye: [-1.1, 0.9, 1.7], target: [0.0, 0.0, 0.85], up: [0, 0, 1]}}}
robot:
  name: ur3
  base: {translation: [0.0, 0.0, 0.8]}
  joints: [0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0]
objects:
  - {name: table_top, box: {size: [1.2, 0.8, 0.04]}, pose: {translation: [0.0, 0.0, 0.78]}}
"""


def test_a_camera_whose_pyramids_the_grid_cannot_use_is_not_asked_for_them(tmp_path):
    """Mixed resolutions: the grid's pyramid levels come from its largest other camera (640x480:
    11), so a 424x240 camera's own (10) would go unread; its worker makes none and the build makes
    them, while the 640x480 one's are copied in. The answers equal a grid loaded with private
    copies of the same frames (which works everything out itself)."""
    from depthguard.rig import Rig
    from depthguard.sim.cells import cell_from_rig
    from depthguard.sources.sim_source import SimFrames, SimWorld

    path = tmp_path / "mixed.yaml"
    path.write_text(MIXED_RIG)
    rig = Rig.load(path)
    cell = cell_from_rig(rig)
    sim = SimFrames(SimWorld("", rig=rig, seed=0))
    d = _Driver(cell)
    try:
        assert [d.mon._workers[c].state_options()[2] for c in ("a", "b", "c")] == [False, True, False]
        q = np.asarray(rig.robot_q0, dtype=np.float64)
        d.scene = type("Still", (), {"robot_q": staticmethod(lambda t: q)})()
        depths = {c.id: np.array(sim.render(c.id, 1.0, q), dtype=np.float32) for c in rig.cameras}
        d.frame(1.0, q, depths, ("a", "b", "c"))
        assert d.mon.fusion._build()
        buf = d.mon.fusion.front
        assert buf.grid.pyramids_used == 1
        points = np.random.default_rng(1).uniform(rig.workspace.lo, rig.workspace.hi, (60, 3))
        assert d.same_answers(buf, points)
    finally:
        d.mon.close()
