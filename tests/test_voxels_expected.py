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


def test_voxel_filter_keeps_the_people_and_nothing_of_the_known_scene():
    """Against an independent render of the whole scene (Embree ray casting of the static CAD, the
    robot at its joints and the people): the voxels the filter keeps are the people's — each
    voxel centre within half a voxel diagonal (plus the filter's offset) of a person's surface,
    allowing a few for the robot's outline, where two renderers may differ by a pixel — and every
    person in view gives voxels (R16-R18)."""
    import pytest

    pytest.importorskip("embreex")
    from depthguard.fusion.voxels import VoxelFilter
    from depthguard.geometry.primitives import sdf_union
    from depthguard.render.embree import EmbreeCaster
    from depthguard.sim import load_cell

    cell = load_cell("ur3-cell")
    rig, scene = cell.rig, cell.scene
    t = cell.time_of("arm_reaching")
    q = scene.robot_q(t)
    people = scene.dynamic_at(t)
    assert people, "the situation has someone in the cell"
    meshes, _ = scene.meshes_at(t, robot=True)
    s = 0.05
    for cam in rig.cameras[:2]:
        depth, _labels, _faces = EmbreeCaster(cam).cast(meshes)
        f = VoxelFilter(cam, (rig.workspace.lo, rig.workspace.hi), voxel_size=s,
                        static_meshes=rig.static_meshes(), robot=rig.robot)
        vs = f.filter(np.asarray(depth, dtype=np.float32), q=q)
        centres = (vs.keys + 0.5) * s
        assert len(centres) >= 5, (cam.id, len(centres))
        near_person = sdf_union(people, centres) <= s * np.sqrt(3) / 2 + 0.05
        assert near_person.mean() >= 0.95, (cam.id, near_person.mean(), len(centres))
