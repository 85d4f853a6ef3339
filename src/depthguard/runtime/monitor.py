"""``Monitor``: the one runtime of a cell — frames and joints in, a reaction out (R29).

    monitor = Monitor(rig)                       # settings: rig.monitor (the rig's monitor: section)
    monitor.push_joints(stamp, q)                # any thread, at the joint rate
    monitor.push_frame(Frame(camera_id, depth, stamp))    # any thread, at the camera rate
    reaction = monitor.step(t)                   # the control thread, at the control rate

Model and data apart: the rig and the :class:`~depthguard.config.MonitorConfig`
describe the cell; the monitor holds the state (joint history, per-camera
workers, two depth grids, the supervisor). Frames are processed off the
control path (:mod:`depthguard.runtime.ingest`); ``step`` never waits for a
frame:

1. joints: ``q`` given, or the newest state received; stale joints (older
   than ``joints_stale_s``) stop the robot (R27);
2. distances of the control points at ``q`` and of the watch points, from
   the front depth grid (R12): ``inf`` = nothing within rho, ``observed``
   False = cannot judge (R26);
3. supervision: a stale or missing camera frame, stale joints, an
   unobserved control point, a control point inside an obstacle frustum
   → the override ramps to 0 (R26, R27), with the reasons;
4. reaction: repulsion at the end effector (R13), joint-velocity limits
   from the other control points and the joint limits (R14), both times the
   override; or (``reaction: ssm | both``) speed and separation monitoring
   (R33, :mod:`depthguard.control.ssm_runtime`): a speed scale for the
   commanded motion and a protective stop, distances looked for within
   ``max(rho, ssm.range)``.

Every clock is the caller's: stamps of frames and joints and the ``t`` of
``step`` are seconds on one clock (``time.monotonic()`` for a live cell,
simulated time for a simulator or a recording replayed fast).
"""

from __future__ import annotations

import math
import threading
import time
from contextlib import contextmanager

import numpy as np

from depthguard.config import MonitorConfig
from depthguard.control.reaction import reaction as reaction_of
from depthguard.control.supervisor import SafetySupervisor, stop_reasons
from depthguard.runtime.distances import DistanceWorker, bound_distances
from depthguard.runtime.ingest import CameraWorker, FusionWorker
from depthguard.robot.joint_history import JointHistory
from depthguard.runtime.result import CameraStatus, Reaction
from depthguard.runtime.refusals import explain_stale

__all__ = ["Monitor"]


class Monitor:
    """The runtime of one cell (module docstring).

    rig : a :class:`~depthguard.rig.Rig` with a robot and cameras.
    config : a :class:`~depthguard.config.MonitorConfig` (default: ``rig.monitor``).
    sinks : callables ``sink(reaction)`` called with every reaction, from the
        thread that calls ``step`` — keep them quick, or wrap them in
        :class:`depthguard.runtime.sinks.SinkFanout`.

    Use as a context manager, or call :meth:`close`.
    """

    def __init__(self, rig, config: MonitorConfig | None = None, *, sinks=()):
        if rig.robot is None:
            raise ValueError(f"rig {rig.name!r} has no robot: the monitor needs one (robot: in the rig file)")
        self.rig = rig
        self.robot = rig.robot
        cfg = config if config is not None else rig.monitor
        if not isinstance(cfg, MonitorConfig):
            raise ValueError(f"config must be a MonitorConfig (got {type(cfg).__name__})")
        self._cameras = {c.id: c for c in rig.cameras}
        for c in cfg.remote_cameras:
            if c not in self._cameras:
                raise ValueError(f"monitor.remote_cameras names {c!r}, which the rig {rig.name!r} does not have; "
                                 f"cameras: {', '.join(self._cameras)}")
        ids = list(cfg.cameras) if cfg.cameras is not None else \
            [c.id for c in rig.cameras if c.id not in cfg.remote_cameras]
        if not ids:
            raise ValueError("the monitor needs at least one camera with frames (remote units judge nothing, R26)")
        for c in ids:
            if c not in self._cameras:
                raise ValueError(f"monitor.cameras names {c!r}, which the rig {rig.name!r} does not have; "
                                 f"cameras: {', '.join(self._cameras)}")
        self.config = cfg
        self._settings_lock = threading.Lock()
        self._camera_ids = self._ordered(ids, cfg.principal)
        self.joints = JointHistory(self.robot.dof, cfg.joint_history_s, q_min=self.robot.q_min,
                                   q_max=self.robot.q_max, max_gap_s=cfg.joints_stale_s)
        self._static = rig.static_meshes()
        self._workers: dict[str, CameraWorker] = {}
        self.fusion = FusionWorker(self._workers, self._make_grid, self._fusion_settings, self.robot)
        self.fusion.prepare(self._camera_ids)      # the grid made now, not by the first frames
        for cid in self._camera_ids:
            self._start_worker(cid)
        self._added_at: dict[str, float] = {}
        from depthguard.runtime.voxel_input import VoxelObstacles
        self.voxels = VoxelObstacles()            # the remote units' voxels (R20)
        self.sinks = list(sinks)
        # control-thread state (preallocated)
        self._data = self.robot.create_data()
        self._cp_names = tuple(c.name for c in self.robot.control_points)
        self._watch = np.array([w.position for w in cfg.watch_points], dtype=np.float64).reshape(-1, 3)
        self._names = self._cp_names + tuple(w.name for w in cfg.watch_points)
        m = len(self._names)
        self._P = np.zeros((m, 3))
        self._is_watch = np.arange(m) >= len(self._cp_names)
        self._q_min, self._q_max, self._qd_max = (np.ascontiguousarray(a, dtype=np.float64) for a in
                                                  (self.robot.q_min, self.robot.q_max, self.robot.qd_max))
        self._react_buf = (np.empty(3), np.empty(self.robot.dof), np.empty(self.robot.dof))
        self._sup = SafetySupervisor(cfg.dt, cfg.stop_time, cfg.resume_time)
        # speed and separation monitoring (R33): the mode is fixed for the monitor's life
        m_cp = len(self._cp_names)
        self._ssm = None
        if cfg.reaction != "repulsion":
            from depthguard.control.ssm_runtime import SpeedSeparation
            self._ssm = SpeedSeparation(cfg.ssm, [self._cameras[c] for c in self._camera_ids], m_cp,
                                        self.robot.dof, cfg.delta_d, cfg.gap_px, cfg.dt)
        self._D_none = np.full(m_cp, np.inf)          # ssm mode: no repulsion, the joint box alone
        self._D_rep = np.empty(m_cp)                  # both: the repulsion sees only what is within rho
        self._qd_meas = np.zeros(self.robot.dof)      # qd not given: from the joints of two cycles
        self._q_ssm_prev: tuple[float, np.ndarray] | None = None
        self._t_last: float | None = None
        self._last_q: np.ndarray | None = None
        self._seen: dict[str, int] = {}          # camera -> version already used by a cycle
        self._refusal_marks: dict[str, tuple[int, int]] = {}   # runtime.refusals: refused since the frame in use
        self._dist_worker: DistanceWorker | None = None     # real_time(): distances off this thread
        self._worker_data = self.robot.create_data()
        self.distance_fallbacks: dict[str, int] = {}   # cycles that queried the grid themselves, by why
        self.distance_queries = 0
        self.distance_answers_from_builds = 0
        self.frame_to_reaction_s: list[float] = []
        self.step_s: list[float] = []
        self.cycles = 0
        self._closed = False
        self.free_space = None                    # R21, R37: the free-space map's worker (start_free_space)
        if cfg.free_space:
            self.start_free_space()

    # ------------------------------------------------------------ set-up
    @staticmethod
    def _ordered(ids, principal) -> tuple[str, ...]:
        ids = list(ids)
        p = principal if principal is not None else ids[0]
        if p not in ids:
            raise ValueError(f"monitor.principal {p!r} is not among the monitored cameras {ids}")
        return tuple([p] + [c for c in ids if c != p])

    def _start_worker(self, cid: str) -> None:
        cfg = self.config
        drift = (dict(k_sigma=cfg.drift_sigma, share=cfg.drift_share, frames=cfg.drift_frames)
                 if cfg.drift_watch else None)                       # R34
        self._workers[cid] = CameraWorker(self._cameras[cid], self.robot, self._static, self.joints,
                                          cfg.joint_wait_s, self.fusion.notify, drift=drift,
                                          state_options=lambda: self._state_options(cid))

    def _state_options(self, cid: str):
        """``(StateOptions, robot_free, pyramids)`` for camera ``cid``'s frames as the depth grid will
        load them (its role: the principal, or another camera whose pyramids the grid reads), or
        None with one camera (no grid, R36)."""
        from depthguard.fusion.depth_grid_state import StateOptions

        with self._settings_lock:
            cfg, ids = self.config, self._camera_ids
        if len(ids) < 2 or cid not in ids:
            return None
        other = cid != ids[0]
        # pyramids stay with the build (False): made here into fresh memory per frame they cost the
        # worker 6-7 ms of page faults on a loaded machine against ~1 ms in the grid's own buffers
        # (measured 2026-11-25); a reused ring needs a check that the build did not copy a torn one
        return StateOptions.of(cfg), cfg.robot_in_others == "free" and other, False

    def _make_grid(self, cams: tuple[str, ...]):
        from depthguard.fusion.depth_grid import DepthGridMap

        cameras = [self._cameras[c] for c in cams]
        if len(cameras) == 1:
            from depthguard.runtime.single import OneCameraMap
            return OneCameraMap(cameras[0])
        d_min, d_max = self.rig.workspace.depth_span(cameras[0])
        return DepthGridMap(cameras, principal=cams[0], d_min=d_min, d_max=d_max, delta_d=self.config.delta_d)

    def _fusion_settings(self):
        """(config, camera ids, points whose cells to classify ahead) for the fusion worker."""
        with self._settings_lock:
            cfg, ids = self.config, self._camera_ids
        latest = self.joints.latest()
        pts = None
        if latest is not None:
            data = self.robot.create_data()
            self.robot.forward(latest[1], data)
            pts = np.concatenate([data.cp_positions, self._watch]) if len(self._watch) else data.cp_positions
        return cfg, ids, pts

    # ------------------------------------------------------------ inputs (any thread)
    @property
    def camera_ids(self) -> tuple[str, ...]:
        """The monitored cameras, principal first."""
        return self._camera_ids

    def push_joints(self, stamp: float, q) -> bool:
        """A joint state ``q`` (dof,) rad measured at ``stamp`` (s). Returns False when it is refused
        (stamp not after the newest, non-finite, wrong length, outside the joint limits); the
        refusals are counted in ``stats()``."""
        return self.joints.push(float(stamp), q)

    def push_frame(self, frame) -> None:
        """A depth frame (:class:`~depthguard.sources.Frame`: camera id, (H, W) metres, capture
        stamp). Returns at once; the frame is processed on its camera's worker thread. A frame of
        a camera that is not monitored (removed) is counted as refused."""
        w = self._workers.get(frame.camera_id)
        if w is None:
            if frame.camera_id not in self._cameras:
                raise ValueError(f"frame of unknown camera {frame.camera_id!r}; the rig's cameras: "
                                 f"{', '.join(self._cameras)}")
            self._unmonitored = getattr(self, "_unmonitored", 0) + 1
            return
        w.offer(frame, time.perf_counter())

    def push_voxels(self, camera_id: str, centres, voxel_size: float, stamp: float) -> None:
        """The voxels (N, 3) world m, cubes of side ``voxel_size`` m, of a remote camera unit's frame
        captured at ``stamp`` s (R20); ``camera_id`` must be one of ``remote_cameras``."""
        if camera_id not in self.config.remote_cameras:
            raise ValueError(f"voxels of camera {camera_id!r}, which is not among the remote cameras "
                             f"{list(self.config.remote_cameras)} (monitor.remote_cameras)")
        self.voxels.push(camera_id, centres, voxel_size, stamp)

    # ------------------------------------------------------------ changes while running
    def set_rho(self, rho: float) -> None:
        """Change the radius of surveillance (m) while running."""
        self.update_config(rho=rho)

    def update_config(self, **changes) -> MonitorConfig:
        """Apply validated changes to the running configuration (``rho``, ``camera_stale_s``,
        ``joints_stale_s``, ``stop_time``, ``resume_time``, ``v_max``, ``alpha``, ``method``);
        ``ValueError`` naming the field on a bad value or one that cannot change while running."""
        allowed = {"rho", "camera_stale_s", "joints_stale_s", "stop_time", "resume_time", "v_max", "alpha",
                   "method", "camera_hz"}
        bad = set(changes) - allowed
        if bad:
            raise ValueError(f"cannot change {', '.join(sorted(bad))} while running; changeable: "
                             f"{', '.join(sorted(allowed))}")
        with self._settings_lock:
            self.config = self.config.with_changes(**changes)
            self._sup.stop_time, self._sup.resume_time = self.config.stop_time, self.config.resume_time
        self.fusion.notify()
        return self.config

    def add_camera(self, camera_id: str, t: float | None = None) -> None:
        """Monitor one more of the rig's cameras; it is used from its first frame, and is not
        awaited (no stale reason) until then."""
        if camera_id not in self._cameras:
            raise ValueError(f"rig {self.rig.name!r} has no camera {camera_id!r}")
        with self._settings_lock:
            if camera_id in self._camera_ids:
                return
            ids = self._camera_ids + (camera_id,)
        self.fusion.prepare(ids)                  # the new grid made here, not by the next frame
        with self._settings_lock:
            if camera_id in self._camera_ids:
                return
            self._start_worker(camera_id)
            self._camera_ids = self._camera_ids + (camera_id,)
        self._added_at[camera_id] = -math.inf if t is None else float(t)

    def accept_camera(self, camera_id: str) -> None:
        """The user trusts camera ``camera_id`` as it is now (R34): its drift flag is cleared and its
        current residual level becomes the baseline — a further growth is flagged again. (A moved
        camera is better recalibrated: ``depthguard calibrate``, then run with the corrected rig.)"""
        w = self._workers.get(camera_id)
        if w is None:
            raise ValueError(f"camera {camera_id!r} is not monitored; monitored: {', '.join(self._camera_ids)}")
        if w.drift is not None:
            w.drift.accept()

    def drift(self) -> dict:
        """Per monitored camera: ``untrusted``, the last judged ``share`` farther than the static
        scene, its ``baseline``, the ``flagged_at`` stamp and the ``message`` (R34); {} when off."""
        out = {}
        for c, w in list(self._workers.items()):
            d = w.drift
            if d is not None:
                out[c] = {"untrusted": d.untrusted, "share": d.share, "baseline": d.baseline,
                          "flagged_at": d.flagged_at, "judged": d.judged, "samples": d.samples,
                          "message": d.message}
        return out

    def remove_camera(self, camera_id: str) -> None:
        """Stop monitoring a camera: its frames are no longer awaited nor used. The principal
        can be removed: the next camera becomes principal."""
        with self._settings_lock:
            if camera_id not in self._camera_ids:
                raise ValueError(f"camera {camera_id!r} is not monitored; monitored: {', '.join(self._camera_ids)}")
            if len(self._camera_ids) == 1:
                raise ValueError("cannot remove the last monitored camera")
            self._camera_ids = tuple(c for c in self._camera_ids if c != camera_id)
            w = self._workers.pop(camera_id)
        w.close()
        self._seen.pop(camera_id, None)
        self.fusion.notify()

    # ------------------------------------------------------------ the control cycle
    def step(self, t: float, q=None, qd=None) -> Reaction:
        """The reaction at time ``t`` (s) with the robot at ``q`` (dof,) rad — default: the newest
        joint state received. Never waits for a frame (module docstring). ``qd`` (dof,) rad/s:
        the commanded joint velocity before any scaling, for speed and separation monitoring
        (R33; default: the joints' rate between the last two cycles)."""
        t_wall = time.perf_counter()
        cfg = self.config
        robot, data = self.robot, self._data
        latest = self.joints.latest()
        joints_age = math.inf if latest is None else t - latest[0]
        if q is None:
            q = latest[1] if latest is not None else (self._last_q if self._last_q is not None
                                                       else np.asarray(self.rig.robot_q0, dtype=np.float64))
        q = np.asarray(q, dtype=np.float64)
        self._last_q = q
        robot.forward(q, data)
        m_cp = len(self._cp_names)
        self._P[:m_cp] = data.cp_positions
        if len(self._watch):
            self._P[m_cp:] = self._watch
        m = len(self._names)
        D = np.full(m, np.inf)
        V = np.zeros((m, 3))
        obs = np.zeros(m, dtype=bool)
        stamps = self._distances(cfg, q, D, V, obs)
        remote = cfg.remote_cameras
        if remote:                                     # the units' voxel boxes (R20, R25)
            caps = robot.collision_segments(q, cfg.robot_padding)
            stamps.update(self.voxels.nearest(self._P, cfg.query_rho, D, V, robot_capsules=caps))
        # supervision (R26, R27)
        with self._settings_lock:
            ids = self._camera_ids + tuple(remote)
        limit = cfg.camera_stale_limit
        cams: dict[str, CameraStatus] = {}
        ages = np.empty(len(ids))
        # an added camera is not awaited before its first frame only while some monitored camera
        # has a frame in use: a grid made of removed cameras' frames alone must not run unsupervised
        in_use = any(c in stamps for c in ids)
        untrusted: dict[str, str] = {}
        for i, c in enumerate(ids):
            w = self._workers.get(c)
            st = stamps.get(c)
            age = math.inf if st is None else t - st
            awaited = not (st is None and c in self._added_at and in_use)   # added, no frame yet: not awaited
            ages[i] = age if awaited else 0.0
            state = "waiting" if st is None else ("stale" if age > limit + 1e-9 else "fresh")
            dw = w.drift if w is not None else None
            if dw is not None and dw.untrusted:       # R34: moved; latched until recalibrated or accepted
                state = "untrusted"
                untrusted[c] = dw.message
            cams[c] = CameraStatus(age, state, w.frames if w else 0, w.refused if w else 0,
                                   -math.inf if st is None else st)
        reasons = stop_reasons(ages, limit, ids, obs[:m_cp], D[:m_cp], V[:m_cp], self._cp_names)
        for c, msg in untrusted.items():
            reasons[f"untrusted:{c}"] = msg
        explain_stale(reasons, self._workers, self._refusal_marks)     # a stale camera's refused frames
        if joints_age > cfg.joints_stale_s + 1e-9:
            reasons["stale:joints"] = (f"joint states: none for more than {cfg.joints_stale_s * 1e3:.0f} ms "
                                       f"- stale data (R27)" if latest is not None else
                                       "joint states: none received yet (R27)")
        dt = cfg.dt if self._t_last is None else min(max(t - self._t_last, 0.0), 1.0)
        self._t_last = t
        k = self._sup.update(t, reasons, dt=dt)
        D_rep = D[:m_cp]
        scale, pstop, ssm_table, s_ssm = float(k), False, None, 1.0
        if self._ssm is not None:                      # R33: speed scale and protective stop
            if cfg.reaction == "ssm":
                D_rep = self._D_none
            else:
                np.copyto(self._D_rep, D_rep)
                self._D_rep[self._D_rep > cfg.rho] = np.inf
                D_rep = self._D_rep
            if qd is None:
                prev = self._q_ssm_prev
                if prev is not None and t > prev[0]:
                    np.subtract(q, prev[1], out=self._qd_meas)
                    self._qd_meas /= t - prev[0]
                self._q_ssm_prev = (t, q.copy())
            age = t - min(stamps.values()) if stamps else cfg.camera_stale_limit   # none: nothing observed
            s_ssm, pstop = self._ssm.update(t, dt, D[:m_cp], V[:m_cp], data.cp_positions, data.cp_jacobians,
                                            self._qd_meas if qd is None else np.asarray(qd, dtype=np.float64),
                                            obs[:m_cp], age)
            scale = float(k) * s_ssm
            ssm_table = self._ssm.table.copy()
            if pstop:
                reasons = {**reasons, **self._ssm.reason(self._cp_names)}
        rep, lo, hi = reaction_of(D_rep, V[:m_cp], data.cp_jacobians, q, self._q_min, self._q_max,
                                  self._qd_max, cfg.dt, cfg.rho, cfg.v_max, cfg.alpha, k, out=self._react_buf)
        step_s = time.perf_counter() - t_wall
        self.cycles += 1
        self.step_s.append(step_s)
        if len(self.step_s) > 100_000:
            del self.step_s[:50_000]
        r = Reaction(t=float(t), override=float(k), repulsion=rep.copy(), qd_min=lo.copy(), qd_max=hi.copy(),
                     names=self._names, distance=D, direction=V, observed=obs, is_watch=self._is_watch,
                     reasons=reasons, cameras=cams, joints_age_s=float(joints_age), q=q.copy(),
                     frame_stamps=stamps, step_s=step_s, reaction=cfg.reaction, speed_scale=scale,
                     protective_stop=pstop, ssm=ssm_table, ssm_scale=float(s_ssm))
        for s in self.sinks:
            s(r)
        return r

    def _distances(self, cfg, q, D, V, obs) -> dict[str, float]:
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
        worker.request(q.copy())
        snap = worker.newest()
        usable = snap is not None and snap.rho == cfg.query_rho and snap.method == cfg.method
        if not usable:
            why = "no_answer" if snap is None else "settings_changed"
        elif time.perf_counter() - snap.wall > worker.max_age_s:
            why = "answer_too_old"
        elif bound_distances(snap, self._P, cfg.query_rho, D, V, obs):
            self._count_frames(snap.versions, snap.pushed_at)
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
            if not bound_distances(snap, self._P, cfg.query_rho, D, V, obs):
                bound_distances(snap, self._P, cfg.query_rho, D, V, obs, strict=False)
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
        now = time.perf_counter()
        for c, v in versions.items():
            if self._seen.get(c) != v:
                self._seen[c] = v
                self.frame_to_reaction_s.append(now - pushed_at[c])

    @contextmanager
    def real_time(self):
        """``with monitor.real_time(): ...`` around a real-time run's control loop, entered on
        the control thread (after its SCHED_FIFO, :mod:`depthguard.runtime.realtime`): the grid
        is queried on a thread of its own at ``distance_hz`` and each cycle bounds the newest
        answer (:mod:`depthguard.runtime.distances`). ``distance_hz`` 0 or the ``mean`` method
        (not a bound under motion): nothing changes. Fast runs do not use it: their logs do not
        depend on thread timing."""
        cfg = self.config
        if cfg.distance_hz <= 0 or cfg.method == "mean" or self._dist_worker is not None:
            single = self.fusion.single
            if self._dist_worker is None:
                self.fusion.set_single(False)    # the cycles read the grid: two, never wait
            try:
                yield self
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
            yield self
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
        (:meth:`~depthguard.runtime.ingest.FusionWorker.set_single` — the same answers at half
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
            return self.config.query_rho, self.config.method

    # ------------------------------------------------------------ state
    @property
    def episodes(self) -> list[dict]:
        """Every stop episode so far: reason, key, t_start, t_end, t_stopped."""
        return self._sup.episodes

    def idle(self) -> bool:
        """True when every frame pushed so far has been processed and swapped in."""
        return all(w.idle() for w in list(self._workers.values())) and self.fusion.idle()

    def flush(self, timeout: float = 10.0) -> None:
        """Wait until every frame pushed so far is in the front grid (tests, replays as fast
        as possible); ``TimeoutError`` after ``timeout`` s."""
        end = time.perf_counter() + timeout
        while not self.idle():
            if time.perf_counter() > end:
                raise TimeoutError(f"monitor: frames still in processing after {timeout} s")
            time.sleep(0.0002)

    def stats(self) -> dict:
        """Counters: per camera ``frames`` processed by its worker, ``fused`` (loaded into a grid:
        a frame replaced by a newer one of its camera before a fusion build is never fused),
        ``dropped`` (replaced before its worker took it), ``refused`` by reason; joints refused;
        fusion builds and errors; cycles."""
        cams = {}
        for c, w in list(self._workers.items()):
            with w.lock:
                fused = self.fusion.fused.get(c, 0)
                cams[c] = {"frames": w.frames, "fused": fused, "dropped": w.dropped, "refused": dict(w.refusals),
                           "last_refusal": w.last_refusal}
        return {"cameras": cams, "joints_refused": self.joints.refused,
                "joints_last_refusal": self.joints.last_refusal, "fusion_builds": self.fusion.builds,
                "fusion_errors": self.fusion.errors, "fusion_last_error": self.fusion.last_error,
                "cycles": self.cycles, "frames_of_removed_cameras": getattr(self, "_unmonitored", 0)}

    # ------------------------------------------------------------ free space, paths (R21, R22, R37)
    def start_free_space(self, hz: float | None = None, voxel_size: float | None = None, on_snapshot=None):
        """Start the free-space map's thread (:mod:`depthguard.runtime.free_space_map`) at ``hz``
        (default ``config.free_space_hz``) with voxels of ``voxel_size`` m (default
        ``config.free_space_voxel``); returns its :class:`FreeSpaceWorker`."""
        from depthguard.runtime.free_space_map import FreeSpaceWorker, RuntimeFreeSpace

        if self.free_space is not None:
            return self.free_space
        cfg = self.config
        space = RuntimeFreeSpace(self.rig, self._camera_ids, voxel_size or cfg.free_space_voxel,
                                 cfg.robot_offset, cfg.robot_padding)
        self.free_space = FreeSpaceWorker(space, self._workers, self._latest_q, hz or cfg.free_space_hz, on_snapshot)
        return self.free_space

    def check_path(self, stamps, q, padding: float | None = None, fresh: bool = False):
        """R22, R37: a planned path — ``stamps`` (n,) s increasing, ``q`` (n, dof) rad — against the
        newest free-space map: a :class:`~depthguard.control.path_check.PathVerdict` (per segment
        safe / maybe / unsafe, the first segment not safe, the reasons). ``padding`` m on the
        robot's capsules (default ``config.robot_padding``); ``fresh`` builds a map from the newest
        frames first. Starts the map if it is off; no map yet (no frame): every segment ``maybe``.
        A bad path raises ``ValueError`` naming the waypoint."""
        from depthguard.control.path_check import PathVerdict, SegmentVerdict, validate_path
        from depthguard.runtime.free_space_map import check_path_in

        worker = self.start_free_space()
        snap = worker.update_now() if fresh or worker.snapshot is None else worker.snapshot
        pad = self.config.robot_padding if padding is None else float(padding)
        if snap is None:
            t, _ = validate_path(stamps, q, self.robot)
            return PathVerdict(tuple(SegmentVerdict(i, float(t[i]), float(t[i + 1]), "maybe", why="no map yet (no frame)")
                                     for i in range(len(t) - 1)))
        return check_path_in(snap, self.robot, stamps, q, pad)

    def _latest_q(self):
        latest = self.joints.latest()
        return None if latest is None else latest[1]

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self.free_space is not None:
            self.free_space.close()
        for w in list(self._workers.values()):
            w.close()
        self.fusion.close()
        for s in self.sinks:
            close = getattr(s, "close", None)
            if close is not None:
                close()

    def __enter__(self) -> "Monitor":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def warm_up(rig, config: MonitorConfig | None = None) -> float:
    """Compile every kernel of the monitor's path (numba, ``cache=True``: from the disk cache
    after the first time) on a throwaway monitor fed with the known scene's expected depth, so
    that no clock of a run includes compilation. Returns the seconds it took."""
    from depthguard.filtering.expected import ExpectedDepth
    from depthguard.sources.frame import Frame

    t0 = time.perf_counter()
    q0 = np.asarray(rig.robot_q0, dtype=np.float64)
    with Monitor(rig, config) as mon:
        mon.push_joints(0.0, q0)
        mon.push_joints(0.001, q0)
        for cid in mon.camera_ids:
            cam = rig.camera(cid)
            mon.push_frame(Frame(cid, np.array(ExpectedDepth(cam, rig.robot, rig.static_meshes()).known(q0)),
                                 0.0005))
        mon.flush(timeout=600.0)
        mon.step(0.001)
        # the distance thread's band query and the cycles' bound of its answer (real_time())
        from depthguard.runtime.distances import DistanceSnapshot, bound_distances

        cfg = mon.config
        grid = mon.fusion.front.grid
        P = mon._P.copy()
        res = grid.query(P, rho=cfg.query_rho + cfg.distance_margin, method=cfg.method, threads=1,
                         rho_core=cfg.query_rho)
        snap = DistanceSnapshot(P, res.distance.copy(), res.direction.copy(), res.observed.copy(), cfg.query_rho,
                                cfg.distance_margin, cfg.method, {}, {}, {}, grid.principal_view(), 0.0)
        m = len(P)
        bound_distances(snap, P, cfg.query_rho, np.empty(m), np.empty((m, 3)), np.empty(m, dtype=bool))
    from depthguard.runtime.voxel_input import VoxelObstacles
    units = VoxelObstacles()                      # the remote units' kernel
    units.push("warm-up", np.zeros((1, 3)), 0.05, 0.0)
    units.nearest(np.ones((2, 3)), 0.4, np.full(2, np.inf), np.zeros((2, 3)),
                  robot_capsules=rig.robot.collision_segments(q0, 0.05))
    return time.perf_counter() - t0
