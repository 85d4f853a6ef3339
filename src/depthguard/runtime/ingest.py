"""Frames in, off the control path: per-camera workers and the fusion worker (R9, R28–R30).

A frame goes through two threads before a control cycle can use it:

1. its camera's **worker** (:class:`CameraWorker`) checks the image, looks
   up the joints at the frame's capture stamp in the joint history (R30:
   interpolated, never extrapolated; a frame outside the history is refused
   and counted), and renders the robot at those joints into the camera
   (R9) — or, for a simulated frame that carries the simulator's robot layer
   drawn with this robot and camera at these joints' bits, takes that image once
   its first ones matched its own render bit for bit (:meth:`CameraWorker.handed_robot`,
   issue 29). Only the newest frame waiting is processed: a camera that delivers
   faster than it can be processed loses its older frames (counted as
   ``dropped``), never the newest one.
2. the **fusion worker** (:class:`~depthguard.runtime.fusion_worker.FusionWorker`) loads the newest product of
   every camera into the *back* depth grid (R10–R12: per-pixel states, the
   robot's padded volume at every camera's capture joints), classifies the
   cells that the robot's control points and watch points can reach within
   ``rho`` (the lazy grid's per-frame memo, filled here rather than in the
   first control cycle), and swaps it with the *front* grid in one
   assignment. ``step`` queries the front grid only, under the buffer's own
   lock, which the fusion worker takes only after a swap: a control cycle
   never waits for a frame and never sees half of one. With one grid
   (:meth:`~depthguard.runtime.fusion_worker.FusionWorker.set_single`: replays that flush before each cycle, and
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
from dataclasses import dataclass

import numpy as np

from depthguard.camera import check_depth_image
from depthguard.depth_io import UnitsCheck
from depthguard.filtering.expected import ExpectedDepth
from depthguard.render.composite import copy_depth_rows
from depthguard.runtime.drift import DriftWatch
from depthguard.frame_pool import BufferPool
from depthguard.robot.joint_history import JointHistory, OutsideHistory

__all__ = ["CameraProduct", "CameraWorker", "background_thread"]

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
    (:class:`~depthguard.fusion.depth_grid_state.CameraState`; None: the build works it out),
    and ``capsules``: ``(robot model, segments (C, 2, 3), radii (C,))`` world m, the model's
    unpadded collision capsules at ``q`` made on the worker (None: the build makes them; R9,
    R12, :func:`~depthguard.robot.volume.robot_volume`'s ``unpadded``), and ``share``: the
    camera's clearing of the grid's cells made from ``state``
    (:class:`~depthguard.fusion.depth_grid_share.CameraShare`; None: the build works it out)."""
    depth: np.ndarray
    robot_depth: np.ndarray
    stamp: float
    q: np.ndarray
    pushed_at: float
    version: int
    state: object = None
    capsules: tuple | None = None
    share: object = None


class CameraWorker:
    """The thread of one camera (module docstring, step 1).

    ``offer(frame, pushed_at)`` from any thread; the newest product is in
    ``product`` (replaced whole under ``lock``) and ``on_product()`` is called
    after each. Counters: ``frames`` processed, ``dropped`` (a newer frame came
    first), ``refused`` by reason key in ``refusals`` with ``last_refusal``.
    """

    def __init__(self, cam, robot, static_meshes, joints: JointHistory, joint_wait_s: float,
                 on_product, name: str | None = None, drift: dict | None = None, state_options=None,
                 learned=None, scene_change: dict | None = None, ssm_muted=None, share=None):
        self.camera = cam
        self._shape = tuple(cam.shape)      # (H, W): a frame of another shape gets the full check
        # the camera's share of the grid build (R36): state_options() -> (StateOptions, robot_free,
        # pyramids, bin) or None (no state made here; the build works it out)
        self.state_options = state_options
        # share(state) -> CameraShare or None: the camera's clearing of the grid's cells, made here
        # after the state (issue 29, runtime.camera_shares)
        self.share = share
        self._state_maker = None
        # issue 29: the frame's arrays (robot depth, state) reused once nothing refers to them
        self.pool = BufferPool()
        self._depth_pool = BufferPool(cap=3)      # a depth that is not float32 C-contiguous, converted
        self._rd_layout = ((tuple(cam.shape), np.float32),)
        self._spans_layout = (((cam.shape[0], 2), np.int32),)
        self.id = cam.id
        self._units = UnitsCheck(cam)             # depth_units_problem, its limits worked out once
        self._layouts: dict = {}                  # _buffers' layout by the state's (pyramids, bin)
        # the known static scene: the CAD and the learned scene (issue 31: a LearnedScene or None), nearer wins
        self.expected = ExpectedDepth(cam, robot, static_meshes,
                                      learned=None if learned is None else learned.depth)
        # the source's robot image instead of this render, once checked (handed_robot, issue 29)
        self.handover: bool | None = None
        # the capture joints' forward kinematics into this worker's data (a RobotModel's; else None)
        model = self.expected.robot_model
        self._robot_data = self._fk = None
        if model is not None and hasattr(model, "forward_into"):
            self._robot_data = model.create_data()
            self._fk = model.forward_into(self._robot_data)      # (reads q as float64 (dof,): checked)
            self._q_shape = (model.dof,)
        self.handover_off: str | None = None
        self._handover_checked = 0
        self.robot_handed = 0
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
        self._refused = 0               # sum(refusals.values())
        self.last_refusal: str | None = None
        self._version = 0
        self._stop = False
        self._thread = threading.Thread(target=self._run, name=name or f"depthguard-camera-{cam.id}", daemon=True)
        self._thread.start()

    @property
    def refused(self) -> int:
        """Frames refused so far: ``sum(refusals.values())``, counted as they are (read every cycle)."""
        return self._refused

    def offer(self, frame, pushed_at: float) -> None:
        """Hand ``frame`` over (any thread). Its depth array becomes the product's as it is when
        float32 and C-contiguous (no copy, issue 29): the caller must not write into it afterwards
        (every source of depthguard makes a new array per frame)."""
        with self._wake:
            if self._inbox is not None:
                self.dropped += 1
            self._inbox = (frame, pushed_at)
            self._wake.notify()
            busy = self._busy
        if busy:
            self.joints.wake()          # a frame waiting for its joints gives way to this newer one

    def idle(self) -> bool:
        with self.lock:
            return self._inbox is None and not self._busy

    def close(self, timeout: float = 2.0) -> None:
        with self._wake:
            self._stop = True
            self._wake.notify()
        self.joints.wake()
        self._thread.join(timeout)

    def _refuse(self, key: str, message: str) -> None:
        with self.lock:
            self.refusals[key] = self.refusals.get(key, 0) + 1
            self._refused += 1
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
        depth = frame.depth
        if not (type(depth) is np.ndarray and depth.ndim == 2 and depth.dtype in _FLOAT_IMAGES
                and depth.shape == self._shape):     # else the full check (its verdict and sentence)
            try:
                depth = check_depth_image(self.camera, depth)
            except ValueError as exc:
                self._refuse("bad_image", str(exc))
                return
        units = self._units(depth)
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
        # the links posed once at the capture joints, for the render and the capsules (issue 29)
        poses = None
        if self._fk is not None and type(q) is np.ndarray and q.dtype == np.float64 and q.shape == self._q_shape:
            if not self._fk(q):
                raise ValueError(f"the joints at the frame are not finite: {q.tolist()}")
            poses = self._robot_data.link_poses
        handed = self.handed_robot(frame, q)
        if handed is not None:                    # the source drew this very image (issue 29)
            rd, rspans = handed.depth, handed.spans
        else:
            rd, rspans = bufs[0], bufs[1]
            # the renderer's buffer is overwritten by its next call: copied, over the rows' spans of
            # the robot now and of what the pooled buffer held (issue 29: not the whole image)
            copy_depth_rows(rd, rspans, self.expected.robot(q, poses), self.expected.robot_spans)
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
        state = self._state(d, rd, wanted, bufs[2:], rspans)
        model = self.expected.robot_model
        # the capture joints' capsules on this thread, not the fusion's (issue 29)
        caps = None
        if model is not None and model.capsules:
            caps = (model, *(model.collision_segments(q, 0.0) if poses is None else model.segments_at(poses)))
        share = self.share(state) if self.share is not None and state is not None else None
        with self.lock:
            self._version += 1
            self.product = CameraProduct(d, rd, stamp, q, pushed_at, self._version, state, caps, share)
            self.frames += 1
        self.on_product(self.id)


    def handed_robot(self, frame, q):
        """The frame's :class:`~depthguard.sources.frame.RobotImage` (the simulator's robot layer)
        when it is what this worker would render at the capture joints ``q`` (R9), else None.
        Taken only for this worker's own robot model and camera objects and the same bits of
        ``q``; its first :data:`HANDOVER_CHECKS` images with the robot in view are checked
        against the worker's own render, bit for bit (image and rows' spans), and are not taken
        meanwhile; one that differs turns the hand-over off for this worker (``handover``:
        None while checking, True, False; ``handover_off`` says why). ``robot_handed`` counts
        the frames that took it."""
        img = getattr(frame, "robot_image", None)      # (a frame of another source may lack it)
        if img is None or self.handover is False:
            return None
        qa = np.asarray(q, dtype=np.float64)
        if (img.robot is not self.expected.robot_model or img.camera is not self.camera
                or img.depth.shape != self._shape or img.q.tobytes() != qa.tobytes()):
            return None
        if self.handover is None:
            own = self.expected.robot(qa)
            if not (np.array_equal(own, img.depth) and np.array_equal(self.expected.robot_spans, img.spans)):
                self.handover = False
                self.handover_off = (f"frame at {frame.stamp:.6f} s: the source's robot image differs from "
                                     f"this worker's render at the same joints")
                return None
            if np.any(img.spans[:, 1] > img.spans[:, 0]):
                self._handover_checked += 1
                if self._handover_checked >= HANDOVER_CHECKS:
                    self.handover = True
            return None
        self.robot_handed += 1
        return img

    def _buffers(self, wanted) -> list:
        """This frame's arrays from the worker's pool (:mod:`depthguard.frame_pool`): the
        robot depth (H, W) float32 and its rows' spans (H, 2) int32 (per row ``[a, b)``: the
        depth is 0 outside, :func:`~depthguard.render.composite.copy_depth_rows`; a new set's
        span is the whole row, its content unknown), then the state's (:meth:`StateMaker.layout
        <depthguard.fusion.depth_grid_state.StateMaker.layout>`) when ``wanted``."""
        key = None if wanted is None else (wanted[2], wanted[3])
        layout = self._layouts.get(key)
        if layout is None:          # made once per role (the same tuple each frame: BufferPool.take)
            layout = self._rd_layout + self._spans_layout
            if wanted is not None:
                layout = layout + self._maker().layout(wanted[2], wanted[3])
            self._layouts[key] = layout
        made = self.pool.made
        bufs = self.pool.take(layout)
        if self.pool.made != made:          # new arrays (np.empty): every pixel is to be written
            spans = bufs[1]
            spans[:, 0] = 0
            spans[:, 1] = self._shape[1]
        return bufs

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

    def _state(self, depth, robot_depth, wanted, out=None, robot_spans=None):
        """The frame's per-pixel state for the depth grid, made here on the camera's thread rather
        than in the fusion's build (R36: the camera's share, in parallel with the other cameras'
        fusion), into ``out`` (pooled arrays of the maker's layout; None: new ones); None where
        the monitor asks for none (``wanted`` None); ``robot_spans`` (H, 2) int32: the rows' spans
        outside which ``robot_depth`` is 0 (:meth:`_buffers`), or None."""
        if wanted is None:
            return None
        options, robot_free, pyramids, bin_px = wanted
        return self._maker().make(depth, robot_depth, options, robot_free, pyramids, bin_px, out=out or None,
                                  robot_spans=robot_spans)


#: a source's robot images with the robot in view that a worker checks against its own render
#: before it takes them (CameraWorker.handed_robot)
HANDOVER_CHECKS = 3

#: the frames' dtypes that pass :func:`~depthguard.camera.check_depth_image` when their shape is the
#: camera's, checked per frame without it (issue 29: ``numpy.issubdtype`` for every frame)
_FLOAT_IMAGES = (np.dtype(np.float32), np.dtype(np.float64))

