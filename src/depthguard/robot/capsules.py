"""Capsules that cover link geometry (robot self volume, R9 / R12 / R21).

A :class:`LinkCapsule` is a segment ``a → b`` in a link's frame with a
radius; the set of points within ``radius`` of the segment. They are the
robot's padded own volume, its ground-truth distance body, and the volume
the free-space map marks as free.

:func:`fit_capsule` finds a capsule that contains every given point exactly
(no point farther than ``radius`` from the segment): for a candidate axis
``u`` through the middle ``c`` of the points' extent across it, with ``t = (v − c)·u`` and ``ρ`` the
distance of ``v`` from the axis, ``r = max ρ`` and the segment
``[max(t − √(r² − ρ²)), min(t + √(r² − ρ²))]`` reversed, i.e. the shortest
segment whose end caps still reach every point. Of the principal axes and
the link frame's axes, the candidate of least volume wins.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["LinkCapsule", "fit_capsule", "point_segment_distance"]


@dataclass(frozen=True, eq=False)
class LinkCapsule:
    """Capsule fixed to ``link``: end points ``a``, ``b`` (3,) in the link frame (m), ``radius`` (m)."""
    link: str
    a: np.ndarray
    b: np.ndarray
    radius: float
    name: str = ""


def point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N,) distance of points ``p`` (N, 3) to the segment ``a b``."""
    p = np.asarray(p, dtype=np.float64).reshape(-1, 3)
    ab = b - a
    L2 = float(ab @ ab)
    t = np.zeros(len(p)) if L2 == 0 else np.clip((p - a) @ ab / L2, 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def _fit_along(v: np.ndarray, c: np.ndarray, u: np.ndarray):
    # centre the axis on the middle of the extent across it
    e1 = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    for e in (e1, e2):
        s = (v - c) @ e
        c = c + 0.5 * (s.min() + s.max()) * e
    d = v - c
    t = d @ u
    rho = np.linalg.norm(d - t[:, None] * u, axis=1)
    r = float(rho.max())
    h = np.sqrt(np.maximum(r * r - rho * rho, 0.0))
    t0, t1 = float(np.min(t + h)), float(np.max(t - h))
    if t0 > t1:  # caps overlap: a sphere about the middle
        tm = 0.5 * (t0 + t1)
        a = b = c + tm * u
        r = float(np.linalg.norm(v - a, axis=1).max())
    else:
        a, b = c + t0 * u, c + t1 * u
    vol = np.pi * r * r * np.linalg.norm(b - a) + 4.0 / 3.0 * np.pi * r ** 3
    return a, b, r, vol


def fit_capsule(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """A capsule ``(a, b, radius)`` containing all ``vertices`` (N, 3); small, not minimal."""
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    if len(v) == 0:
        raise ValueError("fit_capsule: no vertices")
    c = v.mean(axis=0)
    cands = list(np.eye(3))
    if len(v) >= 3:
        _, _, vt = np.linalg.svd(v - c, full_matrices=False)
        cands += list(vt)
    best = None
    for u in cands:
        fit = _fit_along(v, c, u / np.linalg.norm(u))
        if best is None or fit[3] < best[3]:
            best = fit
    a, b, r, _ = best
    return a, b, r
