"""Server restarts (R20, R27, R35): the registry keeps camera → unit id, nodes come back by
themselves, and the monitor's input sees the gap (no set captured in it), so the units'
cameras go stale there. Truth: the ids before the kill, the node processes' own pids
(they are never restarted), the wall clock, and the registry file on disk."""

import json
import signal
import subprocess
import sys
import threading
import time

import pytest

from depthguard.distributed.registry import Registry
from depthguard.transport.client import ServerClient, ServerUnavailable
from depthguard.transport.keys import init_authority, issue_admin, issue_node, load_identity
from loopback import free_port, wait_until
from small_rigs import write_abc_rig as write_rig


def _cli(*args):
    return [sys.executable, "-m", "depthguard.cli", *args]


def test_registry_is_atomic_and_refuses_a_bad_file(tmp_path):
    p = tmp_path / "reg.json"
    r = Registry(p)
    assert (r.assign("camA"), r.assign("camB"), r.assign("camA")) == (1, 2, 1)
    assert json.loads(p.read_text()) == {"version": 1, "units": {"camA": 1, "camB": 2}}
    assert Registry(p).assign("camC") == 3 and Registry(p).as_dict() == {"camA": 1, "camB": 2, "camC": 3}
    assert [f.name for f in tmp_path.iterdir()] == ["reg.json"]          # no temporary left behind
    for bad, why in (("{", "cannot read it as JSON"), ('{"version": 1, "units": {"a": 0}}', "integer in 1.."),
                     ('{"version": 1, "units": {"a": 1, "b": 1}}', "share a unit id"),
                     ('{"version": 1, "units": {"a/b": 1}}', "Zenoh key"), ("[]", "expected")):
        p.write_text(bad)
        with pytest.raises(ValueError, match=why):
            Registry(p)
        assert p.read_text() == bad                                        # left as it was


@pytest.mark.multiprocess
@pytest.mark.slow
@pytest.mark.timeout(170)
@pytest.mark.parametrize("mode", ["tcp", "tls"])
def test_server_killed_and_restarted(tmp_path, mode):
    rig = write_rig(tmp_path / "rig.yaml")
    port = free_port()
    reg = tmp_path / "registry.json"
    if mode == "tls":
        init_authority(tmp_path / "ca")
        for c in ("camA", "camB"):
            issue_node(c, tmp_path / "ca", tmp_path / c)
        issue_admin(tmp_path / "ca", tmp_path / "admin")
        ep = f"tls/127.0.0.1:{port}"
        keys = {c: ["--keys", str(tmp_path / c)] for c in ("camA", "camB", "ca")}
        admin_id = load_identity(tmp_path / "admin")
    else:
        ep = f"tcp/127.0.0.1:{port}"
        keys = {c: [] for c in ("camA", "camB", "ca")}
        admin_id = None

    def start_server():
        return subprocess.Popen(_cli("server", "--rig", str(rig), "--listen", ep, "--registry", str(reg),
                                     "--every", "0", "--duration", "160", *keys["ca"]),
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    procs = [start_server()]
    src = None
    stop = threading.Event()
    try:
        for c in ("camB", "camA"):               # camB first: ids are not alphabetical
            procs.append(subprocess.Popen(_cli("node", "--rig", str(rig), "--camera", c, "--source", "pattern",
                                               "--connect", ep, "--fps", "20", *keys[c]),
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
            time.sleep(0.3 if c == "camB" else 0)
        admin = ServerClient([ep], identity=admin_id)

        def both_fresh():
            try:
                st = admin.status(timeout=1.0)
            except ServerUnavailable:
                return None
            n = {x["camera"]: x for x in st["nodes"]}
            return n if {"camA", "camB"} <= set(n) and all(n[c]["state"] == "fresh" for c in ("camA", "camB")) else None
        before = wait_until(both_fresh, 60.0, step=0.3)
        assert before, "nodes never became fresh"
        ids = {c: before[c]["id"] for c in ("camA", "camB")}
        assert sorted(ids.values()) == [1, 2] and json.loads(reg.read_text())["units"] == ids
        pids = {c: before[c]["address"].split("/")[1] for c in ("camA", "camB")}
        # the monitor's input (tcp: the units source) records when each camera's sets arrive
        arrivals = []
        if mode == "tcp":
            from depthguard.sources.units import UnitsSource

            src = UnitsSource(ep, poll_hz=50.0)

            def drain():
                while not stop.is_set():
                    for cam, _c, _s, stamp in src.voxels_until(1e18):
                        arrivals.append((cam, stamp))
                    time.sleep(0.01)
            threading.Thread(target=drain, daemon=True).start()
            assert wait_until(lambda: any(c == "camA" for c, _ in arrivals), 10.0)
        # kill -9 the server, keep it down 3 s
        procs[0].send_signal(signal.SIGKILL)
        procs[0].wait(10)
        t_kill = time.time()
        time.sleep(1.0)
        with pytest.raises(ServerUnavailable):
            admin.status(timeout=0.5)
        time.sleep(2.0)
        t_back = time.time()
        procs[0] = start_server()
        after = wait_until(both_fresh, 60.0, step=0.3)
        t_fresh = time.time() - t_back
        assert after, "nodes did not come back by themselves"
        assert {c: after[c]["id"] for c in ("camA", "camB")} == ids              # same ids
        assert {c: after[c]["address"].split("/")[1] for c in ("camA", "camB")} == pids   # same processes
        print(f"{mode}: nodes fresh again {t_fresh:.2f} s after the server restarted")
        if mode == "tcp":
            assert wait_until(lambda: any(c == "camA" and s > t_back for c, s in arrivals), 10.0)
            stamps = sorted(s for c, s in arrivals if c == "camA")
            gaps = [(b - a, a) for a, b in zip(stamps, stamps[1:])]
            gap, at = max(gaps)
            # no set captured while the server was down reached the monitor: its camera goes stale
            # there (the monitor's camera_stale_limit is well under a second, R27)
            assert at <= t_kill + 0.2 and gap >= 3.0 - 0.3, (gap, at - t_kill)
            assert not any(t_kill + 0.2 < s < t_back for s in stamps)
    finally:
        stop.set()
        if src is not None:
            src.close()
        for p in procs:
            if p.poll() is None:
                p.terminate()
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
        if "admin" in locals():
            admin.close()
