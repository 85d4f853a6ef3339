"""The wire format between camera nodes and the fusion server (R20).

A compact, versioned, size-limited binary format, little-endian::

    header  "DGW" | version u8 | type u8 | flags u8 | reserved u16 | body_len u32   (12 bytes)
    body    body_len bytes, by message type (below)
    trailer crc32 u32 over header + body

=====================  ==========================================================
INIT_REQ     (1)       cam_len u8, camera id (utf-8), addr_len u8, address (utf-8)
INIT_REP     (2)       unit_id u32, settings
UPDATE_REQ   (3)       unit_id u32, seq u32, stamp f64 (s, capture time), voxel_size f32 (m),
                       n u32, invalid_frac f32 (share of the image's pixels without a valid
                       measurement: R28, "cannot judge" there), keys n×3 int16, counts n×u16
                       (8 bytes per voxel)
UPDATE_REP   (4)       settings; flag bit 0 = the server does not see the node's liveliness token
ERROR_REP    (5)       code u16, msg_len u16, message (utf-8)
STATUS_REQ   (6)       empty
STATUS_REP   (7)       utf-8 JSON object
SETTINGS_REQ (8)       utf-8 JSON object of settings to change (voxel_size, threshold, ...)
UNITS_REQ    (9)       n u8, n × (cam_len u8, camera id, version u32, stamp f64): the sets the
                       asker already holds (empty: none)
UNITS_REP    (10)      cam_len u8, camera id, unit_id u32, version u32 (the server's update count
                       of that unit), seq u32, stamp f64 (s, capture time), voxel_size f32 (m),
                       invalid_frac f32, n u32, keys n×3 int16 (6 bytes per voxel); flag bit 0 =
                       unchanged since the version and stamp the request named (then n = 0)
=====================  ==========================================================

settings = epoch u32, voxel_size f32, threshold f32, stale_s f32, offset_const f32,
offset_k f32, n_joints u8, joints n×f64, then optionally the monitor's state options (issue 29:
what a unit that makes its camera's depth grid state must make it with, ``Settings.state``):
"SO" | robot_offset f64 (m) | invalid u8 | robot_in_others u8 (0 unknown, 1 free) |
silhouette_px u8 | gap_px u8 | principal camera id (len u8 + utf-8). A settings block without
it (an older server) decodes with ``state = ()``.

Every message is at most :data:`MAX_MESSAGE_BYTES`; :func:`decode` checks size,
magic, version, type, lengths, CRC and value ranges, and raises :class:`WireError`
(a ``ValueError``) naming what is wrong — it never returns a half-parsed message.
"""

from __future__ import annotations

import json
import math
import struct
import zlib
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

__all__ = ["WireError", "MsgType", "Settings", "Message", "encode", "decode",
           "init_request", "init_reply", "update_request", "update_reply", "error_reply",
           "status_request", "status_reply", "settings_request", "units_request", "units_reply",
           "MAX_MESSAGE_BYTES", "MAX_VOXELS", "MAX_UNIT_VOXELS", "VERSION", "BYTES_PER_VOXEL"]

MAGIC = b"DGW"
VERSION = 1
MAX_MESSAGE_BYTES = 1 << 20
_HDR = struct.Struct("<3sBBBHI")
_CRC = struct.Struct("<I")
_OVERHEAD = _HDR.size + _CRC.size
_UPD = struct.Struct("<IIdfIf")
BYTES_PER_VOXEL = 8
MAX_VOXELS = (MAX_MESSAGE_BYTES - _OVERHEAD - _UPD.size) // BYTES_PER_VOXEL
_SET = struct.Struct("<IfffffB")
_UNIT = struct.Struct("<IIIdffI")
_KNOWN = struct.Struct("<Id")
MAX_UNIT_VOXELS = (MAX_MESSAGE_BYTES - _OVERHEAD - _UNIT.size - 1 - 64) // 6
MAX_JOINTS = 32
MAX_ID_BYTES = 64
MAX_ADDR_BYTES = 200


class WireError(ValueError):
    """A message that cannot be decoded (or encoded): malformed, oversized or out of range."""


class MsgType(IntEnum):
    INIT_REQ = 1
    INIT_REP = 2
    UPDATE_REQ = 3
    UPDATE_REP = 4
    ERROR_REP = 5
    STATUS_REQ = 6
    STATUS_REP = 7
    SETTINGS_REQ = 8
    UNITS_REQ = 9
    UNITS_REP = 10


@dataclass(frozen=True)
class Settings:
    """What the server hands to every node with each reply (R20)."""
    epoch: int = 0
    voxel_size: float = 0.02
    threshold: float = 0.55
    stale_s: float = 0.5
    offset_const: float = float("nan")   # NaN = node uses its sensor's default offset
    offset_k: float = float("nan")
    joints: tuple[float, ...] = ()
    # issue 29: the monitor's StateOptions + principal camera id, () = none (units send voxels):
    # (robot_offset m, invalid "unknown"|"free", robot_in_others "unknown"|"free", silhouette_px, gap_px,
    # principal)
    state: tuple = ()

    def check(self) -> "Settings":
        if not (0.01 - 1e-6 <= self.voxel_size <= 0.1 + 1e-6):
            raise WireError(f"settings: voxel size {self.voxel_size * 1000:g} mm outside 10-100 mm")
        if not (0.0 <= self.threshold <= 1.0):
            raise WireError(f"settings: threshold {self.threshold} outside [0, 1]")
        if not (0.0 < self.stale_s <= 60.0):
            raise WireError(f"settings: stale_s {self.stale_s} outside (0, 60] s")
        for name in ("offset_const", "offset_k"):
            v = getattr(self, name)
            if not (math.isnan(v) or 0.0 <= v < 10.0):
                raise WireError(f"settings: {name} {v} must be NaN (default) or in [0, 10)")
        if len(self.joints) > MAX_JOINTS or not all(math.isfinite(q) for q in self.joints):
            raise WireError(f"settings: joints must be at most {MAX_JOINTS} finite values")
        if not (0 <= self.epoch < 2 ** 32):
            raise WireError(f"settings: epoch {self.epoch} out of range")
        if self.state:
            _check_state(self.state)
        return self


_STATE = struct.Struct("<2sdBBBB")
_POLICIES = ("unknown", "free")


def _check_state(st) -> None:
    """The state options of :class:`Settings` (issue 29), or :class:`WireError` naming the problem."""
    if len(st) != 6:
        raise WireError(f"settings: state options need 6 values (got {len(st)})")
    off, inv, rio, sil, gap, principal = st
    if not (isinstance(off, float) and math.isfinite(off) and 0.0 <= off <= 1.0):
        raise WireError(f"settings: state robot_offset {off!r} outside [0, 1] m")
    if inv not in _POLICIES or rio not in _POLICIES:
        raise WireError(f"settings: state invalid / robot_in_others must be 'unknown' or 'free' (got {inv!r}, {rio!r})")
    for name, v in (("silhouette_px", sil), ("gap_px", gap)):
        if not (isinstance(v, int) and 0 <= v <= 255):
            raise WireError(f"settings: state {name} {v!r} outside 0-255")
    if not isinstance(principal, str) or not principal or len(principal.encode("utf-8")) > MAX_ID_BYTES:
        raise WireError(f"settings: state principal camera id {principal!r} is empty or too long")


@dataclass
class Message:
    type: MsgType
    flags: int = 0
    camera: str = ""
    address: str = ""
    unit_id: int = 0
    seq: int = 0
    stamp: float = 0.0
    voxel_size: float = 0.0
    keys: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int16))
    counts: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint16))
    invalid_frac: float = 0.0
    settings: Settings | None = None
    code: int = 0
    text: str = ""          # error message, or JSON for STATUS_REP / SETTINGS_REQ
    version: int = 0        # UNITS_REP: the server's update count of the unit
    known: dict = field(default_factory=dict)   # UNITS_REQ: camera -> (version, stamp) held by the asker


# ------------------------------------------------------------------ encode
def _frame(mtype: MsgType, body: bytes, flags: int = 0) -> bytes:
    if len(body) + _OVERHEAD > MAX_MESSAGE_BYTES:
        raise WireError(f"{mtype.name}: message of {len(body) + _OVERHEAD} bytes exceeds "
                        f"the limit of {MAX_MESSAGE_BYTES}")
    head = _HDR.pack(MAGIC, VERSION, int(mtype), flags & 0xFF, 0, len(body))
    return head + body + _CRC.pack(zlib.crc32(head + body))


def _settings_bytes(s: Settings) -> bytes:
    s.check()
    out = _SET.pack(s.epoch, s.voxel_size, s.threshold, s.stale_s, s.offset_const, s.offset_k,
                    len(s.joints)) + np.asarray(s.joints, dtype="<f8").tobytes()
    if s.state:
        off, inv, rio, sil, gap, principal = s.state
        out += (_STATE.pack(b"SO", off, _POLICIES.index(inv), _POLICIES.index(rio), sil, gap)
                + _short_str("principal camera id", principal, MAX_ID_BYTES))
    return out


def _short_str(what: str, s: str, limit: int) -> bytes:
    b = s.encode("utf-8")
    if len(b) > limit:
        raise WireError(f"{what} longer than {limit} bytes")
    return struct.pack("<B", len(b)) + b


def init_request(camera: str, address: str) -> bytes:
    if not camera:
        raise WireError("camera id must not be empty")
    return _frame(MsgType.INIT_REQ, _short_str("camera id", camera, MAX_ID_BYTES)
                  + _short_str("address", address, MAX_ADDR_BYTES))


def init_reply(unit_id: int, settings: Settings) -> bytes:
    return _frame(MsgType.INIT_REP, struct.pack("<I", unit_id) + _settings_bytes(settings))


def update_request(unit_id: int, seq: int, stamp: float, voxel_size: float,
                   keys: np.ndarray, counts: np.ndarray, invalid_frac: float = 0.0) -> bytes:
    """UPDATE_REQ; keys (N, 3) int within int16, counts (N,) (saturated at 65535),
    invalid_frac in [0, 1] (share of invalid pixels)."""
    k = np.asarray(keys)
    c = np.asarray(counts)
    if k.ndim != 2 or k.shape[1] != 3 or c.shape != (k.shape[0],):
        raise WireError(f"keys must be (N, 3) and counts (N,), got {k.shape} and {c.shape}")
    if len(k) > MAX_VOXELS:
        raise WireError(f"{len(k)} voxels exceed the limit of {MAX_VOXELS} per update")
    if len(k) and (k.min() < -32768 or k.max() > 32767):
        raise WireError("voxel keys outside the int16 range of the wire format")
    if not math.isfinite(stamp):
        raise WireError("stamp must be finite")
    if not (0.0 <= invalid_frac <= 1.0):
        raise WireError(f"invalid_frac {invalid_frac} outside [0, 1]")
    if not (0.01 - 1e-6 <= voxel_size <= 0.8):
        raise WireError(f"voxel size {voxel_size} m outside the wire range 0.01-0.8 m")
    body = (_UPD.pack(unit_id, seq & 0xFFFFFFFF, stamp, voxel_size, len(k), invalid_frac)
            + k.astype("<i2").tobytes() + np.clip(c, 0, 65535).astype("<u2").tobytes())
    return _frame(MsgType.UPDATE_REQ, body)


def update_reply(settings: Settings, token_missing: bool = False) -> bytes:
    return _frame(MsgType.UPDATE_REP, _settings_bytes(settings), flags=1 if token_missing else 0)


def error_reply(code: int, text: str) -> bytes:
    b = text.encode("utf-8")[:1000]
    return _frame(MsgType.ERROR_REP, struct.pack("<HH", code, len(b)) + b)


def status_request() -> bytes:
    return _frame(MsgType.STATUS_REQ, b"")


def status_reply(obj: dict) -> bytes:
    return _frame(MsgType.STATUS_REP, json.dumps(obj).encode("utf-8"))


def settings_request(**changes) -> bytes:
    return _frame(MsgType.SETTINGS_REQ, json.dumps(changes).encode("utf-8"))


def units_request(known=None) -> bytes:
    """UNITS_REQ: ``known`` maps camera id -> (version, stamp) of the sets the asker holds; the
    server answers those still current with an empty "unchanged" UNITS_REP."""
    known = dict(known or {})
    if len(known) > 255:
        raise WireError(f"{len(known)} known units exceed the limit of 255")
    body = struct.pack("<B", len(known))
    for cam, (version, stamp) in known.items():
        if not math.isfinite(stamp):
            raise WireError("known stamp must be finite")
        body += _short_str("camera id", cam, MAX_ID_BYTES) + _KNOWN.pack(int(version) & 0xFFFFFFFF, float(stamp))
    return _frame(MsgType.UNITS_REQ, body)


def units_reply(camera: str, unit_id: int, version: int, seq: int, stamp: float, voxel_size: float,
                keys: np.ndarray, invalid_frac: float = 0.0, unchanged: bool = False) -> bytes:
    """UNITS_REP: one unit's voxel keys (N, 3) within int16 at ``voxel_size`` m, captured at
    ``stamp`` s; ``unchanged`` sends no keys (the asker holds this version already)."""
    k = np.zeros((0, 3), np.int64) if unchanged else np.asarray(keys)
    if k.ndim != 2 or k.shape[1] != 3:
        raise WireError(f"keys must be (N, 3), got {k.shape}")
    if len(k) > MAX_UNIT_VOXELS:
        raise WireError(f"{len(k)} voxels exceed the limit of {MAX_UNIT_VOXELS} per unit reply")
    if len(k) and (k.min() < -32768 or k.max() > 32767):
        raise WireError("voxel keys outside the int16 range of the wire format")
    if not math.isfinite(stamp):
        raise WireError("stamp must be finite")
    if not (0.01 - 1e-6 <= voxel_size <= 0.8):
        raise WireError(f"voxel size {voxel_size} m outside the wire range 0.01-0.8 m")
    if not (0.0 <= invalid_frac <= 1.0):
        invalid_frac = 0.0 if not math.isfinite(invalid_frac) else min(max(invalid_frac, 0.0), 1.0)
    body = (_short_str("camera id", camera, MAX_ID_BYTES)
            + _UNIT.pack(unit_id, version & 0xFFFFFFFF, seq & 0xFFFFFFFF, stamp, voxel_size, invalid_frac, len(k))
            + k.astype("<i2").tobytes())
    return _frame(MsgType.UNITS_REP, body, flags=1 if unchanged else 0)


def encode(msg: Message) -> bytes:
    """Encode a :class:`Message` (the inverse of :func:`decode`)."""
    t = msg.type
    if t == MsgType.INIT_REQ:
        return init_request(msg.camera, msg.address)
    if t == MsgType.INIT_REP:
        return init_reply(msg.unit_id, msg.settings or Settings())
    if t == MsgType.UPDATE_REQ:
        return update_request(msg.unit_id, msg.seq, msg.stamp, msg.voxel_size, msg.keys, msg.counts,
                              msg.invalid_frac)
    if t == MsgType.UPDATE_REP:
        return update_reply(msg.settings or Settings(), bool(msg.flags & 1))
    if t == MsgType.ERROR_REP:
        return error_reply(msg.code, msg.text)
    if t == MsgType.STATUS_REQ:
        return status_request()
    if t == MsgType.STATUS_REP:
        return _frame(t, msg.text.encode("utf-8"))
    if t == MsgType.SETTINGS_REQ:
        return _frame(t, msg.text.encode("utf-8"))
    if t == MsgType.UNITS_REQ:
        return units_request(msg.known)
    if t == MsgType.UNITS_REP:
        return units_reply(msg.camera, msg.unit_id, msg.version, msg.seq, msg.stamp, msg.voxel_size, msg.keys,
                           msg.invalid_frac, bool(msg.flags & 1))
    raise WireError(f"unknown message type {t!r}")


# ------------------------------------------------------------------ decode
class _Reader:
    def __init__(self, body: bytes, what: str):
        self.b, self.i, self.what = body, 0, what

    def take(self, n: int, field_name: str) -> bytes:
        if n < 0 or self.i + n > len(self.b):
            raise WireError(f"{self.what}: truncated at {field_name} (needs {n} bytes at offset {self.i}, "
                            f"body has {len(self.b)})")
        out = self.b[self.i:self.i + n]
        self.i += n
        return out

    def unpack(self, st: struct.Struct, field_name: str):
        return st.unpack(self.take(st.size, field_name))

    def text(self, field_name: str) -> str:
        (n,) = self.unpack(struct.Struct("<B"), field_name)
        try:
            return self.take(n, field_name).decode("utf-8")
        except UnicodeDecodeError:
            raise WireError(f"{self.what}: {field_name} is not valid utf-8") from None

    def end(self) -> None:
        if self.i != len(self.b):
            raise WireError(f"{self.what}: {len(self.b) - self.i} unexpected trailing bytes")


def _read_settings(r: _Reader) -> Settings:
    epoch, vs, thr, stale, oc, ok, nj = r.unpack(_SET, "settings")
    if nj > MAX_JOINTS:
        raise WireError(f"{r.what}: {nj} joints exceed the limit of {MAX_JOINTS}")
    joints = tuple(float(q) for q in np.frombuffer(r.take(8 * nj, "joints"), dtype="<f8"))
    state = ()
    if r.i < len(r.b):                       # the monitor's state options (issue 29)
        tag, off, inv, rio, sil, gap = r.unpack(_STATE, "state options")
        if tag != b"SO" or inv > 1 or rio > 1:
            raise WireError(f"{r.what}: malformed state options")
        state = (float(off), _POLICIES[inv], _POLICIES[rio], int(sil), int(gap), r.text("principal camera id"))
    return Settings(epoch, _r6(vs), _r6(thr), _r6(stale), _r6(oc), _r6(ok), joints, state).check()


def _r6(x: float) -> float:
    """f32 on the wire → the decimal value sent (sizes are whole micrometres)."""
    x = float(x)
    return round(x, 6) if math.isfinite(x) else x


def _json_obj(body: bytes, what: str) -> str:
    try:
        text = body.decode("utf-8")
        obj = json.loads(text)
    except (UnicodeDecodeError, ValueError) as exc:
        raise WireError(f"{what}: body is not utf-8 JSON ({exc})") from None
    if not isinstance(obj, dict):
        raise WireError(f"{what}: body must be a JSON object")
    return text


def decode(buf: bytes | bytearray | memoryview, expect: MsgType | tuple[MsgType, ...] | None = None) -> Message:
    """Decode one message; :class:`WireError` names the first problem found.

    ``expect``: the message type(s) acceptable here (e.g. the server's update
    endpoint accepts only UPDATE_REQ).
    """
    b = bytes(buf)
    if len(b) > MAX_MESSAGE_BYTES:
        raise WireError(f"message of {len(b)} bytes exceeds the limit of {MAX_MESSAGE_BYTES}")
    if len(b) < _OVERHEAD:
        raise WireError(f"message of {len(b)} bytes is shorter than the {_OVERHEAD}-byte frame")
    magic, ver, mtype, flags, _res, blen = _HDR.unpack_from(b)
    if magic != MAGIC:
        raise WireError(f"bad magic {magic!r} (expected {MAGIC!r})")
    if ver != VERSION:
        raise WireError(f"unsupported wire version {ver} (this end speaks {VERSION})")
    if blen != len(b) - _OVERHEAD:
        raise WireError(f"body length field {blen} does not match the {len(b) - _OVERHEAD} bytes received")
    (crc,) = _CRC.unpack_from(b, len(b) - _CRC.size)
    if crc != zlib.crc32(b[:-_CRC.size]):
        raise WireError("CRC mismatch: message corrupted")
    try:
        t = MsgType(mtype)
    except ValueError:
        raise WireError(f"unknown message type {mtype}") from None
    if expect is not None:
        ok = (expect,) if isinstance(expect, MsgType) else tuple(expect)
        if t not in ok:
            raise WireError(f"unexpected message type {t.name} here (expected {', '.join(e.name for e in ok)})")
    r = _Reader(b[_HDR.size:len(b) - _CRC.size], t.name)
    m = Message(type=t, flags=flags)
    if t == MsgType.INIT_REQ:
        m.camera = r.text("camera id")
        m.address = r.text("address")
        if not m.camera:
            raise WireError("INIT_REQ: empty camera id")
    elif t == MsgType.INIT_REP:
        (m.unit_id,) = r.unpack(struct.Struct("<I"), "unit id")
        m.settings = _read_settings(r)
    elif t == MsgType.UPDATE_REQ:
        m.unit_id, m.seq, m.stamp, vs, n, inv = r.unpack(_UPD, "update header")
        m.voxel_size = _r6(vs)
        m.invalid_frac = _r6(inv)
        if not (0.0 <= m.invalid_frac <= 1.0):
            raise WireError(f"UPDATE_REQ: invalid_frac {m.invalid_frac} outside [0, 1]")
        if not math.isfinite(m.stamp):
            raise WireError("UPDATE_REQ: stamp is not finite")
        if not (0.01 - 1e-6 <= m.voxel_size <= 0.8):
            raise WireError(f"UPDATE_REQ: voxel size {m.voxel_size} m outside 0.01-0.8 m")
        if n > MAX_VOXELS:
            raise WireError(f"UPDATE_REQ: {n} voxels exceed the limit of {MAX_VOXELS}")
        m.keys = np.frombuffer(r.take(6 * n, "keys"), dtype="<i2").reshape(n, 3).astype(np.int32)
        m.counts = np.frombuffer(r.take(2 * n, "counts"), dtype="<u2").astype(np.int32)
    elif t == MsgType.UPDATE_REP:
        m.settings = _read_settings(r)
    elif t == MsgType.ERROR_REP:
        m.code, n = r.unpack(struct.Struct("<HH"), "error header")
        try:
            m.text = r.take(n, "error message").decode("utf-8")
        except UnicodeDecodeError:
            raise WireError("ERROR_REP: message is not valid utf-8") from None
    elif t == MsgType.STATUS_REQ:
        pass
    elif t in (MsgType.STATUS_REP, MsgType.SETTINGS_REQ):
        m.text = _json_obj(r.take(len(r.b), "json"), t.name)
    elif t == MsgType.UNITS_REQ:
        (n,) = r.unpack(struct.Struct("<B"), "known count")
        for _ in range(n):
            cam = r.text("camera id")
            version, stamp = r.unpack(_KNOWN, "known unit")
            if not cam or not math.isfinite(stamp):
                raise WireError("UNITS_REQ: empty camera id or non-finite stamp")
            m.known[cam] = (version, stamp)
    elif t == MsgType.UNITS_REP:
        m.camera = r.text("camera id")
        if not m.camera:
            raise WireError("UNITS_REP: empty camera id")
        m.unit_id, m.version, m.seq, m.stamp, vs, inv, n = r.unpack(_UNIT, "unit header")
        m.voxel_size = _r6(vs)
        m.invalid_frac = _r6(inv)
        if not math.isfinite(m.stamp):
            raise WireError("UNITS_REP: stamp is not finite")
        if not (0.01 - 1e-6 <= m.voxel_size <= 0.8):
            raise WireError(f"UNITS_REP: voxel size {m.voxel_size} m outside 0.01-0.8 m")
        if not (0.0 <= m.invalid_frac <= 1.0):
            raise WireError(f"UNITS_REP: invalid_frac {m.invalid_frac} outside [0, 1]")
        if n > MAX_UNIT_VOXELS or (flags & 1 and n):
            raise WireError(f"UNITS_REP: {n} voxels (limit {MAX_UNIT_VOXELS}; none when unchanged)")
        m.keys = np.frombuffer(r.take(6 * n, "keys"), dtype="<i2").reshape(n, 3).astype(np.int32)
    r.end()
    return m
