"""The units' voxels as a monitor input: the server's ``units/*`` queryable and the
``units:ENDPOINT`` source (R20, R27, R29). Zenoh on loopback only.

Truth: the server's own storage (what the node sent), the wire format's rules, and the
pattern node's geometry (a patch at the depth of the workspace centre).
"""

import time

import numpy as np
import pytest

from depthguard.distributed.server import FusionServer
from depthguard.transport import wire
from depthguard.transport.client import ServerClient

from loopback import free_port, wait_until
from small_rigs import write_rig


def _rig(tmp_path):
    return write_rig(tmp_path / "rig.yaml")


@pytest.fixture
def server():
    ep = f"tcp/127.0.0.1:{free_port()}"
    srv = FusionServer(["cam0", "cam1", "cam2", "cam3"], wire.Settings(stale_s=0.5), listen=[ep]).start()
    srv.endpoint = ep
    yield srv
    srv.close()


def _ask(client, key, known=None):
    out = {}
    for r in client.session.get(key, payload=wire.units_request(known), timeout=2.0):
        if r.ok is None:
            out[None] = wire.decode(r.err.payload.to_bytes())
            continue
        m = wire.decode(r.ok.payload.to_bytes(), expect=wire.MsgType.UNITS_REP)
        assert str(r.ok.key_expr) == f"depthguard/units/{m.camera}"
        out[m.camera] = m
    return out


@pytest.mark.multiprocess
@pytest.mark.timeout(60)
def test_units_queryable(server):
    with ServerClient([server.endpoint]) as c:
        c.wait_for_server(5.0)
        assert c.status()["cameras"] == ["cam0", "cam1", "cam2", "cam3"]
        assert _ask(c, "depthguard/units/*") == {}                 # nobody yet
        k0 = np.array([[1, 2, 3], [-4, 5, 6]])
        server.local_update("cam0", k0, np.array([3, 4]), 0.02, 10.5, invalid_frac=0.25)
        server.local_update("cam1", np.array([[7, 7, 7]]), np.array([1]), 0.05, 10.6)
        got = _ask(c, "depthguard/units/*")
        assert set(got) == {"cam0", "cam1"}
        m = got["cam0"]
        assert (m.stamp, m.voxel_size, m.invalid_frac, m.version) == (10.5, 0.02, 0.25, 1)
        np.testing.assert_array_equal(m.keys, k0)
        # one camera asked: only its reply
        assert set(_ask(c, "depthguard/units/cam1")) == {"cam1"}
        # sets the asker holds come back "unchanged", without keys; a new update does not
        known = {"cam0": (m.version, m.stamp), "cam1": (got["cam1"].version, got["cam1"].stamp)}
        again = _ask(c, "depthguard/units/*", known)
        assert all(x.flags & 1 and len(x.keys) == 0 for x in again.values()) and len(again) == 2
        server.local_update("cam0", k0[:1], np.array([3]), 0.02, 10.7)
        again = _ask(c, "depthguard/units/*", known)
        assert not again["cam0"].flags & 1 and again["cam0"].stamp == 10.7 and len(again["cam0"].keys) == 1
        assert again["cam1"].flags & 1
        # a stale unit is not answered (R20: no update within stale_s)
        time.sleep(0.6)
        server.local_update("cam1", np.array([[7, 7, 7]]), np.array([1]), 0.05, 11.2)
        assert set(_ask(c, "depthguard/units/*")) == {"cam1"}
        # a malformed request: an error reply, counted
        r0 = server.rejected
        errs = [r for r in c.session.get("depthguard/units/*", payload=b"junk", timeout=2.0)]
        assert len(errs) == 1 and errs[0].ok is None and server.rejected == r0 + 1
        assert wire.decode(errs[0].err.payload.to_bytes()).type == wire.MsgType.ERROR_REP


@pytest.mark.multiprocess
@pytest.mark.timeout(120)
@pytest.mark.parametrize("link", ["tcp", "tls"])
def test_units_source_pulls_a_unit_from_a_real_server(tmp_path, link):
    """Also with the cell's certificates (R35): server, node and the monitor's source on mutual TLS."""
    from depthguard.distributed.node import build_node
    from depthguard.rig import Rig
    from depthguard.runtime.voxel_input import VoxelObstacles
    from depthguard.sources.base import open_source, source_schemes
    from depthguard.transport.keys import init_authority, issue_admin, issue_node, load_identity

    assert "units" in source_schemes()
    rig_path = _rig(tmp_path)
    rig = Rig.load(rig_path)
    ep = f"{link}/127.0.0.1:{free_port()}"
    ids = {"server": None, "node": None}
    context = {"units_poll_hz": 50.0}
    if link == "tls":
        init_authority(tmp_path / "ca")
        issue_node("cam0", tmp_path / "ca", tmp_path / "cam0")
        issue_admin(tmp_path / "ca", tmp_path / "admin")
        ids = {"server": load_identity(tmp_path / "ca"), "node": load_identity(tmp_path / "cam0")}
        context.update(units_keys=tmp_path / "admin", units_timeout_s=20.0)
    # units stay fresh for 30 s here: the node steps by hand
    server = FusionServer(["cam0", "cam1", "cam2", "cam3"], wire.Settings(stale_s=30.0), listen=[ep],
                          identity=ids["server"]).start()
    server.endpoint = ep
    node = build_node(str(rig_path), "cam0", "pattern", connect=[server.endpoint], identity=ids["node"])
    src = None
    try:
        node.declare_token()
        node.initialize(timeout=10)
        assert wait_until(lambda: server.units["cam0"].alive, 5.0)
        assert node.step() > 0
        src = open_source(f"units:{server.endpoint}", rig, context)
        assert src.camera_ids == ["cam0", "cam1", "cam2", "cam3"]
        assert src.frames_until(1e18) == [] and not src.done and src.lost is None
        u = server.units["cam0"]
        # nothing captured before t is served before t
        assert wait_until(lambda: src.received == 1, 5.0)
        assert src.voxels_until(u.stamp - 1.0) == []
        got = src.voxels_until(u.stamp)
        assert [g[0] for g in got] == ["cam0"]
        cam, centres, s, stamp = got[0]
        assert (s, stamp) == (u.voxel_size, u.stamp)
        np.testing.assert_allclose(centres, (u.keys + 0.5) * u.voxel_size)
        # unchanged sets are not sent again
        polls = src.polls
        assert wait_until(lambda: src.polls >= polls + 5, 5.0)
        assert src.voxels_until(1e18) == [] and src.received == 1
        # the next update arrives whole, with its newer stamp
        node.step()
        assert wait_until(lambda: src.received == 2, 5.0)
        (cam2, centres2, s2, stamp2), = src.voxels_until(1e18)
        assert cam2 == "cam0" and stamp2 == server.units["cam0"].stamp > stamp
        # into the monitor's store: the pattern patch lies at the workspace centre's depth,
        # so the centre is within a voxel diagonal of a voxel box
        vo = VoxelObstacles()
        vo.push(cam2, centres2, s2, stamp2)
        D, V = np.full(1, np.inf), np.zeros((1, 3))
        centre = (rig.workspace.lo + rig.workspace.hi) / 2
        assert vo.nearest(centre[None], 0.5, D, V) == {"cam0": stamp2}
        assert D[0] < s2 * np.sqrt(3)
    finally:
        if src is not None:
            src.close()
            assert src.done
        node.close()
        server.close()


@pytest.mark.multiprocess
@pytest.mark.timeout(30)
def test_units_source_without_server_fails_at_open():
    from depthguard.sources.units import UnitsSource

    t0 = time.monotonic()
    with pytest.raises(ValueError, match="no fusion server answered"):
        UnitsSource(f"tcp/127.0.0.1:{free_port()}", timeout_s=0.5)
    assert time.monotonic() - t0 < 10
    with pytest.raises(ValueError, match="locator"):
        UnitsSource("127.0.0.1:7447")
