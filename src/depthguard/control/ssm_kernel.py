"""Speed and separation monitoring per control cycle, in numba (R33): the twin of
:func:`depthguard.control.ssm.ssm_numpy` (same equations, same closed forms), writing
into a preallocated (m, len(TERMS)) table so that a cycle allocates nothing.

``limits`` fills, per control point, ``D`` (the range where nothing is within it),
``v_h``, ``v_r`` (at scale 1), ``T_r``, ``C``, ``Z_d``, ``Z_r`` and ``limit`` (the
largest scale with ``D ≥ S_p``) and returns the smallest limit over the observed
points; ``terms_at`` then writes ``v_r``, ``T_s``, ``S_h``, ``S_r``, ``S_s``,
``S_p`` at the scale finally commanded. Stopping model: ``kind`` 0 = maximum
deceleration ``decel`` with ``brake_delay``, 1 = table (``tab_v``, ``tab_s``,
``tab_t``). Column indices follow :data:`depthguard.control.ssm.TERMS`.
"""

from __future__ import annotations

import math

import numba

__all__ = ["limits", "terms_at"]

_D, _VH, _VR, _TR, _TS, _SH, _SR, _SS, _C, _ZD, _ZR, _SP, _LIM = range(13)


@numba.njit(cache=True, nogil=True)
def _stop(v, kind, decel, brake_delay, tab_v, tab_s, tab_t):
    """(S_s, T_s) at speed v >= 0."""
    if kind == 0:
        return v * brake_delay + v * v / (2.0 * decel), brake_delay + v / decel
    k = tab_v.shape[0]
    j = k - 2
    for i in range(k - 1):
        if v <= tab_v[i + 1]:
            j = i
            break
    u = (v - tab_v[j]) / (tab_v[j + 1] - tab_v[j])
    return tab_s[j] + u * (tab_s[j + 1] - tab_s[j]), tab_t[j] + u * (tab_t[j + 1] - tab_t[j])


@numba.njit(cache=True, nogil=True)
def _g(v, v_h, T_r, K, kind, decel, brake_delay, tab_v, tab_s, tab_t):
    S_s, T_s = _stop(v, kind, decel, brake_delay, tab_v, tab_s, tab_t)
    return v_h * (T_r + T_s) + v * T_r + S_s + K


@numba.njit(cache=True, nogil=True)
def _largest(d, v0, v_h, T_r, K, kind, decel, brake_delay, tab_v, tab_s, tab_t):
    g0 = _g(0.0, v_h, T_r, K, kind, decel, brake_delay, tab_v, tab_s, tab_t)
    if g0 > d:
        return 0.0
    if v0 <= 0.0 or _g(v0, v_h, T_r, K, kind, decel, brake_delay, tab_v, tab_s, tab_t) <= d:
        return 1.0
    if kind == 0:
        A = 1.0 / (2.0 * decel)
        B = T_r + brake_delay + v_h / decel
        x = d - g0
        return 2.0 * x / (B + math.sqrt(B * B + 4.0 * A * x)) / v0
    va = 0.0
    ga = g0
    for i in range(1, tab_v.shape[0] + 1):
        vb = v0 if i == tab_v.shape[0] else min(tab_v[i], v0)
        if vb <= va:
            continue
        gb = _g(vb, v_h, T_r, K, kind, decel, brake_delay, tab_v, tab_s, tab_t)
        if gb > d:
            return (va + (d - ga) / (gb - ga) * (vb - va)) / v0
        va, ga = vb, gb
        if va >= v0:
            break
    return 1.0


@numba.njit(cache=True, nogil=True)
def limits(D, V, P, J, qd, observed, rng, Rc, tc, fc, sig_a, sig_z2, qc, delta_d, n_sigma, T_r, C, Z_r,
           v_h_far, v_h_near, near_limit, use_measured, v_h_floor, v_h_measured,
           kind, decel, brake_delay, tab_v, tab_s, tab_t, out):
    """Per-point terms at scale 1 and limits into ``out`` (module docstring); returns the
    smallest limit over the observed points (1.0 when none is)."""
    m = D.shape[0]
    n = qd.shape[0]
    nc = fc.shape[0]
    s_min = 1.0
    for i in range(m):
        vr = 0.0
        sq = 0.0
        for a in range(3):
            acc = 0.0
            for j in range(n):
                acc += J[i, a, j] * qd[j]
            vr += V[i, a] * acc
            sq += acc * acc
        near = math.isfinite(D[i]) and D[i] < rng
        d = D[i] if near else rng
        if not near:
            vr = math.sqrt(sq)
        zd = 0.0
        for c in range(nc):
            z = tc[c, 2]
            for a in range(3):
                x = P[i, a] + d * V[i, a] if near else P[i, a]
                z += Rc[c, 2, a] * x
            if not near:
                z += rng
            z = max(z, 0.0)
            w = z / fc[c]
            e = 0.5 * math.sqrt(2.0 * w * w + delta_d * delta_d) + n_sigma * (sig_a[c] + sig_z2[c] * z * z) \
                + 0.5 * qc[c] * z * z
            zd = max(zd, e)
        if use_measured:
            v_h = max(v_h_floor, v_h_measured[i])
        else:
            v_h = v_h_near if d < near_limit else v_h_far
        s = _largest(d, vr, v_h, T_r, C + zd + Z_r, kind, decel, brake_delay, tab_v, tab_s, tab_t)
        out[i, _D] = d
        out[i, _VH] = v_h
        out[i, _VR] = vr
        out[i, _TR] = T_r
        out[i, _C] = C
        out[i, _ZD] = zd
        out[i, _ZR] = Z_r
        out[i, _LIM] = s
        if observed[i]:
            s_min = min(s_min, s)
    return s_min


@numba.njit(cache=True, nogil=True)
def terms_at(s, kind, decel, brake_delay, tab_v, tab_s, tab_t, out):
    """Write ``v_r``, ``T_s``, ``S_h``, ``S_r``, ``S_s``, ``S_p`` of every point at scale ``s``
    (``out`` filled by :func:`limits`; its ``v_r`` at scale 1 becomes ``s v_r``)."""
    for i in range(out.shape[0]):
        vr = s * out[i, _VR]
        v = max(vr, 0.0)
        S_s, T_s = _stop(v, kind, decel, brake_delay, tab_v, tab_s, tab_t)
        out[i, _VR] = vr
        out[i, _TS] = T_s
        out[i, _SH] = out[i, _VH] * (out[i, _TR] + T_s)
        out[i, _SR] = v * out[i, _TR]
        out[i, _SS] = S_s
        out[i, _SP] = out[i, _SH] + out[i, _SR] + S_s + out[i, _C] + out[i, _ZD] + out[i, _ZR]
