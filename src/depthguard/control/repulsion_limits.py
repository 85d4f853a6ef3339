"""The repulsive velocity and the joint-velocity limits of one control cycle in one numba
kernel (R13, R14; the papers' "repulsive velocity" and "joint velocity limits"), for
the 500 Hz loop.

``repulsion_and_limits_numpy`` is the plain twin, written with the functions that read like
the equations (:mod:`~depthguard.control.repulsion`,
:mod:`~depthguard.control.joint_limits`); the tests compare both.

Inputs: ``D`` (m,) distances (``inf`` = nothing within ρ), ``V`` (m, 3) unit
vectors towards the obstacle, ``J`` (m, 3, n) control-point Jacobians; point 0
is the end effector (repulsion), points 1… are constraints (R14). ``q``,
``q_min``, ``q_max`` (n,) rad, ``qd_max`` (n,) rad/s, ``dt`` s, ``k`` the
safety override in [0, 1] that scales the box.
Outputs: ``rep`` (3,) m/s, ``lo``, ``hi`` (n,) rad/s with ``lo ≤ 0 ≤ hi``.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from depthguard.control.joint_limits import INFLUENCE_TOL, combine_limits, constraint_limits, position_limits
from depthguard.control.repulsion import check_repulsion_params, repulsive_velocity

__all__ = ["repulsion_and_limits", "repulsion_and_limits_numpy"]


@numba.njit(cache=True)      # microseconds: keeps the GIL (a release costs the control thread a hand-over)
def _repulsion_and_limits_kernel(D, V, J, q, q_min, q_max, qd_max, dt, rho, v_max, alpha, k, tol, rep, lo, hi):
    m = D.shape[0]
    n = q.shape[0]
    # R13 at the end effector
    rep[0] = 0.0
    rep[1] = 0.0
    rep[2] = 0.0
    if math.isfinite(D[0]):
        v = v_max / (1.0 + math.exp((D[0] * 2.0 / rho - 1.0) * alpha))
        for a in range(3):
            rep[a] = -v * V[0, a]
    # joint position / speed limits
    for i in range(n):
        h = min(qd_max[i], (q_max[i] - q[i]) / dt)
        l_ = max(-qd_max[i], (q_min[i] - q[i]) / dt)
        hi[i] = max(h, 0.0)
        lo[i] = min(l_, 0.0)
    # R14 for the other control points
    s = np.empty(n)
    for c in range(1, m):
        if not math.isfinite(D[c]):
            continue
        f = 1.0 / (1.0 + math.exp((D[c] * 2.0 / rho - 1.0) * alpha))
        if f == 0.0:
            continue
        smax = 0.0
        for i in range(n):
            acc = 0.0
            for a in range(3):
                acc += J[c, a, i] * V[c, a] * f
            s[i] = acc
            smax = max(smax, abs(acc))
        if smax == 0.0:
            continue
        for i in range(n):
            cap = qd_max[i] * (1.0 - f)
            if s[i] > tol * smax:
                hi[i] = min(hi[i], cap)
            elif s[i] < -tol * smax:
                lo[i] = max(lo[i], -cap)
    for i in range(n):
        lo[i] *= k
        hi[i] *= k


def repulsion_and_limits(D, V, J, q, q_min, q_max, qd_max, dt: float, rho: float, v_max: float, alpha: float,
             k: float = 1.0, out: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None):
    """``(rep (3,), lo (n,), hi (n,))`` of one cycle (module docstring); ``out`` reuses buffers.

    Inputs are float64 arrays of the documented shapes (the loop's own
    buffers); ``D`` must be ``>= 0`` or ``inf``.
    """
    n = q.shape[0]
    rep, lo, hi = out if out is not None else (np.empty(3), np.empty(n), np.empty(n))
    _repulsion_and_limits_kernel(D, V, J, q, q_min, q_max, qd_max, float(dt), float(rho), float(v_max), float(alpha),
                     float(k), INFLUENCE_TOL, rep, lo, hi)
    return rep, lo, hi


def repulsion_and_limits_numpy(D, V, J, q, q_min, q_max, qd_max, dt, rho, v_max, alpha, k=1.0):
    """Plain twin of :func:`repulsion_and_limits`: R13 + R14 + position limits, tightest per joint, times ``k``."""
    check_repulsion_params(rho, alpha, v_max)
    rep = repulsive_velocity(D[0], V[0], rho, v_max, alpha)
    box_c = constraint_limits(J[1:], D[1:], V[1:], qd_max, rho, alpha)
    box_p = position_limits(q, q_min, q_max, qd_max, dt)
    lo, hi = combine_limits(box_c, box_p)
    return rep, k * lo, k * hi
