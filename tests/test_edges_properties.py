"""Issue 20: property tests (hypothesis) for every loader of outside input.

For points CSV files, depth files, rig files and the arguments of ``depthguard distance``:
no input gives a traceback (only the loader's ``ValueError`` / ``FileNotFoundError``,
which the CLI prints as one line), and no malformed input gives an answer. The oracles
are the formats as documented (``read_points_csv``, ``depth_io``, ``docs/ARCHITECTURE.md``),
written here independently of the loaders: a file is generated from known values, or
from known values with one known defect.
"""

import contextlib
import io
import string
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, assume, event, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from depthguard.cli.distance import read_points_csv
from depthguard.depth_io import DepthFileError, read_depth
from depthguard.rig import Rig, RigError

FAST = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                        HealthCheck.too_slow])


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    return tmp_path_factory.mktemp("edges")


def _write(workdir: Path, name: str, data) -> Path:
    p = workdir / name
    if isinstance(data, bytes):
        p.write_bytes(data)
    else:
        p.write_text(data)
    return p


# ------------------------------------------------------------------ points CSV
coordinate = st.floats(-20.0, 20.0, allow_nan=False, allow_infinity=False)
point = st.tuples(coordinate, coordinate, coordinate)
name = st.text(string.ascii_letters + "_", min_size=1, max_size=3).map(lambda s: s + " [m]").filter(
    lambda s: s.split(" ")[0].lower() not in ("nan", "inf"))


@st.composite
def points_file(draw):
    """``(text, points, data_line_numbers)``: a CSV of known points with a header or not,
    ``,`` or ``;``, spaces, comments and blank lines."""
    pts = draw(st.lists(point, min_size=1, max_size=12))
    sep = draw(st.sampled_from([",", ";", ", ", " ; "]))
    lines, numbers = [], []
    if draw(st.booleans()):
        lines.append("# control points")
    if draw(st.booleans()):
        lines.append(sep.join(draw(st.tuples(name, name, name))))
    for p in pts:
        if draw(st.integers(0, 4)) == 0:
            lines.append(draw(st.sampled_from(["", "   ", "# a comment"])))
        comment = draw(st.sampled_from(["", "  # hand", "#x"]))
        lines.append(sep.join(repr(v) for v in p) + comment)
        numbers.append(len(lines))
    return "\n".join(lines) + "\n", np.array(pts), numbers


@FAST
@given(points_file())
def test_points_csv_reads_back_the_points_written(workdir, case):
    text, pts, _ = case
    np.testing.assert_array_equal(read_points_csv(_write(workdir, "pts.csv", text)), pts)


def _corrupt(field: str, kind: int) -> list[str]:
    return [
        [field + "x", "0", "0"],            # a typo after a number
        [field, "0"],                      # a missing coordinate
        [field, "0", "0", "1"],            # one too many
        ["nan", "0", field],               # not finite
        ["0", "inf", field],
        ["", field, "0"],                  # an empty field
        [field.replace("0", "O").replace("1", "l") + "O", "1", "2"],   # letters for digits
    ][kind]


@FAST
@given(points_file(), st.data())
def test_points_csv_with_one_bad_line_is_refused_naming_the_line(workdir, case, data):
    text, _, numbers = case
    lines = text.splitlines()
    k = data.draw(st.sampled_from(numbers))
    field = repr(data.draw(coordinate))
    bad = _corrupt(field, data.draw(st.integers(0, 6)))
    lines[k - 1] = data.draw(st.sampled_from([",", ";"])).join(bad)
    with pytest.raises(ValueError, match=rf"pts\.csv:{k}:"):
        read_points_csv(_write(workdir, "pts.csv", "\n".join(lines) + "\n"))


@FAST
@given(st.one_of(st.text(max_size=200), st.binary(max_size=200)))
def test_points_csv_any_content_is_points_or_one_error(workdir, content):
    try:
        pts = read_points_csv(_write(workdir, "any.csv", content))
    except ValueError as exc:          # UnicodeDecodeError included
        assert str(exc)
        return
    assert pts.ndim == 2 and pts.shape[1] == 3 and len(pts) >= 1 and np.isfinite(pts).all()


# ------------------------------------------------------------------ depth files
DTYPES = [np.float32, np.float64, np.float16, np.uint16, np.int16, np.int32, np.uint8, np.bool_, np.complex64]


@FAST
@given(st.sampled_from(DTYPES).flatmap(
    lambda dt: arrays(dt, st.lists(st.integers(0, 5), min_size=0, max_size=3).map(tuple))))
def test_npy_depth_is_a_valid_image_or_one_error(workdir, arr):
    p = workdir / "d.npy"
    np.save(p, arr)
    well_formed = (arr.ndim == 2 and arr.size > 0 and np.issubdtype(arr.dtype, np.floating)
                   and not (np.nan_to_num(arr.astype(np.float64), nan=0.0, posinf=0.0, neginf=-1.0) < 0).any())
    try:
        d = read_depth(p)
    except DepthFileError as exc:
        assert not well_formed, f"refused a well-formed image: {exc}"
        return
    assert well_formed, f"accepted {arr.dtype} {arr.shape}"
    assert d.dtype == np.float32 and d.shape == arr.shape and np.isfinite(d).all() and (d >= 0).all()
    expect = arr.astype(np.float32)
    expect[~np.isfinite(expect)] = 0
    np.testing.assert_array_equal(d, expect)


@FAST
@given(st.sampled_from(["I;16", "L", "RGB", "LA", "P"]), st.integers(1, 6), st.integers(1, 6), st.data())
def test_png_depth_is_millimetres_or_one_error(workdir, mode, w, h, data):
    from PIL import Image

    if mode == "I;16":
        img = Image.fromarray(data.draw(arrays(np.uint16, (h, w))))
    else:
        shape = {"RGB": (h, w, 3), "LA": (h, w, 2)}.get(mode, (h, w))
        img = Image.fromarray(data.draw(arrays(np.uint8, shape)), mode=mode)
    p = workdir / "d.png"
    img.save(p)
    with Image.open(p) as back:
        stored = np.asarray(back).astype(np.int64)
        stored_mode = back.mode
    well_formed = stored.ndim == 2 and stored_mode.startswith("I") and stored.min() >= 0 and stored.max() <= 65535
    try:
        d = read_depth(p)
    except DepthFileError:
        assert not well_formed
        return
    assert well_formed, f"accepted a {stored_mode} PNG"
    np.testing.assert_allclose(d, stored / 1000.0, rtol=1e-6, atol=0)     # float32 metres


@FAST
@given(st.binary(max_size=300), st.sampled_from([".png", ".npy", ".tiff", ""]))
def test_any_bytes_as_a_depth_file_is_one_error_or_an_image(workdir, content, suffix):
    p = _write(workdir, "junk" + suffix, content)
    try:
        d = read_depth(p)
    except DepthFileError as exc:
        assert str(p) in str(exc)
        return
    assert d.ndim == 2 and d.dtype == np.float32 and np.isfinite(d).all() and (d >= 0).all() and d.size > 0


@FAST
@given(st.floats(0.125, 0.625, width=32), st.floats(2.0, 10.0, width=32), st.data())
def test_units_check_tells_metres_from_millimetres(lo, hi, data):
    """Depth inside the camera's range passes; the same depth in millimetres, or metres in a
    millimetre PNG (divided by 1000), is refused with the numbers (R28)."""
    from depthguard.camera import Camera
    from depthguard.depth_io import UNITS_STEP, depth_units_problem

    cam = Camera(id="c", width=16, height=12, fx=10.0, fy=10.0, cx=7.5, cy=5.5, world_from_camera=np.eye(4),
                 min_range=lo, max_range=hi)
    depth = data.draw(arrays(np.float32, (12, 16), elements=st.floats(lo, hi, width=32)))
    holes = data.draw(arrays(np.bool_, (12, 16)))
    depth[holes] = 0.0
    assume((depth[::UNITS_STEP, ::UNITS_STEP] > 0).any())     # the check's sample holds a measurement
    assert depth_units_problem(depth, cam) is None
    assert "millimetres" in depth_units_problem(depth * 1000.0, cam)
    assert "metres" in depth_units_problem(depth / 1000.0, cam)


# ------------------------------------------------------------------ rig files
CAMERA = {"id": "cam0", "width": 64, "height": 48, "fx": 50.0, "fy": 50.0, "cx": 31.5, "cy": 23.5,
          "range": [0.4, 4.0], "pose": {"translation": [0, 0, 0], "quaternion": [0, 0, 0, 1]}}
TETRA_OBJ = "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"


def valid_rig() -> dict:
    return {"name": "prop", "workspace": {"min": [-1, -1, 0], "max": [1, 1, 2]},
            "cameras": [dict(CAMERA, pose=dict(CAMERA["pose"])),
                        {"id": "cam1", "sensor": "kinect_v1",
                         "pose": {"look_at": {"eye": [2, 0, 1.5], "target": [0, 0, 0.5]}}}],
            "robot": {"name": "lwr4", "joints": [0, 0.5, 0, -1, 0, 0.5, 0]},
            "objects": [{"name": "table", "box": {"size": [0.5, 0.5, 0.8]},
                         "pose": {"translation": [0.5, 0, 0.4]}},
                        {"name": "fixture", "mesh": "tetra.obj", "scale": 1.0,      # beside the robot, not in it
                         "pose": {"translation": [-0.5, -0.5, 0.0]}}]}


# (where, value, what the error must name): each value is wrong for its field
DEFECTS = [
    (("cameras", 0, "fx"), v, "cameras[0].fx") for v in (0, -50.0, "fifty", float("nan"), [50])
] + [
    (("cameras", 0, "width"), v, "cameras[0].width") for v in (0, -64, 6.5, "64px")
] + [
    (("cameras", 0, "fx"), None, "missing fx"),
    (("cameras", 0, "cx"), 500.0, "cameras[0]"),
    (("cameras", 0, "range"), [4.0, 0.4], "cameras[0].range"),
    (("cameras", 0, "range"), [-1.0, 4.0], "cameras[0].range"),
    (("cameras", 0, "id"), "side/left", "cameras[0].id"),
    (("cameras", 0, "id"), "", "cameras[0].id"),
    (("cameras", 0, "pose", "quaternion"), [0, 0, 0, 2], "cameras[0].pose"),
    (("cameras", 0, "pose", "translation"), [0, float("nan"), 0], "cameras[0]"),
    (("cameras", 0, "pose", "translation"), [0, 1], "cameras[0].pose.translation"),
    (("cameras", 0, "pose", "matrix"), [[1, 0, 0, 0], [0, 2, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "cameras[0].pose"),
    (("cameras", 0, "lens"), 3, "cameras[0].lens"),
    (("cameras", 1, "sensor"), "kinect_v9", "cameras[1].sensor"),
    (("cameras", 1, "pose", "look_at", "up"), [0.2, 0.0, 0.1], "cameras[1].pose.look_at.up"),
    (("cameras", 1, "pose", "look_at", "target"), [2, 0, 1.5], "cameras[1].pose"),
    (("workspace", "min"), [2, -1, 0], "workspace"),
    (("workspace", "max"), [1, 1], "workspace.max"),
    (("robot", "name"), "lwr9", "robot.name"),
    (("robot", "joints"), [0, 0, 0, 9.0, 0, 0, 0], "robot.joints[3]"),
    (("robot", "joints"), [0, 0, 0], "robot.joints"),
    (("objects", 0, "box", "size"), [0.5, -0.5, 0.8], "objects[0].box.size"),
    (("objects", 1, "scale"), -1.0, "objects[1].scale"),
    (("objects", 1, "scale"), [1, 1, 0], "objects[1].scale"),
    (("objects", 1, "mesh"), "missing.obj", "objects[1].mesh"),
    (("version",), 2, "version"),
]


def _set(d, where, value):
    for k in where[:-1]:
        d = d[k]
    d[where[-1]] = value


@FAST
@given(st.lists(st.sampled_from(range(len(DEFECTS))), min_size=1, max_size=3, unique=True))
def test_a_rig_with_a_defect_is_refused_naming_the_field(workdir, picks):
    _write(workdir, "tetra.obj", TETRA_OBJ)
    rig = valid_rig()
    for i in picks:
        where, value, _ = DEFECTS[i]
        _set(rig, where, value)
    p = workdir / "rig.yaml"
    p.write_text(yaml.safe_dump(rig))
    with pytest.raises(RigError) as err:
        Rig.load(p)
    message = str(err.value)
    assert str(p) in message
    # the first defect the loader reaches is named; every named field is one of the defects
    assert any(DEFECTS[i][2] in message for i in picks), (message, [DEFECTS[i][2] for i in picks])


def test_the_valid_rig_loads(workdir):
    _write(workdir, "tetra.obj", TETRA_OBJ)
    p = workdir / "rig.yaml"
    p.write_text(yaml.safe_dump(valid_rig()))
    rig = Rig.load(p)
    assert rig.camera_ids == ["cam0", "cam1"] and rig.robot.dof == 7 and len(rig.objects) == 2


json_like = st.recursive(
    st.none() | st.booleans() | st.integers(-10, 10) | st.floats(allow_nan=True) | st.text(max_size=6),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(
        st.sampled_from(["name", "workspace", "cameras", "robot", "objects", "min", "max", "id", "fx", "pose",
                         "translation", "width", "sensor", "box", "size", "monitor", "rho", "x"]), inner, max_size=5),
    max_leaves=20)


@FAST
@given(json_like)
def test_any_document_is_a_rig_or_one_rig_error(doc):
    try:
        rig = Rig.from_dict(doc, source="doc.yaml")
    except RigError as exc:
        assert str(exc).startswith("doc.yaml")
        return
    assert rig.cameras                              # a rig always has a camera


@FAST
@given(st.text(max_size=300) | st.binary(max_size=300))
def test_any_file_is_a_rig_or_one_rig_error(workdir, content):
    p = _write(workdir, "any.yaml", content)
    try:
        Rig.load(p)
    except RigError as exc:
        assert str(p) in str(exc)


# ------------------------------------------------------------------ depthguard distance arguments
@pytest.fixture(scope="module")
def distance_files(workdir):
    from PIL import Image

    from depthguard.depth_io import write_depth
    from depthguard.robot import load_robot

    d = workdir / "dist"
    d.mkdir()
    rig = {"name": "one", "workspace": {"min": [-1, -1, 0], "max": [1, 1, 4]}, "cameras": [CAMERA],
           "robot": {"name": "lwr4", "base": {"translation": [0, 0, 3.5]}}}
    (d / "rig.yaml").write_text(yaml.safe_dump(rig))
    (d / "norobot.yaml").write_text(yaml.safe_dump({k: v for k, v in rig.items() if k != "robot"}))
    write_depth(d / "wall.png", np.full((48, 64), 3.0, np.float32))
    np.save(d / "wall.npy", np.full((48, 64), 3.0, np.float32))
    np.save(d / "mm.npy", np.full((48, 64), 3000.0, np.float32))
    Image.fromarray(np.full((48, 64), 3, np.uint16)).save(d / "metres.png")
    write_depth(d / "small.png", np.full((24, 32), 3.0, np.float32))
    (d / "pts.csv").write_text("x,y,z\n0,0,2.7\n0.2,0.1,1.0\n0,0,-1\n")
    (d / "typo.csv").write_text("0.0,0.19,1.49x\n0,0,2.7\n")
    (d / "empty.csv").write_text("# nothing\n")
    lwr = load_robot("lwr4")
    return d, lwr


@st.composite
def distance_args(draw, d, lwr):
    """``(args, malformed)``: the arguments of ``depthguard distance`` with zero to three
    known defects (a bad value, or a required option left out), in any order."""
    q_ok = ",".join("0.1" for _ in range(lwr.dof))
    q_far = ",".join(["0"] * (lwr.dof - 1) + [f"{lwr.q_max[-1] + 0.5:.3f}"])
    # option: (good values, bad values, required)
    options = {
        "--rig": ([str(d / "rig.yaml")], [str(d / "nope.yaml"), str(d / "pts.csv"), str(d / "typo.csv")], True),
        "--depth": ([f"cam0={d / 'wall.png'}", f"cam0={d / 'wall.npy'}"],
                    ["cam0", f"cam7={d / 'wall.png'}", f"cam0={d / 'missing.png'}", f"cam0={d / 'pts.csv'}",
                     f"cam0={d / 'mm.npy'}", f"cam0={d / 'metres.png'}", f"cam0={d / 'small.png'}", "=x"], True),
        "--points": ([str(d / "pts.csv")],
                     [str(d / "typo.csv"), str(d / "empty.csv"), str(d / "gone.csv"), str(d / "wall.png")], True),
        "--rho": (["0.4", "0.25", "1e-3"], ["0", "-0.4", "nan", "inf", "far", ""], False),
        "--method": (["min", "mean", "hybrid"], ["max", "MIN", ""], False),
        "--invalid": (["unknown", "free"], ["maybe"], False),
        "--robot-mode": (["drop", "shadow"], ["keep"], False),
        "--robot-joints": ([q_ok], [q_far, "0,0", "a,b,c,d,e,f,g", ",".join(["nan"] * lwr.dof)], False),
    }
    names = list(options)
    bad = set(draw(st.lists(st.sampled_from(names), max_size=3, unique=True)))
    parts = []
    for name in names:
        good_values, bad_values, required = options[name]
        if name in bad:
            if required and draw(st.booleans()):
                continue                                  # a required option left out
            parts.append([name, draw(st.sampled_from(bad_values))])
        elif required or draw(st.booleans()):
            parts.append([name, draw(st.sampled_from(good_values))])
    args = ["distance"]
    for part in draw(st.permutations(parts)):
        args += part
    if draw(st.booleans()):
        args.append("--json")
    malformed = bool(bad)
    if draw(st.integers(0, 9)) == 0:
        args.append(draw(st.sampled_from(["--unknown-flag", "extra", "--rho"])))
        malformed = True
    return args, malformed


def _run_main(args):
    """``depthguard ARGS`` in this process, as the entry point runs it: (exit status, output)."""
    from depthguard.cli import main

    out, err = io.StringIO(), io.StringIO()
    old = sys.argv
    sys.argv = ["depthguard", *args]
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                main()
                code = 0
            except SystemExit as done:
                code = done.code if isinstance(done.code, int) else (0 if done.code is None else 1)
    finally:
        sys.argv = old
    return code, out.getvalue() + err.getvalue()


@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                 HealthCheck.too_slow])
@given(st.data())
def test_distance_arguments_give_an_answer_only_when_well_formed(distance_files, data):
    d, lwr = distance_files
    args, malformed = data.draw(distance_args(d, lwr))
    code, out = _run_main(args)          # an exception other than SystemExit fails the test: a traceback
    event(f"malformed={malformed} exit={code}")
    if malformed:
        assert code == 2, (args, out)
        assert "Traceback" not in out
        return
    assert code == 0, (args, out)
    if "--json" in args:
        import json
        rows = json.loads(out)["results"]
        assert [r["point"] for r in rows] == [0, 1, 2]
        assert [r["verdict"] for r in rows][2] == "cannot_judge"       # behind the camera
        rho = float(args[args.index("--rho") + 1]) if "--rho" in args else 0.4
        for r in rows:
            assert (r["obstacle_within_rho"] is None) == (r["verdict"] == "cannot_judge" and r["distance"] is None)
            assert r["distance"] is None or 0 <= r["distance"] <= rho + 1e-12
