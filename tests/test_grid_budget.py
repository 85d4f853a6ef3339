"""The depth grid's column size from its budget (issue 29, :mod:`depthguard.grid_budget`):
checked by projecting the region of surveillance through the binned camera itself."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from depthguard.grid_budget import COLUMNS_ACROSS, MAX_BIN, auto_principal_bin, robot_depth
from depthguard.rig import Rig
from depthguard.sim.cells import cell_rig_path, load_cell

CELLS_WITH_ROBOT = ["flacco-cell", "ur3-cell", "fr3-cell"]


def _columns_across(cam, b: int, d: float, rho: float) -> int:
    """Grid columns the binned principal spends on a ``2 rho`` wide segment at depth ``d`` on
    its optical axis, counted by projecting the segment's points (1 mm apart) through
    ``cam.binned(b)``."""
    x = np.linspace(-rho, rho, int(2 * rho / 0.001) + 1)
    pc = np.stack([x, np.zeros_like(x), np.full_like(x, d)], axis=1)       # camera frame
    pw = cam.camera_to_world(pc)
    u = cam.binned(b).world_to_depth_space(pw)[:, 0]
    cols = np.floor(u + 0.5).astype(int)
    return int(cols.max() - cols.min() + 1)


@pytest.mark.parametrize("name", CELLS_WITH_ROBOT)
def test_built_in_cells_get_the_finest_column_within_the_budget(name):
    rig = load_cell(name).rig
    cfg = rig.monitor
    cam = rig.camera(cfg.principal) if cfg.principal else rig.cameras[0]
    b = cfg.principal_bin
    assert 1 <= b <= MAX_BIN and rig.principal_bin_why.startswith(f"principal_bin {b}:")
    d = robot_depth(cam, rig.robot, rig.robot_q0)
    # the robot's depth, independently: its capsules' mid-points through the camera's pose
    data = rig.robot.create_data()
    rig.robot.forward(rig.robot_q0, data)
    mids = np.array([data.link_poses[rig.robot.chain.link_index(c.link)] @ np.r_[0.5 * (c.a + c.b), 1.0]
                     for c in rig.robot.capsules])[:, :3]
    z = (mids - cam.position) @ np.asarray(cam.R)[2]              # along the optical axis
    assert np.isclose(d, np.median(z[z > 0]), rtol=1e-9)
    rho = cfg.query_rho
    # within the budget (one column of rounding at each end), and the next finer column is not
    assert _columns_across(cam, b, d, rho) <= COLUMNS_ACROSS + 1
    if b > 1:
        assert _columns_across(cam, b - 1, d, rho) > COLUMNS_ACROSS - 1


def test_a_rigs_own_principal_bin_wins(tmp_path):
    path = cell_rig_path("ur3-cell")
    data = yaml.safe_load(path.read_text())
    for o in data.get("objects", []):                       # meshes by absolute path
        if "mesh" in o:
            o["mesh"] = str((path.parent / o["mesh"]).resolve())
    chosen = Rig.from_dict(data)
    assert chosen.monitor.principal_bin > 2 and "principal_bin" in chosen.principal_bin_why
    data.setdefault("monitor", {})["principal_bin"] = 2
    own = Rig.from_dict(data)
    assert own.monitor.principal_bin == 2 and own.principal_bin_why == ""


@pytest.mark.parametrize("budget", [8, 32, 128])
def test_other_budgets_hold_and_are_the_finest(budget):
    """Any budget: the chosen column keeps the region within it, the next finer does not
    (until the finest, 1 pixel, or the coarsest, MAX_BIN)."""
    rig = load_cell("ur3-cell").rig
    cam = rig.cameras[0]
    d = robot_depth(cam, rig.robot, rig.robot_q0)
    b, why = auto_principal_bin(cam, rig.robot, rig.robot_q0, 0.4, columns_across=budget)
    assert f"budget {budget}" in why
    if b < MAX_BIN:
        assert _columns_across(cam, b, d, 0.4) <= budget + 1
    if b > 1:
        assert _columns_across(cam, b - 1, d, 0.4) > budget - 1
    with pytest.raises(ValueError, match="rho"):
        auto_principal_bin(cam, rig.robot, rig.robot_q0, 0.0)
