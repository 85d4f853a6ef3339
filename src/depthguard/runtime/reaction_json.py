"""One reaction as its JSON-lines record, written without the intermediate dicts (R31, issue 29).

:func:`reaction_json` returns exactly ``json.dumps(reaction.to_dict(), allow_nan=False)``
(the record of ``docs/MONITOR.md``), byte for byte, at a fraction of its cost: the log
line is written for every control cycle (500 Hz), and building the per-point dicts and
lists of :meth:`~depthguard.runtime.result.Reaction.to_dict` to have ``json`` walk them
again cost about 0.1 ms a line (measured 2026-11-26 on ur3-cell's eight control points).
Every number is formatted as the record formats it — ``round(x, 6)``, then ``float.__repr__``
(what ``json`` writes for a float) — and every string with ``json``'s own encoder. A
reaction whose record holds anything else than the usual finite values (a NaN distance, an
infinite term, an integer that is not an ``int``) is encoded by the reference path, which
raises the same ``ValueError``.
"""

from __future__ import annotations

import json
import math
from json.encoder import encode_basestring_ascii as _s

import numpy as np

from depthguard.runtime.result import _SSM_TERMS    # the record's own column names

__all__ = ["reaction_json", "reaction_json_reference"]

_BOOL = ("false", "true")
_names_cache: dict = {}


def reaction_json_reference(r) -> str:
    """The record as ``json`` writes it from :meth:`~depthguard.runtime.result.Reaction.to_dict`."""
    return json.dumps(r.to_dict(), allow_nan=False)


def _numbers(values: list) -> list[str]:
    """``repr(round(v, 6))`` of each float in ``values`` — what the record writes — made with one
    ``%.6f`` pass (the same correctly rounded digits as ``round``; |v| < 1e9 has at most 15
    significant digits, so the shortest repr of the rounded float is those digits with the
    trailing zeros stripped); values that print in exponent form (0 < |round(v, 6)| < 1e-4) or are
    1e9 or more are formatted one by one."""
    n = len(values)
    if n == 0:
        return []
    text = (("%.6f|" * n) % tuple(values)).replace(".000000|", ".0#")
    for _ in range(5):                  # the trailing zeros of the other fractions, one a pass (C speed)
        if "0|" not in text:
            break
        text = text.replace("0|", "|")
    text = text.replace("#", "|")
    out = text.split("|")
    out.pop()
    if "0.0000" in text or max(map(abs, values)) >= 1e9:
        for i, x in enumerate(out):
            if x.startswith(("0.0000", "-0.0000", "1", "2", "3", "4", "5", "6", "7", "8", "9", "-")) \
                    and (len(x) > 16 or "0.0000" in x):
                out[i] = repr(round(values[i], 6))
    return out


def _heads(names, is_watch) -> tuple[str, ...]:
    """Per point ``{"name": ..., "watch": ..., "distance": `` (made once per point set)."""
    key = (names, is_watch.tobytes())
    heads = _names_cache.get(key)
    if heads is None:
        if len(_names_cache) > 64:
            _names_cache.clear()
        heads = tuple(f'{{"name": {_s(n)}, "watch": {_BOOL[bool(w)]}, "distance": '
                      for n, w in zip(names, is_watch.tolist()))
        _names_cache[key] = heads
    return heads


def _terms_ok(a, names=None) -> bool:
    if names is not None and not (len(set(names)) == len(names) and all(type(n) is str for n in names)):
        return False                     # the record's dict would merge or convert them
    return a is None or (isinstance(a, np.ndarray) and a.ndim == 2 and bool(np.isfinite(a).all()))


def reaction_json(r) -> str:
    """``json.dumps(r.to_dict(), allow_nan=False)`` (module docstring), for a
    :class:`~depthguard.runtime.result.Reaction`."""
    try:
        fast = _fast(r)
    except Exception:  # noqa: BLE001 - anything unusual: the reference path (and its error)
        fast = None
    return fast if fast is not None else reaction_json_reference(r)


def _fast(r) -> str | None:
    names = r.names
    dist = r.distance
    direc = r.direction
    m = len(names)
    if not (isinstance(names, tuple) and isinstance(dist, np.ndarray) and dist.shape == (m,)
            and isinstance(direc, np.ndarray) and direc.shape == (m, 3)):
        return None
    finite = np.isfinite(dist)
    if np.isnan(dist).any() or not np.isfinite(direc[finite]).all():
        return None
    ssm = r.ssm
    terms = [(n, p) for n, p in r.parts.items() if n != "ssm" and p.terms is not None]
    if not _terms_ok(ssm) or not all(_terms_ok(p.terms, p.term_names) for _, p in terms):
        return None
    rep, q = r.repulsion.tolist(), r.q.tolist()
    head = [float(r.t), float(r.override)]
    tail = [float(r.speed_scale), float(r.ssm_scale)]
    if len(rep) != 3 or not math.isfinite(sum(rep) + sum(q) + sum(head) + sum(tail)):
        return None
    ja = r.joints_age_s
    if not isinstance(ja, float) or ja != ja:
        return None
    cams = list(r.cameras.items())
    ages = []
    for _, s in cams:
        age = s.age_s
        if type(s.frames) is not int or type(s.refused) is not int or not isinstance(age, float) or age != age:
            return None
        if math.isfinite(age):
            ages.append(age)
    heads = _heads(names, np.asarray(r.is_watch, dtype=bool))
    obs = r.observed.tolist()
    fin = finite.tolist()
    n_ssm = 0 if ssm is None else min(len(ssm), m)
    # every number of the record in the order it is written
    vals = head + rep
    per_point = np.concatenate([dist[:, None], direc], axis=1)[finite]
    vals += per_point.ravel().tolist()
    if n_ssm:
        vals += ssm[:n_ssm].ravel().tolist()
    for _, p in terms:
        vals += p.terms[:m].ravel().tolist()
    vals += ages
    if math.isfinite(ja):
        vals.append(ja)
    vals += q
    vals += tail
    nx = iter(_numbers(vals)).__next__
    t_s, k_s = nx(), nx()
    rep_s = f"[{nx()}, {nx()}, {nx()}]"
    pts = []
    for i in range(m):
        if fin[i]:
            body = (f"{heads[i]}{nx()}, \"direction\": [{nx()}, {nx()}, {nx()}], \"observed\": "
                    f"{_BOOL[bool(obs[i])]}")
        else:
            body = f"{heads[i]}null, \"direction\": null, \"observed\": {_BOOL[bool(obs[i])]}"
        pts.append(body)
    for i in range(n_ssm):
        pts[i] += ", \"ssm\": {" + ", ".join([f"\"{k}\": {nx()}" for k in _SSM_TERMS]) + "}"
    part_s = []
    for name, p in terms:
        keys = [_s(k) for k in p.term_names]
        rows = [", " + _s(name) + ": {" + ", ".join([f"{k}: {nx()}" for k in keys]) + "}"
                for _ in range(min(len(p.terms), m))]
        part_s.append(rows)
    for rows in part_s:
        for i, row in enumerate(rows):
            pts[i] += row
    cam_s = []
    for c, s in cams:
        age = nx() if math.isfinite(s.age_s) else "null"
        cam_s.append(f"{_s(c)}: {{\"age_s\": {age}, \"state\": {_s(s.state)}, \"frames\": {s.frames!r}, "
                     f"\"refused\": {s.refused!r}}}")
    ja_s = nx() if math.isfinite(ja) else "null"
    q_s = "[" + ", ".join([nx() for _ in q]) + "]"
    line = (f"{{\"t\": {t_s}, \"override\": {k_s}, \"repulsion\": {rep_s}, "
            f"\"points\": [{'}, '.join(pts)}}}], "
            f"\"reasons\": {json.dumps(dict(r.reasons), allow_nan=False) if r.reasons else '{}'}, "
            f"\"cameras\": {{{', '.join(cam_s)}}}, \"joints_age_s\": {ja_s}, \"q\": {q_s}, "
            f"\"reaction_mode\": {_s(r.reaction_mode)}, \"speed_scale\": {nx()}, "
            f"\"protective_stop\": {_BOOL[bool(r.protective_stop)]}, \"ssm_scale\": {nx()}")
    own = {n: dict(p.record, scale=round(float(p.scale), 6), stop=bool(p.stop))
           for n, p in r.parts.items() if p.record}
    if own:
        line += ", \"policies\": " + json.dumps(own, allow_nan=False)
    return line + "}"
