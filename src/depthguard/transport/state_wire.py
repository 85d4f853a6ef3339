"""The wire format of a camera unit's depth grid state (issue 29 point 3, R20, R36).

A camera unit (``depthguard node --states``) makes its own frame's per-pixel state — what
:class:`~depthguard.fusion.depth_grid_state.StateMaker` makes on a camera worker of the
monitor: ``free`` (H, W) float64 m, the depth up to which each ray is free, and ``kind``
(H, W) int8 (0 surface, 1 robot, 2 unknown) — with the robot removed at the frame's capture
joints, and publishes it on ``<prefix>/states/<camera>``. The monitor's ``units:`` source
decodes it and hands it to the depth grid build as the camera's state, so the build is the
one a monitor that had the frame would make. The decode is **bit-exact**: every ``free``
value decodes to the float64 the unit computed.

Layout, little-endian::

    head    "DGS" | version u8 | codec u8 | flags u8 (bit 0: robot_free) | height u16 | width u16 |
            seq u32 | stamp f64 (s, capture) | robot_offset f64 (m) | invalid u8 |
            robot_in_others u8 (0 unknown, 1 free) | silhouette_px u8 | gap_px u8 |
            n_joints u8 | n_table u8 | cam_len u8                                 (37 bytes)
    then    camera id (utf-8) | joints n_joints x f64 (rad, the joints the robot was removed at) |
            table n_table x f64 (m) | head_crc u32 (CRC-32 of everything before it)
    payload free: codec 0 "f64": H*W x f64; codec 1 "f32": H*W x f32, where a value that
            float32 does not hold exactly is a quiet NaN whose low byte indexes ``table``
            (``0x7FC7FF00 | i``; ``free`` never holds a NaN) | kind: H*W x int8

Codec 1 is exact because ``free`` is a measured depth, a rendered robot depth (both float32),
``inf``, or one of a few float64 constants (the camera's ``min_range`` / ``max_range``, a robot
depth less the offset): those go into the table (at most 255 distinct values; more, and the
unit sends codec 0). Size of a 640x480 frame: codec 0 2.76 MB, codec 1 1.54 MB. The payload
carries no checksum of its own (a CRC over 1.5 MB costs ~0.9 ms on the bench machine, the
monitor's whole budget): the transport is TCP / TLS, and a certificate-signed envelope
(:mod:`depthguard.transport.auth`) covers every byte when the cell has keys. The decode checks
the rest: size (exactly the length the head announces: a truncated message is refused),
magic, version, codec, the head's CRC, value ranges, and every ``kind`` in 0-2 and ``free``
>= 0 and not NaN (one pass, :func:`check_f64` / :func:`expand_f32`, numba with a plain-numpy
twin). :class:`StateWireError` (a ``ValueError``) names what is wrong.
"""

from __future__ import annotations

import math
import struct
import zlib
from typing import NamedTuple

import numpy as np
from numba import njit

__all__ = ["StateWireError", "UnitState", "encode_state", "decode_state", "VERSION", "CODEC_F64", "CODEC_F32",
           "expand_f32", "expand_f32_numpy", "check_f64", "check_f64_numpy", "state_bytes"]

MAGIC = b"DGS"
VERSION = 1
CODEC_F64, CODEC_F32 = 0, 1
_HEAD = struct.Struct("<3sBBBHHIddBBBBBBB")
_CRC = struct.Struct("<I")
_POLICIES = ("unknown", "free")
_SENTINEL = 0x7FC7FF00               # a quiet NaN; low byte = table index
MAX_PIXELS = 4096 * 4096
MAX_JOINTS = 32
MAX_TABLE = 255


class StateWireError(ValueError):
    """A state message that cannot be decoded (or encoded)."""


class UnitState(NamedTuple):
    """A decoded state message: ``camera`` id, ``seq``, capture ``stamp`` (s), ``q`` (dof,) rad the
    robot was removed at, ``options`` ``(robot_offset, invalid, robot_in_others, silhouette_px,
    gap_px)`` (the fields of :class:`~depthguard.fusion.depth_grid_state.StateOptions`),
    ``robot_free``, ``free`` (H, W) float64 m (read-only), ``kind`` (H, W) int8 (read-only),
    ``nbytes`` of the message."""
    camera: str
    seq: int
    stamp: float
    q: np.ndarray
    options: tuple
    robot_free: bool
    free: np.ndarray
    kind: np.ndarray
    nbytes: int


def state_bytes(height: int, width: int, codec: int = CODEC_F32) -> int:
    """Payload bytes of one (H, W) state (``free`` + ``kind``)."""
    return height * width * ((8 if codec == CODEC_F64 else 4) + 1)


def encode_state(camera: str, seq: int, stamp: float, q, options, robot_free: bool, free: np.ndarray,
                 kind: np.ndarray, codec: int = CODEC_F32) -> bytes:
    """One state message (module docstring). ``codec`` CODEC_F32 falls back to CODEC_F64 when
    ``free`` holds more than 255 float64 values that float32 does not hold exactly."""
    free = np.ascontiguousarray(free, dtype=np.float64)
    kind = np.ascontiguousarray(kind, dtype=np.int8)
    if free.ndim != 2 or kind.shape != free.shape or free.size > MAX_PIXELS or free.size == 0:
        raise StateWireError(f"free and kind must be one (H, W) shape (got {free.shape}, {kind.shape})")
    H, W = free.shape
    q = np.asarray(q, dtype="<f8").reshape(-1)
    if len(q) > MAX_JOINTS or not np.all(np.isfinite(q)):
        raise StateWireError(f"joints must be at most {MAX_JOINTS} finite values")
    if not math.isfinite(stamp):
        raise StateWireError("stamp must be finite")
    off, inv, rio, sil, gap = options
    cam = camera.encode("utf-8")
    if not cam or len(cam) > 64:
        raise StateWireError("camera id must be 1-64 bytes")
    table = np.zeros(0)
    body = None
    if codec == CODEC_F32:
        f32 = free.astype(np.float32)
        bad = f32.astype(np.float64) != free
        if np.any(bad):
            table = np.unique(free[bad])
            if len(table) <= MAX_TABLE:
                bits = f32.view(np.uint32)
                bits[bad] = _SENTINEL | np.searchsorted(table, free[bad]).astype(np.uint32)
            else:
                codec, table = CODEC_F64, np.zeros(0)
        if codec == CODEC_F32:
            body = f32.astype("<f4", copy=False).tobytes()
    if codec == CODEC_F64:
        body = free.astype("<f8", copy=False).tobytes()
    elif body is None:
        raise StateWireError(f"unknown codec {codec!r}")
    try:
        head = _HEAD.pack(MAGIC, VERSION, codec, 1 if robot_free else 0, H, W, int(seq) & 0xFFFFFFFF, float(stamp),
                          float(off), _POLICIES.index(inv), _POLICIES.index(rio), int(sil), int(gap), len(q),
                          len(table), len(cam))
    except (struct.error, ValueError) as exc:
        raise StateWireError(f"state options out of range: {exc}") from None
    head += cam + q.tobytes() + table.astype("<f8").tobytes()
    return head + _CRC.pack(zlib.crc32(head)) + body + kind.tobytes()


def decode_state(buf) -> UnitState:
    """Decode one state message; :class:`StateWireError` names the first problem. The arrays are
    views of ``buf`` (codec 0) or one new float64 array (codec 1)."""
    b = memoryview(buf).cast("B") if not isinstance(buf, bytes) else buf
    n = len(b)
    if n < _HEAD.size + _CRC.size:
        raise StateWireError(f"state message of {n} bytes is shorter than its {_HEAD.size + _CRC.size}-byte head")
    (magic, ver, codec, flags, H, W, seq, stamp, off, inv, rio, sil, gap, nj, nt, nc) = _HEAD.unpack_from(b)
    if magic != MAGIC:
        raise StateWireError(f"bad magic {bytes(magic)!r} (expected {MAGIC!r})")
    if ver != VERSION:
        raise StateWireError(f"unsupported state wire version {ver} (this end speaks {VERSION})")
    if codec not in (CODEC_F64, CODEC_F32):
        raise StateWireError(f"unknown codec {codec}")
    hlen = _HEAD.size + nc + 8 * nj + 8 * nt
    if n < hlen + _CRC.size:
        raise StateWireError(f"state message truncated in its head ({n} bytes)")
    (crc,) = _CRC.unpack_from(b, hlen)
    if crc != zlib.crc32(b[:hlen]):
        raise StateWireError("head CRC mismatch: message corrupted")
    if H == 0 or W == 0 or H * W > MAX_PIXELS:
        raise StateWireError(f"image size {W}x{H} out of range")
    if nj > MAX_JOINTS or inv > 1 or rio > 1:
        raise StateWireError("joints or state options out of range")
    if (codec == CODEC_F64 and nt) or (codec == CODEC_F32 and nt > MAX_TABLE):
        raise StateWireError(f"table of {nt} values with codec {codec}")
    want = hlen + _CRC.size + state_bytes(H, W, codec)
    if n != want:
        raise StateWireError(f"state message of {n} bytes, its head announces {want} ({W}x{H}, codec {codec})"
                             + (": truncated" if n < want else ""))
    if not (math.isfinite(stamp) and math.isfinite(off) and off >= 0.0):
        raise StateWireError("stamp or robot_offset not finite")
    i = _HEAD.size
    try:
        camera = bytes(b[i:i + nc]).decode("utf-8")
    except UnicodeDecodeError:
        raise StateWireError("camera id is not utf-8") from None
    if not camera:
        raise StateWireError("empty camera id")
    i += nc
    q = np.frombuffer(b, dtype="<f8", count=nj, offset=i).astype(np.float64)
    i += 8 * nj
    table = np.frombuffer(b, dtype="<f8", count=nt, offset=i).astype(np.float64)
    i += 8 * nt + _CRC.size
    if not np.all(np.isfinite(q)):
        raise StateWireError("joints not finite")
    kind = np.frombuffer(b, dtype=np.int8, count=H * W, offset=n - H * W).reshape(H, W)
    if codec == CODEC_F64:
        free = np.frombuffer(b, dtype="<f8", count=H * W, offset=i).reshape(H, W)
        bad = check_f64(free.reshape(-1), kind.reshape(-1))
    else:
        bits = np.frombuffer(b, dtype="<u4", count=H * W, offset=i)
        free = np.empty((H, W), dtype=np.float64)
        bad = expand_f32(bits, bits.view("<f4"), table, kind.reshape(-1), free.reshape(-1))
    if bad:
        raise StateWireError(f"{bad} pixels with a free depth < 0 / NaN, a kind outside 0-2 or a table index "
                             f"beyond the table")
    free.flags.writeable = False
    return UnitState(camera, int(seq), float(stamp), q, (float(off), _POLICIES[inv], _POLICIES[rio], int(sil),
                                                          int(gap)), bool(flags & 1), free, kind, n)


@njit(cache=True, nogil=True)
def expand_f32(bits, f32, table, kind, out):
    """Codec 1's ``free``: ``bits`` (N,) uint32 (float32 bit patterns, sentinels; ``f32`` the same
    memory as float32) → ``out`` (N,)
    float64 m; the number of bad pixels (NaN / negative free, sentinel beyond ``table``, kind
    outside 0-2)."""
    bad = 0
    nt = table.shape[0]
    for i in range(bits.shape[0]):
        b = bits[i]
        if (b & np.uint32(0xFFFFFF00)) == np.uint32(_SENTINEL):
            j = b & np.uint32(0xFF)
            if j < nt:
                out[i] = table[j]
            else:
                out[i] = 0.0
                bad += 1
        else:
            out[i] = np.float64(f32[i])
        v = out[i]
        if not (v >= 0.0) or kind[i] < 0 or kind[i] > 2:
            bad += 1
    return bad


def expand_f32_numpy(bits, f32, table, kind, out) -> int:
    """The plain-numpy twin of :func:`expand_f32`."""
    bits = np.asarray(bits, dtype=np.uint32)
    sent = (bits & np.uint32(0xFFFFFF00)) == np.uint32(_SENTINEL)
    idx = (bits & np.uint32(0xFF)).astype(np.int64)
    out[:] = np.asarray(f32).astype(np.float64)
    inside = sent & (idx < len(table))
    out[inside] = np.asarray(table)[idx[inside]]
    out[sent & ~inside] = 0.0
    return int(np.count_nonzero(sent & ~inside) + np.count_nonzero(~(out >= 0.0))
               + np.count_nonzero((kind < 0) | (kind > 2)))


@njit(cache=True, nogil=True)
def check_f64(free, kind):
    """Codec 0's check: the number of pixels with ``free`` (N,) NaN or < 0, or ``kind`` outside 0-2."""
    bad = 0
    for i in range(free.shape[0]):
        if not (free[i] >= 0.0) or kind[i] < 0 or kind[i] > 2:
            bad += 1
    return bad


def check_f64_numpy(free, kind) -> int:
    """The plain-numpy twin of :func:`check_f64`."""
    return int(np.count_nonzero(~(np.asarray(free) >= 0.0) | (kind < 0) | (kind > 2)))
