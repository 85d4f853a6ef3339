"""Blind spots of a camera layout (R12, R32): space next to the robot that no camera sees.

Truth: geometry — each lattice point tested in every camera's noiseless render — and,
for the monitor's side, the depth grid's own answer over the same frames: where the
layout leaves a pocket nobody sees, the grid must report it (unknown is an obstacle,
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


def _grid_distances(cell):
    """The monitor's fusion (the rig's monitor: settings) over noiseless frames at the rig joints."""
    from depthguard.filtering.expected import ExpectedDepth
    from depthguard.fusion.depth_grid import DepthGridMap
    from depthguard.runtime.ingest import robot_volume
    from depthguard.sources.simulated import SimSource

    rig, cfg, robot = cell.rig, cell.rig.monitor, cell.rig.robot
    q = cell.scene.robot_q(0.0)
    frames = SimSource(cell, noiseless=True).frames(0.0)
    static = cell.scene.meshes_at(0.0, robot=False)[0]
    rdepth = {c.id: np.array(ExpectedDepth(c, robot, static).robot(q), copy=True) for c in rig.cameras}
    d_min, d_max = rig.workspace.depth_span(rig.cameras[0])
    grid = DepthGridMap(rig.cameras, principal=rig.cameras[0], d_min=d_min, d_max=d_max, delta_d=cfg.delta_d)
    grid.set_frames({c: f.depth for c, f in frames.items()}, rdepth, robot_offset=cfg.robot_offset,
                    robot_capsules=robot_volume(robot, [q], cfg.robot_padding), invalid=cfg.invalid,
                    robot_in_others=cfg.robot_in_others, silhouette_px=cfg.silhouette_px, gap_px=cfg.gap_px)
    res = grid.query(robot.control_point_positions(q), rho=cfg.rho, method=cfg.method)
    return res.distance.copy(), [cp.name for cp in robot.control_points]


def test_old_layout_has_a_pocket_and_the_grid_reports_it(cells):
    _, old = cells
    spots = blind_spots(old, [0.0])
    assert {b.point for b in spots} >= {"elbow", "upperarm_end"}
    for b in spots:
        # hidden from every camera: the robot from the two on its side, the fixtures from the others
        assert b.hidden_by["camC"] == "feeder" and b.hidden_by["camD"] == "sensor_post"
        assert b.hidden_by["camA"].startswith("robot/") and b.hidden_by["camB"].startswith("robot/")
    dist, names = _grid_distances(old)
    step = 0.02 * np.sqrt(3) / 2 + 0.01                 # lattice half-diagonal + one depth slice
    for b in spots:
        # unknown is an obstacle: the grid never reports the pocket farther than it is
        assert dist[names.index(b.point)] <= b.distance + step, (b, dist[names.index(b.point)])


def test_built_in_layout_sees_around_the_robot(cells):
    new, _ = cells
    assert blind_spots(new, [0.0]) == []
    dist, names = _grid_distances(new)
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
