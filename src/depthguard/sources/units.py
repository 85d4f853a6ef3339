"""``units:ENDPOINT`` — the voxels of the distributed camera units, read from the fusion server (R20, R29).

A camera unit (``depthguard node``) filters its own camera (robot removed at the
frame's capture joints when it has a joint stream, R30) and sends its voxels of
unknown objects to the fusion server (``depthguard server``). This source is a
zenoh peer connected to the server's ``ENDPOINT`` (``units:tcp/127.0.0.1:7447``;
an empty argument means that default) that polls the server's ``<prefix>/units/*``
queryable (:meth:`depthguard.distributed.server.FusionServer.units_replies`) on a
thread, ``poll_hz`` times a second, and keeps each unit's newest voxel set. Sets it
already holds are answered "unchanged" without their voxels, so a poll costs
little when nothing is new.

It serves a frame source's interface with no frames (``frames_until(t) -> []``)
and, for the monitor, ``voxels_until(t) -> [(camera_id, centres (N, 3) float64
world m, voxel_size m, stamp s)]``: per unit camera, its newest set captured at
or before ``t`` not returned yet (an older set not taken in time is replaced,
counted in ``replaced``). ``camera_ids`` are the cameras the server accepts (its
rig's), asked when the source opens. ``done`` turns True when closed; ``lost``
holds a sentence when the polling thread failed.

Clock: ``stamp`` is the capture stamp the unit sent, on the unit's frame source's
clock; the monitor compares it with its own clock (a unit's staleness is its
camera's, R27), so the units must stamp frames on the monitor's clock (a unit with
a joint stream does: its frames are interpolated against the monitor's joint
stamps). The server answers only for units it holds fresh (an update within its
``stale_s``); a unit that stops sending is then no longer answered and its last
set, kept by the monitor, grows old until the robot stops.

Context keys (``open_source(spec, rig, context)``): ``units_prefix`` (default
``"depthguard"``), ``units_poll_hz`` (default 100), ``units_timeout_s`` (seconds to
wait for the server at open, default 5), ``units_listen`` (own endpoints, default
``tcp/127.0.0.1:0``), ``units_session`` (a shared zenoh session), ``units_keys`` (a
certificate directory of the cell, ``depthguard keys admin``: the link is Zenoh's mutual
TLS and the status request is signed, for a server started with ``--keys``; the
endpoint is then ``tls/HOST:PORT``, R35).

States (issue 29): units started with ``--states`` publish each frame's depth grid state on
``<prefix>/states/<camera>`` (:mod:`depthguard.transport.state_wire`), which the fusion server
passes on to ``<prefix>/relay/states/<camera>`` (:mod:`depthguard.distributed.state_relay`); the
source subscribes to those, decodes each on arrival (in Zenoh's callback: the decode is the monitor's share of a
remote frame) and ``states_until(t) -> [UnitState]`` returns per camera the newest state
captured at or before ``t`` not returned yet (an older one not taken in time is counted in
``states_replaced``). A message that cannot be decoded (truncated, another wire version, a
corrupted head, values out of range), whose camera is not the one of its key or not in the
server's rig, or (with keys) not signed by that camera's certificate, is refused: counted
by reason in ``states_refused`` (``malformed``, ``wrong_camera``, ``auth``), the sentence in
``states_last_refusal``. The monitor checks the rest (its options, the camera's role, the
joints: :mod:`depthguard.runtime.unit_states`).

Talks to the server through :mod:`depthguard.transport` (the client, wire format and
keys the camera units use too), imported at open.
"""

from __future__ import annotations

import math
import threading
import time
from typing import Sequence

import numpy as np

from depthguard.sources.base import register_source

__all__ = ["UnitsSource", "open_units"]


class UnitsSource:
    """Voxels of the camera units from a fusion server (module docstring)."""

    first_stamp = None          # a live source has no recorded start
    live = True                 # stamps on the wall clock (time.time()): the runner's clock is then too

    def __init__(self, endpoint: str, rig=None, *, prefix: str = "depthguard", poll_hz: float = 100.0,
                 timeout_s: float = 5.0, listen: Sequence[str] | None = ("tcp/127.0.0.1:0",), session=None,
                 identity=None):
        from depthguard.transport import wire
        from depthguard.transport.client import ServerClient, ServerUnavailable
        from depthguard.transport.settings import check_endpoint

        if not (math.isfinite(poll_hz) and poll_hz > 0):
            raise ValueError(f"units: poll_hz must be > 0 (got {poll_hz!r})")
        self.endpoint = check_endpoint(endpoint)
        self._wire = wire
        if identity is not None:
            listen = None                    # with certificates: no listener of our own (ServerClient)
        self._client = ServerClient([self.endpoint], listen, prefix, session=session, identity=identity)
        self.keys = self._client.keys
        try:
            status = self._client.wait_for_server(timeout_s)
        except ServerUnavailable:
            self._client.close()
            raise ValueError(f"units:{endpoint}: no fusion server answered within {timeout_s:g} s") from None
        self.camera_ids: list[str] = list(status.get("cameras") or [n["camera"] for n in status["nodes"]])
        self.rig = rig
        self.poll_s = 1.0 / float(poll_hz)
        self._lock = threading.Lock()
        self._pending: dict[str, tuple[np.ndarray, float, float]] = {}
        self._known: dict[str, tuple[int, float]] = {}
        self.received = 0            # sets received (with their voxels)
        self.replaced = 0            # sets replaced by a newer one before voxels_until took them
        self.rejected = 0            # replies that could not be decoded
        self.last_error: str | None = None
        self.polls = 0
        self._lost: str | None = None
        self._stop = threading.Event()
        self._states: dict = {}          # camera -> newest UnitState not taken yet
        self.states_received = 0
        self.states_replaced = 0
        self.states_refused: dict[str, int] = {}
        self.states_last_refusal: str | None = None
        self.decode_s: list[float] = []  # seconds per decoded state (the bench's units.combine_ms)
        self._verifier = getattr(self._client, "_verifier", None)
        self._state_sub = self._client.session.declare_subscriber(self.keys.state_relay("*"), self._on_state)
        self._thread = threading.Thread(target=self._run, name=f"depthguard-units-{endpoint}", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------ states (issue 29)
    def _refuse_state(self, reason: str, text: str) -> None:
        with self._lock:
            self.states_refused[reason] = self.states_refused.get(reason, 0) + 1
            self.states_last_refusal = text

    def take_state(self, data: bytes, key: str):
        """Decode and check one state message that came on ``key``: the UnitState, or None when
        refused (counted, module docstring). Also the subscriber's callback body."""
        from depthguard.transport.state_wire import StateWireError, decode_state

        t0 = time.perf_counter()
        cam_key = key.rsplit("/", 1)[-1]
        key = self.keys.states(cam_key) if key == self.keys.state_relay(cam_key) else key   # the unit's key
        if self._verifier is not None:
            from depthguard.transport.auth import AuthError
            try:
                signed = self._verifier.open(data, key)
            except AuthError as exc:
                self._refuse_state("auth", f"state on {key}: {exc}")
                return None
            from depthguard.transport.keys import ROLE_NODE
            if signed.role != ROLE_NODE or signed.name != cam_key:
                self._refuse_state("auth", f"state on {key} signed by {signed.role}/{signed.name}, not by camera "
                                           f"{cam_key!r}'s unit")
                return None
            data = signed.message
        try:
            st = decode_state(data)
        except StateWireError as exc:
            self._refuse_state("malformed", f"state on {key}: {exc}")
            return None
        if st.camera != cam_key or st.camera not in self.camera_ids:
            self._refuse_state("wrong_camera", f"state on {key} names camera {st.camera!r}"
                               + ("" if st.camera == cam_key else f", not {cam_key!r}")
                               + ("" if st.camera in self.camera_ids else " (not in the server's rig)"))
            return None
        with self._lock:
            if st.camera in self._states:
                self.states_replaced += 1
            self._states[st.camera] = st
            self.states_received += 1
            self.decode_s.append(time.perf_counter() - t0)
            if len(self.decode_s) > 4096:
                del self.decode_s[:2048]
        return st

    def _on_state(self, sample) -> None:
        try:
            self.take_state(sample.payload.to_bytes(), str(sample.key_expr))
        except Exception as exc:  # noqa: BLE001 - a callback must not raise; counted
            self._refuse_state("error", f"state on {sample.key_expr}: {type(exc).__name__}: {exc}")

    def states_until(self, t: float) -> list:
        """Per unit camera its newest state (a :class:`~depthguard.transport.state_wire.UnitState`)
        captured at or before ``t`` (s) not returned yet."""
        with self._lock:
            out = [st for st in self._states.values() if st.stamp <= t]
            for st in out:
                del self._states[st.camera]
        return out

    # ------------------------------------------------------------ polling thread
    def poll_once(self, timeout: float = 1.0) -> int:
        """One query of every fresh unit's voxels; the number of new sets received."""
        wire = self._wire
        with self._lock:
            known = dict(self._known)
        replies = self._client.session.get(self.keys.units("*"), payload=wire.units_request(known), timeout=timeout)
        new = 0
        for r in replies:
            if r.ok is None:
                with self._lock:
                    self.rejected += 1
                    try:
                        self.last_error = wire.decode(r.err.payload.to_bytes()).text
                    except Exception:  # noqa: BLE001 - an undecodable error is still an error
                        self.last_error = "the server answered with an error"
                continue
            try:
                m = wire.decode(r.ok.payload.to_bytes(), expect=wire.MsgType.UNITS_REP)
            except wire.WireError as exc:
                with self._lock:
                    self.rejected += 1
                    self.last_error = f"{r.ok.key_expr}: {exc}"
                continue
            if m.flags & 1:                      # unchanged: we hold it already
                continue
            centres = (m.keys.astype(np.float64) + 0.5) * m.voxel_size
            with self._lock:
                if m.camera in self._pending:
                    self.replaced += 1
                self._pending[m.camera] = (centres, float(m.voxel_size), float(m.stamp))
                self._known[m.camera] = (m.version, m.stamp)
                self.received += 1
            new += 1
        with self._lock:
            self.polls += 1
        return new

    def _run(self) -> None:
        while not self._stop.is_set():
            t0 = time.monotonic()
            try:
                self.poll_once(timeout=max(self.poll_s * 10, 0.5))
            except Exception as exc:  # noqa: BLE001 - reported, the units go stale at the monitor
                if self._stop.is_set():
                    return
                self._lost = f"units:{self.endpoint}: polling the fusion server failed: {type(exc).__name__}: {exc}"
                return
            self._stop.wait(max(0.0, self.poll_s - (time.monotonic() - t0)))

    # ------------------------------------------------------------ the source interface
    def voxels_until(self, t: float) -> list[tuple[str, np.ndarray, float, float]]:
        """Per unit camera its newest set with stamp <= ``t`` (s) not returned yet:
        ``[(camera_id, centres (N, 3) float64 world m, voxel_size m, stamp s)]``."""
        out = []
        with self._lock:
            for cam in list(self._pending):
                centres, s, stamp = self._pending[cam]
                if stamp <= t:
                    out.append((cam, centres, s, stamp))
                    del self._pending[cam]
        return out

    def frames_until(self, t: float) -> list:
        """No depth frames: the units send voxels (:meth:`voxels_until`)."""
        return []

    @property
    def done(self) -> bool:
        return self._stop.is_set()

    @property
    def lost(self) -> str | None:
        return self._lost

    def close(self) -> None:
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join(5.0)
        try:
            self._state_sub.undeclare()
        except Exception:  # noqa: BLE001 - closing anyway
            pass
        self._client.close()


@register_source("units")
def open_units(argument: str, rig, context: dict) -> UnitsSource:
    """Factory of ``units:ENDPOINT`` (module docstring; ``ENDPOINT`` default ``tcp/127.0.0.1:7447``)."""
    from depthguard.transport.settings import DEFAULT_ENDPOINT

    identity = None
    if context.get("units_keys"):
        from depthguard.transport.keys import load_identity

        identity = load_identity(context["units_keys"])
    return UnitsSource(argument or DEFAULT_ENDPOINT, rig, prefix=context.get("units_prefix", "depthguard"),
                       poll_hz=float(context.get("units_poll_hz", 100.0)),
                       timeout_s=float(context.get("units_timeout_s", 5.0)),
                       listen=context.get("units_listen", ("tcp/127.0.0.1:0",)),
                       session=context.get("units_session"), identity=identity)
