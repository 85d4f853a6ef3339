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
so it is the shortest repr of the rounded float, i.e. what ``json`` writes. A line with a
number that prints in exponent form (0 < |round(x, 6)| < 1e-4) or of 1e9 or more, or a
reaction whose record holds anything else than the usual finite values (a NaN distance, an
infinite term, an integer that is not an ``int``), is encoded by the reference path, which
raises the same ``ValueError`` where the record has one.
"""

from __future__ import annotations

import json
import math
from json.encoder import encode_basestring_ascii as _s

import numpy as np

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
    if names is not None and not (len(set(names)) == len(names) and all(type(n) is str for n in names)
                                  and len(names) == a.shape[1]):
        return False                     # the record's dict would merge or convert them
    return a is None or (isinstance(a, np.ndarray) and a.ndim == 2 and bool(np.isfinite(a).all()))


def _fast(r) -> str | None:
    names = r.names
    dist = r.distance
    direc = r.direction
    m = len(names)
    if not (isinstance(names, tuple) and type(dist) is np.ndarray and dist.shape == (m,)
            and type(direc) is np.ndarray and direc.shape == (m, 3) and dist.dtype == np.float64):
        return None
    finite = np.isfinite(dist)
    if np.isnan(dist).any():
        return None
    ssm = r.ssm
    parts = r.parts
    terms = [(n, p) for n, p in parts.items() if n != "ssm" and p.terms is not None] if parts else []
    if (ssm is not None and not _terms_ok(ssm)) or not all(_terms_ok(p.terms, p.term_names) for _, p in terms):
        return None
    n_ssm = 0 if ssm is None else min(len(ssm), m)
    cams = list(r.cameras.items())
    ja = r.joints_age_s
    if not isinstance(ja, float) or ja != ja:
        return None
    ja_fin = ja - ja == 0.0
    obs = r.observed
    key = (names, r.is_watch.tobytes(), finite.tobytes(), obs.tobytes(), n_ssm,
           tuple((n, p.term_names, len(p.terms)) for n, p in terms),
           tuple((c, st.state, st.age_s - st.age_s == 0.0) for c, st in cams), ja_fin, len(r.q),
           r.reaction_mode, bool(r.protective_stop))
    tpl = _templates.get(key)
    if tpl is None:
        if len(_templates) > 256:
            _templates.clear()
        tpl = _templates[key] = _template(r, finite.tolist(), obs.tolist(), n_ssm, terms, cams, ja_fin)
    # the numbers (and the few dynamic strings) in the order the line writes them
    vals = [float(r.t), float(r.override)]
    vals += r.repulsion.tolist()
    if n_ssm or terms:
        fin = finite.tolist()
        d_l, v_l = dist.tolist(), direc.tolist()
        for i in range(m):
            if fin[i]:
                vals.append(d_l[i])
                vals += v_l[i]
            if i < n_ssm:
                vals += ssm[i].tolist()
            for _, p in terms:
                if i < len(p.terms):
                    vals += p.terms[i].tolist()
    else:
        vals += np.concatenate((dist[:, None], direc), axis=1)[finite].ravel().tolist()
    vals.append(json.dumps(dict(r.reasons), allow_nan=False) if r.reasons else "{}")
    for _, st in cams:
        if type(st.frames) is not int or type(st.refused) is not int or not isinstance(st.age_s, float):
            return None
        if st.age_s - st.age_s == 0.0:
            vals.append(st.age_s)
        vals.append(st.frames)
        vals.append(st.refused)
    if ja_fin:
        vals.append(ja)
    vals += r.q.tolist()
    vals.append(float(r.speed_scale))
    vals.append(float(r.ssm_scale))
    own = {n: dict(p.record, scale=round(float(p.scale), 6), stop=bool(p.stop))
           for n, p in parts.items() if p.record} if parts else None
    vals.append(", \"policies\": " + json.dumps(own, allow_nan=False) if own else "")
    nums = [v for v in vals if type(v) is float]
    if not math.isfinite(sum(nums)) or max(map(abs, nums)) >= 1e9:
        return None                               # non-finite (the reference raises) or too large
    line = tpl % tuple(vals)
    # every number was written "%.6f\0": strip its trailing zeros as repr(round(x, 6)) does
    line = line.replace(".000000\x00", ".0\x01")
    for _ in range(5):
        if "0\x00" not in line:
            break
        line = line.replace("0\x00", "\x00")
    line = line.replace("\x00", "").replace("\x01", "")
    if "0.0000" in line:
        return None                               # exponent form (0 < |x| < 1e-4): the reference path
    return line
