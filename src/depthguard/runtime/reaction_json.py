"""One reaction as its JSON-lines record, written without the intermediate dicts (R31, issue 29).

:func:`reaction_json` returns exactly ``json.dumps(reaction.to_dict(), allow_nan=False)``
(the record of ``docs/MONITOR.md``), byte for byte, at a fraction of its cost: the log
line is written for every control cycle (500 Hz), and building the per-point dicts and
lists of :meth:`~depthguard.runtime.result.Reaction.to_dict` to have ``json`` walk them
again cost about 0.1 ms a line (measured 2026-11-26 on ur3-cell's eight control points).
The line's layout — its keys, names, which points have an obstacle within rho, which are
observed, the cameras' states — changes seldom; per layout a ``%``-template is made once
(strings escaped with ``json``'s own encoder) and every cycle fills it with one ``%`` call:
each number as ``%.6f`` (the correctly rounded digits of ``round(x, 6)``), its trailing
zeros then stripped — for |x| < 1e9 the 6-decimal string has at most 15 significant digits,
so it is the shortest repr of the rounded float, i.e. what ``json`` writes. A number that
``repr`` writes in exponent form (0 < |round(x, 6)| < 1e-4, ``%.6f`` gives ``0.0000dd``) is
rewritten as ``repr(float("0.0000dd"))`` (issue 29: such lines, ~6 % of a run's, took the
reference path at 3x the cost). A number of 1e9 or more, or a reaction whose record holds
anything else than the usual finite values (a NaN distance, an infinite term, an integer
that is not an ``int``), is encoded by the reference path, which raises the same
``ValueError`` where the record has one. Measured 2026-11-26 on ur3-cell's reactions (CPU,
A/B in one process): 116-132 us a line before, 55-64 us after.

The monitor's usual line — no policy with terms or a record of its own, float64 arrays — is
written by a compiled kernel instead (:func:`_compiled`, :mod:`depthguard.runtime.reaction_text`):
the same layout's literals made once from the template, the numbers written between them by
``encode_line`` with the same digits (``repr(round(x, 6))``, taken exactly); anything it
refuses goes to the template, then to the reference. Measured 2026-11-26 (CPU, A/B in one
process, ur3-cell's 1501 reactions of a ``--fast`` run, medians of 7 rounds): 52-61 us a line by
the template, 21-28 us by the kernel. Two things of a line are not in its compiled layout: the
reasons' JSON (an SSM reason's sentence carries the cycle's distances) is spliced in at a marker
byte, and a ``t`` of 1e9 s or more (a live source's wall clock) is written as
``repr(round(t, 6))`` in Python over the kernel's ``0.0`` (issue 29: before, every line of a
live run went through ``json.dumps``, the sinks thread at 0.35 cores beside franky-sim).
"""

from __future__ import annotations

import json
import math
import re
import threading
from itertools import repeat
from json.encoder import encode_basestring_ascii as _s

import numpy as np

from depthguard.runtime import reaction_text as T
from depthguard.runtime.result import _SSM_TERMS    # the record's own column names

__all__ = ["reaction_json", "reaction_json_reference"]

_BOOL = ("false", "true")
_NUM = "%.6f\x00"                   # a number: its digits, then a mark for the zero stripping
_templates: dict = {}


def reaction_json_reference(r) -> str:
    """The record as ``json`` writes it from :meth:`~depthguard.runtime.result.Reaction.to_dict`."""
    return json.dumps(r.to_dict(), allow_nan=False)


def reaction_json(r) -> str:
    """``json.dumps(r.to_dict(), allow_nan=False)`` (module docstring), for a
    :class:`~depthguard.runtime.result.Reaction`."""
    try:
        fast = _compiled(r)
        if fast is None:
            fast = _fast(r)
    except Exception:  # noqa: BLE001 - anything unusual: the reference path (and its error)
        fast = None
    return fast if fast is not None else reaction_json_reference(r)


def _lit(text: str) -> str:
    return text.replace("%", "%%")


def _template(r, fin, obs, n_ssm, terms, cams, ja_fin) -> str:
    """The ``%``-template of the line's layout (module docstring)."""
    out = ['{"t": ' + _NUM + ', "override": ' + _NUM + ', "repulsion": [' + ", ".join([_NUM] * 3) + '], "points": [']
    pts = []
    for i, n in enumerate(r.names):
        p = _lit(f'{{"name": {_s(n)}, "watch": {_BOOL[bool(r.is_watch[i])]}, "distance": ')
        if fin[i]:
            p += _NUM + ', "direction": [' + ", ".join([_NUM] * 3) + "]"
        else:
            p += 'null, "direction": null'
        p += ', "observed": ' + _BOOL[bool(obs[i])]
        if i < n_ssm:
            p += ', "ssm": {' + ", ".join([f'"{k}": {_NUM}' for k in _SSM_TERMS]) + "}"
        for name, part in terms:
            if i < len(part.terms):
                p += ", " + _lit(_s(name)) + ": {" + ", ".join([_lit(_s(k)) + ": " + _NUM for k in part.term_names]) + "}"
        pts.append(p + "}")
    out.append(", ".join(pts) + '], "reasons": %s, "cameras": {')
    cs = []
    for c, st in cams:
        age = _NUM if math.isfinite(st.age_s) else "null"
        cs.append(_lit(_s(c)) + ': {"age_s": ' + age + ', "state": ' + _lit(_s(st.state))
                  + ', "frames": %d, "refused": %d}')
    out.append(", ".join(cs) + '}, "joints_age_s": ' + (_NUM if ja_fin else "null") + ', "q": ['
               + ", ".join([_NUM] * len(r.q)) + '], "reaction_mode": ' + _lit(_s(r.reaction_mode))
               + ', "speed_scale": ' + _NUM + ', "protective_stop": ' + _BOOL[bool(r.protective_stop)]
               + ', "ssm_scale": ' + _NUM + "%s}")
    return "".join(out)


def _terms_ok(a, names=None) -> bool:
    """A terms table the template can write: a 2-D array whose columns are ``names`` (distinct
    strings), or the 13 SSM columns; its values' finiteness is checked with the line's numbers."""
    if not (type(a) is np.ndarray and a.ndim == 2):
        return False
    if names is None:
        return a.shape[1] == len(_SSM_TERMS)
    return (len(set(names)) == len(names) and all(type(n) is str for n in names)  # the dict would merge them
            and len(names) == a.shape[1])


#: a number that ``%.6f`` writes as ``0.0000dd`` (0 < |round(x, 6)| < 1e-4): ``repr`` writes it in
#: exponent form (``3.2e-05``); not one inside another number (``10.000032``)
_EXPONENT = re.compile("0\\.0000(?:0[1-9]|[1-9][0-9])\x00")
_ZEROS = repeat("0")
_reasons_json: dict = {}            # the reasons' items -> their JSON (they change seldom)


def _exponent(m) -> str:
    i = m.start()
    if i and m.string[i - 1] in "0123456789":
        return m.group()                             # the tail of another number (10.000032)
    return repr(float(m.group()[:-1])) + "\x01"      # float("%.6f" % x) is round(x, 6); a sign stays


def _fast(r) -> str | None:
    """The line, or None where the reference path must write it (module docstring)."""
    names = r.names
    dist = r.distance
    direc = r.direction
    if not (type(names) is tuple and type(dist) is np.ndarray and type(direc) is np.ndarray
            and dist.dtype == np.float64):
        return None
    m = len(names)
    if dist.shape != (m,) or direc.shape != (m, 3):
        return None
    d_l = dist.tolist()
    fin = tuple([x - x == 0.0 for x in d_l])          # inf - inf and nan - nan are nan
    for x in d_l:
        if x != x:
            return None                               # a NaN distance: the reference raises
    ssm = r.ssm
    parts = r.parts
    terms = [(n, p) for n, p in parts.items() if n != "ssm" and p.terms is not None] if parts else ()
    if ssm is not None and not _terms_ok(ssm):
        return None
    for _, p in terms:
        if not _terms_ok(p.terms, p.term_names):
            return None
    n_ssm = 0 if ssm is None else min(len(ssm), m)
    cams = r.cameras
    ja = r.joints_age_s
    if type(ja) is not float or ja != ja:
        return None
    ja_fin = ja - ja == 0.0
    c_key = []
    tail = []                                         # the cameras' numbers, in the line's order
    for c, st in cams.items():
        age = st.age_s
        if type(st.frames) is not int or type(st.refused) is not int or type(age) is not float:
            return None
        a_fin = age - age == 0.0
        c_key.append((c, st.state, a_fin))
        if a_fin:
            tail.append(age)
        tail.append(st.frames)
        tail.append(st.refused)
    q_l = r.q.tolist()
    key = (names, r.is_watch.tobytes(), fin, r.observed.tobytes(), n_ssm,
           tuple([(n, p.term_names, len(p.terms)) for n, p in terms]) if terms else (),
           tuple(c_key), ja_fin, len(q_l), r.reaction_mode, bool(r.protective_stop))
    tpl = _templates.get(key)
    if tpl is None:
        if len(_templates) > 256:
            _templates.clear()
        tpl = _templates[key] = _template(r, list(fin), r.observed.tolist(), n_ssm, terms, list(cams.items()),
                                          ja_fin)
    # the numbers, in the order the line writes them; every float is in `fl` for the checks
    fl = [float(r.t), float(r.override)]
    fl += r.repulsion.tolist()
    v_l = direc.tolist()
    if n_ssm or terms:
        s_l = ssm.tolist() if n_ssm else None
        t_l = [(len(p.terms), p.terms.tolist()) for _, p in terms]
        for i in range(m):
            if fin[i]:
                fl.append(d_l[i])
                fl += v_l[i]
            if i < n_ssm:
                fl += s_l[i]
            for n_t, rows in t_l:
                if i < n_t:
                    fl += rows[i]
    else:
        for i in range(m):
            if fin[i]:
                fl.append(d_l[i])
                fl += v_l[i]
    fl2 = [ja] if ja_fin else []
    fl2 += q_l
    fl2.append(float(r.speed_scale))
    fl2.append(float(r.ssm_scale))
    for x in fl:
        if type(x) is not float:
            return None                               # the record's round() would raise or convert
    for x in tail:
        if type(x) is float:
            fl2.append(x)
    s = sum(fl) + sum(fl2)
    if s - s != 0.0 or max(fl) >= 1e9 or min(fl) <= -1e9 or max(fl2) >= 1e9 or min(fl2) <= -1e9:
        return None                                   # non-finite (the reference raises) or too large
    reasons = r.reasons
    fl.append(_reasons_text(reasons) if reasons else "{}")
    fl += tail
    if ja_fin:
        fl.append(ja)
    fl += q_l
    fl.append(float(r.speed_scale))
    fl.append(float(r.ssm_scale))
    own = {n: dict(p.record, scale=round(float(p.scale), 6), stop=bool(p.stop))
           for n, p in parts.items() if p.record} if parts else None
    fl.append(", \"policies\": " + json.dumps(own, allow_nan=False) if own else "")
    line = tpl % tuple(fl)
    # every number was written "%.6f\0": strip its trailing zeros as repr(round(x, 6)) does
    line = line.replace(".000000\x00", ".0\x01")
    if "0.0000" in line:                              # seldom (the zeros are gone): a tiny number?
        line = _EXPONENT.sub(_exponent, line)
    # every number left ends at a \0 with a nonzero decimal: its zeros stripped segment by segment
    return "".join(map(str.rstrip, line.split("\x00"), _ZEROS)).replace("\x01", "")


_programs: dict = {}                # layout key (the reasons apart) -> the compiled writer's program
_SLOT = re.compile("(%\\.6f\x00|%d|%s|%%)")
_local = threading.local()          # each thread's output buffer (the sinks' thread: one)


def _program(tpl: str, rj: str, fin, n_ssm: int, cam_fin, ja_fin: bool, n_q: int):
    """``(lits, lit_off, src, idx)`` of :func:`~depthguard.runtime.reaction_text.encode_line` for
    the layout of ``tpl`` with the reasons ``rj``: the template's literals (its ``%%`` undone, the
    reasons in, no policies' record) and its number slots, the values' sources in the order the
    template writes them (:func:`_fast`'s ``fl``); None if the template's slots do not match."""
    slots = [(T.SRC_SCALAR, 0), (T.SRC_SCALAR, 1), (T.SRC_SCALAR, 2), (T.SRC_SCALAR, 3), (T.SRC_SCALAR, 4)]
    for i, f in enumerate(fin):
        if f:
            slots += [(T.SRC_DISTANCE, i)] + [(T.SRC_DIRECTION, 3 * i + c) for c in range(3)]
        if i < n_ssm:
            slots += [(T.SRC_SSM, len(_SSM_TERMS) * i + c) for c in range(len(_SSM_TERMS))]
    for c, a_fin in enumerate(cam_fin):
        if a_fin:
            slots.append((T.SRC_SCALAR, 8 + c))
        slots += [(T.SRC_INT, 2 * c), (T.SRC_INT, 2 * c + 1)]
    if ja_fin:
        slots.append((T.SRC_SCALAR, 5))
    slots += [(T.SRC_Q, i) for i in range(n_q)] + [(T.SRC_SCALAR, 6), (T.SRC_SCALAR, 7)]
    lits, cur, k, strings = [], [], 0, [rj, ""]
    for tok in _SLOT.split(tpl):
        if tok == "%%":
            cur.append("%")
        elif tok == "%s":
            cur.append(strings.pop(0))
        elif tok in (_NUM, "%d"):
            if k >= len(slots) or (tok == "%d") != (slots[k][0] == T.SRC_INT):
                return None
            lits.append("".join(cur))
            cur = []
            k += 1
        else:
            cur.append(tok)
    lits.append("".join(cur))
    if k != len(slots) or strings:
        return None
    b = [x.encode("ascii") for x in lits]
    off = np.zeros(len(b) + 1, dtype=np.int64)
    off[1:] = np.cumsum([len(x) for x in b])
    return (np.frombuffer(b"".join(b), dtype=np.uint8).copy(), off, np.array([s for s, _ in slots], dtype=np.int64),
            np.array([i for _, i in slots], dtype=np.int64), int(off[-1]) + T.SLOT_BYTES * len(slots))


def _compiled(r) -> str | None:
    """The line written by :func:`~depthguard.runtime.reaction_text.encode_line` (issue 29): for
    a reaction whose arrays are float64 and whose policies add no terms or record of their own
    (the monitor's usual line); None: :func:`_fast` writes it. Per cycle only the layout's key
    and the numbers are gathered in Python."""
    names, dist, direc, rep, q = r.names, r.distance, r.direction, r.repulsion, r.q
    if not (type(names) is tuple and type(dist) is np.ndarray and dist.dtype == np.float64
            and type(direc) is np.ndarray and direc.dtype == np.float64 and type(rep) is np.ndarray
            and rep.dtype == np.float64 and rep.shape == (3,) and type(q) is np.ndarray and q.dtype == np.float64
            and q.ndim == 1):
        return None
    m = len(names)
    if dist.shape != (m,) or direc.shape != (m, 3):
        return None
    parts = r.parts
    if parts:
        for name, p in parts.items():
            if p.record or (name != "ssm" and p.terms is not None):
                return None                           # a policy's own terms or record: _fast
    ssm = r.ssm
    if ssm is None:
        n_ssm, ssm = 0, _NO_SSM
    elif _terms_ok(ssm) and ssm.dtype == np.float64:
        n_ssm = min(len(ssm), m)
    else:
        return None
    fin = np.isfinite(dist)
    fb = fin.tobytes()
    if fb.count(0) and np.isnan(dist).any():
        return None                                   # a NaN distance: the reference raises
    ja = r.joints_age_s
    if type(ja) is not float or ja != ja:
        return None
    ja_fin = ja - ja == 0.0
    t = float(r.t)
    # a live source's clock is the wall clock (~1.8e9 s), beyond the compiled numbers' range
    # (|x| < 1e9): the line is written with t = 0.0 and its first number put back as the record
    # writes it, repr(round(t, 6)) (issue 29: every line of a live run took the reference path)
    t_text = repr(round(t, 6)) if (t >= 1e9 or t <= -1e9) and t - t == 0.0 else None
    scal = [0.0 if t_text is not None else t, float(r.override), *rep.tolist(), ja, float(r.speed_scale),
            float(r.ssm_scale)]
    ints = []
    c_key = []
    cams = r.cameras
    for c, st in cams.items():
        age = st.age_s
        if type(st.frames) is not int or type(st.refused) is not int or type(age) is not float:
            return None
        c_key.append((c, st.state, age - age == 0.0))
        scal.append(age)
        ints.append(st.frames)
        ints.append(st.refused)
    reasons = r.reasons
    rj = _reasons_text(reasons) if reasons else "{}"
    # the reasons are not part of the layout (issue 29: an SSM reason's sentence carries the cycle's
    # distances, 2,067 distinct sets in 3,818 cycles of fr3-cell, and a program made per line kept
    # the sinks thread at 0.48 cores): the program writes _REASONS where they go, spliced below
    key = (names, r.is_watch.tobytes(), fb, r.observed.tobytes(), n_ssm, tuple(c_key), ja_fin, len(q),
           r.reaction_mode, bool(r.protective_stop))
    prog = _programs.get(key)
    if prog is None:
        if len(_programs) > 256:
            _programs.clear()
        fin_l = fin.tolist()
        tpl = _template(r, fin_l, r.observed.tolist(), n_ssm, (), list(cams.items()), ja_fin)
        prog = _programs[key] = _program(tpl, _REASONS, fin_l, n_ssm, [k[2] for k in c_key], ja_fin, len(q))
    if prog is None:
        return None
    lits, off, src, idx, size = prog
    out = getattr(_local, "out", None)
    if out is None or len(out) < size:
        out = _local.out = np.empty(max(size, 4096), dtype=np.uint8)
    n = T.encode_line(lits, off, src, idx, np.array(scal, dtype=np.float64), np.ascontiguousarray(dist),
                      np.ascontiguousarray(direc), np.ascontiguousarray(ssm), np.ascontiguousarray(q),
                      np.array(ints, dtype=np.int64), out)
    if n < 0:
        return None
    line = out[:n].tobytes().decode("ascii")
    if t_text is not None:
        if not line.startswith(_T_ZERO):
            return None
        line = '{"t": ' + t_text + line[len(_T_ZERO) - 1:]
    # the one _REASONS byte of the line (names and sentences are JSON-escaped: "\u0001")
    return line.replace(_REASONS, rj, 1) if line.count(_REASONS) == 1 else None


#: how a line written with t = 0.0 starts (the record's first key, then its value)
_T_ZERO = '{"t": 0.0,'

#: where a program writes the reasons' JSON object (spliced in per line; no JSON text holds it raw)
_REASONS = "\x01"

_NO_SSM = np.zeros((0, len(_SSM_TERMS)))


def _reasons_text(reasons) -> str:
    """The reasons' JSON object, made once per distinct set of reasons (kept for up to 256 sets)."""
    items = tuple(reasons.items())
    rj = _reasons_json.get(items)
    if rj is None:
        if len(_reasons_json) > 256:
            _reasons_json.clear()
        rj = _reasons_json[items] = json.dumps(dict(reasons), allow_nan=False)
    return rj
