"""The camera units and the free-space map take the rig's learned scene (issue 31 point 2).

Truth: the CAD. A rig file of flacco-cell at 160x120 with its CAD objects, and the same rig
without them naming a learned scene (``scene: {learned: DIR}``) whose depth is the CAD's own
expected depth at each camera: a ``depthguard node`` unit built from either must filter a frame
(people in the cell, the robot moving) to the same voxels, and differ from a unit with no known
scene (the table and floor kept). A learned scene of another size than ``--resolution`` is refused
with one sentence. The runtime free-space map's background is the known scene's whichever way it
is known.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from depthguard.filtering.expected import ExpectedDepth
from depthguard.geometry.primitives import Box
from depthguard.learned_scene import LearnedScene, save
from depthguard.rig import Rig
from depthguard.sensors import depth_sigma, intrinsics_for
from depthguard.sim import load_cell
from depthguard.sources import SimulatedCamera


def _write_rigs(tmp_path):
    from importlib.resources import files

    data = yaml.safe_load((files("depthguard") / "data" / "cells" / "flacco-cell.yaml").read_text())
    k = intrinsics_for("kinect_v1", 640, 480)
    for c in data["cameras"]:                     # a quarter of the pixels per side, same field of view
        c.update(width=160, height=120, fx=k["fx"] / 4, fy=k["fy"] / 4, cx=(k["cx"] + 0.5) / 4 - 0.5,
                 cy=(k["cy"] + 0.5) / 4 - 0.5)
    (tmp_path / "cad.yaml").write_text(yaml.safe_dump(data))
    cad_rig = Rig.load(tmp_path / "cad.yaml")
    cad = list(cad_rig.static_meshes())
    scenes = {}
    for cam in cad_rig.cameras:
        d = ExpectedDepth(cam, None, cad).static.astype(np.float32)
        s = np.where(d > 0, depth_sigma(cam, d), 0).astype(np.float32)
        scenes[cam.id] = LearnedScene(cam, d, s, np.full(cam.shape, 9, np.uint16), 9)
    save(tmp_path / "learned", scenes, {"source": "the CAD's expected depth (test)"})
    bare = dict(data)
    bare.pop("objects")
    (tmp_path / "none.yaml").write_text(yaml.safe_dump(bare))
    bare["scene"] = {"learned": "learned"}
    (tmp_path / "learned.yaml").write_text(yaml.safe_dump(bare))
    return cad_rig


def _person():
    return Box.from_bounds([0.4, -0.75, -0.85], [0.8, -0.45, 0.85], name="person").mesh()


def test_a_node_filters_with_the_learned_scene_as_with_cad(tmp_path):
    from depthguard.distributed.node import build_node
    from loopback import free_port

    cad_rig = _write_rigs(tmp_path)
    ep = f"tcp/127.0.0.1:{free_port()}"
    cam = cad_rig.camera("cam0")
    robot = cad_rig.robot
    q = np.asarray(cad_rig.robot_q0, float) + 0.3
    d = SimulatedCamera(cam, seed=3).capture(list(cad_rig.static_meshes()) + list(robot.link_meshes(q)) + [_person()],
                                             stamp=1.0)
    keys = {}
    for name in ("cad", "learned", "none"):
        node = build_node(str(tmp_path / f"{name}.yaml"), "cam0", "pattern", connect=[ep])
        try:
            keys[name] = {tuple(k) for k in node.filter.filter(d, q).keys}
        finally:
            node.close()
    assert keys["cad"] and keys["cad"] == keys["learned"]
    assert len(keys["none"] - keys["cad"]) > 0.3 * len(keys["cad"])    # the known scene matters here
    with pytest.raises(ValueError, match=r"--resolution 640x480: camera cam0's learned scene .* learned at 160x120"):
        build_node(str(tmp_path / "learned.yaml"), "cam0", "pattern", resolution=(640, 480), connect=[ep])


def test_the_free_space_background_is_the_learned_scene(tmp_path):
    """The runtime map's background with the learned scene in place of the CAD is the CAD's, and a
    map built from the same frames gives every voxel the CAD rig's state; without a known scene
    it does not."""
    from depthguard.runtime.free_space_map import RuntimeFreeSpace

    cad_rig = _write_rigs(tmp_path)
    maps = {name: RuntimeFreeSpace(Rig.load(tmp_path / f"{name}.yaml")) for name in ("cad", "learned", "none")}
    for cam in cad_rig.cameras:
        np.testing.assert_array_equal(maps["learned"].backgrounds[cam.id], maps["cad"].backgrounds[cam.id])
    robot = cad_rig.robot
    q = np.asarray(cad_rig.robot_q0, float) + 0.3
    meshes = list(cad_rig.static_meshes()) + list(robot.link_meshes(q)) + [_person()]
    depths = {c.id: SimulatedCamera(c, seed=5).capture(meshes, stamp=1.0) for c in cad_rig.cameras}
    rd = {c.id: np.array(ExpectedDepth(c, robot).robot(q)) for c in cad_rig.cameras}
    st = {name: m.build(depths, rd, q).state for name, m in maps.items()}
    np.testing.assert_array_equal(st["learned"], st["cad"])
    assert np.count_nonzero(st["none"] != st["cad"]) > 100
