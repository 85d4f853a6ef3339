"""Joint-velocity limits: Cartesian constraints of the control points (R14)
and the robot's own joint position and velocity limits.

Flacco 2014 §5.2, eqs. (20)–(22). For a control point ``C`` on a link with
minimum distance ``D`` and unit direction ``V`` (towards the obstacle)::

    f = 1 / (1 + exp((2D/ρ − 1)·α))                risk (eq. 20)
    s = J_Cᵀ · (V · f)                              influence on each joint (eq. 21)
    s_i > 0:  q̇max_i = Vmax_i · (1 − f)           (eq. 22)
    s_i < 0:  q̇min_i = −Vmax_i · (1 − f)

Each joint keeps its tightest limit over all constraints.

Deviation from the letter of eq. (22), stated: the paper writes ``s_i ≥ 0``.
A joint whose column of ``J_C`` is zero (a joint beyond the link that carries
``C``) has ``s_i = 0`` exactly and does not move ``C`` at all; capping it would
only take redundancy away. Joints with ``|s_i| ≤ tol · max_j |s_j|`` (and
``s = 0`` entirely) are therefore left unconstrained by that point.

``D = inf`` (no obstacle within ρ) gives ``f = 0``: no constraint.
"""

from __future__ import annotations

import numpy as np

from depthguard.control.repulsion import risk

__all__ = ["constraint_limits", "position_limits", "combine_limits", "INFLUENCE_TOL"]

INFLUENCE_TOL = 1e-9


def _as_limits(qd_max, n: int | None = None) -> np.ndarray:
    v = np.asarray(qd_max, dtype=np.float64).reshape(-1)
    if n is not None and v.shape != (n,):
        raise ValueError(f"qd_max must have shape ({n},), got {v.shape}")
    if not np.all(np.isfinite(v)) or np.any(v <= 0):
        raise ValueError("qd_max (joint velocity limits, rad/s) must be finite and > 0")
    return v


def constraint_limits(J_C, D, V, qd_max, rho: float, alpha: float,
                      tol: float = INFLUENCE_TOL) -> tuple[np.ndarray, np.ndarray]:
    """Joint-velocity box from the Cartesian constraints of control points (R14).

    ``J_C``: (m, 3, n) position Jacobians of the control points; ``D``: (m,)
    minimum distances in m (``inf`` = no obstacle within ρ); ``V``: (m, 3)
    unit vectors towards the obstacle (ignored where ``D = inf``);
    ``qd_max``: (n,) joint speed limits ``Vmax_i`` in rad/s.

    Returns ``(lo, hi)``, each (n,) rad/s with ``lo ≤ 0 ≤ hi``: the tightest
    limit of each joint over the ``m`` constraints (``±qd_max`` where no
    constraint acts).
    """
    J = np.asarray(J_C, dtype=np.float64)
    if J.ndim == 2:
        J = J[None]
    if J.ndim != 3 or J.shape[1] != 3:
        raise ValueError(f"J_C must have shape (m, 3, n), got {np.shape(J_C)}")
    m, _, n = J.shape
    d = np.asarray(D, dtype=np.float64).reshape(-1)
    v = np.asarray(V, dtype=np.float64).reshape(-1, 3) if np.size(V) else np.zeros((0, 3))
    if d.shape != (m,) or v.shape != (m, 3):
        raise ValueError(f"D must have shape ({m},) and V ({m}, 3); got {d.shape} and {v.shape}")
    vmax = _as_limits(qd_max, n)
    f = risk(d, rho, alpha)                                    # (m,), 0 where D = inf
    Vf = np.where(np.isfinite(d)[:, None], v, 0.0) * f[:, None]  # (m, 3); V ignored where D = inf
    s = np.einsum("cij,ci->cj", J, Vf)                         # eq. (21), (m, n)
    smax = np.abs(s).max(axis=1, keepdims=True)                # (m, 1)
    pos = s > tol * smax                                       # joint i moves C towards the obstacle
    neg = s < -tol * smax
    cap = vmax[None, :] * (1.0 - f)[:, None]                   # eq. (22), (m, n)
    hi = np.minimum(vmax, np.where(pos, cap, np.inf).min(axis=0))
    lo = np.maximum(-vmax, np.where(neg, -cap, -np.inf).max(axis=0))
    return lo, hi


def position_limits(q, q_min, q_max, qd_max, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Joint-velocity box from the joint position and speed limits.

    ``hi_i = min(qd_max_i, (q_max_i − q_i)/dt)``, ``lo_i = max(−qd_max_i,
    (q_min_i − q_i)/dt)``: one control period ``dt`` (s) at the returned
    speed cannot cross a position limit. A joint already at or beyond a limit
    gets 0 on that side (the box always contains 0, as SNS requires), so it
    can stop or move back but never further out. Shapes (n,), rad and rad/s.
    """
    q = np.asarray(q, dtype=np.float64).reshape(-1)
    n = q.shape[0]
    qmin = np.asarray(q_min, dtype=np.float64).reshape(-1)
    qmax = np.asarray(q_max, dtype=np.float64).reshape(-1)
    if qmin.shape != (n,) or qmax.shape != (n,):
        raise ValueError(f"q_min and q_max must have shape ({n},)")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a positive period in seconds, got {dt!r}")
    vmax = _as_limits(qd_max, n)
    hi = np.maximum(np.minimum(vmax, (qmax - q) / dt), 0.0)
    lo = np.minimum(np.maximum(-vmax, (qmin - q) / dt), 0.0)
    return lo, hi


def combine_limits(*boxes: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Intersection of joint-velocity boxes: per joint the largest ``lo`` and smallest ``hi``."""
    if not boxes:
        raise ValueError("combine_limits needs at least one (lo, hi) box")
    lo = np.max(np.stack([np.asarray(b[0], float) for b in boxes]), axis=0)
    hi = np.min(np.stack([np.asarray(b[1], float) for b in boxes]), axis=0)
    return lo, hi
