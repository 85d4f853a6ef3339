"""docs/OWN_CELL.md runs as written (issue 33: "its rig file lives in the repository and a test
loads it and runs each command of the tutorial on it").

The commands are taken from the tutorial itself (every line of its ```sh blocks), so the
tutorial cannot drift from the program. They run in order (the replay reads the bag the record
wrote) from a scratch folder that sees the repository's ``examples/``, with the CLI of this
checkout, each through the program's entry point as written, one after another in one process
(tests/tutorial_shell.py: one import and one load of numba's cache instead of one per command);
each must exit 0 and leave what the tutorial says it writes. The ```sh device block
needs a RealSense camera: without one each of its commands must stop with one line (exit 2,
no traceback). The rig's numbers are checked against the file's own YAML (independent of the
loader): the robot's joints from the URDF, the fixture in metres.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
TUTORIAL = ROOT / "docs" / "OWN_CELL.md"
RIG = ROOT / "examples" / "own_cell" / "cell.yaml"
DG = [sys.executable, "-m", "depthguard.cli"]


def blocks(kind: str) -> list[list[str]]:
    """The command lines of the tutorial's fenced blocks ```KIND (``sh`` or ``sh device``)."""
    found = re.findall(r"^```([^\n]*)\n(.*?)^```", TUTORIAL.read_text(), flags=re.S | re.M)
    return [[ln for ln in body.splitlines() if ln.strip() and not ln.startswith("#")]
            for info, body in found if info.strip() == kind]


def _env() -> dict:
    return {**os.environ, "PYTHONPATH": str(ROOT / "src") + os.pathsep + os.environ.get("PYTHONPATH", ""),
            "COLUMNS": "200"}


def _run(line: str, cwd: Path) -> subprocess.CompletedProcess:
    args = shlex.split(line)
    assert args[0] == "depthguard", line
    return subprocess.run(DG + args[1:], cwd=cwd, env=_env(), capture_output=True, text=True, timeout=900)


def _run_all(lines: list[str], cwd: Path) -> list[dict]:
    """``lines`` run in order by tests/tutorial_shell.py in one process from ``cwd``: per line run
    (up to the first that fails) its exit status and what it wrote."""
    results = cwd / ".tutorial-results.json"
    res = subprocess.run([sys.executable, str(Path(__file__).with_name("tutorial_shell.py")), str(results), *lines],
                         cwd=cwd, env=_env(), capture_output=True, text=True, timeout=1800)
    assert res.returncode == 0 and results.is_file(), f"{res.stdout[-2000:]}\n{res.stderr[-3000:]}"
    return json.loads(results.read_text())


def test_the_tutorial_names_its_rig_and_the_rig_is_what_it_says():
    text = TUTORIAL.read_text()
    assert "examples/own_cell/cell.yaml" in text
    spec = yaml.safe_load(RIG.read_text())
    assert [c["sensor"] for c in spec["cameras"]] == ["realsense_d435"] * 2
    fixture = next(o for o in spec["objects"] if o["name"] == "fixture")
    assert fixture["scale"] == 0.001
    import trimesh                                          # the independent reader of the STL
    extent = trimesh.load(RIG.parent / fixture["mesh"]).extents * fixture["scale"]
    assert 0.1 < extent.max() < 1.0                          # millimetres made metres: a 0.3 m fixture
    from depthguard.rig import Rig
    rig = Rig.load(RIG)
    assert rig.robot.dof == len(spec["robot"]["joints"]) == 6
    assert list(rig.robot.joint_names) == ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
                                           "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]
    np.testing.assert_allclose(rig.robot_q0, spec["robot"]["joints"])
    # every yaml block of the tutorial is a part of the shipped rig, as shipped
    shipped = spec
    for snippet in re.findall(r"```yaml\n(.*?)```", text, flags=re.S):
        part = yaml.safe_load(snippet)
        for key, value in part.items():
            if isinstance(value, list):
                for item in value:
                    assert item in shipped[key], (key, item)
            else:
                assert value == shipped[key], key


@pytest.mark.slow
def test_every_command_of_the_tutorial_runs(tmp_path):
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    commands = [ln for b in blocks("sh") for ln in b]
    assert len(commands) >= 8, commands
    if shutil.which("chromium") is None and shutil.which("chromium-browser") is None:
        commands = [ln for ln in commands if "--screenshot" not in ln]     # the view's photograph needs Chromium
    done = _run_all(commands, tmp_path)
    for res in done:
        assert res["code"] == 0, f"{res['line']}\n{res['stdout'][-2000:]}\n{res['stderr'][-3000:]}"
        assert "Traceback" not in res["stderr"], res["stderr"]
    assert [r["line"] for r in done] == commands
    out = tmp_path / "out" / "own_cell"
    assert {p.name for p in (out / "render").iterdir()} >= {"left.png", "right.png", "contact_sheet.png"}
    for run in ("sim", "replay"):
        summary = json.loads((out / run / "summary.json").read_text())
        assert summary["cycles"] > 400, (run, summary["cycles"])        # 1 s at 500 Hz
    assert (out / "bag" / "metadata.yaml").is_file()
    assert (out / "reach" / "summary.json").is_file()


@pytest.mark.slow
def test_the_real_sensor_commands_say_in_one_line_that_no_camera_is_there(tmp_path):
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    commands = [ln for b in blocks("sh device") for ln in b]
    assert len(commands) == 2, commands
    for line in commands:
        res = _run(line, tmp_path)
        if res.returncode == 0:                                # a camera is connected: it ran
            continue
        assert res.returncode == 2, f"{line}\n{res.stderr}"
        lines = [ln for ln in res.stderr.strip().splitlines() if ln.strip()]
        assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr


def test_a_package_urdf_that_is_nowhere_is_one_sentence(tmp_path):
    from depthguard.rig import Rig, RigError

    bad = tmp_path / "cell.yaml"
    bad.write_text(RIG.read_text().replace("package://example-robot-data/robots/ur_description/urdf/ur5_robot.urdf",
                                           "package://my_robot_description/urdf/my_robot.urdf"))
    (tmp_path / "meshes").symlink_to(RIG.parent / "meshes")
    with pytest.raises(RigError, match=r"robot\.urdf: cannot find 'package://my_robot_description/urdf/"
                                       r"my_robot\.urdf'.*ROS_PACKAGE_PATH"):
        Rig.load(bad)
