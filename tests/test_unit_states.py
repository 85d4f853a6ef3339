"""The state wire format and the monitor's checks of unit states (issue 29 point 3).

Truth: the state the monitor's own :class:`StateMaker` makes of a simulated frame with the robot
rendered (the decode must give back its float64 bits), the plain-numpy twins of the decode
kernels, and the monitor's settings (a state made with other options, role, size, joints or an
older stamp must be refused and counted, never combined).
"""

import numpy as np
import pytest

from depthguard.distributed.unit_state import StateUnit, options_of, state_settings_of
from depthguard.runtime.monitor import Monitor
from depthguard.sim import load_cell
from depthguard.sources import SimSource
from depthguard.transport import state_wire as sw
from depthguard.transport import wire


@pytest.fixture(scope="module")
def made():
    cell = load_cell("ur3-cell")
    rig = cell.rig
    cam = rig.cameras[1]
    t = 0.5
    depth = SimSource(cell, seed=1).frames(t)[cam.id].depth.copy()
    depth[:12] = 0.0                      # a band without returns: free up to min_range (a float64 constant)
    depth[12:16, :200] = 2 * cam.max_range   # returns beyond the rated range: free up to max_range
    q = cell.scene.robot_q(t)
    unit = StateUnit(cam, rig.robot)
    st = unit.make(depth, q, state_settings_of(rig))
    return cell, rig, cam, depth, q, unit, st


def _bits(a):
    return np.ascontiguousarray(a, dtype=np.float64).view(np.uint64)


@pytest.mark.parametrize("codec", [sw.CODEC_F64, sw.CODEC_F32])
def test_decode_is_bit_exact(made, codec):
    cell, rig, cam, depth, q, unit, st = made
    assert np.count_nonzero(st.kind == 1) > 100            # the robot is in view: robot pixels
    msg = sw.encode_state(cam.id, 7, 0.5, q, tuple(st.options), st.robot_free, st.free, st.kind, codec)
    d = sw.decode_state(msg)
    np.testing.assert_array_equal(_bits(d.free), _bits(st.free))
    np.testing.assert_array_equal(d.kind, st.kind)
    assert (d.camera, d.seq, d.stamp, d.robot_free) == (cam.id, 7, 0.5, st.robot_free)
    np.testing.assert_array_equal(d.q, q)
    assert d.options == tuple(st.options) and d.nbytes == len(msg)
    H, W = cam.shape
    assert len(msg) - sw.state_bytes(H, W, codec) < 200                    # the head is small
    if codec == sw.CODEC_F32:                  # float64 values float32 cannot hold went through the table
        f32 = st.free.astype(np.float32).astype(np.float64)
        assert float(np.float32(cam.min_range)) != float(cam.min_range) and np.count_nonzero(f32 != st.free) >= 12 * W


def test_kernels_equal_their_numpy_twins(made):
    *_, st = made
    msg = sw.encode_state("c", 1, 1.0, [], tuple(st.options), False, st.free, st.kind, sw.CODEC_F32)
    n = st.free.size
    bits = np.frombuffer(msg, dtype="<u4", count=n, offset=len(msg) - n - 4 * n).copy()
    bits[:5] = 0x7FC7FF00 | 250                       # sentinels beyond the table: bad
    kind = st.kind.reshape(-1).copy()
    kind[10] = 5
    table = np.sort(np.unique(st.free[st.free.astype(np.float32).astype(np.float64) != st.free]))
    a, b = np.empty(n), np.empty(n)
    assert sw.expand_f32(bits, bits.view("<f4"), table, kind, a) == sw.expand_f32_numpy(bits, bits.view("<f4"),
                                                                                          table, kind, b) == 6
    np.testing.assert_array_equal(_bits(a), _bits(b))
    free = st.free.reshape(-1).copy()
    free[3] = np.nan
    free[4] = -1.0
    assert sw.check_f64(free, kind) == sw.check_f64_numpy(free, kind) == 3


def test_bad_messages_are_refused_with_a_reason(made):
    cell, rig, cam, depth, q, unit, st = made
    msg = bytearray(sw.encode_state(cam.id, 1, 0.5, q, tuple(st.options), False, st.free, st.kind))
    with pytest.raises(sw.StateWireError, match="truncated"):
        sw.decode_state(bytes(msg[:-1]))
    with pytest.raises(sw.StateWireError, match="shorter"):
        sw.decode_state(bytes(msg[:20]))
    bad = bytearray(msg)
    bad[3] = 9
    with pytest.raises(sw.StateWireError, match="version 9"):
        sw.decode_state(bytes(bad))
    bad = bytearray(msg)
    bad[40] ^= 0xFF                                   # in the camera id: the head's CRC
    with pytest.raises(sw.StateWireError, match="CRC"):
        sw.decode_state(bytes(bad))
    bad = bytearray(msg)
    bad[-1] = 7                                       # a kind outside 0-2
    with pytest.raises(sw.StateWireError, match="kind"):
        sw.decode_state(bytes(bad))
    free = st.free.copy()
    free[0, 0] = np.nan
    with pytest.raises(sw.StateWireError, match="free depth"):
        sw.decode_state(sw.encode_state(cam.id, 1, 0.5, q, tuple(st.options), False, free, st.kind, sw.CODEC_F64))


def test_settings_carry_the_state_options(made):
    rig = made[1]
    st = state_settings_of(rig)
    s = wire.Settings(state=st)
    assert wire.decode(wire.init_reply(3, s)).settings.state == st
    assert wire.decode(wire.update_reply(s)).settings.state == st
    assert wire.decode(wire.update_reply(wire.Settings())).settings.state == ()      # none: voxels
    with pytest.raises(wire.WireError, match="invalid"):
        wire.Settings(state=(0.08, "maybe", "unknown", 4, 3, "c")).check()
    opts, free = options_of((0.08, "unknown", "free", 4, 3, "cam_a"), "cam_b")
    assert free and not options_of((0.08, "unknown", "free", 4, 3, "cam_a"), "cam_a")[1]


def test_the_monitor_refuses_states_it_would_not_have_made(made):
    cell, rig, cam, depth, q, unit, st = made
    cfg = rig.monitor.with_changes(state_cameras=(cam.id,))
    msg = sw.encode_state(cam.id, 1, 0.5, q, tuple(st.options), st.robot_free, st.free, st.kind)
    good = sw.decode_state(msg)
    with Monitor(rig, cfg) as m:
        w = m._workers[cam.id]
        m.push_joints(0.49, q)
        cases = {
            "options": good._replace(options=(0.05,) + good.options[1:]),
            "role": good._replace(robot_free=not good.robot_free),
            "shape": good._replace(free=good.free[:10], kind=good.kind[:10]),
            "joints": good._replace(q=q[:-1]),
        }
        for reason, bad in cases.items():
            assert not m.push_state(bad)
            assert w.refusals.get(reason) == 1, (reason, w.refusals, w.last_refusal)
        assert w.product is None                                     # nothing combined
        assert m.push_state(good) and w.product.state.free is good.free
        np.testing.assert_array_equal(w.product.q, q)
        assert not m.push_state(good) and w.refusals["out_of_order"] == 1
        other = rig.cameras[0].id                                   # a camera with frames at the monitor
        assert not m.push_state(good._replace(camera=other)) and m.unit_states_unmonitored == 1


class _Recorded:
    """Items (frames or unit states) recorded beforehand, served by stamp."""

    first_stamp = None

    def __init__(self, items):
        self.items = sorted(items, key=lambda x: x.stamp)

    def _until(self, t):
        out = [x for x in self.items if x.stamp <= t]
        self.items = self.items[len(out):]
        return out

    @property
    def done(self):
        return not self.items


class _Frames(_Recorded):
    def frames_until(self, t):
        return self._until(t)


class _States(_Recorded):
    def frames_until(self, t):
        return []

    def states_until(self, t):
        return self._until(t)


class _JointStates(_Recorded):
    def states_until(self, t):
        return [(x.stamp, x.q) for x in self._until(t)]


@pytest.mark.slow
def test_a_run_fed_unit_states_reacts_as_one_fed_the_frames():
    """The runner hands a source's unit states to the monitor (fast mode): every reaction of a run
    fed the units' states equals that of a run fed the same frames."""
    from collections import namedtuple

    from depthguard.runtime.runner import run

    cell = load_cell("ur3-cell")
    rig = cell.rig
    J = namedtuple("J", "stamp q")
    joints = [J(0.45 + k * 0.002, cell.scene.robot_q(0.45 + k * 0.002)) for k in range(120)]
    frames, states = [], []
    sim = SimSource(cell, seed=2)
    settings = state_settings_of(rig)
    units = {c.id: StateUnit(c, rig.robot) for c in rig.cameras}
    for i, t in enumerate((0.5, 0.5 + 1 / 30, 0.5 + 2 / 30)):
        t = min(joints, key=lambda j: abs(j.stamp - t)).stamp     # on a joint stamp: the joints the monitor uses
        for cid, f in sim.frames(t).items():
            frames.append(f)
            states.append(sw.decode_state(units[cid].encode(f.depth, t, cell.scene.robot_q(t), i, settings)))
    got = {}
    for name, src, cfg in (("frames", _Frames(frames), rig.monitor),
                           ("states", _States(states), rig.monitor.with_changes(state_cameras=tuple(rig.camera_ids)))):
        out = got[name] = []
        with Monitor(rig, cfg) as m:
            run(m, [src], _JointStates(joints), fast=True, on_reaction=lambda r: out.append(r))
            assert m.stats()["fusion_errors"] == 0
            assert all(c["frames"] == 3 and not c["refused"] for c in m.stats()["cameras"].values())
    assert len(got["frames"]) == len(got["states"]) > 50
    for a, b in zip(got["frames"], got["states"]):
        assert a.t == b.t and a.frame_stamps == b.frame_stamps
        np.testing.assert_array_equal(a.distance, b.distance)
        np.testing.assert_array_equal(a.observed, b.observed)
    assert any(np.isfinite(r.distance).any() for r in got["frames"])


@pytest.mark.slow
def test_bench_units_rows_in_quick_mode():
    """``depthguard bench --only units`` gives its rows, finite, the combine beside its peer (no speed
    asserted: the bench's), and the bytes of a 640x480 message as the format says."""
    from depthguard.evaluation.bench import BenchContext, run

    rows = {r.name: r for r in run(["units"], BenchContext(quick=True))}
    assert {"units.unit_ms", "units.combine_ms", "units.combine_cpu_ms", "units.combine_f64_ms",
            "units.bytes_per_frame", "units.net_mb_s_per_camera"} <= set(rows)
    assert all(np.isfinite(r.value) and r.value > 0 for r in rows.values())
    assert rows["units.combine_ms"].peer_value > 0
    assert sw.state_bytes(480, 640) < rows["units.bytes_per_frame"].value < sw.state_bytes(480, 640) + 200
