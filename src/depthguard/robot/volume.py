"""The robot's own volume while the cameras' frames were captured (R9, R12, R25).

Used by the fusion worker of the monitor (:mod:`depthguard.runtime.ingest`: the volume
the depth grid excludes) and by the layout's blind-spot check
(:mod:`depthguard.evaluation.coverage`); it sits with the robot, below both.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["robot_volume"]


@njit(cache=True)      # microseconds: keeps the GIL
def _grow_by(grow, ab, ab2):
    """``grow[c] = max(grow[c], |ab2[c, e] - ab[c, e]|)`` over both end points ``e``: how far
    capsule ``c``'s ends (C, 2, 3) m moved between two poses (one compiled call per pose instead of
    numpy's difference, norm and max: the fusion's build runs it per frame, issue 29)."""
    for c in range(ab.shape[0]):
        g = grow[c]
        for e in range(2):
            dx = ab2[c, e, 0] - ab[c, e, 0]
            dy = ab2[c, e, 1] - ab[c, e, 1]
            dz = ab2[c, e, 2] - ab[c, e, 2]
            g = max(g, math.sqrt(dx * dx + dy * dy + dz * dz))
        grow[c] = g


def robot_volume(robot, poses, padding: float, cache: dict | None = None,
                 unpadded=None) -> tuple[np.ndarray, np.ndarray]:
    """The robot's own volume for frames captured at several joint poses (R9, R12): its padded
    capsules at the first pose, each grown by how far that capsule's end points move to any
    other pose — ``(segments (C, 2, 3), radii (C,))`` metres, world.

    The cameras are not synchronised: each frame shows the robot where it was at that frame's
    capture, and a cell behind the robot in one camera is confirmed by another that saw the
    robot a moment earlier or later. The robot swept the space between those poses in that
    time, so that space is its own, not an obstacle (without the growth, at 1 m/s and 21 ms
    between two captures the end effector read a phantom 0.10-0.15 m away). One pose's grown
    capsules hold every pose's padded capsules and every sweep between two poses: a point
    between ``p_j(t)`` and ``p_k(t)`` on the segments of poses ``j`` and ``k`` lies within
    ``max(|p_j(t) - p_i(t)|, |p_k(t) - p_i(t)|)`` of pose ``i``'s segment (the distance is
    convex), at most the growth. So the other poses' grown capsules add nothing the robot
    occupied, only more exclusion (and twice the capsules per build). An excluded cell lies
    within ``padding`` plus the robot's motion between the captures in use (R25).

    ``cache``: a dict the caller keeps between calls (the fusion worker: one per grid build
    loop). A pose given as the same array object as in an earlier call with the same
    ``padding`` reuses that call's capsules (a camera whose frame did not change keeps its
    capture joints' array); the arrays must not be written in between. At most 64 poses
    are kept.

    ``unpadded``: optional, aligned with ``poses``: per pose ``None`` or the capsules
    ``robot.collision_segments(q, 0.0)`` already made at it (the camera worker's, issue 29: made
    on the camera's thread, not the fusion's); their radii plus ``padding`` are the padded
    capsules bit for bit (``r + 0.0 == r``), so the forward kinematics is not done again.
    """
    given = {} if unpadded is None else {id(q): s for q, s in zip(poses, unpadded) if s is not None}
    uniq = list({id(q): q for q in poses}.values())
    segs = []
    for q in uniq:
        hit = None if cache is None else cache.get(id(q))
        if hit is None or hit[0] is not q or hit[1] != padding:
            made = given.get(id(q))
            made = robot.collision_segments(q, padding) if made is None else (made[0], made[1] + float(padding))
            if cache is None:
                segs.append(made)
                continue
            if len(cache) >= 64:
                cache.clear()
            hit = cache[id(q)] = (q, padding, made)
        segs.append(hit[2])
    ab, r = segs[0]
    if len(segs) == 1:
        return ab, r.copy()
    grow = np.zeros(len(r))
    for ab2, _ in segs[1:]:
        _grow_by(grow, ab, ab2)
    return ab, r + grow
