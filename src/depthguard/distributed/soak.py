"""Soak of the distributed mode: N simulated units at 30 Hz on loopback (R35, ``depthguard soak``).

The fusion server runs in its own process (``python -m depthguard.distributed.soak serve``,
so its memory is its own); the N units run as threads of the calling process, each with
its own Zenoh session, liveliness token and unit id, sending a fixed voxel set (``voxels``
keys, 8 bytes each on the wire) with consecutive sequence numbers every 1/``hz`` s. The
units do not filter images: the soak loads the link and the server, not the per-camera
filter (whose cost the ``voxels`` bench measures).

Figures (:func:`run_soak`):

* ``lost``: updates a unit sent that the server never stored (sent − stored; the server
  also counts the gaps of each unit's sequence numbers, ``seq_gaps``);
* ``late_slots``: 30 Hz slots a unit could not use because it was still busy (the CPU
  did not keep up; nothing was sent for them, so they are not "lost" on the link);
* ``refresh_ms`` p50 / p99 / max: the interval between two stored updates of one unit
  at the server (ideal 1000/``hz``); ``rtt_ms`` p50 / p99: a unit's request → reply;
* ``rss_mb``: the server's resident memory sampled every ``sample_s``;
  ``rss_growth_pct``: last sample vs the first after the warm-up (max(30 s, 20 %)).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np

__all__ = ["run_soak", "serve_main"]

_BIN_MS = 0.5
_NBINS = 4000                     # 0 .. 2 s, then overflow


def _percentile(hist: np.ndarray, q: float) -> float:
    """The ``q`` percentile (ms) of a histogram of ``_BIN_MS`` bins (bin upper edge; inf = overflow)."""
    n = int(hist.sum())
    if n == 0:
        return float("nan")
    i = int(np.searchsorted(np.cumsum(hist), q / 100.0 * n))
    return float("inf") if i >= _NBINS else (i + 1) * _BIN_MS


def _add(hist: np.ndarray, ms: float) -> None:
    hist[min(int(ms / _BIN_MS), _NBINS)] += 1


def _rss_mb(pid: int) -> float:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return float("nan")


def serve_main(argv: list[str]) -> int:
    """``serve --units N --port P --out FILE``: a server for ``unit0..unitN-1`` until SIGTERM;
    then the refresh histogram and per-unit counts go to FILE (JSON)."""
    from depthguard.distributed.server import FusionServer
    from depthguard.transport import wire

    ap = argparse.ArgumentParser(prog="depthguard-soak-serve")
    ap.add_argument("--units", type=int, required=True)
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    hist = np.zeros(_NBINS + 1, np.int64)
    last: dict[str, float] = {}
    lock = threading.Lock()
    problems: list[str] = []

    def on_update(u):
        with lock:
            t = u.t_update
            prev = last.get(u.camera)
            if prev is not None and t > prev:
                _add(hist, (t - prev) * 1000.0)
            last[u.camera] = max(t, prev or t)

    def log(line: str) -> None:
        if ("rejected" in line or "error" in line or "refused" in line) and len(problems) < 20:
            problems.append(line)

    srv = FusionServer([f"unit{i}" for i in range(a.units)], wire.Settings(stale_s=0.5),
                       listen=[f"tcp/127.0.0.1:{a.port}"], log=log)
    srv.on_update = on_update
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    srv.start()
    print("ready", flush=True)
    stop.wait()
    with srv._lock:
        out = {"hist": hist.tolist(), "updates": {u.camera: u.updates for u in srv.units.values()},
               "seq_gaps": {u.camera: u.lost for u in srv.units.values()}, "rejected": srv.rejected,
               "refused": srv.refused, "problems": problems}
    srv.close()
    with open(a.out, "w") as f:
        json.dump(out, f)
    return 0


class _Unit(threading.Thread):
    def __init__(self, i: int, endpoint: str, hz: float, voxels: int, stop: threading.Event):
        super().__init__(name=f"soak-unit{i}", daemon=True)
        self.camera = f"unit{i}"
        self.endpoint, self.hz, self.stop = endpoint, hz, stop
        rng = np.random.default_rng(i)
        self.keys = rng.integers(-200, 200, (voxels, 3))
        self.counts = rng.integers(1, 50, voxels)
        self.rtt = np.zeros(_NBINS + 1, np.int64)
        self.sent = self.failed = self.late = 0
        self.error: str | None = None
        self.ready = threading.Event()

    def run(self) -> None:
        from depthguard.transport import wire
        from depthguard.transport.client import ServerClient, ServerUnavailable

        try:
            with ServerClient([self.endpoint]) as c:
                tok = c.session.liveliness().declare_token(c.keys.alive(self.camera))
                uid = c.request(c.keys.init, wire.init_request(self.camera, f"soak/{os.getpid()}"), 10.0,
                                wire.MsgType.INIT_REP).unit_id
                self.ready.set()
                period = 1.0 / self.hz
                next_t = time.monotonic()
                seq = 0
                while not self.stop.is_set():
                    seq += 1
                    msg = wire.update_request(uid, seq, time.time(), 0.02, self.keys, self.counts, 0.2)
                    t0 = time.perf_counter()
                    try:
                        c.request(c.keys.update, msg, 1.0, wire.MsgType.UPDATE_REP)
                        _add(self.rtt, (time.perf_counter() - t0) * 1000.0)
                    except ServerUnavailable:
                        self.failed += 1
                    self.sent += 1
                    next_t += period
                    delay = next_t - time.monotonic()
                    if delay > 0:
                        self.stop.wait(delay)
                    else:                                   # busy past the next slot(s): skip them
                        missed = int(-delay / period)
                        self.late += missed
                        next_t += missed * period
                tok.undeclare()
        except Exception as exc:  # noqa: BLE001 - reported in the result
            self.error = f"{type(exc).__name__}: {exc}"
            self.ready.set()


def run_soak(units: int = 16, minutes: float = 10.0, hz: float = 30.0, voxels: int = 500,
             sample_s: float = 5.0, log=None) -> dict:
    """Run the soak (module docstring); the figures as a dict."""
    from depthguard.transport.settings import DEFAULT_PORT

    if not (1 <= units <= 255):
        raise ValueError(f"--units must be within 1-255 (got {units})")
    if not (minutes > 0 and hz > 0 and voxels >= 0):
        raise ValueError("--minutes, --hz must be > 0 and --voxels >= 0")
    log = log or (lambda m: None)
    import socket
    import tempfile

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1] or DEFAULT_PORT
    ep = f"tcp/127.0.0.1:{port}"
    tmp = tempfile.mkdtemp(prefix="depthguard-soak-")
    out_path = os.path.join(tmp, "server.json")
    srv = subprocess.Popen([sys.executable, "-m", "depthguard.distributed.soak", "serve", "--units", str(units),
                            "--port", str(port), "--out", out_path], stdout=subprocess.PIPE, text=True)
    stop = threading.Event()
    threads: list[_Unit] = []
    try:
        if srv.stdout.readline().strip() != "ready":
            raise RuntimeError("the soak server did not start")
        threads = [_Unit(i, ep, hz, voxels, stop) for i in range(units)]
        for t in threads:
            t.start()
        for t in threads:
            t.ready.wait(30)
        errors = [t.error for t in threads if t.error]
        if errors:
            raise RuntimeError(f"units failed to join: {errors[0]}")
        duration = minutes * 60.0
        t0 = time.monotonic()
        samples = []
        while True:
            el = time.monotonic() - t0
            samples.append((round(el, 1), _rss_mb(srv.pid)))
            if el >= duration:
                break
            if len(samples) % max(1, int(60 / sample_s)) == 1:
                log(f"soak: {el:.0f}/{duration:.0f} s, server RSS {samples[-1][1]:.1f} MB, "
                    f"sent {sum(t.sent for t in threads)}")
            time.sleep(min(sample_s, duration - el))
        stop.set()
        for t in threads:
            t.join(10)
        time.sleep(0.3)
    finally:
        stop.set()
        if srv.poll() is None:
            srv.send_signal(signal.SIGTERM)
        try:
            srv.wait(30)
        except subprocess.TimeoutExpired:
            srv.kill()
    with open(out_path) as f:
        server = json.load(f)
    hist = np.asarray(server["hist"])
    rtt = np.sum([t.rtt for t in threads], axis=0)
    sent = sum(t.sent for t in threads)
    stored = sum(server["updates"].values())
    warm = max(30.0, 0.2 * minutes * 60.0)
    after = [r for el, r in samples if el >= warm]
    growth = (100.0 * (after[-1] - after[0]) / after[0]) if len(after) >= 2 else float("nan")
    slots = int(minutes * 60.0 * hz) * units
    return {
        "units": units, "hz": hz, "minutes": minutes, "voxels": voxels, "cpu_count": os.cpu_count(),
        "sent": sent, "stored": stored, "lost": sent - stored, "seq_gaps": sum(server["seq_gaps"].values()),
        "failed_requests": sum(t.failed for t in threads), "late_slots": sum(t.late for t in threads),
        "slots": slots, "rejected": server["rejected"], "refused": server["refused"],
        "server_problems": server.get("problems", []),
        "refresh_ms": {"p50": _percentile(hist, 50), "p99": _percentile(hist, 99),
                       "max": _percentile(hist, 100), "ideal": 1000.0 / hz},
        "rtt_ms": {"p50": _percentile(rtt, 50), "p99": _percentile(rtt, 99)},
        "rss_mb": samples, "rss_growth_pct": growth, "warmup_s": warm,
    }


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "serve":
        sys.exit(serve_main(sys.argv[2:]))
    print("usage: python -m depthguard.distributed.soak serve --units N --port P --out FILE "
          "(the user command is `depthguard soak`)", file=sys.stderr)
    sys.exit(2)
