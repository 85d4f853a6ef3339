"""Path watch: stop before a segment ahead turns unsafe, resume when it clears (R37; a reaction policy).

The robot runs a planned path (waypoints with stamps, :mod:`depthguard.control.path_check`); at
every map update the remaining segments get fresh verdicts. :class:`PathWatch` turns those
verdicts and the robot's progress into a speed limit in [0, 1] and a reason, using the stopping
model of the SSM settings (:func:`depthguard.control.ssm.stopping`, R33):

- the distance left ``L`` (m) is the travel of the robot's fastest point from its progress to
  the start of the first segment whose verdict is in ``stop_on`` (default ``("unsafe",)``; add
  ``"maybe"`` to stop before unknown space as well), the path's own per-segment travel
  (:func:`segment_travel`) pro rata within the current segment;
- at point speed ``v`` (m/s, at scale 1) the robot needs ``v T_r + S_s(v)`` to stop (``T_r`` the
  reaction time: map period + latencies; ``S_s`` the SSM stopping distance); the limit is the
  largest scale ``s`` in [0, 1] with ``v T_r + S_s(s v) <= L - margin`` — the reaction term at
  full speed, since until the limit applies the robot may still run at ``v`` (with ``s v`` there,
  a robot braking along the limit overshoots by its lag) — 1 far away, falling along a braking
  curve as the robot nears the blocked segment, 0 when it can no longer stop short of it plus
  ``margin``;
- nothing ahead blocked (it cleared): 1, so the robot resumes by itself.

:class:`PathWatchPolicy` is the reaction policy ``path_watch`` (issue 28's registry; the most
restrictive of all policies wins): ``monitor: reactions: [repulsion, path_watch]`` and
``Monitor.watch_path(stamps, q)``. No numba: a bisection of 40 steps per cycle while a segment
ahead is blocked, nothing otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from depthguard.control.path_check import capsule_ends
from depthguard.control.ssm import stopping

__all__ = ["PathWatch", "PathLimit", "segment_travel", "PathWatchPolicy", "WatchedPath"]


def segment_travel(robot, q) -> np.ndarray:
    """(n-1,) m: per segment of the path ``q`` (n, dof) rad, the largest displacement of a capsule
    axis end from one waypoint to the next (the fastest point's travel; exact for straight
    Cartesian moves, a lower bound of the arc otherwise — waypoints close together keep it near)."""
    A, B = capsule_ends(robot, np.asarray(q, dtype=np.float64))
    ends = np.concatenate([A, B], axis=1)                     # (n, 2K, 3)
    return np.max(np.linalg.norm(np.diff(ends, axis=0), axis=2), axis=1)


@dataclass(frozen=True)
class PathLimit:
    """``limit`` in [0, 1] (1 = no limit), ``reason`` ('' when 1), ``segment`` the blocked segment
    ahead (None: none), ``distance`` m left to it (inf: none)."""
    limit: float
    reason: str = ""
    segment: int | None = None
    distance: float = math.inf


class PathWatch:
    """The path watch (module docstring).

    ssm : the :class:`~depthguard.control.ssm_config.SSMConfig` (its stopping model).
    reaction_time : s from a map's frames to the robot applying the limit (map period + latencies).
    margin : m kept between the stopped robot and the blocked segment.
    stop_on : the verdicts that block a segment.
    """

    def __init__(self, ssm, reaction_time: float, margin: float = 0.05, stop_on=("unsafe",)):
        if not (math.isfinite(reaction_time) and reaction_time >= 0):
            raise ValueError(f"reaction_time must be >= 0 s, got {reaction_time!r}")
        if not (math.isfinite(margin) and margin >= 0):
            raise ValueError(f"margin must be >= 0 m, got {margin!r}")
        bad = set(stop_on) - {"unsafe", "maybe"}
        if bad:
            raise ValueError(f"stop_on takes 'unsafe' and 'maybe', got {sorted(bad)}")
        self.ssm = ssm
        self.reaction_time = float(reaction_time)
        self.margin = float(margin)
        self.stop_on = tuple(stop_on)

    def needed(self, v: float) -> float:
        """m to stop from point speed ``v`` m/s: ``v T_r + S_s(v)``."""
        return v * self.reaction_time + stopping(v, self.ssm)[0]

    def limit(self, verdict, stamps, travel, t: float, v: float) -> PathLimit:
        """The limit at path time ``t`` s (the robot's progress, on the path's stamps) and point
        speed ``v`` m/s at scale 1, given ``verdict`` (a :class:`PathVerdict` of the path, or of
        its remaining part with the same segment indices), the path's ``stamps`` (n,) s and
        ``travel`` (n-1,) m (:func:`segment_travel`)."""
        stamps = np.asarray(stamps, dtype=np.float64)
        travel = np.asarray(travel, dtype=np.float64)
        if t >= stamps[-1]:
            return PathLimit(1.0)
        blocked = [s for s in verdict.segments if s.verdict in self.stop_on and s.t1 > t]
        if not blocked:
            return PathLimit(1.0)
        seg = blocked[0]
        k = seg.index
        if t >= stamps[k]:                       # already inside the blocked segment
            return PathLimit(0.0, f"path watch: in segment {k}, which is {seg.verdict}: {seg.reason}", k, 0.0)
        i = int(np.searchsorted(stamps, t, side="right")) - 1
        i = max(i, 0)
        frac = (stamps[i + 1] - t) / (stamps[i + 1] - stamps[i])
        L = float(frac * travel[i] + np.sum(travel[i + 1:k]))
        room = L - self.margin
        v = max(float(v), 0.0)
        brake_room = room - v * self.reaction_time     # until the limit applies: still at up to v
        if brake_room <= 0.0:
            s = 0.0
        elif self.needed(v) <= room:
            s = 1.0
        else:
            lo, hi = 0.0, 1.0
            for _ in range(40):
                mid = 0.5 * (lo + hi)
                if stopping(mid * v, self.ssm)[0] <= brake_room:
                    lo = mid
                else:
                    hi = mid
            s = lo
        why = (f"path watch: segment {k} ahead ({seg.t0:.2f}-{seg.t1:.2f} s, {L:.2f} m away) is {seg.verdict}: "
               f"{seg.reason}")
        return PathLimit(s, why if s < 1.0 else "", k, L)


@dataclass(frozen=True)
class WatchedPath:
    """The path being run: ``stamps`` (n,) s, ``q`` (n, dof) rad, ``travel`` (n-1,) m per segment
    (:func:`segment_travel`), ``speed`` (n-1,) m/s its fastest point's speed per segment."""
    stamps: np.ndarray
    q: np.ndarray
    travel: np.ndarray
    speed: np.ndarray


class PathWatchPolicy:
    """The path watch as a reaction policy (:mod:`depthguard.control.policy`, R37): registered as
    ``path_watch``; the most restrictive of the monitor's policies wins.

    The monitor gives it the path the robot runs (:meth:`set_path`, from ``Monitor.watch_path``)
    and, at every map update, the fresh verdict of that path (:meth:`set_verdict`, on the map's
    thread). Each cycle: the robot's progress along the path from its joints (the nearest point of
    the path in joint space, never more than one segment back), its fastest point's speed on the
    path ahead at scale 1, and :meth:`PathWatch.limit` -> ``scale``; ``stop`` when it is 0 (the
    supervisor ramps back up once the segment clears: the robot resumes by itself). The reaction
    time is two map periods (a frame waits up to one for a build, the build and check take at
    most another) + the SSM settings' camera and controller latencies + one control period; the
    margin 5 cm. No path or no verdict yet: no limit.
    """
    name = "path_watch"

    def __init__(self, setup):
        cfg = setup.config
        self.robot = setup.robot
        t_r = 2.0 / cfg.free_space_hz + cfg.ssm.camera_latency_s + cfg.ssm.controller_latency_s + cfg.dt
        self.watch = PathWatch(cfg.ssm, reaction_time=t_r, margin=0.05)
        self.path: WatchedPath | None = None
        self.verdict = None
        self._seg = 0

    def set_path(self, stamps, q) -> WatchedPath:
        """Watch the path ``stamps`` (n,) s, ``q`` (n, dof) rad (validated by the caller); its
        verdict is unknown until the next :meth:`set_verdict`."""
        stamps = np.asarray(stamps, dtype=np.float64)
        q = np.asarray(q, dtype=np.float64)
        travel = segment_travel(self.robot, q)
        path = WatchedPath(stamps, q, travel, travel / np.diff(stamps))
        self.verdict = None
        self._seg = 0
        self.path = path
        return path

    def clear_path(self) -> None:
        self.path = None
        self.verdict = None

    def set_verdict(self, verdict, path: WatchedPath | None = None) -> None:
        """The verdict of ``path`` (default the current one) in a fresh map; dropped if the path
        changed meanwhile."""
        if path is None or path is self.path:
            self.verdict = verdict

    def progress(self, q) -> float:
        """Path time (s) of the nearest point of the path to the joints ``q`` (dof,) rad."""
        p = self.path
        i0 = max(self._seg - 1, 0)
        a = p.q[i0:-1]
        d = p.q[i0 + 1:] - a
        L2 = np.einsum("ij,ij->i", d, d)
        u = np.clip(np.einsum("ij,ij->i", q - a, d) / np.where(L2 > 0, L2, 1.0), 0.0, 1.0)
        e = q - (a + u[:, None] * d)
        k = int(np.argmin(np.einsum("ij,ij->i", e, e)))
        self._seg = i0 + k
        return float(p.stamps[i0 + k] + u[k] * (p.stamps[i0 + k + 1] - p.stamps[i0 + k]))

    def update(self, c):
        from depthguard.control.policy import Part

        p, verdict = self.path, self.verdict
        if p is None or verdict is None:
            return Part(record={"watching": p is not None, "verdict": None})
        t = self.progress(np.asarray(c.q, dtype=np.float64))
        v = float(np.max(p.speed[min(self._seg, len(p.speed) - 1):]))
        lim = self.watch.limit(verdict, p.stamps, p.travel, t, v)
        stop = lim.limit <= 0.0
        return Part(scale=float(lim.limit), stop=stop, reasons={"path_watch": lim.reason} if lim.limit < 1.0 else {},
                    record={"watching": True, "verdict": verdict.verdict, "path_t": t, "segment": lim.segment,
                            "distance": lim.distance if math.isfinite(lim.distance) else None,
                            "limit": float(lim.limit)})
