"""``warm_up``: compile every kernel of the monitor's path before any clock of a run starts (R29)."""

from __future__ import annotations

import threading
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

__all__ = ["warm_up", "wait_idle", "CompileActivity", "compile_locks", "CompileCount"]


class _CompileEvents:
    """numba's ``numba:compile`` events (compiling a kernel or loading it from the disk cache)
    handed to ``started(ev)`` / ``ended(ev)`` while installed as a context manager."""

    def started(self, ev) -> None:
        pass

    def ended(self, ev) -> None:
        pass

    def __enter__(self):
        from numba.core import event

        owner = self

        class _Listener(event.Listener):
            def on_start(self, ev):
                owner.started(ev)

            def on_end(self, ev):
                owner.ended(ev)

        self._listener = _Listener()
        event.register("numba:compile", self._listener)
        return self

    def __exit__(self, *exc):
        from numba.core import event

        event.unregister("numba:compile", self._listener)
        return False


class CompileActivity(_CompileEvents):
    """numba at work in this process (compiling a kernel or loading it from the disk cache, on
    any thread), while installed: ``with CompileActivity() as a: ...; a.quiet_s()`` is 0 while a
    compilation runs, else the seconds since the last one ended (or since the ``with`` began)."""

    def __init__(self):
        self._lock = threading.Lock()
        self._active = 0
        self._last = time.perf_counter()
        self.compiles = 0

    def quiet_s(self) -> float:
        with self._lock:
            return 0.0 if self._active else time.perf_counter() - self._last

    def started(self, ev) -> None:
        with self._lock:
            self._active += 1
            self._last = time.perf_counter()

    def ended(self, ev) -> None:
        with self._lock:
            self._active -= 1
            self.compiles += 1
            self._last = time.perf_counter()


def wait_idle(target, timeout: float, activity: CompileActivity, poll_s: float = 0.0002) -> None:
    """Wait until ``target.idle()`` (a :class:`Monitor`: every frame pushed is in the front grid).
    ``timeout`` (s) counts only the time in which numba compiles nothing (``activity``): a cold
    disk cache on a loaded machine compiles for many minutes (a fresh clone's ``depthguard run``
    at load 9 on 2 cores: over 600 s wall, issue 33), which is work, not a hang. ``TimeoutError``
    when the target stays busy ``timeout`` s after the last compilation ended."""
    while not target.idle():
        quiet = activity.quiet_s()
        if quiet > timeout:
            raise TimeoutError(f"monitor: frames still in processing {timeout:g} s after the last kernel "
                               f"compilation ({activity.compiles} compiled or loaded)")
        time.sleep(poll_s)


def warm_up(rig, config=None, timeout: float = 600.0) -> float:
    """Compile every kernel of the monitor's path (numba, ``cache=True``: from the disk cache
    after the first time) on a throwaway monitor fed with the known scene's expected depth, so
    that no clock of a run includes compilation (R29). ``timeout`` (s): how long the frames may
    take through the fusion once numba compiles nothing more (:func:`wait_idle`; compiling from
    a cold cache takes as long as it takes). Returns the seconds it took."""
    from depthguard.filtering.expected import ExpectedDepth
    from depthguard.runtime.monitor import Monitor
    from depthguard.sources.frame import Frame

    t0 = time.perf_counter()
    q0 = np.asarray(rig.robot_q0, dtype=np.float64)
    with CompileActivity() as activity, Monitor(rig, config) as mon:
        mon.push_joints(0.0, q0)
        mon.push_joints(0.001, q0)
        known = {cid: np.array(ExpectedDepth(rig.camera(cid), rig.robot, rig.static_meshes()).known(q0))
                 for cid in mon.camera_ids}
        # three rounds: the grid, then (with ``camera_shares``) the other cameras' share requests
        # (their second frames), then their shares made on the workers and installed by the builds
        for stamp in (0.0005, 0.0006, 0.0007):
            for cid in mon.camera_ids:
                mon.push_frame(Frame(cid, known[cid].copy(), stamp))
            wait_idle(mon, timeout, activity)
        mon.step(0.001)
        # the distance thread's band query and the cycles' bound of its answer (real_time())
        from depthguard.runtime.distances import DistanceSnapshot, bound_distances, moved_beyond

        cfg = mon.config
        grid = mon.fusion.front.grid
        P = mon._P.copy()
        res = grid.query(P, rho=cfg.query_rho + cfg.distance_margin, method=cfg.method, threads=1,
                         rho_core=cfg.query_rho)
        snap = DistanceSnapshot(P, res.distance.copy(), res.direction.copy(), res.observed.copy(), cfg.query_rho,
                                cfg.distance_margin, cfg.method, {}, {}, {}, grid.principal_view(), 0.0)
        m = len(P)
        bound_distances(snap, P, cfg.query_rho, np.empty(m), np.empty((m, 3)), np.empty(m, dtype=bool))
        moved_beyond(P, P.copy(), cfg.distance_margin)          # the worker's test of its newest answer
    from depthguard.runtime.voxel_input import VoxelObstacles
    units = VoxelObstacles()                      # the remote units' kernel
    units.push("warm-up", np.zeros((1, 3)), 0.05, 0.0)
    units.nearest(np.ones((2, 3)), 0.4, np.full(2, np.inf), np.zeros((2, 3)),
                  robot_capsules=rig.robot.collision_segments(q0, 0.05))
    return time.perf_counter() - t0


# ---------------------------------------------------------------- several processes, one cache (R29)
# `depthguard warm-up --jobs N` compiles the package's kernels in N processes that share numba's
# disk cache. Without coordination two processes that reach the same kernel compile it twice, and
# two that save overloads of one kernel at once can lose an entry of its index (numba reads,
# updates and rewrites the index). compile_locks() makes each process take an exclusive file lock
# per kernel before compiling it: the second one waits, then loads what the first one saved.

_held: set[str] = set()


def _locked_compile(orig, lock_dir: Path):
    """A ``Dispatcher.compile`` that holds ``lock_dir/<kernel>.lock`` (``fcntl.flock``) while the
    original looks into the disk cache and, on a miss, compiles and saves."""
    import fcntl
    import hashlib

    from numba.core.compiler_lock import global_compiler_lock

    def compile(self, sig):
        cache = getattr(self, "_cache", None)
        py_func = getattr(self, "py_func", None)
        if py_func is None or cache is None or type(cache).__name__ == "NullCache":
            return orig(self, sig)                        # not cached: nothing to share
        key = f"{py_func.__module__}.{py_func.__qualname__}"
        # numba compiles one thing at a time per process (its global compiler lock, re-entrant):
        # taken first, it leaves _held and the file locks to one thread of this process at a time
        with global_compiler_lock:
            if key in _held:                              # a kernel's compilation needing itself
                return orig(self, sig)
            name = hashlib.sha1(key.encode()).hexdigest()[:20] + ".lock"
            with open(lock_dir / name, "a") as f:
                fcntl.flock(f, fcntl.LOCK_EX)
                _held.add(key)
                try:
                    return orig(self, sig)
                finally:
                    _held.discard(key)
                    fcntl.flock(f, fcntl.LOCK_UN)

    return compile


@contextmanager
def compile_locks(lock_dir):
    """Within the ``with``: numba compiles a cached kernel (``cache=True``) only under an
    exclusive lock per kernel in the folder ``lock_dir`` shared by the processes warming one
    cache, so no kernel is compiled twice and no index entry is lost (R29, ``depthguard
    warm-up``). Kernels without ``cache=True`` compile as before."""
    from numba.core.dispatcher import Dispatcher

    lock_dir = Path(lock_dir)
    lock_dir.mkdir(parents=True, exist_ok=True)
    orig = Dispatcher.compile
    Dispatcher.compile = _locked_compile(orig, lock_dir)
    try:
        yield
    finally:
        Dispatcher.compile = orig


class CompileCount(_CompileEvents):
    """Counts numba's compilations (cache misses) of kernels, outermost only, while installed:
    ``with CompileCount() as c: ...; c.kernels`` (names), ``c.seconds`` (wall seconds)."""

    def __init__(self):
        self.kernels: list[str] = []
        self.seconds = 0.0
        self._depth, self._t0 = 0, 0.0

    def started(self, ev) -> None:
        if self._depth == 0:
            self._t0 = time.perf_counter()
        self._depth += 1

    def ended(self, ev) -> None:
        self._depth -= 1
        if self._depth == 0:
            f = getattr(ev.data.get("dispatcher"), "py_func", None)
            self.kernels.append(f"{f.__module__}.{f.__qualname__}" if f is not None else "?")
            self.seconds += time.perf_counter() - self._t0
