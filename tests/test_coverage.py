"""Blind spots of a camera layout (R12, R32): space next to the robot that no camera sees.

Truth: geometry — each lattice point tested in every camera's noiseless render — and,
for the monitor's side, the monitor's own answer over the same frames: where the
layout leaves a pocket nobody sees, the monitor must report it (unknown is an obstacle,
never farther than the pocket by more than the discretisation); where it does not,
the robot alone must not read anything much nearer than the fixed objects.
"""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.evaluation.coverage import blind_spots
from depthguard.rig import Rig
from depthguard.sim.cells import cell_from_rig, cell_rig_path, load_cell

OLD_POST = "translation: [-0.5, -0.3, 1.0]"       # where ur3-cell's sensor post stood before


@pytest.fixture(scope="module")
def cells(tmp_path_factory):
    """ur3-cell as built in, and with its sensor post where it stood before; robot at its rig joints."""
    path = cell_rig_path("ur3-cell")
    text = path.read_text()
    assert "translation: [-0.5, 0.0, 1.0]" in text
    d = tmp_path_factory.mktemp("ur3")
    (d / "meshes").symlink_to(path.parent / "meshes")
    old = d / "ur3-old.yaml"
    old.write_text(text.replace("translation: [-0.5, 0.0, 1.0]", OLD_POST))
    return cell_from_rig(Rig.load(path)), cell_from_rig(Rig.load(old))


def _monitor_distances(cell):
    """The monitor (the rig's monitor: settings, one runtime) over noiseless frames at the rig
    joints: the control points' distances of one cycle."""
    from depthguard.runtime.monitor import Monitor
    from depthguard.sources.frame import Frame
    from depthguard.sources.simulated import SimSource

    rig = cell.rig
    q = cell.scene.robot_q(0.0)
    frames = SimSource(cell, noiseless=True).frames(0.0)
    with Monitor(rig, rig.monitor) as mon:
        mon.push_joints(0.0, q)
        mon.push_joints(0.01, q)
        for cid, f in frames.items():
            mon.push_frame(Frame(cid, f.depth, 0.005))
        mon.flush(timeout=120.0)
        r = mon.step(0.01, q)
    m = int(np.sum(~r.is_watch))
    assert np.all(r.observed[:m]) and set(r.frame_stamps) == set(frames)
    return r.distance[:m].copy(), list(r.names[:m])


def test_old_layout_has_a_pocket_and_the_monitor_reports_it(cells):
    _, old = cells
    spots = blind_spots(old, [0.0])
    assert {b.point for b in spots} >= {"elbow", "upperarm_end"}
    for b in spots:
        # hidden from every camera: the robot from the two on its side, the fixtures from the others
        assert b.hidden_by["camC"] == "feeder" and b.hidden_by["camD"] == "sensor_post"
        assert b.hidden_by["camA"].startswith("robot/") and b.hidden_by["camB"].startswith("robot/")
    dist, names = _monitor_distances(old)
    step = 0.02 * np.sqrt(3) / 2 + 0.01                 # lattice half-diagonal + one depth slice
    for b in spots:
        # unknown is an obstacle: the monitor never reports the pocket farther than it is
        assert dist[names.index(b.point)] <= b.distance + step, (b, dist[names.index(b.point)])


def test_built_in_layout_sees_around_the_robot(cells):
    new, _ = cells
    assert blind_spots(new, [0.0]) == []
    dist, names = _monitor_distances(new)
    from depthguard.sim.ground_truth import true_distance

    rig = new.rig
    truth = true_distance(list(new.scene.static), rig.robot.control_point_positions(new.scene.robot_q(0.0)))
    ref = np.minimum(truth, rig.monitor.rho)
    near = [(n, d, r) for n, d, r in zip(names, dist, ref) if np.isfinite(d) and d < r - 0.05]
    assert not near, near


@pytest.mark.slow
def test_built_in_ur3_path_has_no_blind_spot():
    cell = load_cell("ur3-cell")
    assert blind_spots(cell, np.arange(0.0, 16.0, 0.5)) == []


def test_recorded_path_times_and_interpolated_joints():
    from depthguard.evaluation.coverage import recorded_path

    states = [(1.0, np.array([0.0, 1.0])), (2.0, np.array([1.0, 3.0])), (2.5, np.array([1.0, 2.0]))]
    times, q_at = recorded_path(states, 0.4)
    np.testing.assert_allclose(times, [1.0, 1.4, 1.8, 2.2, 2.5])          # every 0.4 s, then the last state
    np.testing.assert_allclose(q_at(1.4), [0.4, 1.8])                     # linear between the states around t
    np.testing.assert_allclose(q_at(2.25), [1.0, 2.5])
    np.testing.assert_allclose(q_at(2.0), [1.0, 3.0])
    one, q1 = recorded_path(states[:1], 0.5)
    assert list(one) == [1.0] and list(q1(1.0)) == [0.0, 1.0]
    with pytest.raises(ValueError, match="every"):
        recorded_path(states, 0.0)
    with pytest.raises(ValueError, match="no states"):
        recorded_path([], 0.5)
