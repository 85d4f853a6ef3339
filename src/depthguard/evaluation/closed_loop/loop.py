"""The closed loop in simulated time: cameras, distances, reactions, robot (R13–R15, R26, R27).

One control cycle (500 Hz, ``dt = 2 ms``) at time ``t``:

1. **Vision** (30 Hz per camera, cameras not synchronised): when a camera's
   next frame is due and it still delivers, the scene at ``t`` with the
   robot at its *current* joints is rendered and passed through the
   camera's noise model (the robot occludes); the robot alone is rendered at
   the same joints for self removal (R9). The frame's stamp is its capture
   time ``t``; it is **delivered** ``camera_latency`` later (default one
   camera period, as a Kinect's frame; 0 = at once) and simulated meanwhile
   on a second thread (:mod:`depthguard.evaluation.closed_loop.camera_pipeline`). The
   static scene is rendered once per camera at set-up and each frame renders
   only the robot and the moving obstacles, combined per pixel with it (the
   same image, :mod:`depthguard.render.composite`).
2. **The runtime** (R29): the loop is :class:`depthguard.runtime.Monitor` fed by the
   simulator. Each cycle pushes the joints at ``t``; the frames delivered now are pushed
   with their capture stamps (the monitor removes the robot at the joints of the capture,
   R30) and fused before the cycle's distances (``flush``, so that a run does not depend
   on thread timing); ``step(t, q)`` returns the distances of the 9 control points, the
   speed override ``k`` with its stop reasons (stale frames R27, unobserved points R26,
   a point inside an obstacle frustum), the repulsion at the end effector (R13) and the
   joint-velocity limits of the other control points (R14), times ``k``.
3. **The robot obeys**: EE task ``ẋ_d = k·ṗ_d(τ) + K_p (p_d(τ) − x)``, ``ẋ_c = ẋ_d + ẋ_rep``;
   joint box = the reaction's limits; SNS gives ``q̇`` with task scale ``s`` and a
   low-priority posture term; ``τ += s·k·dt``; ``q += q̇·dt``. With ``reaction`` ``ssm`` or
   ``both`` (R33) the monitor gets that command before scaling and returns a speed scale;
   the robot applies it to ``q̇`` and ``τ``, braking no harder than the stopping model's
   deceleration allows (:mod:`depthguard.evaluation.closed_loop.ssm_truth`). This robot is the
   package's one obeying robot, :class:`depthguard.sim.obeying_robot.ObeyingRobot` with its
   :class:`~depthguard.sim.obeying_robot.TaskFollower` (the ``sim:`` source drives the same
   object on its joint path).
4. **Ground truth** (not part of the system): the robot's collision capsules
   against the true obstacles (``scene.true_distance`` + the scenario's
   scripted primitives), sampled along each capsule axis every
   ``gt_step`` m (overestimates by at most ``gt_step/2``):
   :mod:`depthguard.evaluation.closed_loop.loop_truth`; in ssm and both modes the SSM
   guarantee against the true human speed, per cycle (``ssm_violation``).

Numba runs on ``LoopConfig.threads`` threads while the loop runs (default:
all but the one the camera thread takes); the results do not depend on the
thread count.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from depthguard.config import MonitorConfig
from depthguard.control.policy import LEGACY_MODES
from depthguard.evaluation.closed_loop.camera_pipeline import CameraPipeline, threadsafe_numba
from depthguard.evaluation.closed_loop.loop_truth import LoopTruth
from depthguard.control.supervisor import SafetySupervisor, stop_reasons
from depthguard.evaluation.closed_loop.trajectory import Hexagon
from depthguard.sim.obeying_robot import ObeyingRobot, TaskFollower
from depthguard.sources.camera_sim import CameraSchedule, CameraSim
from depthguard.sources.frame import Frame

__all__ = ["LoopConfig", "LoopResult", "ClosedLoop", "SafetySupervisor", "solve_ik", "stop_reasons"]


#: the settings the loop shares with the runtime take the product's defaults, defined once in MonitorConfig
_PRODUCT = {name: MonitorConfig.model_fields[name].default
            for name in ("rho", "v_max", "alpha", "control_hz", "camera_hz", "stop_time", "resume_time", "method",
                         "delta_d", "robot_offset", "robot_padding", "invalid", "reaction")}


@dataclass(frozen=True)
class LoopConfig:
    """Parameters of the closed loop (the runtime's: MonitorConfig's defaults, which are Flacco 2014
    §5.3, 2015 §VIII; the loop's own below)."""
    rho: float = _PRODUCT["rho"]                 # m, radius of surveillance
    v_max: float = _PRODUCT["v_max"]             # m/s, largest repulsive speed (R13)
    alpha: float = _PRODUCT["alpha"]             # shape factor (R13, R14)
    control_hz: float = _PRODUCT["control_hz"]
    camera_hz: float = _PRODUCT["camera_hz"]
    camera_latency: float | None = None   # s from capture to delivery (None: one camera period); camera_pipeline.py
    stale_periods: float = 3.0       # R27: frame age limit in camera periods
    stop_time: float = _PRODUCT["stop_time"]     # s, override ramp 1 -> 0
    resume_time: float = _PRODUCT["resume_time"]  # s, override ramp 0 -> 1
    k_p: float = 5.0                 # 1/s, CLIK gain on the EE position error
    k_posture: float = 1.0           # 1/s, null-space pull to the start posture
    method: str = _PRODUCT["method"]
    fusion: str = "grid"             # "grid" (all cameras, R12) | "single" (principal camera only)
    principal: str | None = None     # default: the rig's first camera
    cameras: tuple[str, ...] | None = None   # subset of the rig's cameras (default all)
    noise: bool = True               # the cameras' noise models
    # self removal and invalid pixels: the product's defaults (MonitorConfig, R9, R12, R28, R32)
    robot_offset: float = _PRODUCT["robot_offset"]    # m, R9 self-removal margin
    robot_padding: float = _PRODUCT["robot_padding"]  # m, robot volume: grid cells inside are never obstacles
    invalid: str = _PRODUCT["invalid"]   # R28: "unknown" (the product's) | "free" (as MonitorConfig.invalid)
    threads: int | None = None       # numba threads of the loop (None: all, but one for the camera thread)
    distance_hz: float | None = None  # None: distances at every control cycle (R15); else this rate
    grid_delta_d: float = _PRODUCT["delta_d"]    # m, depth slice of the grid (R10)
    gt_step: float = 0.01            # m, ground-truth sampling along capsule axes
    hexagon: Hexagon = field(default_factory=Hexagon)
    reaction: str = _PRODUCT["reaction"]  # R33: "repulsion" | "ssm" | "both" (the monitor's mode)
    ssm: object = None               # SSMConfig (None: its defaults); the robot brakes by its stopping model

    def __post_init__(self):
        if self.reaction not in LEGACY_MODES:
            raise ValueError(f"LoopConfig.reaction must be repulsion, ssm or both, got {self.reaction!r}")
        for name in ("rho", "v_max", "alpha", "control_hz", "camera_hz", "stale_periods",
                     "stop_time", "resume_time", "gt_step", "grid_delta_d"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"LoopConfig.{name} must be > 0, got {v!r}")
        if self.camera_latency is not None and not (np.isfinite(self.camera_latency) and self.camera_latency >= 0):
            raise ValueError(f"LoopConfig.camera_latency must be >= 0 s or None, got {self.camera_latency!r}")
        if self.threads is not None and not (isinstance(self.threads, int) and self.threads >= 1):
            raise ValueError(f"LoopConfig.threads must be an integer >= 1 or None (all), got {self.threads!r}")
        if self.invalid not in ("free", "unknown"):
            raise ValueError(f"LoopConfig.invalid must be 'free' or 'unknown', got {self.invalid!r}")
        if self.fusion not in ("grid", "single"):
            raise ValueError(f"LoopConfig.fusion must be 'grid' or 'single', got {self.fusion!r}")
        if self.method not in ("min", "mean", "hybrid"):
            raise ValueError(f"LoopConfig.method must be min, mean or hybrid, got {self.method!r}")

    @property
    def dt(self) -> float:
        return 1.0 / self.control_hz

    @property
    def latency(self) -> float:
        """Seconds from a frame's capture to its delivery (default one camera period)."""
        return 1.0 / self.camera_hz if self.camera_latency is None else float(self.camera_latency)


def solve_ik(robot, target: np.ndarray, q0: np.ndarray, iters: int = 500, tol: float = 1e-6) -> np.ndarray:
    """Joints that put control point 0 (the EE) at ``target`` (3,), from ``q0``: damped least squares
    with a small pull towards ``q0``; raises ``ValueError`` if the target is not reached."""
    q = np.array(q0, dtype=np.float64)
    data = robot.create_data()
    lam = 1e-2
    for _ in range(iters):
        robot.forward(q, data)
        e = target - data.cp_positions[0]
        if np.linalg.norm(e) < tol:
            return np.clip(q, robot.q_min, robot.q_max)
        J = data.cp_jacobians[0]
        dq = J.T @ np.linalg.solve(J @ J.T + lam ** 2 * np.eye(3), e)
        N = np.eye(robot.dof) - np.linalg.pinv(J) @ J
        q = np.clip(q + dq + 0.05 * N @ (q0 - q), robot.q_min, robot.q_max)
    raise ValueError(f"end effector cannot reach {np.round(target, 3).tolist()} (IK residual "
                     f"{np.linalg.norm(e):.3f} m); choose another hexagon centre/radius")


@dataclass
class LoopResult:
    """Time series of one run (T samples, one per control cycle) and the timing."""
    t: np.ndarray                 # (T,) s
    q: np.ndarray                 # (T, n) rad
    qd: np.ndarray                # (T, n) rad/s
    ee: np.ndarray                # (T, 3) m, actual EE
    ee_des: np.ndarray            # (T, 3) m, p_d(tau)
    D: np.ndarray                 # (T, m) sensed distance per control point (inf = none within rho)
    observed: np.ndarray          # (T, m) bool
    rep: np.ndarray               # (T, 3) m/s, EE repulsive velocity
    scale: np.ndarray             # (T,) SNS task scale
    override: np.ndarray          # (T,) safety override k
    gt_cp: np.ndarray             # (T, m) true distance of each control point to the obstacles
    gt_robot: np.ndarray          # (T,) true distance robot capsules <-> obstacles
    gt_robot_dyn: np.ndarray      # (T,) the same to the moving obstacles only (people, props, scripted)
    frame_age: np.ndarray         # (T, n_cam) s
    control_point_names: list[str]
    camera_ids: list[str]
    episodes: list[dict]
    timing: dict[str, float]      # wall seconds per stage
    n_frames: dict[str, int]
    excluded_capsules: list[str]
    snapshots: list = field(default_factory=list)   # (t, camera id, depth (H, W)) of the principal
    tau: np.ndarray | None = None  # (T,) s, the task's progress (its own time: = t when never slowed)
    ssm_scale: np.ndarray | None = None      # (T,) the scale the robot applied (braking included), R33
    protective_stop: np.ndarray | None = None  # (T,) bool
    ssm_margin: np.ndarray | None = None     # (T,) m, ground truth: min over points of d - S_p (ssm_truth.py)
    ssm_violation: np.ndarray | None = None  # (T,) bool
    ssm_violation_zd: np.ndarray | None = None  # (T,) bool, the stricter count with Z_d


class ClosedLoop:
    """The closed loop of one scenario on a simulated cell (module docstring).

    ``cell``: from :func:`depthguard.sim.load_cell` (``.rig`` with cameras and
    robot, ``.scene``); ``extra_obstacles``: ``t -> list[Primitive]`` scripted
    by the scenario (rendered and in the ground truth); ``dropout``: camera id
    -> time after which it delivers no more frames; ``cell_dynamic``: also the
    cell's own scripted people and props (off by default: they are scripted
    around the cell's own robot trajectory, not around this controlled robot).
    """

    def __init__(self, cell, config: LoopConfig | None = None,
                 extra_obstacles: Callable[[float], list] | None = None,
                 dropout: dict[str, float] | None = None, seed: int = 0, cell_dynamic: bool = False):
        self.cfg = cfg = config or LoopConfig()
        self.cell = cell
        rig = cell.rig
        if rig.robot is None:
            raise ValueError("the cell's rig has no robot")
        self.robot = rig.robot
        self.scene = cell.scene
        self.cell_dynamic = bool(cell_dynamic)
        self._static_meshes = [p.mesh() for p in self.scene.static]
        cams = list(rig.cameras)
        if cfg.cameras is not None:
            cams = [rig.camera(c) for c in cfg.cameras]
        principal = cfg.principal or cams[0].id
        if principal not in [c.id for c in cams]:
            raise ValueError(f"principal camera {principal!r} is not among {[c.id for c in cams]}")
        cams.sort(key=lambda c: c.id != principal)           # principal first
        if cfg.fusion == "single":
            cams = cams[:1]
        self.cams = cams
        self.principal = principal
        self._extra_fn = extra_obstacles or (lambda t: [])
        self._extra_memo: tuple[float, list] | None = None
        self.dropout = dict(dropout or {})
        for cid in self.dropout:
            if cid not in [c.id for c in cams]:
                raise ValueError(f"dropout names unknown camera {cid!r}")
        import numba
        self.threads = max(1, min(int(cfg.threads or numba.config.NUMBA_NUM_THREADS), numba.config.NUMBA_NUM_THREADS))
        # the package's one camera simulator (sources/camera_sim.py): the static scene rendered once
        # per camera, the robot (also the self-removal image, R9) and the moving obstacles per frame
        self.camera_sim = CameraSim(cams, robot=self.robot, static_meshes=self._static_meshes, seed=seed,
                                    noiseless=not cfg.noise, invalid=cfg.invalid, parallel=self.threads > 1)
        self.sims = self.camera_sim.sims
        self.hexagon = cfg.hexagon
        q_start = np.asarray(getattr(rig, "robot_q0", None) if getattr(rig, "robot_q0", None) is not None
                             else self.robot.q_home, dtype=np.float64)
        p0, _ = self.hexagon.at(0.0)
        self.q_start = solve_ik(self.robot, p0, q_start)
        self.cp_names = [c.name for c in self.robot.control_points]
        self.truth = LoopTruth(self.robot, self.scene.static, self.q_start, cfg.gt_step)
        self.excluded_caps = self.truth.excluded
        # the runtime (R29): the loop is the monitor fed by the simulator; the robot obeys its reaction
        from depthguard.runtime.monitor import warm_up
        warm_up(self.cell.rig, self.monitor_config())     # compile before any clock starts

    # ------------------------------------------------------------ set-up
    def monitor_config(self):
        """The runtime's settings for this loop (:class:`~depthguard.config.MonitorConfig`): the
        loop's rho, reaction and supervision parameters; self removal, the robot volume and the
        invalid-pixel rules the product's (R28)."""
        cfg = self.cfg
        return MonitorConfig(
            rho=cfg.rho, method=cfg.method, delta_d=cfg.grid_delta_d, principal=self.principal,
            cameras=tuple(c.id for c in self.cams), robot_offset=cfg.robot_offset,
            robot_padding=cfg.robot_padding, invalid=cfg.invalid,
            camera_hz=cfg.camera_hz, camera_stale_s=cfg.stale_periods / cfg.camera_hz,
            joints_stale_s=max(10.0 * cfg.dt, 0.01), joint_history_s=max(1.0, 3.0 * cfg.latency + 0.5),
            joint_wait_s=0.0, control_hz=cfg.control_hz, v_max=cfg.v_max, alpha=cfg.alpha,
            stop_time=cfg.stop_time, resume_time=cfg.resume_time, reaction=cfg.reaction,
            **({} if cfg.ssm is None else {"ssm": cfg.ssm}))

    # ------------------------------------------------------------ pieces
    def extra(self, t: float) -> list:
        """The scenario's scripted primitives at ``t`` (the last time's answer is kept: a camera
        frame and the ground truth of the same cycle ask for the same ``t``)."""
        memo = self._extra_memo                          # one read: the camera thread asks too
        if memo is None or memo[0] != t:
            memo = self._extra_memo = (t, list(self._extra_fn(t)))
        return memo[1]

    def obstacles_at(self, t: float) -> list:
        """Every obstacle at ``t``: the cell's static objects, its people and props if
        ``cell_dynamic``, and the scenario's scripted primitives."""
        out = list(self.scene.static)
        if self.cell_dynamic:
            out += list(self.scene.dynamic_at(t))
        return out + list(self.extra(t))

    def ground_truth(self, P: np.ndarray, q: np.ndarray, t: float) -> tuple[np.ndarray, float, float]:
        """True distances at ``t`` (:class:`~depthguard.evaluation.closed_loop.loop_truth.LoopTruth`): the control
        points ``P`` to the obstacles (0 inside), the robot's capsules (all but ``excluded_caps``)
        to every obstacle and to the moving ones alone (``<= 0`` = collision)."""
        dyn = ([] if not self.cell_dynamic else list(self.scene.dynamic_at(t))) + list(self.extra(t))
        return self.truth(P, q, dyn)

    def _simulate_frame(self, i: int, t: float, q: np.ndarray):
        """Camera ``i``'s frame captured at ``t`` with the robot at ``q`` (may run on the camera
        thread, see camera_pipeline.py): ``(measured depth, robot depth, robot render seconds,
        scene seconds)``, new arrays. The robot alone is rendered for self removal (R9) and
        combined with the static scene (rendered once) and the moving obstacles; the camera's
        noise model turns the ideal image into the measured one."""
        return tuple(self.camera_sim.shot(self.cams[i].id, t, q, self._dynamic_meshes(t), keep_robot=True))

    def _dynamic_meshes(self, t: float) -> list:
        """Meshes of everything but the static scene and the robot at ``t``."""
        dyn = list(self.scene.dynamic_at(t)) if self.cell_dynamic else []
        return [p.mesh() for p in dyn + list(self.extra(t))]

    # ------------------------------------------------------------ run
    def run(self, duration: float, progress: Callable | None = None,
            snapshot_times: tuple[float, ...] = ()) -> LoopResult:
        """Simulate ``duration`` seconds; ``progress(iterable, total)`` wraps the cycle loop (e.g. track);
        the principal camera's first frame at or after each of ``snapshot_times`` is kept."""
        cfg = self.cfg
        if not (np.isfinite(duration) and duration > 0):
            raise ValueError(f"duration must be > 0 s, got {duration!r}")
        T = int(round(duration / cfg.dt))
        steps = range(T) if progress is None else progress(range(T), T)
        timing = dict(camera_sim=0.0, self_removal=0.0, distance=0.0, reaction=0.0, ground_truth=0.0)
        import numba
        threads_before = numba.get_num_threads()
        # with latency the frames are simulated on a camera thread that takes one core
        threaded = cfg.latency > 0 and threadsafe_numba()
        n_all = numba.config.NUMBA_NUM_THREADS
        numba.set_num_threads(self.threads if cfg.threads else max(1, n_all - 1) if threaded else n_all)
        cams_sim = CameraPipeline(self._simulate_frame, [c.id for c in self.cams], cfg.latency, timing,
                                  threaded=threaded)
        from depthguard.runtime.monitor import Monitor

        # the papers' runs start in steady state (the robot on its path, frames captured at t = 0
        # delivered), so the override starts at 1; a live monitor starts at 0 (Monitor's docstring)
        mon = Monitor(self.cell.rig, self.monitor_config(), start_override=1.0)
        try:
            with mon.replay():                     # frames flushed before each cycle: one grid
                return self._run(T, steps, snapshot_times, cams_sim, timing, mon)
        finally:
            mon.close()
            cams_sim.close()
            numba.set_num_threads(threads_before)

    def _run(self, T: int, steps, snapshot_times, cams_sim: CameraPipeline, timing: dict, mon) -> LoopResult:
        """The ``T`` control cycles (module docstring, steps 1-5)."""
        cfg, robot, dt = self.cfg, self.robot, self.cfg.dt
        n, m = robot.dof, len(self.cp_names)
        cam_ids = [c.id for c in self.cams]
        nc = len(cam_ids)
        schedule = CameraSchedule(nc, cfg.camera_hz)     # the cameras' timing, the sim: source's
        period = schedule.period
        stamps = np.full(nc, -np.inf)
        depths: dict[str, np.ndarray] = {}
        n_frames = {c: 0 for c in cam_ids}
        R = {k: np.zeros(s) for k, s in dict(q=(T, n), qd=(T, n), ee=(T, 3), ee_des=(T, 3), D=(T, m),
                                               rep=(T, 3), gt_cp=(T, m), frame_age=(T, nc)).items()}
        R["observed"] = np.zeros((T, m), dtype=bool)
        for k in ("scale", "override", "gt_robot", "gt_robot_dyn", "t", "tau", "ssm_scale", "ssm_margin"):
            R[k] = np.zeros(T)
        for k in ("protective_stop", "ssm_violation", "ssm_violation_zd"):
            R[k] = np.zeros(T, dtype=bool)
        ssm_on = cfg.reaction != "repulsion"
        mcfg = mon.config
        truth_ssm = None
        if ssm_on:
            from depthguard.evaluation.closed_loop.ssm_truth import SSMTruth
            truth_ssm = SSMTruth(mcfg.ssm, dt)
        from depthguard.evaluation.closed_loop.ssm_truth import braking_deceleration
        # the package's one obeying robot (sim/obeying_robot.py), here the papers' SNS on the task
        follower = TaskFollower(robot, self.hexagon, self.q_start, cfg.k_p, cfg.k_posture,
                                brake=braking_deceleration(mcfg.ssm) if ssm_on else None)
        bot = ObeyingRobot(follower, n)
        table, pstop = None, False
        q = bot.q
        wall0 = time.perf_counter()
        snaps_todo = sorted(float(x) for x in snapshot_times)
        snapshots = []
        n_distance, next_distance = 0, 0.0
        new_frames: set[str] = set()            # cameras with a frame the monitor has not had yet
        cams_sim.start(q, [i for i, c in enumerate(cam_ids) if not (c in self.dropout and self.dropout[c] <= 0.0)])
        for j in range(int(np.ceil((cfg.latency + period) / dt)), 0, -1):
            mon.push_joints(-j * dt, q)                  # the robot stood still while the first frames were taken
        for k in steps:
            t = k * dt
            # 1. vision: capture the frames due now, deliver those whose latency has passed
            for i, cid in enumerate(cam_ids):
                if not schedule.due(i, t):
                    continue
                schedule.take(i, t)
                if cid in self.dropout and t >= self.dropout[cid]:
                    continue
                cams_sim.capture(i, t, q)
            for i, cid, t_cap, _q_cap, d, _rd in cams_sim.deliver(t):
                depths[cid] = d
                stamps[i] = t_cap
                n_frames[cid] += 1
                new_frames.add(cid)
                if i == 0 and snaps_todo and t_cap >= snaps_todo[0] - 1e-9:
                    snaps_todo.pop(0)
                    snapshots.append((t_cap, cid, d.copy()))
            # 2-4. the runtime: joints and the frames delivered now in, the reaction out (R29)
            t0 = time.perf_counter()
            data = follower.forward(q)
            P = data.cp_positions
            due = k == 0 or cfg.distance_hz is None or t + 1e-9 >= next_distance
            if due:                                    # else: hold the last cycle's reaction
                mon.push_joints(t, q)
                for cid in new_frames:                 # the frames delivered in this cycle,
                    mon.push_frame(Frame(cid, depths[cid], float(stamps[cam_ids.index(cid)])))
                if new_frames:                         # fused before this cycle's distances
                    mon.flush()
                    new_frames = set()
                react = mon.step(t, q, qd=follower.qd_nominal) if ssm_on else mon.step(t, q)
                D, obs = react.distance[:m], react.observed[:m]
                table, pstop = react.ssm, react.protective_stop
                bot.obey(react)                        # R13, R14, joint limits, times k; R33's scale
                n_distance += 1
                if cfg.distance_hz is not None:
                    next_distance = t + 1.0 / cfg.distance_hz
            t1 = time.perf_counter()
            timing["distance"] += t1 - t0
            ages = t - stamps
            # the robot obeys: EE task scaled by the override, plus the repulsion, within the limits
            bot.command(dt)
            qd_c = bot.qd
            t2 = time.perf_counter()
            timing["reaction"] += t2 - t1
            # record (before integrating: state at t)
            R["t"][k] = t
            R["q"][k] = q
            R["qd"][k] = qd_c
            R["tau"][k] = bot.tau
            R["ssm_scale"][k] = follower.applied if ssm_on else 1.0
            R["protective_stop"][k] = pstop
            R["ee"][k] = P[0]
            R["ee_des"][k] = follower.target
            R["D"][k] = D
            R["observed"][k] = obs
            R["rep"][k] = bot.repulsion
            R["scale"][k] = follower.task_scale
            R["override"][k] = bot.override
            R["frame_age"][k] = ages
            # 5. ground truth
            R["gt_cp"][k], R["gt_robot"][k], R["gt_robot_dyn"][k] = self.ground_truth(P, q, t)
            if truth_ssm is not None:
                Xdot = np.einsum("mij,j->mi", data.cp_jacobians, qd_c)
                moving = ([] if not self.cell_dynamic else list(self.scene.dynamic_at(t))) + list(self.extra(t))
                standing = float(np.abs(qd_c).max()) < 1e-9
                R["ssm_margin"][k], R["ssm_violation"][k], R["ssm_violation_zd"][k] = truth_ssm.check(
                    P, Xdot, moving, table, pstop or standing)
            timing["ground_truth"] += time.perf_counter() - t2
            # integrate
            bot.move(dt)
            q = bot.q
        timing["total"] = time.perf_counter() - wall0
        timing["distance_cycles"] = n_distance
        return LoopResult(t=R["t"], q=R["q"], qd=R["qd"], ee=R["ee"], ee_des=R["ee_des"], D=R["D"],
                          observed=R["observed"], rep=R["rep"], scale=R["scale"], override=R["override"],
                          gt_cp=R["gt_cp"], gt_robot=R["gt_robot"], gt_robot_dyn=R["gt_robot_dyn"], frame_age=R["frame_age"],
                          control_point_names=list(self.cp_names), camera_ids=cam_ids,
                          episodes=mon.episodes, timing=timing, n_frames=n_frames,
                          excluded_capsules=list(self.excluded_caps), snapshots=snapshots, tau=R["tau"],
                          ssm_scale=R["ssm_scale"], protective_stop=R["protective_stop"],
                          ssm_margin=R["ssm_margin"], ssm_violation=R["ssm_violation"],
                          ssm_violation_zd=R["ssm_violation_zd"])


def _depth_span(cam, workspace) -> tuple[float, float]:
    """Depth range of the workspace box in ``cam`` (clipped to the camera's range) for the grid (R10)."""
    return workspace.depth_span(cam)
