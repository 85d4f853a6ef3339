"""The monitor's distances of one cycle (R12, R15): the front grid queried on the control thread, or
the distance worker's newest answer bounded at the cycle's points (:meth:`MonitorDistances.real_time`,
:mod:`depthguard.runtime.distances`). A part of :class:`depthguard.runtime.monitor.Monitor`, apart
to keep each file short; it uses the monitor's fusion worker, points and counters.
"""

from __future__ import annotations

import time
from contextlib import contextmanager

import numpy as np

from depthguard.runtime.distances import DistanceWorker, bound_distances
from depthguard.runtime.realtime import TIMING_KEEP, frozen_heap

__all__ = ["MonitorDistances"]


class MonitorDistances:
    """The distance half of :class:`~depthguard.runtime.monitor.Monitor` (module docstring)."""

    def _distances(self, cfg, q, D, V, obs, query_rho=None) -> dict[str, float]:
        """Distances of ``self._P`` into ``D``, ``V``, ``obs``; returns the capture stamps of the
        frames used. With the distance worker (:meth:`real_time`): its newest answer bounded at
        ``self._P``; when that answer is older than the worker's ``max_age_s`` (the worker
        starved or failed) or a point moved beyond the margin, a query of the grid here — unless
        the one grid is being built or the worker's last query took more than half a control
        period: then the bound of the newest answer however old (its frames' stamps say how
        old), points it cannot decide unobserved
        (:mod:`depthguard.runtime.distances`). Without the worker: a query of the front grid."""
        worker = self._dist_worker
        if worker is None:
            return self._query_front(cfg, D, V, obs)
        rho = cfg.query_rho if query_rho is None else query_rho     # the caller's, worked out once per config
        worker.request(q.copy(), self._P)
        snap = worker.newest()
        usable = snap is not None and snap.rho == rho and snap.method == cfg.method
        if not usable:
            why = "no_answer" if snap is None else "settings_changed"
        elif time.perf_counter() - snap.wall > worker.max_age_s:
            why = "answer_too_old"
        elif bound_distances(snap, self._P, rho, D, V, obs):
            if snap.versions is not self._counted:       # a snapshot's dicts are its own: counted once
                self._count_frames(snap.versions, snap.pushed_at)
                self._counted = snap.versions            # (a grid buffer's change in place: never kept)
            return dict(snap.stamps)
        else:
            why = "moved_beyond_margin"
        if worker.last_query_s > 0.5 * cfg.dt:  # a query here would take the cycle: never
            stamps, busy = None, "_query_too_slow"
        else:
            stamps, busy = self._query_front(cfg, D, V, obs, wait=not self.fusion.single), "_grid_busy"
        if stamps is None:                      # the one grid is being built: never wait
            if not usable:
                return {}                       # nothing to bound: unobserved, no frame in use
            why += busy
            if not bound_distances(snap, self._P, rho, D, V, obs):
                bound_distances(snap, self._P, rho, D, V, obs, strict=False)
                why += "_some_points_unjudged"
            self._count_frames(snap.versions, snap.pushed_at)
            stamps = dict(snap.stamps)
        if stamps:                              # a grid answered (not: no frame yet)
            self.distance_fallbacks[why] = self.distance_fallbacks.get(why, 0) + 1
        return stamps

    def _query_front(self, cfg, D, V, obs, wait: bool = True) -> dict[str, float] | None:
        """Query the front grid on this thread (the cycle's own query). ``wait`` False: None
        when the grid is locked (a build into the one grid, or another reader)."""
        stamps: dict[str, float] = {}
        with self.fusion.swap_lock:
            buf = self.fusion.front
            if buf is not None and not buf.lock.acquire(blocking=wait):
                return None
        if buf is not None:
            try:
                if buf.loaded:
                    res = buf.grid.query(self._P, rho=cfg.query_rho, method=cfg.method, threads=1)
                    D[:] = res.distance
                    V[:] = res.direction
                    obs[:] = res.observed
                    stamps = dict(buf.stamps)
                    self._count_frames(buf.versions, buf.pushed_at)
            finally:
                buf.lock.release()
        return stamps

    def _count_frames(self, versions, pushed_at) -> None:
        """Frame-to-reaction times of the frames a cycle uses for the first time."""
        self._counted = None
        now = time.perf_counter()
        for c, v in versions.items():
            if self._seen.get(c) != v:
                self._seen[c] = v
                self.frame_to_reaction_s.append(now - pushed_at[c])
                if len(self.frame_to_reaction_s) > TIMING_KEEP:     # a long run keeps the newest
                    del self.frame_to_reaction_s[:TIMING_KEEP // 2]

    @contextmanager
    def real_time(self):
        """``with monitor.real_time(): ...`` around a real-time run's control loop, entered on
        the control thread (after its SCHED_FIFO, :mod:`depthguard.runtime.realtime`): the grid
        is queried on a thread of its own at ``distance_hz`` and each cycle bounds the newest
        answer (:mod:`depthguard.runtime.distances`). ``distance_hz`` 0 or the ``mean`` method
        (not a bound under motion): nothing changes there. Fast runs do not use it: their logs do
        not depend on thread timing.

        For its length the objects made before it are left out of the cyclic garbage collector
        (:func:`~depthguard.runtime.realtime.frozen_heap`, as :func:`~depthguard.runtime.runner.run`
        does; nested, only the outermost collects and freezes): a full collection walks only what
        the run makes. Without it a program that drives the monitor itself met a full collection
        of ~200k objects now and then, 30-70 ms holding the GIL, and every thread waited (the
        monitor bench's 8 cameras: 30 cycles late, 7 frames replaced before their worker took
        them, issue 29)."""
        with frozen_heap():
            with self._distance_thread():
                yield self

    @contextmanager
    def _distance_thread(self):
        """The distance half of :meth:`real_time`."""
        cfg = self.config
        if cfg.distance_hz <= 0 or cfg.method == "mean" or self._dist_worker is not None:
            single = self.fusion.single
            if self._dist_worker is None:
                self.fusion.set_single(False)    # the cycles read the grid: two, never wait
            try:
                yield
            finally:
                self.fusion.set_single(single)
            return
        worker = DistanceWorker(self.fusion, self._points_at, self._distance_settings, cfg.distance_hz,
                                cfg.distance_margin)
        self.fusion.ahead_margin = cfg.distance_margin
        single = self.fusion.single
        self.fusion.set_single(True)             # no cycle reads the grid: one grid, half the builds' work
        self._dist_worker = worker
        self.fusion.answer = worker.offer        # a build's own query is the newest answer at once
        worker.start()
        try:
            yield
        finally:
            self._dist_worker = None
            self.fusion.answer = None
            self.fusion.set_single(single)
            self.fusion.ahead_margin = 0.0
            worker.close()
            self.distance_queries += worker.queries
            self.distance_answers_from_builds += worker.offered

    @contextmanager
    def replay(self):
        """``with monitor.replay(): ...`` for runs that ``flush()`` before every ``step`` (the
        simulated closed loop, fast replays): one grid instead of two
        (:meth:`~depthguard.runtime.fusion_worker.FusionWorker.set_single` — the same answers at half
        the work per frame when cameras take turns); a cycle then waits for a build in progress,
        which a real-time loop must never do."""
        single = self.fusion.single
        self.fusion.set_single(True)
        try:
            yield self
        finally:
            self.fusion.set_single(single)

    def _points_at(self, q) -> np.ndarray:
        """(m, 3) the control points at ``q`` then the watch points (the distance worker's thread)."""
        data = self._worker_data
        self.robot.forward(q, data)
        return np.concatenate([data.cp_positions, self._watch]) if len(self._watch) else data.cp_positions.copy()

    def _distance_settings(self):
        with self._settings_lock:
            cfg = self.config
        return self._derived(cfg)[1], cfg.method        # query_rho worked out once per configuration
