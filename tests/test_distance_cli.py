"""``depthguard distance``: hand-checked output on a written depth image, one-line errors."""

import json
import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

from depthguard.cli import app
from depthguard.cli.distance import read_points_csv
from depthguard.depth_io import write_depth

RIG = """
name: one
workspace: {min: [-1, -1, 0], max: [1, 1, 4]}
cameras:
  - id: cam0
    width: 64
    height: 48
    fx: 50.0
    fy: 50.0
    cx: 31.5
    cy: 23.5
    range: [0.4, 4.0]
    pose: {translation: [0, 0, 0], quaternion: [0, 0, 0, 1]}
"""


@pytest.fixture
def files(tmp_path):
    (tmp_path / "rig.yaml").write_text(RIG)
    write_depth(tmp_path / "cam0.png", np.full((48, 64), 3.0, np.float32))   # wall at z = 3 m
    (tmp_path / "pts.csv").write_text("x,y,z\n0,0,2.7\n0,0,1.0  # too far from the wall\n0,0,-1\n")
    return tmp_path


def test_distance_json_hand_checked(files):
    r = CliRunner().invoke(app, ["distance", "--rig", str(files / "rig.yaml"), "--depth", f"cam0={files / 'cam0.png'}",
                                 "--points", str(files / "pts.csv"), "--rho", "0.4", "--method", "min", "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.output)["results"]
    assert [o["point"] for o in out] == [0, 1, 2]
    assert out[0]["distance"] == pytest.approx(0.3, abs=1e-6) and out[0]["observed"]
    np.testing.assert_allclose(out[0]["direction"], [0, 0, 1], atol=1e-9)
    assert out[1]["distance"] is None and not out[1]["obstacle_within_rho"] and out[1]["observed"]
    assert out[2]["distance"] is None and not out[2]["observed"]          # behind the camera


def test_distance_table_output(files):
    r = CliRunner().invoke(app, ["distance", "--rig", str(files / "rig.yaml"), "--depth", f"cam0={files / 'cam0.png'}",
                                 "--points", str(files / "pts.csv")])
    assert r.exit_code == 0, r.output
    assert "none within rho" in r.output and "cannot judge" in r.output


@pytest.mark.parametrize("args, msg", [
    (["--depth", "cam0"], "CAMERA=FILE"),
    (["--depth", "cam7={d}/cam0.png"], "no camera 'cam7'"),
    (["--depth", "cam0={d}/cam0.png", "--robot-joints", "0,0"], "has no robot"),
    (["--depth", "cam0={d}/cam0.png", "--rho", "0"], "rho"),
    (["--depth", "cam0={d}/cam0.png", "--method", "nearest"], "method"),
])
def test_distance_errors_are_one_line(files, args, msg):
    args = [a.format(d=files) for a in args]
    res = subprocess.run([sys.executable, "-m", "depthguard.cli.__main__", "distance", "--rig", str(files / "rig.yaml"),
                          "--points", str(files / "pts.csv"), *args], capture_output=True, text=True)
    assert res.returncode == 2, res.stderr
    assert msg in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1


def test_points_csv_errors(tmp_path):
    p = tmp_path / "p.csv"
    p.write_text("1,2,3\n4,5\n")
    with pytest.raises(ValueError, match=r"p.csv:2"):
        read_points_csv(p)
    p.write_text("1,2,3\n4,x,6\n")
    with pytest.raises(ValueError, match=r"p.csv:2"):
        read_points_csv(p)
    p.write_text("# nothing\n")
    with pytest.raises(ValueError, match="no points"):
        read_points_csv(p)
    with pytest.raises(FileNotFoundError):
        read_points_csv(tmp_path / "missing.csv")
    p.write_text("x;y;z\n1;2;3\n")
    np.testing.assert_array_equal(read_points_csv(p), [[1, 2, 3]])
