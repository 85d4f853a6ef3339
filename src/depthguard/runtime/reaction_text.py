"""The log line's numbers written by a compiled kernel (R31, issue 29).

:func:`encode_line` writes a JSON-lines record of ``docs/MONITOR.md`` into a byte buffer: the
layout's literal text (keys, names, ``null`` for a missing distance, the reasons) is fixed per
layout by :mod:`depthguard.runtime.reaction_json`, and the kernel fills the number slots between
the literals in one pass, under the GIL for a few microseconds instead of the ~50 us of Python
string work a 500 Hz line cost (measured 2026-11-26, ur3-cell).

A float slot is written as ``json`` writes ``round(x, 6)`` (:func:`num_text`): the correctly
rounded (half to even, on the exact binary value) integer ``k`` of ``x * 1e6`` — ``x * 1e6``
and its rounding error are taken exactly (Dekker's product), so no tie is decided on a rounded
product — then, as ``repr`` of the rounded float, the decimal ``k / 1e6`` with its trailing zeros
stripped (``-0.0`` keeps its sign; below 1e-4, ``repr``'s exponent form ``3.2e-05``). For
``|x| < 1e9`` that is ``repr(round(x, 6))`` (at most 15 significant digits: the shortest
decimal of the rounded float); a larger, infinite or NaN number makes the kernel return -1 and
the caller writes the line the reference way. An int slot (a camera's frame counters) is its
decimal. ``tests/test_reaction_json.py`` checks the lines against ``json.dumps(r.to_dict())``
and :func:`num_text` against ``repr(round(x, 6))`` (its twin :func:`num_text_reference`).
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["encode_line", "warm_up", "num_text", "num_text_reference", "SRC_SCALAR", "SRC_DISTANCE", "SRC_DIRECTION",
           "SRC_SSM", "SRC_Q", "SRC_INT", "SLOT_BYTES"]

#: where a slot's value comes from (the program's ``src``; ``idx`` indexes that array, flat)
SRC_SCALAR, SRC_DISTANCE, SRC_DIRECTION, SRC_SSM, SRC_Q, SRC_INT = 0, 1, 2, 3, 4, 5
#: the most bytes one slot writes (a sign, 9 + 6 digits and a point; an int64's 20 characters)
SLOT_BYTES = 24


@numba.njit(cache=True)
def _digits(v, out, n):
    """The decimal of ``v`` >= 0 (int64) at ``out[n:]``; the new end."""
    if v == 0:
        out[n] = 48
        return n + 1
    k = 0
    w = v
    while w > 0:
        w //= 10
        k += 1
    for j in range(k - 1, -1, -1):
        out[n + j] = 48 + v % 10
        v //= 10
    return n + k


@numba.njit(cache=True)
def _num(x, out, n):
    """``repr(round(x, 6))`` (module docstring) at ``out[n:]``; the new end, or -1 where
    ``x`` is not finite or ``|x| >= 1e9``."""
    if not (x - x == 0.0):
        return -1
    a = abs(x)
    if a >= 1e9:
        return -1
    neg = math.copysign(1.0, x) < 0.0
    k = 0
    if a >= 1e-7:                                     # below, x * 1e6 < 0.1 rounds to 0
        p = a * 1e6
        c = 134217729.0 * a                           # Veltkamp's split of a (1e6 has 20 bits: exact)
        ah = c - (c - a)
        al = a - ah
        e = (ah * 1e6 - p) + al * 1e6                 # a * 1e6 == p + e exactly (Dekker)
        k0 = math.floor(p)
        d = ((p - k0) - 0.5) + e                      # the exact fraction's excess over a half; its sign
        k = np.int64(k0)
        if d > 0.0 or (d == 0.0 and k % 2 == 1):
            k += 1
    if neg:
        out[n] = 45                                   # "-"
        n += 1
    if k == 0:
        out[n] = 48
        out[n + 1] = 46
        out[n + 2] = 48
        return n + 3
    if k < 100:                                       # below 1e-4: repr's exponent form
        if k < 10:
            out[n] = 48 + k
            n += 1
            tail = 54                                 # e-06
        else:
            out[n] = 48 + k // 10
            n += 1
            if k % 10:
                out[n] = 46
                out[n + 1] = 48 + k % 10
                n += 2
            tail = 53                                 # e-05
        out[n] = 101
        out[n + 1] = 45
        out[n + 2] = 48
        out[n + 3] = tail
        return n + 4
    n = _digits(k // 1000000, out, n)
    out[n] = 46                                       # "."
    n += 1
    f = k % 1000000
    if f == 0:
        out[n] = 48
        return n + 1
    w = 6
    while f % 10 == 0:
        f //= 10
        w -= 1
    for j in range(w - 1, -1, -1):
        out[n + j] = 48 + f % 10
        f //= 10
    return n + w


@numba.njit(cache=True)
def encode_line(lits, lit_off, src, idx, scal, dist, direc, ssm, q, ints, out):
    """The line into ``out`` (uint8, at least ``len(lits) + SLOT_BYTES * len(src)``); returns its
    length, or -1 where a number cannot be written (module docstring).

    ``lits`` (uint8): the literals, literal ``j`` = ``lits[lit_off[j]:lit_off[j + 1]]``
    (``len(src) + 1`` of them, slot ``j`` between literals ``j`` and ``j + 1``); slot ``j``'s value:
    ``src[j]`` (``SRC_*``) and ``idx[j]`` into ``scal`` (float64), ``dist`` (m,), ``direc`` (m, 3),
    ``ssm`` (n, 13), ``q`` (dof,), all float64, or ``ints`` (int64)."""
    if len(lit_off) != len(src) + 2 or len(idx) != len(src) or lit_off[-1] > len(lits) \
            or len(out) < lit_off[-1] + SLOT_BYTES * len(src):
        return -1                                     # not a program for these buffers (never the writer's)
    n = 0
    for j in range(len(src)):
        for b in range(lit_off[j], lit_off[j + 1]):
            out[n] = lits[b]
            n += 1
        s = src[j]
        i = idx[j]
        if i < 0 or i >= (len(ints) if s == SRC_INT else len(scal) if s == SRC_SCALAR else dist.size
                          if s == SRC_DISTANCE else direc.size if s == SRC_DIRECTION else ssm.size
                          if s == SRC_SSM else q.size):
            return -1                                 # a slot beyond its array: the layout does not fit
        if s == SRC_INT:
            v = ints[i]
            if v < 0:
                out[n] = 45
                n += 1
                v = -v
            n = _digits(v, out, n)
            continue
        if s == SRC_SCALAR:
            x = scal[i]
        elif s == SRC_DISTANCE:
            x = dist[i]
        elif s == SRC_DIRECTION:
            x = direc[i // 3, i % 3]
        elif s == SRC_SSM:
            x = ssm[i // ssm.shape[1], i % ssm.shape[1]]
        else:
            x = q[i]
        n = _num(x, out, n)
        if n < 0:
            return -1
    for b in range(lit_off[len(src)], lit_off[len(src) + 1]):
        out[n] = lits[b]
        n += 1
    return n


def num_text(x: float) -> str | None:
    """What :func:`encode_line` writes for the float ``x`` (None: it would refuse the line)."""
    out = np.empty(SLOT_BYTES, dtype=np.uint8)
    n = _num(float(x), out, 0)
    return None if n < 0 else out[:n].tobytes().decode("ascii")


def num_text_reference(x: float) -> str | None:
    """The twin of :func:`num_text`: ``json.dumps(round(x, 6))`` for a finite ``|x| < 1e9``."""
    if not math.isfinite(x) or abs(x) >= 1e9:
        return None
    return repr(round(x, 6))


def warm_up() -> None:
    """Compile (or load from numba's disk cache) :func:`encode_line` for the arrays the log's
    writer passes, before a run's clock starts (a first line would otherwise pay it under the GIL)."""
    f = np.zeros(1)
    encode_line(np.zeros(1, dtype=np.uint8), np.zeros(3, dtype=np.int64), np.zeros(1, dtype=np.int64),
                np.zeros(1, dtype=np.int64), f, f, np.zeros((1, 3)), np.zeros((0, 13)), f, np.zeros(1, dtype=np.int64),
                np.zeros(64, dtype=np.uint8))
