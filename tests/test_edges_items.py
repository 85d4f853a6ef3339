"""Issue 20, silent wrong answers at the edges: each one is now a clear error or a correct answer.

Every test here failed on the code before the fix (checked by running it first):

1. a typo on the first line of a points CSV was taken for a header (a point vanished);
2. depth in the wrong units (an ``.npy`` in millimetres, a 16-bit PNG holding metres)
   gave distances with no hint;
3. ``depthguard distance`` said ``"obstacle_within_rho": false`` for a point no camera
   can judge (SPEC §7, R26);
4. ``--robot-joints`` outside the robot's joint limits was accepted;
5. a negative mesh ``scale`` and a ``look_at`` whose ``up`` is parallel to the view were
   accepted when the rig loaded;
6. ``reproduce ... --out`` was checked only after the computation.

The truths are independent of the code under test: hand-checked geometry (a wall at
3 m seen by a camera at the origin), the robot model's own joint limits, the camera's
range written in the rig.
"""

import json

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from depthguard.cli import app
from depthguard.cli.distance import read_points_csv
from depthguard.depth_io import write_depth
from depthguard.rig import Rig, RigError

CAMERA = {"id": "cam0", "width": 64, "height": 48, "fx": 50.0, "fy": 50.0, "cx": 31.5, "cy": 23.5,
          "range": [0.4, 4.0], "pose": {"translation": [0, 0, 0], "quaternion": [0, 0, 0, 1]}}


def write_rig(path, **extra):
    rig = {"name": "one", "workspace": {"min": [-1, -1, 0], "max": [1, 1, 4]}, "cameras": [CAMERA]}
    rig.update(extra)
    path.write_text(yaml.safe_dump(rig))
    return path


def run(args):
    """The CLI as ``depthguard.cli.main`` runs it: a ValueError is the one-line exit-2 error."""
    r = CliRunner().invoke(app, [str(a) for a in args])
    if r.exception is not None and not isinstance(r.exception, SystemExit):
        assert isinstance(r.exception, (ValueError, FileNotFoundError)), repr(r.exception)
        return 2, str(r.exception)
    return r.exit_code, r.output


@pytest.fixture
def cell(tmp_path):
    write_rig(tmp_path / "rig.yaml")
    write_depth(tmp_path / "wall.png", np.full((48, 64), 3.0, np.float32))     # a wall at z = 3 m
    (tmp_path / "pts.csv").write_text("0,0,2.7\n")
    return tmp_path


# ------------------------------------------------------------ 1. points CSV header
@pytest.mark.parametrize("first", ["0.0,0.19,1.49x", "O.0,0.19,1.49", "1.0,2.0", "x,y,1.5", "0,0,zz"])
def test_a_typo_on_the_first_line_is_not_a_header(tmp_path, first):
    p = tmp_path / "pts.csv"
    p.write_text(f"{first}\n0.1,0.2,0.3\n0.4,0.5,0.6\n")
    with pytest.raises(ValueError, match=r"pts\.csv:1:"):
        read_points_csv(p)


@pytest.mark.parametrize("header", ["x,y,z", "x_m, y_m, z_m", "X;Y;Z", "# points\nx,y,z", "\nx [m],y [m],z [m]"])
def test_a_real_header_is_skipped(tmp_path, header):
    p = tmp_path / "pts.csv"
    p.write_text(f"{header}\n0.1,0.2,0.3\n0.4,0.5,0.6\n")
    np.testing.assert_array_equal(read_points_csv(p), [[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]])


# ------------------------------------------------------------ 2. depth in the wrong units
def test_millimetres_in_an_npy_are_refused_with_the_numbers(cell):
    np.save(cell / "mm.npy", np.full((48, 64), 3000.0, np.float32))          # 3 m written as mm
    code, out = run(["distance", "--rig", cell / "rig.yaml", "--depth", f"cam0={cell / 'mm.npy'}",
                     "--points", cell / "pts.csv", "--json"])
    assert code == 2, out
    assert "cam0" in out and "100 %" in out and "12 m" in out and "3000" in out and "millimetres" in out


def test_metres_in_a_png_are_refused_with_the_numbers(cell):
    from PIL import Image

    Image.fromarray(np.full((48, 64), 3, np.uint16)).save(cell / "m.png")    # 3 m written as 3 "mm"
    code, out = run(["distance", "--rig", cell / "rig.yaml", "--depth", f"cam0={cell / 'm.png'}",
                     "--points", cell / "pts.csv", "--json"])
    assert code == 2, out
    assert "cam0" in out and "100 %" in out and "0.1 m" in out and "0.003" in out and "metres" in out


def test_the_flag_accepts_out_of_range_depth_as_it_is(cell):
    np.save(cell / "mm.npy", np.full((48, 64), 3000.0, np.float32))
    code, out = run(["distance", "--rig", cell / "rig.yaml", "--depth", f"cam0={cell / 'mm.npy'}",
                     "--points", cell / "pts.csv", "--json", "--accept-out-of-range"])
    assert code == 0, out
    res = json.loads(out)["results"][0]
    # a depth beyond 3 x max_range is no return: unknown space from the near range -> distance 0
    assert res["observed"] and res["distance"] == 0.0


def test_depth_in_range_is_not_refused(cell):
    code, out = run(["distance", "--rig", cell / "rig.yaml", "--depth", f"cam0={cell / 'wall.png'}",
                     "--points", cell / "pts.csv", "--json", "--method", "min"])
    assert code == 0, out
    assert json.loads(out)["results"][0]["distance"] == pytest.approx(0.3, abs=1e-6)


# ------------------------------------------------------------ 3. cannot judge != none within rho
def test_distance_keeps_cannot_judge_apart_from_nothing_within_rho(cell):
    # (0,0,2.7): 0.3 m from the wall; (0,0,1.0): observed, nothing within rho; (0,0,-1): behind the camera;
    # (1.9,0,2.9): just outside the image (x/z = 0.655 > 32/50), near the edge of the wall it sees
    (cell / "pts.csv").write_text("0,0,2.7\n0,0,1.0\n0,0,-1\n1.9,0,2.9\n")
    args = ["distance", "--rig", cell / "rig.yaml", "--depth", f"cam0={cell / 'wall.png'}",
            "--points", cell / "pts.csv", "--method", "min"]
    code, out = run(args + ["--json"])
    assert code == 0, out
    near, clear, unseen, edge = json.loads(out)["results"]
    assert (near["verdict"], near["obstacle_within_rho"]) == ("obstacle", True)
    assert (clear["verdict"], clear["obstacle_within_rho"]) == ("clear", False)
    assert (unseen["verdict"], unseen["obstacle_within_rho"]) == ("cannot_judge", None)
    assert not unseen["observed"] and unseen["distance"] is None
    # unobserved, but the wall's edge is seen within rho: the corner (0.64 * 3 m, 3 m) of the frustum
    assert (edge["verdict"], edge["obstacle_within_rho"], edge["observed"]) == ("cannot_judge", True, False)
    assert edge["distance"] == pytest.approx(np.hypot(0.64 * 3 - 1.9, 3 - 2.9), abs=1e-9)
    code, table = run(args)
    assert code == 0, table
    rows = [ln for ln in table.splitlines() if "cam0" in ln]
    assert len(rows) == 4
    assert "none within rho" in rows[1] and "cannot judge" not in rows[1]
    assert "none within rho" not in rows[2] and "cannot judge" in rows[2]
    assert "<= 0.1020 (cannot judge)" in rows[3]


# ------------------------------------------------------------ 4. --robot-joints outside the limits
def test_robot_joints_outside_the_limits_are_refused_with_the_limits(cell):
    from depthguard.robot import load_robot

    write_rig(cell / "robot.yaml", robot={"name": "lwr4", "base": {"translation": [0, 0, 3.5]}})
    lwr = load_robot("lwr4")
    q = [0.0] * lwr.dof
    q[3] = float(lwr.q_max[3]) + 0.1                      # joint 4 just beyond its upper limit
    code, out = run(["distance", "--rig", cell / "robot.yaml", "--depth", f"cam0={cell / 'wall.png'}",
                     "--points", cell / "pts.csv", "--robot-joints", ",".join(f"{v:.4f}" for v in q)])
    assert code == 2, out
    assert "--robot-joints" in out and "[3]" in out
    assert f"{lwr.q_min[3]:.4f}" in out and f"{lwr.q_max[3]:.4f}" in out
    q[3] = float(lwr.q_max[3]) - 0.1                      # inside: accepted
    code, out = run(["distance", "--rig", cell / "robot.yaml", "--depth", f"cam0={cell / 'wall.png'}",
                     "--points", cell / "pts.csv", "--robot-joints", ",".join(f"{v:.4f}" for v in q)])
    assert code == 0, out


# ------------------------------------------------------------ 5. rig fields refused when it loads
TETRA_OBJ = "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"


@pytest.mark.parametrize("scale", [-1.0, 0.0, [1.0, -1.0, 1.0], [1.0, 1.0, 0.0]])
def test_a_mesh_scale_that_mirrors_or_flattens_is_refused(tmp_path, scale):
    (tmp_path / "tetra.obj").write_text(TETRA_OBJ)
    p = write_rig(tmp_path / "rig.yaml", objects=[{"name": "fixture", "mesh": "tetra.obj", "scale": scale}])
    with pytest.raises(RigError, match=r"objects\[0\]\.scale"):
        Rig.load(p)


def test_a_positive_mesh_scale_loads(tmp_path):
    (tmp_path / "tetra.obj").write_text(TETRA_OBJ)
    p = write_rig(tmp_path / "rig.yaml", objects=[{"name": "fixture", "mesh": "tetra.obj", "scale": [2, 1, 1]}])
    lo, hi = Rig.load(p).objects[0].mesh.bounds
    np.testing.assert_allclose(hi - lo, [0.2, 0.1, 0.1])


@pytest.mark.parametrize("up", [[0, 0, 1], [0, 0, -2], [0, 0, 0]])
def test_look_at_up_along_the_view_is_refused(tmp_path, up):
    cam = dict(CAMERA, pose={"look_at": {"eye": [0, 0, 3], "target": [0, 0, 0], "up": up}})
    p = tmp_path / "rig.yaml"
    p.write_text(yaml.safe_dump({"workspace": {"min": [-1, -1, 0], "max": [1, 1, 2]}, "cameras": [cam]}))
    with pytest.raises(RigError, match=r"cameras\[0\]\.pose\.look_at\.up"):
        Rig.load(p)


def test_look_at_with_a_usable_up_loads(tmp_path):
    cam = dict(CAMERA, pose={"look_at": {"eye": [0, 0, 3], "target": [0, 0, 0], "up": [0, 1, 0]}})
    p = tmp_path / "rig.yaml"
    p.write_text(yaml.safe_dump({"workspace": {"min": [-1, -1, 0], "max": [1, 1, 2]}, "cameras": [cam]}))
    R = Rig.load(p).cameras[0].world_from_camera[:3, :3]
    np.testing.assert_allclose(R[:, 2], [0, 0, -1], atol=1e-12)     # looks down
    np.testing.assert_allclose(R[:, 1], [0, -1, 0], atol=1e-12)     # image y against up


# ------------------------------------------------------------ 6. reproduce --out checked first
@pytest.mark.parametrize("command, runner", [
    ("flacco2014", "depthguard.evaluation.flacco2014.run_flacco2014"),
    ("flacco2015", "depthguard.evaluation.flacco2015.run_flacco2015"),
    ("hamersma2011", "depthguard.evaluation.hamersma2011.run"),
])
@pytest.mark.parametrize("bad", ["/dev/null/x", "FILE"])
def test_reproduce_checks_its_output_folder_before_computing(tmp_path, monkeypatch, command, runner, bad):
    calls = []
    module, name = runner.rsplit(".", 1)
    monkeypatch.setattr(__import__(module, fromlist=[name]), name, lambda *a, **k: calls.append(1))
    if bad == "FILE":
        bad = tmp_path / "results.md"
        bad.write_text("kept\n")                              # a file already stored there
    code, out = run(["reproduce", command, "--out", bad])
    assert code == 2 and "--out" in out and str(bad) in out, out
    assert calls == [], "the computation ran before the output folder was checked"
    if str(bad).endswith("results.md"):
        assert bad.read_text() == "kept\n"


def test_the_monitor_refuses_metres_in_a_millimetre_image_with_the_same_check():
    """The monitor's ``bad_units`` refusal is the same check: a frame whose depth was written as
    metres into a millimetre image (every value 1000 times too small) is refused and says so."""
    from depthguard.filtering.expected import ExpectedDepth
    from depthguard.runtime.monitor import Monitor
    from depthguard.sim import load_cell
    from depthguard.sources.frame import Frame

    rig = load_cell("flacco-cell").rig
    q0 = np.asarray(rig.robot_q0, dtype=np.float64)
    cam = rig.cameras[0]
    still = np.array(ExpectedDepth(cam, rig.robot, rig.static_meshes()).known(q0), copy=True)
    with Monitor(rig, rig.monitor.with_changes(invalid="free")) as mon:
        mon.push_joints(0.0, q0)
        mon.push_joints(0.002, q0)
        mon.push_frame(Frame(cam.id, still / 1000.0, 0.001))
        mon.flush()
        st = mon.stats()["cameras"][cam.id]
        assert st["refused"] == {"bad_units": 1} and "hold metres" in st["last_refusal"]
        assert cam.id not in mon.step(0.002).frame_stamps
