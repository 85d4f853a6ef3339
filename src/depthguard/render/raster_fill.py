"""The rasteriser's fill and read-out (R16): :mod:`depthguard.render.raster`'s kernels draw each
set-up triangle with :func:`_fill` and read the z-buffer out with :func:`read_out_rows`.

Per row of the image the fill keeps the hull ``[a, b)`` of the pixels its triangles cover
(``rows`` (H, 2) int32, ``(W, 0)`` = none yet): the read-out then visits only those pixels and
the last call's (``spans`` (H, 2) int32, ``(0, 0)`` = none), not the whole box of the drawn
triangles — a person's box in a 640x480 D435 holds 3x the pixels the person covers (issue 29).
The spans are also the layer's: the pixels outside a row's span are 0 (nothing), so a frame's
compositing (:class:`~depthguard.sources.layered.LayeredCamera`) takes them as they are.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["read_out_rows", "read_out_depth_rows", "reset_rows"]


@njit(cache=True, error_model="numpy", inline="always")
def _inside(x, A0, X0, r0, t0, A1, X1, r1, t1, A2, X2, r2, t2):
    """Pixel centre at column ``x`` of a row covered (edge values ``A (x - X) + r``, top-left ties)."""
    e0 = A0 * (x - X0) + r0
    if e0 < 0.0 or (e0 == 0.0 and not t0):
        return False
    e1 = A1 * (x - X1) + r1
    if e1 < 0.0 or (e1 == 0.0 and not t1):
        return False
    e2 = A2 * (x - X2) + r2
    if e2 < 0.0 or (e2 == 0.0 and not t2):
        return False
    return True


@njit(cache=True, error_model="numpy", inline="always")
def _fill(key, A0, B0, X0, Y0, A1, B1, X1, Y1, A2, B2, X2, Y2, Pa, Pb, xw, yw, w0, tl, ua, ub, va, vb,
          wbuf, sbuf, rows, ids=True):
    """Z-buffer one set-up triangle (``key`` = its face) into rows ``va .. vb``, columns
    ``ua .. ub``: where it covers a pixel centre with a larger ``w = 1/z`` (strictly: on an
    exact tie the triangle drawn first keeps the pixel), ``wbuf = w`` and ``sbuf = key``
    (``ids`` False: a depth-only render, ``sbuf`` is not touched: ``wbuf > 0`` is the pixel's
    "drawn", as a winning ``w`` is > 0).
    ``rows`` (H, 2) int32: per row the hull ``[a, b)`` of the pixels covered so far, grown."""
    t0 = (tl & 1) != 0
    t1 = (tl & 2) != 0
    t2 = (tl & 4) != 0
    if ub - ua < 4:  # a few columns: test each pixel, without branches (the tests of
        nt0 = not t0  # _inside, evaluated in full: most faces here cover a pixel or two)
        nt1 = not t1
        nt2 = not t2
        for v in range(va, vb + 1):
            y = float(v)
            r0e = B0 * (y - Y0)
            r1e = B1 * (y - Y1)
            r2e = B2 * (y - Y2)
            rp = w0 + Pb * (y - yw)
            lo = ub + 1                            # the row's covered pixels: [lo, hi)
            hi = ua
            for u in range(ua, ub + 1):
                x = float(u)
                e0 = A0 * (x - X0) + r0e
                e1 = A1 * (x - X1) + r1e
                e2 = A2 * (x - X2) + r2e
                out = (int(e0 < 0.0) | int((e0 == 0.0) & nt0) | int(e1 < 0.0) | int((e1 == 0.0) & nt1)
                       | int(e2 < 0.0) | int((e2 == 0.0) & nt2))
                w = Pa * (x - xw) + rp
                old = wbuf[v, u]
                win = int(w > old) & (1 - out)
                wbuf[v, u] = max(old, w * win)     # w > old >= 0 where it wins, else old
                if ids:
                    s0 = sbuf[v, u]
                    sbuf[v, u] = s0 + (key - s0) * win
                lo = min(lo, u if out == 0 else lo)
                hi = max(hi, u + 1 if out == 0 else hi)
            if hi > lo:
                rows[v, 0] = min(rows[v, 0], lo)
                rows[v, 1] = max(rows[v, 1], hi)
        return
    i0 = 1.0 / A0 if A0 != 0.0 else 0.0
    i1 = 1.0 / A1 if A1 != 0.0 else 0.0
    i2 = 1.0 / A2 if A2 != 0.0 else 0.0
    for v in range(va, vb + 1):
        y = float(v)
        r0e = B0 * (y - Y0)
        r1e = B1 * (y - Y1)
        r2e = B2 * (y - Y2)
        rp = w0 + Pb * (y - yw)
        # The covered pixels of a row form one interval (each edge test is monotone
        # in x, also in floating point). Estimate its ends from the edge crossings
        # x_i = X_i - r_i / A_i; where every crossing lies farther than M from the
        # pixel centres that decide (M: 1e-9 of the coordinates' size, a million
        # times the rounding of an edge value and of x_i), the ends are exact as they
        # are; else settle them with the exact tests. Then fill without testing.
        x0 = X0 - r0e * i0
        x1 = X1 - r1e * i1
        x2 = X2 - r2e * i2
        lo = float(ua)
        hi = float(ub)
        if A0 > 0.0:
            lo = max(lo, x0)
        elif A0 < 0.0:
            hi = min(hi, x0)
        elif r0e < 0.0 or (r0e == 0.0 and not t0):
            continue
        if A1 > 0.0:
            lo = max(lo, x1)
        elif A1 < 0.0:
            hi = min(hi, x1)
        elif r1e < 0.0 or (r1e == 0.0 and not t1):
            continue
        if A2 > 0.0:
            lo = max(lo, x2)
        elif A2 < 0.0:
            hi = min(hi, x2)
        elif r2e < 0.0 or (r2e == 0.0 and not t2):
            continue
        if lo > hi + 1.0:
            continue
        a = max(ua, int(math.ceil(lo)))
        e = min(ub, int(math.floor(hi)))
        fa = float(a)
        fe = float(e)
        M = 1e-9 * (1.0 + abs(fa) + abs(fe) + abs(X0) + abs(X1) + abs(X2)
                    + abs(r0e * i0) + abs(r1e * i1) + abs(r2e * i2))
        sure = ((a == ua) | (lo - (fa - 1.0) > M)) & ((e == ub) | ((fe + 1.0) - hi > M))
        sure &= ((A0 > 0.0) & (fa - x0 > M)) | ((A0 < 0.0) & (x0 - fe > M)) | (A0 == 0.0)
        sure &= ((A1 > 0.0) & (fa - x1 > M)) | ((A1 < 0.0) & (x1 - fe > M)) | (A1 == 0.0)
        sure &= ((A2 > 0.0) & (fa - x2 > M)) | ((A2 < 0.0) & (x2 - fe > M)) | (A2 == 0.0)
        if not sure:
            a = max(ua, a - 1)
            e = min(ub, e + 1)
            while a <= e and not _inside(float(a), A0, X0, r0e, t0, A1, X1, r1e, t1, A2, X2, r2e, t2):
                a += 1
            while e >= a and not _inside(float(e), A0, X0, r0e, t0, A1, X1, r1e, t1, A2, X2, r2e, t2):
                e -= 1
        if e >= a:
            rows[v, 0] = min(rows[v, 0], a)
            rows[v, 1] = max(rows[v, 1], e + 1)
        for u in range(a, e + 1):
            w = Pa * (float(u) - xw) + rp
            if w > wbuf[v, u]:
                wbuf[v, u] = w
                if ids:
                    sbuf[v, u] = key


@njit(cache=True, error_model="numpy", nogil=True)
def reset_rows(rows, r0, r1, W):
    """Rows ``r0 .. r1-1`` of ``rows`` (H, 2) int32 to ``(W, 0)``: no pixel covered yet."""
    for v in range(r0, r1):
        rows[v, 0] = W
        rows[v, 1] = 0


@njit(cache=True, error_model="numpy", nogil=True)
def read_out_rows(r0, r1, wbuf, sbuf, face_label, depth, labels, face_ids, rows, spans):
    """Rows ``r0 .. r1-1``: ``depth = float32(1/w)`` (0 = nothing), ``labels`` (mesh) and
    ``face_ids`` (packed face; -1 = nothing) from the z-buffer over this call's hull ``rows``
    (:func:`_fill`), the z-buffer cleared on the way (0 / -1: ready for the next call); the last
    call's pixels outside it (``spans``) back to 0 / -1; ``spans`` becomes this call's
    (``[a, b)``, ``(0, 0)`` = none). Returns the pixels read out."""
    n = 0
    for v in range(r0, r1):
        a = rows[v, 0]
        b = rows[v, 1]
        if b <= a:
            a = 0
            b = 0
        for u in range(spans[v, 0], min(spans[v, 1], a)):
            depth[v, u] = 0.0
            labels[v, u] = -1
            face_ids[v, u] = -1
        for u in range(max(spans[v, 0], b), spans[v, 1]):
            depth[v, u] = 0.0
            labels[v, u] = -1
            face_ids[v, u] = -1
        for u in range(a, b):
            k = sbuf[v, u]
            if k >= 0:
                depth[v, u] = np.float32(1.0 / wbuf[v, u])
                labels[v, u] = face_label[k]
                face_ids[v, u] = k
                wbuf[v, u] = 0.0
                sbuf[v, u] = -1
            else:
                depth[v, u] = 0.0
                labels[v, u] = -1
                face_ids[v, u] = -1
        spans[v, 0] = a
        spans[v, 1] = b
        n += b - a
    return n


@njit(cache=True, error_model="numpy", nogil=True)
def read_out_depth_rows(r0, r1, wbuf, depth, rows, spans):
    """:func:`read_out_rows` of a depth-only render (``_fill`` with ``ids`` False): ``depth =
    float32(1/w)`` where ``wbuf`` holds a winning ``w > 0`` (a pixel :func:`read_out_rows` reads
    as drawn, ``sbuf >= 0``, exactly), else 0; no labels, no face ids. The same depth bits."""
    n = 0
    for v in range(r0, r1):
        a = rows[v, 0]
        b = rows[v, 1]
        if b <= a:
            a = 0
            b = 0
        for u in range(spans[v, 0], min(spans[v, 1], a)):
            depth[v, u] = 0.0
        for u in range(max(spans[v, 0], b), spans[v, 1]):
            depth[v, u] = 0.0
        for u in range(a, b):
            w = wbuf[v, u]
            depth[v, u] = np.float32(1.0 / w) if w > 0.0 else np.float32(0.0)
            wbuf[v, u] = 0.0
        spans[v, 0] = a
        spans[v, 1] = b
        n += b - a
    return n
