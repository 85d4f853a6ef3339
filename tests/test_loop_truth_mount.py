"""The closed loop's ground truth knows what the robot is mounted on (issue 33 item 5, R15).

A UR5 from example-robot-data stands on a table top: the capsules fitted to its shoulder and
upper arm overhang their meshes and reach up to 4 mm into the table in every pose, which
``run --rig`` reported as a collision (min true distance -0.4 cm). The table still counts
against every capsule point that can move towards it, and against everything else."""

import json

import numpy as np
import pytest
import yaml

from depthguard.geometry import Box, Sphere
from depthguard.robot.urdf import example_robot_data_dir

ERD = example_robot_data_dir()
if ERD is None or not (ERD / "robots" / "ur_description" / "urdf" / "ur5_robot.urdf").is_file():
    pytest.skip("example-robot-data's UR5 is not installed", allow_module_level=True)

UR5 = ERD / "robots" / "ur_description" / "urdf" / "ur5_robot.urdf"
Q0 = [0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0]


def _rig(path):
    rig = {"name": "my-ur5", "workspace": {"min": [-1.2, -1.2, 0.0], "max": [1.2, 1.2, 2.0]},
           "cameras": [{"id": "front", "sensor": "realsense_d435", "width": 424, "height": 240,
                        "pose": {"look_at": {"eye": [1.6, -1.2, 1.8], "target": [0.0, 0.0, 0.9]}}}],
           "robot": {"urdf": str(UR5), "base": {"translation": [0.0, 0.0, 0.8]}, "joints": Q0},
           "objects": [{"name": "table", "box": {"size": [1.2, 0.8, 0.04]}, "pose": {"translation": [0, 0, 0.78]}}]}
    path.write_text(yaml.safe_dump(rig))
    return path


@pytest.fixture(scope="module")
def ur5(tmp_path_factory):
    from depthguard.rig import Rig

    return Rig.load(_rig(tmp_path_factory.mktemp("ur5") / "rig.yaml"))


def test_the_capsules_overhang_into_the_table_the_robot_stands_on(ur5):
    """The premise, measured: at the rig joints the shoulder capsule is 3.9 mm into the table top."""
    ab, r = ur5.robot.collision_segments(np.array(Q0))
    names = [c.link for c in ur5.robot.capsules]
    i = names.index("shoulder_link")
    pts = ab[i, 0] + np.linspace(0, 1, 50)[:, None] * (ab[i, 1] - ab[i, 0])
    assert ur5.objects[0].primitive.sdf(pts).min() - r[i] < -0.003


def test_the_truth_leaves_out_the_mount_contact_and_keeps_every_other(ur5):
    from depthguard.evaluation.closed_loop.loop_truth import LoopTruth

    table = ur5.objects[0].primitive
    q = np.array(Q0)
    truth = LoopTruth(ur5.robot, [table], q, 0.01)
    P = ur5.robot.control_point_positions(q)
    _, d_robot, _ = truth(P, q, [])
    assert d_robot > 0.0                                       # standing on its table is no collision
    assert any("shoulder_link against table" in e for e in truth.excluded)
    # the upper arm swung down to the table top: a collision, the mount or not
    down = q.copy()
    down[1] = 0.25                                             # shoulder lift: the arm below horizontal
    _, d_down, _ = truth(ur5.robot.control_point_positions(down), down, [])
    assert d_down < 0.0
    # a box on the table beside the base, in the shoulder capsule's reach: counted
    box = Box(size=(0.1, 0.1, 0.1), world_from_local=np.array([[1, 0, 0, 0.0], [0, 1, 0, 0.0], [0, 0, 1, 0.88],
                                                                  [0, 0, 0, 1.0]]), name="box")
    truth2 = LoopTruth(ur5.robot, [table], q, 0.01)
    _, d_box, d_box_moving = truth2(P, q, [box])
    assert d_box < 0.0 and d_box_moving < 0.0                  # a moving object on the mount's contact points
    # a static sphere that only the shoulder touches is no mount: it never stays in contact
    ball = Sphere(radius=0.05, world_from_local=np.array([[1, 0, 0, 0.13], [0, 1, 0, 0.0], [0, 0, 1, 0.85],
                                                           [0, 0, 0, 1.0]]), name="ball")
    truth3 = LoopTruth(ur5.robot, [table, ball], q, 0.01)
    _, d_ball, _ = truth3(P, q, [])
    assert d_ball < 0.0 and not any("ball" in e for e in truth3.excluded)


@pytest.mark.slow
def test_run_rig_reports_no_collision_for_a_ur5_on_its_table(tmp_path):
    from typer.testing import CliRunner

    from depthguard.cli import app

    out = tmp_path / "run"
    res = CliRunner().invoke(app, ["run", "--rig", str(_rig(tmp_path / "rig.yaml")), "-s", "empty", "--duration",
                                   "0.5", "-o", str(out), "--no-noise", "--quiet"])
    assert res.exit_code == 0, res.output
    s = json.loads((out / "summary.json").read_text())
    assert s["collision"] is False and s["min_true_distance_m"] > 0.0, s["min_true_distance_m"]
    assert "no collision" in res.output
