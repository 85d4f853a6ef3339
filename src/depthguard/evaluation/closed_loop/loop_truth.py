"""Ground truth of the closed loop: how far the robot really is from everything else (R15, R25).

Not part of the system: the simulation's own yardstick for ``min_true_distance_m``
and ``collision`` in a run's summary. :class:`LoopTruth` samples each capsule
axis of the robot every ``step`` metres and takes the exact signed distance of
those points (and of the control points) to the static scene and to the moving
obstacles, in one numba pass over the packed primitives
(:mod:`depthguard.geometry.packed`): a capsule's true clearance is
overestimated by at most ``step / 2``.

What the robot is mounted on: a capsule fitted around a link overhangs the
link's mesh, and the capsule of a link next to the base (a UR's shoulder)
reaches a few millimetres into the table top the robot stands on — a
collision in every cycle that no motion causes or can avoid. A static object
is the **mount** of a capsule's point when the point touches it at the start and its
distance to it does not change, within 1 mm, when the joints move (the
shoulder turning about the vertical over a table): such a contact is the
capsule's overhang at the mount, which no motion causes or removes. It is
decided per sample point of the capsule axis: the points at the end of the
upper arm's capsule on (within 2 mm of) the shoulder joint's axis, which stay at the table when
the arm turns, are carried; the rest of the upper arm, which the arm can swing
down, keeps counting against the table. Every point counts against every other
object and the people. The carried points are named in
:attr:`LoopTruth.excluded`.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from depthguard.geometry.packed import PackedSolids

__all__ = ["LoopTruth"]


class LoopTruth:
    """True distances of a robot in a scene (module docstring).

    ``robot``: the robot model (``collision_segments``, ``capsules``, joint limits);
    ``static``: the scene's static primitives; ``q_start`` (n,) rad: where the run starts;
    ``step`` m: the sampling along the capsule axes.

    Capsules that never move and touch the static scene (the base on its mount) are left
    out (:attr:`excluded`, named in the summary); every other capsule counts.
    """

    def __init__(self, robot, static: Sequence, q_start: np.ndarray, step: float):
        from depthguard.sim.ground_truth import true_distance
        self.robot = robot
        q = np.asarray(q_start, dtype=np.float64)
        ab0, r0 = robot.collision_segments(q)
        rng = np.random.default_rng(1)
        moved = np.zeros(len(ab0), dtype=bool)
        for _ in range(3):
            q2 = np.clip(q + rng.uniform(-0.5, 0.5, q.shape), robot.q_min, robot.q_max)
            ab2, _ = robot.collision_segments(q2)
            moved |= np.abs(ab2 - ab0).reshape(len(ab0), -1).max(axis=1) > 1e-9
        lengths = np.linalg.norm(ab0[:, 1] - ab0[:, 0], axis=1)
        n = np.maximum(2, np.ceil(lengths / step).astype(int) + 1)
        touching = np.zeros(len(ab0), dtype=bool)
        for i in range(len(ab0)):
            u = np.linspace(0.0, 1.0, n[i])[:, None]
            pts = ab0[i, 0] * (1 - u) + ab0[i, 1] * u
            touching[i] = np.min(true_distance(static, pts) - r0[i]) <= 0.005
        keep = np.nonzero(moved | ~touching)[0]
        # the sample points of every kept capsule axis at once: capsule index and parameter u
        self._cap = np.concatenate([np.full(n[i], i, dtype=np.intp) for i in keep] or [np.zeros(0, np.intp)])
        self._u = np.concatenate([np.linspace(0.0, 1.0, n[i]) for i in keep] or [np.zeros(0)])[:, None]
        # per mount object: the sample points it carries (their distance to it is not counted)
        mount = _mount_points(robot, static, q, self._cap, self._u, rng)
        self._mount = [(static[j], carried) for j, carried in mount]
        mounts = {j for j, _ in mount}
        self._static, self._static_rest = PackedSolids.split([p for j, p in enumerate(static) if j not in mounts])
        self._dyn_memo = None
        names = [c.name or c.link for c in robot.capsules]
        self.excluded = [names[i] for i in range(len(names)) if i not in set(keep.tolist())]
        for j, carried in mount:
            caps = sorted(set(self._cap[carried].tolist()))
            self.excluded += [f"{names[i]} against {static[j].name or f'static object {j}'}, its mount "
                              f"({int(np.sum(carried & (self._cap == i)))} of {int(np.sum(self._cap == i))} "
                              f"axis points)" for i in caps]

    def __call__(self, P: np.ndarray, q: np.ndarray, moving: list) -> tuple[np.ndarray, float, float]:
        """``(d_cp (m,), d_robot, d_robot_moving)``: the control points ``P`` (m, 3) to every
        obstacle (0 inside); the robot's kept capsules at joints ``q`` to every obstacle and to the
        ``moving`` primitives alone (axis-point distance minus the radius: ``<= 0`` = collision)."""
        ab, r = self.robot.collision_segments(q)
        m = len(P)
        c, u = self._cap, self._u
        X = np.concatenate([P, ab[c, 0] * (1.0 - u) + ab[c, 1] * u])
        r_all = np.concatenate([np.zeros(m), r[c]])
        memo = self._dyn_memo            # one read: a still person's solids are packed once
        if memo is None or len(memo[0]) != len(moving) or any(a is not b for a, b in zip(memo[0], moving)):
            memo = self._dyn_memo = (list(moving), *PackedSolids.split(moving))
        sd_dyn = memo[1].sdf_min(X)
        for prim in memo[2]:
            np.minimum(sd_dyn, prim.sdf(X), out=sd_dyn)
        sd_dyn = np.maximum(sd_dyn, 0.0)                                   # 0 inside
        sd_static = self._static.sdf_min(X)
        for prim in self._static_rest:
            np.minimum(sd_static, prim.sdf(X), out=sd_static)
        for prim, carried in self._mount:                # a mount: not against the capsules it carries
            sd = prim.sdf(X)
            sd[m:][carried] = np.inf
            np.minimum(sd_static, sd, out=sd_static)
        d = np.minimum(sd_dyn, np.maximum(sd_static, 0.0)) - r_all
        return np.maximum(d[:m], 0.0), float(d[m:].min()), float((sd_dyn - r_all)[m:].min())


def _mount_points(robot, static, q: np.ndarray, cap: np.ndarray, u: np.ndarray, rng, touch: float = 0.005,
                  invariant: float = 1e-3) -> list[tuple[int, np.ndarray]]:
    """``[(static index, (k,) bool), ...]``: per static object that carries the robot, which of the
    ``k`` capsule-axis sample points (capsule ``cap``, parameter ``u`` (k, 1)) it carries (module
    docstring): within ``touch`` m of it at ``q`` (n,), at a distance that changes by at most
    ``invariant`` m over six joint motions (three of +-0.5 rad, three anywhere in the limits)."""
    lo = np.where(np.isfinite(robot.q_min), robot.q_min, -np.pi)
    hi = np.where(np.isfinite(robot.q_max), robot.q_max, np.pi)
    motions = [np.clip(q + rng.uniform(-0.5, 0.5, q.shape), lo, hi) for _ in range(3)]
    motions += [rng.uniform(lo, hi) for _ in range(3)]

    def points(qm):
        ab, r = robot.collision_segments(qm)
        return ab[cap, 0] * (1.0 - u) + ab[cap, 1] * u, r[cap]

    X0, r = points(q)
    Xs = [points(qm)[0] for qm in motions]
    out = []
    for j, prim in enumerate(static):
        d0 = prim.sdf(X0) - r
        carried = d0 <= touch
        for X in Xs:
            if not carried.any():
                break
            carried &= np.abs(prim.sdf(X) - r - d0) <= invariant
        if carried.any():
            out.append((j, carried))
    return out
