"""The one simulated robot that obeys the reaction (sim/obeying_robot.py): its two controllers
against analytic truths, and both simulations (the sim: source, the closed loop) driving it."""

from types import SimpleNamespace

import numpy as np
import pytest

from depthguard.robot import load_robot
from depthguard.sim.obeying_robot import ObeyingRobot, PathFollower, TaskFollower


def reaction(k, lo, hi, rep=(0.0, 0.0, 0.0), ssm_scale=1.0):
    return SimpleNamespace(override=k, qd_min=np.asarray(lo, float), qd_max=np.asarray(hi, float),
                           repulsion=np.asarray(rep, float), ssm_scale=ssm_scale)


def test_a_linear_path_moves_at_the_largest_rate_the_box_allows():
    a, b = np.array([0.1, -0.2, 0.3]), np.array([0.5, -0.25, 0.0])     # q(tau) = a + b tau, rad/s at rate 1
    bot = ObeyingRobot(PathFollower(lambda tau: a + b * tau), dof=3)
    dt = 0.002
    # box: joint 0 may go 0.2 rad/s up, joint 1 0.05 down; joint 2 does not move -> rate = min(0.4, 0.2)
    bot.obey(reaction(0.9, [-1, -0.05, -1], [0.2, 1, 0.0]))
    q = bot.step(dt)
    assert bot.rate == pytest.approx(min(0.2 / 0.5, 0.05 / 0.25))
    np.testing.assert_allclose(q, a + b * bot.rate * dt, atol=1e-12)
    np.testing.assert_allclose(bot.qd, b * bot.rate, atol=1e-9)            # within the box
    assert np.all(bot.qd <= [0.2, 1, 0.0 + 1e-12]) and np.all(bot.qd >= [-1, -0.05 - 1e-12, -1])
    bot.obey(reaction(0.1, [-1, -1, -1], [1, 1, 1]))                      # the override binds
    bot.step(dt)
    assert bot.rate == pytest.approx(0.1)
    bot.obey(reaction(0.8, [-1, 0.0, -1], [1, 1, 1]))                     # joint 1 may not go down: stop
    tau = bot.tau
    for _ in range(10):
        bot.step(dt)
    assert bot.rate == 0.0 and bot.tau == tau and bot.stopped_s == pytest.approx(10 * dt)
    assert bot.rate_min == 0.0 and bot.slowed_s == pytest.approx(12 * dt)


def test_the_path_follower_obeys_the_speed_scale_of_the_ssm_and_other_policies():
    """A reaction's ``speed_scale`` (the override times the policies' scales, R33) is what the
    path's robot moves at: an SSM scale of 0.25 under an override of 1 quarters its rate; a
    protective stop (speed scale 0, override 1) stands it still."""
    a, b = np.zeros(2), np.array([0.1, -0.1])
    bot = ObeyingRobot(PathFollower(lambda tau: a + b * tau), dof=2)
    free = ([-9, -9], [9, 9])
    r = reaction(1.0, *free, ssm_scale=0.25)
    r.speed_scale = 0.25
    bot.obey(r)
    tau = bot.tau
    bot.step(0.002)
    assert bot.rate == pytest.approx(0.25) and bot.tau - tau == pytest.approx(0.25 * 0.002)
    r.speed_scale = 0.0
    bot.obey(r)
    tau = bot.tau
    for _ in range(5):
        bot.step(0.002)
    assert bot.rate == 0.0 and bot.tau == tau
    bot.obey(reaction(0.6, *free))              # a reaction without a speed scale: its override
    bot.step(0.002)
    assert bot.rate == pytest.approx(0.6)


class Line:
    """p_d(tau) = p0 + v tau (the task), ṗ_d = v."""

    def __init__(self, p0, v):
        self.p0, self.v = np.asarray(p0, float), np.asarray(v, float)

    def at(self, tau):
        return self.p0 + self.v * tau, self.v.copy()


def test_the_task_follower_tracks_its_task_within_the_box_and_stops_on_zero_override():
    robot = load_robot("lwr4")
    q0 = np.array([0.0, 0.5, 0.0, -1.2, 0.0, 0.6, 0.0])
    data = robot.create_data()
    robot.forward(q0, data)
    task = Line(data.cp_positions[0].copy(), [0.0, 0.05, 0.0])                    # 5 cm/s sideways
    f = TaskFollower(robot, task, q0, k_p=5.0, k_posture=1.0)
    bot = ObeyingRobot(f, robot.dof)
    box = np.full(robot.dof, 1.0)
    dt = 0.002
    for _ in range(500):                                                   # 1 s
        bot.obey(reaction(1.0, -box, box))
        bot.command(dt)
        J = f.forward(bot.q).cp_jacobians[0]
        assert np.all(np.abs(bot.qd) <= 1.0 + 1e-9)
        # SNS: the end effector moves at s times the commanded task velocity (independent: J qd)
        xc = task.v + 5.0 * (f.target - f.data.cp_positions[0])
        np.testing.assert_allclose(J @ bot.qd, f.task_scale * xc, atol=1e-7)
        bot.move(dt)
    robot.forward(bot.q, data)
    np.testing.assert_allclose(data.cp_positions[0], task.at(bot.tau)[0], atol=2e-3)   # tracked
    assert bot.tau == pytest.approx(1.0)
    tau = bot.tau
    for _ in range(5):                                                     # override 0: the path halts
        bot.obey(reaction(0.0, -box * 0.0, box * 0.0))
        bot.step(dt)
    assert bot.tau == tau and np.all(bot.qd == 0.0)


def test_the_sim_source_and_the_closed_loop_drive_the_one_robot():
    from depthguard.sources.sim_source import SimWorld

    world = SimWorld("flacco-cell", alone=True, noiseless=True)
    assert isinstance(world.robot_sim, ObeyingRobot) and isinstance(world.robot_sim.controller, PathFollower)
    dof = world.robot.dof
    world.advance(0.0)
    world.on_reaction(reaction(0.5, -np.ones(dof), np.ones(dof)))
    world.advance(0.1)
    assert world.scale == pytest.approx(0.5) and world.robot_sim.tau == pytest.approx(0.05)
    np.testing.assert_allclose(world.history.latest()[1], world.scene.robot_q(0.05), atol=1e-12)
