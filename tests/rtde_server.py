"""A test peer that speaks the RTDE protocol (Real-Time Data Exchange, protocol version 2) on loopback.

It is NOT a UR controller and not URSim: it implements the wire protocol as Universal Robots'
"Real-Time Data Exchange (RTDE) Guide" describes it, with a made-up robot behind it, so that
the real RTDE clients (the PyPI package ``ur-rtde``: ``rtde_receive``, ``rtde_io``) can be run
against something nobody here wrote the client side of. Written from that description; no
controller code was read or copied.

What it emulates:

- TCP, one client per connection, every package ``[uint16 size][uint8 type][payload]``,
  big-endian, ``size`` counting the three header bytes;
- ``V`` request protocol version (1 or 2 accepted), ``v`` controller version (default 5.11.0.0,
  an e-Series: the clients then ask for 500 Hz), ``O`` setup outputs (v2: a double frequency, then
  comma-separated names; the answer is a recipe id and the types, ``NOT_FOUND`` for an unknown
  name and recipe id 0), ``I`` setup inputs (the same; ``IN_USE`` for a variable another
  connection's recipe holds), ``S`` start, ``P`` pause, ``U`` data packages both ways, ``M`` text
  messages (sent on a bad package, v2 layout);
- outputs: the variables of the guide's output table the clients ask for (``timestamp``,
  ``actual_q`` and ``actual_qd`` of the simulated joints, ``target_speed_fraction`` = the speed
  slider, ``speed_scaling`` = 1, ``robot_mode`` 7 running, ``safety_mode`` 1 normal,
  ``runtime_state`` 2 playing; every other known name reads 0), sent at the recipe's frequency
  after ``S`` until ``P``;
- inputs: the guide's input variables. ``speed_slider_fraction`` is applied when bit 0 of
  ``speed_slider_mask`` is set, clamped to [0, 1]; every value received is kept in
  :attr:`RtdeServer.sliders` as ``(server time s, fraction)``. Input data packages are accepted
  without a ``S`` start: ``rtde_io`` (ur-rtde 1.6.5) sets up its 16 input recipes and sends data
  without ever starting (``V``, ``I`` x 16, ``U``...), and it is known to work on robots.

The robot: six joints ``q(t) = q0 + amplitude * sin(2 pi phase)``, where the phase advances at
``cycles_per_s * slider`` — the slider scales the speed along the path, 0 halts it there.

Not emulated: the dashboard (29999), primary/secondary (30001/30002) and real-time (30003)
interfaces, URScript, the safety system. ``rtde_control`` needs those and is not served.
``ur-rtde``'s constructors hold the Python GIL while they wait for answers: run the server in
another process (:class:`ServerProcess`) than the client.
The clients of ``ur-rtde`` connect to port 30004 only (their Python bindings take no port), so a
test runs one server per loopback address ``127.x.y.z`` (:func:`free_loopback_host`) instead
of one per ephemeral port; the server refuses any address outside 127.0.0.0/8.
"""

from __future__ import annotations

import ipaddress
import math
import random
import socket
import struct
import threading
import time

RTDE_PORT = 30004

_FORMATS = {"BOOL": "?", "UINT8": "B", "UINT32": "I", "UINT64": "Q", "INT32": "i", "DOUBLE": "d",
            "VECTOR3D": "3d", "VECTOR6D": "6d", "VECTOR6INT32": "6i", "VECTOR6UINT32": "6I"}


def _outputs() -> dict[str, str]:
    """The output variables of the guide and their types."""
    types = {n: "VECTOR6D" for n in (
        "target_q", "target_qd", "target_qdd", "target_current", "target_moment", "actual_q", "actual_qd",
        "actual_current", "joint_control_output", "actual_TCP_pose", "actual_TCP_speed", "actual_TCP_force",
        "target_TCP_pose", "target_TCP_speed", "joint_temperatures", "actual_joint_voltage", "payload_inertia",
        "ft_raw_wrench", "actual_current_window", "actual_current_as_torque", "elbow_position", "elbow_velocity")}
    types.update({n: "DOUBLE" for n in (
        "timestamp", "actual_execution_time", "speed_scaling", "target_speed_fraction", "actual_momentum",
        "actual_main_voltage", "actual_robot_voltage", "actual_robot_current", "standard_analog_input0",
        "standard_analog_input1", "standard_analog_output0", "standard_analog_output1", "io_current",
        "tool_analog_input0", "tool_analog_input1", "tool_output_current", "tool_temperature", "tcp_force_scalar",
        "payload", "euromap67_24V_voltage", "euromap67_24V_current")})
    types.update({n: "INT32" for n in ("robot_mode", "safety_mode", "safety_status", "tool_output_voltage")})
    types.update({n: "UINT32" for n in (
        "runtime_state", "robot_status_bits", "safety_status_bits", "analog_io_types", "tool_mode",
        "tool_analog_input_types", "output_bit_registers0_to_31", "output_bit_registers32_to_63",
        "input_bit_registers0_to_31", "input_bit_registers32_to_63", "euromap67_input_bits",
        "euromap67_output_bits", "script_control_line")})
    types.update({n: "UINT64" for n in ("actual_digital_input_bits", "actual_digital_output_bits")})
    types.update({"joint_mode": "VECTOR6INT32", "actual_tool_accelerometer": "VECTOR3D", "payload_cog": "VECTOR3D",
                  "tool_output_mode": "UINT8", "tool_digital_output0_mode": "UINT8",
                  "tool_digital_output1_mode": "UINT8"})
    for i in range(48):
        types[f"output_int_register_{i}"] = types[f"input_int_register_{i}"] = "INT32"
        types[f"output_double_register_{i}"] = types[f"input_double_register_{i}"] = "DOUBLE"
    for i in range(64, 128):
        types[f"output_bit_register_{i}"] = types[f"input_bit_register_{i}"] = "BOOL"
    return types


def _inputs() -> dict[str, str]:
    """The input variables of the guide and their types."""
    types = {"speed_slider_mask": "UINT32", "speed_slider_fraction": "DOUBLE",
             "standard_digital_output_mask": "UINT8", "standard_digital_output": "UINT8",
             "configurable_digital_output_mask": "UINT8", "configurable_digital_output": "UINT8",
             "tool_digital_output_mask": "UINT8", "tool_digital_output": "UINT8",
             "standard_analog_output_mask": "UINT8", "standard_analog_output_type": "UINT8",
             "standard_analog_output_0": "DOUBLE", "standard_analog_output_1": "DOUBLE",
             "input_bit_registers0_to_31": "UINT32", "input_bit_registers32_to_63": "UINT32",
             "external_force_torque": "VECTOR6D", "payload_mass": "DOUBLE", "payload_cog": "VECTOR3D",
             "script_control_line": "UINT32"}
    for i in range(48):
        types[f"input_int_register_{i}"] = "INT32"
        types[f"input_double_register_{i}"] = "DOUBLE"
    for i in range(64, 128):
        types[f"input_bit_register_{i}"] = "BOOL"
    return types


OUTPUTS = _outputs()
INPUTS = _inputs()


def free_loopback_host() -> str:
    """A loopback address ``127.x.y.z`` whose port 30004 is free now (the RTDE port is fixed)."""
    rng = random.Random()
    for _ in range(100):
        host = f"127.{rng.randint(1, 254)}.{rng.randint(1, 254)}.{rng.randint(1, 254)}"
        with socket.socket() as s:
            try:
                s.bind((host, RTDE_PORT))
            except OSError:
                continue
            return host
    raise RuntimeError("no free loopback address for an RTDE server")


class _Recipe:
    def __init__(self, names, types, frequency=0.0):
        self.names, self.types, self.frequency = list(names), list(types), float(frequency)
        self.fmt = ">" + "".join(_FORMATS[t] for t in self.types)
        self.size = struct.calcsize(self.fmt)


class RtdeServer:
    """An RTDE peer on ``host:port`` (module docstring); stops by itself after ``lifetime_s``.

    ``q0``, ``amplitude``: (6,) rad; ``cycles_per_s``: path cycles per second at slider 1.
    Records: ``sliders`` (every slider value received), ``inputs`` (every input package as
    ``(time, {name: value})``), ``outputs_asked`` (the names of every output recipe),
    ``messages`` (package types received, in order), ``connections``.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 0, *, controller_version=(5, 11, 0, 0),
                 q0=(0.0, -1.2, 1.0, -1.4, -1.57, 0.0), amplitude=(0.6, 0.3, 0.3, 0.2, 0.2, 0.4),
                 cycles_per_s: float = 0.1, slider: float = 1.0, lifetime_s: float = 120.0):
        if not ipaddress.ip_address(host).is_loopback:
            raise ValueError(f"the RTDE test server serves loopback only (got {host})")
        self.controller_version = tuple(int(v) for v in controller_version)
        self.q0, self.amplitude = [float(v) for v in q0], [float(v) for v in amplitude]
        self.cycles_per_s = float(cycles_per_s)
        self._lock = threading.Lock()
        self._segments = [(0.0, 0.0, float(slider))]      # (start s, phase at start, slider) of the path
        self.sliders: list[tuple[float, float]] = []
        self.inputs: list[tuple[float, dict]] = []
        self.outputs_asked: list[list[str]] = []
        self.messages: list[str] = []
        self.connections = 0
        self._claims: dict[str, int] = {}            # input variable -> connection number holding it
        self._socks: list[socket.socket] = []
        self._stop = threading.Event()
        self._listen = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._listen.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._listen.bind((host, int(port)))
        self._listen.listen(8)
        self._listen.settimeout(0.2)
        self.host, self.port = self._listen.getsockname()[:2]
        self.t0 = time.monotonic()
        self._deadline = self.t0 + float(lifetime_s)
        self._thread = threading.Thread(target=self._accept, name="rtde-server", daemon=True)
        self._thread.start()

    # --- the simulated robot ---------------------------------------------------------------
    @property
    def slider(self) -> float:
        with self._lock:
            return self._segments[-1][2]

    def phase_at(self, t: float) -> float:
        """The path phase (cycles) at ``t`` s on the server's clock (``timestamp``)."""
        with self._lock:
            segments = list(self._segments)
        for start, phase, slider in reversed(segments):
            if t >= start:
                return phase + (t - start) * self.cycles_per_s * slider
        return segments[0][1]

    def joints_at(self, t: float) -> tuple[list[float], list[float]]:
        """``(q rad, qd rad/s)`` of the simulated robot at ``t`` s on the server's clock."""
        ph, rate = self.phase_at(t), self.cycles_per_s * self._slider_at(t)
        w = 2.0 * math.pi
        q = [q0 + a * math.sin(w * ph) for q0, a in zip(self.q0, self.amplitude)]
        qd = [a * w * rate * math.cos(w * ph) for a in self.amplitude]
        return q, qd

    def _slider_at(self, t: float) -> float:
        with self._lock:
            segments = list(self._segments)
        return next((s for start, _, s in reversed(segments) if t >= start), segments[0][2])

    def now(self) -> float:
        """The server's clock (s since it started): what it sends as ``timestamp``."""
        return time.monotonic() - self.t0

    def _set_slider(self, fraction: float) -> None:
        t = self.now()
        ph = self.phase_at(t)
        with self._lock:
            self.sliders.append((t, float(fraction)))
            if math.isfinite(fraction):
                self._segments.append((t, ph, min(max(float(fraction), 0.0), 1.0)))

    def _value(self, name: str, now: float):
        t = OUTPUTS[name]
        if name in ("actual_q", "target_q", "actual_qd", "target_qd"):
            q, qd = self.joints_at(now)
            return q if name.endswith("q") else qd
        scalar = {"timestamp": now, "target_speed_fraction": self.slider, "speed_scaling": 1.0,
                  "robot_mode": 7, "safety_mode": 1, "safety_status": 1, "runtime_state": 2,
                  "robot_status_bits": 0b11, "safety_status_bits": 1}.get(name, 0)
        n = {"VECTOR6D": 6, "VECTOR6INT32": 6, "VECTOR6UINT32": 6, "VECTOR3D": 3}.get(t)
        if n is not None:
            return [0.0 if t.endswith("D") else 0] * n
        return float(scalar) if t == "DOUBLE" else (bool(scalar) if t == "BOOL" else int(scalar))

    # --- the wire ------------------------------------------------------------------------------
    def _accept(self) -> None:
        while not self._stop.is_set() and time.monotonic() < self._deadline:
            try:
                conn, _ = self._listen.accept()
            except socket.timeout:
                continue
            except OSError:
                break
            self.connections += 1
            self._socks.append(conn)
            threading.Thread(target=self._serve, args=(conn, self.connections), name="rtde-conn", daemon=True).start()
        self.stop()

    def _serve(self, conn: socket.socket, number: int) -> None:
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        send_lock = threading.Lock()
        state = {"version": 1, "outputs": {}, "inputs": {}, "started": False}

        def send(kind: str, payload: bytes = b"") -> None:
            with send_lock:
                conn.sendall(struct.pack(">HB", 3 + len(payload), ord(kind)) + payload)

        def text(message: str) -> None:
            m, s = message.encode()[:255], b"rtde_server"
            send("M", bytes([len(m)]) + m + bytes([len(s)]) + s + bytes([1]))

        streamer = None
        try:
            while not self._stop.is_set():
                header = _read(conn, 3)
                size, kind = struct.unpack(">HB", header)
                payload = _read(conn, size - 3) if size > 3 else b""
                kind = chr(kind)
                self.messages.append(kind)
                if kind == "V":
                    version = struct.unpack(">H", payload[:2])[0] if len(payload) >= 2 else 0
                    ok = version in (1, 2)
                    if ok:
                        state["version"] = version
                    send("V", bytes([int(ok)]))
                elif kind == "v":
                    send("v", struct.pack(">IIII", *self.controller_version))
                elif kind == "O":
                    freq = 125.0
                    if state["version"] >= 2:
                        freq, payload = struct.unpack(">d", payload[:8])[0], payload[8:]
                    names = [n for n in payload.decode().strip().split(",") if n]
                    self.outputs_asked.append(names)
                    types = [OUTPUTS.get(n, "NOT_FOUND") for n in names]
                    if "NOT_FOUND" in types or not names or not 0 < freq <= 500:
                        send("O", bytes([0]) + ",".join(types).encode())
                        continue
                    rid = len(state["outputs"]) + 1
                    state["outputs"][rid] = _Recipe(names, types, freq)
                    send("O", bytes([rid]) + ",".join(types).encode())
                elif kind == "I":
                    names = [n for n in payload.decode().strip().split(",") if n]
                    with self._lock:
                        types = [("IN_USE" if self._claims.get(n, number) != number else INPUTS[n])
                                 if n in INPUTS else "NOT_FOUND" for n in names]
                        ok = names and all(t in _FORMATS for t in types)
                        if ok:
                            for n in names:
                                self._claims[n] = number
                    if not ok:
                        send("I", bytes([0]) + ",".join(types).encode())
                        continue
                    rid = len(state["inputs"]) + 1
                    state["inputs"][rid] = _Recipe(names, types)
                    send("I", bytes([rid]) + ",".join(types).encode())
                elif kind == "S":
                    ok = bool(state["outputs"]) or bool(state["inputs"])
                    state["started"] = ok
                    send("S", bytes([int(ok)]))
                    if ok and state["outputs"] and streamer is None:
                        streamer = threading.Thread(target=self._stream, args=(state, send), daemon=True,
                                                    name="rtde-stream")
                        streamer.start()
                elif kind == "P":
                    state["started"] = False
                    send("P", bytes([1]))
                elif kind == "U":
                    recipe = state["inputs"].get(payload[0]) if payload else None
                    if recipe is None or len(payload) - 1 != recipe.size:
                        text(f"data package for unknown input recipe or of wrong size ({len(payload)} bytes)")
                        continue
                    self._apply(recipe, struct.unpack(recipe.fmt, payload[1:]))
                else:
                    text(f"unknown package type {kind!r}")
        except (ConnectionError, OSError, struct.error):
            pass
        finally:
            state["started"] = False
            with self._lock:
                for n in [n for n, c in self._claims.items() if c == number]:
                    del self._claims[n]
            try:
                conn.close()
            except OSError:
                pass

    def _apply(self, recipe: _Recipe, flat) -> None:
        values, i = {}, 0
        for name, t in zip(recipe.names, recipe.types):
            n = len(_FORMATS[t]) > 1 and int(_FORMATS[t][0]) or 1
            values[name] = flat[i] if n == 1 else list(flat[i:i + n])
            i += n
        self.inputs.append((self.now(), values))
        if "speed_slider_fraction" in values and int(values.get("speed_slider_mask", 0)) & 1:
            self._set_slider(float(values["speed_slider_fraction"]))

    def _stream(self, state, send) -> None:
        """Send each output recipe at its frequency while started."""
        next_at = {rid: self.now() for rid in state["outputs"]}
        while state["started"] and not self._stop.is_set():
            now = self.now()
            for rid, recipe in list(state["outputs"].items()):
                due = next_at.setdefault(rid, now)
                if now >= due:
                    flat = []
                    for name in recipe.names:
                        v = self._value(name, now)
                        flat.extend(v if isinstance(v, list) else [v])
                    try:
                        send("U", bytes([rid]) + struct.pack(recipe.fmt, *flat))
                    except OSError:
                        return
                    next_at[rid] = max(due + 1.0 / recipe.frequency, now)
            time.sleep(max(0.0, min(next_at.values()) - self.now()))

    def stop(self) -> None:
        """Close the listening socket and every connection (a lost robot, as the clients see it)."""
        self._stop.set()
        for s in [self._listen, *self._socks]:
            try:
                if s is not self._listen:
                    s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            try:
                s.close()
            except OSError:
                pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()


def _read(conn: socket.socket, n: int) -> bytes:
    out = b""
    while len(out) < n:
        chunk = conn.recv(n - len(out))
        if not chunk:
            raise ConnectionError("client closed")
        out += chunk
    return out


def _child(conn, host: str, port: int, options: dict) -> None:
    """The child process of :class:`ServerProcess`: one server, answering the parent's calls."""
    try:
        server = RtdeServer(host, port, **options)
    except Exception as exc:  # noqa: BLE001 - reported to the parent
        conn.send((False, f"{type(exc).__name__}: {exc}"))
        return
    conn.send((True, (server.host, server.port)))
    while not server._stop.is_set():
        if not conn.poll(0.2):
            continue
        try:
            name, args = conn.recv()
        except EOFError:
            break
        if name == "stop":
            server.stop()
            conn.send(None)
            break
        value = getattr(server, name)
        conn.send(value(*args) if callable(value) else value)
    server.stop()


class ServerProcess:
    """An :class:`RtdeServer` in a child process, and a proxy to its records.

    ``ur-rtde``'s constructors hold the Python GIL while they wait for the server's answers, so a
    server running in the client's own process never answers: the peer runs in its own process
    (``spawn``). Attributes and methods of the server are read with :meth:`call`; the common ones
    are properties here. The child ends with the server's ``lifetime_s`` or :meth:`stop`.
    """

    def __init__(self, host: str, port: int = RTDE_PORT, **options):
        import multiprocessing

        ctx = multiprocessing.get_context("spawn")
        self._lock = threading.Lock()
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_child, args=(child, host, port, options), daemon=True,
                                 name="rtde-server")
        self._proc.start()
        if not self._conn.poll(30.0):
            self._proc.kill()
            raise RuntimeError("the RTDE test server did not start within 30 s")
        ok, info = self._conn.recv()
        if not ok:
            raise RuntimeError(f"the RTDE test server did not start: {info}")
        self.host, self.port = info

    def call(self, name: str, *args):
        with self._lock:
            if not self._proc.is_alive():
                raise RuntimeError("the RTDE test server has stopped")
            self._conn.send((name, args))
            if not self._conn.poll(10.0):
                raise RuntimeError(f"the RTDE test server did not answer {name}")
            return self._conn.recv()

    sliders = property(lambda self: self.call("sliders"))
    inputs = property(lambda self: self.call("inputs"))
    messages = property(lambda self: self.call("messages"))
    outputs_asked = property(lambda self: self.call("outputs_asked"))
    connections = property(lambda self: self.call("connections"))
    slider = property(lambda self: self.call("slider"))

    def now(self) -> float:
        return self.call("now")

    def joints_at(self, t: float):
        return self.call("joints_at", t)

    def stop(self) -> None:
        """Stop the server (every connection closes: a lost robot) and end the child."""
        with self._lock:
            if self._proc.is_alive():
                try:
                    self._conn.send(("stop", ()))
                    self._conn.poll(5.0)
                except (OSError, EOFError):
                    pass
            self._proc.join(5.0)
            if self._proc.is_alive():
                self._proc.kill()
                self._proc.join(2.0)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()
