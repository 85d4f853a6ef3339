"""Distributed camera subsystem over zenoh on loopback (R20, R27).

In-process: the protocol (ids, refusal, rejection counting, settings, staleness,
liveliness). Multi-process: four node processes; one SIGKILLed, one SIGSTOPped;
restart; a voxel-size change; fuzzed messages against the running server.
Truth: the server's own storage before the failure (which voxels were exclusively
whose), wall-clock deadlines, and the protocol's stated rules.
"""

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from depthguard.distributed.server import ERR_REFUSED, FusionServer
from depthguard.transport import wire
from depthguard.transport.client import ServerClient, ServerRefused
from small_rigs import write_rig
from loopback import free_port, wait_until






@pytest.fixture
def server():
    port = free_port()
    logs = []
    srv = FusionServer(["cam0", "cam1", "cam2", "cam3"], wire.Settings(stale_s=0.5),
                       listen=[f"tcp/127.0.0.1:{port}"], log=logs.append).start()
    srv.logs = logs
    srv.endpoint = f"tcp/127.0.0.1:{port}"
    yield srv
    srv.close()


@pytest.fixture
def client(server):
    c = ServerClient([server.endpoint])
    c.wait_for_server(5.0)
    yield c
    c.close()


def _update(client, uid, keys, seq=1, s=0.02):
    keys = np.asarray(keys)
    return client.request("depthguard/update", wire.update_request(uid, seq, time.time(), s, keys,
                                                                  np.full(len(keys), 9)))


def test_protocol_in_process(server, client):
    uid = client.request("depthguard/init", wire.init_request("cam0", "a")).unit_id
    uid1 = client.request("depthguard/init", wire.init_request("cam1", "b")).unit_id
    assert uid != uid1
    # seen before → same id, no new storage
    assert client.request("depthguard/init", wire.init_request("cam0", "a2")).unit_id == uid
    assert len(server.units) == 2 and server.units["cam0"].inits == 2
    # unknown camera refused, logged, counted
    with pytest.raises(ServerRefused) as e:
        client.request("depthguard/init", wire.init_request("intruder", "evil"))
    assert e.value.code == ERR_REFUSED and server.refused == 1
    assert any("intruder" in m for m in server.logs)
    # no liveliness token yet → the unit is "left" and the reply asks for the token
    rep = _update(client, uid, [[1, 2, 3]])
    assert rep.flags & 1
    assert server.status()["nodes"][0]["state"] == "left"
    tok = client.session.liveliness().declare_token("depthguard/alive/cam0")
    assert wait_until(lambda: server.units["cam0"].alive, 2.0)
    rep = _update(client, uid, [[1, 2, 3], [4, 5, 6]], seq=2)
    assert not rep.flags & 1
    keys, s = server.global_map()
    np.testing.assert_array_equal(keys, [[1, 2, 3], [4, 5, 6]])
    # settings change reaches the next reply
    server.set_settings(voxel_size=0.05, joints=[0.1, 0.2])
    rep = _update(client, uid, [[1, 2, 3]], seq=3)
    assert rep.settings.voxel_size == 0.05 and rep.settings.joints == (0.1, 0.2)
    # voxels sent at the old size are re-gridded conservatively into the new one
    keys, s = server.global_map()
    # voxel (1, 2, 3) at 2 cm = [0.02, 0.04) x [0.04, 0.06) x [0.06, 0.08): y straddles 0.05
    assert s == 0.05
    np.testing.assert_array_equal(keys, [[0, 0, 1], [0, 1, 1]])
    # stale after stale_s without updates (R20), and left out of the map
    time.sleep(0.6)
    st_ = client.status()
    assert st_["nodes"][0]["state"] == "stale" and st_["voxels_total"] == 0
    # token gone → left
    tok.undeclare()
    assert wait_until(lambda: server.status()["nodes"][0]["state"] == "left", 2.0)
    # malformed / unexpected messages rejected and counted, the server answers on
    r0 = server.rejected
    for bad in (b"", b"garbage", wire.status_request()):
        with pytest.raises(ServerRefused):
            client.request("depthguard/update", bad)
    with pytest.raises(ServerRefused):
        client.set_settings(voxel_size=3.0)
    assert server.rejected == r0 + 4
    with pytest.raises(ServerRefused, match="not initialised"):
        _update(client, 999, [[0, 0, 0]])
    assert set(client.status()) >= {"nodes", "voxels_total", "bytes_per_s"}
    # centralised mode: voxels computed in the server's process enter the same map
    server.local_update("cam3", np.array([[7, 7, 7]]), np.array([5]), 0.05, time.time())
    keys, _ = server.global_map()
    assert [7, 7, 7] in keys.tolist()
    with pytest.raises(ValueError, match="not in the rig"):
        server.local_update("intruder", np.zeros((0, 3)), np.zeros(0), 0.05, 0.0)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(key=st.sampled_from(["init", "update", "status", "settings"]), data=st.binary(max_size=300))
def test_fuzzed_messages_crash_nothing(server, client, key, data):
    r0 = server.rejected + server.refused
    try:
        client.request(f"depthguard/{key}", data, timeout=2.0)
    except ServerRefused:
        assert server.rejected + server.refused == r0 + 1
    except wire.WireError:
        pytest.fail("the server replied with something undecodable")
    assert "nodes" in client.status()


# ------------------------------------------------------------------ multi-process
def _rig(tmp_path):
    return write_rig(tmp_path / "rig.yaml")


def _spawn(rig, cam, endpoint, fps=20, keys=None):
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    extra = [] if keys is None else ["--keys", str(keys / cam)]
    return subprocess.Popen([sys.executable, "-m", "depthguard.distributed.node", "--rig", str(rig),
                             "--camera", cam, "--connect", endpoint, "--fps", str(fps), "--quiet", *extra],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)


@pytest.fixture(scope="module")
def pki(tmp_path_factory):
    """The cell's authority, a certificate per camera node and an administrator's (R35)."""
    from depthguard.transport.keys import init_authority, issue_admin, issue_node

    d = tmp_path_factory.mktemp("pki")
    init_authority(d / "ca")
    for i in range(4):
        issue_node(f"cam{i}", d / "ca", d / f"cam{i}")
    issue_admin(d / "ca", d / "admin")
    return d


@pytest.fixture(params=["tcp", "tls"])
def any_server(request, pki):
    """``(server, admin client, key dir or None)``: plain loopback, and mutual TLS + signed messages."""
    from depthguard.transport.keys import load_identity

    port = free_port()
    tls = request.param == "tls"
    ep = f"{request.param}/127.0.0.1:{port}"
    srv = FusionServer(["cam0", "cam1", "cam2", "cam3"], wire.Settings(stale_s=0.5), listen=[ep],
                       identity=load_identity(pki / "ca") if tls else None).start()
    srv.endpoint = ep
    c = ServerClient([ep], identity=load_identity(pki / "admin") if tls else None)
    c.wait_for_server(5.0)
    yield srv, c, (pki if tls else None)
    c.close()
    srv.close()


@pytest.mark.multiprocess
@pytest.mark.slow
@pytest.mark.timeout(120)
def test_four_nodes_kill_freeze_restart_settings(tmp_path, any_server):
    server, client, keys = any_server
    rig = _rig(tmp_path)
    procs = {}
    try:
        for i in range(4):
            procs[f"cam{i}"] = _spawn(rig, f"cam{i}", server.endpoint, keys=keys)

        def all_fresh():
            st_ = server.status()
            return len(st_["nodes"]) == 4 and all(n["state"] == "fresh" and n["voxels"] > 0 for n in st_["nodes"])
        assert wait_until(all_fresh, 60.0), (server.status(), [p.poll() for p in procs.values()])
        ids = {u.camera: u.id for u in server.units.values()}
        # each node reports its share of invalid pixels (pattern: a 48x36 patch of 160x120 valid)
        for n in server.status()["nodes"]:
            assert abs(n["invalid_frac"] - (1 - 48 * 36 / (160 * 120))) < 1e-3
        own = {c: set(map(tuple, u.keys.tolist())) for c, u in server.units.items()}
        excl = {c: own[c] - set().union(*(own[o] for o in own if o != c)) for c in own}
        assert all(len(e) > 0 for e in excl.values())
        # SIGKILL cam1, SIGSTOP cam2
        t0 = time.monotonic()
        procs["cam1"].send_signal(signal.SIGKILL)
        procs["cam2"].send_signal(signal.SIGSTOP)

        def dropped():
            st_ = {n["camera"]: n for n in server.status()["nodes"]}
            if st_["cam1"]["state"] == "fresh" or st_["cam2"]["state"] == "fresh":
                return False
            keys = set(map(tuple, server.global_map()[0].tolist()))
            return not (keys & (excl["cam1"] | excl["cam2"])) and excl["cam0"] <= keys and excl["cam3"] <= keys
        assert wait_until(dropped, 1.5, step=0.01), server.status()
        t_drop = time.monotonic() - t0
        assert t_drop <= 1.5
        # the killed one is reported left at once (its session closed); the frozen one after the lease
        assert wait_until(lambda: {n["camera"]: n["state"] for n in server.status()["nodes"]}["cam1"] == "left", 0.5)
        t_killed_left = time.monotonic() - t0
        assert wait_until(lambda: {n["camera"]: n["state"] for n in server.status()["nodes"]}["cam2"] == "left",
                          1.6 - (time.monotonic() - t0) + 0.5)
        t_frozen_left = time.monotonic() - t0
        print(f"voxels dropped after {t_drop:.3f} s; killed 'left' after {t_killed_left:.3f} s; "
              f"frozen 'left' after {t_frozen_left:.3f} s")
        # restart the killed one: old id back, no new storage
        procs["cam1"].wait(5)
        procs["cam1"] = _spawn(rig, "cam1", server.endpoint, keys=keys)
        assert wait_until(lambda: server.units["cam1"].inits == 2
                          and server.unit_state(server.units["cam1"]) == "fresh", 60.0)
        assert server.units["cam1"].id == ids["cam1"] and len(server.units) == 4
        # a voxel-size change reaches every running node
        client.set_settings(voxel_size=0.05)

        def all_at_new_size():
            return all(server.units[c].voxel_size == 0.05 and server.unit_state(server.units[c]) == "fresh"
                       for c in ("cam0", "cam1", "cam3"))
        assert wait_until(all_at_new_size, 5.0), server.status()
        # the frozen one resumes, re-joins and picks up the new size too
        procs["cam2"].send_signal(signal.SIGCONT)
        assert wait_until(lambda: server.units["cam2"].voxel_size == 0.05
                          and server.unit_state(server.units["cam2"]) == "fresh", 10.0), server.status()
        assert server.units["cam2"].id == ids["cam2"]
    finally:
        for p in procs.values():
            if p.poll() is None:
                try:
                    p.send_signal(signal.SIGCONT)
                except ProcessLookupError:
                    pass
                p.kill()
            p.wait(10)


def _cli(*args):
    return [sys.executable, "-m", "depthguard.cli", *args]


@pytest.mark.multiprocess
@pytest.mark.slow
@pytest.mark.timeout(120)
def test_cli_server_node_status(tmp_path):
    """`depthguard server`, `depthguard node`, `depthguard status --json` as a user runs them;
    a node whose camera is not in the server's rig is refused (exit 2, one error line)."""
    import json

    rig = _rig(tmp_path)
    bad_rig = tmp_path / "intruder.yaml"
    bad_rig.write_text(rig.read_text().replace("id: cam3", "id: intruder"))
    ep = f"tcp/127.0.0.1:{free_port()}"
    procs = []
    try:
        srv = subprocess.Popen(_cli("server", "--rig", str(rig), "--listen", ep, "--every", "0", "--duration", "60"),
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        procs.append(srv)
        node = subprocess.Popen(_cli("node", "--rig", str(rig), "--camera", "cam0", "--source", "pattern",
                                     "--connect", ep, "--fps", "20"),
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        procs.append(node)

        def fresh():
            r = subprocess.run(_cli("status", "--connect", ep, "--json", "--timeout", "1"),
                               capture_output=True, text=True, timeout=30)
            if r.returncode != 0:
                return None
            st = json.loads(r.stdout)
            return st if st["nodes"] and st["nodes"][0]["state"] == "fresh" else None
        st = wait_until(fresh, 60.0, step=0.5)
        assert st, "node never became fresh"
        n = st["nodes"][0]
        assert (n["camera"], n["id"]) == ("cam0", 1) and n["voxels"] > 0 and n["age_s"] < 0.5
        assert st["voxels_total"] == n["voxels"] and st["bytes_per_s"] > 0
        intr = subprocess.run(_cli("node", "--rig", str(bad_rig), "--camera", "intruder", "--source", "pattern",
                                   "--connect", ep), capture_output=True, text=True, timeout=60)
        assert intr.returncode == 2
        assert "not in the rig" in intr.stderr and len(intr.stderr.strip().splitlines()) == 1
        r = subprocess.run(_cli("status", "--connect", ep, "--json"), capture_output=True, text=True, timeout=30)
        assert json.loads(r.stdout)["refused"] == 1
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
            p.wait(10)
    r = subprocess.run(_cli("status", "--connect", ep, "--timeout", "0.3"), capture_output=True, text=True, timeout=30)
    assert r.returncode == 2 and "no server answered" in r.stderr


def test_node_reinitialises_after_server_restart(tmp_path):
    """A node whose server restarted (unknown unit id) initialises again and carries on."""
    from depthguard.distributed.node import build_node

    rig = _rig(tmp_path)
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    srv = FusionServer(["cam0"], wire.Settings(voxel_size=0.05), listen=[ep]).start()
    node = build_node(str(rig), "cam0", "pattern", connect=[ep])
    try:
        node.declare_token()
        node.initialize(timeout=10)
        assert node.step() > 0 and node.filter.voxel_size == 0.05
        srv.close()
        srv = FusionServer(["cam0"], wire.Settings(voxel_size=0.03), listen=[ep]).start()
        # the restarted server does not know unit 1: the node initialises again and adopts its settings
        assert wait_until(lambda: _try_step(node) and "cam0" in srv.units and srv.units["cam0"].updates > 0, 15.0)
        assert node.filter.voxel_size == 0.03 and srv.units["cam0"].inits == 1
    finally:
        node.close()
        srv.close()


def _try_step(node):
    from depthguard.transport.client import ServerUnavailable
    try:
        node.step()
        return True
    except ServerUnavailable:
        return False


def test_fit_to_wire_coarsens_conservatively(rng):
    from depthguard.distributed.node import fit_to_wire

    keys = rng.integers(-400, 400, (wire.MAX_VOXELS + 5000, 3))
    k2, c2, s2 = fit_to_wire(keys, np.ones(len(keys), np.int32), 0.01)
    assert len(k2) <= wire.MAX_VOXELS and s2 > 0.01
    covered = set(map(tuple, k2.tolist()))
    pts = (keys[:2000] + rng.uniform(0, 1, (2000, 3))) * 0.01
    assert all(tuple(np.floor(p / s2).astype(int)) in covered for p in pts)
    wire.update_request(1, 1, 0.0, s2, k2, c2)     # and it encodes


def test_network_defaults_are_loopback_and_checked():
    import inspect

    from depthguard.distributed.node import CameraNode
    from depthguard.transport import settings as NS

    assert NS.DEFAULT_ENDPOINT.startswith("tcp/127.0.0.1:")
    assert inspect.signature(FusionServer).parameters["listen"].default == (NS.DEFAULT_ENDPOINT,)
    assert inspect.signature(CameraNode).parameters["listen"].default is None   # → ServerClient's loopback default
    # R35: no certificates → loopback only, unless told --insecure
    with pytest.raises(ValueError, match="refusing to listen on tcp/0.0.0.0:7447 without certificates"):
        NS.check_exposure(["tcp/0.0.0.0:7447"])
    NS.check_exposure(["tcp/0.0.0.0:7447"], insecure=True)
    NS.check_exposure(["tcp/127.0.0.1:7447", "tcp/localhost:1", "tcp/[::1]:2"])
    with pytest.raises(ValueError, match="needs certificates: give --keys"):
        NS.check_exposure(["tls/127.0.0.1:7447"])
    with pytest.raises(ValueError, match="needs certificates"):
        FusionServer(["cam0"], listen=["tls/127.0.0.1:7447"])
    with pytest.raises(ValueError, match="refusing to listen"):
        FusionServer(["cam0"], listen=["tcp/192.168.1.10:7447"])
    with pytest.raises(ValueError, match="locator"):
        NS.zenoh_config(listen=["127.0.0.1:7447"])
    with pytest.raises(ValueError, match="lease"):
        NS.zenoh_config(lease_ms=5000)
    with pytest.raises(ValueError, match="zenoh key"):
        NS.Keys().alive("cam/*")
