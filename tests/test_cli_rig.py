"""Every command that takes a cell takes a rig file too (R2): ``scenes render --rig``,
``placement --rig``, ``run --rig`` — a user simulates and checks their own cell.

The rigs are written by the tests (a UR3 on a table with one small camera; cameras
around a small box of interest) or are the shipped rig files used as a user's.
"""

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from depthguard.cli import app
from depthguard.cli.common import load_rig_or_cell
from depthguard.depth_io import read_depth
from depthguard.rig import Rig, RigError
from depthguard.sim.cells import cell_from_rig, cell_rig_path

UR3_JOINTS = [0.9, -1.3, 1.4, -1.7, -1.5708, 0.2]     # rad, the base turned 0.9 rad from the UR3's q_home


def _camera(cid, eye, target, w=160, h=120, f=120.0, rng=(0.3, 6.0)):
    return {"id": cid, "width": w, "height": h, "fx": f, "fy": f, "cx": (w - 1) / 2, "cy": (h - 1) / 2,
            "range": list(rng), "pose": {"look_at": {"eye": list(eye), "target": list(target), "up": [0, 0, 1]}}}


def write_ur3_rig(path: Path, cameras=None, joints=UR3_JOINTS) -> Path:
    """A UR3 on a table (top at z = 0.8 m) with a floor and one 160x120 camera."""
    rig = {
        "name": "my-ur3",
        "workspace": {"min": [-1.0, -1.0, 0.0], "max": [1.0, 1.0, 1.6]},
        "cameras": cameras or [_camera("cam0", (1.6, -1.3, 1.7), (0.0, 0.0, 0.9))],
        "robot": {"name": "ur3", "base": {"translation": [0.0, 0.0, 0.8]}, "joints": list(joints)},
        "objects": [
            {"name": "table", "box": {"size": [1.2, 0.8, 0.04]}, "pose": {"translation": [0.0, 0.0, 0.78]}},
            {"name": "floor", "box": {"size": [6.0, 6.0, 0.05]}, "pose": {"translation": [0.0, 0.0, -0.025]}},
        ],
    }
    path.write_text(yaml.safe_dump(rig, sort_keys=False))
    return path


def write_ring_rig(path: Path, azimuths_deg, radius=3.0) -> Path:
    """Cameras at ``radius`` m around a 0.6 x 0.6 x 0.6 m box of interest (the workspace), at the
    given azimuths, all looking at its centre; nothing else."""
    cams = [_camera(f"c{k}", (radius * math.cos(math.radians(a)), radius * math.sin(math.radians(a)), 1.5),
                    (0.0, 0.0, 0.3)) for k, a in enumerate(azimuths_deg)]
    rig = {"name": "ring", "workspace": {"min": [-0.3, -0.3, 0.0], "max": [0.3, 0.3, 0.6]}, "cameras": cams}
    path.write_text(yaml.safe_dump(rig, sort_keys=False))
    return path


# ------------------------------------------------------------------ the helper
def test_load_rig_or_cell_one_helper_for_rig_files_and_built_in_cells(tmp_path):
    f = write_ur3_rig(tmp_path / "rig.yaml")
    rig, cell = load_rig_or_cell(f, None)
    assert isinstance(rig, Rig) and cell is None and rig.name == "my-ur3"
    rig, cell = load_rig_or_cell(f, None, simulate=True)
    assert cell.rig is rig and cell.name == "my-ur3" and cell.situations == {}
    rig, cell = load_rig_or_cell(None, None, default="ur3-cell")
    assert cell.name == "ur3-cell" and rig is cell.rig
    with pytest.raises(ValueError, match="not both"):
        load_rig_or_cell(f, "ur3-cell")
    with pytest.raises(ValueError, match="give --rig FILE"):
        load_rig_or_cell(None, None, default=None)
    with pytest.raises(RigError, match="rig file not found"):
        load_rig_or_cell(tmp_path / "nope.yaml", None)


def test_cell_from_rig_is_the_rigs_static_objects_and_robot_at_its_joints(tmp_path):
    rig = Rig.load(write_ur3_rig(tmp_path / "rig.yaml"))
    cell = cell_from_rig(rig)
    assert [p.name for p in cell.scene.static] == ["table", "floor"]
    for t in (0.0, 3.7, 100.0):
        np.testing.assert_array_equal(cell.scene.robot_q(t), UR3_JOINTS)
        assert cell.scene.dynamic_at(t) == []
    meshes, names = cell.scene.meshes_at(0.0)
    assert names[:2] == ["table", "floor"] and all(n.startswith("robot/") for n in names[2:])
    # a rig with a mesh object (the ur3-cell's STL fixture) becomes a mesh solid with true distances
    ur3 = cell_from_rig(Rig.load(cell_rig_path("ur3-cell")))
    ring = next(p for p in ur3.scene.static if p.name == "ring_fixture")
    # the ring (inner radius 30 mm, outer 60, 40 high) at (0.32, -0.22, 0.8): a point in its wall is inside
    assert ring.sdf(np.array([[0.32 + 0.045, -0.22, 0.82]]))[0] < 0


# ------------------------------------------------------------------ scenes render --rig
def test_scenes_render_rig_writes_each_camera_matching_an_independent_ray_cast(tmp_path):
    embree = pytest.importorskip("depthguard.render.embree")
    pytest.importorskip("embreex")
    cams = [_camera("front", (1.6, -1.3, 1.7), (0.0, 0.0, 1.0), f=200.0),
            _camera("back", (-1.5, 1.2, 1.9), (0.1, 0.0, 1.0), f=200.0)]
    f = write_ur3_rig(tmp_path / "rig.yaml", cameras=cams)
    out = tmp_path / "render"
    res = CliRunner().invoke(app, ["scenes", "render", "--rig", str(f), "--out", str(out), "--noiseless"])
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in out.iterdir()) == ["back.png", "contact_sheet.png", "front.png"]
    rig = Rig.load(f)
    robot = rig.robot
    for cam in rig.cameras:
        got = read_depth(out / f"{cam.id}.png")
        # the oracle: Embree ray casting of the rig's meshes and the robot's links at the rig joints,
        # not through the scene or the rasteriser
        at_rig = embree.EmbreeCaster(cam).cast(rig.static_meshes() + list(robot.link_meshes(np.array(UR3_JOINTS))))
        at_home = embree.EmbreeCaster(cam).cast(rig.static_meshes() + list(robot.link_meshes(robot.q_home)))
        robot_pixels = at_rig[1] >= len(rig.objects)
        assert robot_pixels.sum() > 200, "the robot is barely in view: a weak test"

        def valid(d):
            return (d >= cam.min_range) & (d <= cam.max_range)

        want = np.where(valid(at_rig[0]), at_rig[0], 0.0)
        both = (got > 0) & (want > 0)
        agree = (got > 0) == (want > 0)
        assert agree.mean() > 0.995, f"{cam.id}: valid pixels differ on {(~agree).sum()} pixels"
        close = np.abs(got - want)[both] <= 0.0005 + 1e-4             # millimetre PNG, float32 casting
        assert close.mean() > 0.995, f"{cam.id}: {(~close).sum()} pixels differ by more than 0.6 mm"
        # the robot stands at the rig's joints, not at its home posture
        home = np.where(valid(at_home[0]), at_home[0], 0.0)
        assert (np.abs(got - home) > 0.01).sum() > 100


def test_scenes_render_needs_exactly_one_of_cell_name_and_rig(tmp_path):
    f = write_ur3_rig(tmp_path / "rig.yaml")
    runner = CliRunner()
    res = runner.invoke(app, ["scenes", "render", "ur3-cell", "--rig", str(f), "--out", str(tmp_path / "x")])
    assert isinstance(res.exception, ValueError) and "not both" in str(res.exception)
    res = runner.invoke(app, ["scenes", "render", "--out", str(tmp_path / "x")])
    assert isinstance(res.exception, ValueError) and "--rig FILE" in str(res.exception)
    res = runner.invoke(app, ["scenes", "render", "--rig", str(f), "--situation", "reach", "--out", str(tmp_path / "x")])
    assert isinstance(res.exception, ValueError) and "situations: none" in str(res.exception)


# ------------------------------------------------------------------ placement --rig
def _placement_share(tmp_path, azimuths_deg) -> float:
    f = write_ring_rig(tmp_path / f"ring{len(azimuths_deg)}_{azimuths_deg[-1]}.yaml", azimuths_deg)
    res = CliRunner().invoke(app, ["placement", "--rig", str(f), "--no-improve", "--voxel", "0.1"])
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    assert lines[0] == f"ring ({f}): {len(azimuths_deg)} cameras"
    crit = next(x for x in lines if x.startswith("free-space criterion"))
    assert ": 216 voxels of 10 cm" in crit                  # 6 x 6 x 6, no clearance
    return float(crit.split(": ")[-1].split(" %")[0])


def test_placement_rig_three_cameras_120_degrees_apart_pass_everywhere(tmp_path):
    # every voxel of a 0.6 m box seen from 3 m: azimuths within ±8.1° of the cameras' ->
    # pairwise >= 103.8° apart (R23 asks 100°)
    assert _placement_share(tmp_path, [0.0, 120.0, 240.0]) == 100.0


def test_placement_rig_fails_with_one_camera_or_three_on_one_side(tmp_path):
    assert _placement_share(tmp_path, [0.0]) == 0.0
    # three views, but pairwise at most 60° + 16.2° apart: the criterion fails everywhere
    assert _placement_share(tmp_path, [0.0, 60.0, 120.0]) == 0.0


def test_placement_rig_and_cell_together_is_one_clear_error(tmp_path):
    f = write_ring_rig(tmp_path / "ring.yaml", [0.0])
    res = CliRunner().invoke(app, ["placement", "--rig", str(f), "--cell", "c-arm-room", "--no-improve"])
    assert isinstance(res.exception, ValueError) and "not both" in str(res.exception)


# ------------------------------------------------------------------ run --rig
def _ee_at(rig, q):
    data = rig.robot.create_data()
    rig.robot.forward(np.asarray(q, float), data)
    return data.cp_positions[0].copy()


def test_run_rig_drives_a_six_joint_ur3_around_a_hexagon_at_its_end_effector(tmp_path):
    """The closed loop on a user's rig: a UR3 (6 joints, SNS on a 3-D task) tracks a hexagon
    centred at its end effector at the rig joints, reachable and clear of the table."""
    from depthguard.evaluation.closed_loop.scenarios import HEXAGON_RADII

    f = write_ur3_rig(tmp_path / "rig.yaml")
    out = tmp_path / "run"
    res = CliRunner().invoke(app, ["run", "--rig", str(f), "-s", "empty", "--duration", "0.4", "-o", str(out),
                                   "--no-noise", "--quiet"])
    assert res.exit_code == 0, res.output
    s = json.loads((out / "summary.json").read_text())
    assert s["cell"] == "my-ur3" and s["rig"] == str(f)
    assert s["collision"] is False and s["safe_stops"] == []
    centre = _ee_at(Rig.load(f), UR3_JOINTS)
    np.testing.assert_allclose(s["params"]["hexagon_center_m"], centre, atol=1e-12)
    assert s["params"]["hexagon_radius_m"] in HEXAGON_RADII
    assert s["ee_tracking_rms_all_m"] < 0.01                    # metres: the 6-joint arm follows the path


def test_run_rig_hexagon_options_and_clear_errors(tmp_path):
    f = write_ur3_rig(tmp_path / "rig.yaml")
    runner = CliRunner()
    # out of the UR3's reach (about 0.5 m): the message says which option to change
    res = runner.invoke(app, ["run", "--rig", str(f), "-s", "empty", "-o", str(tmp_path / "a"),
                              "--hexagon-centre", "2,0,1", "--quiet"])
    assert isinstance(res.exception, ValueError)
    msg = str(res.exception)
    assert "cannot reach" in msg and "--hexagon-centre" in msg and "\n" not in msg
    # a radius that puts the path into the table (top at z = 0.8 m)
    centre = _ee_at(Rig.load(f), UR3_JOINTS)
    res = runner.invoke(app, ["run", "--rig", str(f), "-s", "empty", "-o", str(tmp_path / "b"),
                              "--hexagon-radius", str(centre[2] - 0.8 + 0.01), "--quiet"])
    assert isinstance(res.exception, ValueError) and "static object" in str(res.exception)
    res = runner.invoke(app, ["run", "--rig", str(f), "-s", "empty", "-o", str(tmp_path / "c"),
                              "--hexagon-centre", "1,2", "--quiet"])
    assert isinstance(res.exception, ValueError) and "three numbers" in str(res.exception)
    res = runner.invoke(app, ["run", "--rig", str(f), "--cell", "flacco-cell", "-s", "empty",
                              "-o", str(tmp_path / "d"), "--quiet"])
    assert isinstance(res.exception, ValueError) and "not both" in str(res.exception)
    no_robot = write_ring_rig(tmp_path / "ring.yaml", [0.0])
    res = runner.invoke(app, ["run", "--rig", str(no_robot), "-s", "empty", "-o", str(tmp_path / "e"), "--quiet"])
    assert isinstance(res.exception, ValueError) and "no robot" in str(res.exception)


def test_reach_scenario_on_a_rig_puts_the_person_in_front_of_the_hexagon_away_from_the_base(tmp_path):
    """``reach`` is placed relative to the hexagon and the robot's base: on flacco-cell (base at
    x = 0, hexagon plane x = -0.6) the person stands at -x; on the UR3 rig (hexagon plane
    x > 0) at +x, outside the table, with the hand near the upper corners."""
    from depthguard.evaluation.closed_loop.loop import LoopConfig
    from depthguard.evaluation.closed_loop.scenarios import build_scenario, rig_hexagon
    from depthguard.sim import load_cell

    flacco = load_cell("flacco-cell")
    hexagon = LoopConfig().hexagon
    torso = next(p for p in build_scenario("reach", flacco, hexagon).obstacles(0.0) if "torso" in p.name)
    assert torso.world_from_local[0, 3] < hexagon.center[0] - 0.4

    cell = cell_from_rig(Rig.load(write_ur3_rig(tmp_path / "rig.yaml")))
    hexagon = rig_hexagon(cell)
    sc = build_scenario("reach", cell, hexagon)
    torso = next(p for p in sc.obstacles(0.0) if "torso" in p.name)
    assert torso.world_from_local[0, 3] > max(hexagon.center[0] + 0.4, 0.6)    # table edge at x = 0.6 m
    hand = np.concatenate([p.mesh().vertices for p in sc.obstacles(3.0) if "right" in p.name and "hand" in p.name])
    top = np.asarray(hexagon.center) + [0.0, 0.0, hexagon.radius]
    assert np.linalg.norm(hand - top, axis=1).min() < 0.25


@pytest.mark.slow  # about 15 s: four 640x480 cameras and an STL fixture in the ground truth
def test_run_rig_on_the_shipped_ur3_cell_file(tmp_path):
    """Half a second shows what 1 s did (measured: the same nearest true distance, 6.19 cm, and
    15-16 frames per camera instead of 30-31) at two thirds of the time."""
    out = tmp_path / "ur3"
    f = cell_rig_path("ur3-cell")
    res = CliRunner().invoke(app, ["run", "--rig", str(f), "-s", "empty", "--duration", "0.5", "-o", str(out),
                                   "--quiet"])
    assert res.exit_code == 0, res.output
    s = json.loads((out / "summary.json").read_text())
    assert s["collision"] is False and s["safe_stops"] == [] and s["min_true_distance_m"] > 0
    assert sorted(s["frames"]) == ["camA", "camB", "camC", "camD"] and min(s["frames"].values()) >= 14  # 30 Hz
    assert (out / "summary.json").is_file() and "no collision" in res.output


@pytest.mark.slow  # interpreter start-ups
def test_rig_errors_are_one_line_exit_2(tmp_path):
    def run_cli(*args):
        return subprocess.run([sys.executable, "-m", "depthguard.cli.__main__", *args], capture_output=True,
                              text=True)

    f = write_ring_rig(tmp_path / "ring.yaml", [0.0])
    r = run_cli("placement", "--rig", str(f), "--cell", "c-arm-room")
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and "not both" in r.stderr
    r = run_cli("scenes", "render", "--rig", str(tmp_path / "missing.yaml"), "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and r.stderr.strip() == f"depthguard: error: {tmp_path / 'missing.yaml'}: rig file not found"
    bad = tmp_path / "bad.yaml"
    bad.write_text("workspace: {min: [0, 0, 0], max: [1, 1, 1]}\ncameras:\n  - {id: c, fx: -1, pose: {}}\n")
    r = run_cli("run", "--rig", str(bad), "-s", "empty", "-o", str(tmp_path / "r"))
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and str(bad) in r.stderr and "cameras" in r.stderr


def test_monitor_on_a_rig_without_walls_sees_no_phantom_where_nothing_is_modelled(tmp_path):
    """A user's rig with a floor and a table only: the simulated camera's rays that meet nothing
    return from beyond the rated range (as a real cell's walls would: free up to max_range,
    R28), so the product's defaults (invalid = unknown) do not stop the robot alone."""
    from depthguard.sources.base import open_source
    from depthguard.sources.simulated import BEYOND_RANGE

    f = write_ur3_rig(tmp_path / "rig.yaml")
    rig = Rig.load(f)
    cam = rig.cameras[0]
    src = open_source("sim", rig, {})
    q = np.asarray(UR3_JOINTS, dtype=float)
    d = src.render(cam.id, 0.0, q)
    ideal = src.sim.expected[cam.id].known(q)
    empty = ideal <= 0
    assert empty.any() and (~empty).any()
    assert np.all(d[empty] == np.float32(BEYOND_RANGE * cam.max_range))
    assert cam.max_range < BEYOND_RANGE * cam.max_range <= 3.0 * cam.max_range
    out = tmp_path / "mon"
    res = CliRunner().invoke(app, ["monitor", "--rig", str(f), "--duration", "2", "--fast", "--out", str(out)])
    assert res.exit_code == 0, res.output
    s = json.loads((out / "summary.json").read_text())
    # never a stop reason: from the first cycle on the override only rises (it starts at 0, R26)
    assert s["episodes"] == [] and s["stopped_s"] == 0.0, (s["stopped_s"], s["episodes"])
    assert s["slowed_s"] <= s["config"]["resume_time"] + 0.01, s["slowed_s"]
    # no control point reads anything much nearer than the fixed objects really are
    from depthguard.sim.cells import cell_from_rig
    from depthguard.sim.ground_truth import true_distance

    truth = true_distance(list(cell_from_rig(rig).scene.static), rig.robot.control_point_positions(q))
    rho = rig.monitor.rho
    worst = np.inf
    for line in (out / "log.jsonl").read_text().splitlines():
        for i, p in enumerate(x for x in json.loads(line)["points"] if not x["watch"]):
            if p["distance"] is not None:
                worst = min(worst, p["distance"] - min(truth[i], rho))
    assert worst > -0.05, worst


def test_placement_rig_names_the_space_next_to_the_robot_that_no_camera_sees(tmp_path):
    """One camera cannot see behind the robot: placement reports the pockets at the rig joints
    and what hides them (R12: unknown is an obstacle), first, before the free-space criterion
    (issue 33: it led with "0.0 % pass" and 30 improver cameras); ur3-cell's four cameras leave none."""
    f = write_ur3_rig(tmp_path / "rig.yaml")
    res = CliRunner().invoke(app, ["placement", "--rig", str(f), "--no-improve", "--voxel", "0.2"])
    assert res.exit_code == 0, res.output
    assert "have space that no camera sees" in res.output.splitlines()[1], res.output
    assert "hidden by cam0: robot/" in res.output, res.output
    res = CliRunner().invoke(app, ["placement", "--cell", "ur3-cell", "--no-improve", "--voxel", "0.2"])
    assert res.exit_code == 0, res.output
    assert "some camera sees around every control point" in res.output, res.output


def test_placement_along_a_recorded_path_checks_the_robot_where_the_path_puts_it(tmp_path):
    """``placement --joints csv:FILE``: the blind spots next to the robot along a recorded path,
    each at the pose the path interpolates for its time. Truth: the UR3's own kinematics at the
    linearly interpolated joints (the reported unseen point is that far from the named control
    point there, and within rho of it), not at the rig joints."""
    import re

    f = write_ur3_rig(tmp_path / "rig.yaml")
    rig = Rig.load(f)
    q1 = np.array(UR3_JOINTS)
    q2 = q1 + np.array([-0.8, 0.3, -0.4, 0.2, 0.0, 0.5])     # the base turned back, the arm raised
    path = tmp_path / "path.csv"
    path.write_text("stamp," + ",".join(f"j{i}" for i in range(6)) + "\n"
                    + "\n".join(f"{s}," + ",".join(repr(float(x)) for x in q) for s, q in ((2.0, q1), (3.0, q2))) + "\n")
    res = CliRunner().invoke(app, ["placement", "--rig", str(f), "--no-improve", "--voxel", "0.2",
                                   "--joints", f"csv:{path}", "--every", "0.4"])
    assert res.exit_code == 0, res.output
    assert f"along csv:{path} (4 poses, every 0.4 s from 2 to 3 s)" in res.output, res.output
    lines = re.findall(r"t=([\d.]+) s (\w+): nothing seen at \(([-\d.]+), ([-\d.]+), ([-\d.]+)\) m, ([\d.]+) m away",
                       res.output)
    assert len(lines) >= 3, res.output
    data = rig.robot.create_data()
    names = [c.name for c in rig.robot.control_points]
    times = set()
    for t, name, x, y, z, d in lines:
        t = float(t)
        times.add(t)
        u = (t - 2.0) / 1.0
        rig.robot.forward((1 - u) * q1 + u * q2, data)
        p = data.cp_positions[names.index(name)]
        dist = float(np.linalg.norm(np.array([float(x), float(y), float(z)]) - p))
        assert abs(dist - float(d)) < 0.006, (t, name, dist, d)          # the printed 2-decimal point
        assert dist <= rig.monitor.rho + 0.006
    assert times == {2.0, 2.4, 2.8, 3.0}, res.output                      # every pose of the path, each at its own
    # the path's errors name what is wrong
    runner = CliRunner()
    res = runner.invoke(app, ["placement", "--rig", str(f), "--no-improve", "--joints", "zenoh:robot/q"])
    assert res.exit_code != 0 and "recorded path" in res.output, res.output
    res = runner.invoke(app, ["placement", "--rig", str(f), "--no-improve", "--joints", f"csv:{tmp_path / 'no.csv'}"])
    assert "does not exist" in str(res.exception), res.output
    res = runner.invoke(app, ["placement", "--rig", str(f), "--no-improve", "--joints", f"csv:{path}",
                              "--every", "0"])
    assert res.exit_code != 0 and "--every" in res.output, res.output
