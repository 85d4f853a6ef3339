"""The results file's Reaction message with its numbers filled in by a compiled kernel (R31, issue 29).

:func:`reaction_cdr_filled` returns the bytes of
:func:`~depthguard.runtime.reaction_cdr.reaction_cdr` — the ``depthguard_msgs/msg/Reaction`` of
``results.mcap``, 500 times a second — without its per-cycle Python lists and ``struct`` pack
(~25 us a message, measured 2026-11-26 on ur3-cell): per layout (frame, point names, the joint
boxes' sizes, the reasons, the cameras and their states, the number of joints) the message made
once by :func:`reaction_cdr` is kept as a template with the offsets of its number fields
(:class:`~depthguard.runtime.reaction_cdr._Layout`'s marks), and :func:`fill_reaction` copies
it and writes the cycle's numbers at those offsets (little-endian, as CDR_LE; the buffer is
shifted by 4 bytes so that every float64 the encapsulation header leaves 8-aligned is 8-aligned
in memory). What the fast path cannot take (arrays of another dtype, a big-endian machine) goes to
:func:`reaction_cdr`. ``tests/test_reaction_json.py`` holds both against ``rosbags``' own
serialisation.
"""

from __future__ import annotations

import sys
import threading

import numba
import numpy as np

from depthguard.runtime.reaction_cdr import (_HEAD, _NO_REASONS, _reaction_head, _reaction_tail, _reason_blocks,
                                             reaction_cdr)

__all__ = ["reaction_cdr_filled", "fill_reaction"]

_SHIFT = 4                          # message byte b at buf[b + _SHIFT]: the CDR body 8-aligned


@numba.njit(cache=True)
def fill_reaction(tmpl, buf, f8, i4, hm, tm, sec, nsec, override, rep, qd_min, qd_max, watch, observed, dist,
                  direc, ages, joints_age, q):
    """The message into ``buf`` (uint8; ``f8`` / ``i4`` its float64 / int32 views): ``tmpl`` (uint8,
    the layout's bytes) copied to ``buf[4:]``, then the numbers at the offsets ``hm`` (10: stamp
    sec and nanosec, override and repulsion, qd_min, qd_max, watch, observed, within_rho,
    distance, direction) and ``tm`` (3: camera ages, joints_age_s, q) from the start of the
    message; within_rho = finite ``dist`` (m,) m, distance and ``direc`` (m, 3) 0 where not, an
    age that is not finite -1. Returns the message's length, or -1 where the arrays do not fit
    the layout (nothing written beyond ``buf``)."""
    L = len(tmpl)
    m = len(dist)
    if (L + 4 > len(buf) or len(hm) != 10 or len(tm) != 3 or len(watch) != m or len(observed) != m
            or direc.shape[0] != m or direc.shape[1] != 3 or len(rep) != 3):
        return -1
    ends = (hm[0] + 4, hm[1] + 4, hm[2] + 32, hm[3] + 8 * len(qd_min), hm[4] + 8 * len(qd_max), hm[5] + m, hm[6] + m,
            hm[7] + m, hm[8] + 8 * m, hm[9] + 24 * m, tm[0] + 8 * len(ages), tm[1] + 8, tm[2] + 8 * len(q))
    for e in ends:
        if e > L:
            return -1                                 # a field beyond the template: not its layout
    for b in range(L):
        buf[b + 4] = tmpl[b]
    i4[(hm[0] + 4) // 4] = sec
    i4[(hm[1] + 4) // 4] = nsec
    k = (hm[2] + 4) // 8
    f8[k] = override
    for c in range(3):
        f8[k + 1 + c] = rep[c]
    k = (hm[3] + 4) // 8
    for i in range(len(qd_min)):
        f8[k + i] = qd_min[i]
    k = (hm[4] + 4) // 8
    for i in range(len(qd_max)):
        f8[k + i] = qd_max[i]
    kd = (hm[8] + 4) // 8
    kv = (hm[9] + 4) // 8
    for i in range(m):
        buf[hm[5] + 4 + i] = 1 if watch[i] else 0
        buf[hm[6] + 4 + i] = 1 if observed[i] else 0
        d = dist[i]
        w = d - d == 0.0
        buf[hm[7] + 4 + i] = 1 if w else 0
        f8[kd + i] = d if w else 0.0
        for c in range(3):
            f8[kv + 3 * i + c] = direc[i, c] if w else 0.0
    k = (tm[0] + 4) // 8
    for i in range(len(ages)):
        a = ages[i]
        f8[k + i] = a if a - a == 0.0 else -1.0
    f8[(tm[1] + 4) // 8] = joints_age if joints_age - joints_age == 0.0 else -1.0
    k = (tm[2] + 4) // 8
    for i in range(len(q)):
        f8[k + i] = q[i]
    return L


_layouts: dict = {}                 # layout key -> (template (uint8), head marks, tail marks)
_local = threading.local()          # each thread's buffer and its views


def _layout(r, frame_id: str, names: tuple, n_min: int, n_max: int, cams: tuple, states: tuple, n_q: int):
    """``(template, hm, tm)`` (:func:`fill_reaction`) of ``r``'s layout: its message from
    :func:`reaction_cdr`, the offsets from its :class:`_Layout` marks (+4, the encapsulation
    header; the tail after the reasons' block); None when an offset is not aligned as the
    kernel writes it."""
    msg = reaction_cdr(r, frame_id)
    hmk: list = []
    head = _reaction_head(frame_id, names, n_min, n_max, hmk)
    n = head[3]
    reasons = r.reasons
    block = _reason_blocks.get((tuple(reasons.items()), n % 4)) if reasons else _NO_REASONS[n % 4]
    if block is None:
        return None
    start = n + len(block)                              # where the cameras begin (as reaction_cdr)
    tmk: list = []
    tail = _reaction_tail(start % 8, cams, states, n_q, tmk)
    if len(_HEAD) + start + tail[3] != len(msg):
        return None
    hm = np.array([len(_HEAD) + x for x in hmk], dtype=np.int64)
    tm = np.array([len(_HEAD) + start + x for x in tmk], dtype=np.int64)
    if len(hm) != 10 or len(tm) != 3:
        return None
    m = len(names)
    f64_fields = [(hm[2], 4), (hm[3], n_min), (hm[4], n_max), (hm[8], m), (hm[9], m), (tm[0], len(cams)), (tm[1], 1),
                  (tm[2], n_q)]
    if any((o + _SHIFT) % 8 for o, k in f64_fields if k) or (hm[0] + _SHIFT) % 4 or (hm[1] + _SHIFT) % 4:
        return None                                     # (CDR aligns them so: never)
    return np.frombuffer(msg, dtype=np.uint8).copy(), hm, tm


def _f64(a, ndim: int):
    return a if (type(a) is np.ndarray and a.dtype == np.float64 and a.ndim == ndim) else None


def reaction_cdr_filled(r, frame_id: str) -> bytes:
    """``reaction_cdr(r, frame_id)`` (module docstring)."""
    qd_min, qd_max, dist, direc, q = (_f64(r.qd_min, 1), _f64(r.qd_max, 1), _f64(r.distance, 1),
                                      _f64(r.direction, 2), _f64(r.q, 1))
    watch, observed, rep = r.is_watch, r.observed, r.repulsion
    if (qd_min is None or qd_max is None or dist is None or direc is None or q is None or sys.byteorder != "little"
            or not (type(watch) is np.ndarray and watch.dtype == np.bool_ and watch.shape == dist.shape)
            or not (type(observed) is np.ndarray and observed.dtype == np.bool_ and observed.shape == dist.shape)
            or direc.shape != (len(dist), 3) or len(r.names) != len(dist)
            or not (type(rep) is np.ndarray and rep.shape == (3,))):
        return reaction_cdr(r, frame_id)
    reasons = r.reasons
    cams = tuple(r.cameras)
    statuses = [r.cameras[c] for c in cams]
    states = tuple([st.state for st in statuses])
    names = tuple(r.names)
    key = (frame_id, names, len(qd_min), len(qd_max), tuple(reasons.items()) if reasons else (), cams, states,
           len(q))
    lay = _layouts.get(key)
    if lay is None:
        if len(_layouts) > 256:
            _layouts.clear()
        lay = _layouts[key] = _layout(r, frame_id, names, len(qd_min), len(qd_max), cams, states, len(q))
    if lay is None:
        return reaction_cdr(r, frame_id)
    tmpl, hm, tm = lay
    views = getattr(_local, "views", None)
    if views is None or len(views[0]) < len(tmpl) + 16:
        buf = np.zeros(max(len(tmpl) + 16, 8192) // 8 * 8, dtype=np.uint8)
        views = _local.views = (buf, buf.view(np.float64), buf.view(np.int32))
    buf, f8, i4 = views
    ns = int(round(r.t * 1e9))
    if not 0 <= ns < 2**31 * 1_000_000_000:
        return reaction_cdr(r, frame_id)              # a stamp an int32 second does not hold: its error
    n = fill_reaction(tmpl, buf, f8, i4, hm, tm, ns // 1_000_000_000, ns % 1_000_000_000, float(r.override),
                      np.ascontiguousarray(rep, dtype=np.float64), np.ascontiguousarray(qd_min),
                      np.ascontiguousarray(qd_max), np.ascontiguousarray(watch), np.ascontiguousarray(observed),
                      np.ascontiguousarray(dist), np.ascontiguousarray(direc),
                      np.array([float(st.age_s) for st in statuses], dtype=np.float64), float(r.joints_age_s),
                      np.ascontiguousarray(q))
    return reaction_cdr(r, frame_id) if n < 0 else buf[_SHIFT:_SHIFT + n].tobytes()
