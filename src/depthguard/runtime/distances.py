"""Distances off the control thread, and their bound at the control cycle's joints (R12, R29).

In a real-time run the control thread does not query the depth grid itself
(0.5–0.8 ms for 9 points on a 2-core machine, most of a 1 ms budget): a
:class:`DistanceWorker` thread queries it at ``distance_hz`` with the joints
of the newest control cycle and publishes a :class:`DistanceSnapshot`. The
cycle at time ``t`` takes the newest snapshot and bounds it at its own
points ``P`` (:func:`bound_distances`):

* The distance to a fixed set of obstacles is 1-Lipschitz in the point's
  position: a point that moved by ``Δ = |P - P₀|`` since the snapshot is at
  least ``d₀ - Δ`` from every obstacle of that snapshot's frames (``d₀`` the
  true distance at ``P₀``). The cycle reports ``max(D₀ - Δ, 0)``: R12's bound
  against the truth is kept (never farther than the truth by more than the
  discretisation), and the answer is at most ``Δ`` nearer than a query at ``P``.
* "Nothing within ρ" needs the same care: the snapshot is queried with
  ``ρ + margin`` (the direction still from the pixels within ρ, R7; the band
  between ρ and ρ + margin counts for the distance only,
  :func:`~depthguard.fusion.depth_grid_lazy_lookup.grid_distances_lazy`), so
  ``D₀ = inf`` at ``P₀`` means nothing within ``ρ + margin - Δ >= ρ`` at ``P``.
* A point that moved more than ``margin`` since the snapshot, a snapshot older
  than ``max_age_s`` of wall time (the worker starved or failed), another ρ
  or method than the cycle's: the cycle queries the grid itself, as without
  the worker — unless the grid is being built (one grid,
  :meth:`~depthguard.runtime.fusion_worker.FusionWorker.set_single`) or a query takes
  more than half a control period (the worker's last one did: a large radius,
  as speed and separation monitoring asks): the cycle does not wait; it keeps
  the bound where it holds and reports the other points unobserved (R26:
  cannot judge), which slows the robot. ``observed`` is the
  snapshot's and ``P`` in the principal's image and range (R26).
* The frames' capture stamps that the supervision checks (R27) are those of
  the snapshot's grid: an old snapshot makes the cameras older, never younger.

The worker queries only when the newest answer is not good enough (issue 29: a query of ur3-cell's
grid takes 1.3–1.7 ms of CPU, and the fusion's builds already publish one at the newest joints
at every frame, :meth:`DistanceWorker.offer`): every period it compares the newest cycle's
points with the newest answer's, and queries when one moved more than
:data:`REQUERY_FRACTION` of the margin, when the front grid is newer than the answer's, or
when the settings changed. An answer of the front grid at points that have not moved that far
is still the newest answer: older than a period it is published again with a new wall time
(``reused``, ~10 us) instead of being queried again — a query of the same grid at the same points
gives the same answer, and the cycles' bound covers the rest.

The worker runs one priority below the control thread when that one is
SCHED_FIFO (it preempts the camera and fusion workers, never the control
cycle), else under normal scheduling.
"""

from __future__ import annotations

import dataclasses
import math
import os
import threading
import time
from dataclasses import dataclass

import numba
import numpy as np

__all__ = ["DistanceSnapshot", "DistanceWorker", "bound_distances", "bound_distances_numpy", "moved_beyond",
           "moved_beyond_numpy", "REQUERY_FRACTION"]

#: a point that moved more than this share of the margin since the newest answer makes the worker query
REQUERY_FRACTION = 0.25


@dataclass(frozen=True)
class DistanceSnapshot:
    """One query of the front grid by the worker.

    P : (m, 3) world m, the points queried (control points at ``q``, then watch points).
    D, V, observed : the grid's answer with radius ``rho + margin`` (direction from ρ).
    stamps, versions, pushed_at : per camera, of the grid's frames.
    view : the principal's ``(R, t, pint, W, H)`` (world → camera, intrinsics) for R26.
    wall : ``perf_counter`` when the query finished.
    generation : the grid buffer's build count when queried (a newer build wins).
    """
    P: np.ndarray
    D: np.ndarray
    V: np.ndarray
    observed: np.ndarray
    rho: float
    margin: float
    method: str
    stamps: dict
    versions: dict
    pushed_at: dict
    view: tuple
    wall: float
    generation: int = -1


@numba.njit(cache=True)      # microseconds: keeps the GIL (a release costs the control thread a hand-over)
def _bound_kernel(P0, D0, V0, obs0, P, rho, margin, R, t, pint, W, H, D, V, obs, strict):
    m = P.shape[0]
    for i in range(m):
        dx = P[i, 0] - P0[i, 0]
        dy = P[i, 1] - P0[i, 1]
        dz = P[i, 2] - P0[i, 2]
        if strict and dx * dx + dy * dy + dz * dz > margin * margin:
            return False
    fx = pint[0]
    fy = pint[1]
    cx = pint[2]
    cy = pint[3]
    for i in range(m):
        dx = P[i, 0] - P0[i, 0]
        dy = P[i, 1] - P0[i, 1]
        dz = P[i, 2] - P0[i, 2]
        delta = math.sqrt(dx * dx + dy * dy + dz * dz)
        xc = R[0, 0] * P[i, 0] + R[0, 1] * P[i, 1] + R[0, 2] * P[i, 2] + t[0]
        yc = R[1, 0] * P[i, 0] + R[1, 1] * P[i, 1] + R[1, 2] * P[i, 2] + t[1]
        zc = R[2, 0] * P[i, 0] + R[2, 1] * P[i, 1] + R[2, 2] * P[i, 2] + t[2]
        seen = False
        if zc > 0.0:
            px = xc * fx / zc + cx
            py = yc * fy / zc + cy
            seen = (zc >= pint[6] and zc <= pint[7] and px >= -0.5 and px < W - 0.5
                    and py >= -0.5 and py < H - 0.5)
        obs[i] = obs0[i] and seen
        d = D0[i] - delta
        if math.isfinite(d) and d < rho:
            D[i] = max(d, 0.0)
            for a in range(3):
                V[i, a] = V0[i, a]
        else:
            D[i] = np.inf
            for a in range(3):
                V[i, a] = 0.0
            if not math.isfinite(d) and delta > margin:
                obs[i] = False          # nothing within rho + margin, moved farther: cannot judge
    return True


def bound_distances(snap: DistanceSnapshot, P, rho: float, D, V, obs, strict: bool = True) -> bool:
    """Bound ``snap`` at the points ``P`` (m, 3) into ``D`` (m,), ``V`` (m, 3), ``obs`` (m,)
    (module docstring). ``strict``: returns False — and writes nothing — when a point moved
    more than ``snap.margin`` (the caller queries the grid itself). Not strict (the grid is
    busy and the cycle must not wait): such a point keeps its bound ``D₀ - Δ`` where it had
    something within ``rho + margin``, and is *unobserved* (cannot judge, R26) where it had
    nothing — it may have come within rho of something."""
    R, t, pint, W, H = snap.view
    return bool(_bound_kernel(snap.P, snap.D, snap.V, snap.observed, P, float(rho), float(snap.margin),
                              R, t, pint, int(W), int(H), D, V, obs, bool(strict)))


def bound_distances_numpy(snap: DistanceSnapshot, P, rho: float, strict: bool = True):
    """Plain twin of :func:`bound_distances`: ``(D, V, obs)``, or None when strict and a point
    moved too far."""
    P = np.asarray(P, dtype=np.float64)
    delta = np.linalg.norm(P - snap.P, axis=1)
    if strict and np.any(delta > snap.margin):
        return None
    R, t, pint, W, H = snap.view
    c = P @ np.asarray(R).T + t
    with np.errstate(divide="ignore", invalid="ignore"):
        px = c[:, 0] * pint[0] / c[:, 2] + pint[2]
        py = c[:, 1] * pint[1] / c[:, 2] + pint[3]
    seen = ((c[:, 2] > 0) & (c[:, 2] >= pint[6]) & (c[:, 2] <= pint[7]) & (px >= -0.5) & (px < W - 0.5)
            & (py >= -0.5) & (py < H - 0.5))
    d = snap.D - delta
    near = np.isfinite(d) & (d < rho)
    D = np.where(near, np.maximum(d, 0.0), np.inf)
    V = np.where(near[:, None], snap.V, 0.0)
    undecided = ~np.isfinite(d) & (delta > snap.margin)
    return D, V, snap.observed & seen & ~undecided


@numba.njit(cache=True)
def moved_beyond(P0, P, r) -> bool:
    """True when a row of ``P`` (m, 3) m lies more than ``r`` m from the same row of ``P0`` (or the
    shapes differ): the distance worker's test of its newest answer (module docstring)."""
    if P0.shape[0] != P.shape[0]:
        return True
    r2 = r * r
    for i in range(P.shape[0]):
        dx = P[i, 0] - P0[i, 0]
        dy = P[i, 1] - P0[i, 1]
        dz = P[i, 2] - P0[i, 2]
        if not dx * dx + dy * dy + dz * dz <= r2:
            return True
    return False


def moved_beyond_numpy(P0, P, r) -> bool:
    """Plain twin of :func:`moved_beyond`."""
    if P0.shape[0] != P.shape[0]:
        return True
    return bool(np.any(~(np.sum((P - P0) ** 2, axis=1) <= r * r)))


class DistanceWorker:
    """The thread that queries the monitor's front grid (module docstring).

    fusion : the monitor's :class:`~depthguard.runtime.fusion_worker.FusionWorker` (its ``front``).
    points : ``points(q) -> (m, 3)`` world m, the control points at ``q`` then the watch points.
    settings : ``() -> (rho, method)``, read before every query.
    hz : queries per second; margin : m, the band beyond ρ (module docstring).
    """

    def __init__(self, fusion, points, settings, hz: float, margin: float):
        if not hz > 0 or not margin > 0:
            raise ValueError(f"distance worker: hz and margin must be > 0 (got {hz!r}, {margin!r})")
        self.fusion, self._points, self._settings = fusion, points, settings
        self.period = 1.0 / float(hz)
        self.margin = float(margin)
        self.max_age_s = 3.0 * self.period + 0.02
        self._req: tuple | None = None      # (q, P or None) of the newest control cycle
        self._snap: DistanceSnapshot | None = None
        self._snap_lock = threading.Lock()
        self.offered = 0                 # answers published by the fusion thread's builds
        self.reused = 0                  # answers published again: same grid, points within the requery band
        self._stop = threading.Event()
        self.queries = 0
        self.last_query_s = 0.0          # wall seconds of the newest query, from the grid's lock on
        self.errors = 0
        self.last_error = ""
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Start the thread — from the control thread: it takes that thread's real-time
        priority minus one (module docstring)."""
        if self._thread is not None:
            return
        self._thread = threading.Thread(target=self._run, name="depthguard-distances", daemon=True)
        self._thread.start()

    def request(self, q: np.ndarray, P: np.ndarray | None = None) -> None:
        """The joints of the newest control cycle (dof,) rad: the next query's; ``P`` (m, 3) world m,
        the cycle's points at ``q`` (``points(q)``; copied here), saves the worker their kinematics."""
        self._req = (q, None if P is None else P.copy())

    def offer(self, buf, P, D, V, observed, rho: float, margin: float, method: str) -> None:
        """A fusion build's own query of grid buffer ``buf`` (held by the caller, just built):
        the classify-ahead query at the newest joints' points ``P`` with radius ``rho + margin``
        and the direction from ``rho`` — the worker's query, so it is published as the newest
        answer at once instead of at the worker's next period. Ignored when its band is not the
        worker's."""
        if margin != self.margin:
            return
        self._store(DistanceSnapshot(np.ascontiguousarray(P, dtype=np.float64), D, V, observed, rho, margin,
                                     method, dict(buf.stamps), dict(buf.versions), dict(buf.pushed_at),
                                     buf.grid.principal_view(), time.perf_counter(), buf.generation))
        self.offered += 1

    def _store(self, snap: DistanceSnapshot) -> None:
        with self._snap_lock:
            old = self._snap
            if old is None or snap.generation >= old.generation:
                self._snap = snap

    def latest(self, now: float) -> DistanceSnapshot | None:
        """The newest snapshot, or None when there is none younger than ``max_age_s`` at ``now``
        (``perf_counter``)."""
        s = self._snap
        if s is None or now - s.wall > self.max_age_s:
            return None
        return s

    def newest(self) -> DistanceSnapshot | None:
        """The newest snapshot however old (None before the first)."""
        return self._snap

    def close(self, timeout: float = 2.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)

    # ------------------------------------------------------------ the thread
    def _priority(self) -> None:
        from depthguard.runtime.realtime import normal_scheduling

        numba.set_num_threads(1)
        if hasattr(os, "sched_getscheduler"):
            tid = threading.get_native_id()
            try:
                if os.sched_getscheduler(tid) == os.SCHED_FIFO:
                    p = os.sched_getparam(tid).sched_priority
                    if p > 1:
                        os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(p - 1))
                        return
            except OSError:
                pass
        normal_scheduling()

    def _run(self) -> None:
        self._priority()
        next_t = time.perf_counter()
        stop = self._stop
        while True:
            delay = next_t - time.perf_counter()
            if delay > 0.0:
                time.sleep(delay)            # a C sleep: cheaper than an Event's wait (close() waits a period)
            if stop.is_set():
                return
            next_t = max(next_t + self.period, time.perf_counter())
            req = self._req
            if req is None:
                continue
            try:
                if not self._reuse(req[1]):
                    self._query(req[0], req[1])
            except Exception as exc:               # reported; the control cycle queries itself
                self.errors += 1
                self.last_error = f"{type(exc).__name__}: {exc}"

    def _reuse(self, P) -> bool:
        """True when the newest answer stands for a query now (module docstring): the front grid's,
        with the current settings, at points within ``REQUERY_FRACTION * margin`` of ``P``;
        published again with a new wall time when older than a period."""
        snap = self._snap
        if snap is None or P is None:
            return False
        fusion = self.fusion
        with fusion.swap_lock:
            buf = fusion.front
        if buf is None or buf.generation != snap.generation or (snap.rho, snap.method) != self._settings():
            return False
        if moved_beyond(snap.P, P, REQUERY_FRACTION * self.margin):
            return False
        if time.perf_counter() - snap.wall > self.period:
            with self._snap_lock:
                if self._snap is snap:
                    self._snap = dataclasses.replace(snap, wall=time.perf_counter())
            self.reused += 1
        return True

    def _query(self, q, P=None) -> None:
        rho, method = self._settings()
        P = np.ascontiguousarray(self._points(q) if P is None else P, dtype=np.float64)
        fusion = self.fusion
        with fusion.swap_lock:
            buf = fusion.front
        if buf is None:
            return
        buf.lock.acquire()        # may wait for a build into the one grid; never with swap_lock held
        t0 = time.perf_counter()  # the query's own time (not the wait): what a cycle's query would take
        try:
            if not buf.loaded:
                return
            grid = buf.grid
            res = grid.query(P, rho=rho + self.margin, method=method, threads=1, rho_core=rho)
            snap = DistanceSnapshot(P, res.distance.copy(), res.direction.copy(), res.observed.copy(), rho,
                                    self.margin, method, dict(buf.stamps), dict(buf.versions),
                                    dict(buf.pushed_at), grid.principal_view(), time.perf_counter(),
                                    buf.generation)
        finally:
            buf.lock.release()
        self._store(snap)
        self.queries += 1
        self.last_query_s = snap.wall - t0
