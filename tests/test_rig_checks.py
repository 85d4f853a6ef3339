"""A rig number that is almost certainly a mistake is a rig error (issue 33 items 3 and 8, R2, R28):
a mesh in the wrong unit, a robot mounted inside a static object."""

import copy

import numpy as np
import pytest
import trimesh
import yaml

import depthguard as dg
from depthguard.geometry import Box
from depthguard.rig import RigError

BASE = {
    "name": "own-cell",
    "workspace": {"min": [-1.5, -1.5, 0.0], "max": [1.5, 1.5, 2.0]},
    "cameras": [{"id": "cam0", "sensor": "realsense_d435", "width": 640, "height": 480,
                 "pose": {"look_at": {"eye": [2.0, 0.0, 1.8], "target": [0.0, 0.0, 0.8]}}}],
    "objects": [],
}


def _fixture_stl(tmp_path, size_m=(0.3, 0.2, 0.1), unit=1000.0):
    """A box fixture written as STL with its lengths in ``1 / unit`` m (unit 1000: millimetres)."""
    v, f = Box(size=tuple(s * unit for s in size_m)).mesh()
    (tmp_path / "meshes").mkdir(exist_ok=True)
    path = tmp_path / "meshes" / "fixture.stl"
    trimesh.Trimesh(v, f).export(path)
    return path


def _load(tmp_path, obj):
    data = copy.deepcopy(BASE)
    data["objects"] = [{"name": "table", "box": {"size": [1.2, 0.8, 0.05]}, "pose": {"translation": [0, 0, 0.7]}},
                       obj]
    p = tmp_path / "cell.yaml"
    p.write_text(yaml.safe_dump(data))
    return dg.Rig.load(p)


def test_an_stl_in_millimetres_without_scale_is_refused_with_the_scale_to_give(tmp_path):
    _fixture_stl(tmp_path)
    with pytest.raises(RigError) as err:
        _load(tmp_path, {"name": "fixture", "mesh": "meshes/fixture.stl", "pose": {"translation": [0, 0, 0.8]}})
    msg = str(err.value)
    assert "objects[1].mesh (fixture)" in msg and "300 m across" in msg and "scale: 0.001" in msg
    assert "millimetres" in msg and "\n" not in msg


def test_the_same_stl_with_scale_loads_at_its_true_size(tmp_path):
    _fixture_stl(tmp_path)
    rig = _load(tmp_path, {"name": "fixture", "mesh": "meshes/fixture.stl", "scale": 0.001,
                           "pose": {"translation": [0, 0, 0.8]}})
    lo, hi = rig.objects[1].mesh.bounds
    np.testing.assert_allclose(hi - lo, [0.3, 0.2, 0.1], atol=1e-9)


def test_a_mesh_in_metres_scaled_as_millimetres_is_refused(tmp_path):
    _fixture_stl(tmp_path, unit=1.0)                       # already metres: 0.001 makes it 0.3 mm
    with pytest.raises(RigError) as err:
        _load(tmp_path, {"name": "fixture", "mesh": "meshes/fixture.stl", "scale": 0.001})
    msg = str(err.value)
    assert "under 1 cm" in msg and "scale: 1," in msg and "(fixture)" in msg


@pytest.mark.parametrize("size, ok", [((0.012, 0.005, 0.005), True), ((0.008, 0.008, 0.008), False),
                                      ((45.0, 1.0, 1.0), True), ((60.0, 1.0, 1.0), False)])
def test_the_limits_are_one_centimetre_and_fifty_metres_of_the_largest_extent(tmp_path, size, ok):
    _fixture_stl(tmp_path, size_m=size, unit=1.0)
    obj = {"name": "fixture", "mesh": "meshes/fixture.stl"}
    if ok:
        _load(tmp_path, obj)
    else:
        with pytest.raises(RigError, match="a rig's lengths are metres"):
            _load(tmp_path, obj)


def _cell_with_base_z(name, dz):
    """The built-in cell ``name``'s rig with its robot moved ``dz`` m along z."""
    from depthguard.sim.cells import cell_rig_path

    path = cell_rig_path(name)
    data = yaml.safe_load(path.read_text())
    t = data["robot"]["base"]["translation"]
    data["robot"]["base"]["translation"] = [t[0], t[1], t[2] + dz]
    return dg.Rig.from_dict(data, source=path)                 # meshes relative to the cell's folder


@pytest.mark.parametrize("name, table, deep_cm", [("flacco-cell", "table", 20.0), ("ur3-cell", "table_top", 2.0)])
def test_a_robot_mounted_20_cm_inside_its_table_is_a_rig_error(name, table, deep_cm):
    """flacco-cell's LWR stands on a 85-cm block: 20 cm lower, its base is 20 cm inside it; the
    UR3 stands on a 4-cm table top: 20 cm lower, its base crosses the top (2 cm deep at its middle)."""
    with pytest.raises(RigError) as err:
        _cell_with_base_z(name, -0.20)
    msg = str(err.value)
    assert f"into the static object {table!r}" in msg and "robot.base" in msg and "\n" not in msg
    assert float(msg.split(" reaches ")[1].split(" cm")[0]) == pytest.approx(deep_cm, abs=0.3)


@pytest.mark.parametrize("name", ["flacco-cell", "ur3-cell"])
@pytest.mark.parametrize("dz, ok", [(0.0, True), (-0.005, True), (0.05, True), (-0.03, False)])
def test_a_base_standing_on_its_table_is_allowed_within_one_centimetre(name, dz, ok):
    if ok:
        assert _cell_with_base_z(name, dz).robot is not None
    else:
        with pytest.raises(RigError, match="contact up to 1 cm is allowed"):
            _cell_with_base_z(name, dz)
