"""The fusion worker: the cameras' newest products into a depth grid, off the control path
(R10–R12, R29).

Step 2 of :mod:`depthguard.runtime.ingest`'s flow: :class:`FusionWorker` loads the newest
product of every camera (:class:`~depthguard.runtime.ingest.CameraProduct`) into the *back*
grid (:class:`GridBuffer`), classifies the cells the control and watch points can reach
within ``rho``, and swaps it with the *front* grid in one assignment — or, with one grid
(:meth:`FusionWorker.set_single`), builds into the grid the readers use, under its lock.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

from depthguard.robot.volume import robot_volume
from depthguard.runtime.ingest import background_thread

__all__ = ["GridBuffer", "FusionWorker"]


@dataclass
class GridBuffer:
    """One of the two depth grids (front / back) with what it holds: per camera the version,
    capture stamp, push time and capture joints of the frame loaded."""
    grid: object
    camera_ids: tuple[str, ...]
    lock: threading.Lock = field(default_factory=threading.Lock)
    versions: dict = field(default_factory=dict)
    stamps: dict = field(default_factory=dict)
    pushed_at: dict = field(default_factory=dict)
    q_caps: dict = field(default_factory=dict)
    loaded: bool = False
    generation: int = 0


class FusionWorker:
    """The fusion thread (module docstring, step 2).

    ``make_grid(camera_ids)`` builds a depth grid map over those cameras (principal
    first); ``settings()`` returns the current ``(config, camera ids, predicted points)``
    — the points (N, 3) world whose cells are classified before the swap.
    ``front`` is the buffer ``step`` reads; ``swap_lock`` guards the assignment.
    """

    def __init__(self, workers: dict, make_grid, settings, robot, threads: int = 0):
        self.workers = workers
        self.make_grid = make_grid
        self.settings = settings
        self.robot = robot
        self.ahead_margin = 0.0          # m beyond rho classified ahead (the distance worker's band)
        self.answer = None               # answer(snapshot): the classify-ahead query as a distance answer
        self.single = False              # one grid instead of two (set_single)
        self.swap_lock = threading.Lock()
        self.front: GridBuffer | None = None
        self._back: GridBuffer | None = None
        self._prepared: GridBuffer | None = None   # made by prepare() for the next camera set
        self._wake = threading.Condition()
        self._pending = False
        self._busy = False
        self._stop = False
        self.builds = 0
        self.fused: dict[str, int] = {}           # per camera: frames loaded into a grid
        self._last_fused: dict[str, int] = {}
        self._volumes: dict = {}                  # robot_volume's capsules per capture-joints array
        self._cfg = None                          # the settings of the last build
        self._rho, self._rho_of = 0.0, None       # _query_rho's
        self._threads_wanted = int(threads)       # numba threads (0: all; MonitorConfig.fusion_threads)
        self.threads = 1                          # the fusion's numba threads (set by its thread)
        self.build_seconds: list[float] = []
        self.errors = 0
        self.last_error: str | None = None
        self._thread = threading.Thread(target=self._run, name="depthguard-fusion", daemon=True)
        self._thread.start()

    def notify(self, _camera_id: str | None = None) -> None:
        with self._wake:
            self._pending = True
            self._wake.notify()

    def idle(self) -> bool:
        with self._wake:
            return not self._pending and not self._busy

    def close(self, timeout: float = 2.0) -> None:
        with self._wake:
            self._stop = True
            self._wake.notify()
        self._thread.join(timeout)

    def _run(self) -> None:
        # the cells classified ahead split over every core (they are most of a build, and the
        # control and distance threads need little); the lookup after it runs on one
        background_thread(numba_threads=self._threads_wanted)
        import numba

        self.threads = numba.get_num_threads()
        rest_until = 0.0
        while True:
            with self._wake:
                while not self._pending and not self._stop:
                    self._wake.wait()
                if self._stop:
                    return
                # the duty's rest (below): frames coalesce meanwhile; a frame's notify() wakes the
                # wait, so wait again until the rest is over (or the worker is closed)
                while not self._stop and (wait := rest_until - time.perf_counter()) > 0.0:
                    self._wake.wait(wait)
                if self._stop:
                    return
                self._pending = False
                self._busy = True
            t0 = time.perf_counter()
            try:
                built = self._build()
                if built:
                    self.builds += 1
                    self.build_seconds.append(time.perf_counter() - t0)
                    if len(self.build_seconds) > 4096:
                        del self.build_seconds[:2048]
            except Exception as exc:
                built = False
                self.errors += 1
                self.last_error = f"fusion: {type(exc).__name__}: {exc}"
            finally:
                with self._wake:
                    self._busy = False
            # the fusion's share of the machine, bounded by design (R36): a build of b seconds
            # on n numba threads is followed by a rest of b (n / duty - 1), so that the fusion
            # never takes more than ``fusion_duty`` of a core, whatever the cell and however
            # many cameras' frames come; frames that come meanwhile go into the next build
            duty = float(getattr(self._cfg, "fusion_duty", 1.0)) if self._cfg is not None else 1.0
            if built and duty < 1.0:
                b = time.perf_counter() - t0
                rest_until = time.perf_counter() + b * (self.threads / duty - 1.0)

    def _products(self, camera_ids) -> dict:
        out = {}
        for cid in camera_ids:
            w = self.workers.get(cid)
            if w is None:
                continue
            with w.lock:
                p = w.product
            if p is not None:
                out[cid] = p
        return out

    def prepare(self, camera_ids) -> None:
        """Make the grid for the cameras ``camera_ids`` (principal first) now, on the calling
        thread, and touch every page of its buffers (``touch()`` where the grid has one), so that
        the build that first has a frame of each of them does not pay for them: a new grid for
        two 640x480 cameras took 140 ms to build instead of 10 ms, its first frames 40-140 ms
        late (measured in ``depthguard bench --only monitor``). The monitor calls it when it
        starts and before a camera is added (the set is then not in use yet). Not on removal:
        the remaining cameras' frames keep coming, so a build makes that grid before a prepared
        one could be ready, and the prepared one would only hold memory. A build whose cameras
        with a frame are others (the principal alone at the start) makes its own grid and
        leaves this one waiting."""
        ids = tuple(camera_ids)
        buf = GridBuffer(self.make_grid(ids), ids)
        touch = getattr(buf.grid, "touch", None)
        if touch is not None:
            touch()
        with self.swap_lock:
            if all(b is None or b.camera_ids != ids for b in (self._back, self.front)):
                self._prepared = buf          # (else a build made its own in the meantime)

    def _query_rho(self, cfg) -> float:
        """``cfg.query_rho`` (m), worked out once per settings object (a property that looks up the
        policies' reaches, called per build)."""
        if self._rho_of is not cfg:
            self._rho, self._rho_of = float(cfg.query_rho), cfg
        return self._rho

    def _grid_for(self, cams: tuple) -> GridBuffer:
        """The grid for cameras ``cams``: the prepared one if it is theirs, else a new one."""
        with self.swap_lock:
            prep = self._prepared
            if prep is not None and prep.camera_ids == cams:
                self._prepared = None
                return prep
        return GridBuffer(self.make_grid(cams), cams)

    def _build(self) -> bool:
        cfg, camera_ids, points = self.settings()
        self._cfg = cfg
        products = self._products(camera_ids)
        # the grid is over the cameras with a frame; the principal (first) must have one
        cams = tuple(c for c in camera_ids if c in products)
        if not cams or cams[0] != camera_ids[0]:
            return False
        with self.swap_lock:
            back = self._back
        if back is None or back.camera_ids != cams:
            back = self._grid_for(cams)
        with back.lock:                       # a reader may still use it (the old front, or the one grid)
            changed = {c for c in cams if back.versions.get(c) != products[c].version} if back.loaded else None
            if changed == set():
                return False
            depths = {c: products[c].depth for c in cams}
            rdepths = {c: products[c].robot_depth for c in cams}
            made = [p.capsules[1:] if p.capsules is not None and p.capsules[0] is self.robot else None
                    for p in products.values()]
            caps = robot_volume(self.robot, [p.q for p in products.values()], cfg.robot_padding, self._volumes,
                                unpadded=made)
            back.loaded = False
            kw = {}
            states = {c: products[c].state for c in cams if products[c].state is not None}
            if states and hasattr(back.grid, "states_used"):
                kw["states"] = states              # each camera's share, made on its worker
                shares = {c: products[c].share for c in cams if products[c].share is not None}
                if shares:
                    kw["shares"] = shares          # ... with its clearing of the grid's cells
            back.grid.set_frames(depths, rdepths, robot_offset=cfg.robot_offset, robot_capsules=caps,
                                 invalid=cfg.invalid, robot_in_others=cfg.robot_in_others,
                                 changed=changed, silhouette_px=cfg.silhouette_px,
                                 gap_px=cfg.gap_px, **kw)
            answer, res = self.answer, None
            rho = self._query_rho(cfg)
            if points is not None and len(points):
                # classify ahead; with a distance worker the query is its own (the band beyond
                # rho counts for the distance only) and its answer is published at once
                res = back.grid.query(points, rho=rho + self.ahead_margin, method=cfg.method,
                                      rho_core=rho if answer is not None else None)
                if answer is not None:
                    res = (points, res.distance.copy(), res.direction.copy(), res.observed.copy())
            for c in cams:
                p = products[c]
                if self._last_fused.get(c) != p.version:
                    self._last_fused[c] = p.version
                    self.fused[c] = self.fused.get(c, 0) + 1
                back.versions[c] = p.version
                back.stamps[c] = p.stamp
                back.pushed_at[c] = p.pushed_at
                back.q_caps[c] = p.q
            back.loaded = True
            back.generation += 1
            if answer is not None and res is not None:
                answer(back, *res, rho, self.ahead_margin, cfg.method)
        with self.swap_lock:
            if self.single:
                self._back = self.front = back
            else:
                self._back, self.front = (self.front if self.front is not back else None), back
        return True

    def set_single(self, single: bool) -> None:
        """One grid (``True``: each frame is built into the grid the readers use, under its lock —
        a reader waits for a build in progress; the other cameras' per-pixel states and memoised
        clearings stay valid, half the work of two grids with cameras that take turns) or two
        (``False``, the default: a reader never waits; each grid must catch up with every camera
        that changed since its own last build)."""
        with self.swap_lock:
            self.single = bool(single)
            self._back = self.front if self.single else None
