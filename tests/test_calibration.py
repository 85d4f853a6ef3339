"""Calibration against the known static scene (R34): check, refine, degenerate scenes, rig file, CLI.

Truths: the simulator renders the frames from the camera's true pose through its sensor's
noise model while the calibration starts from a wrong one; a floor's null space is analytic
(height and the two tilts are fixed by it, nothing else).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from depthguard.calibration import StaticScene, calibrate_camera, pose_error, residual_stats
from depthguard.calibration.refine import so3_exp
from depthguard.calibration.study import perturb, recovery_study, summarise
from depthguard.camera import Camera
from depthguard.geometry import Box
from depthguard.rig import Rig
from depthguard.sim import load_cell
from depthguard.sources import SimulatedCamera
from depthguard.transforms import look_at


# ----------------------------------------------------------------------------- recovery
@pytest.mark.parametrize("cell_name,n", [("flacco-cell", 4), ("ur3-cell", 4), ("c-arm-room", 6)])
def test_random_pose_errors_up_to_3_deg_and_5_cm_are_recovered(cell_name, n):
    rows = recovery_study(cell_name, n=n, seed=11, frames=1)
    s = summarise(rows)
    assert s["not_converged"] == 0 and s["degenerate"] == 0, rows
    assert s["median_deg"] <= 0.1 and s["median_mm"] <= 3.0, s
    assert max(r["given_deg"] for r in rows) > 1.0                 # the errors were real
    assert all(r["after"] == "good" for r in rows), [(r["camera"], r["before"], r["after"]) for r in rows]


@pytest.mark.slow          # the full study: 20 perturbations per built-in cell (about 2 min here)
@pytest.mark.parametrize("cell_name", ["flacco-cell", "ur3-cell", "c-arm-room", "flacco-walls"])
def test_recovery_study_twenty_perturbations_per_cell(cell_name):
    s = summarise(recovery_study(cell_name, n=20, seed=0))
    if cell_name == "flacco-walls":       # degenerate: along the wall, see the next test
        assert s["degenerate"] == 20
        assert s["median_constrained_deg"] <= 0.1 and s["median_constrained_mm"] <= 3.0, s
    else:
        assert s["median_deg"] <= 0.1 and s["median_mm"] <= 3.0, s


# ----------------------------------------------------------------------------- degenerate scenes
def _floor_camera():
    T = look_at([0.0, -2.0, 1.5], [0.0, 0.0, 0.0])
    return Camera("floorcam", 320, 240, 290.0, 290.0, 159.5, 119.5, T, 0.3, 8.0, "realsense_d435")


def test_a_floor_alone_fixes_height_and_tilt_and_reports_the_rest_unconstrained():
    cam = _floor_camera()
    scene = StaticScene([Box.from_bounds([-6, -6, -0.1], [6, 6, 0.0]).mesh()])
    d = SimulatedCamera(cam, seed=1).capture(scene.meshes, stamp=0.0)
    # wrong in every direction: 1 deg about a tilted axis, 3 cm along x, y and z
    T = cam.world_from_camera.copy()
    T[:3, :3] = so3_exp(np.radians(1.0) * np.array([0.6, 0.48, 0.64])) @ T[:3, :3]
    T[:3, 3] += [0.03, 0.03, 0.03]
    cal = calibrate_camera(cam.with_pose(T), [d], scene)
    ref = cal.refinement
    assert ref.converged and ref.degenerate and len(ref.unconstrained) == 3
    # the analytic null space of a horizontal plane: x, y translation and rotation about z
    null = ref.eigenvectors[:, ~ref.constrained]
    expect = np.zeros((6, 3))
    expect[0, 0] = expect[1, 1] = expect[5, 2] = 1.0
    assert np.allclose(null @ (null.T @ expect), expect, atol=1e-3)     # same subspace
    Tr = cal.refined.world_from_camera
    # fixed: the height and the tilt of the optical axis against the floor
    assert abs(Tr[2, 3] - cam.world_from_camera[2, 3]) < 0.003
    assert abs(Tr[2, 2] - cam.world_from_camera[2, 2]) < math.sin(math.radians(0.1))
    # not "fixed" by noise: x and y stay as given (the wrong values), not moved towards anything
    assert np.allclose(Tr[:2, 3], T[:2, 3], atol=1e-4)
    assert any("rotation about" in s for s in ref.unconstrained)
    assert any("translation along" in s for s in ref.unconstrained)
    assert any("NOT CONSTRAINED" in line for line in cal.report())


def test_flacco_walls_table_and_one_wall_face_leave_the_position_along_the_wall_open():
    rows = recovery_study("flacco-walls", n=3, seed=4, frames=1, rot_deg=1.0, trans_m=0.03)
    for r in rows:
        assert any("translation along (+0.00, +1.00" in u or "translation along (-0.00, -1.00" in u
                   or "translation along (+0.00, -1.00" in u or "translation along (-0.00, +1.00" in u
                   for u in r["unconstrained"]), r["unconstrained"]
        assert r["constrained_deg"] <= 0.1 and r["constrained_mm"] <= 3.0, r


# ----------------------------------------------------------------------------- residual check
@pytest.fixture(scope="module")
def ur3():
    cell = load_cell("ur3-cell")
    rig = cell.rig
    cam = rig.camera("camA")
    q = rig.robot_q0
    meshes = list(rig.static_meshes()) + list(rig.robot.link_meshes(q))
    d = SimulatedCamera(cam, seed=9).capture(meshes, stamp=0.0)
    return rig, cam, q, meshes, d


def test_check_right_pose_good_turned_one_degree_wrong(ur3):
    from depthguard.filtering.expected import ExpectedDepth

    rig, cam, q, _meshes, d = ur3
    ex = ExpectedDepth(cam, rig.robot, rig.static_meshes())
    good = residual_stats(cam, d, ex.static, ex.robot(q))
    assert good.verdict == "good" and good.share_far < 0.01 and abs(good.median) < 0.002, good
    T = cam.world_from_camera.copy()
    T[:3, :3] = so3_exp(np.radians(1.0) * T[:3, 0]) @ T[:3, :3]           # tilted by 1 deg
    bad_cam = cam.with_pose(T)
    exb = ExpectedDepth(bad_cam, rig.robot, rig.static_meshes())
    bad = residual_stats(bad_cam, d, exb.static, exb.robot(q))
    assert bad.verdict == "wrong" and bad.share_far > 0.03 and bad.share_near > 0.25, bad


def test_people_in_front_are_occluders_not_evidence_of_a_moved_camera(ur3):
    from depthguard.filtering.expected import ExpectedDepth

    rig, cam, q, meshes, _d = ur3
    person = Box.from_bounds([0.3, -0.6, 0.0], [0.7, 0.2, 1.9]).mesh()      # a big box between camera and table
    d = SimulatedCamera(cam, seed=10).capture(meshes + [person], stamp=0.0)
    ex = ExpectedDepth(cam, rig.robot, rig.static_meshes())
    st = residual_stats(cam, d, ex.static, ex.robot(q))
    assert st.share_near > 0.1 and st.verdict == "good", st
    # and the refinement of a wrong pose is not pulled by it
    T = perturb(cam.world_from_camera, np.random.default_rng(5), 2.0, 0.04)
    cal = calibrate_camera(cam.with_pose(T), [d], StaticScene(rig.static_meshes()), rig.robot, [q])
    deg, m = pose_error(cal.refined.world_from_camera, cam.world_from_camera)
    assert deg < 0.1 and m < 0.003, (deg, m)


def test_too_little_known_scene_in_view_cannot_be_judged():
    cam = _floor_camera()
    d = np.zeros(cam.shape, np.float32)
    st = residual_stats(cam, d, np.full(cam.shape, 2.0, np.float32))
    assert st.verdict == "unknown" and "cannot be judged" in st.reason


# ----------------------------------------------------------------------------- rig file and CLI
RIG_TEXT = """\
# my cell: keep this comment
version: 1
name: mine
workspace: {min: [-1, -1, 0], max: [1, 1, 2]}
cameras:
  - id: a          # the left one
    sensor: realsense_d435
    width: 424
    height: 240
    range: [0.3, 8.0]
    pose:
      look_at: {eye: [0.0, -2.0, 1.5], target: [0.0, 0.0, 0.0]}
    # comment after a's pose
  - {id: b, sensor: realsense_d435, width: 424, height: 240, range: [0.3, 8.0], pose: {look_at: {eye: [2.0, 0.0, 1.5], target: [0.0, 0.0, 0.0]}}}
objects:
  - {name: floor, box: {size: [12, 12, 0.1]}, pose: {translation: [0, 0, -0.05]}}
  - {name: crate, box: {size: [0.6, 0.4, 0.5]}, pose: {translation: [0.3, 0.2, 0.25]}}
  - {name: post, box: {size: [0.1, 0.1, 1.2]}, pose: {translation: [-0.6, 0.5, 0.6]}}
"""


def _write_rig(folder, text=RIG_TEXT):
    p = folder / "mine.yaml"
    p.write_text(text)
    return p


def test_calibrated_rig_file_keeps_the_users_file_and_never_overwrites(tmp_path):
    from depthguard.calibration.rig_file import write_calibrated_rig

    src = _write_rig(tmp_path)
    rig = Rig.load(src)
    new_a = perturb(rig.camera("a").world_from_camera, np.random.default_rng(1), 1.0, 0.02)
    out_dir = tmp_path / "elsewhere"
    out_dir.mkdir()
    out = out_dir / "fixed.yaml"
    write_calibrated_rig(src, out, {"a": new_a}, header="refined a")
    text = out.read_text()
    assert "# my cell: keep this comment" in text and "# the left one" in text and "# comment after a's pose" in text
    assert text.startswith("# refined a\n")
    back = Rig.load(out)
    assert np.allclose(back.camera("a").world_from_camera, new_a, atol=1e-9)
    assert np.allclose(back.camera("b").world_from_camera, rig.camera("b").world_from_camera)
    assert [o.name for o in back.objects] == [o.name for o in rig.objects]
    assert yaml.safe_load(text)["cameras"][1]["pose"] == yaml.safe_load(RIG_TEXT)["cameras"][1]["pose"]
    with pytest.raises(ValueError, match="exists already"):
        write_calibrated_rig(src, out, {"a": new_a})
    assert Rig.load(out).camera("a").key() == back.camera("a").key()


def test_relative_mesh_paths_still_name_the_same_file_from_another_folder(tmp_path):
    from depthguard.calibration.rig_file import write_calibrated_rig
    from depthguard.sim.cells import ring_fixture_mesh

    (tmp_path / "meshes").mkdir()
    ring_fixture_mesh().export(tmp_path / "meshes" / "ring.stl")
    src = _write_rig(tmp_path, RIG_TEXT + "  - {name: ring, mesh: meshes/ring.stl, scale: 0.001}\n")
    out = tmp_path / "sub" / "fixed.yaml"
    out.parent.mkdir()
    write_calibrated_rig(src, out, {"b": Rig.load(src).camera("b").world_from_camera})
    back = Rig.load(out)
    assert np.allclose(back.objects[-1].mesh.vertices, Rig.load(src).objects[-1].mesh.vertices)


def test_cli_calibrate_from_depth_files_writes_the_corrected_rig(tmp_path):
    from typer.testing import CliRunner

    from depthguard.cli import app
    from depthguard.depth_io import write_depth

    src = _write_rig(tmp_path)
    rig = Rig.load(src)
    true_a = rig.camera("a")
    wrong = true_a.world_from_camera.copy()                   # 1.5 deg about a skew axis, 3 cm
    wrong[:3, :3] = so3_exp(np.radians(1.5) * np.array([0.36, 0.48, 0.8])) @ wrong[:3, :3]
    wrong[:3, 3] += [0.02, -0.01, 0.02]
    # the file believes the wrong pose; the images come from the true one
    bumped_text = RIG_TEXT.replace("look_at: {eye: [0.0, -2.0, 1.5], target: [0.0, 0.0, 0.0]}",
                                   "matrix: " + str(np.round(wrong, 12).tolist()))
    bumped = tmp_path / "bumped.yaml"
    bumped.write_text(bumped_text)
    files = []
    for k in range(2):
        d = SimulatedCamera(true_a, seed=k).capture(rig.static_meshes(), stamp=float(k))
        files.append(write_depth(tmp_path / f"a{k}.npy", d))
    out = tmp_path / "fixed.yaml"
    res = CliRunner().invoke(app, ["calibrate", "--rig", str(bumped), "--depth", f"a={files[0]}",
                                   "--depth", f"a={files[1]}", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "as given wrong" in res.output and "camera a: moved" in res.output and "wrote" in res.output
    deg, m = pose_error(Rig.load(out).camera("a").world_from_camera, true_a.world_from_camera)
    assert deg < 0.1 and m < 0.003, (deg, m)
    # bad input: one clear error, nothing written
    res = CliRunner().invoke(app, ["calibrate", "--rig", str(bumped), "--depth", f"a={files[0]}", "--out", str(out)])
    assert res.exit_code != 0 and "exists already" in str(res.exception)
    res = CliRunner().invoke(app, ["calibrate", "--rig", str(bumped), "--depth", "nope"])
    assert res.exit_code != 0 and "CAMERA=FILE" in res.output
    res = CliRunner().invoke(app, ["calibrate", "--rig", str(bumped), "--depth", f"zz={files[0]}"])
    assert res.exit_code != 0 and "no camera 'zz'" in str(res.exception)


def test_gauss_newton_agrees_with_scipy_least_squares_on_the_same_problem():
    """A second solver on the same association and noise model: SciPy's trust-region least
    squares with a soft-L1 loss (the bench's peer) ends where the Gauss-Newton / Tukey solver does."""
    from depthguard.calibration import refine_pose
    from depthguard.evaluation.bench.calibrate import scipy_refine

    cell = load_cell("c-arm-room")
    rig = cell.rig
    cam = rig.camera("tof03")
    scene = StaticScene(rig.static_meshes())
    d = SimulatedCamera(cam, seed=4).capture(rig.static_meshes(), stamp=0.0)
    wrong = cam.with_pose(perturb(cam.world_from_camera, np.random.default_rng(8), 2.0, 0.03))
    ours = refine_pose(wrong, d, scene, stride=3).world_from_camera
    peer = scipy_refine(wrong, d, scene, stride=3)
    deg, m = pose_error(ours, peer)
    assert deg < 0.01 and m < 0.0005, (deg, m)
    assert pose_error(wrong.world_from_camera, cam.world_from_camera)[0] > 0.5
    assert pose_error(ours, cam.world_from_camera)[0] < 0.05


def test_cli_calibrate_from_the_simulator_fixes_the_moved_camera_and_only_it(tmp_path):
    """``--source sim:ur3-cell`` is the cell as it is (robot removed at the sim's joints); the rig
    file believes camB moved by 3.6 cm and turned ~1.8 deg."""
    from typer.testing import CliRunner

    from depthguard.cli import app
    from depthguard.sim.cells import cell_rig_path

    src = cell_rig_path("ur3-cell")
    text = src.read_text().replace("look_at: {eye: [1.1, 0.9, 1.7], target: [0.0, 0.0, 0.85]",
                                   "look_at: {eye: [1.13, 0.88, 1.71], target: [0.03, 0.02, 0.83]")
    bumped = tmp_path / "bumped.yaml"
    bumped.write_text(text.replace("meshes/ring_fixture.stl", str(src.parent / "meshes" / "ring_fixture.stl")))
    out = tmp_path / "fixed.yaml"
    res = CliRunner().invoke(app, ["calibrate", "--rig", str(bumped), "--source", "sim:ur3-cell", "--frames", "1",
                                   "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "camera camB: as given wrong" in res.output and "1 of 4 cameras' poses changed" in res.output
    truth, fixed = load_cell("ur3-cell").rig, Rig.load(out)
    deg, m = pose_error(fixed.camera("camB").world_from_camera, truth.camera("camB").world_from_camera)
    assert deg < 0.1 and m < 0.003, (deg, m)
    for cid in ("camA", "camC", "camD"):                     # kept as written (look_at), untouched
        assert np.array_equal(fixed.camera(cid).world_from_camera, Rig.load(bumped).camera(cid).world_from_camera)
