"""The end-effector task of Flacco 2014 §5.3 / 2015 §VIII: the six corners of
a hexagon in a vertical plane ``X = const``, visited over and over (R15).

Each side is a straight line run with a trapezoidal speed profile (cruise
speed ``speed``, acceleration ``accel``), so the path passes exactly through
the corners and the velocity is continuous. ``p(τ)``, ``ṗ(τ)`` are functions
of the path time ``τ``; the loop advances ``τ`` by ``s·k·dt`` (SNS task
scale ``s`` times the safety override ``k``), so a scaled or stopped task
resumes where it stopped instead of chasing a target that ran away.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

__all__ = ["Hexagon"]


@dataclass(frozen=True)
class Hexagon:
    """Hexagon in the plane ``x = center[0]`` (world, m), corners at radius ``radius``.

    Corner ``k`` is ``center + radius·(0, cos θ_k, sin θ_k)``, ``θ_k = θ0 + k·60°``.
    ``speed`` m/s (paper: 0.4), ``accel`` m/s².
    """
    center: tuple[float, float, float] = (-0.6, 0.0, 0.6)
    radius: float = 0.2
    speed: float = 0.4
    accel: float = 2.0
    theta0_deg: float = 90.0

    def __post_init__(self):
        c = np.asarray(self.center, dtype=np.float64)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise ValueError(f"hexagon center must be 3 finite numbers (m), got {self.center!r}")
        for name in ("radius", "speed", "accel"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"hexagon {name} must be > 0, got {v!r}")

    @cached_property
    def corners(self) -> np.ndarray:
        """(6, 3) world corners."""
        th = np.deg2rad(self.theta0_deg + 60.0 * np.arange(6))
        c = np.asarray(self.center, dtype=np.float64)
        return c + self.radius * np.stack([np.zeros(6), np.cos(th), np.sin(th)], axis=1)

    @property
    def side(self) -> float:
        return self.radius                        # regular hexagon: side = circumradius

    def _profile(self):
        L, v, a = self.side, self.speed, self.accel
        t_acc = v / a
        if a * t_acc ** 2 > L:                     # triangular profile: never reaches cruise
            t_acc = np.sqrt(L / a)
            v = a * t_acc
            t_cruise = 0.0
        else:
            t_cruise = (L - a * t_acc ** 2) / v
        return t_acc, t_cruise, v, a

    @property
    def side_time(self) -> float:
        t_acc, t_cruise, _, _ = self._profile()
        return 2 * t_acc + t_cruise

    @property
    def period(self) -> float:
        """Seconds per lap."""
        return 6 * self.side_time

    def at(self, tau: float) -> tuple[np.ndarray, np.ndarray]:
        """Desired position (3,) m and velocity (3,) m/s at path time ``tau`` (s)."""
        t_acc, t_cruise, v, a = self._profile()
        T = 2 * t_acc + t_cruise
        tau = float(tau) % (6 * T)
        k = min(int(tau // T), 5)
        u = tau - k * T
        if u < t_acc:
            s, sd = 0.5 * a * u * u, a * u
        elif u < t_acc + t_cruise:
            s, sd = 0.5 * a * t_acc ** 2 + v * (u - t_acc), v
        else:
            w = T - u
            s, sd = self.side - 0.5 * a * w * w, a * w
        C = self.corners
        p0, p1 = C[k], C[(k + 1) % 6]
        e = (p1 - p0) / self.side
        return p0 + s * e, sd * e

    def path_distance(self, points: np.ndarray) -> np.ndarray:
        """(N,) distance (m) of points (N, 3) to the hexagon's polyline (geometric tracking error)."""
        P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        C = self.corners
        out = np.full(len(P), np.inf)
        for k in range(6):
            a, b = C[k], C[(k + 1) % 6]
            ab = b - a
            t = np.clip((P - a) @ ab / (ab @ ab), 0.0, 1.0)
            out = np.minimum(out, np.linalg.norm(P - (a + t[:, None] * ab), axis=1))
        return out
