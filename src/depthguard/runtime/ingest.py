"""Frames in, off the control path: per-camera workers and the fusion worker (R9, R28–R30).

A frame goes through two threads before a control cycle can use it:

1. its camera's **worker** (:class:`CameraWorker`) checks the image, looks
   up the joints at the frame's capture stamp in the joint history (R30:
   interpolated, never extrapolated; a frame outside the history is refused
   and counted), and renders the robot at those joints into the camera
   (R9). Only the newest frame waiting is processed: a camera that delivers
   faster than it can be processed loses its older frames (counted as
   ``dropped``), never the newest one.
2. the **fusion worker** (:class:`FusionWorker`) loads the newest product of
   every camera into the *back* depth grid (R10–R12: per-pixel states, the
   robot's padded volume at every camera's capture joints), classifies the
   cells that the robot's control points and watch points can reach within
   ``rho`` (the lazy grid's per-frame memo, filled here rather than in the
   first control cycle), and swaps it with the *front* grid in one
   assignment. ``step`` queries the front grid only, under the buffer's own
   lock, which the fusion worker takes only after a swap: a control cycle
   never waits for a frame and never sees half of one. With one grid
   (:meth:`FusionWorker.set_single`: replays that flush before each cycle, and
   real-time runs whose distances come from their own thread,
   :mod:`depthguard.runtime.distances`) each frame is built into the grid the
   readers use, under its lock: half the work when cameras take turns, since
   each of two grids must otherwise catch up with every camera that changed
   since its own previous build (measured: two grids 37–44 ms per build, one
   grid 20 ms, same answers, on a loaded machine).

Numba runs on one thread in each worker, and the workers run at a lower
scheduling priority (Linux, :func:`background_thread`), so that the control
thread keeps a core (the kernels release the GIL).
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from depthguard.camera import check_depth_image
from depthguard.filtering.expected import ExpectedDepth
from depthguard.runtime.drift import DriftWatch
from depthguard.runtime.frame_pool import BufferPool
from depthguard.robot.joint_history import JointHistory, OutsideHistory
from depthguard.robot.volume import robot_volume

__all__ = ["CameraProduct", "CameraWorker", "GridBuffer", "FusionWorker", "background_thread"]

#: niceness of the monitor's worker threads (Linux): when the cores are short, the control
#: thread that calls ``step`` runs first; a frame then waits, a control cycle does not
WORKER_NICENESS = 3      # weight 526 against 1024: another busy process does not starve the frames


def background_thread(numba_threads: int = 1) -> None:
    """Make the calling thread a background one: ``numba_threads`` numba threads (0: all), and
    a lower scheduling priority where the system allows it per thread (Linux); silently nothing
    elsewhere."""
    import os

    import numba

    from depthguard.runtime.realtime import normal_scheduling

    normal_scheduling()                  # started by a real-time control thread: not one itself
    n_all = numba.config.NUMBA_NUM_THREADS
    numba.set_num_threads(n_all if numba_threads <= 0 else min(int(numba_threads), n_all))
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), WORKER_NICENESS)
    except (AttributeError, OSError):
        pass


@dataclass
class CameraProduct:
    """One camera frame ready for fusion: depth and robot depth (H, W) float32 m, the capture
    stamp (s), the joints at capture (dof,), the wall time (``perf_counter``) of its push, and
    the camera's share of the depth grid build made on its worker
    (:class:`~depthguard.fusion.depth_grid_state.CameraState`; None: the build works it out)."""
    depth: np.ndarray
    robot_depth: np.ndarray
    stamp: float
    q: np.ndarray
    pushed_at: float
    version: int
    state: object = None


class CameraWorker:
    """The thread of one camera (module docstring, step 1).

    ``offer(frame, pushed_at)`` from any thread; the newest product is in
    ``product`` (replaced whole under ``lock``) and ``on_product()`` is called
    after each. Counters: ``frames`` processed, ``dropped`` (a newer frame came
    first), ``refused`` by reason key in ``refusals`` with ``last_refusal``.
    """

    def __init__(self, cam, robot, static_meshes, joints: JointHistory, joint_wait_s: float,
                 on_product, name: str | None = None, drift: dict | None = None, state_options=None,
                 learned=None, scene_change: dict | None = None, ssm_muted=None):
        self.camera = cam
        # the camera's share of the grid build (R36): state_options() -> (StateOptions, robot_free,
        # pyramids, bin) or None (no state made here; the build works it out)
        self.state_options = state_options
        self._state_maker = None
        # issue 29: the frame's arrays (robot depth, state) reused once nothing refers to them
        self.pool = BufferPool()
        self._depth_pool = BufferPool(cap=3)      # a depth that is not float32 C-contiguous, converted
        self._rd_layout = ((tuple(cam.shape), np.float32),)
        self.id = cam.id
        # the known static scene: the CAD and the learned scene (issue 31: a LearnedScene or None), nearer wins
        self.expected = ExpectedDepth(cam, robot, static_meshes,
                                      learned=None if learned is None else learned.depth)
        # R34: the drift watch on the static scene (settings: DriftWatch's keywords), None = off; a
        # learned surface's observed spread widens its tolerance where it exceeds the sensor's
        self.drift = (DriftWatch(cam, self.expected.static, sigma=None if learned is None else learned.sigma,
                                 **drift) if drift is not None else None)
        # issue 31 point 3: SSM from what is not the known scene: ssm_muted = (VoxelFilter, push(cid,
        # centres, size, stamp)) or None; the frame's unknown objects are pushed after each frame
        self.ssm_muted = ssm_muted
        self._known = np.zeros(cam.shape, dtype=np.float32) if ssm_muted is not None else None
        # issue 31 point 4: where the cell no longer matches its learned scene, said per region
        self.scene_change = None
        if learned is not None:
            from depthguard.runtime.scene_change import SceneChangeWatch
            self.scene_change = SceneChangeWatch(cam, learned, **(scene_change or {}))
        self.joints = joints
        self.joint_wait_s = float(joint_wait_s)
        self.on_product = on_product
        self.lock = threading.Lock()
        self._wake = threading.Condition(self.lock)
        self._inbox = None              # (frame, pushed_at)
        self._busy = False
        self.product: CameraProduct | None = None
        self.frames = 0
        self.dropped = 0
        self.refusals: dict[str, int] = {}
        self.last_refusal: str | None = None
        self._version = 0
        self._stop = False
        self._thread = threading.Thread(target=self._run, name=name or f"depthguard-camera-{cam.id}", daemon=True)
        self._thread.start()

    @property
    def refused(self) -> int:
        return sum(self.refusals.values())

    def offer(self, frame, pushed_at: float) -> None:
        """Hand ``frame`` over (any thread). Its depth array becomes the product's as it is when
        float32 and C-contiguous (no copy, issue 29): the caller must not write into it afterwards
        (every source of depthguard makes a new array per frame)."""
        with self._wake:
            if self._inbox is not None:
                self.dropped += 1
            self._inbox = (frame, pushed_at)
            self._wake.notify()

    def idle(self) -> bool:
        with self.lock:
            return self._inbox is None and not self._busy

    def close(self, timeout: float = 2.0) -> None:
        with self._wake:
            self._stop = True
            self._wake.notify()
        self._thread.join(timeout)

    def _refuse(self, key: str, message: str) -> None:
        with self.lock:
            self.refusals[key] = self.refusals.get(key, 0) + 1
            prefix = f"camera {self.id}: "       # a message from depth_io already names the camera
            self.last_refusal = message if message.startswith(prefix) else prefix + message

    def _run(self) -> None:
        background_thread()
        while True:
            with self._wake:
                while self._inbox is None and not self._stop:
                    self._wake.wait()
                if self._stop:
                    return
                frame, pushed_at = self._inbox
                self._inbox = None
                self._busy = True
            try:
                self._process(frame, pushed_at)
            except Exception as exc:          # a bad frame never kills the camera's thread
                self._refuse("error", f"frame at {frame.stamp:.6f} s: {exc}")
            finally:
                with self.lock:
                    self._busy = False

    def _process(self, frame, pushed_at: float) -> None:
        try:
            depth = check_depth_image(self.camera, frame.depth)
        except ValueError as exc:
            self._refuse("bad_image", str(exc))
            return
        units = _wrong_units(depth, self.camera)
        if units:
            self._refuse("bad_units", units)
            return
        stamp = float(frame.stamp)
        if not math.isfinite(stamp):
            self._refuse("bad_stamp", f"frame stamp {stamp!r} is not finite")
            return
        if self.drift is not None:
            self.drift.update(depth, stamp)       # R34: a cheap statistic on a subsample

        def newer_or_closing() -> bool:
            with self.lock:
                return self._stop or self._inbox is not None

        try:     # joints may lag the frame by a little: wait for them, never extrapolate (R30)
            q = self.joints.wait_at(stamp, self.joint_wait_s, newer_or_closing)
        except OutsideHistory as exc:
            self._refuse(exc.kind, f"frame at {stamp:.6f} s refused: {exc} (R30)")
            return
        with self.lock:
            newest = self.product.stamp if self.product is not None else -math.inf
        if stamp <= newest:
            self._refuse("out_of_order", f"frame at {stamp:.6f} s is not newer than the frame in use "
                                         f"({newest:.6f} s)")
            return
        wanted = self.state_options() if self.state_options is not None else None
        bufs = self._buffers(wanted)
        rd = bufs[0]
        np.copyto(rd, self.expected.robot(q))     # the renderer's buffer is overwritten by its next call
        if self.scene_change is not None:
            self.scene_change.update(depth, rd, stamp)
        if self.ssm_muted is not None:            # R17's filter: the known scene and the robot removed
            from depthguard.render.composite import nearest_depth
            vfilter, push = self.ssm_muted
            np.copyto(self._known, self.expected.static)
            nearest_depth(self._known, rd)
            vs = vfilter.filter(depth, expected=self._known)
            push(self.id, vs.centres(), vs.voxel_size, stamp)
        d = self._own_depth(depth)
        state = self._state(d, rd, wanted, bufs[1:])
        with self.lock:
            self._version += 1
            self.product = CameraProduct(d, rd, stamp, q, pushed_at, self._version, state)
            self.frames += 1
        self.on_product(self.id)


    def _buffers(self, wanted) -> list:
        """This frame's arrays from the worker's pool (:mod:`depthguard.runtime.frame_pool`): the
        robot depth (H, W) float32, then the state's (:meth:`StateMaker.layout
        <depthguard.fusion.depth_grid_state.StateMaker.layout>`) when ``wanted``."""
        layout = self._rd_layout
        if wanted is not None:
            layout = layout + self._maker().layout(wanted[2], wanted[3])
        return self.pool.take(layout)

    def _own_depth(self, depth: np.ndarray) -> np.ndarray:
        """The frame's depth as the product holds it: the frame's own array when it is float32 and
        C-contiguous (no copy: a source hands a frame's array over and never writes into it again,
        :meth:`offer`), else converted into a pooled float32 buffer. (Not made read-only: numba
        compiles a read-only array as another type, every kernel that reads the frame twice.)"""
        if depth.dtype == np.float32 and depth.flags.c_contiguous:
            return depth
        d = self._depth_pool.take(self._rd_layout)[0]
        np.copyto(d, depth, casting="unsafe")    # float32 as np.array(depth, dtype=np.float32) rounds
        return d

    def _maker(self):
        if self._state_maker is None:
            from depthguard.fusion.depth_grid_state import StateMaker

            self._state_maker = StateMaker(self.camera)
        return self._state_maker

    def _state(self, depth, robot_depth, wanted, out=None):
        """The frame's per-pixel state for the depth grid, made here on the camera's thread rather
        than in the fusion's build (R36: the camera's share, in parallel with the other cameras'
        fusion), into ``out`` (pooled arrays of the maker's layout; None: new ones); None where
        the monitor asks for none (``wanted`` None)."""
        if wanted is None:
            return None
        options, robot_free, pyramids, bin_px = wanted
        return self._maker().make(depth, robot_depth, options, robot_free, pyramids, bin_px, out=out or None)


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
            caps = robot_volume(self.robot, [p.q for p in products.values()], cfg.robot_padding, self._volumes)
            back.loaded = False
            kw = {}
            states = {c: products[c].state for c in cams if products[c].state is not None}
            if states and hasattr(back.grid, "states_used"):
                kw["states"] = states              # each camera's share, made on its worker
            back.grid.set_frames(depths, rdepths, robot_offset=cfg.robot_offset, robot_capsules=caps,
                                 invalid=cfg.invalid, robot_in_others=cfg.robot_in_others,
                                 changed=changed, silhouette_px=cfg.silhouette_px,
                                 gap_px=cfg.gap_px, **kw)
            answer, res = self.answer, None
            if points is not None and len(points):
                # classify ahead; with a distance worker the query is its own (the band beyond
                # rho counts for the distance only) and its answer is published at once
                res = back.grid.query(points, rho=cfg.query_rho + self.ahead_margin, method=cfg.method,
                                      rho_core=cfg.query_rho if answer is not None else None)
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
                answer(back, *res, cfg.query_rho, self.ahead_margin, cfg.method)
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

def _wrong_units(depth: np.ndarray, cam) -> str | None:
    """A sentence when most measured pixels of ``depth`` lie outside what any sensor returns
    (millimetres read as metres, or metres in a millimetre PNG); the one check of
    :func:`depthguard.depth_io.depth_units_problem`. None otherwise."""
    from depthguard.depth_io import depth_units_problem

    return depth_units_problem(depth, cam)
