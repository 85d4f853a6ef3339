"""Camera units that make their camera's share of the depth grid; the monitor only combines
(issue 29 point 3). Four units (``CameraNode(states=True)``, each its own Zenoh session) on
loopback, the fusion server, the ``units:`` source: the distances of a ``Monitor`` fed the
units' states equal, cycle by cycle and bit for bit, those of a ``Monitor`` fed the same frames
and joints itself (the centralised fusion) — the independent truth is the monitor's own
pipeline, which renders the robot and makes each state on its camera workers.
"""

import math

import numpy as np
import pytest

from depthguard.distributed.node import CameraNode
from depthguard.distributed.server import FusionServer
from depthguard.distributed.state_relay import StateRelay
from depthguard.distributed.unit_state import state_settings_of
from depthguard.runtime.monitor import Monitor
from depthguard.sim import load_cell
from depthguard.sources import Frame, SimSource
from depthguard.sources.units import UnitsSource
from depthguard.transport import wire

from loopback import free_port, wait_until


class _Joints:
    """A joint stream (``states_until``): the states the test hands to a unit, as the monitor's."""

    def __init__(self):
        self.queue = []

    def states_until(self, t):
        out, self.queue = self.queue, []
        return out

    def close(self):
        pass


K = 4                # cycles compared


def _bad_messages(node, ids, units, relay, monitor, frames, t, q):
    """Bad network messages: refused and counted by the source (truncated, another version, another
    camera than the key's, a camera not in the rig), or by the monitor (other options), never combined."""
    from depthguard.transport import state_wire as sw

    a, b = ids[0], ids[1]
    good = node.state_unit.encode(frames[a].depth, t + 1.0, q, 99, node.settings.state)
    other_opts = node.state_unit.encode(frames[a].depth, t + 1.0, q, 99,
                                        (0.01,) + tuple(node.settings.state[1:]))
    made = node.state_unit.make(frames[a].depth, q, node.settings.state)
    naming_b = sw.encode_state(b, 99, t + 1.0, q, tuple(made.options), False, made.free, made.kind)
    ghost = sw.encode_state("ghost", 99, t + 1.0, q, tuple(made.options), False, made.free, made.kind)
    old = bytearray(good)
    old[3] = 0
    s, keys = node.client.session, node.keys

    def put(key, msg, reason):
        n = units.states_refused.get(reason, 0)
        s.put(key, msg)
        assert wait_until(lambda: units.states_refused.get(reason, 0) == n + 1, 10.0), units.states_refused

    put(keys.states(a), good[:-100], "malformed")             # truncated
    put(keys.states(a), bytes(old), "malformed")              # another wire version
    put(keys.states(a), naming_b, "wrong_camera")             # not the key's camera
    put(keys.state_relay("ghost"), ghost, "wrong_camera")     # not in the rig (straight to the source)
    s.put(keys.states("ghost"), ghost)                        # ... which the server does not pass on
    assert wait_until(lambda: relay.refused == 1, 10.0)
    assert units.states_refused == {"malformed": 2, "wrong_camera": 2}, units.states_last_refusal
    assert units.states_until(float("inf")) == []                    # nothing of them reaches the monitor
    s.put(keys.states(a), other_opts)
    got = wait_until(lambda: units.states_until(float("inf")), 10.0)
    assert len(got) == 1 and not monitor.push_state(got[0])
    w = monitor._workers[a]
    assert w.refusals == {"options": 1} and "options" in w.last_refusal


@pytest.mark.multiprocess
@pytest.mark.slow
@pytest.mark.timeout(360)
def test_four_units_equal_the_centralised_fusion():
    cell = load_cell("ur3-cell")
    rig = cell.rig
    ids = list(rig.camera_ids)
    assert len(ids) == 4
    cfg = rig.monitor
    cfg_units = cfg.with_changes(state_cameras=tuple(ids))
    ep = f"tcp/127.0.0.1:{free_port()}"
    server = FusionServer(ids, wire.Settings(stale_s=5.0, state=state_settings_of(rig)), listen=[ep]).start()
    relay = StateRelay(server).start()                    # the server passes the states on
    current, joints, nodes = {}, {}, {}
    units = central = distributed = None
    try:
        ws = (rig.workspace.lo, rig.workspace.hi)
        for cam in rig.cameras:
            joints[cam.id] = _Joints()
            nodes[cam.id] = CameraNode(cam, ws, (lambda cid=cam.id: current[cid]), robot=rig.robot, connect=[ep],
                                       states=True, joint_source=joints[cam.id], joint_span_s=cfg.joint_history_s,
                                       joint_gap_s=cfg.joints_stale_s, joint_wait_s=0.0)
            nodes[cam.id].declare_token()
            nodes[cam.id].initialize(timeout=10.0)
            assert nodes[cam.id].settings.state == state_settings_of(rig)     # the options reached the unit
        units = UnitsSource(ep, rig)
        central = Monitor(rig)
        distributed = Monitor(rig, cfg_units)
        sim = SimSource(cell, seed=3)
        t0 = float(cell.situations[next(iter(cell.situations))].time) if cell.situations else 0.0
        tj = t0 - 0.1
        compared = 0
        for k in range(K):
            t = t0 + k / 15.0
            while tj <= t + 0.004:                          # joints at 500 Hz past the frame
                q = cell.scene.robot_q(tj)
                assert central.push_joints(tj, q) and distributed.push_joints(tj, q)
                for j in joints.values():
                    j.queue.append((tj, q))
                tj += 0.002
            frames = sim.frames(t)
            for cid in ids:
                central.push_frame(frames[cid])
                current[cid] = (frames[cid].depth, t)
                assert nodes[cid].step() is not None, nodes[cid].skipped
            got = {}

            def all_states():
                for st in units.states_until(math.inf):
                    got[st.camera] = st
                return len(got) == len(ids)
            assert wait_until(all_states, 10.0), (sorted(got), units.states_refused, units.states_last_refusal)
            for st in got.values():
                assert st.stamp == t
                assert distributed.push_state(st), distributed.stats()["cameras"][st.camera]
            central.flush(240.0)           # the first: numba's compile in a fresh checkout (minutes under load)
            distributed.flush(60.0)
            for dt in (0.0, 0.01):
                tq = t + 0.004 + dt
                rc, ru = central.step(tq), distributed.step(tq)
                assert set(rc.frame_stamps) == set(ids) and rc.frame_stamps == ru.frame_stamps
                np.testing.assert_array_equal(ru.distance, rc.distance)      # bit for bit, inf included
                np.testing.assert_array_equal(ru.direction, rc.direction)
                np.testing.assert_array_equal(ru.observed, rc.observed)
                compared += int(np.isfinite(rc.distance).sum())
        assert compared > 0, "no finite distance compared: the scene must put something within rho"
        assert units.states_refused == {}
        st = distributed.stats()
        assert all(c["refused"] == {} and c["frames"] == K for c in st["cameras"].values())
        assert st["fusion_errors"] == 0 and central.stats()["fusion_errors"] == 0
        _bad_messages(nodes[ids[0]], ids, units, relay, distributed, frames, t, q)
    finally:
        for m in (central, distributed):
            if m is not None:
                m.close()
        if units is not None:
            units.close()
        for n in nodes.values():
            n.close()
        relay.close()
        server.close()


@pytest.mark.multiprocess
@pytest.mark.timeout(60)
def test_a_unit_sends_no_state_without_the_monitors_options(tmp_path):
    """A server whose settings carry no state options (not started with the monitor's rig): the unit
    sends nothing, and says why once (counted in ``skipped["no_options"]``)."""
    from depthguard.distributed.node import build_node
    from small_rigs import write_rig

    rig_path = write_rig(tmp_path / "rig.yaml")
    ep = f"tcp/127.0.0.1:{free_port()}"
    server = FusionServer(["cam0", "cam1"], wire.Settings(stale_s=5.0), listen=[ep]).start()
    said = []
    node = build_node(str(rig_path), "cam0", "pattern", connect=[ep], states=True, log=said.append)
    try:
        node.initialize(timeout=10.0)
        assert node.settings.state == ()
        assert node.step() is None and node.step() is None
        assert node.skipped == {"no_options": 2} and node.sent_bytes == 0
        assert sum("no state options" in m for m in said) == 1
    finally:
        node.close()
        server.close()
