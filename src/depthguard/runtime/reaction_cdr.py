"""The results file's per-cycle messages as CDR bytes, written directly (R31, issue 29).

``results.mcap`` gets two messages every control cycle (500 Hz): the whole reaction
(``depthguard_msgs/msg/Reaction``, :data:`depthguard.runtime.mcap_results.REACTION_MSG`) and the
override (``std_msgs/msg/Float64``). Building the message objects and having ``rosbags``
serialise them cost ~65 us a cycle (measured 2026-11-26, ur3-cell); :func:`reaction_cdr` and
:func:`float64_cdr` write the same bytes — little-endian CDR with its 4-byte encapsulation
header, every primitive aligned to its size from the end of that header, sequences and strings
prefixed by a uint32 count (strings NUL-terminated, the count including it) — in one pass.
``rosbags``' own serialisation is the test's truth (``tests/test_reaction_json.py``).
"""

from __future__ import annotations

import math
import struct

import numpy as np

__all__ = ["reaction_cdr", "float64_cdr"]

_HEAD = b"\x00\x01\x00\x00"        # CDR_LE encapsulation
_F64 = struct.Struct("<d")
_blocks: dict = {}                  # (strings, offset mod 4) -> their bytes (names, cameras, states)


def float64_cdr(x: float) -> bytes:
    """``std_msgs/msg/Float64(data=x)`` serialised."""
    return _HEAD + _F64.pack(float(x))


class _Out:
    __slots__ = ("parts", "n")

    def __init__(self):
        self.parts: list[bytes] = []
        self.n = 0                  # bytes written after the encapsulation header

    def pad(self, a: int) -> None:
        r = (-self.n) % a
        if r:
            self.parts.append(b"\x00" * r)
            self.n += r

    def raw(self, b: bytes) -> None:
        self.parts.append(b)
        self.n += len(b)

    def u32(self, v: int) -> None:
        self.pad(4)
        self.raw(struct.pack("<I", v))

    def f64s(self, values: np.ndarray) -> None:
        """A float64 sequence: count, then the values (aligned to 8 when there are any)."""
        a = np.ascontiguousarray(values, dtype="<f8")
        self.u32(a.shape[0])
        if a.shape[0]:
            self.pad(8)
            self.raw(a.tobytes())

    def bools(self, values) -> None:
        a = np.ascontiguousarray(values, dtype=np.bool_)
        self.u32(a.shape[0])
        self.raw(a.view(np.uint8).tobytes())

    def string(self, s: str) -> None:
        b = s.encode("utf-8")
        self.u32(len(b) + 1)
        self.raw(b + b"\x00")

    def strings(self, values) -> None:
        """A string sequence; the same names at the same alignment are encoded once."""
        key = (tuple(values), self.n % 4)
        block = _blocks.get(key)
        if block is None:
            sub = _Out()
            sub.n = key[1]
            sub.u32(len(values))
            for s in values:
                sub.string(s)
            block = b"".join(sub.parts)
            if len(_blocks) > 512:
                _blocks.clear()
            _blocks[key] = block
        self.raw(block)


def reaction_cdr(r, frame_id: str) -> bytes:
    """The ``depthguard_msgs/msg/Reaction`` of reaction ``r`` serialised, as
    :meth:`~depthguard.runtime.mcap_results.McapResults.reaction_msg` fills it (``within_rho`` =
    finite distance; distance and direction 0 where not; an age of ``inf`` as -1)."""
    ns = int(round(r.t * 1e9))
    o = _Out()
    o.raw(struct.pack("<iI", ns // 1_000_000_000, ns % 1_000_000_000))
    o.string(frame_id)
    o.pad(8)
    rep = r.repulsion
    o.raw(struct.pack("<dddd", float(r.override), float(rep[0]), float(rep[1]), float(rep[2])))
    o.f64s(r.qd_min)
    o.f64s(r.qd_max)
    o.strings(list(r.names))
    within = np.isfinite(r.distance)
    o.bools(r.is_watch)
    o.bools(r.observed)
    o.bools(within)
    o.f64s(np.where(within, r.distance, 0.0))
    direc = np.where(within[:, None], np.asarray(r.direction, dtype=np.float64), 0.0)
    o.u32(direc.shape[0])
    if direc.shape[0]:
        o.pad(8)
        o.raw(np.ascontiguousarray(direc, dtype="<f8").tobytes())
    o.strings(list(r.reasons))
    o.strings(list(r.reasons.values()))
    cams = list(r.cameras)
    o.strings(cams)
    o.strings([r.cameras[c].state for c in cams])
    o.f64s(np.array([_age(r.cameras[c].age_s) for c in cams], dtype=np.float64))
    o.pad(8)
    o.raw(_F64.pack(_age(r.joints_age_s)))
    o.f64s(r.q)
    return _HEAD + b"".join(o.parts)


def _age(x: float) -> float:
    return float(x) if math.isfinite(x) else -1.0          # -1 = nothing yet (as McapResults)
