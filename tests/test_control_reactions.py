"""Reactions (R13, R14) and SNS: hand-computed expectations and an LP check."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import linprog

from depthguard.control.joint_limits import combine_limits, constraint_limits, position_limits
from depthguard.control.repulsion import repulsive_magnitude, repulsive_velocity, risk
from depthguard.control.sns import SNSWorkspace, sns_velocity, sns_velocity_numpy, task_scaling_factor

RHO, VMAX, ALPHA = 0.4, 1.5, 5.0


# ------------------------------------------------------------------ R13 repulsion
def test_repulsive_magnitude_hand_values():
    # v(0) = 1.5 / (1 + e^-5) = 1.48996..., v(rho/2) = Vmax/2, v(rho) = 1.5 / (1 + e^5) = 0.0100393...
    v = repulsive_magnitude(np.array([0.0, RHO / 2, RHO, np.inf]), RHO, VMAX, ALPHA)
    assert v[0] == pytest.approx(1.5 / (1 + math.exp(-5)), rel=1e-12)
    assert v[0] == pytest.approx(1.48996, abs=1e-5)
    assert v[1] == pytest.approx(0.75, rel=1e-12)
    assert v[2] == pytest.approx(0.0100393, abs=1e-7)       # small, not zero (the step at rho)
    assert v[3] == 0.0                                       # inf: nothing within rho
    d = np.linspace(0, RHO, 101)
    assert np.all(np.diff(repulsive_magnitude(d, RHO, VMAX, ALPHA)) < 0)


def test_repulsion_points_away_from_obstacle():
    rng = np.random.default_rng(3)
    P = rng.uniform(-1, 1, (50, 3))
    O = P + rng.normal(size=(50, 3)) * 0.1
    D = np.linalg.norm(O - P, axis=1)
    V = (O - P) / D[:, None]                       # towards the obstacle (distance contract)
    rep = repulsive_velocity(D, V, RHO, VMAX, ALPHA)
    away = (P - O) / D[:, None]
    mag = np.linalg.norm(rep, axis=1)
    np.testing.assert_allclose(rep, mag[:, None] * away, atol=1e-12)
    np.testing.assert_allclose(mag, VMAX / (1 + np.exp((2 * D / RHO - 1) * ALPHA)), rtol=1e-12)
    # D = inf -> exactly zero whatever V holds
    r = repulsive_velocity(np.array([np.inf]), np.array([[np.nan, np.nan, np.nan]]), RHO, VMAX, ALPHA)
    assert np.all(r == 0.0)


def test_reaction_bad_input():
    with pytest.raises(ValueError, match="rho"):
        risk(0.1, -1.0, ALPHA)
    with pytest.raises(ValueError, match="NaN or negative"):
        risk(np.array([0.1, np.nan]), RHO, ALPHA)
    with pytest.raises(ValueError, match="shape"):
        repulsive_velocity(np.array([0.1, 0.2]), np.zeros((3, 3)), RHO, VMAX, ALPHA)


# ------------------------------------------------------------------ R14 joint limits
def test_joint_limits_from_one_constraint_hand():
    # four joints; columns of J_C: +x, -y, 0 (joint beyond the link), -x
    J = np.array([[[1.0, 0.0, 0.0, -1.0],
                   [0.0, -1.0, 0.0, 0.0],
                   [0.0, 0.0, 0.0, 0.0]]])
    V = np.array([[0.6, -0.8, 0.0]])
    D = np.array([RHO / 2])                       # f = 1/2 exactly
    qd_max = np.array([1.0, 2.0, 3.0, 4.0])
    lo, hi = constraint_limits(J, D, V, qd_max, RHO, ALPHA)
    # s = J^T V f = (0.3, 0.4, 0, -0.3): joints 0, 1 capped above at Vmax/2, joint 3 below, joint 2 free
    np.testing.assert_allclose(hi, [0.5, 1.0, 3.0, 4.0])
    np.testing.assert_allclose(lo, [-1.0, -2.0, -3.0, -2.0])
    # no obstacle within rho: the plain speed limits
    lo, hi = constraint_limits(J, np.array([np.inf]), np.full((1, 3), np.nan), qd_max, RHO, ALPHA)
    np.testing.assert_array_equal(hi, qd_max)
    np.testing.assert_array_equal(lo, -qd_max)


def test_joint_limits_tightest_over_constraints():
    J = np.zeros((2, 3, 2))
    J[:, 0, 0] = 1.0                               # joint 0 moves both points along +x
    J[:, 1, 1] = 1.0                               # joint 1 along +y
    V = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    D = np.array([0.3, 0.1])
    f = 1 / (1 + np.exp((2 * D / RHO - 1) * ALPHA))
    lo, hi = constraint_limits(J, D, V, np.array([1.0, 1.0]), RHO, ALPHA)
    assert hi[0] == pytest.approx(1 - f[0]) and lo[0] == -1.0
    assert lo[1] == pytest.approx(-(1 - f[1])) and hi[1] == 1.0
    # combined with a box from position limits
    plo, phi = position_limits([0.0, 0.99], [-1, -1], [1, 1], [1.0, 1.0], dt=0.002)
    assert phi[1] == 1.0                                   # (1 - 0.99) / 0.002 = 5 > speed limit
    lo2, hi2 = combine_limits((lo, hi), (plo, phi))
    np.testing.assert_allclose(hi2, np.minimum(hi, phi))


def test_position_limits_hand():
    lo, hi = position_limits([0.0, 0.999, -1.2], [-1, -1, -1], [1, 1, 1], [2.0, 2.0, 2.0], dt=0.002)
    np.testing.assert_allclose(hi, [2.0, 0.5, 2.0])               # (1 - 0.999) / 0.002 = 0.5
    np.testing.assert_allclose(lo, [-2.0, -2.0, 0.0])     # beyond q_min: may not go further out
    with pytest.raises(ValueError, match="dt"):
        position_limits([0.0], [-1], [1], [1.0], dt=0.0)


# ------------------------------------------------------------------ SNS
def _lp_scale(J, xd, lo, hi):
    """max s in [0, 1] s.t. J qd = s xd, lo <= qd <= hi (the independent truth)."""
    m, n = J.shape
    c = np.zeros(n + 1)
    c[-1] = -1.0
    res = linprog(c, A_eq=np.hstack([J, -xd[:, None]]), b_eq=np.zeros(m),
                  bounds=list(zip(lo, hi)) + [(0.0, 1.0)], method="highs")
    assert res.status == 0
    return res.x[-1]


def test_sns_keeps_feasible_task_exactly():
    rng = np.random.default_rng(0)
    J = rng.normal(size=(3, 7))
    xd = np.array([0.1, -0.2, 0.05])
    lo, hi = -np.ones(7), np.ones(7)
    r = sns_velocity(J, xd, lo, hi)
    assert r.scale == 1.0 and not r.saturated.any()
    np.testing.assert_allclose(J @ r.qd, xd, atol=1e-12)
    np.testing.assert_allclose(r.qd, np.linalg.pinv(J) @ xd, atol=1e-12)   # min-norm when inside the box
    # a tight joint: the task is still feasible, SNS saturates and keeps it exactly
    pinv_q = np.linalg.pinv(J) @ xd
    k = int(np.argmax(np.abs(pinv_q)))
    hi2, lo2 = hi.copy(), lo.copy()
    if pinv_q[k] > 0:
        hi2[k] = 0.5 * pinv_q[k]
    else:
        lo2[k] = 0.5 * pinv_q[k]
    r = sns_velocity(J, xd, lo2, hi2)
    assert r.scale == 1.0 and r.saturated[k]
    np.testing.assert_allclose(J @ r.qd, xd, atol=1e-12)
    assert np.all(r.qd <= hi2 + 1e-12) and np.all(r.qd >= lo2 - 1e-12)


def test_sns_scales_infeasible_task_hand():
    # J = [1 1], xd = 3, |qd_i| <= 1: the best is qd = (1, 1), s = 2/3
    r = sns_velocity(np.array([[1.0, 1.0]]), np.array([3.0]), -np.ones(2), np.ones(2))
    assert r.scale == pytest.approx(2 / 3, abs=1e-12)
    np.testing.assert_allclose(r.qd, [1.0, 1.0], atol=1e-12)
    # all joints frozen: scale 0, qd = 0
    r = sns_velocity(np.eye(3), np.array([1.0, 0, 0]), np.zeros(3), np.zeros(3))
    assert r.scale == 0.0 and np.all(r.qd == 0.0)


def test_task_scaling_factor_hand():
    s, j = task_scaling_factor(np.array([2.0, -1.0]), np.zeros(2), -np.ones(2), np.ones(2))
    assert s == 0.5 and j == 0


@pytest.mark.parametrize("box", ["symmetric", "risk"])
def test_sns_scale_against_lp(box):
    """SNS vs the LP optimum on random 3x7 tasks.

    SNS is a greedy heuristic: its scale never exceeds the LP's (it returns a
    feasible point) and equals it in most cases; the measured gaps (seed 0,
    400 cases) are stated in the asserts.
    """
    rng = np.random.default_rng(0)
    ws = SNSWorkspace(3, 7)
    gaps, feasible, kept = [], 0, 0
    for _ in range(400):
        J = rng.normal(size=(3, 7))
        xd = rng.normal(size=3) * rng.uniform(0.1, 5.0)
        v = rng.uniform(0.5, 2.0, 7)
        if box == "symmetric":
            lo, hi = -v, v.copy()
        else:   # R14-like boxes: one side of some joints shrunk by (1 - f), some to zero
            f = rng.uniform(0, 1, 7) ** 0.5
            up = rng.random(7) < 0.5
            lo, hi = -v * np.where(up, 1, 1 - f), v * np.where(up, 1 - f, 1)
        r = sns_velocity(J, xd, lo, hi, workspace=ws)
        assert np.all(r.qd <= hi + 1e-9) and np.all(r.qd >= lo - 1e-9)
        np.testing.assert_allclose(J @ r.qd, r.scale * xd, atol=1e-9)
        s_lp = _lp_scale(J, xd, lo, hi)
        assert r.scale <= s_lp + 1e-7
        gaps.append(s_lp - r.scale)
        if s_lp > 1 - 1e-9:
            feasible += 1
            kept += r.scale == 1.0
    gaps = np.array(gaps)
    share_equal = np.mean(gaps < 1e-6)
    assert feasible > 50
    assert kept >= 0.98 * feasible
    assert share_equal >= 0.9
    assert np.quantile(gaps, 0.95) < 0.05
    assert gaps.max() < 0.4


def test_sns_numba_matches_numpy_twin():
    rng = np.random.default_rng(5)
    ws = SNSWorkspace(3, 7)
    for k in range(300):
        J = rng.normal(size=(3, 7))
        xd = rng.normal(size=3) * rng.uniform(0.1, 5)
        lo, hi = -rng.uniform(0, 2, 7), rng.uniform(0, 2, 7)
        q0 = rng.normal(size=7) if k % 2 else None
        a = sns_velocity(J, xd, lo, hi, q0, workspace=ws)
        b = sns_velocity_numpy(J, xd, lo, hi, q0)
        np.testing.assert_allclose(a.qd, b.qd, atol=1e-10)
        assert a.scale == pytest.approx(b.scale, abs=1e-12)
        np.testing.assert_array_equal(a.saturated, b.saturated)


def test_sns_null_space_velocity_does_not_disturb_task():
    rng = np.random.default_rng(2)
    J = rng.normal(size=(3, 7))
    xd = np.array([0.3, 0.0, -0.1])
    lo, hi = -np.ones(7), np.ones(7)
    q0 = rng.normal(size=7)
    r = sns_velocity(J, xd, lo, hi, qd0=q0)
    np.testing.assert_allclose(J @ r.qd, xd, atol=1e-10)
    assert 0.0 < r.null_scale <= 1.0
    N = np.eye(7) - np.linalg.pinv(J) @ J
    # what was added is the (scaled) null-space projection of q0
    np.testing.assert_allclose(r.qd - np.linalg.pinv(J) @ xd, r.null_scale * N @ q0, atol=1e-10)


def test_sns_bad_input():
    with pytest.raises(ValueError, match="lo <= 0 <= hi"):
        sns_velocity(np.eye(3), np.zeros(3), np.ones(3), 2 * np.ones(3))
    with pytest.raises(ValueError, match="task velocity"):
        sns_velocity(np.eye(3), np.zeros(2), -np.ones(3), np.ones(3))


def test_repulsion_and_limits_kernel_matches_numpy_twin():
    from depthguard.control.repulsion_limits import repulsion_and_limits, repulsion_and_limits_numpy

    rng = np.random.default_rng(11)
    n, m = 7, 9
    for trial in range(200):
        D = rng.uniform(0.0, 0.5, m)
        D[rng.random(m) < 0.3] = np.inf
        V = rng.normal(size=(m, 3))
        V /= np.linalg.norm(V, axis=1, keepdims=True)
        J = rng.normal(size=(m, 3, n))
        J[:, :, rng.integers(n):] *= rng.random() < 0.5          # joints beyond a link: zero columns
        q_min, q_max = -np.full(n, 2.0), np.full(n, 2.0)
        q = rng.uniform(-2.1, 2.1, n)
        qd_max = rng.uniform(1.0, 3.0, n)
        k = rng.uniform(0, 1)
        a = repulsion_and_limits(D, V, J, q, q_min, q_max, qd_max, 0.002, RHO, VMAX, ALPHA, k)
        b = repulsion_and_limits_numpy(D, V, J, q, q_min, q_max, qd_max, 0.002, RHO, VMAX, ALPHA, k)
        for x, y in zip(a, b):
            np.testing.assert_allclose(x, y, rtol=1e-12, atol=1e-12)
        assert np.all(a[1] <= 0) and np.all(a[2] >= 0)
