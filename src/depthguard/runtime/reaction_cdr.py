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

__all__ = ["reaction_cdr", "float64_cdr", "markers_cdr"]

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

    def i32s(self, *v: int) -> None:
        self.pad(4)
        self.raw(struct.pack(f"<{len(v)}i", *v))

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


_markers: dict = {}                 # (offset mod 8, frame_id, ns, points) -> a marker's layout


def _marker_layout(off: int, frame_id: str, ns: str, n_points: int):
    """``(Struct, template, slots, size)`` of one ``visualization_msgs/msg/Marker`` starting at
    ``off`` (mod 8) after the encapsulation header: its bytes are ``Struct.pack(*args)`` with
    ``args`` the template with its ``slots`` set to, in order, the stamp's sec and nanosec, id,
    type, action, position (3), scale (3), colour (4 float32), the points (3 each) and the
    texture header's sec and nanosec; everything else (strings, empty sequences, the identity
    orientation, zero lifetime, false flags, padding) is constant."""
    fmt, args, n = ["<"], [], off

    def pad(a):
        nonlocal n
        r = (-n) % a
        if r:
            fmt.append(f"{r}x")
            n += r

    def const(b):
        nonlocal n
        fmt.append(f"{len(b)}s")
        args.append(b)
        n += len(b)

    def var(code, k, size):
        nonlocal n
        fmt.append(f"{k}{code}")
        args.extend([None] * k)
        n += k * size

    def string(text):
        pad(4)
        b = text.encode("utf-8")
        const(struct.pack("<I", len(b) + 1) + b + b"\x00")

    def u32(v):
        pad(4)
        const(struct.pack("<I", v))

    pad(4)
    var("i", 1, 4)                       # header: stamp, frame_id
    var("I", 1, 4)
    string(frame_id)
    string(ns)
    pad(4)
    var("i", 3, 4)                       # id, type, action
    pad(8)
    var("d", 3, 8)                       # pose: position, then the identity orientation
    const(struct.pack("<4d", 0.0, 0.0, 0.0, 1.0))
    var("d", 3, 8)                       # scale
    var("f", 4, 4)                       # color
    const(b"\x00" * 9)                   # lifetime 0 s 0 ns, frame_locked false
    u32(n_points)
    if n_points:
        pad(8)
        var("d", 3 * n_points, 8)
    u32(0)                               # colors
    string("")                           # texture_resource
    pad(4)
    var("i", 1, 4)                       # texture: its header, format "", no data
    var("I", 1, 4)
    string(frame_id)
    string("")
    u32(0)
    u32(0)                               # uv_coordinates
    string("")                           # text
    string("")                           # mesh_resource
    string("")                           # mesh_file: filename "", no data
    u32(0)
    const(b"\x00")                       # mesh_use_embedded_materials false
    slots = [i for i, x in enumerate(args) if x is None]
    return struct.Struct("".join(fmt)), args, slots, n - off


def markers_cdr(t: float, frame_id: str, names, n_cp: int, positions: np.ndarray, sizes, observed,
                distance: np.ndarray, direction: np.ndarray) -> bytes:
    """The ``visualization_msgs/msg/MarkerArray`` of
    :meth:`~depthguard.runtime.mcap_results.McapResults.markers_msg` serialised (ROS 2 Humble's
    ``Marker``): a DELETEALL, then per point ``i`` (``positions`` (m, 3) m, ``sizes`` (m,) m) a
    sphere — namespace ``control_points`` for ``i < n_cp``, else ``watch_points``; grey when not
    ``observed``, orange with an obstacle within rho (finite ``distance``), else green — and, for
    an observed point with an obstacle, an arrow from it along ``direction`` (m, 3) for its
    distance. Each marker is one ``struct`` pack of a layout made once (:func:`_marker_layout`);
    several times cheaper than building the message objects for ``rosbags`` (issue 29)."""
    ns = int(round(t * 1e9))
    sec, nsec = ns // 1_000_000_000, ns % 1_000_000_000
    pos = np.asarray(positions, dtype=np.float64).tolist()
    direc = np.asarray(direction, dtype=np.float64)
    dist = np.asarray(distance, dtype=np.float64).tolist()
    obs_l = np.asarray(observed, dtype=bool).tolist()
    items = [("", (0, 0, 3, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), ())]        # DELETEALL
    for i in range(len(names)):
        obs, d = obs_l[i], dist[i]
        near = obs and math.isfinite(d)
        rgba = (0.6, 0.6, 0.6, 0.8) if not obs else ((1.0, 0.5, 0.0, 0.9) if near else (0.1, 0.8, 0.2, 0.8))
        s = float(sizes[i])
        p = pos[i]
        items.append(("control_points" if i < n_cp else "watch_points", (i, 2, 0, *p, s, s, s, *rgba), ()))
        if near:
            end = (np.asarray(p) + d * direc[i]).tolist()
            items.append(("distance", (i, 0, 0, 0.0, 0.0, 0.0, 0.01, 0.02, 0.03, 1.0, 0.2, 0.1, 1.0), (*p, *end)))
    parts = [_HEAD, struct.pack("<I", len(items))]
    n = 4
    for name, fields, points in items:
        key = (n % 8, frame_id, name, len(points) // 3)
        lay = _markers.get(key)
        if lay is None:
            if len(_markers) > 256:
                _markers.clear()
            lay = _markers[key] = _marker_layout(*key)
        st, args, slots, size = lay
        args = list(args)
        for j, v in zip(slots, (sec, nsec, *fields, *points, sec, nsec)):
            args[j] = v
        parts.append(st.pack(*args))
        n += size
    return b"".join(parts)


def _age(x: float) -> float:
    return float(x) if math.isfinite(x) else -1.0          # -1 = nothing yet (as McapResults)
