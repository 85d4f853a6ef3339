"""Saturation in the Null Space (SNS): joint velocities within box limits
that keep the task where that is possible and scale it where it is not (R14).

Flacco, De Luca, Khatib, "Motion control of redundant robots under joint
constraints: saturation in the null space" (ICRA 2012) and "Control of
redundant robots under hard joint constraints: saturation in the null space"
(IEEE T-RO 31(3), 2015), Algorithm 1 (single task, velocity level).

Given the task Jacobian ``J`` (m, n), the task velocity ``ẋ`` (m,) and the
box ``lo ≤ q̇ ≤ hi`` (with ``lo ≤ 0 ≤ hi``)::

    W = I, q̇_N = 0, s = 1, s* = 0
    repeat
        q̇ = q̇_N + (J W)⁺ (ẋ − J q̇_N)               the candidate at full task
        a = (J W)⁺ ẋ,  b = q̇ − a                    q̇(s) = s·a + b
        s_j = largest s ≤ 1 with q̇(s) in the box,  j = first joint to hit
        keep (W, q̇_N, s_j) if s_j is the best scale so far
        if q̇ is in the box: done (task kept exactly, s = 1)
        saturate joint j: W_jj = 0, q̇_N,j = its violated bound
        if rank(J W) < m: fall back to the best (W*, q̇_N*, s*),
                          q̇ = q̇_N* + (J W*)⁺ (s* ẋ − J q̇_N*); done

The result satisfies ``J q̇ = s·ẋ`` with ``0 ≤ s ≤ 1`` and the box limits.
It is a heuristic for the largest feasible ``s`` of the LP
``max s s.t. J q̇ = s ẋ, lo ≤ q̇ ≤ hi``; the tests compare both.

An optional null-space velocity ``q̇_0`` (e.g. a posture term) is added with
the lowest priority: projected into the null space of the unsaturated
columns, ``δ = W (I − (JW)⁺ JW) q̇_0``, and scaled by the largest
``β ∈ [0, 1]`` that keeps the box; it never changes ``J q̇``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

__all__ = ["SNSResult", "SNSWorkspace", "sns_velocity", "sns_velocity_numpy", "task_scaling_factor"]

RANK_TOL = 1e-6     # singular values below this (relative to 1) count as rank loss
_EPS = 1e-12


@dataclass(frozen=True)
class SNSResult:
    qd: np.ndarray            # (n,) joint velocity, rad/s, within [lo, hi]
    scale: float              # task scale s in [0, 1]: J qd = s * xd
    saturated: np.ndarray     # (n,) bool, joints fixed at a bound by SNS
    iterations: int
    null_scale: float = 0.0   # beta applied to the null-space velocity qd_0


def _pinv_rank(A: np.ndarray) -> tuple[np.ndarray, int]:
    U, S, Vt = np.linalg.svd(A, full_matrices=False)
    r = int(np.sum(S > RANK_TOL * max(1.0, S[0] if S.size else 0.0)))
    inv = np.zeros_like(S)
    inv[:r] = 1.0 / S[:r]
    return (Vt.T * inv) @ U.T, r


def task_scaling_factor(a: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                        active: np.ndarray | None = None) -> tuple[float, int]:
    """Largest ``s ∈ [0, 1]`` with ``lo ≤ s·a + b ≤ hi`` and the joint that binds first.

    ``a, b, lo, hi``: (n,); only ``active`` joints count (default all).
    Returns ``(s, j)`` (T-RO 2015, getTaskScalingFactor): ``j`` is the joint
    with the smallest upper bound on ``s`` (``-1`` if no joint bounds ``s``);
    ``s = 0`` if no ``s ∈ [0, 1]`` is feasible. A joint with ``a_j = 0``
    whose ``b_j`` lies outside its box makes every ``s`` infeasible (``s = 0``,
    ``j`` = that joint).
    """
    n = a.shape[0]
    s_max, s_min, j = np.inf, -np.inf, -1
    for i in range(n):
        if active is not None and not active[i]:
            continue
        if abs(a[i]) <= _EPS:
            if b[i] > hi[i] + 1e-12 or b[i] < lo[i] - 1e-12:
                return 0.0, i
            continue
        lo_i = (lo[i] - b[i]) / a[i]
        hi_i = (hi[i] - b[i]) / a[i]
        if lo_i > hi_i:
            lo_i, hi_i = hi_i, lo_i
        if hi_i < s_max:
            s_max, j = hi_i, i
        s_min = max(s_min, lo_i)
    if s_min > s_max + 1e-12 or s_max < 0.0 or s_min > 1.0:
        return 0.0, j
    if s_max >= 1.0:
        return 1.0, j
    return float(s_max), j


def _check(J, xd, lo, hi):
    J = np.asarray(J, dtype=np.float64)
    if J.ndim != 2:
        raise ValueError(f"J must be a (m, n) task Jacobian, got shape {J.shape}")
    m, n = J.shape
    xd = np.asarray(xd, dtype=np.float64).reshape(-1)
    lo = np.asarray(lo, dtype=np.float64).reshape(-1)
    hi = np.asarray(hi, dtype=np.float64).reshape(-1)
    if xd.shape != (m,):
        raise ValueError(f"task velocity must have shape ({m},), got {xd.shape}")
    if lo.shape != (n,) or hi.shape != (n,):
        raise ValueError(f"joint limits lo/hi must have shape ({n},), got {lo.shape} and {hi.shape}")
    if not (np.all(np.isfinite(J)) and np.all(np.isfinite(xd))):
        raise ValueError("J and the task velocity must be finite")
    if np.any(lo > 1e-12) or np.any(hi < -1e-12):
        raise ValueError("SNS needs lo <= 0 <= hi for every joint (standing still must be allowed)")
    return J, xd, np.minimum(lo, 0.0), np.maximum(hi, 0.0)


def sns_velocity_numpy(J, xd, lo, hi, qd0=None, max_iter: int | None = None) -> SNSResult:
    """Plain-numpy twin of :func:`sns_velocity` (T-RO 2015, Algorithm 1), for the tests.

    ``J``: (m, n) task Jacobian; ``xd``: (m,) task velocity (m/s); ``lo``,
    ``hi``: (n,) joint velocity box (rad/s) with ``lo ≤ 0 ≤ hi``; ``qd0``:
    optional (n,) lowest-priority null-space velocity. Returns an
    :class:`SNSResult` with ``J @ qd = scale * xd`` (to rounding) and
    ``lo ≤ qd ≤ hi``.
    """
    J, xd, lo, hi = _check(J, xd, lo, hi)
    m, n = J.shape
    tol = 1e-10 * (1.0 + np.abs(hi - lo))
    W = np.ones(n, dtype=bool)            # diagonal of W (False = saturated joint)
    qd_N = np.zeros(n)
    best_s, best_W, best_qdN = -1.0, W.copy(), qd_N.copy()
    P, rank = _pinv_rank(J)
    it = 0
    limit = n + 1 if max_iter is None else max_iter
    while True:
        it += 1
        qd = qd_N + P @ (xd - J @ qd_N)
        a = P @ xd
        b = qd - a                                  # qd(s) = s a + b
        exceeded = bool(np.any(qd < lo - tol) or np.any(qd > hi + tol))
        s, j = task_scaling_factor(a, b, lo, hi, active=W)
        if s > best_s:
            best_s, best_W, best_qdN = s, W.copy(), qd_N.copy()
        if not exceeded:
            s_final = 1.0
            break
        fallback = j < 0 or it >= limit
        if not fallback:
            W[j] = False                            # saturate the most critical joint
            qd_N[j] = hi[j] if (a[j] > 0 if abs(a[j]) > _EPS else qd[j] > hi[j]) else lo[j]
            P, rank = _pinv_rank(J * W)
            fallback = rank < m
        if fallback:
            W, qd_N, s_final = best_W, best_qdN, max(best_s, 0.0)
            P, _ = _pinv_rank(J * W)
            qd = qd_N + P @ (s_final * xd - J @ qd_N)
            break
    qd = np.clip(qd, lo, hi)
    beta = 0.0
    if qd0 is not None:
        q0 = np.asarray(qd0, dtype=np.float64).reshape(-1)
        if q0.shape != (n,) or not np.all(np.isfinite(q0)):
            raise ValueError(f"qd0 must be a finite ({n},) joint velocity")
        JW = J * W
        P, _ = _pinv_rank(JW)
        delta = W * (q0 - P @ (JW @ q0))
        beta = _box_step(qd, delta, lo, hi)
        qd = np.clip(qd + beta * delta, lo, hi)
    return SNSResult(qd=qd, scale=float(s_final), saturated=~W, iterations=it, null_scale=beta)


def _box_step(x: np.ndarray, d: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
    """Largest β ∈ [0, 1] with ``lo ≤ x + β d ≤ hi`` (x inside the box)."""
    beta = 1.0
    for i in range(x.shape[0]):
        if d[i] > _EPS:
            beta = min(beta, (hi[i] - x[i]) / d[i])
        elif d[i] < -_EPS:
            beta = min(beta, (lo[i] - x[i]) / d[i])
    return max(beta, 0.0)


# --------------------------------------------------------------------- numba kernel
@numba.njit(cache=True, nogil=True)
def _pinv_rank_nb(A, out):
    """``out[:] = A⁺`` (n, m) via SVD; returns the rank (singular values > RANK_TOL)."""
    U, S, Vt = np.linalg.svd(A, False)
    smax = 1.0
    if S.shape[0] > 0 and S[0] > 1.0:
        smax = S[0]
    r = 0
    out[:, :] = 0.0
    for k in range(S.shape[0]):
        if S[k] > RANK_TOL * smax:
            r += 1
            inv = 1.0 / S[k]
            for i in range(out.shape[0]):
                for j in range(out.shape[1]):
                    out[i, j] += Vt[k, i] * inv * U[j, k]
    return r


@numba.njit(cache=True, nogil=True)
def _tsf_nb(a, b, lo, hi, W):
    n = a.shape[0]
    s_max = np.inf
    s_min = -np.inf
    j = -1
    for i in range(n):
        if not W[i]:
            continue
        if abs(a[i]) <= _EPS:
            if b[i] > hi[i] + 1e-12 or b[i] < lo[i] - 1e-12:
                return 0.0, i
            continue
        lo_i = (lo[i] - b[i]) / a[i]
        hi_i = (hi[i] - b[i]) / a[i]
        if lo_i > hi_i:
            lo_i, hi_i = hi_i, lo_i
        if hi_i < s_max:
            s_max = hi_i
            j = i
        if lo_i > s_min:
            s_min = lo_i
    if s_min > s_max + 1e-12 or s_max < 0.0 or s_min > 1.0:
        return 0.0, j
    if s_max >= 1.0:
        return 1.0, j
    return s_max, j


@numba.njit(cache=True, nogil=True)
def _sns_kernel(J, xd, lo, hi, qd0, use_qd0, max_iter, qd, W, P, JW, qd_N, best_W, best_qdN, a, b, tmp):
    """SNS (Algorithm 1) into preallocated buffers; returns (scale, iterations, beta).

    ``J`` (m, n), ``xd`` (m,), ``lo``/``hi``/``qd0`` (n,); buffers: ``qd``,
    ``qd_N``, ``best_qdN``, ``a``, ``b``, ``tmp`` (n,), ``W``/``best_W`` (n,)
    bool, ``P`` (n, m), ``JW`` (m, n). Mirrors :func:`sns_velocity_numpy`.
    """
    m, n = J.shape
    for i in range(n):
        W[i] = True
        qd_N[i] = 0.0
    best_s = -1.0
    for i in range(m):
        for k in range(n):
            JW[i, k] = J[i, k]
    rank = _pinv_rank_nb(JW, P)
    it = 0
    s_final = 1.0
    while True:
        it += 1
        # r = xd - J qd_N ; qd = qd_N + P r ; a = P xd ; b = qd - a
        exceeded = False
        for k in range(n):
            acc_q = qd_N[k]
            acc_a = 0.0
            for i in range(m):
                r_i = xd[i]
                for l in range(n):
                    r_i -= J[i, l] * qd_N[l]
                acc_q += P[k, i] * r_i
                acc_a += P[k, i] * xd[i]
            qd[k] = acc_q
            a[k] = acc_a
            b[k] = acc_q - acc_a
            tol = 1e-10 * (1.0 + abs(hi[k] - lo[k]))
            if acc_q < lo[k] - tol or acc_q > hi[k] + tol:
                exceeded = True
        s, j = _tsf_nb(a, b, lo, hi, W)
        if s > best_s:
            best_s = s
            for k in range(n):
                best_W[k] = W[k]
                best_qdN[k] = qd_N[k]
        if not exceeded:
            s_final = 1.0
            break
        fallback = j < 0 or it >= max_iter
        if not fallback:
            W[j] = False
            if abs(a[j]) > _EPS:
                up = a[j] > 0
            else:
                up = qd[j] > hi[j]
            qd_N[j] = hi[j] if up else lo[j]
            for i in range(m):
                for k in range(n):
                    JW[i, k] = J[i, k] if W[k] else 0.0
            rank = _pinv_rank_nb(JW, P)
            fallback = rank < m
        if fallback:
            s_final = best_s if best_s > 0.0 else 0.0
            for k in range(n):
                W[k] = best_W[k]
                qd_N[k] = best_qdN[k]
            for i in range(m):
                for k in range(n):
                    JW[i, k] = J[i, k] if W[k] else 0.0
            _pinv_rank_nb(JW, P)
            for k in range(n):
                acc_q = qd_N[k]
                for i in range(m):
                    r_i = s_final * xd[i]
                    for l in range(n):
                        r_i -= J[i, l] * qd_N[l]
                    acc_q += P[k, i] * r_i
                qd[k] = acc_q
            break
    for k in range(n):
        qd[k] = min(max(qd[k], lo[k]), hi[k])
    beta = 0.0
    if use_qd0:
        # JW, P belong to the final W; delta = W (qd0 - P JW qd0)
        for i in range(m):
            acc = 0.0
            for k in range(n):
                acc += JW[i, k] * qd0[k]
            a[i] = acc                      # a[:m] reused as JW qd0
        for k in range(n):
            acc = qd0[k]
            for i in range(m):
                acc -= P[k, i] * a[i]
            tmp[k] = acc if W[k] else 0.0
        beta = 1.0
        for k in range(n):
            if tmp[k] > _EPS:
                beta = min(beta, (hi[k] - qd[k]) / tmp[k])
            elif tmp[k] < -_EPS:
                beta = min(beta, (lo[k] - qd[k]) / tmp[k])
        if beta < 0.0:
            beta = 0.0
        for k in range(n):
            qd[k] = min(max(qd[k] + beta * tmp[k], lo[k]), hi[k])
    return s_final, it, beta


class SNSWorkspace:
    """Preallocated buffers for :func:`sns_velocity` with an (m, n) task (model/data apart)."""

    def __init__(self, m: int, n: int):
        self.m, self.n = m, n
        self.qd = np.zeros(n)
        self.W = np.ones(n, dtype=np.bool_)
        self.P = np.zeros((n, m))
        self.JW = np.zeros((m, n))
        self.qd_N = np.zeros(n)
        self.best_W = np.ones(n, dtype=np.bool_)
        self.best_qdN = np.zeros(n)
        self.a = np.zeros(max(n, m))
        self.b = np.zeros(n)
        self.tmp = np.zeros(n)
        self.zero = np.zeros(n)


def sns_velocity(J, xd, lo, hi, qd0=None, max_iter: int | None = None,
                 workspace: SNSWorkspace | None = None) -> SNSResult:
    """SNS joint velocity for one task (T-RO 2015, Algorithm 1), numba kernel.

    ``J``: (m, n) task Jacobian; ``xd``: (m,) task velocity (m/s); ``lo``,
    ``hi``: (n,) joint velocity box (rad/s) with ``lo ≤ 0 ≤ hi``; ``qd0``:
    optional (n,) lowest-priority null-space velocity (rad/s). Returns an
    :class:`SNSResult` with ``J @ qd = scale * xd`` (to rounding) and
    ``lo ≤ qd ≤ hi``. ``workspace``: reuse buffers across calls (the loop
    does); the returned arrays are copies.
    """
    J, xd, lo, hi = _check(J, xd, lo, hi)
    m, n = J.shape
    ws = workspace if workspace is not None and (workspace.m, workspace.n) == (m, n) else SNSWorkspace(m, n)
    if qd0 is not None:
        q0 = np.ascontiguousarray(qd0, dtype=np.float64).reshape(-1)
        if q0.shape != (n,) or not np.all(np.isfinite(q0)):
            raise ValueError(f"qd0 must be a finite ({n},) joint velocity")
    else:
        q0 = ws.zero
    s, it, beta = _sns_kernel(np.ascontiguousarray(J), xd, lo, hi, q0, qd0 is not None,
                              n + 1 if max_iter is None else int(max_iter),
                              ws.qd, ws.W, ws.P, ws.JW, ws.qd_N, ws.best_W, ws.best_qdN, ws.a, ws.b, ws.tmp)
    return SNSResult(qd=ws.qd.copy(), scale=float(s), saturated=~ws.W, iterations=int(it), null_scale=float(beta))
