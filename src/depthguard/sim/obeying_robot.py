"""The simulated robot that obeys the monitor's reaction, defined once (R13, R14, R29, R33).

One object, :class:`ObeyingRobot`, is the robot of every simulation that closes the loop:
the ``sim:`` source's world (:class:`depthguard.sources.sim_source.SimWorld`) and the closed
loop of ``depthguard run`` / ``make demo``
(:class:`depthguard.evaluation.closed_loop.loop.ClosedLoop`). It takes each reaction
(:meth:`ObeyingRobot.obey`: the speed override ``k``, the end effector's repulsion (3,) m/s
(R13), the joint-velocity box ``qd_min`` / ``qd_max`` (dof,) rad/s (R14, already times
``k``), the SSM scale (R33)) and moves in ticks of ``dt`` s: :meth:`~ObeyingRobot.command`
(the joint velocity at the present state) then :meth:`~ObeyingRobot.move` (integrate).

What it does with the reaction is its controller's (model apart from the state, as the
robot's model/data split): a pluggable object with ``start(bot)``, ``command(bot, dt)`` and
``move(bot, dt)``. Two are given:

- :class:`PathFollower`: the cell's scripted joint path ``q(τ)``, its path time ``τ``
  advancing at the largest rate in ``[0, s]`` that keeps every joint within the box, ``s`` the
  reaction's speed scale (the override times the SSM and other policies' scales; a joint
  path cannot follow the end effector's repulsion, which it ignores);
- :class:`TaskFollower`: the papers' robot (Flacco 2012 §V, 2015 §VIII): an end-effector
  task ``p_d(τ)`` (e.g. the hexagon), ``ẋ_c = k·ṗ_d(τ) + K_p (p_d(τ) − x) + ẋ_rep``, the joint
  velocity from SNS (Flacco 2015 T-RO, :func:`depthguard.control.sns.sns_velocity`) within
  the box with a posture term in the null space, ``τ += s·k·dt``; with ``brake`` (m/s², the
  SSM's stopping model) it also applies the SSM scale, braking no harder than that.

State (``bot.``): ``q`` (dof,) rad, ``tau`` s of path time, ``rate`` = dτ/dt of the last
tick (0 = standing), ``qd`` (dof,) rad/s commanded; the run's figures ``rate_min``,
``slowed_s`` (rate below 0.95), ``stopped_s`` (below 0.01).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

__all__ = ["ObeyingRobot", "PathFollower", "TaskFollower"]


class ObeyingRobot:
    """The simulated robot's state and the reaction it obeys (module docstring).

    controller : :class:`PathFollower` | :class:`TaskFollower` (or any object with
        ``start(bot)``, ``command(bot, dt)``, ``move(bot, dt)``).
    dof : joints. tau : the path time it starts at (s).
    """

    def __init__(self, controller, dof: int, tau: float = 0.0):
        self.controller = controller
        self.dof = int(dof)
        self.tau = float(tau)
        self.override = 1.0                      # k of the newest reaction
        self.speed_scale = 1.0                   # k times the reaction policies' scales (SSM, R33)
        self.qd_min: np.ndarray | None = None    # (dof,) rad/s, None before a reaction
        self.qd_max: np.ndarray | None = None
        self.repulsion = np.zeros(3)             # m/s, the end effector's (R13)
        self.ssm_scale = 1.0                     # R33
        self.rate = 1.0                          # dτ/dt of the last tick
        self.rate_min = 1.0
        self.slowed_s = 0.0
        self.stopped_s = 0.0
        self.qd = np.zeros(self.dof)
        self.q = np.zeros(self.dof)
        controller.start(self)

    def obey(self, reaction) -> None:
        """Take a reaction (a :class:`~depthguard.runtime.result.Reaction` or anything with its
        ``override``, ``qd_min``, ``qd_max``; ``repulsion`` and ``ssm_scale`` optional)."""
        self.override = float(reaction.override)
        self.speed_scale = float(getattr(reaction, "speed_scale", reaction.override))
        self.qd_min = np.asarray(reaction.qd_min, dtype=np.float64)
        self.qd_max = np.asarray(reaction.qd_max, dtype=np.float64)
        rep = getattr(reaction, "repulsion", None)
        self.repulsion = np.zeros(3) if rep is None else np.asarray(rep, dtype=np.float64)
        self.ssm_scale = float(getattr(reaction, "ssm_scale", 1.0))

    def command(self, dt: float) -> None:
        """The controller's command at the present state for a tick of ``dt`` s (sets ``qd``,
        ``rate`` and the controller's own terms)."""
        self.controller.command(self, dt)

    def move(self, dt: float) -> None:
        """Integrate the command over ``dt`` s and count the run's figures."""
        self.controller.move(self, dt)
        self.rate_min = min(self.rate_min, self.rate)
        self.slowed_s += dt if self.rate < 0.95 else 0.0
        self.stopped_s += dt if self.rate < 0.01 else 0.0

    def step(self, dt: float) -> np.ndarray:
        """One tick: command, then move; the new ``q``."""
        self.command(dt)
        self.move(dt)
        return self.q

    def coast(self, ticks: int, dt: float) -> None:
        """Jump ``ticks`` ticks ahead at the last tick's rate (a world far behind its clock)."""
        self.tau += self.rate * ticks * dt
        self.controller.start(self, keep_tau=True)


class PathFollower:
    """The scripted joint path ``path_q(τ) -> (dof,)``, slowed to obey the reaction (module docstring)."""

    def __init__(self, path_q: Callable[[float], np.ndarray]):
        self.path_q = path_q

    def start(self, bot: ObeyingRobot, keep_tau: bool = False) -> None:
        bot.q = self.path_q(bot.tau)

    def command(self, bot: ObeyingRobot, dt: float) -> None:
        """``rate``: the largest scale in ``[0, s]`` of the path's speed at ``τ`` that keeps every
        joint within the reaction's velocity limits (R14); ``s`` is the reaction's
        ``speed_scale`` (the override times the policies' scales, R33), the override where a
        reaction has none."""
        s = bot.speed_scale
        if bot.qd_min is None or s <= 0.0:
            bot.rate = max(s, 0.0)
            return
        qd = self.qd_nominal(bot, dt)
        for v, lo, hi in zip(qd, bot.qd_min, bot.qd_max):
            if v > 1e-12:
                s = min(s, max(hi, 0.0) / v)
            elif v < -1e-12:
                s = min(s, max(-lo, 0.0) / -v)
        bot.rate = max(s, 0.0)

    def qd_nominal(self, bot: ObeyingRobot, dt: float) -> np.ndarray:
        """(dof,) rad/s: the path's joint velocity at scale 1 at ``bot.tau``, over a tick of ``dt``
        s — what the reaction's speed scale scales (R33)."""
        return (self.path_q(bot.tau + dt) - self.path_q(bot.tau)) / dt

    def move(self, bot: ObeyingRobot, dt: float) -> None:
        bot.tau += bot.rate * dt
        q = self.path_q(bot.tau)
        bot.qd = (q - bot.q) / dt
        bot.q = q


class TaskFollower:
    """The papers' robot: an end-effector task followed by SNS within the reaction's box
    (module docstring).

    robot : :class:`~depthguard.robot.RobotModel`; task : ``task.at(τ) -> (p_d (3,) m,
    ṗ_d (3,) m/s)``; q_start : (dof,) rad, the start and rest posture; k_p : 1/s, the gain
    on the end effector's position error; k_posture : 1/s, the null-space pull to
    ``q_start``; brake : m/s², the SSM's braking deceleration when the robot applies the SSM
    scale (R33), None when it does not.

    Its own terms each tick: ``task_scale`` (SNS's ``s``), ``target`` (p_d (3,)),
    ``applied`` (the SSM scale applied, braking included), ``qd_nominal`` (the command before
    it, which the monitor's SSM takes the next cycle).
    """

    def __init__(self, robot, task, q_start, k_p: float, k_posture: float, brake: float | None = None):
        from depthguard.control.sns import SNSWorkspace

        self.robot, self.task = robot, task
        self.q_start = np.asarray(q_start, dtype=np.float64)
        self.k_p, self.k_posture, self.brake = float(k_p), float(k_posture), brake
        self.data = robot.create_data()
        self._at: np.ndarray | None = None        # the joints self.data was computed at
        self._ws = SNSWorkspace(3, robot.dof)
        self.task_scale, self.applied = 1.0, 1.0
        self.target = np.zeros(3)
        self.qd_nominal = np.zeros(robot.dof)

    def start(self, bot: ObeyingRobot, keep_tau: bool = False) -> None:
        if not keep_tau:
            bot.q = self.q_start.copy()

    def forward(self, q: np.ndarray):
        """The robot's data (control points, Jacobians) at ``q``, computed once per pose."""
        if self._at is None or not np.array_equal(self._at, q):
            self.robot.forward(q, self.data)
            self._at = np.array(q, dtype=np.float64, copy=True)
        return self.data

    def command(self, bot: ObeyingRobot, dt: float) -> None:
        from depthguard.control.sns import sns_velocity

        data = self.forward(bot.q)
        lo = -self.robot.qd_max if bot.qd_min is None else bot.qd_min
        hi = self.robot.qd_max if bot.qd_max is None else bot.qd_max
        k = bot.override
        p_d, v_d = self.task.at(bot.tau)
        xd = k * v_d + self.k_p * (p_d - data.cp_positions[0])
        xc = xd + bot.repulsion
        r = sns_velocity(data.cp_jacobians[0], xc, lo, hi, qd0=self.k_posture * (self.q_start - bot.q),
                         workspace=self._ws)
        qd = r.qd
        if self.brake is not None:          # R33: the robot obeys the scale, braking at most by its model
            self.qd_nominal = r.qd.copy()
            v_peak = float(np.sqrt((np.einsum("mij,j->mi", data.cp_jacobians, r.qd) ** 2).sum(axis=1)).max())
            floor = self.applied - self.brake * dt / v_peak if v_peak > 0 else 0.0
            self.applied = min(1.0, max(bot.ssm_scale, floor))
            qd = self.applied * r.qd
        self.task_scale, self.target = r.scale, p_d
        bot.qd = qd
        bot.rate = r.scale * k * (self.applied if self.brake is not None else 1.0)

    def move(self, bot: ObeyingRobot, dt: float) -> None:
        bot.q = bot.q + bot.qd * dt
        bot.tau += bot.rate * dt
