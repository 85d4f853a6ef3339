"""Authenticated distributed mode (R35): the cell's authority, mutual TLS, camera binding.

Truths used: OpenSSL's own ``openssl verify`` and Python's ``ssl`` module (a TLS
client nobody here wrote) for the certificates and the handshake; the server
process's own log and counters; the three attacks of issue #19 replayed against a
real server process with a real node process running beside them.
"""

import json
import os
import socket
import ssl
import stat
import subprocess
import sys
import time

import pytest

from depthguard.transport import wire
from depthguard.transport.client import ServerClient, ServerRefused, ServerUnavailable
from depthguard.transport.keys import (ROLE_ADMIN, ROLE_NODE, ROLE_SERVER, init_authority, issue_admin,
                                         issue_node, load_identity)
from loopback import free_port, wait_until
from small_rigs import write_abc_rig as write_rig

@pytest.fixture(scope="module")
def pki(tmp_path_factory):
    """The cell's authority + certificates, and a foreign authority's."""
    d = tmp_path_factory.mktemp("pki")
    init_authority(d / "ca")
    for cam in ("camA", "camB"):
        issue_node(cam, d / "ca", d / cam)
    issue_admin(d / "ca", d / "admin")
    init_authority(d / "other")
    issue_node("camA", d / "other", d / "foreignA")
    # trusts our server, but presents a camA certificate of the other authority
    (d / "mixedA").mkdir()
    for n in ("node.pem", "node.key"):
        (d / "mixedA" / n).write_bytes((d / "foreignA" / n).read_bytes())
    os.chmod(d / "mixedA" / "node.key", 0o600)
    (d / "mixedA" / "ca.pem").write_bytes((d / "ca" / "ca.pem").read_bytes())
    return d


def _cli(*args):
    return [sys.executable, "-m", "depthguard.cli", *args]


def test_keys_files_modes_and_openssl_verify(pki, tmp_path):
    for sub, stem in (("ca", "ca"), ("ca", "server"), ("camA", "node"), ("admin", "admin")):
        mode = stat.S_IMODE((pki / sub / f"{stem}.key").stat().st_mode)
        assert mode == 0o600, (sub, stem, oct(mode))
    # OpenSSL itself checks the chain and the purposes
    for sub, stem, purpose in (("ca", "server", "sslserver"), ("camA", "node", "sslclient"),
                               ("admin", "admin", "sslclient")):
        r = subprocess.run(["openssl", "verify", "-purpose", purpose, "-CAfile", str(pki / "ca" / "ca.pem"),
                            str(pki / sub / f"{stem}.pem")], capture_output=True, text=True)
        assert r.returncode == 0 and ": OK" in r.stdout, r.stdout + r.stderr
    r = subprocess.run(["openssl", "verify", "-CAfile", str(pki / "ca" / "ca.pem"),
                        str(pki / "foreignA" / "node.pem")], capture_output=True, text=True)
    assert r.returncode != 0
    ident = load_identity(pki / "camA")
    assert (ident.role, ident.name) == (ROLE_NODE, "camA")
    assert (load_identity(pki / "ca").role, load_identity(pki / "admin").role) == (ROLE_SERVER, ROLE_ADMIN)
    # nothing is overwritten; a camera id that cannot name a key is refused
    before = (pki / "ca" / "ca.key").read_bytes()
    with pytest.raises(ValueError, match="nothing was overwritten"):
        init_authority(pki / "ca")
    with pytest.raises(ValueError, match="nothing was overwritten"):
        issue_node("camA", pki / "ca", pki / "camA")
    assert (pki / "ca" / "ca.key").read_bytes() == before
    with pytest.raises(ValueError, match="Zenoh key"):
        issue_node("side/left", pki / "ca", tmp_path / "x")
    with pytest.raises(FileNotFoundError, match="keys init"):
        issue_node("camA", tmp_path / "nothing", tmp_path / "y")
    # a key readable by others is refused with the command that fixes it
    issue_node("camB", pki / "ca", tmp_path / "loose")
    os.chmod(tmp_path / "loose" / "node.key", 0o644)
    with pytest.raises(ValueError, match="chmod 600"):
        load_identity(tmp_path / "loose")


def test_keys_cli(tmp_path):
    r = subprocess.run(_cli("keys", "init", str(tmp_path / "ca"), "--host", "10.0.0.5"), capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    r = subprocess.run(_cli("keys", "node", "cam1", "--ca", str(tmp_path / "ca"), "--out", str(tmp_path / "n1")),
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and (tmp_path / "n1" / "node.pem").exists(), r.stderr
    r = subprocess.run(_cli("keys", "admin", "--ca", str(tmp_path / "ca"), "--out", str(tmp_path / "adm")),
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and (tmp_path / "adm" / "admin.pem").exists(), r.stderr
    text = subprocess.run(["openssl", "x509", "-noout", "-text", "-in", str(tmp_path / "ca" / "server.pem")],
                          capture_output=True, text=True).stdout
    assert "IP Address:10.0.0.5" in text and "IP Address:127.0.0.1" in text and "DNS:localhost" in text
    r = subprocess.run(_cli("keys", "node", "cam1", "--ca", str(tmp_path / "ca"), "--out", str(tmp_path / "n1")),
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and r.stderr.startswith("depthguard: error:") and "overwritten" in r.stderr


def _tls_probe(port, pki, cert_dir=None, stem="node"):
    """Python's ssl (OpenSSL) as a client of the server's port: 'ok' when the link is held open,
    else the error the server's TLS answered with."""
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.load_verify_locations(str(pki / "ca" / "ca.pem"))
    if cert_dir is not None:
        ctx.load_cert_chain(str(cert_dir / f"{stem}.pem"), str(cert_dir / f"{stem}.key"))
    with socket.create_connection(("127.0.0.1", port), timeout=3) as raw:
        try:
            with ctx.wrap_socket(raw, server_hostname="localhost") as s:
                s.settimeout(1.0)
                try:
                    data = s.recv(1)          # TLS 1.3: a refused client certificate arrives as an alert here
                except socket.timeout:
                    return "ok"               # held open: zenoh waits for our InitSyn
                return "closed" if data == b"" else "ok"
        except (ssl.SSLError, ConnectionError) as exc:
            return f"refused: {exc}"


@pytest.mark.multiprocess
@pytest.mark.slow
@pytest.mark.timeout(150)
def test_attacks_fail_and_are_logged(pki, tmp_path):
    """Issue #19's three attacks, wrong certificates, and a plain TCP client, against a server
    process with --keys while the real camA node runs."""
    rig = write_rig(tmp_path / "rig.yaml")
    port = free_port()
    ep = f"tls/127.0.0.1:{port}"
    log_path = tmp_path / "server.log"
    procs = []
    with open(log_path, "w") as log_file:
        try:
            procs.append(subprocess.Popen(_cli("server", "--rig", str(rig), "--keys", str(pki / "ca"), "--listen", ep,
                                               "--every", "0", "--duration", "140"),
                                          stdout=log_file, stderr=log_file))   # zenoh's own log is on stdout
            procs.append(subprocess.Popen(_cli("node", "--rig", str(rig), "--camera", "camA", "--source", "pattern",
                                               "--keys", str(pki / "camA"), "--connect", ep, "--fps", "20"),
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
            admin = ServerClient([ep], identity=load_identity(pki / "admin"))
            procs_clients = [admin]

            def fresh_a():
                try:
                    st = admin.status(timeout=1.0)
                except ServerUnavailable:
                    return None
                n = {x["camera"]: x for x in st["nodes"]}
                return st if "camA" in n and n["camA"]["state"] == "fresh" and n["camA"]["voxels"] > 0 else None
            st0 = wait_until(fresh_a, 60.0, step=0.3)
            assert st0, log_path.read_text()[-2000:]
            a_id = {n["camera"]: n["id"] for n in st0["nodes"]}["camA"]
            a_vox = {n["camera"]: n["voxels"] for n in st0["nodes"]}["camA"]
            offset0 = st0["settings"]["epoch"]

            def refused():
                return admin.status()["refused"]
            r0 = refused()

            # 1. settings changed by a stranger: no certificate → no link at all; a node's certificate → refused
            stranger = ServerClient([f"tcp/127.0.0.1:{port}"])
            procs_clients.append(stranger)
            with pytest.raises(ServerUnavailable):
                stranger.set_settings(timeout=1.0, offset_const=0.5)
            node_b = ServerClient([ep], identity=load_identity(pki / "camB"))
            procs_clients.append(node_b)
            with pytest.raises(ServerRefused, match="needs a depthguard-admin certificate"):
                node_b.set_settings(offset_const=0.5)
            # a node's certificate sending an unsigned message (a raw zenoh query on the TLS link)
            raw = [r for r in node_b.session.get("depthguard/settings",
                                                 payload=wire.settings_request(offset_const=0.5), timeout=2.0)
                   if r.ok is not None]
            assert raw and b"not signed" in raw[0].ok.payload.to_bytes()
            st = admin.status()
            assert st["settings"]["epoch"] == offset0 and st["refused"] == r0 + 2
            # 2. updates to a unit id never joined, and to camA's id, with camB's certificate
            upd = wire.update_request(a_id + 1, 1, time.time(), 0.02, [[0, 0, 0]], [9])
            with pytest.raises(ServerRefused, match="not initialised"):
                node_b.request("depthguard/update", upd)
            upd = wire.update_request(a_id, 10 ** 6, time.time(), 0.02, [[0, 0, 0]], [9])
            with pytest.raises(ServerRefused, match=f"unit id {a_id} is not camera 'camB'"):
                node_b.request("depthguard/update", upd)
            # 3. joining as the running camA with camB's certificate
            with pytest.raises(ServerRefused, match="certificate of camera 'camB' cannot join as camera 'camA'"):
                node_b.request("depthguard/init", wire.init_request("camA", "evil"))
            # camA's unit is untouched: same id, its own voxels, fresh
            st = admin.status()
            n = {x["camera"]: x for x in st["nodes"]}
            assert n["camA"]["id"] == a_id and n["camA"]["state"] == "fresh"
            assert abs(n["camA"]["voxels"] - a_vox) <= 2 and "camB" not in n and st["refused"] == r0 + 5
            # a replayed (recorded) signed request is refused
            from depthguard.transport.auth import Signer
            env, _ = Signer(load_identity(pki / "admin")).seal(wire.status_request(), "depthguard/status")
            got = [r.ok.payload.to_bytes() for k in range(2)
                   for r in admin.session.get("depthguard/status", payload=env, timeout=2.0) if r.ok is not None]
            assert len(got) == 2 and b"replayed" in got[1] and b"replayed" not in got[0]
            # wrong authority, or no client certificate: the TLS handshake refuses them
            foreign = ServerClient([ep], identity=load_identity(pki / "mixedA"))
            procs_clients.append(foreign)
            with pytest.raises(ServerUnavailable):
                foreign.request("depthguard/init", wire.init_request("camA", "x"), timeout=1.5)
            assert _tls_probe(port, pki, pki / "camA") == "ok"             # control: a cell certificate is held
            assert _tls_probe(port, pki, pki / "mixedA") != "ok"
            assert _tls_probe(port, pki, None) != "ok"
            # a plain TCP client gets a TLS alert record (content type 21) and a closed link, nothing else
            with socket.create_connection(("127.0.0.1", port), timeout=3) as s:
                s.sendall(b"\x00" * 64)
                s.settimeout(3)
                data, closed = b"", False
                try:
                    while chunk := s.recv(100):
                        data += chunk
                    closed = True
                except ConnectionError:
                    closed = True
                except socket.timeout:
                    pass
                assert closed and (data == b"" or (data[0] == 21 and len(data) == 7)), (closed, data)
            # the status lists camC (never joined) as missing, over the admin's TLS link (CLI, table and JSON)
            r = subprocess.run(_cli("status", "--keys", str(pki / "admin"), "--connect", ep, "--json"),
                               capture_output=True, text=True, timeout=60)
            assert r.returncode == 0, r.stderr
            js = json.loads(r.stdout)
            assert js["missing"] == ["camB", "camC"] and js["refused"] >= r0 + 6
            r = subprocess.run(_cli("status", "--keys", str(pki / "admin"), "--connect", ep),
                               capture_output=True, text=True, timeout=60, env=dict(os.environ, COLUMNS="200"))
            rows = {ln.split("│")[1].strip(): ln for ln in r.stdout.splitlines() if ln.count("│") > 3}
            assert "missing" in rows["camC"] and "missing" in rows["camB"] and "fresh" in rows["camA"], r.stdout
            # the administrator changes a setting (the one thing a stranger could do before)
            r = subprocess.run(_cli("status", "--keys", str(pki / "admin"), "--connect", ep, "--json",
                                    "--set", "threshold=0.6"), capture_output=True, text=True, timeout=60)
            assert r.returncode == 0, r.stderr
            js = json.loads(r.stdout)["settings"]
            assert js["epoch"] == offset0 + 1 and js["threshold"] == pytest.approx(0.6)
            # the status needs an admin certificate: camB's is refused, one line
            r = subprocess.run(_cli("status", "--keys", str(pki / "camB"), "--connect", ep, "--timeout", "3"),
                               capture_output=True, text=True, timeout=60)
            assert r.returncode == 2 and "needs a depthguard-admin certificate" in r.stderr
            assert len(r.stderr.strip().splitlines()) == 1
        finally:
            for c in locals().get("procs_clients", []):
                c.close()
            for p in procs:
                if p.poll() is None:
                    p.terminate()
                try:
                    p.wait(10)
                except subprocess.TimeoutExpired:
                    p.kill()
    log = log_path.read_text()
    for why in ("changing settings needs a depthguard-admin certificate; depthguard-node/camB may not",
                "message is not signed",
                f"refused update from unknown unit id {a_id + 1} (certificate of camera 'camB')",
                f"certificate of camera 'camB' sent an update for unit id {a_id}, which is camera 'camA'",
                "certificate of camera 'camB' cannot join as camera 'camA'",
                "replayed"):
        assert why in log, f"{why!r} not in the server log:\n{log[-3000:]}"
    # Zenoh's TLS layer (rustls) logged the refused handshakes in the server process
    assert "invalid peer certificate" in log and "peer sent no certificates" in log, log[-3000:]


def test_tls_without_keys_and_exposure_are_one_line_errors(tmp_path):
    rig = write_rig(tmp_path / "rig.yaml")
    r = subprocess.run(_cli("server", "--rig", str(rig), "--listen", "tls/127.0.0.1:7999", "--duration", "1"),
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "needs certificates: give --keys" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    r = subprocess.run(_cli("server", "--rig", str(rig), "--listen", "tcp/0.0.0.0:7999", "--duration", "1"),
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "refusing to listen on tcp/0.0.0.0:7999 without certificates" in r.stderr
    assert "--insecure" in r.stderr and len(r.stderr.strip().splitlines()) == 1


@pytest.mark.multiprocess
@pytest.mark.timeout(60)
def test_a_cell_member_answering_in_place_of_the_server_is_ignored(pki):
    """camB's holder declares its own ``init`` queryable and answers with a forged unit id and
    settings (unsigned, and signed with camB's key).

    In the deployed topology (nodes without listeners, the server a Zenoh peer that does not
    broker) the rogue is never even asked. Where some topology does deliver such replies (a
    Zenoh router, brokering peers; here: the rogue's queryable on camA's own session), camA
    still takes only the server's signed reply for its own request."""
    from depthguard.distributed.server import FusionServer
    from depthguard.transport.auth import Signer

    port = free_port()
    ep = f"tls/127.0.0.1:{port}"
    srv = FusionServer(["camA", "camB"], wire.Settings(), listen=[ep], identity=load_identity(pki / "ca")).start()
    rogue = ServerClient([ep], identity=load_identity(pki / "camB"))
    node = ServerClient([ep], identity=load_identity(pki / "camA"))
    forged = wire.init_reply(99, wire.Settings(threshold=1.0))
    signer = Signer(load_identity(pki / "camB"))
    asked = {"rogue": 0, "local": 0}

    def answer(who):
        def cb(query):
            asked[who] += 1
            query.reply(query.key_expr, forged)                                      # unsigned
            nonce = query.payload.to_bytes()[12:28]        # the request's nonce, read from its envelope
            query.reply(query.key_expr, signer.seal(forged, str(query.key_expr), reply_to=nonce)[0])
        return cb
    queryables = [rogue.session.declare_queryable("depthguard/init", answer("rogue"))]
    try:
        time.sleep(1.0)
        got = wait_until(lambda: _init_or_none(node), 10.0, step=0.2)
        assert got is not None and got.unit_id == 1 and asked["rogue"] == 0
        queryables.append(node.session.declare_queryable("depthguard/init", answer("local")))
        time.sleep(0.5)
        got = _init_or_none(node)
        assert got is not None and got.unit_id == 1 and got.settings.threshold == pytest.approx(0.55)
        # without the server only the forged replies come, and none is taken
        srv.close()
        time.sleep(0.5)
        with pytest.raises(ServerUnavailable, match="a reply was refused: reply signed by depthguard-node/camB, not by the server"):
            node.request("depthguard/init", wire.init_request("camA", "x"), timeout=1.5)
        assert asked["local"] >= 2
    finally:
        for q in queryables:
            q.undeclare()
        rogue.close()
        node.close()
        srv.close()


def _init_or_none(client):
    try:
        return client.request("depthguard/init", wire.init_request("camA", "node"), timeout=1.0)
    except ServerUnavailable:
        return None


@pytest.mark.multiprocess
@pytest.mark.timeout(60)
def test_the_monitors_units_source_reads_a_tls_server_with_an_admin_certificate(pki, tmp_path):
    """The monitor's side of a server started with --keys: ``units:tls/...`` with the cell's admin
    certificate (context ``units_keys``, CLI ``monitor --units-keys``) gets camA's voxels over mutual
    TLS; without a certificate the same source finds no server."""
    from depthguard.distributed.node import build_node
    from depthguard.distributed.server import FusionServer
    from depthguard.rig import Rig
    from depthguard.sources.base import open_source

    rig_path = write_rig(tmp_path / "rig.yaml")
    rig = Rig.load(rig_path)
    ep = f"tls/127.0.0.1:{free_port()}"
    srv = FusionServer(["camA", "camB", "camC"], wire.Settings(stale_s=30.0), listen=[ep],
                       identity=load_identity(pki / "ca")).start()
    node = build_node(str(rig_path), "camA", "pattern", connect=[ep], identity=load_identity(pki / "camA"))
    src = None
    try:
        node.declare_token()
        node.initialize(timeout=20)
        assert wait_until(lambda: srv.units["camA"].alive, 10.0)
        assert node.step() > 0
        with pytest.raises(ValueError, match="no fusion server answered"):
            open_source(f"units:tcp/127.0.0.1:{ep.rsplit(':', 1)[1]}", rig,
                        {"units_timeout_s": 2.0})                     # no certificate: no link at all
        src = open_source(f"units:{ep}", rig, {"units_keys": pki / "admin", "units_poll_hz": 50.0,
                                               "units_timeout_s": 20.0})
        assert src.camera_ids == ["camA", "camB", "camC"]
        assert wait_until(lambda: src.received >= 1, 10.0), src.last_error
        (cam, centres, size, stamp), = src.voxels_until(1e18)
        u = srv.units["camA"]
        assert cam == "camA" and stamp == u.stamp and len(centres) == len(u.keys) > 0
    finally:
        if src is not None:
            src.close()
        node.close()
        srv.close()


def test_unit_states_are_signed_by_their_cameras_certificate(pki, tmp_path):
    """Issue 29: with keys a unit's depth grid state goes out sealed by its certificate; the monitor's
    ``units:`` source takes it, and refuses (counted, ``auth``) a state on camA's key sealed by camB's
    certificate, or not sealed at all."""
    from depthguard.distributed.node import build_node
    from depthguard.distributed.server import FusionServer
    from depthguard.distributed.state_relay import StateRelay
    from depthguard.distributed.unit_state import state_settings_of
    from depthguard.rig import Rig
    from depthguard.sources.base import open_source
    from depthguard.transport.auth import Signer

    rig_path = write_rig(tmp_path / "rig.yaml")
    rig = Rig.load(rig_path)
    ep = f"tls/127.0.0.1:{free_port()}"
    srv = FusionServer(["camA", "camB", "camC"], wire.Settings(stale_s=30.0, state=state_settings_of(rig)),
                       listen=[ep], identity=load_identity(pki / "ca")).start()
    relay = StateRelay(srv).start()
    node = build_node(str(rig_path), "camA", "pattern", connect=[ep], identity=load_identity(pki / "camA"),
                      states=True)
    src = None
    try:
        node.declare_token()
        node.initialize(timeout=20)
        src = open_source(f"units:{ep}", rig, {"units_keys": pki / "admin", "units_timeout_s": 20.0})
        time.sleep(0.5)                                   # the source's subscriber reaches the node
        assert node.step() == 0                           # no voxels: the state went out instead
        assert wait_until(lambda: src.states_received >= 1, 10.0), src.states_refused
        (st,) = src.states_until(1e18)
        assert st.camera == "camA" and st.free.shape == rig.camera("camA").shape
        key = node.keys.states("camA")
        raw = node.state_unit.encode(*node.source(), node.q, 5, node.settings.state)
        forged, _ = Signer(load_identity(pki / "camB")).seal(raw, key)
        # one at a time: a 1.5 MB put may be dropped by Zenoh's default congestion control while
        # another is on its way (the unit itself puts with BLOCK)
        node.client.session.put(key, forged)
        assert wait_until(lambda: src.states_refused.get("auth", 0) == 1, 10.0), src.states_refused
        node.client.session.put(key, raw)
        assert wait_until(lambda: src.states_refused.get("auth", 0) == 2, 10.0), src.states_refused
        assert src.states_until(1e18) == []
    finally:
        if src is not None:
            src.close()
        node.close()
        relay.close()
        srv.close()
