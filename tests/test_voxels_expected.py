"""The per-camera voxel filter takes the known scene's expected depth from
:class:`depthguard.filtering.expected.ExpectedDepth` — the one the monitor's camera workers use (R16)."""

import numpy as np


def test_voxel_filter_expected_depth_is_the_monitors():
    from depthguard.filtering.expected import ExpectedDepth
    from depthguard.fusion.voxels import VoxelFilter
    from depthguard.sim import load_cell

    cell = load_cell("ur3-cell")
    rig = cell.rig
    cam = rig.cameras[0]
    f = VoxelFilter(cam, (rig.workspace.lo, rig.workspace.hi), static_meshes=rig.static_meshes(), robot=rig.robot)
    ref = ExpectedDepth(cam, rig.robot, rig.static_meshes())
    for t in (0.0, cell.time_of("arm_reaching"), 0.0):
        q = cell.scene.robot_q(t)
        np.testing.assert_array_equal(f.expected_depth(q), ref.known(q))
        np.testing.assert_array_equal(f.expected_depth(None), ref.static)
    assert isinstance(f._expected_depth(), ExpectedDepth)
    # the measured known scene leaves nothing unknown
    q = cell.scene.robot_q(cell.time_of("arm_reaching"))
    assert len(f.filter(np.array(ref.known(q)), q=q)) == 0
