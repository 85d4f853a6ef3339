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
4. reaction: the reaction policies of ``cfg.policies`` (:mod:`depthguard.control.policy`),
   each given the cycle's distances, joints and override: repulsion at the end effector
   (R13) with joint-velocity limits from the other control points and the joint limits
   (R14), both times the override; speed and separation monitoring (R33,
   :mod:`depthguard.control.policy_ssm`): a speed scale and a protective stop, distances
   looked for within ``max(rho, ssm.range)``. The most restrictive wins: the speed scale
   is the override times the smallest policy scale, the boxes are intersected.

Every clock is the caller's: stamps of frames and joints and the ``t`` of
``step`` are seconds on one clock (``time.monotonic()`` for a live cell,
simulated time for a simulator or a recording replayed fast).
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np

from depthguard.config import MonitorConfig
from depthguard.control.policy import Cycle, PolicySetup, make_policies
from depthguard.control.repulsion_limits import repulsion_and_limits
from depthguard.control.supervisor import SafetySupervisor, point_reasons, points_hold_robot
from depthguard.runtime.monitor_distances import MonitorDistances
from depthguard.runtime.monitor_paths import MonitorPaths
from depthguard.runtime.monitor_watches import MonitorWatches
from depthguard.runtime.camera_shares import CameraShares
from depthguard.runtime.camera_supervision import camera_pass
from depthguard.runtime.fusion_worker import FusionWorker
from depthguard.runtime.ingest import CameraWorker
from depthguard.robot.joint_history import JointHistory
from depthguard.runtime.result import Reaction
from depthguard.runtime.refusals import explain_stale
from depthguard.runtime.realtime import TIMING_KEEP
from depthguard.runtime.unit_states import UnitStateInput, UnitWorker
from depthguard.runtime.warm_up import warm_up

__all__ = ["Monitor", "warm_up"]


class Monitor(MonitorDistances, UnitStateInput, MonitorPaths, MonitorWatches):
    """The runtime of one cell (module docstring).

    rig : a :class:`~depthguard.rig.Rig` with a robot and cameras.
    config : a :class:`~depthguard.config.MonitorConfig` (default: ``rig.monitor``).
    sinks : callables ``sink(reaction)`` called with every reaction, from the
        thread that calls ``step`` — keep them quick, or wrap them in
        :class:`depthguard.runtime.sinks.SinkFanout`.
    start_override : the override before the first cycle. 0 (the default, R26, R27): the robot
        starts stopped and ramps up over ``resume_time`` once a cycle finds no stop reason.
        1 only for a simulator whose cell is in steady state at t = 0 (the closed loop: the
        papers' runs start with the robot moving and frames captured at t = 0 delivered); a
        stop reason in the first cycle still ramps it down at once.

    Use as a context manager, or call :meth:`close`.
    """

    def __init__(self, rig, config: MonitorConfig | None = None, *, sinks=(), start_override: float = 0.0):
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
        self._state_options_memo: tuple = (None, None, {})   # _state_options by (settings, cameras)
        self._settings_data = self._settings_fk = None           # _fusion_settings' kinematics
        self.joints = JointHistory(self.robot.dof, cfg.joint_history_s, q_min=self.robot.q_min,
                                   q_max=self.robot.q_max, max_gap_s=cfg.joints_stale_s)
        self._static = rig.static_meshes()
        # issue 31 point 3: SSM from what is not the known scene (ssm.known_scene: muted): the
        # cameras' unknown objects as voxels, like the camera units' (R17, R25)
        self._ssm_voxels = None
        if cfg.reaction != "repulsion" and cfg.ssm.known_scene == "muted":
            from depthguard.runtime.voxel_input import VoxelObstacles
            self._ssm_voxels = VoxelObstacles()
        self._workers: dict[str, CameraWorker] = {}
        self._shares = CameraShares(self)          # the cameras' clearing, made on their workers
        self.fusion = FusionWorker(self._workers, self._make_grid, self._fusion_settings, self.robot,
                                   threads=cfg.fusion_threads)
        self.fusion.prepare(self._camera_ids)      # the grid made now, not by the first frames
        for cid in self._camera_ids:
            self._start_worker(cid)
        self._added_at: dict[str, float] = {}
        from depthguard.runtime.voxel_input import VoxelObstacles
        self.voxels = VoxelObstacles()            # the remote units' voxels (R20)
        self.sinks = list(sinks)
        #: ``commanded_qd(q) -> (dof,) rad/s or None``: the program's joint velocity at speed scale 1
        #: at ``q``, for SSM when ``step`` is given no ``qd`` (R33); set by what knows the robot's
        #: program: the sink that runs it (:meth:`depthguard.runtime.franky_sink.FrankySink.attach`)
        #: or a robot that reports its speed scaling (:meth:`depthguard.sources.ur_rtde.UrRtdeJoints.attach`).
        #: None: the joints' measured rate, which is the motion already scaled by the reaction
        self.commanded_qd = None
        # control-thread state (preallocated)
        self._data = self.robot.create_data()
        self._fk = self.robot.forward_into(self._data)    # step's forward kinematics, bound once
        self._q_shape = (self.robot.dof,)
        self._cp_names = tuple(c.name for c in self.robot.control_points)
        self._watch = np.array([w.position for w in cfg.watch_points], dtype=np.float64).reshape(-1, 3)
        self._names = self._cp_names + tuple(w.name for w in cfg.watch_points)
        m = len(self._names)
        self._P = np.zeros((m, 3))
        self._D_inf = np.full(m, np.inf)
        self._is_watch = np.arange(m) >= len(self._cp_names)
        self._q_min, self._q_max, self._qd_max = (np.ascontiguousarray(a, dtype=np.float64) for a in
                                                  (self.robot.q_min, self.robot.q_max, self.robot.qd_max))
        self._sup = SafetySupervisor(cfg.dt, cfg.stop_time, cfg.resume_time, k0=start_override)
        # the reaction policies (control.policy, R13, R14, R33): fixed for the monitor's life
        m_cp = len(self._cp_names)
        setup = PolicySetup(cfg, self.robot, tuple(self._cameras[c] for c in self._camera_ids), self._cp_names,
                            ssm_obstacles=self._ssm_voxels)
        self._policies = make_policies(cfg.policies, setup)
        self._mode = cfg.reaction_mode
        self._D_none = np.full(m_cp, np.inf)          # no policy gives a box: the joint limits' alone
        self._box_buf = (np.empty(3), np.empty(self.robot.dof), np.empty(self.robot.dof))
        self._t_last: float | None = None
        self._cfg_cache: tuple | None = None          # (config, query_rho, camera stale limit): _derived
        self._last_q: np.ndarray | None = None
        self._seen: dict[str, int] = {}          # camera -> version already used by a cycle
        self._counted = None                      # the distance snapshot's versions last counted (_distances)
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
        if cid in cfg.state_cameras:                 # its unit makes its state (issue 29): push_state
            self._workers[cid] = UnitWorker(self._cameras[cid], self.robot, lambda: self._unit_expected(cid),
                                            self.fusion.notify)
            return
        drift = (dict(k_sigma=cfg.drift_sigma, share=cfg.drift_share, frames=cfg.drift_frames)
                 if cfg.drift_watch else None)                       # R34
        self._workers[cid] = CameraWorker(self._cameras[cid], self.robot, self._static, self.joints,
                                          cfg.joint_wait_s, self.fusion.notify, drift=drift,
                                          state_options=lambda: self._state_options(cid),
                                          share=self._shares.maker(cid) if cfg.camera_shares else None,
                                          learned=getattr(self.rig, "learned", {}).get(cid),   # issue 31
                                          scene_change=cfg.scene_change_settings(),
                                          ssm_muted=self._ssm_muted(cid))

    def _ssm_muted(self, cid: str):
        """``(VoxelFilter, push)`` for camera ``cid`` when SSM mutes the known scene, else None. The
        filter's box is the workspace grown by SSM's separation range (sideways and up; not below
        its floor): a person outside the workspace but within the range of the robot is seen,
        not taken for "nothing within range" (R33)."""
        if self._ssm_voxels is None:
            return None
        from depthguard.control.policy_ssm import SpeedSeparationPolicy
        from depthguard.fusion.voxels import VoxelFilter
        ws = self.rig.workspace
        r = SpeedSeparationPolicy.separation_range(self.config)
        lo = np.asarray(ws.lo, dtype=np.float64) - (r, r, 0.0)
        hi = np.asarray(ws.hi, dtype=np.float64) + r
        return (VoxelFilter(self._cameras[cid], (lo, hi), voxel_size=self.config.ssm.muted_voxel_size),
                self._ssm_voxels.push)

    def _state_options(self, cid: str):
        """``(StateOptions, robot_free, pyramids, bin)`` for camera ``cid``'s frames as the depth grid will
        load them (its role: the principal, or another camera whose pyramids the grid reads), or
        None with one camera (no grid, R36)."""
        with self._settings_lock:
            cfg, ids = self.config, self._camera_ids
        memo = self._state_options_memo           # per frame of every camera (issue 29): worked out
        if memo[0] is cfg and memo[1] is ids and cid in memo[2]:   # once per settings and camera set
            return memo[2][cid]
        if memo[0] is not cfg or memo[1] is not ids:
            memo = self._state_options_memo = (cfg, ids, {})
        memo[2][cid] = out = self._work_out_state_options(cfg, ids, cid)
        return out

    def _work_out_state_options(self, cfg, ids: tuple, cid: str):
        """:meth:`_state_options` for the settings ``cfg`` and cameras ``ids``."""
        from depthguard.fusion.depth_grid_state import StateOptions, pyramid_levels

        if len(ids) < 2 or cid not in ids:
            return None
        other = cid != ids[0]
        # another camera's min / max pyramids are made on its worker, into the worker's pooled
        # buffers (frame_pool: no page faults, never one a reader holds), and the build reads
        # them in place with the state (fusion/camera_views): 0.36-0.45 ms of the build. Only
        # where the grid's levels (from the largest other camera) are the camera's own: else
        # the grid makes them (DepthGridMap._load_frames) and the worker's would go unread
        pyramids = False
        if other:
            cams = [self._cameras[c] for c in ids[1:]]
            cam = self._cameras[cid]
            pyramids = (pyramid_levels(cam.height, cam.width)
                        == pyramid_levels(max(c.height for c in cams), max(c.width for c in cams)))
        return StateOptions.of(cfg), cfg.robot_in_others == "free" and other, pyramids, 1 if other else cfg.principal_bin

    def _make_grid(self, cams: tuple[str, ...]):
        from depthguard.fusion.depth_grid import DepthGridMap

        cameras = [self._cameras[c] for c in cams]
        if len(cameras) == 1:
            from depthguard.runtime.single import OneCameraMap
            return OneCameraMap(cameras[0])
        d_min, d_max = self.rig.workspace.depth_span(cameras[0])
        grid = DepthGridMap(cameras, principal=cams[0], d_min=d_min, d_max=d_max, delta_d=self.config.delta_d,
                            principal_bin=self.config.principal_bin)
        # the other cameras' workers clear its cells (issue 29), when the rig asks for it
        grid.share_requests = bool(self.config.camera_shares)
        return grid

    def _fusion_settings(self):
        """(config, camera ids, points whose cells to classify ahead) for the fusion worker."""
        with self._settings_lock:
            cfg, ids = self.config, self._camera_ids
        latest = self.joints.latest()
        pts = None
        if latest is not None:
            # on the fusion thread alone (its one caller): its own data, the kinematics bound once
            if self._settings_fk is None:
                self._settings_data = self.robot.create_data()
                self._settings_fk = self.robot.forward_into(self._settings_data)
            q = latest[1]                  # (a copy of the history's float64 (dof,) state: checked there)
            if not self._settings_fk(q):
                self.robot.check_q(q)      # raises, naming the bad value
            cp = self._settings_data.cp_positions
            # new arrays: the build hands its points on with its answer (the distance worker keeps them)
            pts = np.concatenate([cp, self._watch]) if len(self._watch) else cp.copy()
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
        stamp). Returns at once; the frame is processed on its camera's worker thread, which keeps
        a float32 C-contiguous depth without copying it: do not write into it afterwards. A frame
        of a camera that is not monitored (removed) is counted as refused."""
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
        self._counted = None
        self.fusion.notify()

    # ------------------------------------------------------------ the control cycle
    def _derived(self, cfg) -> tuple:
        """``(cfg, query_rho, camera_stale_limit)`` of the running configuration, worked out once per
        configuration (each is a property that walks the policies: ~10 us a cycle, issue 29)."""
        c = self._cfg_cache
        if c is None or c[0] is not cfg:
            c = self._cfg_cache = (cfg, float(cfg.query_rho), float(cfg.camera_stale_limit))
        return c

    def step(self, t: float, q=None, qd=None) -> Reaction:
        """The reaction at time ``t`` (s) with the robot at ``q`` (dof,) rad — default: the newest
        joint state received. Never waits for a frame (module docstring). ``qd`` (dof,) rad/s:
        the commanded joint velocity before any scaling, for speed and separation monitoring
        (R33; default: :attr:`commanded_qd` at ``q`` where it is set, else the joints' rate
        between the last two cycles)."""
        t_wall = time.perf_counter()
        cfg = self.config
        _, query_rho, limit = self._derived(cfg)
        robot, data = self.robot, self._data
        latest = self.joints.latest()
        joints_age = math.inf if latest is None else t - latest[0]
        if q is None:
            q = latest[1] if latest is not None else (self._last_q if self._last_q is not None
                                                       else np.asarray(self.rig.robot_q0, dtype=np.float64))
        q = np.asarray(q, dtype=np.float64)
        self._last_q = q
        if q.shape != self._q_shape or not self._fk(q):
            robot.forward(q, data)                     # its ValueError: a wrong length or a value not finite
        m_cp = len(self._cp_names)
        self._P[:m_cp] = data.cp_positions
        if len(self._watch):
            self._P[m_cp:] = self._watch
        m = len(self._names)
        D = self._D_inf.copy()                        # fresh: the reaction keeps them
        V = np.zeros((m, 3))
        obs = np.zeros(m, dtype=bool)
        stamps = self._distances(cfg, q, D, V, obs, query_rho)
        remote = cfg.remote_cameras
        if remote:                                     # the units' voxel boxes (R20, R25)
            caps = robot.collision_segments(q, cfg.robot_padding)
            stamps.update(self.voxels.nearest(self._P, query_rho, D, V, robot_capsules=caps))
        # supervision (R26, R27): the stop reasons of supervisor.stop_reasons, in its order (the cameras'
        # stale data, then the control points'), made in this one pass over the cameras (issue 29)
        with self._settings_lock:
            ids = self._camera_ids + tuple(remote) if remote else self._camera_ids
        cams, reasons, untrusted = camera_pass(t, ids, stamps, self._workers, self._added_at, limit)
        o_cp, D_cp, V_cp = obs[:m_cp], D[:m_cp], V[:m_cp]
        if points_hold_robot(o_cp, D_cp, V_cp):       # the usual cycle: every point observed, none enclosed
            point_reasons(reasons, o_cp, D_cp, V_cp, self._cp_names)
        if untrusted:
            for c, msg in untrusted.items():
                reasons[f"untrusted:{c}"] = msg
        explain_stale(reasons, self._workers, self._refusal_marks)     # a stale camera's refused frames
        if joints_age > cfg.joints_stale_s + 1e-9:
            reasons["stale:joints"] = (f"joint states: none for more than {cfg.joints_stale_s * 1e3:.0f} ms "
                                       f"- stale data (R27)" if latest is not None else
                                       "joint states: none received yet (R27)")
        if qd is None and self.commanded_qd is not None:
            qd = self.commanded_qd(q)
        dt = cfg.dt if self._t_last is None else min(max(t - self._t_last, 0.0), 1.0)
        self._t_last = t
        k = self._sup.update(t, reasons, dt=dt)
        age = t - min(stamps.values()) if stamps else cfg.camera_stale_limit   # none: nothing observed
        cycle = Cycle(float(t), dt, q, None if qd is None else np.asarray(qd, dtype=np.float64), D_cp,
                      V_cp, o_cp, data.cp_positions, data.cp_jacobians, age, float(k), reasons, cfg)
        rep, lo, hi, s_pol, pstop, parts = self._react(cycle)
        for part in parts.values():
            if part.reasons:
                reasons = {**reasons, **part.reasons}
        scale = float(k) * s_pol
        ssm = parts.get("ssm")
        step_s = time.perf_counter() - t_wall
        self.cycles += 1
        self.step_s.append(step_s)
        if len(self.step_s) > TIMING_KEEP:
            del self.step_s[:TIMING_KEEP // 2]
        r = Reaction.made(dict(t=float(t), override=float(k), repulsion=rep, qd_min=lo, qd_max=hi,
                               names=self._names, distance=D, direction=V, observed=obs, is_watch=self._is_watch,
                               reasons=reasons, cameras=cams, joints_age_s=float(joints_age), q=q.copy(),
                               frame_stamps=stamps, step_s=step_s, reaction_mode=self._mode, speed_scale=scale,
                               protective_stop=pstop, ssm=None if ssm is None else ssm.terms,
                               ssm_scale=1.0 if ssm is None else float(ssm.scale), parts=parts))
        for s in self.sinks:
            s(r)
        return r

    def _react(self, c: Cycle):
        """The policies' parts composed (:mod:`depthguard.control.policy`): ``(repulsion (3,),
        qd_min, qd_max (dof,), scale, stop, parts)`` — the repulsions summed, the boxes
        intersected (none: the joint limits' box times the override), the smallest scale (0
        when one stops)."""
        parts = {}
        rep = lo = hi = None
        scale, stop = 1.0, False
        for name, pol in self._policies:         # a part's arrays are its own (fresh): kept, not copied
            part = pol.update(c)
            parts[name] = part
            if part.scale < scale:
                scale = float(part.scale)
            if part.stop:
                stop, scale = True, 0.0
            if part.repulsion is not None:
                rep = part.repulsion if rep is None else rep + part.repulsion
            if part.qd_min is not None:
                lo = part.qd_min if lo is None else np.maximum(lo, part.qd_min)
                hi = part.qd_max if hi is None else np.minimum(hi, part.qd_max)
        if lo is None:
            cfg = c.config
            _, lo, hi = repulsion_and_limits(self._D_none, c.direction, c.jacobians, c.q, self._q_min, self._q_max,
                                    self._qd_max, cfg.dt, cfg.rho, cfg.v_max, cfg.alpha, c.override,
                                    out=self._box_buf)
            lo, hi = lo.copy(), hi.copy()
        return np.zeros(3) if rep is None else rep, lo, hi, scale, stop, parts

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
