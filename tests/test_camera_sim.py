"""The one camera simulator (issue 28): ``sources/camera_sim.py``.

Truth: a second implementation — the whole scene rendered at once by a
:class:`~depthguard.sources.simulated.SimulatedCamera` (one z-buffer over every mesh, the
noise drawn from the same stamp's generator) — and the cameras' timing written out
analytically (camera ``i`` at ``0.37 i`` periods + ``k`` periods).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from depthguard.geometry.decimate import SIM_CELL
from depthguard.sim import load_cell
from depthguard.sources import SimSource, SimulatedCamera
from depthguard.sources.camera_sim import CameraSchedule, CameraSim
from depthguard.sources.simulated import BEYOND_RANGE

T = 3.0          # ur3-cell: a person in view of every camera, the robot moving


@pytest.fixture(scope="module")
def cell():
    return load_cell("ur3-cell")


def _whole_scene(cell, cam, t, seed=1, noiseless=False):
    """The second implementation: every mesh of the scene in one render (the robot as the
    simulator has it: its meshes clustered to SIM_CELL), then the noise."""
    meshes, _ = cell.scene.meshes_at(t, robot=False)
    meshes += cell.scene.robot.render_link_meshes(cell.scene.robot_q(t), SIM_CELL)
    return SimulatedCamera(cam, seed=seed, noiseless=noiseless).capture(meshes, stamp=t)


def test_frame_equals_the_whole_scene_rendered_at_once(cell):
    cams = cell.rig.cameras[:2]
    sim = CameraSim(cams, robot=cell.scene.robot, static_meshes=cell.scene.static_meshes, seed=1, invalid=None)
    moving, _ = cell.scene.moving_meshes_at(T)
    assert moving, "the check needs a person in view"
    for cam in cams:
        shot = sim.shot(cam.id, T, cell.scene.robot_q(T), moving, keep_robot=True)
        np.testing.assert_array_equal(shot.depth, _whole_scene(cell, cam, T))
        # the robot alone: the self-removal image, a copy that the next frame does not overwrite
        robot_only = SimulatedCamera(cam, noiseless=True).renderer.render(
            cell.scene.robot.render_link_meshes(cell.scene.robot_q(T), SIM_CELL))[0]
        np.testing.assert_array_equal(shot.robot_depth, robot_only)
        before = shot.robot_depth.copy()
        sim.shot(cam.id, 0.0, cell.scene.robot_q(0.0), [], keep_robot=True)
        np.testing.assert_array_equal(shot.robot_depth, before)


def test_simsource_is_the_simulator(cell):
    got = SimSource(cell, seed=1).frames(T)
    for cam in cell.rig.cameras:
        np.testing.assert_array_equal(got[cam.id].depth, _whole_scene(cell, cam, T))


def test_invalid_pixels_in_the_monitors_vocabulary(cell):
    cam = cell.rig.cameras[0]
    q = cell.scene.robot_q(T)
    moving, _ = cell.scene.moving_meshes_at(T)
    args = dict(robot=cell.scene.robot, static_meshes=[], seed=1)     # no walls: rays that meet nothing
    raw = CameraSim([cam], invalid=None, **args).depth(cam.id, T, q, moving)
    ideal = CameraSim([cam], invalid=None, noiseless=True, **args).depth(cam.id, T, q, moving)
    nothing = ideal <= 0
    assert nothing.any() and (~nothing).any()
    unknown = CameraSim([cam], invalid="unknown", **args).depth(cam.id, T, q, moving)
    assert np.all(unknown[nothing] == np.float32(BEYOND_RANGE * cam.max_range))    # R28: free up to the range
    np.testing.assert_array_equal(unknown[~nothing], raw[~nothing])                  # dropouts stay 0
    free = CameraSim([cam], invalid="free", **args).depth(cam.id, T, q, moving)
    assert np.all(free[raw <= 0] == np.float32(cam.max_range - 1e-3))
    np.testing.assert_array_equal(free[raw > 0], raw[raw > 0])
    with pytest.raises(ValueError, match="invalid must be"):
        CameraSim([cam], invalid="far")


def test_dark_clothing_returns_nothing_where_the_person_is_nearest(cell):
    cam = cell.rig.cameras[0]
    q = cell.scene.robot_q(T)
    moving, _ = cell.scene.moving_meshes_at(T)
    sim = CameraSim([cam], robot=cell.scene.robot, static_meshes=cell.scene.static_meshes, noiseless=True)
    lit, dark = sim.depth(cam.id, T, q, moving), sim.depth(cam.id, T, q, moving, dark=True)
    person = SimulatedCamera(cam, noiseless=True).renderer.render(moving)[0]
    seen = (person > 0) & (np.abs(lit - person) < 1e-6)            # the person is what the pixel sees
    assert seen.sum() > 50
    assert np.all(dark[seen] == 0)
    np.testing.assert_array_equal(dark[~seen & (lit > 0)], lit[~seen & (lit > 0)])


def test_schedule_captures_each_camera_on_its_own_phase():
    hz, n = 30.0, 3
    period = 1.0 / hz
    want = [sorted({0.0} | {0.37 * i * period + k * period for k in range(31)
                           if 0.37 * i * period + k * period <= 1.0 + 1e-12}) for i in range(n)]
    # the sim: source steps from capture to capture
    s = CameraSchedule(n, hz)
    got = [[] for _ in range(n)]
    for i in range(n):
        while s.due(i, 1.0, tol=1e-12):
            got[i].append(s.next[i])
            s.take(i, s.next[i])
    for i in range(n):
        np.testing.assert_allclose(got[i], want[i], atol=1e-12)
    # the closed loop scans 2 ms control cycles: each frame once, at the first cycle at or after it
    s = CameraSchedule(n, hz)
    for i in range(n):
        cycles = [k * 0.002 for k in range(501) if s.due(i, k * 0.002) and (s.take(i, k * 0.002) or True)]
        expect = [math.ceil(c / 0.002 - 1e-6) * 0.002 for c in want[i]]
        np.testing.assert_allclose(cycles, expect, atol=1e-9)
    # a camera far behind skips to its latest capture due
    s = CameraSchedule(2, hz)
    assert s.skip_to_latest(1, 0.5) == 14 and abs(s.next[1] - (0.37 * period + 14 * period)) < 1e-12


def test_people_posed_in_place_give_the_whole_scene(cell):
    """The people and props as the ``sim:`` source hands them over — packed once, posed in
    place once per time (:class:`~depthguard.sim.posed.PosedMeshes`) — at times where the
    person walks, reaches and leaves: every frame is the whole scene rendered at once."""
    from depthguard.sim.posed import PosedMeshes

    cam = cell.rig.cameras[0]
    sim = CameraSim([cam], robot=cell.scene.robot, static_meshes=cell.scene.static_meshes, seed=1, invalid=None)
    posed = PosedMeshes(cell.scene)
    for t in (T, 6.5, 10.5, 15.5):
        moving = posed.at(t)
        assert moving is not None
        np.testing.assert_array_equal(sim.depth(cam.id, t, cell.scene.robot_q(t), moving),
                                      _whole_scene(cell, cam, t))


@pytest.mark.parametrize("own", [False, True])
def test_a_robot_standing_still_is_not_drawn_again_and_the_frames_are_the_same(cell, own):
    """A camera whose robot stands still (the same joints as its last frame, e.g. stopped, R27)
    keeps its robot image instead of drawing it again: each frame is still the whole scene
    rendered at once (the second implementation), bit for bit, whether the cameras share the posed
    robot or each has its own (``own_robot_buffers``); the robot's renderer draws only when the
    joints a camera sees change, or another camera moved the shared robot in between."""
    cams = cell.rig.cameras[:2]
    sim = CameraSim(cams, robot=cell.scene.robot, static_meshes=cell.scene.static_meshes, seed=1, invalid=None)
    if own:
        sim.own_robot_buffers()
    draws = {c.id: 0 for c in cams}
    for c in cams:
        r = sim._robot[c.id]
        r.render_arrays = (lambda f, cid: lambda *a, **k: (draws.__setitem__(cid, draws[cid] + 1), f(*a, **k))[1])(
            r.render_arrays, c.id)
    q_still, q_moved = cell.scene.robot_q(T), cell.scene.robot_q(T + 0.5)
    assert not np.array_equal(q_still, q_moved)
    # (camera, time, joints): camA twice still, camB still, camA still, then moved and still again
    plan = [(0, T, q_still), (0, T + 0.05, q_still), (1, T + 0.06, q_still), (0, T + 0.1, q_still),
            (1, T + 0.11, q_moved), (0, T + 0.12, q_still), (0, T + 0.15, q_moved), (0, T + 0.2, q_moved)]
    for i, t, q in plan:
        cam = cams[i]
        moving, _ = cell.scene.moving_meshes_at(t)
        meshes, _ = cell.scene.meshes_at(t, robot=False)              # as _whole_scene, robot at q
        want = SimulatedCamera(cam, seed=1).capture(meshes + cell.scene.robot.render_link_meshes(q, SIM_CELL), stamp=t)
        np.testing.assert_array_equal(sim.shot(cam.id, t, q, moving).depth, want)
    # camA: drawn at the first frame, at q_still again after camB moved the shared robot (own
    # buffers: not needed), and at q_moved; camB: at q_still and q_moved
    assert draws == ({cams[0].id: 2, cams[1].id: 2} if own else {cams[0].id: 3, cams[1].id: 2})
