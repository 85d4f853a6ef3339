"""Ground truth of speed and separation monitoring in the closed loop (R33; not part of the system).

At every cycle, for every control point ``i`` and the moving obstacles (the
people and props of the scenario, every one of them taken for a person):

* ``d_i``: the true distance of the point to the nearest moving obstacle (exact SDF, 0 inside);
* ``v_h,i``: the **true** speed of that obstacle towards the point: how fast the
  distance of the (fixed) point shrinks between the previous cycle's obstacles
  and this cycle's, ``max(0, (d_i(t − dt) − d_i(t)) / dt)``;
* ``v_r,i``: the **true** speed of the point towards it: how fast the distance
  shrinks as the point moves by its applied velocity ``J_i q̇ dt`` against this
  cycle's obstacles;
* ``S_p,i = v_h,i (T_r + T_s) + v_r,i⁺ T_r + S_s + C + Z_r`` with ``T_r``, ``C``,
  ``Z_r`` as the monitor logged them and ``S_s``, ``T_s`` from the stopping model
  (which the simulated robot obeys when it brakes) at ``v_r,i⁺``. ``Z_d`` is left
  out: the truth has no sensing error (it is what ``Z_d`` covers); the count with
  it is reported too, as the stricter reading.

A **violation** is a cycle where some point has ``d_i < S_p,i`` while the robot is
neither in a protective stop (braking by the stopping model) nor standing.
"""

from __future__ import annotations

import math

import numpy as np

from depthguard.control.ssm import TERMS, stopping
from depthguard.geometry.packed import PackedSolids

__all__ = ["SSMTruth", "braking_deceleration"]

_TR, _C, _ZD, _ZR = (TERMS.index(k) for k in ("T_r", "C", "Z_d", "Z_r"))


def _moving_distance(X: np.ndarray, moving: list) -> np.ndarray:
    """(k,) m: the distance of the points ``X`` (k, 3) to the nearest of ``moving`` (0 inside,
    inf when there is none)."""
    if not moving:
        return np.full(len(X), np.inf)
    packed, rest = PackedSolids.split(moving)
    d = packed.sdf_min(X) if len(packed) else np.full(len(X), np.inf)
    for prim in rest:
        np.minimum(d, prim.sdf(X), out=d)
    return np.maximum(d, 0.0)


class SSMTruth:
    """Per-cycle check of the SSM guarantee from the simulator's truth (module docstring)."""

    def __init__(self, ssm_cfg, dt: float):
        self.cfg = ssm_cfg
        self.dt = float(dt)
        self._prev: list | None = None

    def check(self, P: np.ndarray, Xdot: np.ndarray, moving: list, table: np.ndarray | None,
              stopping_now: bool) -> tuple[float, bool, bool]:
        """``(margin m, violation, violation counting Z_d)`` of this cycle. ``P`` (m, 3) the control
        points, ``Xdot`` (m, 3) m/s their applied velocities, ``moving`` the obstacles now,
        ``table`` the monitor's SSM terms (m, 13); ``stopping_now``: protective stop in force or
        the robot standing. ``margin`` = min over points of ``d − S_p`` (inf: nothing moving)."""
        prev, self._prev = self._prev, list(moving)
        if not moving or table is None:
            return math.inf, False, False
        d = _moving_distance(P, moving)
        d_before = _moving_distance(P, prev) if prev else d
        d_next = _moving_distance(P + Xdot * self.dt, moving)
        v_h = np.maximum(0.0, (d_before - d) / self.dt)
        v_r = np.maximum(0.0, (d - d_next) / self.dt)
        margin, margin_zd = math.inf, math.inf
        for i in range(len(P)):
            if not math.isfinite(d[i]):
                continue
            S_s, T_s = stopping(v_r[i], self.cfg)
            T_r = table[i, _TR]
            S_p = v_h[i] * (T_r + T_s) + v_r[i] * T_r + S_s + table[i, _C] + table[i, _ZR]
            margin = min(margin, d[i] - S_p)
            margin_zd = min(margin_zd, d[i] - S_p - table[i, _ZD])
        return margin, (margin < 0.0 and not stopping_now), (margin_zd < 0.0 and not stopping_now)


def braking_deceleration(ssm_cfg) -> float:
    """m/s², the deceleration the simulated robot brakes with (R33): the model's, or for a
    stopping table the smallest ``v² / (2 S_s)`` of its rows (no faster than the table says)."""
    if ssm_cfg.stop_model == "deceleration":
        return float(ssm_cfg.deceleration)
    tab = ssm_cfg.stop_table
    return float(min(v * v / (2.0 * s) for v, s in zip(tab.speed, tab.distance) if v > 0 and s > 0))
