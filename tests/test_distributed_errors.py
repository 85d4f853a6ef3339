"""First contact with the distributed commands (issue #20): one line saying what is wrong
and what to do, never a traceback; ``status`` names every camera of the rig."""

import json
import socket
import subprocess
import sys
import time

import pytest

from loopback import free_port, wait_until
from small_rigs import write_abc_rig as write_rig


def _cli(*args):
    return [sys.executable, "-m", "depthguard.cli", *args]


def _one_error_line(r):
    lines = r.stderr.strip().splitlines()
    errors = [ln for ln in lines if ln.startswith("depthguard: error:")]
    assert r.returncode == 2 and len(errors) == 1 and "Traceback" not in r.stderr, r.stderr
    return errors[0]


@pytest.mark.multiprocess
@pytest.mark.timeout(60)
def test_node_without_server_says_so_at_once_and_ends_in_one_line(tmp_path):
    rig = write_rig(tmp_path / "rig.yaml")
    ep = f"tcp/127.0.0.1:{free_port()}"
    t0 = time.monotonic()
    p = subprocess.Popen(_cli("node", "--rig", str(rig), "--camera", "camA", "--source", "pattern",
                              "--connect", ep, "--wait", "3"), stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True)
    first = p.stderr.readline()          # before the wait is over, the node says what it waits for
    t_first = time.monotonic() - t0
    rest = p.stderr.read()
    p.wait(30)
    assert "waiting for the fusion server on " + ep in first and t_first < 3 + 10, first
    r = subprocess.CompletedProcess(p.args, p.returncode, "", first + rest)
    line = _one_error_line(r)
    assert f"no fusion server answered on {ep} within 3 s" in line and "start `depthguard server` first" in line


@pytest.mark.multiprocess
@pytest.mark.timeout(60)
def test_server_on_a_taken_port_is_one_line(tmp_path):
    rig = write_rig(tmp_path / "rig.yaml")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        r = subprocess.run(_cli("server", "--rig", str(rig), "--listen", f"tcp/127.0.0.1:{port}", "--duration", "1"),
                           capture_output=True, text=True, timeout=60)
    line = _one_error_line(r)
    assert "already in use" in line and "--listen" in line and "ZError" not in r.stderr


def test_tls_endpoint_without_keys_is_refused_before_anything_starts(tmp_path):
    rig = write_rig(tmp_path / "rig.yaml")
    for cmd in (("server", "--rig", str(rig), "--listen", "tls/127.0.0.1:7448", "--duration", "1"),
                ("node", "--rig", str(rig), "--camera", "camA", "--source", "pattern", "--connect",
                 "tls/127.0.0.1:7448", "--wait", "1"),
                ("status", "--connect", "tls/127.0.0.1:7448", "--timeout", "1")):
        r = subprocess.run(_cli(*cmd), capture_output=True, text=True, timeout=60)
        line = _one_error_line(r)
        assert "needs certificates: give --keys DIR" in line and "Missing TLS" not in r.stderr, (cmd, r.stderr)


@pytest.mark.multiprocess
@pytest.mark.slow
@pytest.mark.timeout(90)
def test_status_lists_every_rig_camera_with_missing(tmp_path):
    rig = write_rig(tmp_path / "rig.yaml")
    ep = f"tcp/127.0.0.1:{free_port()}"
    procs = []
    try:
        procs.append(subprocess.Popen(_cli("server", "--rig", str(rig), "--listen", ep, "--every", "0",
                                           "--duration", "80"), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        procs.append(subprocess.Popen(_cli("node", "--rig", str(rig), "--camera", "camB", "--source", "pattern",
                                           "--connect", ep, "--fps", "10"),
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))

        def joined():
            r = subprocess.run(_cli("status", "--connect", ep, "--json", "--timeout", "1"),
                               capture_output=True, text=True, timeout=30)
            return json.loads(r.stdout) if r.returncode == 0 and json.loads(r.stdout)["nodes"] else None
        st = wait_until(joined, 60.0, step=0.5)
        assert st and st["missing"] == ["camA", "camC"] and [n["camera"] for n in st["nodes"]] == ["camB"]
        r = subprocess.run(_cli("status", "--connect", ep), capture_output=True, text=True, timeout=30,
                           env={**__import__("os").environ, "COLUMNS": "200"})
        rows = {ln.split("│")[1].strip(): ln for ln in r.stdout.splitlines() if ln.count("│") > 3}
        assert set(rows) >= {"camA", "camB", "camC"}, r.stdout
        assert "missing" in rows["camA"] and "missing" in rows["camC"] and "missing" not in rows["camB"]
    finally:
        for p in procs:
            p.terminate()
            p.wait(10)
