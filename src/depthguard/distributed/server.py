"""The fusion server (main unit) of the distributed camera subsystem (Oščádal 2022, R20).

Zenoh queryables under ``<prefix>/``:

* ``init``    INIT_REQ(camera id, address) → INIT_REP(unit id, settings). A camera
  seen before (a restarted node) gets its old id and keeps its storage; a camera id
  that is not in the rig is refused (ERROR_REP) and logged.
* ``update``  UPDATE_REQ(unit id, voxels, capture stamp) → UPDATE_REP(settings):
  replaces that unit's voxels and records the receive time ``T_update``.
* ``status``  STATUS_REQ → STATUS_REP (JSON, see :meth:`FusionServer.status`).
* ``settings`` SETTINGS_REQ(JSON changes) → STATUS_REP; the new settings reach every
  node in its next reply.
* ``units/*`` UNITS_REQ(sets held: camera → version, stamp) → one UNITS_REP per
  **fresh** unit, on ``<prefix>/units/<camera>`` (query ``units/*`` for all, or
  ``units/<camera>`` for one): its camera id, voxel keys and size, capture stamp and
  version (the unit's update count); a set the asker already holds is answered
  "unchanged", without keys. Stale and departed units are not answered. This is how
  the monitor reads the units (:mod:`depthguard.sources.units`). A set larger than one
  reply holds is coarsened conservatively (:func:`~depthguard.fusion.voxels.regrid`).

Join and leave: each node holds the liveliness token ``<prefix>/alive/<camera>``;
its disappearance (a killed process at once, a frozen one after the 1 s lease) marks
the unit *left* and drops its voxels. The global map is the union of the voxels of
units whose data are fresh, ``T_now − T_update < stale_s``; stale and departed
units are left out and reported (R20, R27).

Malformed, oversized or unexpected messages are answered with ERROR_REP and counted
(``rejected``); the server keeps running.

Trust (R35, ``docs/THREAT_MODEL.md``). With an ``identity`` (``--keys``) the server
listens only on ``tls/`` endpoints with mutual certificates of the cell's authority,
and every request must be signed (:mod:`depthguard.transport.auth`): INIT and
UPDATE by a node certificate naming the camera they are for, STATUS and SETTINGS by
an administrator certificate. Anything else is refused (ERROR_REP ``ERR_AUTH``),
counted in ``refused`` and logged with the reason; replies are signed by the server.
Without an identity the server listens on loopback only unless ``insecure``.

Restarts. With a ``registry`` file the camera → unit id assignment survives a
restart (:mod:`depthguard.distributed.registry`); a node re-initialises by itself
(its update to an id not initialised in this run is refused with ERR_UNKNOWN_UNIT)
and gets its old id back.
"""

from __future__ import annotations

import json
import threading
import time
from collections import deque
from dataclasses import replace
from typing import Callable, Sequence

import numpy as np

from depthguard.distributed.server_units import (ERR_AUTH, ERR_BAD_SETTINGS, ERR_MALFORMED,  # noqa: F401
                                                  ERR_REFUSED, ERR_UNKNOWN_UNIT, RATE_WINDOW_S, Unit,
                                                  clean_setting_changes, fit_one_reply)
from depthguard.fusion.voxels import VoxelSet, union
from depthguard.transport import wire
from depthguard.transport.settings import DEFAULT_ENDPOINT, DEFAULT_LEASE_MS, Keys, check_exposure, zenoh_config

__all__ = ["FusionServer", "Unit", "ERR_REFUSED", "ERR_MALFORMED", "ERR_UNKNOWN_UNIT", "ERR_BAD_SETTINGS",
           "ERR_AUTH"]


class FusionServer:
    """Main unit: node registry, voxel storage, freshness, global map (R20).

    Parameters
    ----------
    cameras : camera ids allowed to join (the rig's cameras).
    settings : initial :class:`~depthguard.transport.wire.Settings`.
    listen / connect : zenoh endpoints (default ``tcp/127.0.0.1:7447``).
    multicast : enable zenoh multicast scouting (off by default).
    log : ``str -> None`` for refused / rejected messages and joins / leaves.
    identity : the server's :class:`~depthguard.transport.keys.Identity` (mutual TLS +
        signed messages, module docstring) or None (loopback only unless ``insecure``).
    registry : path of the camera → unit id file (kept across restarts) or None.
    """

    def __init__(self, cameras: Sequence[str], settings: wire.Settings | None = None, *,
                 listen: Sequence[str] = (DEFAULT_ENDPOINT,), connect: Sequence[str] = (),
                 prefix: str = "depthguard", multicast: bool = False, lease_ms: int = DEFAULT_LEASE_MS,
                 log: Callable[[str], None] | None = None, identity=None, insecure: bool = False,
                 registry=None, auth_window_s: float = 30.0):
        self.cameras = list(cameras)
        if not self.cameras:
            raise ValueError("the server needs at least one camera id (from the rig)")
        self.settings = (settings or wire.Settings()).check()
        self.keys = Keys(prefix)
        check_exposure(listen, connect, identity, insecure)
        self.listen = list(listen)
        self.identity = identity
        self._signer = self._verifier = None
        if identity is not None:
            from depthguard.transport.auth import Signer, Verifier
            from depthguard.transport.keys import ROLE_SERVER

            if identity.role != ROLE_SERVER:
                raise ValueError(f"--keys {identity.directory}: the server needs the server's certificate "
                                 f"(a directory made by `depthguard keys init`), not a {identity.role} one")
            self._signer, self._verifier = Signer(identity), Verifier(identity.ca_cert, auth_window_s)
        self._conf = zenoh_config(listen, connect, multicast, lease_ms, identity=identity)
        from depthguard.distributed.registry import Registry

        self.registry = Registry(registry)
        self._log = log or (lambda m: None)
        self._lock = threading.RLock()
        self.units: dict[str, Unit] = {}
        self._alive: set[str] = set()
        self.rejected = 0
        self.refused = 0
        self._bytes: deque[tuple[float, int]] = deque()
        self._session = None
        self._decls: list = []
        self.on_update: Callable[[Unit], None] | None = None   # hook (bench: refresh timing)

    # -------------------------------------------------------------- lifecycle
    def start(self) -> "FusionServer":
        import zenoh

        try:
            self._session = zenoh.open(self._conf)
        except zenoh.ZError as exc:
            text = str(exc)
            if "in use" in text.lower():
                raise ValueError(f"cannot listen on {', '.join(self.listen)}: the address is already in use "
                                 f"(another depthguard server?). Stop it, or choose another port with "
                                 f"--listen tcp/127.0.0.1:PORT") from None
            raise ValueError(f"cannot open the server's Zenoh session on {', '.join(self.listen)}: {text}") from None
        s, k = self._session, self.keys
        self._decls = [
            s.liveliness().declare_subscriber(k.alive("*"), self._on_liveliness, history=True),
            s.declare_queryable(k.init, self._guard(self._on_init)),
            s.declare_queryable(k.update, self._guard(self._on_update)),
            s.declare_queryable(k.status, self._guard(self._on_status)),
            s.declare_queryable(k.settings, self._guard(self._on_settings)),
            s.declare_queryable(k.units("*"), self._on_units),
        ]
        return self

    def close(self) -> None:
        for d in self._decls:
            try:
                d.undeclare()
            except Exception:  # noqa: BLE001 - closing anyway
                pass
        self._decls = []
        if self._session is not None:
            self._session.close()
            self._session = None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.close()

    @property
    def session(self):
        return self._session

    # ---------------------------------------------------------------- settings
    def set_settings(self, **changes) -> wire.Settings:
        """Change settings (voxel_size, threshold, stale_s, offset_const, offset_k, joints);
        the epoch increases and the new values go out with every following reply."""
        clean = clean_setting_changes(changes)
        with self._lock:
            new = replace(self.settings, epoch=self.settings.epoch + 1, **clean)
            try:
                new.check()
            except wire.WireError as exc:
                raise ValueError(str(exc)) from None
            self.settings = new
        self._log(f"settings epoch {new.epoch}: {clean}")
        return new

    # ---------------------------------------------------------------- queries
    def _refuse(self, text: str, code: int = ERR_AUTH) -> bytes:
        """Count, log and answer a refusal (R35)."""
        with self._lock:
            self.refused += 1
        self._log(f"refused: {text}")
        return wire.error_reply(code, text)

    def _guard(self, fn):
        """Wrap a queryable callback: check the envelope (with an identity), then ``fn(data, who)``;
        bad input → ERROR_REP + counted; never raises."""
        from depthguard.transport.auth import NO_NONCE, AuthError

        def cb(query):
            payload = query.payload
            data = payload.to_bytes() if payload is not None else b""
            key = str(query.key_expr)
            nonce = NO_NONCE
            try:
                who = None
                if self._verifier is not None:
                    try:
                        who = self._verifier.open(data, key)
                        data, nonce = who.message, who.nonce
                    except AuthError as exc:
                        who = exc
                reply = (self._refuse(f"message on {key}: {who}") if isinstance(who, AuthError)
                         else fn(data, who))
            except wire.WireError as exc:
                with self._lock:
                    self.rejected += 1
                self._log(f"rejected message on {query.key_expr}: {exc}")
                reply = wire.error_reply(ERR_MALFORMED, str(exc))
            except Exception as exc:  # noqa: BLE001 - the server must keep running
                with self._lock:
                    self.rejected += 1
                self._log(f"error handling {query.key_expr}: {type(exc).__name__}: {exc}")
                reply = wire.error_reply(ERR_MALFORMED, f"{type(exc).__name__}: {exc}")
            try:
                if self._signer is not None:
                    reply, _ = self._signer.seal(reply, key, reply_to=nonce)
                query.reply(query.key_expr, reply)
            except Exception as exc:  # noqa: BLE001
                self._log(f"reply failed on {query.key_expr}: {exc}")
        return cb

    def _role_check(self, who, role: str, what: str) -> str | None:
        """None when ``who`` (an opened envelope, or None without identity) may do ``what``;
        else the sentence to refuse with."""
        if who is None:
            return None
        if who.role != role:
            return f"{what} needs a {role} certificate; {who.role}/{who.name} may not"
        return None

    def _on_init(self, data: bytes, who=None) -> bytes:
        from depthguard.transport.keys import ROLE_NODE

        m = wire.decode(data, expect=wire.MsgType.INIT_REQ)
        bad = self._role_check(who, ROLE_NODE, f"joining as camera {m.camera!r}")
        if bad is None and who is not None and who.name != m.camera:
            bad = f"certificate of camera {who.name!r} cannot join as camera {m.camera!r}"
        if bad is not None:
            return self._refuse(f"{bad} (address {m.address!r})")
        with self._lock:
            if m.camera not in self.cameras:
                self.refused += 1
                self._log(f"refused unknown camera {m.camera!r} from {m.address!r}")
                return wire.error_reply(ERR_REFUSED, f"camera {m.camera!r} is not in the rig")
            u = self.units.get(m.camera)
            if u is None:
                u = Unit(self.registry.assign(m.camera), m.camera, m.address, alive=m.camera in self._alive,
                         voxel_size=self.settings.voxel_size)
                self.units[m.camera] = u
                self._log(f"unit {u.id} joined: camera {m.camera} at {m.address}")
            else:
                u.inits += 1
                u.address = m.address
                u.alive = m.camera in self._alive
                self._log(f"unit {u.id} re-initialised: camera {m.camera} at {m.address}")
            return wire.init_reply(u.id, self.settings)

    def _unit_by_id(self, uid: int) -> Unit | None:
        for u in self.units.values():
            if u.id == uid:
                return u
        return None

    def _on_update(self, data: bytes, who=None) -> bytes:
        from depthguard.transport.keys import ROLE_NODE

        now = time.monotonic()
        m = wire.decode(data, expect=wire.MsgType.UPDATE_REQ)
        bad = self._role_check(who, ROLE_NODE, f"an update of unit id {m.unit_id}")
        if bad is not None:
            return self._refuse(bad)
        with self._lock:
            u = self._unit_by_id(m.unit_id)
            if u is None:
                self.refused += 1
                self._log(f"refused update from unknown unit id {m.unit_id}"
                          + ("" if who is None else f" (certificate of camera {who.name!r})"))
                return wire.error_reply(ERR_UNKNOWN_UNIT, f"unit id {m.unit_id} is not initialised")
            if who is not None and who.name != u.camera:
                self.refused += 1
                self._log(f"refused: certificate of camera {who.name!r} sent an update for unit id "
                          f"{m.unit_id}, which is camera {u.camera!r}")
                return wire.error_reply(ERR_AUTH, f"unit id {m.unit_id} is not camera {who.name!r}")
            if u.updates and m.seq > u.seq + 1:
                u.lost += m.seq - u.seq - 1
            u.keys, u.counts, u.voxel_size = m.keys, m.counts, m.voxel_size
            u.stamp, u.seq, u.t_update = m.stamp, m.seq, now
            u.invalid_frac = m.invalid_frac
            u.updates += 1
            self._bytes.append((now, len(data)))
            while now - self._bytes[0][0] > RATE_WINDOW_S:     # bounded without status queries
                self._bytes.popleft()
            token_missing = not u.alive
            reply = wire.update_reply(self.settings, token_missing=token_missing)
        if self.on_update is not None:
            self.on_update(u)
        return reply

    def local_update(self, camera: str, keys: np.ndarray, counts: np.ndarray, voxel_size: float,
                     stamp: float, address: str = "local", invalid_frac: float = float("nan")) -> Unit:
        """Centralised mode: store a camera's voxels computed in this process (no network);
        the unit counts as present while this is called."""
        if camera not in self.cameras:
            raise ValueError(f"camera {camera!r} is not in the rig")
        now = time.monotonic()
        with self._lock:
            u = self.units.get(camera)
            if u is None:
                u = Unit(self.registry.assign(camera), camera, address)
                self.units[camera] = u
            u.alive = True
            self._alive.add(camera)
            u.keys, u.counts, u.voxel_size = np.asarray(keys), np.asarray(counts), float(voxel_size)
            u.stamp, u.t_update = float(stamp), now
            u.invalid_frac = float(invalid_frac)
            u.seq += 1
            u.updates += 1
        return u

    def _on_status(self, data: bytes, who=None) -> bytes:
        from depthguard.transport.keys import ROLE_ADMIN

        wire.decode(data, expect=wire.MsgType.STATUS_REQ)
        bad = self._role_check(who, ROLE_ADMIN, "the status")
        if bad is not None:
            return self._refuse(bad)
        return wire.status_reply(self.status())

    def _on_settings(self, data: bytes, who=None) -> bytes:
        from depthguard.transport.keys import ROLE_ADMIN

        m = wire.decode(data, expect=wire.MsgType.SETTINGS_REQ)
        bad = self._role_check(who, ROLE_ADMIN, "changing settings")
        if bad is not None:
            return self._refuse(f"{bad} (asked {m.text[:200]!r})")
        try:
            changes = json.loads(m.text)
            self.set_settings(**changes)
        except (ValueError, TypeError) as exc:
            with self._lock:
                self.rejected += 1
            self._log(f"rejected settings {m.text[:200]!r}: {exc}")
            return wire.error_reply(ERR_BAD_SETTINGS, str(exc))
        return wire.status_reply(self.status())

    def units_replies(self, known=None, cameras=None) -> list[tuple[str, bytes]]:
        """``[(camera, UNITS_REP bytes)]`` for every fresh unit (of ``cameras``, default all):
        "unchanged" for a set whose (version, stamp) is in ``known``."""
        known = known or {}
        now = time.monotonic()
        with self._lock:
            units = [(u.camera, u.id, u.updates, u.seq, u.stamp, u.voxel_size, u.keys, u.invalid_frac)
                     for u in self.units.values()
                     if self.unit_state(u, now) == "fresh" and (cameras is None or u.camera in cameras)]
        out = []
        for cam, uid, version, seq, stamp, vs, keys, inv in units:
            same = known.get(cam) == (version & 0xFFFFFFFF, stamp)
            if not same:
                keys, vs = fit_one_reply(keys, vs)
            try:
                out.append((cam, wire.units_reply(cam, uid, version, seq, stamp, vs, keys,
                                               inv if inv == inv else 0.0, unchanged=same)))
            except wire.WireError as exc:
                self._log(f"units: cannot send camera {cam}'s voxels: {exc}")
        return out

    def _on_units(self, query) -> None:
        """Queryable ``<prefix>/units/*`` (module docstring); errors go back as ``reply_err``."""
        import zenoh

        try:
            payload = query.payload
            m = wire.decode(payload.to_bytes() if payload is not None else b"", expect=wire.MsgType.UNITS_REQ)
            asked = zenoh.KeyExpr(str(query.key_expr))
            tail = str(query.key_expr)[len(f"{self.keys.prefix}/units/"):]
            one = None if any(ch in tail for ch in "*$") else {tail}     # one camera asked: encode only it
            for cam, msg in self.units_replies(m.known, one):
                try:
                    key = self.keys.units(cam)
                except ValueError as exc:           # a rig camera id that cannot name a key
                    self._log(f"units: {exc}")
                    continue
                if asked.intersects(zenoh.KeyExpr(key)):
                    query.reply(key, msg)
        except wire.WireError as exc:
            with self._lock:
                self.rejected += 1
            self._log(f"rejected message on {query.key_expr}: {exc}")
            try:
                query.reply_err(wire.error_reply(ERR_MALFORMED, str(exc)))
            except Exception as exc2:  # noqa: BLE001
                self._log(f"reply failed on {query.key_expr}: {exc2}")
        except Exception as exc:  # noqa: BLE001 - the server must keep running
            with self._lock:
                self.rejected += 1
            self._log(f"error handling {query.key_expr}: {type(exc).__name__}: {exc}")

    def _on_liveliness(self, sample) -> None:
        import zenoh

        key = str(sample.key_expr)
        cam = key.rsplit("/", 1)[-1]
        if cam not in self.cameras:
            self._log(f"liveliness token of unknown camera {cam!r} ignored")
            return
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self._alive.add(cam)
                u = self.units.get(cam)
                if u is not None:
                    u.alive = True
                self._log(f"liveliness: camera {cam} present")
            else:
                self._alive.discard(cam)
                u = self.units.get(cam)
                if u is not None:
                    u.alive = False
                    u.keys = np.zeros((0, 3), np.int32)      # drop a departed unit's voxels
                    u.counts = np.zeros(0, np.int32)
                self._log(f"liveliness: camera {cam} left")

    # ---------------------------------------------------------------- merging
    def unit_state(self, u: Unit, now: float | None = None) -> str:
        """``"fresh"`` | ``"stale"`` | ``"left"`` (R20: ``T_now − T_update < stale_s``)."""
        now = time.monotonic() if now is None else now
        if not u.alive:
            return "left"
        if u.t_update is None or now - u.t_update >= self.settings.stale_s:
            return "stale"
        return "fresh"

    def global_map(self) -> tuple[np.ndarray, float]:
        """(M, 3) int64 keys of the union of the fresh units' voxels, and the voxel size (m)."""
        now = time.monotonic()
        with self._lock:
            s = self.settings.voxel_size
            sets = [VoxelSet(u.keys, u.counts, u.voxel_size) for u in self.units.values()
                    if self.unit_state(u, now) == "fresh"]
        return union(sets, s), s

    def bytes_per_s(self, now: float | None = None) -> float:
        now = time.monotonic() if now is None else now
        with self._lock:
            while self._bytes and now - self._bytes[0][0] > RATE_WINDOW_S:
                self._bytes.popleft()
            return sum(b for _, b in self._bytes) / RATE_WINDOW_S

    def status(self) -> dict:
        """The server's view: ``{"cameras": [rig camera ids], "missing": [rig cameras that never
        joined since this server started], "nodes": [{"camera", "id", "state",
        "age_s", "voxels", "invalid_frac", ...}],
        "voxels_total", "bytes_per_s", "rejected", "refused", "settings"}``."""
        now = time.monotonic()
        keys, s = self.global_map()
        with self._lock:
            nodes = []
            for u in sorted(self.units.values(), key=lambda u: u.id):
                state = self.unit_state(u, now)
                nodes.append({
                    "camera": u.camera, "id": u.id, "state": state,
                    "age_s": None if u.t_update is None else round(now - u.t_update, 4),
                    "voxels": int(len(u.keys)) if state == "fresh" else 0,
                    "voxel_size": u.voxel_size, "address": u.address,
                    "invalid_frac": None if u.invalid_frac != u.invalid_frac else round(u.invalid_frac, 4),
                    "updates": u.updates, "inits": u.inits, "lost": u.lost,
                })
            st = self.settings
            return {
                "cameras": list(self.cameras),
                "missing": [c for c in self.cameras if c not in self.units],
                "nodes": nodes, "voxels_total": int(len(keys)), "voxel_size": s,
                "bytes_per_s": round(self.bytes_per_s(now), 1),
                "rejected": self.rejected, "refused": self.refused,
                "settings": {"epoch": st.epoch, "voxel_size": st.voxel_size, "threshold": st.threshold,
                             "stale_s": st.stale_s, "joints": list(st.joints)},
            }
