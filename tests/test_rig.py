"""Rig files (R2): a valid rig loads; each broken rig gets a message naming file, field and problem."""

import copy

import numpy as np
import pytest
import yaml

import depthguard as dg

GOOD = {
    "name": "test-cell",
    "workspace": {"min": [-1.0, -1.0, 0.0], "max": [1.0, 1.0, 2.0]},
    "cameras": [
        {"id": "cam0", "width": 640, "height": 480, "fx": 525.0, "fy": 525.0, "cx": 319.5, "cy": 239.5,
         "range": [0.4, 4.0], "pose": {"translation": [2.0, 0.0, 1.0], "quaternion": [-0.5, -0.5, 0.5, 0.5]}},
        {"id": "cam1", "sensor": "realsense_d435", "width": 424, "height": 240,
         "pose": {"look_at": {"eye": [-2.0, 0.5, 1.5], "target": [0.0, 0.0, 0.5]}}},
        {"id": "cam2", "sensor": "kinect_v1",
         "pose": {"matrix": [[1, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 3.0], [0, 0, 0, 1]]}},
    ],
    "objects": [
        {"name": "table", "box": {"size": [1.2, 0.8, 0.05]}, "pose": {"translation": [0, 0, 0.7]}},
        {"name": "ball", "sphere": {"radius": 0.1}, "pose": {"translation": [0.3, 0, 0.85]}},
    ],
}


def write(tmp_path, data, name="cell.yaml"):
    p = tmp_path / name
    p.write_text(yaml.safe_dump(data) if not isinstance(data, str) else data)
    return p


def test_good_rig_loads(tmp_path):
    rig = dg.Rig.load(write(tmp_path, GOOD))
    assert rig.camera_ids == ["cam0", "cam1", "cam2"]
    c1 = rig.camera("cam1")
    assert (c1.width, c1.height, c1.min_range, c1.max_range) == (424, 240, 0.2, 6.0)
    c0 = rig.camera("cam0")
    # quaternion xyzw [-0.5,-0.5,0.5,0.5]: columns x=+y, y=-z, z=-x (looks back at the origin, image y down)
    assert np.allclose(c0.world_from_camera[:3, :3], [[0, 0, -1], [1, 0, 0], [0, -1, 0]], atol=1e-9)
    assert np.allclose(c0.position, [2.0, 0.0, 1.0])
    assert np.allclose(rig.camera("cam2").world_from_camera[:3, 2], [0, 0, -1])
    assert [o.name for o in rig.objects] == ["table", "ball"]
    assert rig.objects[0].mesh.bounds[1, 2] == pytest.approx(0.725)
    assert rig.workspace.contains([[0, 0, 1], [0, 0, 3]]).tolist() == [True, False]


def test_mesh_object_relative_to_rig_file(tmp_path):
    from depthguard.geometry import Box
    import trimesh
    v, f = Box(size=(100.0, 200.0, 300.0)).mesh()
    (tmp_path / "meshes").mkdir()
    trimesh.Trimesh(v, f).export(tmp_path / "meshes" / "part.stl")
    data = copy.deepcopy(GOOD)
    data["objects"] = [{"name": "part", "mesh": "meshes/part.stl", "scale": 0.001,
                        "pose": {"translation": [0, 0, 1.0]}}]
    rig = dg.Rig.load(write(tmp_path, data))
    b = rig.objects[0].mesh.bounds
    assert np.allclose(b, [[-0.05, -0.1, 0.85], [0.05, 0.1, 1.15]])


def broken(mutator):
    data = copy.deepcopy(GOOD)
    mutator(data)
    return data


BROKEN = [
    ("negative focal length", broken(lambda d: d["cameras"][0].update(fx=-525.0)), r"cameras\[0\]\.fx: focal length must be > 0"),
    ("principal point outside", broken(lambda d: d["cameras"][0].update(cx=900.0)), r"cameras\[0\].*principal point"),
    ("non-orthonormal rotation", broken(lambda d: d["cameras"][2]["pose"].update(matrix=[[1, 0, 0, 0], [0, 2, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])), r"cameras\[2\]\.pose: .*not orthonormal"),
    ("reflection", broken(lambda d: d["cameras"][2]["pose"].update(matrix=[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 0], [0, 0, 0, 1]])), r"cameras\[2\]\.pose: .*determinant"),
    ("non-unit quaternion", broken(lambda d: d["cameras"][0]["pose"].update(quaternion=[0, 0, 0, 3])), r"cameras\[0\]\.pose: quaternion must have unit norm"),
    ("two pose forms", broken(lambda d: d["cameras"][1]["pose"].update(translation=[0, 0, 0])), r"cameras\[1\]\.pose: give exactly one"),
    ("unknown sensor", broken(lambda d: d["cameras"][1].update(sensor="kinect_v9")), r"cameras\[1\]\.sensor: unknown sensor model 'kinect_v9'"),
    ("sensor mode that does not exist", broken(lambda d: d["cameras"][2].update(width=1280, height=720)), r"cameras\[2\].*no 1280x720 mode"),
    ("incomplete intrinsics", broken(lambda d: d["cameras"][0].pop("fy")), r"cameras\[0\]: intrinsics incomplete: missing fy"),
    ("duplicate camera ids", broken(lambda d: d["cameras"][1].update(id="cam0")), r"cameras: camera ids must be unique \(repeated: cam0\)"),
    ("misspelt field", broken(lambda d: d["cameras"][0].update(fz=3.0)), r"cameras\[0\]\.fz: unknown field"),
    ("missing workspace", broken(lambda d: d.pop("workspace")), r"workspace: required field is missing"),
    ("inverted workspace", broken(lambda d: d["workspace"].update(min=[2, 0, 0])), r"workspace: workspace min must be < max"),
    ("bad range", broken(lambda d: d["cameras"][0].update(range=[3.0, 1.0])), r"cameras\[0\]\.range: range must be"),
    ("missing mesh file", broken(lambda d: d["objects"].append({"name": "ghost", "mesh": "nowhere.stl"})), r"objects\[2\]\.mesh \(ghost\): mesh file not found"),
    ("object with two shapes", broken(lambda d: d["objects"][0].update(sphere={"radius": 1.0})), r"objects\[0\]: give exactly one shape"),
    ("no cameras", broken(lambda d: d.update(cameras=[])), r"cameras: .*at least 1"),
    ("wrong version", broken(lambda d: d.update(version=7)), r"version: unsupported rig version 7"),
]


@pytest.mark.parametrize("what,data,pattern", BROKEN, ids=[b[0] for b in BROKEN])
def test_broken_rigs_name_file_field_and_problem(tmp_path, what, data, pattern):
    p = write(tmp_path, data, "broken.yaml")
    with pytest.raises(dg.RigError) as info:
        dg.Rig.load(p)
    msg = str(info.value)
    assert "broken.yaml" in msg, msg
    import re
    assert re.search(pattern, msg), msg


def test_a_malformed_rig_file_is_one_line_naming_where(tmp_path):
    """PyYAML's own message spans 7 lines with the source echoed (issue 33's first-contact check:
    a workspace line missing its closing brace); the rig's error is one line with the line and
    column where the parser gave up and where the unclosed mapping began."""
    text = ("version: 1\nname: c\nworkspace: {min: [-1, -1, 0], max: [1, 1, 2]\n"
            "cameras:\n  - {id: a, sensor: kinect_v1, pose: {translation: [0, 0, 1]}}\n")
    p = write(tmp_path, text, "unclosed.yaml")
    with pytest.raises(dg.RigError) as exc:
        dg.Rig.load(p)
    msg = str(exc.value)
    assert "\n" not in msg, msg
    assert msg.startswith(f"{p}: not valid YAML: ") and "at line 4, column 1" in msg, msg
    assert "flow mapping at line 3, column 12" in msg, msg


def test_not_yaml_and_missing_file(tmp_path):
    with pytest.raises(dg.RigError, match="rig file not found"):
        dg.Rig.load(tmp_path / "nope.yaml")
    p = write(tmp_path, "cameras: [ {id: a,\n", "bad.yaml")
    with pytest.raises(dg.RigError, match="bad.yaml: not valid YAML"):
        dg.Rig.load(p)
    p = write(tmp_path, "- just\n- a list\n", "list.yaml")
    with pytest.raises(dg.RigError, match="list.yaml: a rig must be a mapping"):
        dg.Rig.load(p)


def _robot_available():
    try:
        import depthguard.robot  # noqa: F401
        return True
    except ImportError:
        return False


needs_robot = pytest.mark.skipif(not _robot_available(), reason="depthguard.robot not importable")


@needs_robot
def test_unknown_robot_is_named(tmp_path):
    data = broken(lambda d: d.update(robot={"name": "r2d2"}))
    with pytest.raises(dg.RigError, match=r"broken.yaml: robot.name: .*r2d2"):
        dg.Rig.load(write(tmp_path, data, "broken.yaml"))


@needs_robot
def test_robot_joints_checked(tmp_path):
    data = broken(lambda d: d.update(robot={"name": "lwr4", "joints": [0.0, 0.0]}))
    with pytest.raises(dg.RigError, match=r"robot.joints: expected 7 joint values"):
        dg.Rig.load(write(tmp_path, data, "broken.yaml"))
    data = broken(lambda d: d.update(robot={"name": "lwr4", "joints": [0, 0, 0, 9.0, 0, 0, 0]}))
    with pytest.raises(dg.RigError, match=r"robot.joints\[3\]: 9.0000 rad is outside the joint limits"):
        dg.Rig.load(write(tmp_path, data, "broken.yaml"))


@needs_robot
def test_robot_loads_with_base(tmp_path):
    # on the table top (z 0.725); at z 0.5 its links would cross the table, a rig error (test_rig_checks)
    data = broken(lambda d: d.update(robot={"name": "lwr4", "base": {"translation": [0, 0, 0.725]}}))
    rig = dg.Rig.load(write(tmp_path, data))
    assert rig.robot.dof == 7
    poses = rig.robot.link_poses(rig.robot_q0)
    assert poses[0][2, 3] == pytest.approx(0.725)


def test_a_camera_id_that_cannot_name_a_zenoh_key_is_refused_when_the_rig_loads(tmp_path):
    import yaml

    from depthguard.rig import Rig, RigError
    from depthguard.sim.cells import cell_rig_path

    data = yaml.safe_load(cell_rig_path("flacco-cell").read_text())
    data["cameras"][1]["id"] = "side/left"
    with pytest.raises(RigError, match=r"cameras\[1\]\.id: .*cannot name a Zenoh key"):
        Rig.from_dict(data, source=tmp_path / "cell.yaml")
    data["monitor"] = {"rho": 0.3, "watch_points": [{"name": "door", "position": [1, 0, 1]}, {"name": "door", "position": [0, 0, 1]}]}
    data["cameras"][1]["id"] = "cam1"
    with pytest.raises(RigError, match=r"monitor: watch point names must be unique"):
        Rig.from_dict(data, source=tmp_path / "cell.yaml")
    data["monitor"] = {"rho": 0.3, "stale": 1}
    with pytest.raises(RigError, match=r"monitor\.stale: unknown field"):
        Rig.from_dict(data, source=tmp_path / "cell.yaml")
    data["monitor"] = {"rho": 0.3}
    assert Rig.from_dict(data, source=tmp_path / "cell.yaml").monitor.rho == 0.3


def test_the_fr3_cell_without_franky_sim_is_one_sentence(monkeypatch):
    """The FR3's model is franky-sim's URDF, found at run time: where the package cannot be
    found, the cell's rig names the field and says what to install (no traceback, no download)."""
    import importlib.util

    from depthguard.rig import RigError
    from depthguard.robot import builtin
    from depthguard.sim import load_cell

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "franky_sim" else real(name, *a))
    builtin._builtin.cache_clear()
    try:
        with pytest.raises(RigError, match=r"fr3-cell.yaml: robot.name: the FR3 model comes from the simulator "
                                           r"franky-sim, which is not installed \(pip install franky-sim"):
            load_cell("fr3-cell")
    finally:
        builtin._builtin.cache_clear()
