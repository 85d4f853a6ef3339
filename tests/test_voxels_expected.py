"""The per-camera voxel filter's expected depth of the known scene (R16, R17) against an
independent truth: Embree ray casting (:class:`depthguard.render.embree.EmbreeCaster`, trimesh's
and the renderer's oracle) of the same meshes — the rig's static CAD and the robot's full-resolution
link meshes at its joints — never through :class:`~depthguard.filtering.expected.ExpectedDepth`
or the z-buffer renderer. Skipped without ``embreex`` (extras ``test``)."""

import numpy as np
import pytest

pytest.importorskip("embreex")

from depthguard.fusion.voxels import VoxelFilter  # noqa: E402
from depthguard.render.embree import EmbreeCaster  # noqa: E402
from depthguard.sim import load_cell  # noqa: E402

# Static CAD: the same triangles, so the two casts agree to float32 rounding (<< 1 mm) except on
# a few silhouette pixels. The robot is rendered from its meshes clustered to RENDER_CELL = 6 mm
# (RobotModel.render_link_meshes: within sqrt(3) cell of the true surface), the oracle casts the
# true meshes. Measured on ur3-cell (4 cameras, 2 postures): static >= 99.99 % within 1 mm, robot
# >= 99.2 % within sqrt(3)*6 mm, median 0.2 mm; the same image shifted by one pixel: static 59 %,
# robot 90 %; moved 2 cm: 0 %.
STATIC_TOL, STATIC_SHARE = 1e-3, 0.999
ROBOT_TOL, ROBOT_SHARE = np.sqrt(3) * 0.006, 0.98


@pytest.fixture(scope="module")
def ur3():
    return load_cell("ur3-cell")


@pytest.fixture(scope="module")
def cast(ur3):
    """``cast(cam, posture)``: :func:`_truth` at ``None`` (no robot), ``"rest"`` (t = 0) or
    ``"reach"`` (arm_reaching), cast once per module."""
    seen = {}
    times = {"rest": 0.0, "reach": ur3.time_of("arm_reaching")}

    def get(cam, posture):
        if (cam.id, posture) not in seen:
            q = None if posture is None else ur3.scene.robot_q(times[posture])
            seen[cam.id, posture] = _truth(cam, ur3.rig, q)
        return seen[cam.id, posture]
    return get


def _cameras(rig):
    """Two cameras looking from opposite sides of the cell (a few seconds for the whole file)."""
    cams = rig.cameras
    return [cams[0], cams[len(cams) // 2]]


def _truth(cam, rig, q):
    """Embree cast of the static CAD and, with ``q``, the robot's true link meshes at ``q``:
    depth (H, W) m (0 = no hit; the expected depth is not cut to the sensor's range) and
    (H, W) bool robot pixels."""
    static = rig.static_meshes()
    robot = list(rig.robot.link_meshes(q)) if q is not None else []
    depth, labels, _ = EmbreeCaster(cam).cast(static + robot)
    return depth.astype(np.float64), labels >= len(static)


def _shares(got, truth, robot_px):
    """Share of static / robot pixels (both known) within their tolerance of the truth."""
    both = (got > 0) & (truth > 0)
    err = np.abs(got.astype(np.float64) - truth)
    st, rb = both & ~robot_px, both & robot_px
    return (err[st] <= STATIC_TOL).mean(), (err[rb] <= ROBOT_TOL).mean(), float(np.median(err[rb]))


def test_voxel_filter_expected_depth_matches_a_ray_cast_of_the_known_scene(ur3, cast):
    """``VoxelFilter.expected_depth(q)``: the static CAD and the robot at ``q`` as an independent
    ray cast sees them, pixel by pixel, in every camera and at two postures; without joints the
    static CAD alone (R16)."""
    rig = ur3.rig
    t_reach = ur3.time_of("arm_reaching")
    postures = [ur3.scene.robot_q(t) for t in (0.0, t_reach)]
    for cam in _cameras(rig):
        f = VoxelFilter(cam, (rig.workspace.lo, rig.workspace.hi), static_meshes=rig.static_meshes(), robot=rig.robot)
        truths = [cast(cam, "rest"), cast(cam, "reach")]
        for k, (q, (truth, robot_px)) in enumerate(zip(postures, truths)):
            assert robot_px.sum() > 1000, f"{cam.id}: the robot is barely in view - a weak test"
            got = np.array(f.expected_depth(q), copy=True)
            agree = (got > 0) == (truth > 0)
            assert agree.mean() >= 0.999, f"{cam.id}: known/unknown differs on {(~agree).sum()} pixels"
            static_ok, robot_ok, robot_med = _shares(got, truth, robot_px)
            assert static_ok >= STATIC_SHARE, f"{cam.id}: static CAD within 1 mm on {static_ok:.2%} of pixels"
            assert robot_ok >= ROBOT_SHARE and robot_med <= 1e-3, \
                f"{cam.id}: robot within {ROBOT_TOL * 1000:.1f} mm on {robot_ok:.2%}, median {robot_med * 1000:.2f} mm"
            # the postures differ enough that an expected depth at the wrong joints fails the check
            other, other_px = truths[1 - k]
            assert _shares(got, other, other_px)[1] < ROBOT_SHARE, f"{cam.id}: the two postures look alike"
        # no joints: the static CAD only, the robot nowhere
        truth, robot_px = cast(cam, None)
        assert not robot_px.any()
        got = f.expected_depth(None)
        assert ((got > 0) == (truth > 0)).mean() >= 0.999
        assert _shares(got, truth, robot_px)[0] >= STATIC_SHARE


def test_voxel_filter_removes_the_known_scene_and_the_robot_at_its_joints(ur3, cast):
    """A measured frame that is exactly the known scene (the ray cast of the CAD and the robot at
    ``q``) leaves no voxel; the same frame filtered without the joints keeps the robot, and only
    the robot: each voxel centre within half a voxel diagonal plus the filter's offset of a
    robot surface point the ray cast hit (R16-R19)."""
    rig = ur3.rig
    q = ur3.scene.robot_q(ur3.time_of("arm_reaching"))
    s = 0.02
    for cam in _cameras(rig):
        f = VoxelFilter(cam, (rig.workspace.lo, rig.workspace.hi), voxel_size=s,
                        static_meshes=rig.static_meshes(), robot=rig.robot)
        truth, robot_px = cast(cam, "reach")
        measured = truth.astype(np.float32)
        assert len(f.filter(measured, q=q)) == 0, f"{cam.id}: the known scene left voxels"
        vs = f.filter(measured, q=None)
        assert len(vs) >= 20, f"{cam.id}: without the joints the robot should remain ({len(vs)} voxels)"
        # the robot's surface as the ray cast hit it, in the world
        v, u = np.nonzero(robot_px & (truth > 0))
        z = truth[v, u]
        pc = cam.ray_directions()[v, u] * z[:, None]                  # camera frame, (N, 3) m
        T = cam.world_from_camera
        surface = pc @ T[:3, :3].T + T[:3, 3]
        centres = (vs.keys + 0.5) * s
        near = np.sqrt(((centres[:, None, :] - surface[None, :, :]) ** 2).sum(-1)).min(axis=1)
        bound = s * np.sqrt(3) / 2 + f.offset(float(z.max())) + ROBOT_TOL
        assert near.max() <= bound, f"{cam.id}: a kept voxel {near.max() * 1000:.0f} mm from the robot"


def test_voxel_filter_keeps_the_people_and_nothing_of_the_known_scene(ur3):
    """Against an independent render of the whole scene (Embree ray casting of the static CAD, the
    robot at its joints and the people): the voxels the filter keeps are the people's — each
    voxel centre within half a voxel diagonal (plus the filter's offset) of a person's surface,
    allowing a few for the robot's outline, where two renderers may differ by a pixel — and every
    person in view gives voxels (R16-R18)."""
    from depthguard.geometry.primitives import sdf_union

    cell = ur3
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
