"""ur-rtde (PyPI ``ur-rtde``, extra ``depthguard[ur]``) run in a child process, spoken to by lines.

Why a child process: the ``ur-rtde`` 1.6.5 Python bindings hold the GIL while their constructors
wait for the robot's answers (the monitor's control thread would stop with them), and
destroying an ``RTDEIOInterface`` whose robot went away aborts the whole process (``terminate``
on a ``Broken pipe`` / ``End of file`` thrown in its destructor) — both seen against the test
peer ``tests/rtde_server.py``. In a child, a wait or an abort costs only the child; the parent
sees a lost connection and says so. The child never runs destructors (it ends with
``os._exit``).

Modes (``python .../ur_rtde_worker.py MODE HOST [FREQUENCY]``, run by its path so that the child
imports the standard library and ur-rtde only, not depthguard):

- ``io``: ``rtde_io.RTDEIOInterface(HOST)``; each line read is a slider fraction, passed to
  ``setSpeedSlider``; answers ``ok <value>`` per line, ``lost <reason>`` (then ends) on failure;
- ``receive``: ``rtde_receive.RTDEReceiveInterface(HOST, FREQUENCY, ["timestamp", "actual_q"])``;
  writes one JSON line ``[host time.time() s, robot timestamp s, [q rad x n]]`` per new robot
  timestamp (polled every 0.5 ms: the host stamp is the arrival time within that), ``lost
  <reason>`` (then ends) when the connection drops.

The first line of either is ``ready`` or ``error <sentence>``. The child ends when its stdin
closes (the parent went away).
"""

from __future__ import annotations

import importlib.util
import json
import os
import socket
import subprocess
import sys
import threading
import time

__all__ = ["RTDE_PORT", "UrError", "parse_address", "check_reachable", "Worker", "missing_package"]

RTDE_PORT = 30004       # the RTDE interface's port; the ur-rtde Python bindings take no other


class UrError(ValueError):
    """A UR robot address or connection that cannot be used (one sentence)."""


def missing_package() -> str | None:
    """A sentence when the ``ur-rtde`` package is not installed, else ``None``."""
    if importlib.util.find_spec("rtde_io") is None or importlib.util.find_spec("rtde_receive") is None:
        return ("ur-rtde: the Python package ur-rtde is not installed (pip install 'depthguard[ur]' "
                "or pip install 'ur-rtde>=1.6')")
    return None


def parse_address(argument: str, what: str) -> str:
    """``HOST[:PORT]`` -> ``HOST``; the port, when given, must be the RTDE port 30004."""
    host, _, port = (argument or "").strip().partition(":")
    host = host.strip()
    if not host:
        raise UrError(f"{what} needs the robot's address: ur-rtde:HOST (e.g. ur-rtde:192.168.1.10)")
    if port.strip() and port.strip() != str(RTDE_PORT):
        raise UrError(f"{what}: port {port.strip()!r}: the ur-rtde client speaks to port {RTDE_PORT} only "
                      f"(give ur-rtde:{host} or ur-rtde:{host}:{RTDE_PORT})")
    return host


def check_reachable(host: str, what: str, timeout_s: float = 2.0) -> None:
    """:class:`UrError` unless a TCP connection to ``host:30004`` opens within ``timeout_s``."""
    try:
        with socket.create_connection((host, RTDE_PORT), timeout=timeout_s):
            pass
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise UrError(f"{what}: cannot reach the robot at {host}:{RTDE_PORT} ({reason}); "
                      f"check the address and that the robot is on") from None


class Worker:
    """The parent's side: starts the child, waits ``timeout_s`` for ``ready``, hands each line
    it writes after that to ``on_line(line)`` (from a reader thread) and ``on_end(reason)`` once
    when it ends. :class:`UrError` when it does not get ready."""

    def __init__(self, mode: str, host: str, on_line, on_end, frequency: float = 125.0, timeout_s: float = 15.0):
        self._on_line, self._on_end = on_line, on_end
        self._lock = threading.Lock()
        # run as a script by its path: the child imports only the standard library and ur-rtde
        self.proc = subprocess.Popen([sys.executable, os.path.abspath(__file__), mode, host, repr(float(frequency))],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                     text=True, bufsize=1)
        first: list[str] = []
        got = threading.Event()

        def read_first():
            first.append(self.proc.stdout.readline().strip())
            got.set()
        threading.Thread(target=read_first, daemon=True).start()
        if not got.wait(timeout_s) or first[0] != "ready":
            self.close()
            why = first[0][len("error "):] if first and first[0].startswith("error ") else \
                f"no answer within {timeout_s:g} s"
            raise UrError(f"ur-rtde {mode} {host}: {why}")
        self._thread = threading.Thread(target=self._read, daemon=True, name=f"ur-rtde-{mode}")
        self._thread.start()

    def _read(self) -> None:
        reason = "the ur-rtde client process ended"
        for line in self.proc.stdout:
            line = line.strip()
            if line.startswith("lost"):
                reason = line[5:] or "connection lost"
                break
            self._on_line(line)
        self._on_end(reason)

    def send(self, line: str) -> bool:
        """Write one line to the child; False when it is gone."""
        with self._lock:
            try:
                self.proc.stdin.write(line + "\n")
                self.proc.stdin.flush()
                return True
            except (OSError, ValueError):
                return False

    @property
    def alive(self) -> bool:
        return self.proc.poll() is None

    def close(self) -> None:
        with self._lock:
            try:
                self.proc.stdin.close()
            except (OSError, ValueError):
                pass
        try:
            self.proc.wait(2.0)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(2.0)


def _say(text: str) -> None:
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


def _watch_parent() -> None:
    """End the child when its stdin closes (the parent went away)."""
    sys.stdin.read()
    os._exit(0)


def _io(host: str) -> None:
    import rtde_io

    io = rtde_io.RTDEIOInterface(host)
    _say("ready")
    for line in sys.stdin:
        try:
            value = float(line)
            io.setSpeedSlider(value)
        except Exception as exc:  # noqa: BLE001 - any failure of the client is a lost connection
            _say(f"lost setting the speed slider failed: {exc}")
            os._exit(3)
        _say(f"ok {value!r}")
    os._exit(0)


def _receive(host: str, frequency: float) -> None:
    import rtde_receive

    receiver = rtde_receive.RTDEReceiveInterface(host, frequency, ["timestamp", "actual_q", "actual_qd",
                                                                   "speed_scaling", "target_speed_fraction"])
    _say("ready")
    threading.Thread(target=_watch_parent, daemon=True).start()
    last = None
    while True:
        if not receiver.isConnected():
            _say("lost the robot closed the RTDE connection")
            os._exit(3)
        stamp = receiver.getTimestamp()
        if stamp != last:
            now = time.time()
            q = receiver.getActualQ()
            qd = receiver.getActualQd()
            scaling = receiver.getSpeedScaling() * receiver.getTargetSpeedFraction()
            last = stamp
            _say(json.dumps([now, stamp, list(q), list(qd), scaling]))
        time.sleep(0.0005)


def main(argv: list[str]) -> None:
    mode, host = argv[0], argv[1]
    frequency = float(argv[2]) if len(argv) > 2 else 125.0
    missing = missing_package()
    if missing:
        _say(f"error {missing}")
        os._exit(2)
    try:
        if mode == "io":
            _io(host)
        elif mode == "receive":
            _receive(host, frequency)
        else:
            _say(f"error unknown mode {mode!r}")
    except Exception as exc:  # noqa: BLE001 - reported to the parent as one line
        _say(f"error {type(exc).__name__}: {exc}")
    os._exit(2)


if __name__ == "__main__":
    main(sys.argv[1:])
