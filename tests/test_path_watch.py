"""Path watch (R37): the limit lets the robot stop short of a blocked segment, and lifts when it clears.

Truth: the SSM stopping model written out by hand (``v T_r + v t_b + v^2 / (2 a)``, the
deceleration model of the settings) and a simulated point running along the path at the limited
speed and braking at the deceleration once the limit asks for 0 — it must come to rest before the
blocked segment's start (less the margin), and with the blocked segment gone the limit is 1.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from depthguard.control.path_check import PathVerdict, SegmentVerdict
from depthguard.control.path_watch import PathWatch, segment_travel
from depthguard.control.ssm_config import SSMConfig

N = 41
STAMPS = np.linspace(0.0, 4.0, N)
TRAVEL = np.full(N - 1, 0.025)          # 1 m over 4 s: 0.25 m/s at scale 1


def verdict(blocked: dict) -> PathVerdict:
    return PathVerdict(tuple(SegmentVerdict(i, STAMPS[i], STAMPS[i + 1], blocked.get(i, "safe"))
                             for i in range(N - 1)))


def test_limit_matches_the_stopping_model_by_hand():
    cfg = SSMConfig()
    w = PathWatch(cfg, reaction_time=0.15, margin=0.05)
    v = 0.25
    need = v * 0.15 + v * cfg.brake_delay_s + v * v / (2 * cfg.deceleration)
    assert math.isclose(w.needed(v), need, rel_tol=1e-12)
    blocked = verdict({30: "unsafe"})
    far = w.limit(blocked, STAMPS, TRAVEL, 0.0, v)             # 0.75 m ahead
    assert far.limit == 1.0 and far.segment == 30 and math.isclose(far.distance, 0.75)
    # where the room left equals the need at full speed, the limit starts to fall
    L_edge = need + 0.05
    t_edge = STAMPS[30] - L_edge / 0.25
    assert w.limit(blocked, STAMPS, TRAVEL, t_edge - 0.05, v).limit == 1.0
    mid = w.limit(blocked, STAMPS, TRAVEL, STAMPS[30] - (0.05 + v * 0.15 + (need - v * 0.15) / 2) / 0.25, v)
    assert 0.0 < mid.limit < 1.0 and "segment 30" in mid.reason
    brake = mid.limit * v * cfg.brake_delay_s + (mid.limit * v) ** 2 / (2 * cfg.deceleration)
    assert math.isclose(v * 0.15 + brake, mid.distance - 0.05, rel_tol=1e-6)
    assert w.limit(blocked, STAMPS, TRAVEL, STAMPS[30] - 0.01, v).limit == 0.0
    assert w.limit(blocked, STAMPS, TRAVEL, STAMPS[30] + 0.05, v).limit == 0.0     # inside it


@pytest.mark.parametrize("block_at", [12, 20, 35])
def test_a_point_obeying_the_limit_stops_before_the_blocked_segment_and_resumes(block_at):
    cfg = SSMConfig()
    T_r = 0.1
    w = PathWatch(cfg, reaction_time=T_r, margin=0.05)
    v_full = 0.25
    dt = 0.002
    s = 0.0                               # arc length of the point, m; path time = s / v_full
    speed = v_full
    blocked = verdict({block_at: "unsafe"})
    pending = []                          # limits applied after the reaction time
    t = 0.0
    applied = 1.0                         # running at full speed when the segment turns unsafe
    assert 0.025 * block_at - 0.05 >= w.needed(v_full)        # it can still stop in time
    for _ in range(int(6.0 / dt)):
        lim = w.limit(blocked, STAMPS, TRAVEL, s / v_full, v_full).limit
        pending.append((t + T_r, lim))
        while pending and pending[0][0] <= t:
            applied = pending.pop(0)[1]
        target = applied * v_full
        if target >= speed:
            speed = target
        else:                              # the robot brakes at the settings' deceleration
            speed = max(target, speed - cfg.deceleration * dt)
        s += speed * dt
        t += dt
    assert s <= 0.025 * block_at - 0.05 + 2 * v_full * dt, (s, 0.025 * block_at)     # 1 mm: the simulation steps
    assert s > 0.025 * block_at - 0.2          # and it did not stop needlessly early
    clear = w.limit(verdict({}), STAMPS, TRAVEL, s / v_full, v_full)
    assert clear.limit == 1.0 and clear.reason == ""


def test_maybe_blocks_only_when_asked():
    v = verdict({10: "maybe"})
    assert PathWatch(SSMConfig(), 0.1).limit(v, STAMPS, TRAVEL, STAMPS[10] - 0.01, 0.25).limit == 1.0
    w = PathWatch(SSMConfig(), 0.1, stop_on=("unsafe", "maybe"))
    assert w.limit(v, STAMPS, TRAVEL, STAMPS[10] - 0.01, 0.25).limit == 0.0


def test_segment_travel_is_the_fastest_capsule_end():
    from depthguard.sim import load_cell

    robot = load_cell("ur3-cell").rig.robot
    q0 = np.asarray(load_cell("ur3-cell").rig.robot_q0, float)
    Q = np.stack([q0, q0 + np.r_[0.1, 0, 0, 0, 0, 0]])
    tr = segment_travel(robot, Q)
    ends = lambda q: np.concatenate([np.stack(c.segment()) for c in robot.collision_capsules(q)])
    assert math.isclose(tr[0], np.max(np.linalg.norm(ends(Q[1]) - ends(Q[0]), axis=1)), rel_tol=1e-9)


def test_the_registered_policy_stops_a_robot_short_of_the_blocked_segment_and_resumes():
    """``path_watch`` from the registry (issue 28) on ur3-cell: the robot follows a 41-waypoint path
    at the policy's scale (applied after the policy's own reaction time, braking at the SSM
    deceleration); segment 30 turns unsafe. Truth: the fastest point's travel along the path
    (capsule axis ends, :func:`segment_travel`) between where the robot rests and segment 30."""
    from depthguard.control.policy import Cycle, PolicySetup, policy_class
    from depthguard.sim import load_cell

    rig = load_cell("ur3-cell").rig
    cfg = rig.monitor.with_changes(reactions=("repulsion", "path_watch"))
    pol = policy_class("path_watch")(PolicySetup(cfg, rig.robot, (), ("ee",)))
    q0 = np.asarray(rig.robot_q0, float)
    Q = np.linspace(q0, q0 + np.r_[1.0, 0, 0, 0, 0, 0], N)
    path = pol.set_path(STAMPS, Q)
    travel = segment_travel(rig.robot, Q)
    pol.set_verdict(verdict({30: "unsafe"}), path)
    dt, T_r = cfg.dt, pol.watch.reaction_time
    tau, rate, pending, applied = 0.0, 1.0, [], 1.0     # path time, its rate (scale) and the applied limit
    z = np.zeros(1)
    parts = []
    for k in range(int(6.0 / dt)):
        t = k * dt
        q = Q[0] + (tau / STAMPS[-1]) * (Q[-1] - Q[0])
        part = pol.update(Cycle(t, dt, q, None, z, np.zeros((1, 3)), np.ones(1, bool), np.zeros((1, 3)),
                                np.zeros((1, 3, 6)), 0.0, 1.0, {}, cfg))
        parts.append(part)
        pending.append((t + T_r, part.scale))
        while pending and pending[0][0] <= t:
            applied = pending.pop(0)[1]
        v_full = float(np.max(path.speed))
        rate = applied if applied >= rate else max(applied, rate - cfg.ssm.deceleration * dt / v_full)
        tau = min(tau + rate * dt, STAMPS[-1])
    i = int(np.searchsorted(STAMPS, tau, side="right")) - 1
    left = (STAMPS[i + 1] - tau) / (STAMPS[i + 1] - STAMPS[i]) * travel[i] + travel[i + 1:30].sum()
    assert tau < STAMPS[30] and left >= pol.watch.margin - 2e-3, (tau, left)
    assert left < 0.3                                            # it did not stop needlessly early
    assert parts[-1].stop and "segment 30" in parts[-1].reasons["path_watch"]
    pol.set_verdict(verdict({}), path)                           # the segment clears: it resumes
    q = Q[0] + (tau / STAMPS[-1]) * (Q[-1] - Q[0])
    free = pol.update(Cycle(6.0, dt, q, None, z, np.zeros((1, 3)), np.ones(1, bool), np.zeros((1, 3)),
                            np.zeros((1, 3, 6)), 0.0, 1.0, {}, cfg))
    assert free.scale == 1.0 and not free.stop and not free.reasons
