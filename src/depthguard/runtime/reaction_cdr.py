"""The results file's per-cycle messages as CDR bytes, written directly (R31, issue 29).

``results.mcap`` gets two messages every control cycle (500 Hz): the whole reaction
(``depthguard_msgs/msg/Reaction``, :data:`depthguard.runtime.mcap_results.REACTION_MSG`) and the
override (``std_msgs/msg/Float64``). Building the message objects and having ``rosbags``
serialise them cost ~65 us a cycle (measured 2026-11-26, ur3-cell); :func:`reaction_cdr` and
:func:`float64_cdr` write the same bytes — little-endian CDR with its 4-byte encapsulation
header, every primitive aligned to its size from the end of that header, sequences and strings
prefixed by a uint32 count (strings NUL-terminated, the count including it) — in one pass.
The markers (``visualization_msgs/msg/MarkerArray``, 30 times a second) likewise
(:func:`markers_cdr`). Each message is made of few ``struct`` packs: what is constant for a
layout (strings, counts, padding) is laid out once per layout (:class:`_Layout`), and a cycle
only fills in the numbers. ``rosbags``' own serialisation is the test's truth
(``tests/test_reaction_json.py``).
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


_reaction_heads: dict = {}          # (frame_id, names, dofs, m) -> the layout up to the reasons
_reaction_tails: dict = {}          # (offset mod 8, cameras, states, dof) -> the layout after them


def _reaction_head(frame_id: str, names: tuple, n_min: int, n_max: int, marks: list | None = None):
    """The :class:`_Layout` of a Reaction from its header to its directions; slots: the stamp's
    sec and nanosec, override, repulsion (3), qd_min, qd_max, watch, observed, within_rho,
    distance (m each) and direction (3 m). ``marks``: gets each of these ten fields' offset."""
    m = len(names)
    o = _Layout(0, marks)
    o.var("i", 1, 4)
    o.var("I", 1, 4)
    o.string(frame_id)
    o.pad(8)
    o.var("d", 4, 8)                     # override, repulsion
    o.f64s(n_min)
    o.f64s(n_max)
    o.strings(names)
    o.bools(m)                           # watch, observed, within_rho
    o.bools(m)
    o.bools(m)
    o.f64s(m)                            # distance
    o.u32(m)                             # direction: m Vector3 (3 float64 each)
    if m:
        o.pad(8)
    o.var("d", 3 * m, 8)
    return o.done()


def _reaction_tail(off: int, cams: tuple, states: tuple, n_q: int, marks: list | None = None):
    """The :class:`_Layout` of a Reaction from its cameras on, starting at ``off`` (mod 8); slots:
    the cameras' ages, joints_age_s and q (``marks``: their three offsets from ``off``)."""
    o = _Layout(off, marks)
    o.strings(cams)
    o.strings(states)
    o.f64s(len(cams))
    o.pad(8)
    o.var("d", 1, 8)
    o.f64s(n_q)
    return o.done()


def _cached(cache: dict, key, make):
    lay = cache.get(key)
    if lay is None:
        if len(cache) > 256:
            cache.clear()
        lay = cache[key] = make(*key)
    return lay


def reaction_cdr(r, frame_id: str) -> bytes:
    """The ``depthguard_msgs/msg/Reaction`` of reaction ``r`` serialised, as
    :meth:`~depthguard.runtime.mcap_results.McapResults.reaction_msg` fills it (``within_rho`` =
    finite distance; distance and direction 0 where not; an age of ``inf`` as -1). The parts
    before and after the reasons are each one ``struct`` pack of a layout made once per
    names, cameras and their states (:class:`_Layout`); the numbers are taken from the arrays
    with one ``tolist`` each (a reaction's own float64 and bool arrays; others are converted
    first)."""
    ns = int(round(r.t * 1e9))
    names = tuple(r.names)
    qd_min = _floats(r.qd_min)
    qd_max = _floats(r.qd_max)
    d_l = _floats(r.distance)
    m = len(d_l)
    direc = r.direction
    v_l = direc.tolist() if (type(direc) is np.ndarray and direc.dtype == np.float64 and direc.shape == (m, 3)) \
        else np.asarray(direc, dtype=np.float64).reshape(-1, 3).tolist()
    head = _cached(_reaction_heads, (frame_id, names, len(qd_min), len(qd_max)), _reaction_head)
    rep = r.repulsion
    vals = [ns // 1_000_000_000, ns % 1_000_000_000, float(r.override), float(rep[0]), float(rep[1]), float(rep[2])]
    vals += qd_min
    vals += qd_max
    vals += _bools(r.is_watch)
    vals += _bools(r.observed)
    within = [x - x == 0.0 for x in d_l]          # finite (inf - inf and nan - nan are nan)
    vals += within
    vals += [x if w else 0.0 for x, w in zip(d_l, within)]
    for v, w in zip(v_l, within):
        vals += v if w else _ZERO3
    parts = [_HEAD, _pack(head, vals)]
    reasons = r.reasons
    n = head[3]
    if reasons:
        key = (tuple(reasons.items()), n % 4)
        block = _reason_blocks.get(key)
        if block is None:                        # the same reasons hold for many cycles: made once
            o = _Out()
            o.n = key[1]
            o.strings([k for k, _ in key[0]])
            o.strings([v for _, v in key[0]])
            if len(_reason_blocks) > 256:
                _reason_blocks.clear()
            block = _reason_blocks[key] = b"".join(o.parts)
        parts.append(block)
        n += len(block)
    else:
        parts.append(_NO_REASONS[n % 4])
        n += len(_NO_REASONS[n % 4])
    cams = tuple(r.cameras)
    statuses = [r.cameras[c] for c in cams]
    q = _floats(r.q)
    tail = _cached(_reaction_tails, (n % 8, cams, tuple([st.state for st in statuses]), len(q)), _reaction_tail)
    vals = [_age(st.age_s) for st in statuses]
    vals.append(_age(r.joints_age_s))
    vals += q
    parts.append(_pack(tail, vals))
    return b"".join(parts)


_ZERO3 = [0.0, 0.0, 0.0]
_reason_blocks: dict = {}           # (reasons' items, offset mod 4) -> their two string sequences' bytes


def _no_reasons(off: int) -> bytes:
    """Two empty string sequences (no reasons) written at ``off`` (mod 4)."""
    o = _Out()
    o.n = off
    o.u32(0)
    o.u32(0)
    return b"".join(o.parts)


_NO_REASONS = [_no_reasons(k) for k in range(4)]


def _floats(a) -> list:
    """A float64 array's values as a list (what ``np.asarray(a, float64).ravel().tolist()`` gives)."""
    if type(a) is np.ndarray and a.dtype == np.float64 and a.ndim == 1:
        return a.tolist()
    return np.asarray(a, dtype=np.float64).ravel().tolist()


def _bools(a) -> list:
    """A bool array's values as a list (what ``np.asarray(a, bool).tolist()`` gives)."""
    if type(a) is np.ndarray and a.dtype == np.bool_ and a.ndim == 1:
        return a.tolist()
    return np.asarray(a, dtype=bool).ravel().tolist()


_markers: dict = {}                 # (offset mod 8, frame_id, ns, points) -> a marker's layout


class _Layout:
    """A message part whose bytes are one ``struct`` pack: constants (strings, counts, padding)
    are fixed when it is made, the variable fields are its ``slots`` (in order).
    :meth:`done` -> ``(Struct, template args, slots, size)``; ``size`` counts from ``off``."""

    def __init__(self, off: int, marks: list | None = None):
        self.fmt, self.args, self.off, self.n = ["<"], [], off, off
        self.marks = [] if marks is None else marks    # each var()'s offset from off, in order

    def pad(self, a: int) -> None:
        r = (-self.n) % a
        if r:
            self.fmt.append(f"{r}x")
            self.n += r

    def const(self, b: bytes) -> None:
        self.fmt.append(f"{len(b)}s")
        self.args.append(b)
        self.n += len(b)

    def var(self, code: str, k: int, size: int) -> None:
        self.marks.append(self.n - self.off)
        if k:
            self.fmt.append(f"{k}{code}")
            self.args.extend([None] * k)
            self.n += k * size

    def u32(self, v: int) -> None:
        self.pad(4)
        self.const(struct.pack("<I", v))

    def string(self, text: str) -> None:
        self.pad(4)
        b = text.encode("utf-8")
        self.const(struct.pack("<I", len(b) + 1) + b + b"\x00")

    def strings(self, values) -> None:
        self.u32(len(values))
        for v in values:
            self.string(v)

    def f64s(self, k: int) -> None:
        """A float64 sequence of ``k`` values: count, then (aligned to 8 when there are any) values."""
        self.u32(k)
        if k:
            self.pad(8)
        self.var("d", k, 8)

    def bools(self, k: int) -> None:
        self.u32(k)
        self.var("?", k, 1)

    def done(self):
        """``(Struct, template args, runs, size)``: ``runs`` are the slots as ``(start, stop)`` index
        ranges of consecutive arguments (a message has a dozen, not a slot per number)."""
        slots = [i for i, x in enumerate(self.args) if x is None]
        runs: list = []
        for i in slots:
            if runs and runs[-1][1] == i:
                runs[-1][1] = i + 1
            else:
                runs.append([i, i + 1])
        return struct.Struct("".join(self.fmt)), self.args, tuple((a, b) for a, b in runs), self.n - self.off


def _pack(layout, values) -> bytes:
    """The layout's bytes with ``values`` (a sequence, one per slot, in order) in its slots."""
    st, args, runs, _ = layout
    if len(runs) == 1 and runs[0] == (0, len(args)):
        return st.pack(*values)
    args = list(args)
    k = 0
    for a, b in runs:
        args[a:b] = values[k:k + b - a]
        k += b - a
    if k != len(values):
        raise ValueError(f"{len(values)} values for {k} slots")
    return st.pack(*args)


def _marker_layout(off: int, frame_id: str, ns: str, n_points: int):
    """The :class:`_Layout` of one ``visualization_msgs/msg/Marker`` starting at ``off`` (mod 8)
    after the encapsulation header; its slots: the stamp's sec and nanosec, id, type, action,
    position (3), scale (3), colour (4 float32), the points (3 each) and the texture header's
    sec and nanosec; everything else (strings, empty sequences, the identity orientation, zero
    lifetime, false flags, padding) is constant."""
    o = _Layout(off)
    o.pad(4)
    o.var("i", 1, 4)                     # header: stamp, frame_id
    o.var("I", 1, 4)
    o.string(frame_id)
    o.string(ns)
    o.pad(4)
    o.var("i", 3, 4)                     # id, type, action
    o.pad(8)
    o.var("d", 3, 8)                     # pose: position, then the identity orientation
    o.const(struct.pack("<4d", 0.0, 0.0, 0.0, 1.0))
    o.var("d", 3, 8)                     # scale
    o.var("f", 4, 4)                     # color
    o.const(b"\x00" * 9)                 # lifetime 0 s 0 ns, frame_locked false
    o.u32(n_points)
    if n_points:
        o.pad(8)
        o.var("d", 3 * n_points, 8)
    o.u32(0)                             # colors
    o.string("")                         # texture_resource
    o.pad(4)
    o.var("i", 1, 4)                     # texture: its header, format "", no data
    o.var("I", 1, 4)
    o.string(frame_id)
    o.string("")
    o.u32(0)
    o.u32(0)                             # uv_coordinates
    o.string("")                         # text
    o.string("")                         # mesh_resource
    o.string("")                         # mesh_file: filename "", no data
    o.u32(0)
    o.const(b"\x00")                     # mesh_use_embedded_materials false
    return o.done()


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
        parts.append(_pack(lay, (sec, nsec, *fields, *points, sec, nsec)))
        n += lay[3]
    return b"".join(parts)


def _age(x: float) -> float:
    return float(x) if math.isfinite(x) else -1.0          # -1 = nothing yet (as McapResults)
